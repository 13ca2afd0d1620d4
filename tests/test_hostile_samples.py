"""Samples from other systems cannot break an application: valid CDR, nonsense values, written against each application.

Hostile writers: the Fast DDS test peer (a real other vendor: eProsima Fast DDS 2.9, tests/fastdds) for enum values
outside the enum, NaN, a point cloud whose sizes disagree, circles of absurd sizes, camera frames of the wrong length;
this test process's raw writer (automotive.wire.rawsample: hand-made CDR or Cyclone's serializer with nonsense values)
for the rest. Every application must

- go on serving its good input: after the hostile samples, good samples of the same topic from a normal writer
  produce the application's normal output (a command line, an alert, a cloud with the circle, a verified frame...),
  and the process is still running;
- report each kind of bad sample in ONE line within the rate-limit window (config.badSampleReport, set long here),
  naming topic, writer and member, and count the others in a summary line (said at the latest when it stops);
- never show Cyclone's own per-sample drop warning (automotive.bus.cyclonelog turns those into one report).
"""

from __future__ import annotations

import math
import re
import struct
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Qos
from dds_helpers import wait_until, write_until
from fastdds_peer import FastDdsPeer
from lidar_helpers import Clouds, circle, points_of
from mcap.reader import make_reader
from mcap.writer import Writer

from automotive import config
from automotive.bus.endpoints import Databus
from automotive.bus.qos import WRITER_REPRESENTATION, QosProfiles
from automotive.cyclone.matched import matched_subscriptions
from automotive.sim.scene import SHAPE_RGB, LidarScene, ScanGrid
from automotive.tools.flows import channel_metadata, system_flows
from automotive.types.Alerts import DriverAlerts
from automotive.types.automotive import ShapeType
from automotive.types.builtin_interfaces.msg.dds_ import Time_
from automotive.types.CameraImage import CameraImageData_64KiB
from automotive.types.Common import ClassificationEnum, IndicatorStatusEnum, POSIXTimestamp
from automotive.types.Platform import PlatformControl, PlatformStatus
from automotive.types.Sensor import RangeModeEnum, SensorObject, SensorObjectList
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_, PointField_
from automotive.types.std_msgs.msg.dds_ import Header_
from automotive.types.Vision import VisionObject, VisionSensor
from automotive.wire.camera import FrameCodec
from automotive.wire.rawsample import RawWriter

ROOT = Path(__file__).resolve().parent.parent
TIMEOUT = 60.0  # processes starting on a loaded 2-core machine
WINDOW = ["-D", "config.badSampleReport=300"]  # every hostile sample of a test falls in one rate-limit window
BURST = 20
STAMP = POSIXTimestamp(s=1_700_000_000, ns=5)
GUID = r"[0-9a-f]+:[0-9a-f]+:[0-9a-f]+:[0-9a-f]+"
FASTDDS_WRITER = rf"writer {GUID} of participant 'fastdds_peer'"
OUR_WRITER = rf"writer {GUID}( '[^']*')? of participant 'automotive'"
CYCLONE_DROP = (rf"bad sample dropped by Cyclone DDS: not deserializable \(for reasons unknown\) .*, from writer "
                rf"{GUID} \(vendor 1\.15 eProsima Fast DDS\)")


def domain(domain_id: int) -> list[str]:
    return ["--domain", str(domain_id)]


def command(sample_id: int = 1, **changes: Any) -> PlatformControl:
    values: dict[str, Any] = dict(sample_id=sample_id, timestamp=STAMP, vehicleSteerAngle=1.0, speed=3.25,
                                  blinkerStatus=IndicatorStatusEnum.INDICATOR_LEFT)
    values.update(changes)
    return PlatformControl(**values)


def sensor_object(height: float = 1.5, **changes: Any) -> SensorObject:
    values: dict[str, Any] = dict(classification=ClassificationEnum.CLASSIFICATION_CAR, position=[1.0, 2.0, 0.0],
                                  velocity=[0.5, 0.0, 0.0], size=[4.0, height, 1.75], amplitude=0.0,
                                  rangeMode=RangeModeEnum.RANGE_NONE, rangeRate=0.0)
    values.update(changes)
    return SensorObject(**values)


def vision(sensor_id: int, stamp: POSIXTimestamp = STAMP, height: float = 1.5) -> VisionSensor:
    return VisionSensor(id=sensor_id, timestamp=stamp, objects=[VisionObject(
        classification=ClassificationEnum.CLASSIFICATION_CAR, position=[1.0, 2.0, 0.0], velocity=[0.5, 0.0, 0.0],
        size=[4.0, height, 1.75])])


