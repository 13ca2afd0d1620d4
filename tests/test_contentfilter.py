"""Content filters (automotive.bus.contentfilter, automotive.wire.filteredraw): the DDS filter grammar, its errors
with their position, filtered typed and raw readers (after the checks of CheckedReader: bad samples are still left
out), and the --filter option / config.filter.<Topic> of the applications (lidar, record)."""

from __future__ import annotations

import dataclasses
import re
import signal
import struct
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from apprunner import command_of
from cyclonedds.core import InstanceState
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy
from dds_helpers import take_samples, wait_until
from test_bad_input import assert_one_line_error

from automotive.bus.badsamples import BadSample
from automotive.bus.checkedreader import CheckedReader
from automotive.bus.contentfilter import MAX_DEPTH, ContentFilter, FilteredReader, FilterError, evaluate
from automotive.bus.endpoints import Databus
from automotive.cyclone.codecs import codec_for
from automotive.cyclone.matched import matched_subscriptions
from automotive.tools.support.children import program_command
from automotive.types.automotive import ShapeType
from automotive.types.Common import ClassificationEnum, POSIXTimestamp
from automotive.types.shape import ShapeType as SuiteShapeType
from automotive.types.Vision import VisionObject, VisionSensor
from automotive.wire.filteredraw import FilteredRawReader
from automotive.wire.rawsample import SampleKind

ROOT = Path(__file__).resolve().parent.parent
TIMEOUT = 60.0
RED = SuiteShapeType(color="RED", x=10, y=200, shapesize=15, additional_payload_size=b"\x01\x02\xff")
VISION = VisionSensor(id=3, timestamp=POSIXTimestamp(s=5, ns=7), objects=[
    VisionObject(classification=ClassificationEnum.CLASSIFICATION_CAR, position=[1.0, 2.0, 3.0],
                 velocity=[0.0, 0.5, 0.0], size=[2.0, 2.0, 2.5])])


def matches(expression: str, sample: Any = RED, parameters: tuple[str, ...] = ()) -> bool:
    return ContentFilter.parse(expression, parameters).bind(type(sample))(sample)


@pytest.mark.parametrize("expression,parameters,expected", [
    ("shapesize <= 20", (), True),
    ("shapesize < 15", (), False),
    ("shapesize >= 15 AND shapesize > 14 AND shapesize <> 16 AND shapesize != 17", (), True),
    ("color = 'RED'", (), True),
    ('color = "RED"', (), True),
    ("color <> 'RED'", (), False),
    ("color = %0", ("'RED'",), True),
    ("color = %0", ("RED",), True),  # a parameter without quotes stands for that string
    ("color = %1 OR color = %0", ("'RED'", "'BLUE'"), True),
    ("x = %0", ("10",), True),
    ("20 >= shapesize", (), True),  # a constant on the left: the comparison turns round
    ("5 < x", (), True),
    ("x < y", (), True),  # two members
    ("x = 0x0A AND y = 2e2 AND shapesize = 15.0 AND x > -3", (), True),
    ("x BETWEEN 5 AND 10", (), True),
    ("x BETWEEN 11 AND 20", (), False),
    ("x NOT BETWEEN 11 AND 20", (), True),
    ("color LIKE 'R%'", (), True),
    ("color LIKE 'R_D'", (), True),
    ("color LIKE 'R_'", (), False),
    ("color NOT LIKE '%E%'", (), False),
    ("color like 'r%'", (), False),  # patterns are case-sensitive; keywords are not
    ("NOT x = 10", (), False),
    ("x = 1 OR x = 10 AND y = 1", (), False),  # AND binds tighter than OR
    ("(x = 1 OR x = 10) AND y = 200", (), True),
    ("NOT (x = 1) and not (y = 1)", (), True),
])
def test_expressions(expression: str, parameters: tuple[str, ...], expected: bool) -> None:
    assert matches(expression, RED, parameters) is expected


