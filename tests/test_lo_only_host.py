"""Who finds the system on its shipped defaults on a host whose only interface is the loopback.

A laptop with its network off, a container started without a network, a CI sandbox: a network namespace with only `lo`
up. Cyclone DDS on its own defaults uses `lo` there, for everything: it announces itself by multicast to 239.255.0.1
on `lo` (the group joined there), with no participant index (unicast on ports nobody can guess). The single-host
default does the same for discovery on such a host (automotive.bus.network), so:

- `cyclonedds ps` (no CYCLONEDDS_URI) lists every application, started before the system or long after it; a plain
  Cyclone participant on its defaults reads every flow from the application that writes it and is matched by every
  application that reads one, in either join order; `automotive shape-main` on its defaults and a stand-in for
  Cyclone's shape application on Cyclone's defaults (tests/cyclone_shape_peer.py) match, either publishing.
- When a LAN interface comes up later (the laptop's network returns), the applications started before go on working,
  an application started after it finds them, and nothing of theirs goes out on the new interface.

The LAN-host versions of these tests are tests/test_host_discovery.py and tests/test_shape_main.py, whose helpers
this module uses (the plain participant is test_host_discovery.py run as a script). Every process that must run on
its defaults runs without the tests' CYCLONEDDS_URI (tests/conftest.py). Needs root (ip netns); skipped otherwise.
"""

from __future__ import annotations

import itertools
import json
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from apprunner import AppRunner, CommandProcess
from dds_helpers import CYCLONEDDS_CLI, wait_until
from lan_host import READY, SNIFFER, frames
from shape_cases import CYCLONE_DEFAULTS_PAIRS, OURS_TO_CYCLONE, Case
from test_host_discovery import (
    APPS,
    LATE_S,
    STATUS_INTERVAL_S,
    TOOL_FIRST_TIMEOUT_S,
    announcers,
    assert_reads_every_flow_and_every_application_finds_it,
    every_flow,
    launch_command,
    needs_namespaces,
    on_defaults,
    participant_command,
    run_ps,
    status_line,
)
from test_shape_main import CYCLONE_DEFAULTS, OURS, run_case

from automotive.tools.support import netlab
from automotive.tools.support.children import program_command

ROOT = Path(__file__).resolve().parent.parent
# `cyclonedds ps` started before the system scans this long: past the plain participant's wait for every flow.
PS_FIRST_SCAN_S = TOOL_FIRST_TIMEOUT_S + 20
# The LAN that comes up later: a veth to a namespace of its own, a private /24 used only inside the test.
LATER_HOST_ADDRESS, LATER_LAN_ADDRESS = "10.234.0.1", "10.234.0.2"
# Our monitor started after the LAN came up, listing the domain's participants after this long a scan.
MONITOR_WAIT_S = 8
# One datagram to the discard port of the address given (the sniffer's proof that it watches the link).
PROBE = "import socket, sys; socket.socket(socket.AF_INET, socket.SOCK_DGRAM).sendto(b'probe', (sys.argv[1], 9))"
_names = itertools.count()


def namespace_name(prefix: str) -> str:
    return f"{prefix}-{os.getpid()}-{next(_names)}"


def lo_sniffer(host: netlab.Namespace) -> list[str]:
    """A sniffer of the namespace's loopback device (tests/lan_host.py): a line per datagram sent on it."""
    return host.exec(sys.executable, str(SNIFFER), "lo")


def ps_names(output: str) -> set[str]:
    """The participant names in a `cyclonedds ps` table."""
    return set(re.findall(r"│ (\w+) \([0-9a-f-]{36}\)", output))


def assert_only_loopback(host: netlab.Namespace) -> None:
    links = netlab.run("ip", "-n", host.name, "-o", "link", "show").stdout
    assert re.findall(r"^\d+: (\S+?):", links, re.M) == ["lo"], links


# -- tools first, then the system ------------------------------------------------------------------------------------

