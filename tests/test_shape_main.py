"""The shape_main-compatible command (automotive.tools.shapes.shape_main, automotive shape-main) through the OMG DDS
interoperability suite's QoS groups: against itself, and with the Fast DDS shape peer (tests/fastdds/shape_peer.cpp)
on either side; and, both on their defaults, with a stand-in for Cyclone's own shape application
(tests/cyclone_shape_peer.py) in a host with a LAN interface, as the suite's runner meets another vendor's
application on one machine.

Each case (tests/shape_cases.py) runs its publishers and subscribers as processes in a network namespace of its own,
created and deleted by the test: the suite's cases use DDS domains 0 and 1, which other tests must not see. Needs
root (ip netns); skipped otherwise. Every application must then stop on SIGINT, as the suite's runner stops them,
with exit code 0 (2 for an option it says is not supported), and print no traceback.
"""

from __future__ import annotations

import itertools
import os
import re
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from apprunner import AppRunner
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from dds_helpers import wait_until
from fastdds_peer import shape_peer
from lan_host import READY as SNIFFING
from lan_host import LanHost
from shape_cases import (
    CYCLONE_DEFAULTS_PAIRS,
    EVENT_TIMEOUT_S,
    FASTDDS_PAIRS,
    OURS_TO_CYCLONE,
    OURS_TO_FASTDDS,
    SELF_CASES,
    Case,
    CaseRun,
    Implementation,
    describe,
)
from test_bad_input import assert_one_line_error
from test_network_config import LOOPBACK_AND_PEER, effective, tracing

from automotive.bus.endpoints import Databus
from automotive.bus.ports import check_domain_id
from automotive.bus.qos import WRITER_REPRESENTATION
from automotive.cyclone.matched import matched_subscriptions
from automotive.tools.shapes.shape_main import parse_options
from automotive.tools.support import netlab
from automotive.tools.support.children import program_command
from automotive.types.shape import ShapeType as SuiteShapeType
from automotive.wire.rawsample import RawWriter

ROOT = Path(__file__).resolve().parent.parent
# Started as `automotive shape-main` starts it: through automotive.start (its import, its signals), without the
# dispatcher.
SHAPE_MAIN = program_command("shape_main")
OURS = Implementation("ours", SHAPE_MAIN)
# Cyclone's application on Cyclone's defaults: no CYCLONEDDS_URI at all (the tests set one for every process).
CYCLONE_DEFAULTS = Implementation("cyclone-defaults", ["env", "-u", "CYCLONEDDS_URI", sys.executable,
                                                       str(ROOT / "tests" / "cyclone_shape_peer.py")])
# Cyclone's defaults announce the participant by multicast to this group on the host's LAN interface.
DEFAULT_SPDP = r" > 239\.255\.0\.1:7400 udp "
_names = itertools.count()


@pytest.fixture
def namespace() -> Iterator[str]:
    """A network namespace with only its own loopback, deleted after the test (and after its processes)."""
    reason = netlab.unavailable()
    if reason is not None:
        pytest.skip(reason)
    with netlab.Namespace(f"shape-{os.getpid()}-{next(_names)}") as created:
        yield created.name


def run_case(case: Case, namespace: str, publisher: Implementation, subscriber: Implementation,
             representation: str) -> None:
    runner = AppRunner(ROOT)
    run = CaseRun(case, runner, namespace, publisher, subscriber, representation)
    try:
        outcomes = run.run()
    finally:
        stopped = run.stop()
        runner.stop_all()
    expected = list(case.outcome)
    asserted = [outcome if want is not None else None for outcome, want in zip(outcomes, expected)]
    assert asserted == expected, describe(run, outcomes)
    for process, code in stopped:
        assert code in (0, 2), f"{process.name} ended with exit code {code}:\n{process.output[-3000:]}"
        assert "Traceback" not in process.output, f"{process.name}:\n{process.output[-3000:]}"
        if code == 2:
            assert "not supported" in process.output or "failed to create" in process.output, process.output


@pytest.mark.parametrize("case", SELF_CASES, ids=[case.name for case in SELF_CASES])
def test_against_itself(case: Case, namespace: str) -> None:
    run_case(case, namespace, OURS, OURS, "2")