@pytest.mark.parametrize("expression,parameters,expected", [
    ("id = 3 AND timestamp.s = 5 AND timestamp.ns BETWEEN 1 AND 10", (), True),
    ("objects[0].classification = CLASSIFICATION_CAR", (), True),
    ("objects[0].classification = 'CLASSIFICATION_CAR'", (), True),
    ("objects[0].classification = %0", ("CLASSIFICATION_BIKE",), False),
    ("objects[0].classification > CLASSIFICATION_BIKE", (), True),  # enumerators compare by their values
    ("objects[0].classification = 5", (), True),
    ("objects[0].size[2] > 2.4 AND objects[0].velocity[1] = 0.5", (), True),
    ("objects[1].classification = CLASSIFICATION_CAR", (), False),  # past the end of the sequence: unknown
    # unknown stays unknown under NOT, as SQL's NULL: neither a comparison past the end nor its NOT matches
    ("NOT objects[1].size[0] > 0", (), False),
    ("objects[1].size[0] > 0 OR id = 3", (), True),  # unknown OR true
    ("objects[1].size[0] > 0 OR id = 4", (), False),
    ("NOT (objects[1].size[0] > 0 AND id = 4)", (), True),  # unknown AND false is false
    ("NOT (objects[1].size[0] > 0 OR id = 4)", (), False),  # unknown OR false is unknown
    ("NOT (objects[1].size[0] > 0 OR id = 3)", (), False),
])
def test_nested_members_arrays_and_enums(expression: str, parameters: tuple[str, ...], expected: bool) -> None:
    assert matches(expression, VISION, parameters) is expected
    # The same on the sample as CheckedReader.use_views gives it: its objects a numpy structured array
    views = codec_for(VisionSensor).decode(VisionSensor.serialize(VISION), views=True)
    assert isinstance(views.objects, np.ndarray)
    assert ContentFilter.parse(expression, parameters).bind(VisionSensor)(views) is expected


def with_classification(value: int) -> VisionSensor:
    """VISION with its object's classification replaced by any int32, as another vendor's writer may send it:
    serialized with one enumerator, then the enum's four bytes patched."""
    car = bytes(VisionSensor.serialize(VISION, use_version_2=False))
    bike = bytes(VisionSensor.serialize(dataclasses.replace(VISION, objects=[dataclasses.replace(
        VISION.objects[0], classification=ClassificationEnum.CLASSIFICATION_BIKE)]), use_version_2=False))
    offset = next(index for index, (a, b) in enumerate(zip(car, bike)) if a != b)
    offset -= offset % 4
    patched = car[:offset] + struct.pack("<i", value) + car[offset + 4:]
    return VisionSensor.deserialize(patched)


def test_an_enum_value_outside_the_enum_is_compared_by_its_number() -> None:
    """Cyclone Python decodes an enumerator the type does not have as a plain int (Cyclone's own writer refuses to
    send one, another vendor's or a recording need not): the filter compares it, never raises."""
    odd = with_classification(99)
    assert odd.objects[0].classification == 99 and not isinstance(odd.objects[0].classification, ClassificationEnum)
    assert matches("objects[0].classification = CLASSIFICATION_CAR", odd) is False
    assert matches("objects[0].classification = 99", odd) is True
    assert matches("objects[0].classification > CLASSIFICATION_CAR", odd) is True


def test_a_filter_that_cannot_be_evaluated_gives_a_bad_sample() -> None:
    class Broken:
        @property
        def x(self) -> int:
            raise RuntimeError("no x here")

    predicate = ContentFilter.parse("x = 1").bind(SuiteShapeType)
    assert evaluate(predicate, RED) is False
    assert evaluate(predicate, dataclasses.replace(RED, x=1)) is True
    verdict = evaluate(predicate, Broken())
    assert isinstance(verdict, BadSample)
    assert verdict.value == "the filter cannot be evaluated on it (RuntimeError: no x here)"


def test_expressions_too_deep_or_numbers_too_long_are_filter_errors() -> None:
    within = " OR ".join(f"x = {value}" for value in range(MAX_DEPTH + 1))  # MAX_DEPTH ORs
    assert matches(within, RED) is True  # x = 10 is among them
    assert matches("NOT " * (MAX_DEPTH - 1) + "x = 10", RED) is False
    for expression in (within + " OR x = 1000", "NOT " * 5000 + "x = 1", "x = 1 AND " * 3000 + "x = 1"):
        with pytest.raises(FilterError, match=rf"nests more than {MAX_DEPTH} conditions deep"):
            ContentFilter.parse(expression)
    with pytest.raises(FilterError, match=r"position 5: the number 99999999999999999999\.\.\. has 5000 digits"):
        ContentFilter.parse("x = " + "9" * 5000).bind(SuiteShapeType)


