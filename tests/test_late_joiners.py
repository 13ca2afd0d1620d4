"""Tools that join a running system late find every application, the way users meet the system.

The whole system runs as `scripts/launch` starts it (eight applications: participant indexes above the four or five
that other stacks probe by default), with its shipped network defaults (no CYCLONEDDS_URI), and has run a minute,
longer than Cyclone's default prune delay for unanswered peers (30 s): until that was fixed, a tool that joined then
missed the applications whose participant index it does not probe itself. The tools use their own defaults for a
single host: RTI Connext with its initial peer udpv4://127.0.0.1 (it probes participant indexes 0-4), Fast DDS with
its initial peer 127.0.0.1 and its default range of four participant indexes. Each must see every flow within
LATE_JOIN_BOUND_S (README: "Late joiners"). In redundant mode, a late RTI reader with EXCLUSIVE ownership follows a
failover.

The same tools starting first are tested in tests/test_rti_shipped_defaults.py and tests/test_fastdds_interop.py.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from apprunner import AppRunner, CommandProcess
from dds_helpers import write_until
from fastdds_peer import FastDdsPeer
from test_launcher import launch, started_pids

pytest.importorskip("rticonnextdds_connector")

from rti_peer import RtiPeer  # noqa: E402

# A minute: well past Cyclone's default prune delay (InitialLocatorPruneDelay, 30 s), after which a system had
# stopped probing for participants that did not answer at its start.
SYSTEM_AGE_S = 60.0
# What the README promises for a participant of any stack that joins later: every application discovered (all its
# flows matched) within this bound. The design gives about 2 s (the announcement interval) plus endpoint discovery;
# the test allows for a loaded 2-core machine.
LATE_JOIN_BOUND_S = 10.0
FLOWS = {  # RTI peer endpoint -> the topic
    "Vision": "VisionTopic", "SensorObjects": "SensorObjects", "PlatformControl": "PlatformControl",
    "PlatformStatus": "PlatformStatus", "Alerts": "AlertTopic", "Lidar": "rt/LidarTopic", "Camera": "CameraImageData",
}
# The shipped system, with the vision period shortened so that the first driver alert (row 95 of the data) comes
# after 2 s instead of 10 s: a late transient-local reader then finds an alert state to receive.
SYSTEM_ARGS = ("-D", "vision:config.pubInterval=20")
# The system's own network defaults, as a user runs it: not the tests' CYCLONEDDS_URI.
SHIPPED_DEFAULTS = {"CYCLONEDDS_URI": ""}


@dataclass
class RunningSystem:
    domain_id: int
    launcher: CommandProcess
    pids: dict[str, int]
    started: float

    def wait_age(self, seconds: float) -> None:
        """Let the system become at least ``seconds`` old: the point of these tests is to join it late."""
        remaining = self.started + seconds - time.monotonic()
        if remaining > 0:
            time.sleep(remaining)
        assert self.launcher.process.poll() is None, self.launcher.output[-4000:]

    def app_lines(self, name: str, pattern: str) -> int:
        return self.launcher.count(app_pattern(name, pattern))

    def wait_app_line(self, name: str, pattern: str, after: int, timeout: float) -> str:
        return self.launcher.wait_for(app_pattern(name, pattern), timeout, count=after + 1)


def app_pattern(name: str, pattern: str) -> str:
    """``pattern`` in a line of application ``name`` on the launcher's console."""
    return rf"^{name}\s+\|.*{pattern}"


def start_system(domain_id: int, log_dir: Path, *args: str) -> Iterator[RunningSystem]:
    runner = AppRunner(Path(__file__).resolve().parent.parent)
    try:
        launcher = launch(runner, domain_id, log_dir, *SYSTEM_ARGS, *args, env=SHIPPED_DEFAULTS)
        pids = started_pids(launcher)
        started = time.monotonic()
        yield RunningSystem(domain_id, launcher, pids, started)
    finally:
        runner.stop_all()


@pytest.fixture(scope="module")
def system(module_domain_id: int, tmp_path_factory: pytest.TempPathFactory) -> Iterator[RunningSystem]:
    yield from start_system(module_domain_id, tmp_path_factory.mktemp("late-logs"))


def matched_within(what: str, condition: dict[str, object], bound: float) -> dict[str, float]:
    """Poll ``condition`` (name -> callable returning bool) until all hold; the time each took. Fails naming the
    ones that did not hold within ``bound`` seconds."""
    started = time.monotonic()
    seen: dict[str, float] = {}
    while len(seen) < len(condition):
        for name, check in condition.items():
            if name not in seen and check():  # type: ignore[operator]
                seen[name] = time.monotonic() - started
        if time.monotonic() - started > bound:
            missing = sorted(set(condition) - set(seen))
            raise AssertionError(f"{what}: not matched within {bound:g} s: {', '.join(missing)} (matched: {seen})")
        time.sleep(0.05)
    return seen


