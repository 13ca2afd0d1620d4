"""The bad-sample machinery in process: the rules (automotive.bus.validation, the semantic rules of
automotive.wire.pointcloud and automotive.wire.camera), the rate-limited reporter and its bounded state
(automotive.bus.badsamples), the checked take
(automotive.bus.checkedreader) and the route of Cyclone's own drop warnings (automotive.bus.cyclonelog)."""

from __future__ import annotations

import logging
import math
import re
import struct
from typing import Any

import numpy as np
import pytest
from cyclonedds._clayer import ddspy_read
from cyclonedds.core import InstanceState
from cyclonedds.pub import DataWriter
from cyclonedds.sub import InvalidSample
from dds_helpers import wait_until

from automotive.bus import cyclonelog, validation
from automotive.bus.badsamples import BadSample, BadSampleError, BadSampleReporter
from automotive.bus.checkedreader import CheckedReader, decoder, set_decoder
from automotive.bus.endpoints import Databus
from automotive.cyclone import logsink
from automotive.cyclone.matched import matched_publications
from automotive.sim.scene import LidarScene, ScanGrid
from automotive.tools.cloudview import render_png
from automotive.types.automotive import ShapeType
from automotive.types.builtin_interfaces.msg.dds_ import Time_
from automotive.types.CameraImage import CameraImageData_64KiB
from automotive.types.Common import ClassificationEnum, IndicatorStatusEnum, POSIXTimestamp
from automotive.types.Platform import PlatformControl
from automotive.types.Sensor import RangeModeEnum, SensorObject, SensorObjectList
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_, PointField_
from automotive.types.std_msgs.msg.dds_ import Header_
from automotive.wire.camera import FrameCodec
from automotive.wire.pointcloud import point_fields
from automotive.wire.rawsample import ANY_STATE, RawReader, RawWriter

NAN, INF = math.nan, math.inf


class Lines(logging.Handler):
    """Collects the reporter's lines."""

    def __init__(self) -> None:
        super().__init__()
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())

    def matching(self, text: str) -> list[str]:
        return [line for line in self.lines if text in line]


def logger(name: str) -> tuple[logging.Logger, Lines]:
    log = logging.getLogger(f"test.badsamples.{name}")
    lines = Lines()
    log.handlers[:] = [lines]
    log.propagate = False
    return log, lines


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def command(**changes: Any) -> PlatformControl:
    values: dict[str, Any] = dict(sample_id=1, timestamp=POSIXTimestamp(s=1_700_000_000, ns=5), vehicleSteerAngle=0.5,
                                  speed=12.0, blinkerStatus=IndicatorStatusEnum.INDICATOR_LEFT)
    values.update(changes)
    return PlatformControl(**values)


def sensor_object(size: tuple[float, float, float] = (4.0, 1.5, 1.75)) -> SensorObject:
    return SensorObject(classification=ClassificationEnum.CLASSIFICATION_CAR, position=[1.0, 2.0, 0.0],
                        velocity=[0.5, 0.0, 0.0], size=list(size), amplitude=0.0, rangeMode=RangeModeEnum.RANGE_NONE,
                        rangeRate=0.0)


def cloud(width: int = 4, height: int = 2, names: tuple[str, ...] = ("x", "y", "z", "rgb"), point_step: int = 16,
          row_step: int | None = None, data_bytes: int | None = None, nanosec: int = 5) -> PointCloud2_:
    fields = [PointField_(name_=name, offset_=4 * index, datatype_=7, count_=1) for index, name in enumerate(names)]
    row_step = width * point_step if row_step is None else row_step
    return PointCloud2_(header_=Header_(stamp_=Time_(sec_=1_700_000_000, nanosec_=nanosec), frame_id_="map"),
                        height_=height, width_=width, fields_=fields, is_bigendian_=False, point_step_=point_step,
                        row_step_=row_step, data_=bytes(row_step * height if data_bytes is None else data_bytes),
                        is_dense_=True)


# -- the rules -------------------------------------------------------------------------------------------------------

