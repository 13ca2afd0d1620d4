"""The shared runtime: endpoints from profiles exchange data, network configurations, the command line."""

from __future__ import annotations

import logging
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest
from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet

from automotive import config
from automotive.bus.endpoints import Databus, wait_for_acks
from automotive.bus.errors import ConfigError
from automotive.bus.network import NetworkConfig, PeerPlan, plan_peers
from automotive.bus.qos import QosProfiles
from automotive.cyclone.bounds import BoundError
from automotive.types.Alerts import DriverAlerts
from automotive.types.Common import ClassificationEnum, POSIXTimestamp
from automotive.types.Vision import VisionObject, VisionSensor

ROOT = Path(__file__).resolve().parent.parent
PROFILES = QosProfiles(config.qos_file())


def wait_for_samples(reader, count: int, timeout: float = 10.0) -> list:  # type: ignore[no-untyped-def]
    waitset = WaitSet(reader.participant)
    waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any))
    received: list = []
    deadline = time.monotonic() + timeout
    while len(received) < count and time.monotonic() < deadline:
        waitset.wait(int(0.2e9))
        received.extend(reader.take(N=100))
    return received


def test_writer_and_reader_from_profiles_exchange_data(domain_id: int) -> None:
    log = logging.getLogger("test")
    bus = Databus(domain_id, PROFILES, "AutomotiveLibrary", log, NetworkConfig())
    try:
        reader = bus.reader("AlertTopic", DriverAlerts, "HMI")
        writer = bus.writer("AlertTopic", DriverAlerts, "HMI")
        alert = DriverAlerts(blindSpotDriver=False, blindSpotPassenger=True, frontCollision=False,
                             backCollision=False, parkingCollision=False, driverAttention=True)
        writer.write(alert)
        assert wait_for_samples(reader, 1) == [alert]

        vision_reader = bus.reader("VisionTopic", VisionSensor, "Vision")
        vision_writer = bus.writer("VisionTopic", VisionSensor, "Vision")
        deadline = time.monotonic() + 10
        while vision_writer.get_matched_subscriptions() == [] and time.monotonic() < deadline:
            time.sleep(0.01)  # best effort: write only once matched
        obj = VisionObject(ClassificationEnum.CLASSIFICATION_CAR, [1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0])
        samples = [VisionSensor(id=i, timestamp=POSIXTimestamp(1, 2), objects=[obj] * i) for i in (1, 2)]
        for sample in samples:
            vision_writer.write(sample)
        assert sorted(wait_for_samples(vision_reader, 2), key=lambda s: s.id) == samples
        with pytest.raises(BoundError, match="Vision::VisionSensor.objects holds 11 elements"):
            vision_writer.write(VisionSensor(id=3, timestamp=POSIXTimestamp(1, 2), objects=[obj] * 11))
    finally:
        bus.close()


_STOPPABLE_ALERT_READER = """
import logging, sys, time
from automotive import config
from automotive.bus.endpoints import Databus
from automotive.bus.network import NetworkConfig
from automotive.bus.qos import QosProfiles
from automotive.types.Alerts import DriverAlerts
bus = Databus(int(sys.argv[1]), QosProfiles(config.qos_file()), "AutomotiveLibrary", logging.getLogger("reader"),
              NetworkConfig())
reader = bus.reader("AlertTopic", DriverAlerts, "HMI")
print("reader ready", flush=True)
time.sleep(600)
"""