def test_tools_started_before_the_system_find_every_application(apps: AppRunner, domain_id: int,
                                                                tmp_path: Path) -> None:
    """`cyclonedds ps` and the plain participant, both on Cyclone's defaults, have announced themselves (multicast on
    lo) before the system starts: each application finds them."""
    needs_namespaces()
    with netlab.Namespace(namespace_name("lo-only")) as host:
        assert_only_loopback(host)
        try:
            sniffer = apps.start_command("sniffer", lo_sniffer(host))
            sniffer.wait_for(READY)
            ps = apps.start_command("ps", on_defaults(host, CYCLONEDDS_CLI, "ps", "--id", str(domain_id), "--runtime",
                                                      f"{PS_FIRST_SCAN_S}s", "--suppress-progress-bar", "--color",
                                                      "none"), env={"COLUMNS": "250"})
            plain = apps.start_command("plain", on_defaults(host, *participant_command(domain_id, "plain",
                                                                                      *every_flow())))
            plain.wait_for(r"^ready$")
            # Both tools have announced themselves by multicast on lo before the first application exists.
            wait_until(lambda: len(announcers(sniffer, domain_id)) >= 2, timeout=30,
                       what="the first announcements of both tools")
            launcher = apps.start_command("launch", on_defaults(host, *launch_command(domain_id, tmp_path)))
            assert_reads_every_flow_and_every_application_finds_it(plain, timeout=TOOL_FIRST_TIMEOUT_S)
            # Done with: for the rest of ps's scan, the camera's 4 MiB frames would cost it and the camera a third of
            # a core each (a third of this test's CPU, 2026-11-28).
            plain.stop()
            assert ps.wait_exit(timeout=PS_FIRST_SCAN_S + 30) == 0, ps.output
            assert ps_names(ps.output) >= set(APPS), ps.output
            assert "Traceback" not in launcher.output
        finally:
            apps.stop_all()


# -- the system first, the tools after it (one system for these tests) ------------------------------------------------

@dataclass
class System:
    host: netlab.Namespace
    runner: AppRunner
    launcher: CommandProcess
    domain: int

    def start(self, name: str, *command: str) -> CommandProcess:
        return self.runner.start_command(name, on_defaults(self.host, *command))



@pytest.fixture(scope="module")
def system(module_domain_id: int, tmp_path_factory: pytest.TempPathFactory) -> Iterator[System]:
    """The system, started alone in a namespace with only lo, left running for the module's tests that join later."""
    needs_namespaces()
    runner = AppRunner(ROOT)
    with netlab.Namespace(namespace_name("lo-only")) as host:
        assert_only_loopback(host)
        try:
            launcher = runner.start_command("launch", on_defaults(host, *launch_command(
                module_domain_id, tmp_path_factory.mktemp("system"))))
            for app in APPS:
                launcher.wait_for(status_line(app), timeout=60)
            for app in APPS:
                launcher.wait_for(status_line(app), count=2, timeout=2 * STATUS_INTERVAL_S + 10)
            yield System(host, runner, launcher, module_domain_id)
        finally:
            runner.stop_all()


def test_cyclonedds_ps_started_after_the_system_lists_every_application(system: System) -> None:
    assert run_ps(system.host, system.domain) >= set(APPS)


def test_plain_participant_joining_the_system_reads_every_flow_and_every_application_finds_it(
        system: System) -> None:
    plain = system.start("plain", *participant_command(system.domain, "plain", *every_flow()))
    try:
        plain.wait_for(r"^ready$")
        assert_reads_every_flow_and_every_application_finds_it(plain, timeout=20)
    finally:
        plain.stop()