def small_cloud(nanosec: int = 5, frame_id: str = "map", names: tuple[str, ...] = ("x", "y", "z", "rgb"),
                width: int = 8, data_bytes: int | None = None) -> PointCloud2_:
    points = np.zeros((width, 4), dtype=np.float32)
    points[:, 0] = np.arange(width)
    points[:, 3] = np.array([0x00FF00], dtype=np.uint32).view(np.float32)
    data = points.tobytes() if data_bytes is None else bytes(data_bytes)
    fields = [PointField_(name_=name, offset_=4 * index, datatype_=7, count_=1) for index, name in enumerate(names)]
    return PointCloud2_(header_=Header_(stamp_=Time_(sec_=1_700_000_000, nanosec_=nanosec), frame_id_=frame_id),
                        height_=1, width_=width, fields_=fields, is_bigendian_=False, point_step_=16,
                        row_step_=16 * width, data_=data, is_dense_=True)


def not_utf8(sample: Any, text: str, replacement: bytes) -> bytes:
    """``sample`` serialized (XCDR1) with the bytes of the string ``text`` replaced: valid CDR, not UTF-8."""
    assert len(replacement) == len(text.encode())
    data = bytes(sample.serialize(use_version_2=False))
    assert data.count(text.encode() + b"\0") == 1
    return data.replace(text.encode() + b"\0", replacement + b"\0")


def matched(writer: DataWriter[Any], readers: int = 1) -> None:
    wait_until(lambda: len(matched_subscriptions(writer)) >= readers, TIMEOUT, "the application's reader")


def stop_and_check(process: Any, once: list[str]) -> str:
    """Stop the application (it must still be running) and check each pattern was reported exactly once; the
    summaries of what was counted come out at the stop. Returns the output."""
    assert process.process.poll() is None, f"{process.name} ended:\n{process.output[-4000:]}"
    assert process.stop() == 0, process.output[-4000:]
    output = str(process.output)
    for pattern in once:
        assert process.count(pattern) == 1, f"/{pattern}/ not reported exactly once:\n{output[-6000:]}"
    assert "Traceback" not in output, output[-6000:]
    assert not re.search(r"deserialization \S+ failed", output), output[-6000:]  # Cyclone's per-sample warning
    return output


def summary(process: Any, topic: str, kind: str) -> int:
    """The number of further samples of a kind counted in the summary line(s), 0 without one."""
    pattern = rf"\[{re.escape(topic)}\] (\d+) more like this in the last \d+ s \({re.escape(kind)}"
    return sum(int(match[1]) for line in process.lines if (match := re.search(pattern, line)))


# -- the applications --------------------------------------------------------------------------------------------------

def test_vehicle_platform(apps, domain_id: int, bus: Databus) -> None:  # type: ignore[no-untyped-def]
    platform = apps.start("vehicle_platform", *domain(domain_id), *WINDOW)
    writer = bus.writer("PlatformControl", PlatformControl, "CollisionAvoidance")
    matched(writer)
    # Other vendors join once the application's reader is discovered: a Fast DDS writer started before it (up
    # ahead of the application's Python) matched the reader, but Cyclone did not find the writer in 60 s.
    FastDdsPeer.hostile(apps, "PlatformControl", "enum", domain_id)  # both write until the end of the test
    FastDdsPeer.hostile(apps, "PlatformControl", "nan", domain_id)
    inf = (r"\[PlatformControl\] bad sample ignored: vehicleSteerAngle = -inf \(expected a finite number\), "
           rf"from {OUR_WRITER}")
    write_until(platform, inf, lambda: writer.write(command(100, vehicleSteerAngle=-math.inf)))
    for index in range(BURST):
        writer.write(command(100 + index, vehicleSteerAngle=-math.inf))
        writer.write(command(200 + index, timestamp=POSIXTimestamp(s=5, ns=1_000_000_000)))
        writer.write(command(300 + index, timestamp=POSIXTimestamp(s=-1, ns=0)))
    once = [inf, rf"\[PlatformControl\] {CYCLONE_DROP}",
            rf"\[PlatformControl\] bad sample ignored: speed = nan \(expected a finite number\), from {FASTDDS_WRITER}",
            r"\[PlatformControl\] bad sample ignored: timestamp.ns = 1000000000 \(expected nanoseconds 0..999999999\)",
            r"\[PlatformControl\] bad sample ignored: timestamp.s = -1 \(expected seconds since 1970, 0 or more\)"]
    for pattern in once:
        platform.wait_for(pattern, TIMEOUT)
    # NaN speeds of our own, once the Fast DDS peer's first was reported: the platform takes commands as they arrive,
    # so the peer's later NaNs may all come after the stop; ours are counted before commands 7-9 are executed (one
    # reliable writer, in order).
    for index in range(BURST):
        writer.write(command(400 + index, speed=math.nan))
    # Good commands from a normal writer are executed; old and far-future stamps are data, not errors.
    writer.write(command(7))
    writer.write(command(8, timestamp=POSIXTimestamp(s=0, ns=1)))
    writer.write(command(9, timestamp=POSIXTimestamp(s=2**31 - 1, ns=999_999_999), speed=-2.5))
    platform.wait_for(r"command 7 stamped 1700000000\.000000005: speed 3\.25, steer 1\.00, blinker INDICATOR_LEFT",
                      TIMEOUT)
    platform.wait_for(r"command 8 stamped 0\.000000001", TIMEOUT)
    platform.wait_for(r"command 9 stamped 2147483647\.999999999: speed -2\.50", TIMEOUT)
    assert platform.count(r"command ([1-4]\d\d) stamped") == 0
    stop_and_check(platform, once)
    for kind in ("speed: a finite number", "vehicleSteerAngle: a finite number", "timestamp.s: seconds since 1970"):
        assert summary(platform, "PlatformControl", kind) > 0, platform.output[-6000:]