def test_good_samples_pass() -> None:
    scene = LidarScene(ScanGrid(azimuth_steps=18, polar_steps=8))
    scene.update_shape("RED", 150, 135, 30)
    assert validation.check(scene.point_cloud2(1_700_000_000, 999_999_999)) is None  # our own LiDAR's cloud
    assert validation.check(command()) is None
    assert validation.check(SensorObjectList(timestamp=POSIXTimestamp(s=1, ns=0), objects=[])) is None  # empty
    many = SensorObjectList(timestamp=POSIXTimestamp(s=1, ns=0), objects=[sensor_object()] * 128)
    assert validation.check(many) is None  # the bound's number of objects
    assert validation.check(ShapeType(color="BLUE", x=0, y=270, shapesize=240)) is None
    # A ROS 2 cloud with padded rows (row_step above width x point_step) and a data length of row_step x height.
    assert validation.check(cloud(width=3, height=2, row_step=64)) is None
    assert validation.check(cloud(width=0, height=0)) is None


@pytest.mark.parametrize("stamp", [POSIXTimestamp(s=0, ns=0), POSIXTimestamp(s=2**31 - 1, ns=999_999_999)])
def test_old_and_future_timestamps_are_not_errors(stamp: POSIXTimestamp) -> None:
    # Replayed recordings carry their original timestamps; what is "too old" depends on the use (StallGuard).
    assert validation.check(command(timestamp=stamp)) is None


@pytest.mark.parametrize("sample,member,value,expected", [
    (command(speed=NAN), "speed", "nan", "a finite number"),
    (command(vehicleSteerAngle=-INF), "vehicleSteerAngle", "-inf", "a finite number"),
    (command(timestamp=POSIXTimestamp(s=5, ns=1_000_000_000)), "timestamp.ns", "1000000000",
     "nanoseconds 0..999999999"),
    (command(timestamp=POSIXTimestamp(s=5, ns=-1)), "timestamp.ns", "-1", "nanoseconds 0..999999999"),
    (command(timestamp=POSIXTimestamp(s=-5, ns=0)), "timestamp.s", "-5", "seconds since 1970, 0 or more"),
    (SensorObjectList(timestamp=POSIXTimestamp(s=1, ns=0),
                      objects=[sensor_object(), sensor_object(), sensor_object(), sensor_object((1.0, NAN, 1.0))]),
     "objects[3].size[1]", "nan", "a finite number"),
    (cloud(nanosec=1_000_000_000), "header_.stamp_.nanosec_", "1000000000", "nanoseconds 0..999999999"),
])
def test_generic_rules(sample: Any, member: str, value: str, expected: str) -> None:
    assert validation.check(sample) == BadSample(member, value, expected)


def test_a_kind_is_the_member_without_indexes_and_the_rule() -> None:
    problem = BadSample("objects[3].size[1]", "nan", "a finite number")
    assert problem.kind == "objects[].size[]: a finite number"
    assert problem.describe() == "objects[3].size[1] = nan (expected a finite number)"
    assert BadSample("", "x" * 500, "y").brief() == "x" * 77 + "..."  # a hostile value is shown shortened


@pytest.mark.parametrize("sample,member", [
    (cloud(width=1000, height=1, data_bytes=16), "data_"),  # width and data length disagree
    (cloud(width=4, height=2, data_bytes=8 * 16 + 1), "data_"),
    (cloud(width=4, row_step=32), "row_step_"),  # rows shorter than their points
    (cloud(names=("i", "j", "k")), "fields_"),  # no position at all
    (cloud(names=("x", "y", "z", "rgb"), point_step=12, row_step=48), "fields_[3].offset_"),  # rgb outside a point
])
def test_point_cloud_geometry(sample: PointCloud2_, member: str) -> None:
    problem = validation.check(sample)
    assert problem is not None and problem.member == member, problem


def test_point_cloud_datatype() -> None:
    sample = cloud()
    sample.fields_ = point_fields()
    sample.fields_[2] = PointField_(name_="z", offset_=8, datatype_=42, count_=1)
    assert validation.check(sample) == BadSample("fields_[2].datatype_", "42", "a PointField datatype 1..8")


@pytest.mark.parametrize("shape,member", [
    (ShapeType(color="RED", x=120, y=135, shapesize=0), "shapesize"),
    (ShapeType(color="RED", x=120, y=135, shapesize=-30), "shapesize"),
    (ShapeType(color="RED", x=120, y=135, shapesize=2_000_000_000), "shapesize"),
    (ShapeType(color="RED", x=1_000_000, y=135, shapesize=30), "x"),
    (ShapeType(color="RED", x=120, y=-271, shapesize=30), "y"),
])
def test_circle_size_and_position(shape: ShapeType, member: str) -> None:
    problem = validation.check(shape)
    assert problem is not None and problem.member == member, problem