@pytest.mark.parametrize("expression,parameters,position,message", [
    ("", (), 1, "the expression is empty"),
    ("shapesize <= ", (), 14, "ends too early"),
    ("shapesize << 2", (), 12, "unexpected '<'"),
    ("x = #", (), 5, "unexpected character '#'"),
    ("x = 1 AND", (), 10, "ends too early"),
    ("(x = 1", (), 7, "ends too early"),
    ("x BETWEEN 1", (), 12, "ends too early"),
    ("colour = 'RED'", (), 1, "ShapeType has no member 'colour'"),
    ("color = RED", (), 9, "a string needs quotes: 'RED'"),
    ("x = 'RED'", (), 5, "x is a number (int32) but 'RED' is a string"),
    ("color = %1", ("'RED'",), 9, "parameter %1 is used but 1 parameter(s) given"),
    ("1 = 1", (), 1, "compares two constants"),
    ("additional_payload_size = 1", (), 1, "is a sequence"),
    ("x LIKE 'a%'", (), 1, "LIKE needs a string member"),
    ("color LIKE x", (), 12, "LIKE needs a 'pattern' string"),
    ("x BETWEEN y AND 3", (), 11, "BETWEEN needs constants"),
    ("x.y = 1", (), 1, "x is a number, it has no member 'y'"),
    ("x[0] = 1", (), 1, "x is a number, it has no [index]"),
])
def test_errors_name_the_position(expression: str, parameters: tuple[str, ...], position: int, message: str) -> None:
    with pytest.raises(FilterError) as raised:
        ContentFilter.parse(expression, parameters).bind(SuiteShapeType)
    assert raised.value.position == position, str(raised.value)
    assert str(raised.value).startswith(f"position {position}: ")
    assert message in str(raised.value)
    assert "\n" not in str(raised.value)


def test_errors_in_nested_members() -> None:
    for expression, message in (("objects = 1", "objects is a sequence"),
                                ("timestamp = 1", "timestamp is a struct (POSIXTimestamp)"),
                                ("objects[0].classification = FOO", "'FOO' is not an enumerator of"),
                                ("objects[0].position.x = 1", "objects[0].position is a sequence")):
        with pytest.raises(FilterError, match=re.escape(message)):
            ContentFilter.parse(expression).bind(VisionSensor)


def circle(color: str, x: int) -> ShapeType:
    return ShapeType(color=color, x=x, y=100, shapesize=30)


RELIABLE_KEEP_ALL = (Policy.Reliability.Reliable(max_blocking_time=100_000_000), Policy.History.KeepAll)


def test_filtered_reader_returns_matching_data_and_the_end_of_seen_instances(bus: Databus) -> None:
    predicate = ContentFilter.parse("color LIKE %0 AND x < 100", ["'RED%'"]).bind(ShapeType)
    reader = bus.reader("Circle", ShapeType, "Shapes", content_filter=predicate, overrides=RELIABLE_KEEP_ALL)
    raw = FilteredRawReader(bus.reader("Circle", ShapeType, "Shapes", overrides=RELIABLE_KEEP_ALL), predicate)
    writer = bus.writer("Circle", ShapeType, "Shapes")
    wait_until(lambda: len(matched_subscriptions(writer)) == 2, what="both readers matched")
    for number, x in enumerate((10, 200, 20)):
        writer.write(circle(f"RED{number}", x))
        writer.write(circle(f"BLUE{number}", x))
    received = take_samples(reader, 2)
    assert [(sample.color, sample.x) for sample in received] == [("RED0", 10), ("RED2", 20)]
    assert reader.filtered_out == 4
    writer.dispose(circle("BLUE0", 0))  # its data never reached the application: its end does not either
    writer.dispose(circle("RED1", 0))  # nor this one's (x = 200)
    writer.dispose(circle("RED0", 0))
    ended: list[Any] = []
    wait_until(lambda: bool(ended.extend(reader.take(N=10)) or ended), what="the disposal")
    assert [(sample.key_sample.color, sample.sample_info.valid_data) for sample in ended] == [("RED0", False)]
    raw_samples: list[Any] = []
    wait_until(lambda: bool(raw_samples.extend(raw.take()) or any(s.kind is SampleKind.DISPOSE for s in raw_samples)),
               what="the raw reader's disposal")
    # Taken after the disposal: RED0's data carries the disposal (one more sample), as RawReader takes them.
    assert sorted((sample.kind.value, ShapeType.deserialize(bytes(sample.data)).color) for sample in raw_samples) == [
        ("data", "RED0"), ("data", "RED2"), ("dispose", "RED0")]
    assert raw.filtered_out == 4