def test_collision_avoidance(apps, domain_id: int, bus: Databus) -> None:  # type: ignore[no-untyped-def]
    avoidance = apps.start("collision_avoidance", *domain(domain_id), *WINDOW)
    objects = bus.writer("SensorObjects", SensorObjectList, "SensorFusion")
    status = bus.writer("PlatformStatus", PlatformStatus, "Platform")
    matched(objects)
    matched(status)
    for kind in ("enum", "nan"):
        FastDdsPeer.hostile(apps, "SensorObjects", kind, domain_id)
    FastDdsPeer.hostile(apps, "SensorObjects", "many", domain_id, period_ms=500)  # valid: the bound's 128 objects
    inf = r"\[SensorObjects\] bad sample ignored: objects\[0\]\.position\[0\] = inf \(expected a finite number\)"
    infinite = SensorObjectList(timestamp=STAMP, objects=[sensor_object(position=[math.inf, 0.0, 0.0])])
    write_until(avoidance, inf, lambda: objects.write(infinite))
    nan_status = PlatformStatus(timestamp=STAMP, vehSpd=math.nan, blinkerStatus=IndicatorStatusEnum.INDICATOR_OFF,
                                posGasPedal=0.0, velocity=0.0, yawRate=0.0, vehicleSteerAngle=0.0)
    nan = rf"\[PlatformStatus\] bad sample ignored: vehSpd = nan \(expected a finite number\), from {OUR_WRITER}"
    write_until(avoidance, nan, lambda: status.write(nan_status))
    for _ in range(BURST):
        objects.write(infinite)
        objects.write(SensorObjectList(timestamp=POSIXTimestamp(s=1, ns=-7), objects=[]))
        status.write(nan_status)
    once = [inf, nan, rf"\[SensorObjects\] {CYCLONE_DROP}",
            rf"\[SensorObjects\] bad sample ignored: objects\[0\]\.size\[1\] = nan \(expected a finite number\), "
            rf"from {FASTDDS_WRITER}",
            r"\[SensorObjects\] bad sample ignored: timestamp\.ns = -7"]
    for pattern in once:
        avoidance.wait_for(pattern, TIMEOUT)
    # A list of 128 objects (the bound) is valid and answered; so is an empty one; a tall object raises the alert.
    avoidance.wait_for(r"command \d+: speed 0\.50, steer 1\.00, blinker INDICATOR_LEFT \(128 objects", TIMEOUT)
    objects.write(SensorObjectList(timestamp=STAMP, objects=[]))
    avoidance.wait_for(r"command \d+: speed 0\.00, steer 0\.00, blinker INDICATOR_OFF \(0 objects", TIMEOUT)
    objects.write(SensorObjectList(timestamp=STAMP, objects=[sensor_object(height=3.0)]))
    avoidance.wait_for(r"ALERT: driver attention needed", TIMEOUT)
    avoidance.wait_for(r"command \d+: speed 0\.50, steer 1\.00, blinker INDICATOR_LEFT \(1 objects", TIMEOUT)
    assert avoidance.count("ALERT") == 1  # the NaN-sized objects raised none
    stop_and_check(avoidance, once)