def test_wait_for_acks_is_false_while_a_matched_reader_does_not_acknowledge(domain_id: int) -> None:
    """A reliable writer whose reader (another process, stopped by SIGSTOP) cannot acknowledge: wait_for_acks says
    False when its time runs out (Cyclone DDS Python 11.0.1's own raises AttributeError there), then True once the
    reader goes on."""
    bus = Databus(domain_id, PROFILES, "AutomotiveLibrary", logging.getLogger("test"), NetworkConfig())
    reader = subprocess.Popen([sys.executable, "-c", _STOPPABLE_ALERT_READER, str(domain_id)], stdout=subprocess.PIPE,
                              text=True)
    try:
        writer = bus.writer("AlertTopic", DriverAlerts, "HMI")
        assert reader.stdout is not None and reader.stdout.readline().strip() == "reader ready"
        deadline = time.monotonic() + 120
        while not writer.get_matched_subscriptions():
            assert time.monotonic() < deadline, "the reader did not match in 120 s"
            time.sleep(0.02)
        # Cyclone's writer may not wait for a reader that has not yet answered one of its heartbeats (a reader stopped
        # that early made the wait succeed, once in a clean-clone run). So stop, write and wait again until one wait
        # runs out (the reader answers the heartbeats of each round while it runs); every round ends acknowledged.
        outcomes = []
        while False not in outcomes:
            assert time.monotonic() < deadline, f"wait_for_acks never ran out with a stopped reader: {outcomes}"
            reader.send_signal(signal.SIGSTOP)
            writer.write(DriverAlerts(blindSpotDriver=False, blindSpotPassenger=False, frontCollision=True,
                                      backCollision=False, parkingCollision=False, driverAttention=False))
            outcomes.append(wait_for_acks(writer, int(0.2e9)))
            reader.send_signal(signal.SIGCONT)
            assert wait_for_acks(writer, int(60e9)) is True
    finally:
        reader.send_signal(signal.SIGCONT)
        reader.kill()
        reader.wait(timeout=30)
        bus.close()


def test_network_configurations() -> None:
    loopback = replace(NetworkConfig.from_settings(), host_interface="").cyclone_xml()
    assert '<NetworkInterface name="lo"/>' in loopback and "<AllowMulticast>false" in loopback
    # every index of this host probed as long as the application runs, every 2 s: a tool started later is found
    assert '<Peer address="127.0.0.1" PruneDelay="inf"/>' in loopback and "<SPDPInterval>2s<" in loopback
    # with the host's LAN interface, for Cyclone's default tools on the host: multicast on lo only, unicast on the
    # LAN interface, no group joined, and the tools' multicast (arriving on an interface used for unicast) kept
    on_lan = replace(NetworkConfig.from_settings(), host_interface="eth7").cyclone_xml()
    assert ('<Interfaces><NetworkInterface name="lo" multicast="true" allow_multicast="spdp"/>'
            '<NetworkInterface name="eth7" allow_multicast="false"/></Interfaces>') in on_lan
    assert "<AllowMulticast>false" in on_lan and "<MulticastRecvNetworkInterfaceAddresses>none<" in on_lan
    assert "<ExtendedPacketInfo>false</ExtendedPacketInfo>" in on_lan and "<MulticastTimeToLive>" not in on_lan
    assert '<Peer address="127.0.0.1" PruneDelay="inf"/>' in on_lan
    # on a host whose only interface is the loopback, as Cyclone's defaults there: multicast discovery on lo, the group
    # joined there (MulticastRecvNetworkInterfaceAddresses at Cyclone's default), and the probes of 127.0.0.1
    only_lo = replace(NetworkConfig.from_settings(), host_interface="lo").cyclone_xml()
    assert ('<Interfaces><NetworkInterface name="lo" multicast="true" allow_multicast="spdp"/></Interfaces>'
            in only_lo)
    assert "<MulticastRecvNetworkInterfaceAddresses>" not in only_lo and "<AllowMulticast>false" in only_lo
    assert '<Peer address="127.0.0.1" PruneDelay="inf"/>' in only_lo and "<SPDPInterval>2s<" in only_lo

    lan = NetworkConfig.from_settings(interface="eth1").cyclone_xml()
    assert '<NetworkInterface name="eth1"/>' in lan and "<AllowMulticast>true" in lan and "<Peer" not in lan

    peers = NetworkConfig.from_settings(peers=["10.0.0.2", "hostb"], interface="eth1", max_participants=30)
    xml = peers.cyclone_xml(PeerPlan(remote=("10.0.0.2", "10.0.0.3"), own=("10.0.0.1",)))
    assert "<AllowMulticast>false" in xml
    assert '<NetworkInterface name="eth1"/>' in xml
    # every host (this one too: Cyclone adds its interface's address) probed as long as the application runs
    assert '<Peer address="10.0.0.2"/><Peer address="10.0.0.3"/><Peer address="10.0.0.1"/>' in xml
    assert "PruneDelay=" not in xml and "<InitialLocatorPruneDelay>inf<" in xml
    # RTI answers a participant of its own host through 127.0.0.1: Cyclone must not drop what arrives on lo
    assert "<ExtendedPacketInfo>false</ExtendedPacketInfo>" in xml
    assert "<MaxAutoParticipantIndex>30</MaxAutoParticipantIndex>" in xml
    assert "<SPDPInterval>1s</SPDPInterval>" in xml
    # without an interface, the one on the route to the first other host
    unnamed = NetworkConfig.from_settings(peers=["10.0.0.2"])
    routed = unnamed.cyclone_xml(PeerPlan(("10.0.0.2",), route_source="10.0.0.1"))
    assert '<NetworkInterface address="10.0.0.1"/>' in routed

    plan = plan_peers(("127.0.0.1", "localhost", "no-such-host.invalid"))
    assert plan.own == ("127.0.0.1",) and plan.remote == ()
    assert [peer for peer, _ in plan.unusable] == ["no-such-host.invalid"]
    assert "does not resolve" in plan.unusable[0][1]

    large = NetworkConfig.from_settings(large_data=True).cyclone_xml()
    assert "<FragmentSize>62000B</FragmentSize>" in large and "<MaxMessageSize>63500B</MaxMessageSize>" in large
    assert '<SocketReceiveBufferSize min="default" max="4MiB"/>' in large
    assert "<FragmentSize>" not in loopback


