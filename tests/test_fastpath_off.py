"""The fast paths degrade, never break: on another cyclonedds version, with a Cyclone internal missing, or turned off
(AUTOMOTIVE_FAST_PATHS=off), the programs say so in one warning line and work through Cyclone's public API, and the
bytes on the wire are those the fast paths write."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from cyclonedds.core import InstanceState
from cyclonedds.qos import Policy
from dds_helpers import take_samples, wait_until

from automotive.bus.endpoints import Databus
from automotive.cyclone import gate
from automotive.cyclone.matched import matched_publications
from automotive.tools.flows import system_flows
from automotive.types.Alerts import DriverAlerts
from automotive.types.CameraImage import CameraImageData_64KiB
from automotive.types.Common import ClassificationEnum, POSIXTimestamp
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.types.Vision import VisionObject, VisionSensor
from automotive.wire.pointcloud import POINT_DTYPE, to_point_cloud2
from automotive.wire.rawsample import RawReader, RawSample, RawWriter, SampleKind

OFF = {gate.SWITCH: "off"}
WARNING = "cyclone: fast paths off"


def run_python(code: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    import os

    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                          env={**os.environ, **(env or {})})


def test_the_tested_version_opens_the_gate() -> None:
    assert gate.cyclone_version() == gate.TESTED_VERSION
    assert gate.why_off() is None


def test_another_version_closes_the_gate_with_one_warning_line() -> None:
    code = """
from automotive.cyclone import gate
gate.cyclone_version = lambda: "11.1.0"  # what the installed distribution would say on another release
from automotive import cyclone
from cyclonedds.idl._builder import Builder
before = Builder.build_machines
print(cyclone.start(), cyclone.start(), cyclone.why_off())
print(Builder.build_machines == before)
"""
    result = run_python(code)
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines() == ["False False cyclonedds 11.1.0 is not the tested 11.0.1", "True"]
    assert result.stderr.count("\n") == 1 and WARNING in result.stderr, result.stderr


def test_a_missing_internal_closes_the_gate() -> None:
    code = """
import cyclonedds._clayer as clayer
del clayer.ddspy_take
from automotive.cyclone import gate
print(gate.why_off())
"""
    result = run_python(code)
    assert result.stdout.strip() == "cyclonedds._clayer lacks ddspy_take", result.stdout + result.stderr


@pytest.fixture
def gate_closed(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """The fast paths off in this process (as on another Cyclone version), for the public-API fallbacks."""
    monkeypatch.setenv(gate.SWITCH, "off")
    gate.why_off.cache_clear()
    monkeypatch.setattr(gate, "_warned", True)  # no warning line in the test's output
    try:
        yield
    finally:
        monkeypatch.delenv(gate.SWITCH)
        gate.why_off.cache_clear()
    assert gate.why_off() is None


def vision(sensor_id: int) -> VisionSensor:
    obj = VisionObject(classification=ClassificationEnum.CLASSIFICATION_CAR, position=[1.0, 2.0, 3.0],
                       velocity=[0.5, 0.0, 0.0], size=[4.0, 1.5, 1.75])
    return VisionSensor(id=sensor_id, timestamp=POSIXTimestamp(s=3, ns=7), objects=[obj])


def take_raw(reader: RawReader, count: int) -> list[RawSample]:
    taken: list[RawSample] = []

    def enough() -> bool:
        taken.extend(reader.take())
        return len(taken) >= count

    wait_until(enough, 15, f"{count} raw samples")
    return taken


def test_raw_samples_through_the_public_api(bus: Databus, gate_closed: None) -> None:
    """Recorder, replayer and bridge without Cyclone's C layer: the same bytes, timestamps, disposals."""
    writer = bus.writer("VisionTopic", VisionSensor, "Vision")
    reader = bus.reader("VisionTopic", VisionSensor, "Vision")
    raw_reader = RawReader(reader)
    assert not raw_reader.zero_copy  # no lent buffers: taken with a copy
    wait_until(lambda: bool(matched_publications(reader)), what="the reader to match the writer")
    sample = vision(7)
    writer.write(sample, timestamp=1_700_000_000_000_000_123)
    writer.dispose(vision(7))
    taken = take_raw(raw_reader, 2)
    assert [t.kind for t in taken] == [SampleKind.DATA, SampleKind.DISPOSE]
    assert bytes(taken[0].data) == sample.serialize(use_version_2=False)
    assert taken[0].source_timestamp == 1_700_000_000_000_000_123
    assert VisionSensor.deserialize(bytes(taken[1].data)).id == 7
    with raw_reader.lend() as lent:
        assert lent == []

    # Writing serialized samples back: data with its timestamp, then the disposal and an unregistration.
    out_writer = RawWriter(bus.writer("VisionReplay", VisionSensor, "Vision"))
    out_reader = bus.reader("VisionReplay", VisionSensor, "Vision")
    wait_until(lambda: bool(matched_publications(out_reader)), what="the replay reader to match")
    out_writer.write(taken[0].data, timestamp=1_700_000_000_000_000_456)
    [received] = take_samples(out_reader, 1)
    assert received == sample and received.sample_info.source_timestamp == 1_700_000_000_000_000_456
    out_writer.put(taken[1])
    wait_until(lambda: any(s.sample_info.instance_state == InstanceState.NotAliveDisposed
                           for s in out_reader.read(N=10)), what="the disposal")


