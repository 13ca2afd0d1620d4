"""Every program's health on ROS 2's /diagnostics (automotive.bus.diagnostics), read as ROS 2's tools read it.

A running program's DiagnosticArray is taken off the DDS topic rt/diagnostics by a plain Cyclone reader with ROS 2's
default QoS and XCDR1 only (what rqt_robot_monitor's rmw creates) and decoded by an independent ROS 2 implementation
(rosbags' Humble type store), never by our own types; its level follows what the program needs (the HMI warns while
its alert reader has no writer, is OK once one matched, and an error once the source is lost); a recording holds the
statuses of every program that rosbags, mcap and Foxglove's libraries read; the Foxglove bridge serves them as a
channel that Foxglove's own decoders decode (tests/foxglove/decode.js). The judging itself (automotive.bus.diagnostics
.assess) is checked without DDS."""

from __future__ import annotations

import json
import signal
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import psutil
import pytest
from cyclonedds._clayer import ddspy_take
from cyclonedds.core import InstanceState, SampleState, ViewState
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from dds_helpers import wait_until
from foxglove_node import FoxgloveDecoder, install, json_lines
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
from test_bridge import start_bridge

from automotive.bus import memtune
from automotive.bus.diagnostics import ERROR, OK, WARN, EndpointState, Problem, ProcessUsage, assess
from automotive.bus.endpoints import Databus
from automotive.cyclone.matched import matched_publications, matched_subscriptions
from automotive.types.Alerts import DriverAlerts
from automotive.types.diagnostic_msgs.msg.dds_ import DiagnosticArray_
from automotive.types.Platform import PlatformControl

TIMEOUT = 60.0
ROS2_TYPE = "diagnostic_msgs/msg/DiagnosticArray"
DDS_TYPE = "diagnostic_msgs::msg::dds_::DiagnosticArray_"
# What a ROS 2 node subscribing to /diagnostics with the default QoS creates (rclcpp's default: reliable, volatile,
# keep last 10); XCDR1 only, as ROS 2's middlewares read.
ROS2_READER = Qos(Policy.Reliability.Reliable(0), Policy.Durability.Volatile, Policy.History.KeepLast(10),
                  Policy.DataRepresentation(use_cdrv0_representation=True))
STORE = get_typestore(Stores.ROS2_HUMBLE)


class DiagnosticsReader:
    """A plain Cyclone participant reading rt/diagnostics; every sample decoded by rosbags."""

    def __init__(self, domain_id: int):
        self.participant = DomainParticipant(domain_id)
        self.reader = DataReader(self.participant, Topic(self.participant, "rt/diagnostics", DiagnosticArray_),
                                 qos=ROS2_READER)
        self.raw: list[bytes] = []

    def take(self) -> list[Any]:
        taken = ddspy_take(self.reader._ref, SampleState.Any | ViewState.Any | InstanceState.Any, 64)
        raw = [bytes(data) for data, info in taken if info.valid_data]
        self.raw.extend(raw)
        return [STORE.deserialize_cdr(data, ROS2_TYPE) for data in raw]

    def status_of(self, name: str, condition: Callable[[Any], bool] = lambda status: True,
                  timeout: float = TIMEOUT, what: str = "") -> Any:
        """The first status of program ``name`` that meets ``condition`` (polled, bounded)."""
        seen: list[str] = []
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for array in self.take():
                for status in array.status:
                    if status.name == name:
                        seen.append(f"{status.level}: {status.message}")
                        if condition(status):
                            return status
            time.sleep(0.05)
        raise AssertionError(f"no status of {name} {what} in {timeout:.0f} s; seen: {seen[-5:]}")

    def close(self) -> None:
        self.participant.__del__()


@pytest.fixture
def diagnostics(domain_id: int) -> Iterator[DiagnosticsReader]:
    """The reader, in the domain of the test (joining the test's ``bus`` when the test asks for it first)."""
    reader = DiagnosticsReader(domain_id)
    try:
        yield reader
    finally:
        reader.close()


def values(status: Any) -> dict[str, str]:
    return {pair.key: pair.value for pair in status.values}