def test_cyclone_c_tools_accept_their_loopback_configuration(domain_id: int) -> None:
    """Debian's ddsperf (Cyclone C 0.10.2, the benchmarks' reference) stops on the PruneDelay attribute that the
    runtime's loopback peer carries (unknown before Cyclone 0.11); the configuration made for it runs."""
    ddsperf = shutil.which("ddsperf")
    assert ddsperf is not None, "ddsperf (Debian's cyclonedds-tools, installed by scripts/setup) is not on PATH"
    xml = NetworkConfig(large_data=True, cyclone_0_10=True).cyclone_xml()
    assert '<Peer address="127.0.0.1"/>' in xml
    result = subprocess.run([ddsperf, "-i", str(domain_id), "-D", "0.2", "sub"], capture_output=True, text=True,
                            env=dict(os.environ, CYCLONEDDS_URI=xml), timeout=30)
    assert result.returncode == 0 and "config:" not in result.stdout + result.stderr, result.stdout + result.stderr

    with pytest.raises(ConfigError, match="peer 'bad host!' is not a host name or IP address"):
        NetworkConfig.from_settings(peers=["bad host!"])
    with pytest.raises(ConfigError, match="network 'peers' needs a list of peers"):
        NetworkConfig.from_settings(network="peers")
    with pytest.raises(ConfigError, match="network 'wifi' is not one of loopback, lan, peers"):
        NetworkConfig.from_settings(network="wifi")


# --- the command-line convention, through a real application (the HMI needs no data file) --------------------------