@pytest.mark.parametrize("case,direction", FASTDDS_PAIRS,
                         ids=[f"{case.name}-{direction}" for case, direction in FASTDDS_PAIRS])
def test_with_fastdds(case: Case, direction: str, namespace: str) -> None:
    fastdds = Implementation("fastdds", [str(shape_peer())])
    publisher, subscriber = (OURS, fastdds) if direction == OURS_TO_FASTDDS else (fastdds, OURS)
    run_case(case, namespace, publisher, subscriber, "1")  # Fast DDS 2.9 reads and writes XCDR1 only


@pytest.fixture
def lan_host() -> Iterator[LanHost]:
    """A host as the suite's runner runs on: loopback and a multicast-capable eth0 on a LAN (tests/lan_host.py), where
    Cyclone's defaults use eth0; deleted after the test."""
    reason = netlab.unavailable()
    if reason is not None:
        pytest.skip(reason)
    with LanHost("shape") as created:
        yield created


@pytest.mark.parametrize("case,direction", CYCLONE_DEFAULTS_PAIRS,
                         ids=[f"{case.name}-{direction}" for case, direction in CYCLONE_DEFAULTS_PAIRS])
def test_on_its_defaults_it_meets_cyclones_application_on_its_defaults_in_one_host(case: Case, direction: str,
                                                                                 lan_host: LanHost) -> None:
    """The suite's runner with no flags: ours on its single-host default (no CYCLONEDDS_URI, no network option) and
    Cyclone's application on Cyclone's defaults (eth0, multicast) match, either publishing, whichever starts first
    (ours, started after Cyclone's, hears it at its next periodic announcement: within 8 s). The sniffer on the
    host's LAN link shows that the stand-in is indeed on Cyclone's defaults (its announcements go out on eth0)."""
    sniffing = AppRunner(ROOT)
    try:
        sniffer = sniffing.start_command("sniffer", lan_host.sniffer_command())
        sniffer.wait_for(SNIFFING, EVENT_TIMEOUT_S)
        publisher, subscriber = (OURS, CYCLONE_DEFAULTS) if direction == OURS_TO_CYCLONE else (CYCLONE_DEFAULTS, OURS)
        run_case(case, lan_host.host.name, publisher, subscriber, "1")  # the reference's default: XCDR1
        sniffer.wait_for(DEFAULT_SPDP, EVENT_TIMEOUT_S)  # the stand-in announced itself on eth0: Cyclone's defaults
    finally:
        sniffing.stop_all()