def test_a_running_application_reports_once_a_second_as_ros2_reads_it(  # type: ignore[no-untyped-def]
        apps, domain_id: int, diagnostics: DiagnosticsReader) -> None:
    vision = apps.start("vision", "--domain", str(domain_id))
    wait_until(lambda: len(matched_publications(diagnostics.reader)) == 1, TIMEOUT, "the vision's diagnostics")
    [handle] = matched_publications(diagnostics.reader)
    writer = diagnostics.reader.get_matched_publication_data(handle)
    assert writer.type_name == DDS_TYPE
    assert Policy.Reliability.Reliable in writer.qos and Policy.Durability.Volatile in writer.qos
    first = diagnostics.status_of("vision", lambda status: float(values(status)["VisionTopic out/s"]) > 0,
                                  what="with samples out")
    second = diagnostics.status_of("vision", what="after the first")
    assert all(data[:4] == b"\x00\x01\x00\x00" for data in diagnostics.raw)  # XCDR1 little endian, as ROS 2 writes
    arrays = [STORE.deserialize_cdr(data, ROS2_TYPE) for data in diagnostics.raw]
    stamps = [array.header.stamp.sec + array.header.stamp.nanosec / 1e9 for array in arrays]
    assert all(abs(stamp - time.time()) < 60 for stamp in stamps)
    assert all(len(array.status) == 1 for array in arrays)
    # Once a second, on a fixed schedule: a report the machine delayed by d is followed by one on time, 1 - d later
    assert 0.2 < stamps[-1] - stamps[-2] < 3.0, stamps

    # The vision writes and reads nothing it needs: OK, with the console's status words.
    for status in (first, second):
        assert status.level == OK == 0 and status.hardware_id, status
    assert first.message.startswith("out VisionTopic "), first.message
    assert "object(s)" in first.message  # its key figure, as on its status line
    figures = values(first)
    assert float(figures["VisionTopic out/s"]) > 0
    assert figures["VisionTopic writer matched readers"] == "0"
    assert figures["VisionTopic deadline missed"] == figures["bad samples"] == "0"
    assert float(figures["RSS MB"]) > 10 and float(figures["CPU %"]) >= 0
    assert figures["pid"] == str(vision.pid) and figures["domain"] == str(domain_id)
    assert "object(s)" in figures["figure"]
    # The report is in no status line and no match report: no console line of its own.
    assert "diagnostics" not in vision.output, vision.output


def test_a_reader_reports_the_latency_of_each_topic_it_reads_and_of_each_writer_over_the_last_10_s(  # type: ignore[no-untyped-def]
        prefix: str, apps, domain_id: int, diagnostics: DiagnosticsReader) -> None:
    # sensor_fusion reads VisionTopic through its checked reader (DDS) and the LiDAR through shared memory.
    shared = ("-D", f"config.shmPrefix={prefix}", "-D", "config.transport=shm")
    apps.start("vision", "--domain", str(domain_id))
    apps.start("lidar", "--domain", str(domain_id), *shared)
    apps.start("sensor_fusion", "--domain", str(domain_id), *shared)
    wanted = [f"{subject} latency {figure} (last 10 s)" for subject in
              ("VisionTopic", "VisionTopic from vision", "rt/LidarTopic", "rt/LidarTopic from lidar")
              for figure in ("p50 ms", "p99 ms", "samples")]
    status = diagnostics.status_of("sensor_fusion", lambda status: set(wanted) <= set(values(status)),
                                   what="with the latency of VisionTopic and rt/LidarTopic, all and per writer")
    figures = values(status)
    for subject in ("VisionTopic", "VisionTopic from vision", "rt/LidarTopic", "rt/LidarTopic from lidar"):
        p50, p99 = (float(figures[f"{subject} latency {figure} ms (last 10 s)"]) for figure in ("p50", "p99"))
        samples = int(figures[f"{subject} latency samples (last 10 s)"])
        assert 0 < p50 <= p99 < 60_000 and samples > 0, (subject, p50, p99, samples)
    # One writer each: all of a topic's samples are that writer's, but for the first clouds a loaded machine may
    # deliver through shared memory before DDS matched their writer, which count as "unknown"'s for 10 s
    # (FlowReader's LocalWriters.shared_writer; a clean-clone run with a core kept busy: 20 samples, 19 the LiDAR's).
    for topic, writer in (("VisionTopic", "vision"), ("rt/LidarTopic", "lidar")):
        per_writer = {key.split(" from ", 1)[1].removesuffix(" latency samples (last 10 s)"): int(value)
                      for key, value in figures.items()
                      if key.startswith(f"{topic} from ") and key.endswith(" latency samples (last 10 s)")}
        assert set(per_writer) <= {writer, "unknown"} and per_writer[writer] > 0, per_writer
        assert int(figures[f"{topic} latency samples (last 10 s)"]) == sum(per_writer.values()), per_writer
    assert not [key for key in figures if key.startswith("SensorObjects") and "latency" in key]  # written, not read