def test_sensor_fusion(apps, domain_id: int, bus: Databus) -> None:  # type: ignore[no-untyped-def]
    fusion = apps.start("sensor_fusion", *domain(domain_id), *WINDOW, "-D", "config.mode=event")
    sensors = bus.writer("VisionTopic", VisionSensor, "Vision")
    clouds = RawWriter(bus.writer("rt/LidarTopic", PointCloud2_, "Lidar"))
    matched(sensors)
    matched(clouds.writer)
    FastDdsPeer.hostile(apps, "VisionTopic", "nan", domain_id)
    FastDdsPeer.hostile(apps, "rt/LidarTopic", "mismatch", domain_id)
    FastDdsPeer.hostile(apps, "rt/LidarTopic", "noxyz", domain_id)
    old = r"\[VisionTopic\] bad sample ignored: timestamp\.s = -3"
    write_until(fusion, old, lambda: sensors.write(vision(5, stamp=POSIXTimestamp(s=-3, ns=0))))
    for _ in range(BURST):
        clouds.write(not_utf8(small_cloud(frame_id="ZZ"), "ZZ", b"\xff\xfe"))
        clouds.write(bytes(small_cloud(nanosec=1_000_000_000).serialize(use_version_2=False)))
    once = [old, rf"\[VisionTopic\] bad sample ignored: objects\[0\]\.size\[1\] = nan .*, from {FASTDDS_WRITER}",
            rf"\[rt/LidarTopic\] bad sample ignored: data_ = 16 bytes \(expected row_step_ x height_ = 16000 bytes\), "
            rf"from {FASTDDS_WRITER}",
            r"\[rt/LidarTopic\] bad sample ignored: fields_ = i,j,k \(expected fields named x, y and z\)",
            r"\[rt/LidarTopic\] bad sample ignored: undecodable \(UnicodeDecodeError: 'utf-8' codec can't decode",
            r"\[rt/LidarTopic\] bad sample ignored: header_\.stamp_\.nanosec_ = 1000000000"]
    for pattern in once:
        fusion.wait_for(pattern, TIMEOUT)
    assert fusion.count("published list") == 0 and fusion.count("lidar sample stamped") == 0
    sensors.write(vision(1))
    fusion.wait_for(r"published list 1: 1 object\(s\) from 1 vision sample\(s\) of sensor\(s\) 1", TIMEOUT)
    clouds.write(bytes(small_cloud().serialize(use_version_2=False)))
    fusion.wait_for(r"lidar sample stamped 1700000000\.000000005: 8 points", TIMEOUT)
    stop_and_check(fusion, once)


def test_lidar(apps, domain_id: int, bus: Databus) -> None:  # type: ignore[no-untyped-def]
    clouds = Clouds(bus)
    lidar = apps.start("lidar", *domain(domain_id), *WINDOW)
    writer = DataWriter(bus.publisher, bus.topic("Circle", ShapeType), qos=Qos(WRITER_REPRESENTATION))
    raw = RawWriter(writer)
    matched(writer)
    FastDdsPeer.hostile(apps, "Circle", "far", domain_id)  # a kind of its own: one line per kind, not per writer
    zero = r"\[Circle\] bad sample ignored: shapesize = 0 \(expected a size of 1\.\.240 pixels\)"
    write_until(lidar, zero, lambda: writer.write(ShapeType(color="ZERO", x=120, y=135, shapesize=0)))
    for index in range(BURST):
        writer.write(ShapeType(color="ZERO", x=120, y=135, shapesize=0))
        writer.write(ShapeType(color="NEGATIVE", x=120, y=135, shapesize=-30))
        writer.write(ShapeType(color="FAR", x=120, y=-1_000_000 - index, shapesize=30))
        writer.write(ShapeType(color="YELLOW", x=120, y=135, shapesize=2**31 - 1))  # the observer 70,000 km up
        raw.write(not_utf8(ShapeType(color="BAD", x=120, y=135, shapesize=30), "BAD", b"\xff\xfe\xfd"))
    once = [zero, rf"\[Circle\] bad sample ignored: x = 1000000 \(expected -240\.\.480: within one canvas of the "
            rf"240 x 270 Shapes Demo canvas\), from {FASTDDS_WRITER}",
            r"\[Circle\] bad sample ignored: y = -10000\d\d \(expected -270\.\.540: within one canvas",
            r"\[Circle\] bad sample ignored: undecodable \(UnicodeDecodeError"]
    for pattern in once:
        lidar.wait_for(pattern, TIMEOUT)
    # More circles than the scene takes (each costs a ray-casting step per frame): the rest are reported once.
    colours = [f"C{index:02d}" for index in range(40)]
    for index, colour in enumerate(colours):
        writer.write(ShapeType(color=colour, x=10 + 5 * index, y=30, shapesize=5))
    lidar.wait_for(r"\[Circle\] bad sample ignored: color = 'C3[2-9]' \(expected one of at most 32 circles", TIMEOUT)
    lidar.wait_for(r"frame \d+: 11520 points, 32 sphere\(s\)", TIMEOUT)
    for colour in colours:
        writer.dispose(ShapeType(color=colour, x=0, y=0, shapesize=5))
    lidar.wait_for_more(r"frame \d+: 11520 points, 0 sphere\(s\),", 1, TIMEOUT)
    x, y = circle(4, 0)
    writer.write(ShapeType(color="GREEN", x=x, y=y, shapesize=60))
    lidar.wait_for(rf"shape GREEN appeared at \({x}, {y}\), size 60", TIMEOUT)
    green = clouds.next(lambda cloud: len(points_of(cloud, SHAPE_RGB["GREEN"])) > 20, "with the green circle",
                        timeout=TIMEOUT)[0]
    hits = points_of(green, SHAPE_RGB["GREEN"])
    assert np.allclose(np.linalg.norm(hits - np.array([4.0, 0.0, 1.0]), axis=1), 1.0, atol=0.1)
    assert lidar.count("shape YELLOW appeared") == 0 and lidar.count("shape ZERO appeared") == 0
    stop_and_check(lidar, once)