def test_camera_frames_of_the_wrong_length_or_stamp() -> None:
    codec = FrameCodec(CameraImageData_64KiB)
    good = codec.encode(1, 2, 3, 4, bytes(65536))
    assert codec.check(codec.decode(good)) is None
    with pytest.raises(BadSampleError, match=r"data = 66560 bytes, too long \(expected a frame of 65536 bytes"):
        codec.decode(good + bytes(1024))
    with pytest.raises(BadSampleError, match=r"data = 1024 bytes, too short"):
        codec.decode(good[:20 + 1024])
    xcdr2 = FrameCodec(CameraImageData_64KiB, xcdr2=True).encode(1, 2, 3, 4, bytes(65536))
    lying = xcdr2[:4] + struct.pack("<I", 99) + xcdr2[8:]
    with pytest.raises(BadSampleError, match=r"DHEADER = 99 \(expected 65552 bytes\)"):
        codec.decode(lying)
    assert codec.check(codec.decode(codec.encode(1, 2, 1_000_000_000, 4, bytes(65536)))) == \
        BadSample("nanosec_", "1000000000", "nanoseconds 0..999999999")


def test_pictures_of_clouds_with_far_points_stay_small_and_quick(tmp_path: Any) -> None:
    # A valid cloud may hold a point 10^30 m away: the view's range rings must not number 10^29 (they did).
    xyz = np.array([[0, 0, 0], [1e30, 5, 0], [3.4e38, -3.4e38, 1e38], [NAN, 0, 0]], dtype=np.float32)
    render_png(xyz, np.zeros((4, 3), dtype=np.uint8), tmp_path / "far.png", (320, 160))
    assert (tmp_path / "far.png").stat().st_size > 0


# -- the reporter --------------------------------------------------------------------------------------------------

def reporter(name: str, interval_s: float = 10.0, max_kinds: int = 256) -> tuple[BadSampleReporter, Lines, Clock]:
    log, lines = logger(name)
    clock = Clock()
    return BadSampleReporter(log, interval_s, max_kinds, clock, timer=False), lines, clock


def test_one_line_per_kind_then_one_summary_per_interval() -> None:
    report, lines, clock = reporter("summary")
    for value in range(100):
        report.report("PlatformControl", BadSample("speed", str(value), "a finite number"), "writer 1:2:3:4")
    report.report("PlatformControl", BadSample("timestamp.ns", "-1", "nanoseconds 0..999999999"), "writer 1:2:3:4")
    assert lines.lines == [
        "[PlatformControl] bad sample ignored: speed = 0 (expected a finite number), from writer 1:2:3:4; more like it "
        "are counted and reported every 10 s",
        "[PlatformControl] bad sample ignored: timestamp.ns = -1 (expected nanoseconds 0..999999999), from writer "
        "1:2:3:4; more like it are counted and reported every 10 s",
    ]
    clock.now += 9.9
    report.flush()
    assert len(lines.lines) == 2  # the interval has not ended
    clock.now += 0.1
    report.flush()
    assert lines.lines[2:] == ["[PlatformControl] 99 more like this in the last 10 s (speed: a finite number); the "
                               "latest: speed = 99, from writer 1:2:3:4"]
    assert report.kinds == 1  # speed goes on being counted; timestamp.ns was quiet for the interval: forgotten
    clock.now += 10
    report.flush()
    assert report.kinds == 0 and len(lines.lines) == 3  # quiet for an interval: forgotten
    report.report("PlatformControl", BadSample("speed", "nan", "a finite number"), "writer 1:2:3:4")
    assert len(lines.lines) == 4  # a new interval: reported in full again
    report.report("PlatformControl", BadSample("speed", "inf", "a finite number"), "writer 1:2:3:4")
    report.close()
    assert lines.lines[-1].startswith("[PlatformControl] 1 more like this in the last 0 s (speed: a finite number)")