def test_the_hmi_warns_without_an_alert_writer_is_ok_with_one_and_errs_when_it_is_lost(  # type: ignore[no-untyped-def]
        apps, bus: Databus, domain_id: int, diagnostics: DiagnosticsReader) -> None:
    hmi = apps.start("hmi", "--domain", str(domain_id), "--ui", "console", "-D", "config.matchReport=1")
    warned = diagnostics.status_of("hmi", lambda status: status.level == WARN, what="at WARN")
    assert warned.message == "[AlertTopic] reader: no writer matched", warned.message
    assert values(warned)["AlertTopic reader matched writers"] == "0"

    # Collision avoidance's side: an alert writer with its profile, in a participant that leaves.
    source = DomainParticipant(domain_id)
    try:
        alerts = DataWriter(source, Topic(source, "AlertTopic", DriverAlerts), qos=bus.profiles.writer_qos(
            bus.library, "HMI"))
        wait_until(lambda: bool(matched_subscriptions(alerts)), TIMEOUT, "the HMI's alert reader")
        alerts.write(DriverAlerts(False, False, False, False, False, False))
        ok = diagnostics.status_of("hmi", lambda status: status.level == OK and "all clear" in status.message,
                                   what="OK and all clear")
        assert values(ok)["AlertTopic reader matched writers"] == "1"
        assert float(values(ok)["AlertTopic in/s"]) >= 0
    finally:
        source.__del__()  # the writer leaves: the source is lost
    lost = diagnostics.status_of("hmi", lambda status: status.level == ERROR, what="at ERROR")
    assert lost.message.startswith("alert source LOST: "), lost.message
    hmi.wait_for(r"alert source LOST", timeout=TIMEOUT)
    assert "diagnostics" not in hmi.output