def test_a_late_rti_participant_with_its_defaults_receives_every_flow(system: RunningSystem) -> None:
    system.wait_age(SYSTEM_AGE_S)
    shapes_before = system.app_lines("lidar", "shape ORANGE appeared")
    readers = {name: "DefaultReader" for name in FLOWS}
    readers["Alerts"] = "Alerts"  # the original HMI's reader: transient local, so the current alert state comes
    with RtiPeer(system.domain_id, readers=readers, writers=["Circle"]) as peer:
        checks: dict[str, object] = {name: (lambda name=name: peer.matched_writers(name) > 0) for name in FLOWS}
        checks["Circle"] = lambda: peer.matched_readers("Circle") > 0
        times = matched_within("a late RTI participant", checks, LATE_JOIN_BOUND_S)
        print("late RTI participant matched after (s):", {name: round(t, 2) for name, t in times.items()})
        for name in FLOWS:
            assert peer.count_until(name, 1, timeout=30), f"the late RTI reader of {name} received nothing"
        # The LiDAR's Circle reader is best effort, as Shapes Demo's: the circle is lost until that reader has
        # matched the RTI writer itself (discovery is not symmetric), so it is written, as Shapes Demo does, until seen.
        write_until(system.launcher, app_pattern("lidar", "shape ORANGE appeared"),
                    lambda: peer.write("Circle", {"color": "ORANGE", "x": 120, "y": 120, "shapesize": 40}),
                    timeout=30, after=shapes_before)


def test_a_late_fastdds_participant_with_its_defaults_receives_every_flow(system: RunningSystem) -> None:
    system.wait_age(SYSTEM_AGE_S)
    runner = AppRunner(Path(__file__).resolve().parent.parent)
    shapes_before = system.app_lines("lidar", "shape PURPLE appeared")
    try:
        # Fast DDS's default range of participant indexes for its initial peer (four), as a user has it
        reader = FastDdsPeer.read(runner, list(FLOWS.values()), system.domain_id, count=0)
        times = matched_within("a late Fast DDS participant", {
            topic: (lambda topic=topic: reader.process.count(rf"^matched: [1-9]\d* writer\(s\) on {topic}$") > 0)
            for topic in FLOWS.values()}, LATE_JOIN_BOUND_S)
        print("late Fast DDS participant matched after (s):", {name: round(t, 2) for name, t in times.items()})
        for topic in FLOWS.values():
            reader.wait_samples(topic, 1, timeout=30)
        FastDdsPeer.write_circle(runner, system.domain_id, "PURPLE", 100, 100, 40)
        system.wait_app_line("lidar", "shape PURPLE appeared", shapes_before, timeout=LATE_JOIN_BOUND_S + 20)
    finally:
        runner.stop_all()


@pytest.fixture
def redundant_system(domain_id: int, tmp_path: Path) -> Iterator[RunningSystem]:
    yield from start_system(domain_id, tmp_path / "logs", "--redundant")


def test_a_late_exclusive_rti_reader_follows_a_failover(redundant_system: RunningSystem) -> None:
    system = redundant_system
    system.wait_age(SYSTEM_AGE_S)
    primary = system.pids["collision_avoidance"]
    with RtiPeer(system.domain_id, readers={"PlatformControl": "ExclusiveReader"}) as peer:
        matched_within("a late exclusive RTI reader", {
            "PlatformControl": lambda: peer.matched_writers("PlatformControl") >= 2}, LATE_JOIN_BOUND_S)
        before = peer.take_until("PlatformControl", 3, timeout=30)
        assert len(before) >= 3, "the late exclusive RTI reader received no commands of the primary"
        switched = system.app_lines("vehicle_platform", "owner changed")
        os.kill(primary, signal.SIGSTOP)
        try:
            # Taken as they come until the platform names its new owner: the reader keeps 100 commands (2 s at the
            # 50 a second here), and on a slow machine a command lost to its history would read as a failover gap.
            commands = list(before)
            deadline = time.monotonic() + 30
            while system.app_lines("vehicle_platform", "owner changed") <= switched:
                assert time.monotonic() < deadline, "the vehicle platform did not change owner"
                commands += peer.take("PlatformControl")
                time.sleep(0.05)
            commands += peer.take_until("PlatformControl", 5, timeout=30)
        finally:
            os.kill(primary, signal.SIGCONT)
    # The commands' own timestamps (written by whichever instance owned the topic): the largest gap is the failover
    # as the RTI reader saw it, independent of when this test looked.
    stamps = [command["timestamp"]["s"] + command["timestamp"]["ns"] / 1e9 for command in commands]
    gaps = [later - earlier for earlier, later in zip(stamps, stamps[1:])]
    assert len(commands) >= 8 and max(gaps) <= FAILOVER_BOUND_S, (
        f"the late exclusive RTI reader saw a gap of {max(gaps):.3f} s (bound {FAILOVER_BOUND_S} s): {stamps}")


# README, redundant mode: the standby's commands reach any reader within the liveliness lease (250 ms) plus the next
# command (the 20 ms vision period here), plus scheduling on a loaded machine.
FAILOVER_BOUND_S = 1.0