def test_the_reporters_state_stays_bounded_whatever_arrives() -> None:
    report, lines, clock = reporter("bounded", max_kinds=64)
    for index in range(10_000):  # distinct values of one kind: one entry
        report.report("SensorObjects", BadSample(f"objects[{index % 128}].size[1]", str(index), "a finite number"),
                      f"writer {index}")
    assert report.kinds == 1
    for index in range(10_000):  # distinct members (a writer cannot make more than its type has; say it could)
        report.report("SensorObjects", BadSample(f"member{index}", "nan", "a finite number"), f"writer {index}")
    assert report.kinds == 64 + 1  # the catch-all entry counts the rest together
    assert len(lines.lines) == 64 + 1
    assert lines.lines[-1].endswith("[further kinds are counted together]")
    clock.now += 10
    report.flush()  # the kinds seen once are forgotten; the two that kept coming are summarised
    assert report.kinds == 2 and len(lines.lines) == 65 + 2
    clock.now += 10
    report.flush()
    assert report.kinds == 0


def test_the_timer_says_the_summary_when_the_flood_stops() -> None:
    log, lines = logger("timer")
    # The real clock: an interval long enough that the five reports fall in one, however a loaded machine schedules
    # this thread (at 0.2 s a preemption between two reports could split them), and the seconds said as they come.
    report = BadSampleReporter(log, interval_s=1.0)
    try:
        for _ in range(5):
            report.report("VisionTopic", BadSample("timestamp.ns", "-1", "nanoseconds 0..999999999"), "writer w")
        wait_until(lambda: len(lines.lines) == 2, 10, "the summary line")
        summary = r"\[VisionTopic\] 4 more like this in the last \d+ s \(timestamp\.ns:"
        assert re.match(summary, lines.lines[1]), lines.lines
    finally:
        report.close()


# -- the checked take ------------------------------------------------------------------------------------------------

def raw_shape(color: bytes, x: int = 120, y: int = 135, size: int = 30) -> bytes:
    """An XCDR1 ShapeType whose colour holds whatever bytes (valid CDR: Cyclone checks the length, not UTF-8)."""
    text = color + b"\0"
    padding = bytes(-len(text) % 4)
    return b"\x00\x01\x00\x00" + struct.pack("<I", len(text)) + text + padding + struct.pack("<iii", x, y, size)


def test_one_bad_sample_never_loses_the_good_ones_of_its_batch(bus: Databus) -> None:
    log, lines = logger("take")
    report = BadSampleReporter(log, timer=False)
    writer = DataWriter(bus.publisher, bus.topic("Circle", ShapeType))
    reader = CheckedReader(bus.subscriber, bus.topic("Circle", ShapeType), reporter=report)
    wait_until(lambda: bool(matched_publications(reader)), what="the reader to match")
    raw = RawWriter(writer)
    raw.write(raw_shape(b"GREEN", 10, 20, 30))
    raw.write(raw_shape(b"\xff\xfeBAD"))  # not UTF-8: Cyclone Python's own take raises UnicodeDecodeError
    raw.write(raw_shape(b"RED", size=2_000_000_000))  # decodes, breaks the circle's rule
    raw.write(raw_shape(b"BLUE", 40, 50, 60))
    raw.dispose(raw_shape(b"\xff\xfeBAD"))  # its unread sample now says the instance is disposed
    wait_until(lambda: len(ddspy_read(reader._ref, ANY_STATE, 16)) == 4, what="four instances' samples")
    taken = reader.take(N=16)
    assert [(s.color, s.x, s.y, s.shapesize) for s in taken if isinstance(s, ShapeType)] == \
        [("GREEN", 10, 20, 30), ("BLUE", 40, 50, 60)]
    invalid = [s for s in taken if isinstance(s, InvalidSample)]
    assert len(invalid) == 1 and invalid[0].key_sample is None  # the disposal still comes through
    # ... as a sample without data, as Cyclone gives a disposal: consumers test valid_data before they read members
    assert invalid[0].sample_info.valid_data is False
    assert invalid[0].sample_info.instance_state == InstanceState.NotAliveDisposed
    assert len(lines.lines) == 2 and report.reported == 2
    assert lines.matching("[Circle] bad sample ignored: undecodable (UnicodeDecodeError: 'utf-8' codec can't decode")
    assert lines.matching("[Circle] bad sample ignored: shapesize = 2000000000 (expected a size of 1..240 pixels)")
    raw.dispose(raw_shape(b"GREEN"))  # a disposal alone (no data): its key decodes
    raw.write(raw_shape(b"\xff\xfeBAD2"))
    wait_until(lambda: len(ddspy_read(reader._ref, ANY_STATE, 16)) == 2, what="a disposal and a sample")
    taken = reader.take(N=16)
    assert [s.key_sample.color for s in taken if isinstance(s, InvalidSample)] == ["GREEN"]
    assert report.reported == 3