def test_a_recording_holds_every_programs_diagnostics_for_rosbags_mcap_and_foxglove(  # type: ignore[no-untyped-def]
        apps, domain_id: int, tmp_path: Path, diagnostics: DiagnosticsReader) -> None:
    recording = tmp_path / "health.mcap"
    recorder = apps.start("record", "--domain", str(domain_id), "--output", str(recording),
                          "--topics", "rt/diagnostics")
    recorder.wait_for(r"recording 1 topic", timeout=TIMEOUT)
    apps.start("vehicle_platform", "--domain", str(domain_id))
    recorder.wait_for(r"\[rt/diagnostics\] reader matched a writer", count=2, timeout=TIMEOUT)  # its own, the app's
    # The application's statuses, as a reader beside the recorder sees them: its second was written after the
    # recorder had matched, and the recorder has the first by then (the recorder's own count alone may come from its
    # own statuses before the application says anything on a loaded machine).
    for seen in (1, 2):
        diagnostics.status_of("vehicle_platform", what=f"(status {seen})")
    recorder.wait_for(r" rt/diagnostics=([4-9]|\d\d+)/", timeout=TIMEOUT)
    assert recorder.stop(signal.SIGINT) == 0, recorder.output[-3000:]

    with open(recording, "rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None
        [schema] = summary.schemas.values()
        assert (schema.name, schema.encoding) == (ROS2_TYPE, "ros2msg")
        [channel] = summary.channels.values()
        assert (channel.topic, channel.metadata["dds_type"]) == ("rt/diagnostics", DDS_TYPE)
        assert "reliability: 1" in channel.metadata["offered_qos_profiles"]  # reliable
        assert "depth: 10" in channel.metadata["offered_qos_profiles"]
    with AnyReader([recording]) as bag:
        names = [status.name for connection, _, raw in bag.messages()
                 for status in bag.deserialize(raw, connection.msgtype).status]
    assert {"record", "vehicle_platform"} <= set(names), names

    lines = FoxgloveDecoder(install()).run("mcap", str(recording), timeout=TIMEOUT)
    assert not [line for line in lines if "error" in line], lines[:3]
    decoded = [line["value"] for line in lines if line["kind"] == "message"]
    assert len(decoded) == len(names)
    platform = next(value["status"][0] for value in decoded if value["status"][0]["name"] == "vehicle_platform")
    assert platform["level"] in (OK, WARN) and platform["hardware_id"] and platform["message"]
    assert any(pair["key"] == "PlatformStatus out/s" for pair in platform["values"]), json.dumps(platform)


def test_the_foxglove_bridge_serves_diagnostics_that_foxgloves_decoders_read(  # type: ignore[no-untyped-def]
        apps, domain_id: int) -> None:
    foxglove = FoxgloveDecoder(install())
    bridge, port = start_bridge(apps, domain_id, "--topics", "rt/diagnostics")
    client = apps.start_command("decode.js ws", foxglove.command("ws", f"ws://127.0.0.1:{port}"), env=foxglove.env)
    client.wait_for(r'"kind":"open"', timeout=TIMEOUT)
    bridge.wait_for(r"client \d+ subscribed to rt/diagnostics", timeout=TIMEOUT)
    client.wait_for(r'"kind":"message","topic":"rt/diagnostics".*"name":"bridge"', timeout=TIMEOUT)
    assert client.stop(signal.SIGTERM) == 0, client.output[-3000:]
    lines = json_lines(client.lines)
    assert not [line for line in lines if "error" in line], lines[:3]
    [channel] = [line for line in lines if line["kind"] == "channel"]
    assert (channel["topic"], channel["schemaName"], channel["schemaEncoding"]) == ("rt/diagnostics", ROS2_TYPE,
                                                                                   "ros2msg")
    message = next(line for line in lines if line["kind"] == "message")
    [status] = message["value"]["status"]
    assert status["name"] == "bridge" and status["level"] in (OK, WARN) and status["message"]
    assert {"RSS MB", "CPU %", "rt/diagnostics reader matched writers"} <= {pair["key"] for pair in status["values"]}


def test_diagnostics_interval_is_a_property_and_bad_values_are_one_line(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    off = apps.run("vision", "--domain", str(domain_id), "--count", "2", "-D", "config.diagnosticsInterval=0",
                   timeout=TIMEOUT)
    assert off.returncode == 0, off.stdout + off.stderr
    bad = apps.run("vision", "--domain", str(domain_id), "-D", "config.diagnosticsInterval=-1", timeout=TIMEOUT)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1, bad.stdout + bad.stderr
    assert "config.diagnosticsInterval" in bad.stderr


# -- the judging, without DDS ------------------------------------------------------------------------------------------

READER = EndpointState("AlertTopic", reader=True, matched=0)
CIRCLE = EndpointState("Circle", reader=True, matched=0)
WRITER = EndpointState("PlatformControl", reader=False, matched=0)


def test_an_unmatched_reader_warns_only_after_the_grace_and_unless_optional() -> None:
    assert assess([READER, WRITER], set(), False, [], [], 0, None) == []
    assert assess([READER, CIRCLE, WRITER], {"Circle"}, True, [], [], 0, None) == [
        Problem(WARN, "[AlertTopic] reader: no writer matched")]  # a writer with no reader is no problem
    matched = EndpointState("AlertTopic", reader=True, matched=1)
    assert assess([matched], set(), True, [], [], 0, None) == []


def test_the_worst_comes_first_and_an_incompatible_qos_says_why_a_reader_has_no_writer() -> None:
    recent = [("AlertTopic", "requested_incompatible_qos",
               "[AlertTopic] a writer was seen but does not match: incompatible QoS DURABILITY (this reader requests "
               "TRANSIENT_LOCAL durability; the writer offers less)"),
              ("VisionTopic", "requested_deadline_missed",
               "[VisionTopic] requested deadline missed: no data in time (total 3)")]
    problems = assess([READER], set(), True, recent, ["[SensorObjects] liveliness LOST of a writer (0 alive, 1 not "
                                                      "alive)"], 2, Problem(ERROR, "alert source LOST: it left"))
    assert problems == [
        Problem(ERROR, "alert source LOST: it left"),
        Problem(WARN, "[AlertTopic] reader: a writer was seen but does not match: incompatible QoS DURABILITY (this "
                      "reader requests TRANSIENT_LOCAL durability; the writer offers less)"),
        Problem(WARN, "[SensorObjects] liveliness LOST of a writer (0 alive, 1 not alive)"),
        Problem(WARN, "[VisionTopic] requested deadline missed: no data in time (total 3)"),
        Problem(WARN, "2 bad sample(s) ignored in the last 5 s"),
    ]
    assert assess([], set(), True, [], [], 0, Problem(OK, "all clear")) == []  # an OK verdict is no problem


def test_two_command_writers_of_one_vehicle_are_warned_on_the_console_and_in_diagnostics(  # type: ignore[no-untyped-def]
        apps, domain_id: int, bus, diagnostics: DiagnosticsReader) -> None:
    """Issue 38: outside redundant mode the platform's command reader is SHARED: a second decider drives the vehicle
    too (every command of each executed). The platform warns, on its console and in /diagnostics, and says when one
    is left."""
    platform = apps.start("vehicle_platform", "--domain", str(domain_id))
    first = bus.writer("PlatformControl", PlatformControl, "CollisionAvoidance")
    platform.wait_for(r"\[PlatformControl\] reader matched a writer: 1 writer")
    # a second decider, which leaves (a plain writer of the test's participant: the bus does not hold it)
    second = DataWriter(bus.participant, bus.topic("PlatformControl", PlatformControl),
                        bus.profiles.writer_qos(bus.library, "CollisionAvoidance"))
    platform.wait_for(r"vehicle_platform WARNING: 2 command writers drive this vehicle \(PlatformControl, shared "
                      r"ownership: every command of each is executed\): run one collision_avoidance, or two in "
                      r"redundant mode")
    diagnostics.status_of("vehicle_platform", lambda status: status.level == WARN
                          and "2 command writers drive this vehicle" in status.message, what="warning of two")
    second.__del__()
    platform.wait_for(r"one command writer on PlatformControl again")
    diagnostics.status_of("vehicle_platform", lambda status: "command writers" not in status.message,
                          what="without the warning")
    assert matched_subscriptions(first)


@pytest.mark.fast
def test_the_report_reads_the_process_memory_and_cpu_as_psutil_does() -> None:
    process = psutil.Process()
    ballast = bytearray(64 << 20)  # 64 MB made resident: both readings see it
    ballast[::4096] = b"x" * len(ballast[::4096])
    assert abs(memtune.resident_bytes() - process.memory_info().rss) < 4 << 20
    del ballast
    # The reading's interval lies inside [wall_before, wall_after] and holds the busy loop: bounds that hold however
    # long the machine keeps this process waiting (a fixed threshold failed once on a loaded machine: 28 % for 30).
    wall_before, cpu_before = time.monotonic(), time.process_time()
    usage = ProcessUsage()
    loop_start = time.monotonic()
    busy_until = time.process_time() + 0.3
    while time.process_time() < busy_until:  # 0.3 s of this process's CPU, all inside the reading's interval
        pass
    loop_wall = time.monotonic() - loop_start
    percent = usage.cpu_percent()  # percent of one core since it was made
    wall_after, cpu_after = time.monotonic(), time.process_time()
    assert percent >= 0.95 * 100 * 0.3 / (wall_after - wall_before)
    assert percent <= 1.05 * 100 * (cpu_after - cpu_before) / loop_wall