def test_lidar_view(apps, domain_id: int, bus: Databus, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    snapshot = tmp_path / "cloud.png"
    view = apps.start("lidar_view", *domain(domain_id), *WINDOW, "--snapshot", str(snapshot),
                      "--timeout", str(TIMEOUT))
    writer = RawWriter(bus.writer("rt/LidarTopic", PointCloud2_, "Lidar"))
    matched(writer.writer)
    once = {
        r"\[rt/LidarTopic\] bad sample ignored: data_ = 16 bytes":
            bytes(small_cloud(width=1000, data_bytes=16).serialize(use_version_2=False)),
        r"\[rt/LidarTopic\] bad sample ignored: fields_ = i,j,k":
            bytes(small_cloud(names=("i", "j", "k")).serialize(use_version_2=False)),
        r"\[rt/LidarTopic\] bad sample ignored: undecodable": not_utf8(small_cloud(frame_id="ZZ"), "ZZ", b"\xff\xfe"),
    }
    # The view keeps only the newest cloud (LidarView: best effort, depth 1): a cloud followed at once by another is
    # never taken, so each kind is written until the view reports it (a burst of all three, once, left the middle
    # one unseen in a clean-clone run), then all of them again in a burst, which must add no line.
    for pattern, data in once.items():
        write_until(view, pattern, lambda data=data: writer.write(data))
    for _ in range(BURST):
        for data in once.values():
            writer.write(data)
    assert not snapshot.exists()
    scene = LidarScene(ScanGrid())
    scene.update_shape("RED", *circle(3, 0), 60)
    cloud = bytes(scene.point_cloud2(1_700_000_000, 5).serialize(use_version_2=False))
    write_until(view, r"snapshot of cloud 1 written to .*cloud\.png \(1600x800\): cloud stamped "
                      r"1700000000\.000000005, frame 'map': 11520 points", lambda: writer.write(cloud))
    assert view.wait_exit(TIMEOUT) == 0, view.output
    assert snapshot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for pattern in once:
        assert view.count(pattern) == 1, view.output


def test_camera_sub(apps, domain_id: int, bus: Databus) -> None:  # type: ignore[no-untyped-def]
    size = ["-D", "config.imageSize=64KiB"]
    sub = apps.start("camera_sub", *domain(domain_id), *WINDOW, *size)
    sub.wait_for("viewing CameraImageData_64KiB frames of 65536 bytes", TIMEOUT)
    writer = RawWriter(bus.writer("CameraImageData", CameraImageData_64KiB, "Camera"))
    matched(writer.writer)
    FastDdsPeer.hostile(apps, "CameraImageData", "short", domain_id, period_ms=100)
    FastDdsPeer.hostile(apps, "CameraImageData", "long", domain_id, period_ms=100)
    codec = FrameCodec(CameraImageData_64KiB)
    for seqnum in range(BURST):  # reliable: written once, delivered once the reader knows the writer
        writer.write(codec.encode(9, 1_700_000_000, 2_000_000_000, seqnum, bytes(65536)))  # a malformed stamp
        writer.write(codec.encode(9, 1_700_000_000, 5, BURST + seqnum, bytes(65536)))  # not the pattern
    once = [rf"\[CameraImageData\] {CYCLONE_DROP}",
            rf"\[CameraImageData\] bad sample ignored: data = 66560 bytes, too long \(expected a frame of 65536 bytes "
            rf"\(CameraImageData_64KiB\)\), from {FASTDDS_WRITER}",
            r"\[CameraImageData\] bad sample ignored: nanosec_ = 2000000000",
            r"\[CameraImageData\] bad sample counted as a mismatch: data = frame \d+ of camera 9: \d+ of 65536 bytes "
            r"differ"]
    for pattern in once:
        sub.wait_for(pattern, TIMEOUT)
    # The publisher's frames are verified: a statistics line with frames and no mismatch.
    apps.start("camera_pub", *domain(domain_id), *size, "-D", "config.pubInterval=50")
    sub.wait_for(r"samples=\d+ size=65536 latency_ms\(min/avg/max\)=[\d.]+/[\d.]+/[\d.]+ MB/s=[\d.]+ mismatches=0 "
                 r"gaps=0", TIMEOUT)
    stop_and_check(sub, once)


def test_hmi_takes_old_and_future_source_timestamps(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                     bus: Databus) -> None:
    # Six booleans: nothing in them can be nonsense once Cyclone has checked the sample (a byte 2 reads as True).
    # Source timestamps far in the past or future are not the HMI's business (only redundant mode judges them).
    hmi = apps.start("hmi", "--ui", "console", *domain(domain_id), *WINDOW)
    writer = RawWriter(bus.writer("AlertTopic", DriverAlerts, "HMI"))
    matched(writer.writer)
    writer.write(b"\x00\x01\x00\x00\x00\x00\x02\x00\x00\x00\x00\x00", timestamp=1)  # frontCollision 2, 1970
    hmi.wait_for("DRIVER ALERT: Front collision warning", TIMEOUT)
    writer.write(b"\x00\x01\x00\x00\x00\x00\x00\x00\x00\x01\x00\x00", timestamp=4_102_444_800 * 10**9)  # year 2100
    hmi.wait_for("DRIVER ALERT: Driver attention required", TIMEOUT)
    stop_and_check(hmi, [])


def test_redundant_collision_avoidance_judges_source_timestamps(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                               bus: Databus) -> None:
    avoidance = apps.start("collision_avoidance", *domain(domain_id), *WINDOW, "-D", "config.redundant=true")
    writer = bus.writer("SensorObjects", SensorObjectList, "SensorFusionRedundant", strength=30)
    matched(writer)
    lists = SensorObjectList(timestamp=STAMP, objects=[sensor_object(height=3.0)])
    hour = 3600 * 10**9
    old = r"\[SensorObjects\] bad sample ignored: source timestamp = \d+\.\d+ s old, before this instance started"
    write_until(avoidance, old, lambda: writer.write(lists, timestamp=hour))  # 1970: no stall of ours explains it
    for _ in range(BURST):
        writer.write(lists, timestamp=hour)
        writer.write(lists, timestamp=time.time_ns() + hour)  # an hour ahead: clocks disagree beyond the lease
    once = [r"\[SensorObjects\] bad sample ignored: source timestamp = \d+\.\d+ s old, before this instance started",
            r"\[SensorObjects\] bad sample ignored: source timestamp = 3\d\d\d\.\d+ s in the future \(expected clocks "
            r"that agree within the 250 ms lease\)"]
    for pattern in once:
        avoidance.wait_for(pattern, TIMEOUT)
    # Lists stamped now are answered, once the instance, alone, has waited 1 s to join: a fusion's pace of 10 Hz.
    stop = threading.Event()

    def publish() -> None:
        while not stop.wait(0.1):
            writer.write(lists)

    publisher = threading.Thread(target=publish, daemon=True)
    publisher.start()
    try:
        avoidance.wait_for(r"command 1: speed 0\.50, steer 1\.00", TIMEOUT)
        avoidance.wait_for(r"ALERT: driver attention needed", TIMEOUT)
    finally:
        stop.set()
        publisher.join(timeout=10)
    assert avoidance.count("stepping down") == 0 and avoidance.count("skipped") == 0
    stop_and_check(avoidance, once)


# -- the tools ---------------------------------------------------------------------------------------------------------

def test_record_and_replay_move_hostile_samples_unharmed(apps, domain_id: int, bus: Databus,  # type: ignore[no-untyped-def]
                                                         tmp_path: Path) -> None:
    recording = tmp_path / "hostile.mcap"
    record = apps.start("record", *domain(domain_id), *WINDOW, "--output", str(recording),
                        "--topics", "PlatformControl,Circle")
    commands = bus.writer("PlatformControl", PlatformControl, "CollisionAvoidance")
    circles = RawWriter(DataWriter(bus.publisher, bus.topic("Circle", ShapeType), qos=Qos(WRITER_REPRESENTATION)))
    matched(commands)
    matched(circles.writer)
    bad_circle = not_utf8(ShapeType(color="BAD", x=120, y=135, shapesize=30), "BAD", b"\xff\xfe\xfd")
    write_until(record, r"recorded=\d+ .* PlatformControl=[1-9]", lambda: commands.write(command(99, speed=math.nan)))
    for index in range(BURST):
        commands.write(command(100 + index, speed=math.nan))
    commands.write(command(42))
    # Written once, so only once the recorder's reader (best effort, as Shapes Demo's) has matched our writer itself.
    record.wait_for(r"\[Circle\] reader matched a writer", TIMEOUT)
    circles.write(bad_circle)  # recorded as received
    record.wait_for(r"recorded=\d+ .* PlatformControl=\d+/.* Circle=1/", TIMEOUT)
    circles.dispose(bad_circle)  # then a disposal, whose key the recorder cannot turn into a sample
    record.wait_for(r"\[Circle\] bad sample ignored: undecodable \(UnicodeDecodeError", TIMEOUT)
    stop_and_check(record, [r"\[Circle\] bad sample ignored: undecodable"])
    assert re.search(r"summary PlatformControl: messages=\d+", record.output)

    # Replayed into a vehicle platform: the NaN commands are reported there, the good one executed.
    platform = apps.start("vehicle_platform", *domain(domain_id), *WINDOW)
    platform.wait_for("vehicle platform:", TIMEOUT)
    # Looping: the platform's reader may learn of the replay's writer only after its first (best-effort) samples.
    replay = apps.start("replay", str(recording), *domain(domain_id), "--topics", "PlatformControl", "--loop",
                        "--wait-readers", "1")
    platform.wait_for(r"command 42 stamped 1700000000\.000000005", TIMEOUT)
    assert replay.stop() == 0, replay.output
    stop_and_check(platform, [r"\[PlatformControl\] bad sample ignored: speed = nan"])


def hostile_recording(path: Path) -> None:
    """An MCAP file (as automotive.tools.record.record writes them) holding PlatformControl messages, one of them with
    blinkerStatus 99:
    a sample Cyclone refuses to write. Such a file comes from another recorder, or is damaged."""
    flow = next(flow for flow in system_flows() if flow.topic == "PlatformControl")
    good = [bytes(command(sample_id).serialize(use_version_2=False)) for sample_id in (1, 2, 3)]
    bad = good[1][:-4] + struct.pack("<I", 99)
    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start(profile="ros2", library="test")
        schema = writer.register_schema(flow.schema.name, flow.schema.encoding, flow.schema.data)
        qos = QosProfiles(config.qos_file()).writer_qos("AutomotiveLibrary", flow.profile)
        channel = writer.register_channel("PlatformControl", "cdr", schema, channel_metadata(flow, qos))
        for index, data in enumerate([good[0], bad, bad, good[2]]):  # 100 ms apart
            writer.add_message(channel, log_time=(index + 1) * 10**8, data=data, publish_time=(index + 1) * 10**8,
                               sequence=index + 1)
        writer.finish()


def test_replay_reports_a_message_cyclone_refuses_and_goes_on(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                              tmp_path: Path) -> None:
    recording = tmp_path / "refused.mcap"
    hostile_recording(recording)
    assert len(list(make_reader(recording.open("rb")).iter_messages())) == 4
    platform = apps.start("vehicle_platform", *domain(domain_id), *WINDOW)
    platform.wait_for("vehicle platform:", TIMEOUT)
    # Looping: the platform's reader may learn of the replay's writer only after its first (best-effort) samples.
    replay = apps.start("replay", str(recording), *domain(domain_id), *WINDOW, "--loop", "--wait-readers", "1")
    platform.wait_for(r"command 3 stamped", TIMEOUT)
    replay.wait_for(r"\[PlatformControl\] bad sample not replayed: refused by Cyclone's writer "
                    r"\(DDS_RETCODE_BAD_PARAMETER\) \(expected a valid Platform::PlatformControl\), from message 2 of "
                    r"channel PlatformControl", TIMEOUT)
    assert replay.stop() == 0, replay.output
    written = int(re.findall(r"replayed (\d+) samples: PlatformControl=\d+$", replay.output, re.M)[-1])
    refused = int(re.search(r"(\d+) message\(s\) not replayed: Cyclone refused them", replay.output)[1])  # type: ignore[index]
    assert written > 0 and abs(written - refused) <= 2, replay.output  # every other message refused, each loop
    assert replay.count(r"bad sample not replayed") == 1, replay.output  # once in the window, then counted:
    assert re.search(rf"{refused - 1} more like this in the last \d+ s", replay.output), replay.output
    stop_and_check(platform, [])


def test_bridge_forwards_on_past_hostile_samples(apps, domain_id: int, bus: Databus) -> None:  # type: ignore[no-untyped-def]
    bridge = apps.start("bridge", *domain(domain_id), *WINDOW, "--port", "0", "--topics", "Circle,PlatformControl")
    circles = RawWriter(DataWriter(bus.publisher, bus.topic("Circle", ShapeType), qos=Qos(WRITER_REPRESENTATION)))
    commands = bus.writer("PlatformControl", PlatformControl, "CollisionAvoidance")
    matched(circles.writer)
    matched(commands)
    bad_circle = not_utf8(ShapeType(color="BAD", x=120, y=135, shapesize=2**31 - 1), "BAD", b"\xff\xfe\xfd")
    write_until(bridge, r"forwarded .*PlatformControl=[1-9]", lambda: commands.write(command(0, speed=math.inf)))
    # Written once, so only once the bridge knows its writer: discovery is not symmetric (our writer matched first),
    # and a sample written before the bridge's reader has matched is lost (seen once in a loaded suite).
    bridge.wait_for(r"\[Circle\] reader matched a writer", TIMEOUT)
    circles.write(bad_circle)
    for index in range(BURST):
        commands.write(command(index, speed=math.inf))
    # Forwarded as received (the bridge moves bytes; a Foxglove panel shows what was sent, inf included).
    bridge.wait_for(r"forwarded Circle=1 PlatformControl=\d+", TIMEOUT)
    circles.dispose(bad_circle)  # a disposal whose key cannot be decoded: not forwarded (none are), said once
    bridge.wait_for(r"\[Circle\] bad sample ignored: undecodable", TIMEOUT)
    circles.write(bytes(ShapeType(color="GREEN", x=1, y=2, shapesize=3).serialize(use_version_2=False)))
    bridge.wait_for(r"forwarded Circle=2 ", TIMEOUT)
    stop_and_check(bridge, [r"\[Circle\] bad sample ignored: undecodable"])


# -- memory ------------------------------------------------------------------------------------------------------------

def rss_kib(pid: int) -> int:
    status = Path(f"/proc/{pid}/status").read_text()
    return int(re.search(r"VmRSS:\s+(\d+) kB", status)[1])  # type: ignore[index]


def test_memory_stays_bounded_under_a_flood_of_bad_samples(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                          bus: Databus) -> None:
    """Thousands of distinct bad samples: the report state is bounded (test_badsamples proves it), and so is the
    process (a generous bound: the allocator's noise)."""
    platform = apps.start("vehicle_platform", *domain(domain_id), "-D", "config.badSampleReport=1")
    writer = bus.writer("PlatformControl", PlatformControl, "CollisionAvoidance")
    matched(writer)
    write_until(platform, r"command 1 stamped", lambda: writer.write(command(1)))
    values = (math.nan, math.inf, -math.inf)

    def flood(rounds: range) -> None:
        for round_ in rounds:
            for index in range(100):
                if index % 2:
                    writer.write(command(index, speed=values[index % 3]))
                else:
                    writer.write(command(index, timestamp=POSIXTimestamp(s=round_, ns=-1 - index)))
            marker = 10**6 + round_  # a good command after each round: the platform has taken the round
            while platform.count(rf"command {marker} stamped") == 0:
                writer.write(command(marker))
                platform.wait_for_more(r"status \d+:", 1, TIMEOUT)

    flood(range(10))
    baseline = rss_kib(platform.process.pid)
    flood(range(10, 50))
    grown = rss_kib(platform.process.pid) - baseline
    assert grown < 16 * 1024, f"RSS grew by {grown} KiB over 4,000 more bad samples"
    assert platform.count(r"more like this in the last") >= 2
    stop_and_check(platform, [])


def test_a_flood_of_new_instances_is_bounded(apps, domain_id: int, bus: Databus) -> None:  # type: ignore[no-untyped-def]
    """A writer that invents new keys without end (here Shapes Demo colours): the reader keeps at most 256 instances
    (the Shapes profile; Vision keeps 1024), so its memory stays bounded; a sample of a further instance is rejected
    and reported once (then counted), and once the flood's instances are gone a new colour is drawn again."""
    lidar = apps.start("lidar", *domain(domain_id), *WINDOW)
    writer = DataWriter(bus.publisher, bus.topic("Circle", ShapeType), qos=Qos(WRITER_REPRESENTATION))
    matched(writer)
    flood = [ShapeType(color=f"F{index:03d}", x=120, y=135, shapesize=5) for index in range(300)]
    rejected = r"\[Circle\] sample rejected \(instance limit\): total \d+; repeats are counted"
    write_until(lidar, rejected, lambda: [writer.write(sample) for sample in flood])
    for sample in flood:
        writer.dispose(sample)
        writer.unregister_instance(sample)
    x, y = circle(4, 0)
    write_until(lidar, rf"shape GREEN appeared at \({x}, {y}\), size 60",
                lambda: writer.write(ShapeType(color="GREEN", x=x, y=y, shapesize=60)))
    stop_and_check(lidar, [rejected])