def test_count_and_clean_exit(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    hmi = apps.start("hmi", "--ui", "console", "--domain", str(domain_id))
    hmi.wait_for("waiting for alerts")
    assert hmi.stop(signal.SIGTERM) == 0
    assert "stopped" in hmi.output and "Traceback" not in hmi.output

    hmi = apps.start("hmi", "--ui", "console", "--domain", str(domain_id))
    hmi.wait_for("waiting for alerts")
    assert hmi.stop(signal.SIGINT) == 0
    assert "Traceback" not in hmi.output


def test_sigusr1_prints_every_threads_stack_and_the_application_goes_on(apps,  # type: ignore[no-untyped-def]
                                                                        domain_id: int) -> None:
    hmi = apps.start("hmi", "--ui", "console", "--domain", str(domain_id))
    hmi.wait_for("waiting for alerts")
    hmi.send_signal(signal.SIGUSR1)
    hmi.wait_for(r"^Current thread 0x[0-9a-f]+ \(most recent call first\):$")
    hmi.wait_for(r'^  File ".*automotive/bus/app\.py", line \d+ in run$')  # the main thread, in the run loop
    assert hmi.poll() is None  # a dump, not an end
    assert hmi.stop(signal.SIGTERM) == 0


# A stop signal that lands while the main thread holds the lock inside the Event that stops it (Event.wait and
# Event.clear take it many times a second in a run loop): a handler that set the Event there waited for itself for
# ever. The work is done by the signal thread, which only waits until the main thread lets go.
STOP_WHILE_THE_LOCK_IS_HELD = """
import os, signal, sys, threading, time
from automotive.bus.cli import on_signals
stopped = threading.Event()
served_by = []
on_signals([signal.SIGTERM], lambda signum: (served_by.append(threading.current_thread().name), stopped.set()))
with stopped._cond:  # what Event.wait and Event.clear hold, for a few bytecodes
    os.kill(os.getpid(), signal.SIGTERM)
    deadline = time.monotonic() + 10
    while not served_by and time.monotonic() < deadline:  # Python keeps running bytecodes: the handler's chance
        pass
assert stopped.wait(10), "the stop was lost"
print("stopped by", served_by[0])
"""


def test_a_stop_signal_while_the_main_thread_holds_the_stop_events_lock_still_stops() -> None:
    result = subprocess.run([sys.executable, "-c", STOP_WHILE_THE_LOCK_IS_HELD], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "stopped by signals"


# A second stop signal while the application closes (``timeout -s INT`` signals the process and its group: two) is
# served like the first; Python's default handler, given back too early, raised KeyboardInterrupt in the close.
SIGNAL_DURING_CLOSE = """
import os, signal, sys, time
from automotive.bus import app as app_module
close = app_module.Application.close

def close_after_a_signal(self):
    os.kill(os.getpid(), signal.SIGINT)
    deadline = time.monotonic() + 0.5
    while time.monotonic() < deadline:  # bytecodes: the main-thread handler runs here
        pass
    close(self)

app_module.Application.close = close_after_a_signal
code = app_module.run("hmi", "test", lambda app: None, ["--domain", sys.argv[1]])
print("exit code", code)
"""


def test_a_stop_signal_while_the_application_closes_does_not_cut_the_close(domain_id: int) -> None:
    result = subprocess.run([sys.executable, "-c", SIGNAL_DURING_CLOSE, str(domain_id)], capture_output=True,
                            text=True, timeout=60)
    assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr
    assert result.stdout.strip().endswith("exit code 0"), result.stdout


def test_an_application_says_when_it_sees_no_peer(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    hmi = apps.start("hmi", "--ui", "console", "--domain", str(domain_id), "-D", "config.matchReport=1")
    hmi.wait_for(r"\[AlertTopic\] reader: no writer matched after 1 s")
    hmi.wait_for(r"no peer seen after 1 s: nothing matched on any topic")


@pytest.mark.parametrize("args,message", [
    (["-D", "config.domainId=abc"], r"^automotive-hmi: -D: config.domainId = 'abc' is not an integer$"),
    (["-D", "config.domainId=999"], r"^automotive-hmi: -D: config.domainId: expected a domain id 0..231, not '999'$"),
    (["-D", "qos.Alerts.Profile=Nope"],
     r"^automotive-hmi: .*automotive_qos.xml: no QoS profile 'AutomotiveLibrary::Nope'"),
    (["-D", "qos.File=/nonexistent/qos.xml"], r"^automotive-hmi: /nonexistent/qos.xml: QoS file not found$"),
    (["-D", "config.typo=1"], r"^automotive-hmi: .*hmi.properties: unknown key\(s\) for hmi: 'config.typo' \(-D\)$"),
    (["--properties", "/nonexistent/hmi.properties"],
     r"^automotive-hmi: /nonexistent/hmi.properties: properties file not found$"),
    (["--peers", "bad host!"], r"^automotive-hmi: .*peer 'bad host!' is not a host name or IP address$"),
    (["--count", "-1"], r"^automotive-hmi: --count -1: expected 0 \(forever\) or a positive number$"),
])
def test_bad_input_is_one_line_and_exit_2(apps, args: list[str], message: str) -> None:  # type: ignore[no-untyped-def]
    result = apps.run("hmi", "--ui", "console", *args)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert re.search(message, lines[0]), lines[0]
    assert "Traceback" not in result.stderr + result.stdout


def test_takes_in_a_wake_up_loop_are_counted_and_timed_after_the_outputs_with_the_takes_clock(bus: Databus) -> None:
    """Inside an application's wake-up loop (deferred_bookkeeping) a take's count and latency wait until the loop
    books them, after the application's outputs, and the latency is the take's; outside, they are booked at once."""
    from automotive.bus import console, latency
    from automotive.bus.checkedreader import deferred_bookkeeping

    topic = "BookkeepingTopic"
    writer = bus.writer(topic, DriverAlerts, "HMI")
    reader = bus.reader(topic, DriverAlerts, "HMI")
    deadline = time.monotonic() + 10
    while not writer.get_matched_subscriptions() and time.monotonic() < deadline:
        time.sleep(0.01)
    alert = DriverAlerts(False, False, False, False, False, True)

    def counted() -> int:
        return console.traffic.totals()[0].get(topic, 0)

    def latencies() -> list[latency.LatencySummary]:
        return [summary for summary in latency.recent.summaries() if summary.topic == topic and summary.writer is None]

    stamp = time.time_ns() - 5_000_000_000  # written "5 s ago": the latency is about 5,000 ms
    writer.write(alert, timestamp=stamp)
    with deferred_bookkeeping() as book:
        assert wait_for_samples(reader, 1) == [alert]
        taken_ns = time.time_ns()
        assert counted() == 0 and latencies() == []  # not yet: the application writes its outputs first
        time.sleep(0.2)  # time passes before the booking; the latency must not include it
        book()
        assert counted() == 1
        [summary] = latencies()
        assert 5_000 <= summary.p50_ms <= (taken_ns - stamp) / 1e6, summary
    writer.write(alert, timestamp=time.time_ns())
    assert wait_for_samples(reader, 1) == [alert]
    assert counted() == 2 and latencies()[0].count == 2  # outside the loop: at once


def test_matched_endpoints_are_asked_past_cyclone_pythons_race_while_readers_come_and_go(domain_id: int) -> None:
    """Cyclone DDS Python sizes the list of matches with one call into libddsc and fills it with a second: a reader
    that matches in between makes it raise IndexError (a user's tool joining could end an application). Readers
    come and go in another thread until Cyclone's own call has raised it; ours never does meanwhile."""
    import threading

    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from automotive.cyclone.matched import matched_publications, matched_subscriptions

    participant = DomainParticipant(domain_id)
    topic = Topic(participant, "MatchRaceTopic", DriverAlerts)
    writer = DataWriter(participant, topic)
    reader = DataReader(participant, topic)
    done = threading.Event()

    def readers_and_writers_come_and_go() -> None:
        endpoints: list[DataReader[DriverAlerts] | DataWriter[DriverAlerts]] = []
        while not done.is_set():
            endpoints += [DataReader(participant, topic), DataWriter(participant, topic)]
            if len(endpoints) > 20:
                for endpoint in endpoints[:2]:
                    endpoint.__del__()
                del endpoints[:2]

    storm = threading.Thread(target=readers_and_writers_come_and_go, daemon=True)
    storm.start()
    races = asked = 0
    deadline = time.monotonic() + 120
    try:
        while (races == 0 or asked < 5_000) and time.monotonic() < deadline:
            try:
                writer.get_matched_subscriptions()
                reader.get_matched_publications()
            except IndexError:
                races += 1
            assert matched_subscriptions(writer) and matched_publications(reader)  # never raises
            asked += 1
    finally:
        done.set()
        storm.join()
        participant.__del__()
    assert races > 0, f"Cyclone's own call never raised in {asked} calls: the race is gone, and this module with it"


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: OpenBLAS would start no thread of its own anyway")
def test_numpy_starts_no_blas_threads_in_a_program() -> None:
    """OpenBLAS's threads (one per core, spinning at numpy's import) are not started: the package sets
    OPENBLAS_NUM_THREADS=1 unless the user did, and the programs it starts inherit it."""
    environment = {name: value for name, value in os.environ.items() if name != "OPENBLAS_NUM_THREADS"}
    count = "import os, numpy; print(len(os.listdir('/proc/self/task')), os.environ['OPENBLAS_NUM_THREADS'])"
    ours = subprocess.run([sys.executable, "-c", f"import automotive; {count}"], env=environment,
                          capture_output=True, text=True, timeout=60, check=True)
    assert ours.stdout.split() == ["1", "1"], ours.stdout + ours.stderr
    mine = subprocess.run([sys.executable, "-c", f"import automotive; {count}"],
                          env={**environment, "OPENBLAS_NUM_THREADS": "2"}, capture_output=True, text=True,
                          timeout=60, check=True)
    assert mine.stdout.split() == ["2", "2"], mine.stdout + mine.stderr  # the user's own setting is kept
