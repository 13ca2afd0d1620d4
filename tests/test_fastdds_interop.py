"""The system with a second, independent DDS stack: eProsima Fast DDS 2.9 (tests/fastdds, ROS 2 Humble's middleware).

The Fast DDS peer declares the original example's types and ROS 2's PointCloud2 (unbounded sequences) itself and
uses Fast DDS's default reader QoS (best effort, volatile, keep last 1), or RViz2's for the cloud (reliable,
volatile, keep last 5). Our applications run as processes with their shipped properties files.

- Every flow of the system reaches it, each sample equal to what a Cyclone reader of the same flow received.
- Camera frames arrive whole: header, size and every byte (CRC-32 against the publisher's LFSR pattern).
- A circle it writes on Circle with Fast DDS's default writer QoS appears as coloured points in our LiDAR's cloud,
  as it reads that cloud, and leaves when the Fast DDS participant does.
"""

from __future__ import annotations

import dataclasses
import enum
import threading
import time
import zlib
from typing import Any

import numpy as np
from fastdds_peer import FastDdsPeer, octets
from lidar_helpers import circle, points_of

from automotive.bus.endpoints import Databus
from automotive.sim import lfsr
from automotive.sim.scene import SHAPE_RGB
from automotive.types.Alerts import DriverAlerts
from automotive.types.builtin_interfaces.msg.dds_ import Time_
from automotive.types.Platform import PlatformControl, PlatformStatus
from automotive.types.Sensor import SensorObjectList
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_, PointField_
from automotive.types.std_msgs.msg.dds_ import Header_
from automotive.types.Vision import VisionSensor

TIMEOUT = 90.0  # eight Python processes starting on a loaded 2-core machine
SAMPLES = 3

# Topic, type and our reader profile of every flow that has a timestamp to pair samples by.
TIMESTAMPED = {
    "VisionTopic": (VisionSensor, "Vision"),
    "SensorObjects": (SensorObjectList, "SensorFusion"),
    "PlatformControl": (PlatformControl, "CollisionAvoidance"),
    "PlatformStatus": (PlatformStatus, "Platform"),
}


def plain(value: Any) -> Any:
    """A Cyclone sample as the Fast DDS peer prints it: nested dicts and lists, enums as numbers, octets as CRC."""
    if dataclasses.is_dataclass(value):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, (bytes, bytearray, memoryview)):
        data = bytes(value)
        return {"size": len(data), "crc32": zlib.crc32(data)}
    if isinstance(value, (list, tuple)):
        return [plain(item) for item in value]
    return value


class Received:
    """What in-process Cyclone readers (the project's profiles) received, taken all along by a thread (the LiDAR
    reader keeps only the last 4 clouds) until :meth:`close`."""

    def __init__(self, bus: Databus):
        self.readers = {topic: bus.reader(topic, data_type, profile)
                        for topic, (data_type, profile) in TIMESTAMPED.items()}
        self.readers["AlertTopic"] = bus.reader("AlertTopic", DriverAlerts, "HMI")
        self.readers["rt/LidarTopic"] = bus.reader("rt/LidarTopic", PointCloud2_, "Lidar")
        self.samples: dict[str, list[Any]] = {topic: [] for topic in self.readers}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._take_all_along, daemon=True)
        self._thread.start()

    def _take_all_along(self) -> None:
        while not self._stop.wait(0.02):
            for topic, reader in self.readers.items():
                taken = [plain(s) for s in reader.take(N=256) if isinstance(s, reader.topic.data_type)]
                with self._lock:
                    self.samples[topic].extend(taken)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10)

    def pair(self, topic: str, samples: list[dict[str, Any]], timeout: float = 5.0
             ) -> list[tuple[dict[str, Any], dict[str, Any] | None]]:
        """Each sample with our reader's sample of the same timestamp (for alerts, which have none: the same one)."""
        def key(sample: dict[str, Any]) -> Any:
            if topic == "AlertTopic":
                return str(sample)
            return str(sample["header_"]["stamp_"] if topic == "rt/LidarTopic" else sample["timestamp"])

        deadline = time.monotonic() + timeout
        while True:
            with self._lock:
                ours = {key(sample): sample for sample in self.samples[topic]}
            pairs = [(sample, ours.get(key(sample))) for sample in samples]
            if all(found is not None for _, found in pairs) or time.monotonic() > deadline:
                return pairs
            time.sleep(0.1)


def test_fastdds_default_readers_receive_every_flow(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                    bus: Databus) -> None:
    received = Received(bus)
    try:
        check_every_flow(apps, domain_id, received)
    finally:
        received.close()