def test_take_returns_n_matches_when_they_are_there(bus: Databus) -> None:
    """A take of N returns N matching samples even when many more that do not match came first."""
    predicate = ContentFilter.parse("x >= 300").bind(ShapeType)
    reader = bus.reader("Circle", ShapeType, "Shapes", content_filter=predicate, overrides=RELIABLE_KEEP_ALL)
    writer = bus.writer("Circle", ShapeType, "Shapes")
    wait_until(lambda: bool(matched_subscriptions(writer)), what="the reader matched")
    for x in range(310):
        writer.write(circle("RED", x))  # one instance, taken in the order written (the reader keeps 256 instances)
    assert isinstance(reader, FilteredReader)
    wait_until(lambda: len(CheckedReader.read(reader, N=1000)) >= 310, what="every sample arrived")  # unfiltered
    taken = reader.take(N=5)
    assert [sample.x for sample in taken] == [300, 301, 302, 303, 304]
    assert reader.filtered_out == 300


def test_filtered_readers_still_leave_out_bad_samples(bus: Databus, capfd: pytest.CaptureFixture[str]) -> None:
    """The filter comes after CheckedReader's checks: a circle far off the canvas (x = 5000, it matches x > 100)
    is reported and left out by the typed and the raw filtered readers alike."""
    predicate = ContentFilter.parse("x > 100").bind(ShapeType)
    reader = bus.reader("Circle", ShapeType, "Shapes", content_filter=predicate, overrides=RELIABLE_KEEP_ALL)
    raw = FilteredRawReader(bus.reader("Circle", ShapeType, "Shapes", overrides=RELIABLE_KEEP_ALL), predicate)
    # A plain DataWriter: the bus's own writers are not where a bad sample comes from
    writer: DataWriter[ShapeType] = DataWriter(bus.participant, bus.topic("Circle", ShapeType))
    wait_until(lambda: len(matched_subscriptions(writer)) == 2, what="both readers matched")
    writer.write(circle("FAR", 5000))
    writer.write(circle("RED", 200))
    writer.write(circle("BLUE", 50))
    received = take_samples(reader, 1)
    assert [(sample.color, sample.x) for sample in received] == [("RED", 200)]
    raw_samples: list[Any] = []
    # BLUE, written last, has been tested once filtered_out counts it
    wait_until(lambda: bool(raw_samples.extend(raw.take()) or raw.filtered_out), what="the raw reader's samples")
    assert [ShapeType.deserialize(bytes(sample.data)).color for sample in raw_samples] == ["RED"]
    # left out by the raw reader's own checks (or, with the fast paths' gate closed, by the checked take under it)
    assert raw.bad in (0, 1) and raw.filtered_out == 1
    assert reader.take(N=10) == [] and isinstance(reader, FilteredReader) and reader.filtered_out == 1



def test_a_disposal_that_comes_with_a_sample_the_filter_leaves_out_still_arrives(bus: Databus) -> None:
    """RED matched once; then comes a sample that does not match, and the disposal lands on it while it is unread
    (Cyclone then keeps no sample of its own for the disposal): the end of RED still reaches the application."""
    predicate = ContentFilter.parse("x < 100").bind(ShapeType)
    reader = bus.reader("Circle", ShapeType, "Shapes", content_filter=predicate, overrides=RELIABLE_KEEP_ALL)
    writer = bus.writer("Circle", ShapeType, "Shapes")
    wait_until(lambda: bool(matched_subscriptions(writer)), what="the reader matched")
    writer.write(circle("RED", 10))
    assert [sample.color for sample in take_samples(reader, 1)] == ["RED"]
    writer.write(circle("RED", 200))
    writer.dispose(circle("RED", 200))
    writer.write(circle("SENTINEL", 20))  # same writer, in order: once its instance exists, RED's disposal is there
    # lookup_instance leaves the samples unread (a read would mark them and make Cyclone add a sample of its own)
    wait_until(lambda: reader.lookup_instance(circle("SENTINEL", 0)) != 0, what="the sentinel's instance")
    taken = reader.take(N=10)
    assert [(type(sample).__name__, sample.sample_info.valid_data, sample.sample_info.instance_state)
            for sample in taken] == [("InvalidSample", False, InstanceState.NotAliveDisposed),
                                     ("ShapeType", True, InstanceState.Alive)]
    assert taken[0].key_sample.color == "RED" and taken[1].color == "SENTINEL"
    assert isinstance(reader, FilteredReader) and reader.filtered_out == 1