def test_bounds_without_cyclones_type_resolution(gate_closed: None) -> None:
    from automotive.cyclone import bounds

    bounds._plan.cache_clear()
    try:
        too_many = VisionSensor(id=1, timestamp=POSIXTimestamp(s=0, ns=0), objects=[vision(1).objects[0]] * 11)
        with pytest.raises(bounds.BoundError, match=r"Vision::VisionSensor.objects holds 11 elements, over its IDL "
                                                   r"bound of 10"):
            bounds.check(too_many)
        cloud = to_point_cloud2(np.zeros(368_640 // 16 + 1, dtype=POINT_DTYPE), 0, 0)
        with pytest.raises(bounds.BoundError, match=r"PointCloud2_.data_ holds 368656 elements, over its IDL bound"):
            bounds.check(cloud)
    finally:
        bounds._plan.cache_clear()


def test_content_filters_without_cyclones_type_resolution(gate_closed: None) -> None:
    """Members of a sequence's element type (a forward reference in the generated code) resolve from the public
    annotations too."""
    from automotive.bus.contentfilter import ContentFilter

    matches = ContentFilter.parse("objects[0].classification = CLASSIFICATION_CAR AND timestamp.s = 3")
    assert matches.bind(VisionSensor)(vision(1)) is True
    assert ContentFilter.parse("objects[1].size[0] > 0").bind(VisionSensor)(vision(1)) is False


# -- the core flows as processes with the fast paths off -----------------------------------------------------------

def wire_bytes(data_type: type[Any], sample: RawSample) -> bytes:
    """What this process's writer writes for the sample the wire carried: decoded, then encoded again with the fast
    paths on (XCDR1, padded to whole 4-byte units as DataWriter.write pads)."""
    encoded = data_type.deserialize(bytes(sample.data)).serialize(use_version_2=False)
    return bytes(encoded).ljust((len(encoded) + 3) & ~3, b"\0")


def test_core_flows_with_the_fast_paths_off(apps, bus: Databus, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    domain = ["--domain", str(domain_id)]
    flows = {flow.topic: flow for flow in system_flows()}
    # Readers that keep the newest samples only: a reliable writer is never held back by this test.
    newest = (Policy.History.KeepLast(4),)
    readers = {topic: RawReader(bus.reader(topic, flows[topic].data_type, flows[topic].profile, overrides=newest))
               for topic in ("VisionTopic", "SensorObjects", "AlertTopic", "PlatformControl", "PlatformStatus",
                             "rt/LidarTopic")}
    readers["CameraImageData"] = RawReader(bus.reader("CameraImageData", CameraImageData_64KiB, "Camera",
                                                      overrides=newest))
    hmi = apps.start("hmi", "--ui", "console", *domain, env=OFF)
    sub = apps.start("camera_sub", *domain, "-D", "config.imageSize=64KiB", env=OFF)
    started = [hmi, sub]
    for name, args in (("vehicle_platform", []), ("collision_avoidance", ["-D", "config.alertSize=1.0"]),
                       ("sensor_fusion", []), ("vision", []), ("lidar", ["-D", "config.noise=0"]),
                       ("camera_pub", ["-D", "config.imageSize=64KiB", "-D", "config.pubInterval=50",
                                       "-D", "config.waitSubscribers=2"])):
        started.append(apps.start(name, *domain, *args, env=OFF))
    hmi.wait_for(r"DRIVER ALERT: Driver attention required", timeout=60)
    sub.wait_for(r"samples=[1-9]\d* size=65536 .* mismatches=0 gaps=0", timeout=60)

    for topic, reader in readers.items():
        data_type = reader.data_type
        taken = [sample for sample in take_raw(reader, 3) if sample.kind is SampleKind.DATA]
        assert taken, topic
        for sample in taken:
            assert bytes(sample.data) == wire_bytes(data_type, sample), f"{topic}: bytes differ from the fast path's"
    for process in started:
        assert process.count(WARNING) == 1, f"{process.name}: {process.output[-2000:]}"
        assert "Traceback" not in process.output
    for process in started:
        assert process.stop() == 0, f"{process.name}: {process.output[-2000:]}"
    sub.wait_for(r"totals: samples=\d+ .* mismatches=0 mismatched_bytes=0 gaps=0")


def test_the_lidar_cloud_is_the_same_with_the_fast_paths_on_and_off(apps, bus: Databus,  # type: ignore[no-untyped-def]
                                                                    domain_id: int) -> None:
    reader = RawReader(bus.reader("rt/LidarTopic", PointCloud2_, "Lidar", overrides=(Policy.History.KeepLast(1),)))
    clouds: dict[str, bytes] = {}
    for label, env in (("on", {}), ("off", OFF)):
        lidar = apps.start("lidar", "--domain", str(domain_id), "-D", "config.noise=0", env=env)
        [sample] = take_raw(reader, 1)[:1]
        lidar.stop()
        reader.take(256)  # what it wrote before it stopped
        cloud = PointCloud2_.deserialize(bytes(sample.data))
        clouds[label] = bytes(cloud.data_)
        assert lidar.count(WARNING) == (1 if env else 0), lidar.output[-2000:]
    assert clouds["on"] == clouds["off"] and len(clouds["on"]) == 184_320
    assert DriverAlerts  # the alert type is among the flows checked above