@pytest.mark.parametrize("args,pattern", [
    (["-P"], r"please specify topic name \[-t\]"),
    (["-t", "Square"], r"please specify publish \[-P\] or subscribe \[-S\]"),
    (["-P", "-S", "-t", "Square"], r"please specify only one of"),
    (["-P", "-t", "Square", "-D", "x"], r"-D x: expected one of v, l, t, p"),
    (["-P", "-t", "Square", "-x", "3"], r"-x 3: expected one of 1, 2"),
    (["-P", "-t", "Square", "-s", "-2"], r"-s -2: expected at least -1"),
    (["-P", "-t", "Square", "--num-instances", "zero"], r"--num-instances zero: expected an integer"),
    (["-P", "-t", "Square", "--datafrag-size", "70000"], r"--datafrag-size 70000: expected at most 65535"),
    (["-S", "-t", "Square", "-c", "RED", "--cft", "x > 1"], r"cannot specify both --cft and -c"),
    (["-P", "-t", "Square", "--bogus"], r"unrecognized arguments: --bogus"),
])
def test_bad_command_lines_end_with_one_line(args: list[str], pattern: str) -> None:
    result = subprocess.run([*SHAPE_MAIN, *args], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert_one_line_error(result, rf"^automotive shape-main: .*{pattern}")


@pytest.mark.parametrize("text", ["232", "-1", "x"])
def test_an_impossible_domain_is_refused_in_the_words_of_every_program(text: str) -> None:
    with pytest.raises(ValueError) as shared:  # what --domain, -D config.domainId and the launcher say
        check_domain_id(text)
    assert str(shared.value) == f"expected a domain id 0..231, not '{text}'"
    result = subprocess.run([*SHAPE_MAIN, "-S", "-t", "Square", "-d", text], capture_output=True, text=True, cwd=ROOT,
                            timeout=60)
    assert_one_line_error(result, "^" + re.escape(f"automotive shape-main: -d: {shared.value} (automotive shape-main "
                                                  "-h shows the options)") + "$")
    assert result.stdout == "", result.stdout


def test_a_user_uri_is_layered_over_its_configuration_and_what_it_replaces_said_once(  # type: ignore[no-untyped-def]
        apps, domain_id: int, tmp_path: Path) -> None:
    """As for the applications (automotive.bus.network): the URI's network is used, the command's own tuning (the
    reorder limits, fragment 0 of Cyclone's configuration) stays, and one warning line names what the URI replaces;
    an explicit --interface wins over the URI's network; the tests' URI (the loopback configuration itself) replaces
    nothing and is not mentioned."""
    traces = {name: tmp_path / f"{name}.log" for name in ("uri", "explicit")}
    uri = apps.start("shape_main", "-S", "-t", "Square", "-d", str(domain_id),
                     env={"CYCLONEDDS_URI": f"{LOOPBACK_AND_PEER},{tracing(traces['uri'])}"})
    explicit = apps.start("shape_main", "-S", "-t", "Square", "-d", str(domain_id), "--interface", "lo",
                          env={"CYCLONEDDS_URI": f"{LOOPBACK_AND_PEER},{tracing(traces['explicit'])}"})
    tests_uri = apps.start("shape_main", "-S", "-t", "Square", "-d", str(domain_id))
    for process in (uri, explicit, tests_uri):
        process.wait_for(r"^Create reader for topic: Square$", 60)
        assert process.stop(signal.SIGINT) == 0, process.output[-3000:]
    assert uri.count(r"^warning: network: ") == 1, uri.output
    assert uri.count(r"^warning: network: your CYCLONEDDS_URI sets General/Interfaces, Discovery/Peers, which replace "
                     r"the applications' network \(single host \(loopback\)\)$") == 1, uri.output
    assert effective(traces["uri"], "Internal/PrimaryReorderMaxSamples/#text") == ["512 {0}"]
    assert effective(traces["uri"], "General/Interfaces/NetworkInterface[@name]") == ["lo {1}"]
    assert effective(traces["uri"], "Discovery/Peers/Peer[@Address]") == ["127.0.0.1 {2}"]
    assert explicit.count(r"^warning: network: ") == 1, explicit.output
    assert explicit.count(r"^warning: network: --interface replaces the network your CYCLONEDDS_URI sets "
                          r"\(Discovery/Peers\)$") == 1, explicit.output
    assert effective(traces["explicit"], "Discovery/Peers/Peer[@Address]") == []
    assert "warning: network" not in tests_uri.output, tests_uri.output


def test_an_unreadable_user_uri_is_one_line(tmp_path: Path) -> None:
    result = subprocess.run([*SHAPE_MAIN, "-S", "-t", "Square"],
                            capture_output=True, text=True, cwd=ROOT, timeout=60,
                            env={**os.environ, "CYCLONEDDS_URI": f"{tmp_path}/missing.xml"})
    assert_one_line_error(result, rf"^automotive shape-main: CYCLONEDDS_URI: file '{tmp_path}/missing.xml' not found")
    assert "Create topic" not in result.stdout, result.stdout  # refused before the participant


def test_sigint_while_ending_keeps_the_exit_code(domain_id: int) -> None:
    """The suite's runner sends SIGINT when it is done, also while the command is already ending after 'not
    supported': the exit code stays 2 (it was -2, the signal, once Python had given its handler back)."""
    import signal

    command = [*SHAPE_MAIN, "-S", "-t", "Square", "--coherent", "--access-scope", "i", "-d", str(domain_id)]
    with subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) as process:
        assert process.stdout is not None
        printed = ""
        while "not supported" not in printed:
            line = process.stdout.readline()
            assert line, f"ended without 'not supported': {printed}"
            printed += line
        for _ in range(30_000):  # SIGINT again and again until it has ended (at most about a minute)
            if process.poll() is not None:
                break
            process.send_signal(signal.SIGINT)
            try:
                process.wait(timeout=0.002)
            except subprocess.TimeoutExpired:
                pass
        process.stdout.read()
    assert process.returncode == 2