def test_a_filtered_reader_of_numpy_views(bus: Databus) -> None:
    """A filter on a reader that gives numpy views (as sensor_fusion's): its elements are numpy records, the enum a
    plain number, and a member named as a numpy attribute (size) is the member."""
    predicate = ContentFilter.parse("objects[0].classification = CLASSIFICATION_CAR AND objects[0].size[2] > 2.4"
                                    ).bind(VisionSensor)
    reader = bus.reader("VisionTopic", VisionSensor, "Vision", content_filter=predicate, overrides=RELIABLE_KEEP_ALL)
    assert isinstance(reader, FilteredReader)
    reader.use_views()
    raw = FilteredRawReader(bus.reader("VisionTopic", VisionSensor, "Vision", overrides=RELIABLE_KEEP_ALL), predicate)
    writer = bus.writer("VisionTopic", VisionSensor, "Vision", overrides=RELIABLE_KEEP_ALL)
    wait_until(lambda: len(matched_subscriptions(writer)) == 2, what="both readers matched")
    writer.write(dataclasses.replace(VISION, id=4, objects=[dataclasses.replace(
        VISION.objects[0], classification=ClassificationEnum.CLASSIFICATION_BIKE)]))
    writer.write(dataclasses.replace(VISION, id=5))
    taken = take_samples(reader, 1)
    assert [sample.id for sample in taken] == [5]
    assert isinstance(taken[0].objects, np.ndarray) and taken[0].objects["size"][0, 2] == 2.5
    assert reader.filtered_out == 1  # the same writer's earlier sample was taken first
    raw_samples: list[Any] = []
    wait_until(lambda: bool(raw_samples.extend(raw.take()) or (raw_samples and raw.filtered_out == 1)),
               what="the raw reader's samples")
    assert [VisionSensor.deserialize(bytes(sample.data)).id for sample in raw_samples] == [5]
    assert raw.bad == 0


def test_sensor_fusion_with_a_filter_on_its_vision_views(apps: Any, domain_id: int, bus: Databus) -> None:
    """sensor_fusion reads the vision objects as numpy views; a --filter on them works (it raised on every take)."""
    fusion = apps.start("sensor_fusion", "--domain", str(domain_id), "-D", "config.mode=event",
                        "--filter", "VisionTopic=objects[0].classification = CLASSIFICATION_CAR")
    writer = bus.writer("VisionTopic", VisionSensor, "Vision")
    wait_until(lambda: bool(matched_subscriptions(writer)), TIMEOUT, "sensor_fusion's reader")
    # Event mode fuses what each wake-up takes: one list may hold samples of several sensors ("of sensor(s) 7,8").
    def listed(sensor: int) -> str:
        return (r"published list \d+: \d+ object\(s\) from \d+ vision sample\(s\) of sensor\(s\) "
                rf"([\d,]*,)?{sensor}(,|$)")

    first = listed(7)

    def written() -> bool:  # a reader may not know a writer it matched yet: written until it arrives
        writer.write(dataclasses.replace(VISION, id=7))
        return fusion.count(first) > 0

    wait_until(written, TIMEOUT, "the first fused list")
    writer.write(dataclasses.replace(VISION, id=3, objects=[dataclasses.replace(
        VISION.objects[0], classification=ClassificationEnum.CLASSIFICATION_BIKE)]))
    writer.write(dataclasses.replace(VISION, id=8))
    fusion.wait_for(listed(8), TIMEOUT)
    assert fusion.count(listed(3)) == 0
    assert fusion.process.poll() is None, fusion.output[-3000:]
    assert fusion.stop() == 0 and "Traceback" not in fusion.output, fusion.output[-3000:]