def test_a_raw_reader_skips_and_reports_a_key_it_cannot_decode(bus: Databus) -> None:
    log, lines = logger("raw")
    report = BadSampleReporter(log, timer=False)
    writer = DataWriter(bus.publisher, bus.topic("Circle", ShapeType))
    reader = CheckedReader(bus.subscriber, bus.topic("Circle", ShapeType), reporter=report)
    wait_until(lambda: bool(matched_publications(reader)), what="the reader to match")
    raw = RawWriter(writer)
    taker = RawReader(reader, zero_copy=False)  # the recorder's and the bridge's take: bytes, never decoded
    raw.write(raw_shape(b"\xff\xfeBAD"))
    raw.write(raw_shape(b"GREEN"))
    wait_until(lambda: len(ddspy_read(reader._ref, ANY_STATE, 16)) == 2, what="two samples")
    assert len(taker.take()) == 2  # both as received: the bytes move, nothing is decoded
    raw.dispose(raw_shape(b"\xff\xfeBAD"))
    raw.dispose(raw_shape(b"GREEN"))
    wait_until(lambda: len(ddspy_read(reader._ref, ANY_STATE, 16)) == 2, what="two disposals")
    disposals = taker.take()  # a disposal is turned into a sample of its key: the bad key cannot be
    assert len(disposals) == 1 and ShapeType.deserialize(disposals[0].data).color == "GREEN"
    assert lines.lines[0].startswith("[Circle] bad sample ignored: undecodable (UnicodeDecodeError")


def test_a_decoder_can_be_replaced_per_type() -> None:
    assert decoder(PlatformControl) == PlatformControl.deserialize
    calls: list[bytes] = []

    def decode(data: bytes) -> PlatformControl:
        calls.append(data)
        return PlatformControl.deserialize(data)

    set_decoder(PlatformControl, decode)
    try:
        assert decoder(PlatformControl) is decode
    finally:
        set_decoder(PlatformControl, None)
    assert decoder(PlatformControl) == PlatformControl.deserialize


# -- Cyclone's own warnings --------------------------------------------------------------------------------------------

MEASURED_WARNING = ("data(application, vendor 1.15): 10f7f01:c848d0dd:0:103 #2: deserialization "
                    "rt/LidarTopic/sensor_msgs::msg::dds_::PointCloud2_ failed (for reasons unknown)")


def test_cyclones_sink_setter_is_found_in_the_pinned_wheel() -> None:
    # cyclonedds 11.0.1's libddsc keeps dds_set_log_sink as a local symbol; without it, drops are logged per sample.
    assert logsink.sink_setter() is not None


def test_cyclones_drop_warning_becomes_one_report(capfd: Any) -> None:
    report, lines, clock = reporter("cyclone")
    sink = cyclonelog._Sink(report, setter=None)
    for _ in range(50):
        sink.handle(cyclonelog.LC_WARNING, "1795463914.888568 [151]       recv: ", MEASURED_WARNING)
    assert lines.lines == [
        "[rt/LidarTopic] bad sample dropped by Cyclone DDS: not deserializable (for reasons unknown) (expected a valid "
        "sensor_msgs::msg::dds_::PointCloud2_: enum values in the enum, strings and sequences within their bounds, "
        "nothing truncated), from writer 10f7f01:c848d0dd:0:103 (vendor 1.15 eProsima Fast DDS); more like it are "
        "counted and reported every 10 s"]
    for number in range(20):  # any other line: the first as Cyclone wrote it, the rest of its kind counted
        sink.handle(cyclonelog.LC_WARNING, "1795463914.888568 [151]       recv: ", f"malformed packet #{number}")
    sink.others.close()
    error = capfd.readouterr().err.splitlines()
    assert error == ["1795463914.888568 [151]       recv: malformed packet #0",
                     "cyclonedds: 19 more like this in the last 0 s (Cyclone DDS: malformed packet ##); the latest: "
                     "1795463914.888568 [151]       recv: malformed packet #19"]