@pytest.mark.parametrize("args,reliable", [([], True), (["-b"], False), (["-r", "-b"], False), (["-b", "-r"], True)])
def test_the_last_of_b_and_r_wins(args: list[str], reliable: bool) -> None:
    assert parse_options(["-S", "-t", "Square", *args]).reliable is reliable


def test_a_bad_colour_whose_instance_then_ends_is_reported_and_the_subscriber_goes_on(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                                                       bus: Databus) -> None:
    """Another system writes a colour that is not UTF-8 and disposes that instance: the subscriber reports the bad
    sample, prints the instance's end with '?' for the colour it cannot decode, and goes on (it ended on this)."""
    subscriber = apps.start("shape_main", "-S", "-t", "Square", "-d", str(domain_id))
    writer: DataWriter[SuiteShapeType] = DataWriter(bus.participant, bus.topic("Square", SuiteShapeType),
                                                    qos=Qos(Policy.Reliability.Reliable(0), WRITER_REPRESENTATION))
    wait_until(lambda: bool(matched_subscriptions(writer)), 60, "the subscriber's reader")
    raw = RawWriter(writer)
    bad = bytes(SuiteShapeType(color="BAD", x=1, y=2, shapesize=3, additional_payload_size=b"").serialize(
        use_version_2=False)).replace(b"BAD\0", b"\xff\xfe\xfd\0")

    def ended() -> bool:  # written again until seen: the reader may not know the writer it matched yet
        raw.write(bad)
        raw.dispose(bad)
        return subscriber.count(r"^Square +\? +NOT_ALIVE_DISPOSED_INSTANCE_STATE") > 0

    wait_until(ended, 60, "the bad instance's end")
    subscriber.wait_for(r"\[Square\] bad sample ignored: undecodable \(UnicodeDecodeError", 60)
    writer.write(SuiteShapeType(color="GREEN", x=10, y=20, shapesize=30, additional_payload_size=b""))
    subscriber.wait_for(r"^Square +GREEN +010 020 \[30\]", 60)
    assert subscriber.stop(signal.SIGINT) == 0, subscriber.output[-3000:]
    assert "Traceback" not in subscriber.output, subscriber.output[-3000:]


def test_a_write_that_times_out_is_not_the_end_of_the_publisher(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    """KEEP_ALL, reliable, 100 kB samples and a reader that does not acknowledge (its process stopped): the writer's
    history fills and write gives up after max_blocking_time. The reference ignores that and writes the next sample;
    ours ended on the DDSException instead (seen once in the suite's LargeData_0, loaded machine)."""
    subscriber = apps.start("shape_main", "-S", "-t", "Square", "-r", "-k", "0", "-d", str(domain_id))
    publisher = apps.start("shape_main", "-P", "-t", "Square", "-r", "-k", "0", "--additional-payload-size",
                           "100000", "-d", str(domain_id))
    subscriber.wait_for(r"^Square +BLUE +\d{3} \d{3} \[\d+\] \{255\}", 60)
    with subscriber.frozen():  # SIGSTOP: no more acknowledgements
        publisher.wait_for(r"automotive shape-main: write of BLUE on Square not done \(DDS_RETCODE_TIMEOUT\)", 60)
        assert publisher.poll() is None, publisher.output[-3000:]
    seen = subscriber.count(r"\{255\}")
    subscriber.wait_for_more(r"^Square +BLUE +\d{3} \d{3} \[\d+\] \{255\}", 1, 60)  # it writes on
    assert subscriber.count(r"\{255\}") > seen
    for process in (publisher, subscriber):
        assert process.stop(signal.SIGINT) == 0, process.output[-3000:]
        assert "Traceback" not in process.output, process.output[-3000:]