def test_cyclonedds_ps_joining_long_after_the_start_lists_every_application(system: System) -> None:
    for app in APPS:  # the system has run for LATE_S: LATE_S / 5 status lines of each application
        system.launcher.wait_for(status_line(app), count=LATE_S // STATUS_INTERVAL_S, timeout=LATE_S + 30)
    assert run_ps(system.host, system.domain) >= set(APPS)


def test_a_lan_interface_coming_up_later_breaks_nothing_and_carries_nothing_of_the_applications(
        system: System) -> None:
    """Last of the module (it adds the interface to the system's namespace): the network returns. The applications,
    started with only lo, go on exchanging their flows; an application of ours started now (the monitor, which uses
    lo and the new interface) finds every one of them; no datagram of theirs goes out on the new interface (a sniffer
    at its far end)."""
    with netlab.Namespace(namespace_name("lo-later-lan")) as lan:
        for namespace in (system.host, lan):  # no IPv6 chatter of the kernel's among the frames
            netlab.run(*namespace.exec("sysctl", "-qw", "net.ipv6.conf.all.disable_ipv6=1",
                                       "net.ipv6.conf.default.disable_ipv6=1"))
        sniffer = system.runner.start_command("lan_sniffer", lan.exec(sys.executable, str(SNIFFER), "lan0"))
        try:
            netlab.veth(system.host, "eth0", LATER_HOST_ADDRESS, lan, "lan0", LATER_LAN_ADDRESS, multicast=True)
            netlab.run("ip", "-n", system.host.name, "route", "add", "default", "via", LATER_LAN_ADDRESS)
            sniffer.wait_for(READY)
            lines_before = len(system.launcher.lines)
            monitor = subprocess.run(on_defaults(system.host, *program_command(
                "monitor", "--domain", str(system.domain), "--once", "--json", "--wait", str(MONITOR_WAIT_S))),
                capture_output=True, text=True, timeout=MONITOR_WAIT_S + 60, cwd=ROOT)
            assert monitor.returncode == 0, monitor.stdout + monitor.stderr
            seen = {participant["name"] for participant in json.loads(monitor.stdout)["participants"]}
            assert seen >= set(APPS), seen
            # Every application still at work, and the flows still flowing: collision avoidance's status line after
            # the interface came up counts SensorObjects (from sensor_fusion, itself fed by vision and lidar) and
            # PlatformStatus (from vehicle_platform, fed by collision avoidance's PlatformControl) above 0/s.
            for app in APPS:
                system.launcher.wait_for_more(status_line(app), timeout=STATUS_INTERVAL_S + 10)
            latest = [line for line in system.launcher.lines[lines_before:]
                      if re.match(status_line("collision_avoidance"), line)][-1]
            assert not re.search(r"\b(SensorObjects|PlatformStatus) 0/s", latest), latest
            # The sniffer watches the right link: a datagram the host sends to the LAN is seen.
            netlab.run(*system.host.exec(sys.executable, "-c", PROBE, LATER_LAN_ADDRESS))
            sniffer.wait_for(rf"^ip {re.escape(LATER_HOST_ADDRESS)}:\d+ > {re.escape(LATER_LAN_ADDRESS)}:9 udp ")
        finally:
            sniffer.stop()
        # Nothing else: the applications (lo) and the monitor (lo and eth0, multicast on lo only) sent nothing there.
        udp = [line for line in frames(sniffer) if " udp " in line and f" > {LATER_LAN_ADDRESS}:9 " not in line]
        assert udp == [], udp


# -- shape-main against Cyclone's shape application, both on their defaults -------------------------------------------

@pytest.fixture
def lo_only_namespace() -> Iterator[str]:
    needs_namespaces()
    with netlab.Namespace(namespace_name("shape-lo")) as created:
        assert_only_loopback(created)
        yield created.name


@pytest.mark.parametrize("case,direction", CYCLONE_DEFAULTS_PAIRS,
                         ids=[f"{case.name}-{direction}" for case, direction in CYCLONE_DEFAULTS_PAIRS])
def test_shape_main_on_its_defaults_meets_cyclones_application_on_its_defaults(case: Case, direction: str,
                                                                             lo_only_namespace: str) -> None:
    """The OMG suite's runner with no flags, on a host with only lo: ours and Cyclone's application match, either
    publishing, whichever starts first."""
    publisher, subscriber = (OURS, CYCLONE_DEFAULTS) if direction == OURS_TO_CYCLONE else (CYCLONE_DEFAULTS, OURS)
    run_case(case, lo_only_namespace, publisher, subscriber, "1")  # the reference's default: XCDR1