# -- the applications' --filter and config.filter.<Topic> ------------------------------------------------------------
@pytest.mark.parametrize("app,args,pattern", [
    ("lidar", ["--filter", "Circle=colour = 'RED'"],
     r"--filter Circle: position 1: ShapeType has no member 'colour' in \"colour = 'RED'\""),
    ("lidar", ["--filter", "Circle=x >> 1"], r"--filter Circle: position 4: unexpected '>'"),
    ("lidar", ["--filter", "Nowhere=x > 1"], r"--filter Nowhere: lidar reads no topic 'Nowhere' \(it reads: Circle\)"),
    ("lidar", ["--filter", "Circle"], r"--filter 'Circle': expected TOPIC=EXPRESSION"),
    ("lidar", ["-D", "config.filter.Circle=color = RED"],
     r"-D: config.filter.Circle: position 9: .*a string needs quotes: 'RED'"),
    ("record", ["--output", "/dev/null", "--overwrite", "--filter", "AlertTopic=frontCollision = 1"],
     r"--filter AlertTopic: position 18: frontCollision is a boolean \(boolean\) but 1 is a number"),
])
def test_bad_filters_end_with_one_line(apps: Any, domain_id: int, app: str, args: list[str], pattern: str) -> None:
    assert_one_line_error(apps.run(app, "--domain", str(domain_id), "--count", "1", *args),
                          rf"^{command_of(app)}: {pattern}")


def test_lidar_sees_only_the_circles_its_filter_accepts(apps: Any, domain_id: int) -> None:
    domain = ["--domain", str(domain_id)]
    lidar = apps.start("lidar", *domain, "--filter", "Circle=color = 'RED' OR shapesize > 70",
                       "-D", "config.logEvery=5")
    red = apps.start("shapes", "publish", "--color", "RED", *domain)
    blue = apps.start("shapes", "publish", "--color", "BLUE", *domain)
    big_green = apps.start("shapes", "publish", "--color", "GREEN", "--shapesize", "80", *domain)
    lidar.wait_for(r"shape RED appeared", TIMEOUT)
    lidar.wait_for(r"shape GREEN appeared", TIMEOUT)
    for shapes in (red, blue, big_green):
        shapes.wait_for(r"\[Circle\] writer matched a reader", TIMEOUT)
    blue.wait_for(r"Circle BLUE at \(", TIMEOUT, count=2)  # BLUE has written since it matched the lidar...
    lidar.wait_for_more(r"lidar debug: frame \d+:", 2, TIMEOUT)  # ... and the lidar has taken its circles since
    assert "shape BLUE" not in lidar.output


def test_record_with_a_filter_records_only_what_it_accepts(apps: Any, domain_id: int, tmp_path: Path) -> None:
    from mcap.reader import make_reader

    output = tmp_path / "red.mcap"
    domain = ["--domain", str(domain_id)]
    recorder = apps.start("record", *domain, "--output", str(output), "--topics", "Circle",
                          "--filter", "Circle=color LIKE 'R%'")
    recorder.wait_for(r"recording 1 topic", TIMEOUT)
    red = apps.start("shapes", "publish", "--color", "RED", *domain)
    blue = apps.start("shapes", "publish", "--color", "BLUE", *domain)
    for shapes in (red, blue):
        shapes.wait_for(r"\[Circle\] writer matched a reader", TIMEOUT)
    blue.wait_for(r"Circle BLUE at \(", TIMEOUT, count=2)
    recorder.wait_for(r"Circle=([3-9]|\d\d+)/", TIMEOUT)  # some RED circles recorded
    recorder.wait_for_more(r"record: recorded=", 2, TIMEOUT)
    assert recorder.stop(signal.SIGINT) == 0
    summary = recorder.wait_for(r"summary Circle: ", 5)
    filtered = int(re.search(r"filtered_out=(\d+)", summary).group(1))  # type: ignore[union-attr]
    assert filtered > 0, summary
    with open(output, "rb") as stream:
        colors = {ShapeType.deserialize(message.data).color
                  for _, channel, message in make_reader(stream).iter_messages() if channel.topic == "Circle"}
    assert colors == {"RED"}


def test_the_shape_command_refuses_a_bad_filter() -> None:
    result = subprocess.run(program_command("shape_main", "-S", "-t", "Square", "-d", "5", "--cft",
                                            "shapesize <= twenty"), capture_output=True, text=True, cwd=ROOT,
                            timeout=60)
    assert_one_line_error(result, r"^automotive shape-main: --cft 'shapesize <= twenty': position 14: ShapeType has "
                                  r"no member 'twenty'")
    assert "failed to create content filtered topic" in result.stdout  # what the OMG suite's runner waits for