def check_every_flow(apps: Any, domain_id: int, received: Received) -> None:
    flows = [*TIMESTAMPED, "AlertTopic"]
    peer = FastDdsPeer.read(apps, flows, domain_id, count=SAMPLES)
    rviz2 = FastDdsPeer.read(apps, ["rt/LidarTopic"], domain_id, count=SAMPLES, qos="rviz2", name="fastdds-rviz2")
    domain = ["--domain", str(domain_id)]
    for name in ("vehicle_platform", "collision_avoidance", "sensor_fusion", "lidar", "vision"):
        apps.start(name, *domain)
    # The shipped vision data shows a tall object (a driver alert) about 10 s in.
    fastdds_samples = {topic: peer.wait_samples(topic, SAMPLES, TIMEOUT) for topic in flows}
    fastdds_samples["rt/LidarTopic"] = rviz2.wait_samples("rt/LidarTopic", SAMPLES, TIMEOUT)
    for topic, samples in fastdds_samples.items():
        pairs = received.pair(topic, samples)
        # A sample written before one of the two readers matched reaches only the other one: not all of them.
        assert any(ours is not None for _, ours in pairs), f"{topic}: no sample of Fast DDS's seen by our reader"
        for sample, ours in pairs:
            assert ours is None or sample == ours, f"{topic}: Fast DDS read {sample}, we read {ours}"
    # collision avoidance's first verdict (all clear, before the tall object; unless it came before the peer matched),
    # then the alert, repeated while it lasts
    alerts = [sample["driverAttention"] for sample in fastdds_samples["AlertTopic"]]
    assert True in alerts and alerts == sorted(alerts), alerts
    for cloud in fastdds_samples["rt/LidarTopic"]:
        assert cloud["header_"]["frame_id_"] == "map"
        assert (cloud["height_"], cloud["width_"], cloud["point_step_"]) == (64, 180, 16)
        assert cloud["data_"]["size"] == 64 * 180 * 16
    assert "incompatible" not in peer.output + rviz2.output


def test_fastdds_default_reader_receives_whole_camera_frames(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    peer = FastDdsPeer.read(apps, ["CameraImageData"], domain_id, count=SAMPLES)
    # camera_pub waits for one subscriber (config.waitSubscribers=1): the Fast DDS reader is the only one.
    camera = apps.start("camera_pub", "--domain", str(domain_id))
    frames = peer.wait_samples("CameraImageData", SAMPLES, TIMEOUT)
    pattern = lfsr.FramePattern(1366 * 768 * 4)
    seqnums = [frame["seqnum"] for frame in frames]
    assert seqnums == sorted(set(seqnums))
    for frame in frames:
        assert frame["id"] == 1  # config.ddsId
        assert abs(frame["sec_"] + frame["nanosec_"] * 1e-9 - time.time()) < TIMEOUT
        assert frame["data"] == {"size": 1366 * 768 * 4, "crc32": zlib.crc32(pattern.frame(frame["seqnum"]))}
    assert "incompatible" not in peer.output + camera.output


def point_cloud(sample: dict[str, Any]) -> PointCloud2_:
    header = sample["header_"]
    return PointCloud2_(
        header_=Header_(stamp_=Time_(**header["stamp_"]), frame_id_=header["frame_id_"]),
        height_=sample["height_"], width_=sample["width_"], fields_=[PointField_(**f) for f in sample["fields_"]],
        is_bigendian_=sample["is_bigendian_"], point_step_=sample["point_step_"], row_step_=sample["row_step_"],
        data_=octets(sample["data_"]), is_dense_=sample["is_dense_"])


def test_fastdds_circle_appears_in_the_cloud_fastdds_reads(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    lidar = apps.start("lidar", "--domain", str(domain_id))
    x, y = circle(4, 0)
    writer = FastDdsPeer.write_circle(apps, domain_id, "ORANGE", x, y, 60)
    writer.wait_matched("Circle", "reader", TIMEOUT)
    lidar.wait_for(rf"shape ORANGE appeared at \({x}, {y}\), size 60", TIMEOUT)
    # Clouds written after the LiDAR took the circle show it; this reader matches only after that.
    reader = FastDdsPeer.read(apps, ["rt/LidarTopic"], domain_id, count=2, qos="rviz2", data=True)
    for sample in reader.wait_samples("rt/LidarTopic", 2, TIMEOUT):
        orange = points_of(point_cloud(sample), SHAPE_RGB["ORANGE"])
        assert len(orange) > 20
        # a sphere of radius 1 m (size 60) on the ground at (4, 0): centre 1 m up; range noise of 2 cm
        assert np.allclose(np.linalg.norm(orange - np.array([4.0, 0.0, 1.0]), axis=1), 1.0, atol=0.1)
    writer.stop()
    lidar.wait_for(r"shape ORANGE removed \((no writers left|disposed)\)", TIMEOUT)


def test_our_shapes_publisher_reaches_a_fastdds_default_reader(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    peer = FastDdsPeer.read(apps, ["Circle"], domain_id, count=SAMPLES)
    apps.start("shapes", "publish", "--color", "PURPLE", "--shapesize", "45", "--domain", str(domain_id))
    shapes = peer.wait_samples("Circle", SAMPLES, TIMEOUT)
    assert all(s["color"] == "PURPLE" and s["shapesize"] == 45 and 0 <= s["x"] <= 240 and 0 <= s["y"] <= 270
               for s in shapes)
