"""The generated codecs: byte for byte Cyclone's own serializer for every type, both ways, XCDR1 and XCDR2, both byte
orders; random (seeded) and edge values; bounds; malformed input; numpy views; the hook into Cyclone and its gate.

The reference is always Cyclone DDS Python's serializer as the applications use it without the codecs (with
automotive.cyclone.fastpath, which moves octet members as one block): ``cyclone()`` turns the codecs' hook off
meanwhile.
"""

# No "from __future__ import annotations": cyclonedds resolves the annotations of the IDL classes below itself.
import importlib.util
import logging
import math
import random
import struct
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, fields, is_dataclass
from enum import auto
from pathlib import Path
from typing import Any

import cyclonedds.idl.annotations as annotate
import cyclonedds.idl.types as types
import numpy as np
import pytest
from cyclonedds._clayer import ddspy_take
from cyclonedds.core import InstanceState, SampleState, ViewState
from cyclonedds.idl import IdlEnum, IdlStruct
from cyclonedds.idl._support import Endianness
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from dds_helpers import take_samples, wait_until

from automotive.bus.endpoints import Databus
from automotive.cyclone import bounds, codec_hook, codecgen, fastpath
from automotive.cyclone.bounds import BoundError
from automotive.cyclone.codecs import Codec, CodecError, codec_for, codecs
from automotive.cyclone.matched import matched_publications, matched_subscriptions
from automotive.types.Alerts import DriverAlerts
from automotive.types.Common import ClassificationEnum, POSIXTimestamp
from automotive.types.Sensor import SENSOR_OBJECT_LIST_MAX_SIZE, RangeModeEnum, SensorObject, SensorObjectList
from automotive.types.sensor_msgs.msg.dds_ import POINT_CLOUD_MAX_DATA, PointCloud2_
from automotive.types.Vision import VisionObject, VisionSensor
from automotive.wire.rawsample import RawReader

ALL_TYPES = sorted(codecs(), key=lambda cls: cls.__idl_typename__)
REPRESENTATIONS = [(False, False), (False, True), (True, False), (True, True)]
REPRESENTATION_IDS = ["xcdr1-le", "xcdr1-be", "xcdr2-le", "xcdr2-be"]


@pytest.fixture(autouse=True, scope="module")
def hook_on() -> Iterator[None]:
    fastpath.enable()
    assert codec_hook.enable()
    yield


@contextmanager
def cyclone() -> Iterator[None]:
    """Cyclone's own serializer (and automotive.cyclone.fastpath) for the duration."""
    codec_hook.disable()
    try:
        yield
    finally:
        codec_hook.enable()


def cyclone_encode(sample: Any, xcdr2: bool, big: bool) -> bytes:
    with cyclone():
        return sample.serialize(use_version_2=xcdr2, endianness=Endianness.Big if big else Endianness.Little)


def cyclone_decode(data_type: type, data: bytes) -> Any:
    with cyclone():
        return data_type.deserialize(data)


def same(a: Any, b: Any, path: str = "") -> None:
    """Equal, with the same Python types (a list stays a list, an enum an enum), NaN equal to NaN."""
    assert type(a) is type(b), f"{path}: {type(a).__name__} != {type(b).__name__}"
    if is_dataclass(a):
        for f in fields(a):
            same(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
    elif isinstance(a, list):
        assert len(a) == len(b), f"{path}: {len(a)} != {len(b)} elements"
        for index, (x, y) in enumerate(zip(a, b)):
            same(x, y, f"{path}[{index}]")
    elif isinstance(a, float) and math.isnan(a):
        assert math.isnan(b), path
    else:
        assert a == b, f"{path}: {a!r} != {b!r}"


# --- random and edge values, from the same model the generator reads ------------------------------------------------

INT_RANGES = {"b": 8, "h": 16, "i": 32, "q": 64}
FLOAT_EDGES = [0.0, -0.0, math.inf, -math.inf, math.nan, 1e-45, 3.4028234663852886e38, -1.5]
TEXT = "abcxyz ABC019_-éü€✓😀"


class Values:
    """Values of a type's members: random (seeded), or at the edges ('empty' and 'full' bounds, extreme numbers)."""

    def __init__(self, seed: int, edge: str | None = None):
        self.random = random.Random(seed)
        self.edge = edge  # None, "empty", "full", "extreme"

    def length(self, bound: int | None, cap: int) -> int:
        if self.edge == "empty":
            return 0
        if self.edge == "full" and bound:
            return bound
        return self.random.randint(0, min(bound or cap, cap))

    def prim(self, node: codecgen.Prim) -> Any:
        rnd = self.random
        if node.code == "?":
            return rnd.random() < 0.5
        if node.code in "fd":
            if self.edge == "extreme" or rnd.random() < 0.1:
                return rnd.choice(FLOAT_EDGES)
            return struct.unpack("<f", struct.pack("<f", rnd.uniform(-1e4, 1e4)))[0] if node.code == "f" \
                else rnd.uniform(-1e300, 1e300)
        bits = node.size * 8
        low, high = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if node.code in INT_RANGES else (0, (1 << bits) - 1)
        if self.edge == "extreme":
            return rnd.choice([low, high])
        return rnd.randint(low, high)

    def value(self, node: Any) -> Any:
        rnd = self.random
        if isinstance(node, codecgen.Prim):
            return self.prim(node)
        if isinstance(node, codecgen.EnumNode):
            members = list(node.cls)
            if self.edge == "extreme":  # the first, the last, and numbers the enum does not define
                return rnd.choice([members[0], members[-1], len(members), 2**32 - 1])
            return rnd.choice(members)
        if isinstance(node, codecgen.Str):
            return "".join(rnd.choice(TEXT) for _ in range(self.length(node.bound, 12)))
        if isinstance(node, codecgen.OctetArray):
            return bytes(rnd.getrandbits(8) for _ in range(min(node.length, 4096))) + bytes(max(node.length - 4096, 0))
        if isinstance(node, codecgen.OctetSeq):
            bound = node.bound or (POINT_CLOUD_MAX_DATA if self.edge == "full" else 0)
            return bytes(rnd.getrandbits(8) for _ in range(self.length(bound or None, 64)))
        if isinstance(node, codecgen.PrimArray):
            return [self.prim(node.prim) for _ in range(node.length)]
        if isinstance(node, codecgen.PrimSeq):
            return [self.prim(node.prim) for _ in range(self.length(node.bound, 6))]
        if isinstance(node, codecgen.StructNode):
            return self.struct(node.model)
        if isinstance(node, codecgen.StructArray):
            return [self.struct(node.model) for _ in range(node.length)]
        if isinstance(node, codecgen.StructSeq):
            return [self.struct(node.model) for _ in range(self.length(node.bound, 4))]
        raise AssertionError(node)

    def struct(self, model: codecgen.Model) -> Any:
        return model.cls(**{name: self.value(node) for name, node in model.members})


MODELS = codecgen.Models()


def samples(data_type: type, count: int = 12) -> list[tuple[str, Any]]:
    model = MODELS.model(data_type)
    seed = sum(map(ord, data_type.__idl_typename__))
    made = [(f"random{i}", Values(seed + i).struct(model)) for i in range(count)]
    made += [(edge, Values(seed, edge).struct(model)) for edge in ("empty", "full", "extreme")]
    return made


# --- byte for byte, both ways ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("xcdr2,big", REPRESENTATIONS, ids=REPRESENTATION_IDS)
@pytest.mark.parametrize("data_type", ALL_TYPES, ids=lambda t: t.__idl_typename__)
def test_same_bytes_as_cyclone_both_ways(data_type: type, xcdr2: bool, big: bool) -> None:
    codec = codec_for(data_type)
    assert codec is not None
    for name, sample in samples(data_type, count=4 if data_type.__name__.startswith("CameraImage") else 12):
        reference = cyclone_encode(sample, xcdr2, big)
        ours = codec.encode(sample, xcdr2, big)
        assert ours == reference, f"{name}: encoded differently"
        same(codec.decode(reference), cyclone_decode(data_type, reference), name)  # Cyclone's bytes, read by us
        same(cyclone_decode(data_type, ours), codec.decode(ours), name)  # ours, read by Cyclone


@pytest.mark.parametrize("data_type", ALL_TYPES, ids=lambda t: t.__idl_typename__)
def test_default_representation_is_cyclones(data_type: type) -> None:
    codec = codec_for(data_type)
    assert codec is not None
    data_type.__idl__.populate()
    assert codec.default_xcdr2 == (data_type.__idl__.default_version == 2)
    sample = samples(data_type, 1)[0][1]
    assert codec.encode(sample) == cyclone_encode(sample, codec.default_xcdr2, sys.byteorder == "big")


def test_every_struct_type_of_the_idl_has_a_codec() -> None:
    declared = set(codecgen.struct_types("automotive.types"))
    assert declared == set(codecs())
    assert len(declared) == 26  # automotive.idl's 25 (diagnostic_msgs' 3 among them) and shape.idl's ShapeType
    generated = Path(codecgen.__file__).parents[1] / "types" / "codecs.py"
    assert generated.read_text().count("    def e1_ShapeType") == 2, "the two ShapeTypes need functions of their own"


# --- XCDR2 appendable: another version of the type on the wire -------------------------------------------------------

def with_dheader(body: bytes, size: int) -> bytes:
    return b"\x00\x09\x00\x00" + struct.pack("<I", size) + body


@pytest.mark.parametrize("size", range(0, 7))
def test_shorter_appendable_takes_defaults_as_cyclone_does(size: int) -> None:
    codec = codec_for(DriverAlerts)
    data = with_dheader(bytes([1, 1, 1, 1, 1, 1])[:size], size)
    same(codec.decode(data), cyclone_decode(DriverAlerts, data))


def test_longer_appendable_skips_the_members_it_does_not_know() -> None:
    sample = SensorObjectList(timestamp=POSIXTimestamp(s=5, ns=6), objects=[])
    known = codec_for(SensorObjectList).encode(sample, xcdr2=True)
    size = struct.unpack_from("<I", known, 4)[0]
    longer = known[:4] + struct.pack("<I", size + 8) + known[8:] + b"\x07" * 8
    same(codec_for(SensorObjectList).decode(longer), cyclone_decode(SensorObjectList, longer))
    same(codec_for(SensorObjectList).decode(longer), sample)


def test_shorter_nested_appendable_in_a_sequence_of_a_point_cloud() -> None:
    """Header_ (appendable, inside PointCloud2_) one member short: its frame id takes the default."""
    header_only_stamp = struct.pack("<II", 12, 8) + struct.pack("<iI", 12, 34)  # Time_ has its DHEADER too
    rest = struct.pack("<II", 1, 2) + struct.pack("<II", 4, 0) + b"\x01\x00\x00\x00" + struct.pack("<II", 16, 32)
    rest += struct.pack("<I", 3) + b"abc" + b"\x01"
    body = header_only_stamp + rest
    data = with_dheader(body, len(body))
    same(codec_for(PointCloud2_).decode(data), cyclone_decode(PointCloud2_, data))
    assert codec_for(PointCloud2_).decode(data).header_.frame_id_ == ""


# --- malformed input -------------------------------------------------------------------------------------------------

# The large types take seconds: in the full suite only, not the fast tier.
@pytest.mark.parametrize("data_type", [
    pytest.param(t, marks=pytest.mark.not_fast) if t.__idl_typename__.startswith(("Lidar.", "CameraImage.")) else t
    for t in ALL_TYPES], ids=lambda t: t.__idl_typename__)
def test_malformed_input_raises_codec_error_only(data_type: type) -> None:
    """Every truncation and random corruptions of valid samples: a CodecError or a sample, nothing else."""
    codec = codec_for(data_type)
    rnd = random.Random(7)
    for name, sample in samples(data_type, 2):
        if data_type.__name__.startswith("CameraImage") and name != "random0":
            continue
        for xcdr2 in (False, True):
            good = codec.encode(sample, xcdr2)
            # A full point cloud (360 kB) takes 60 ms to decode: 20 tries of each kind there, not 200 (what its
            # points hold is the same from one point to the next; the lengths and headers are tried on every size)
            tries = 200 if len(good) < 100_000 else 20
            cuts = range(len(good)) if len(good) < 2000 else rnd.sample(range(len(good)), tries)
            for cut in cuts:
                try:
                    codec.decode(good[:cut])
                except CodecError as error:
                    assert codec.label in str(error) and "\n" not in str(error)
            for _ in range(tries):
                broken = bytearray(good)
                for _ in range(rnd.randint(1, 4)):
                    broken[rnd.randrange(len(broken))] = rnd.getrandbits(8)
                try:
                    codec.decode(bytes(broken))
                except CodecError:
                    pass


@pytest.mark.parametrize("data", [b"", b"\x00\x01", "text", None, 5, b"\x00\x01\x00\x00\xff\xff\xff\xff"],
                         ids=["empty", "header cut", "str", "None", "int", "huge count"])
def test_not_a_sample_is_one_clear_error(data: Any) -> None:
    with pytest.raises(CodecError, match=r"^Vision::VisionSensor: "):
        codec_for(VisionSensor).decode(data)


def test_length_over_the_idl_bound_is_refused_when_reading() -> None:
    sample = VisionSensor(id=1, timestamp=POSIXTimestamp(s=1, ns=2), objects=[])
    data = bytearray(codec_for(VisionSensor).encode(sample, xcdr2=False))
    struct.pack_into("<I", data, 16, 11)
    data += bytes(11 * 40)
    with pytest.raises(CodecError, match="Vision::VisionSensor.objects: 11 elements announced, over its IDL bound"):
        codec_for(VisionSensor).decode(bytes(data))


# --- bounds on writing -----------------------------------------------------------------------------------------------

def vision_object(i: int) -> VisionObject:
    return VisionObject(classification=ClassificationEnum(i % 8), position=[float(i), 1.0, 2.0],
                        velocity=[0.0, 1.0, 2.0], size=[1.0, 2.5 + i, 1.0])


def sensor_object(i: int) -> SensorObject:
    return SensorObject(classification=ClassificationEnum(i % 8), position=[float(i), 2.0, 0.0],
                        velocity=[1.0, 2.0, 3.0], size=[1.0, 2.5, 3.0], amplitude=0.75, rangeMode=RangeModeEnum(i % 4),
                        rangeRate=-1.25)


OVER_BOUND = {
    "Vision::VisionSensor.objects": VisionSensor(id=1, timestamp=POSIXTimestamp(s=1, ns=2),
                                                 objects=[vision_object(0)] * 11),
    "Sensor::SensorObjectList.objects": SensorObjectList(timestamp=POSIXTimestamp(s=1, ns=2),
                                                         objects=[sensor_object(0)] * 129),
}


@pytest.mark.parametrize("member", sorted(OVER_BOUND))
def test_over_bound_raises_the_bound_error_of_bounds_check(member: str) -> None:
    sample = OVER_BOUND[member]
    with pytest.raises(BoundError) as expected:
        bounds.check(sample)
    for xcdr2 in (False, True):
        with pytest.raises(BoundError) as error:
            codec_for(type(sample)).encode(sample, xcdr2)
        assert str(error.value) == str(expected.value)
        with pytest.raises(BoundError) as error:  # Cyclone's serialize, through the hook
            sample.serialize(use_version_2=xcdr2)
        assert str(error.value) == str(expected.value)


def test_a_sample_the_codec_refuses_has_its_bounds_checked_before_cyclones_serializer(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Writers leave a codec's type's bounds to the codec (automotive.bus.endpoints.CheckedWriter); a sample the
    codec refuses goes to Cyclone's serializer, and its bounds are checked on the way, with the same message."""
    sample = OVER_BOUND["Vision::VisionSensor.objects"]
    codec = codec_for(VisionSensor)

    def refuse(*args: object, **kwargs: object) -> bytes:
        raise CodecError("Vision::VisionSensor: cannot encode (refused for the test)")

    monkeypatch.setattr(codec, "encode", refuse)
    with pytest.raises(BoundError, match=r"^Vision::VisionSensor.objects holds 11 elements, over its IDL bound of 10$"):
        sample.serialize()


def test_full_bound_is_accepted_and_extra_bounds_apply() -> None:
    full = SensorObjectList(timestamp=POSIXTimestamp(s=1, ns=2),
                            objects=[sensor_object(i) for i in range(SENSOR_OBJECT_LIST_MAX_SIZE)])
    assert codec_for(SensorObjectList).encode(full, False) == cyclone_encode(full, False, sys.byteorder == "big")
    six = VisionSensor(id=1, timestamp=POSIXTimestamp(s=1, ns=2), objects=[vision_object(0)] * 6)
    try:
        bounds.set_extra_bound(VisionSensor, "objects", 5)
        with pytest.raises(BoundError, match="holds 6 elements, over its IDL bound of 5"):
            codec_for(VisionSensor).encode(six)
    finally:
        del bounds.EXTRA_BOUNDS[(VisionSensor, "objects")]
        bounds._plan.cache_clear()
    codec_for(VisionSensor).encode(six)
    cloud = samples(PointCloud2_, 1)[0][1]
    cloud.data_ = bytes(POINT_CLOUD_MAX_DATA + 1)
    with pytest.raises(BoundError, match="data_ holds 368641 elements, over its IDL bound of 368640"):
        codec_for(PointCloud2_).encode(cloud)


def test_values_cyclone_refuses_are_refused() -> None:
    codec = codec_for(SensorObject)
    bad = [sensor_object(1) for _ in range(5)]
    bad[0].position = [1.0, 2.0]  # an array of the wrong length
    bad[1].amplitude = "loud"
    bad[2].classification = True  # not an int, not an enum member
    bad[3].rangeMode = -1
    bad[4].rangeRate = 1e39  # out of float32's range
    for sample in bad:
        with pytest.raises(CodecError, match=r"^Sensor::SensorObject: cannot encode"):
            codec.encode(sample)
        with pytest.raises(Exception):  # noqa: B017 - through the hook, Cyclone's own error
            sample.serialize()


# --- numpy views -----------------------------------------------------------------------------------------------------

def test_views_are_read_only_numpy_arrays_over_the_sample() -> None:
    codec = codec_for(SensorObjectList)
    sample = SensorObjectList(timestamp=POSIXTimestamp(s=1, ns=2), objects=[sensor_object(i) for i in range(128)])
    for xcdr2 in (False, True):
        for big in (False, True):
            data = codec.encode(sample, xcdr2, big)
            viewed = codec.decode(data, views=True)
            objects = viewed.objects
            assert isinstance(objects, np.ndarray) and objects.shape == (128,) and not objects.flags.writeable
            assert np.shares_memory(objects, np.frombuffer(data, np.uint8))
            assert objects.dtype.names == codec.element_dtype("objects").names
            assert objects["classification"].tolist() == [o.classification.value for o in sample.objects]
            assert objects["position"].tolist() == [o.position for o in sample.objects]
            assert objects["size"][:, 1].tolist() == [2.5] * 128
            assert objects["rangeMode"].tolist() == [o.rangeMode.value for o in sample.objects]
            same(viewed.timestamp, sample.timestamp)
            # a numpy array encodes as its elements do
            assert codec.encode(SensorObjectList(timestamp=sample.timestamp, objects=objects), xcdr2, big) == data
    assert codec.element_dtype("objects").itemsize == 52
    with pytest.raises(KeyError, match="timestamp is not a sequence of fixed-size structs"):
        codec.element_dtype("timestamp")


def test_numpy_arrays_of_another_dtype_are_converted_or_refused() -> None:
    codec = codec_for(VisionSensor)
    dtype = codec.element_dtype("objects")
    aligned = np.zeros(3, dtype=np.dtype([(name, dtype.fields[name][0]) for name in dtype.names], align=True))
    aligned["classification"] = [1, 2, 3]
    aligned["size"][:, 1] = 2.5
    as_objects = [VisionObject(classification=ClassificationEnum(c), position=[0.0] * 3, velocity=[0.0] * 3,
                               size=[0.0, 2.5, 0.0]) for c in (1, 2, 3)]
    stamp = POSIXTimestamp(s=1, ns=2)
    assert codec.encode(VisionSensor(id=4, timestamp=stamp, objects=aligned)) == \
        codec.encode(VisionSensor(id=4, timestamp=stamp, objects=as_objects))
    with pytest.raises(CodecError, match="expected a structured array with fields"):
        codec.encode(VisionSensor(id=4, timestamp=stamp, objects=np.zeros(3, dtype=[("x", "f4")])))


# --- the hook into Cyclone -------------------------------------------------------------------------------------------

def test_hook_covers_every_type_without_octet_blocks() -> None:
    for data_type, codec in codecs().items():
        assert codec_hook.installed(data_type) == (not codec.has_octet_blocks)
    assert {f"{t.__module__}.{t.__name__}" for t, c in codecs().items() if c.has_octet_blocks} == {
        "automotive.types.sensor_msgs.msg.dds_._automotive.PointCloud2_", *(
            f"automotive.types.CameraImage._automotive.{name}"
            for name in ("CameraImageData", "CameraImageData_64KiB", "CameraImageData_1MiB", "CameraImageData_4MiB")),
        "automotive.types.shape.ShapeType"}  # the OMG suite's: its additional payload is a sequence of octets


def test_keys_still_go_through_cyclone() -> None:
    sample = VisionSensor(id=42, timestamp=POSIXTimestamp(s=1, ns=2), objects=[vision_object(1)])
    key = sample.serialize_key()
    with cyclone():
        assert key == sample.serialize_key()
        assert VisionSensor.deserialize_key(key).id == 42
    assert VisionSensor.deserialize_key(key).id == 42


def test_gate_refuses_an_untested_cyclone_with_one_line(monkeypatch: pytest.MonkeyPatch,
                                                        caplog: pytest.LogCaptureFixture) -> None:
    codec_hook.disable()
    try:
        monkeypatch.setattr(codec_hook.gate, "cyclone_version", lambda: "12.0.0")
        monkeypatch.setattr(codec_hook, "_refused", None)
        log = logging.getLogger("test-gate")
        with caplog.at_level(logging.WARNING, logger="test-gate"):
            assert not codec_hook.enable(log)
            assert not codec_hook.enable(log)
        assert [r.getMessage() for r in caplog.records] == [
            "codecs: cyclonedds 12.0.0 is not the tested 11.0.1; Cyclone's serializer is used"]
        assert not codec_hook.enabled() and not codec_hook.installed(VisionSensor)
        monkeypatch.setenv("AUTOMOTIVE_CODECS", "off")
        monkeypatch.setattr(codec_hook.gate, "cyclone_version", lambda: "11.0.1")
        assert not codec_hook.enable(log)
    finally:
        monkeypatch.undo()
        assert codec_hook.enable()


def test_writers_and_readers_use_the_codecs_over_dds(bus: Databus, monkeypatch: pytest.MonkeyPatch) -> None:
    """Samples written and taken through the project's endpoints never reach Cyclone's serializer."""
    from cyclonedds.idl._machinery import StructMachine

    def refuse(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("Cyclone's serializer was used")

    writer = bus.writer("SensorObjects", SensorObjectList, "SensorFusion")
    reader = bus.reader("SensorObjects", SensorObjectList, "SensorFusion")
    wait_until(lambda: bool(matched_publications(reader)), what="the reader to match")
    monkeypatch.setattr(StructMachine, "serialize", refuse)
    monkeypatch.setattr(StructMachine, "deserialize", refuse)
    sample = SensorObjectList(timestamp=POSIXTimestamp(s=1, ns=2), objects=[sensor_object(i) for i in range(128)])
    writer.write(sample)
    [received] = take_samples(reader, 1)
    same(received, sample)
    assert received.sample_info.valid_data


@pytest.mark.parametrize("xcdr2", [False, True], ids=["xcdr1", "xcdr2"])
def test_wire_bytes_and_keys_are_cyclones(bus: Databus, xcdr2: bool) -> None:
    """What a plain writer puts on the wire (padded to 4 bytes), keyed instances and disposal, through the hook."""
    topic = bus.topic("VisionTopic", VisionSensor)
    both = Policy.DataRepresentation(use_cdrv0_representation=True, use_xcdrv2_representation=True)
    one = Policy.DataRepresentation(use_cdrv0_representation=not xcdr2, use_xcdrv2_representation=xcdr2)
    reliable = [Policy.Reliability.Reliable(10**9), Policy.History.KeepAll]
    reader = DataReader(bus.participant, topic, qos=Qos(*reliable, both))
    writer = DataWriter(bus.participant, topic, qos=Qos(*reliable, one))
    wait_until(lambda: writer.get_publication_matched_status().current_count > 0, what="writer matched")
    sent = [VisionSensor(id=i % 3, timestamp=POSIXTimestamp(s=i, ns=1), objects=[vision_object(j) for j in range(i)])
            for i in range(1, 8)]
    for sample in sent:
        writer.write(sample)
    writer.dispose(sent[0])
    raw: list[tuple[bytes, Any]] = []

    def taken(condition: Any) -> bool:
        got = ddspy_take(reader._ref, SampleState.Any | ViewState.Any | InstanceState.Any, 16)
        raw.extend((bytes(data), info) for data, info in got)
        return condition()

    wait_until(lambda: taken(lambda: sum(info.valid_data for _, info in raw) >= len(sent)), what="every sample")
    data = [(d, info) for d, info in raw if info.valid_data]
    by_time = {sample.timestamp.s: sample for sample in sent}
    for wire, _ in data:  # taken instance by instance, not in the order written
        sample = by_time[VisionSensor.deserialize(wire).timestamp.s]
        reference = cyclone_encode(sample, xcdr2, sys.byteorder == "big")
        assert wire == reference.ljust(-(-len(reference) // 4) * 4, b"\0")
        same(VisionSensor.deserialize(wire), sample)
    handles = {VisionSensor.deserialize(wire).id: info.instance_handle for wire, info in data}
    assert len(set(handles.values())) == 3  # three keys, three instances
    wait_until(lambda: taken(lambda: any(info.instance_state == InstanceState.NotAliveDisposed for _, info in raw)),
               what="the disposal")
    disposed = [info for _, info in raw if info.instance_state == InstanceState.NotAliveDisposed]
    assert {info.instance_handle for info in disposed} == {handles[sent[0].id]}


def test_raw_samples_decode_with_views(bus: Databus) -> None:
    """The per-sample decode step of a raw take: bytes -> dataclass, or numpy views."""
    writer = bus.writer("VisionTopic", VisionSensor, "Vision")
    reader = RawReader(bus.reader("VisionTopic", VisionSensor, "Vision"))
    wait_until(lambda: bool(matched_publications(reader.reader)), what="the reader to match")
    sample = VisionSensor(id=3, timestamp=POSIXTimestamp(s=1, ns=2), objects=[vision_object(i) for i in range(10)])
    writer.write(sample)
    taken: list[Any] = []
    wait_until(lambda: bool(taken.extend(reader.take())) or bool(taken), what="a raw sample")
    codec = codec_for(VisionSensor)
    same(codec.decode(taken[0].data), sample)
    viewed = codec.decode(taken[0].data, views=True)
    assert viewed.objects["size"][:, 1].tolist() == [2.5 + i for i in range(10)]


# --- the generator on constructs the IDL does not use (yet) ----------------------------------------------------------

class Colour(IdlEnum, typename="codec_test.Colour", default="RED"):
    RED = auto()
    GREEN = auto()
    BLUE = auto()


@dataclass
@annotate.final
class Inner(IdlStruct, typename="codec_test.Inner"):
    a: types.int8
    b: types.float64  # aligned to 8 in XCDR1, to 4 in XCDR2
    c: types.uint16


@dataclass
@annotate.final
class Wide(IdlStruct, typename="codec_test.Wide"):
    x: types.float64
    n: types.int32
    m: types.int32


@dataclass
@annotate.appendable
class Nested(IdlStruct, typename="codec_test.Nested"):
    name: str
    x: types.int64
    inner: Inner
    flags: types.array[bool, 3]


@dataclass
@annotate.appendable
class Everything(IdlStruct, typename="codec_test.Everything"):
    o: types.uint8
    d: types.float64
    s: types.bounded_str[8]
    q: types.int64
    inner: Inner
    nested: Nested
    inners: types.sequence[Inner, 5]
    wides: types.sequence[Wide]
    nesteds: types.sequence[Nested]
    doubles: types.sequence[types.float64]
    shorts: types.sequence[types.int16, 7]
    pair: types.array[Inner, 2]
    nested_pair: types.array[Nested, 2]
    octs: types.sequence[types.uint8]
    blob: types.array[types.uint8, 3]
    big: types.array[types.int32, 20]
    colour: Colour
    tail: types.int8


@dataclass
@annotate.mutable
class Mutable(IdlStruct, typename="codec_test.Mutable"):
    a: types.int32


@pytest.fixture(scope="module")
def generated() -> Any:
    text = codecgen.generate([Inner, Wide, Nested, Everything, Mutable], "test codecs", "tests/test_codecs.py")
    assert "#   codec_test::Mutable: mutable extensibility" in text
    spec = importlib.util.spec_from_loader("codec_test_generated", loader=None)
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    exec(compile(text, "<generated>", "exec"), module.__dict__)  # noqa: S102
    module.CODECS = {data_type: Codec(data_type, *parts) for data_type, parts in module.CODEC_PARTS.items()}
    return module


@pytest.mark.parametrize("xcdr2,big", REPRESENTATIONS, ids=REPRESENTATION_IDS)
@pytest.mark.parametrize("data_type", [Inner, Wide, Nested, Everything], ids=lambda t: t.__name__)
def test_generator_on_every_construct(generated: Any, data_type: type, xcdr2: bool, big: bool) -> None:
    codec = generated.CODECS[data_type]
    assert Mutable not in generated.CODECS
    model = codecgen.Models().model(data_type)
    for seed in range(20):
        for edge in (None, "empty", "full", "extreme"):
            sample = Values(seed, edge).struct(model)
            reference = cyclone_encode(sample, xcdr2, big)
            assert codec.encode(sample, xcdr2, big) == reference, (seed, edge)
            same(codec.decode(reference), cyclone_decode(data_type, reference))


def test_generator_refuses_what_it_cannot_mirror() -> None:
    models = codecgen.Models()
    with pytest.raises(codecgen.Unsupported, match="mutable"):
        models.model(Mutable)
    with pytest.raises(codecgen.Unsupported):
        models.node(types.sequence(types.sequence(types.int32)))


# --- numpy views through the checked reader's rules ------------------------------------------------------------------

@pytest.mark.parametrize("member,index,component", [("size", 3, 1), ("position", 0, 2), ("velocity", 9, 0)])
def test_views_are_checked_like_dataclasses(member: str, index: int, component: int) -> None:
    """A NaN in a viewed sequence of structs is the same bad sample, named the same way, as in the dataclasses."""
    from automotive.bus import validation

    objects = [vision_object(i) for i in range(10)]
    getattr(objects[index], member)[component] = math.nan
    data = codec_for(VisionSensor).encode(VisionSensor(id=1, timestamp=POSIXTimestamp(s=1, ns=2), objects=objects))
    as_dataclasses = validation.check(VisionSensor.deserialize(data))
    as_views = validation.check(codec_for(VisionSensor).decode(data, views=True))
    assert as_dataclasses is not None and as_views is not None
    assert (as_views.member, as_views.expected) == (as_dataclasses.member, as_dataclasses.expected)
    assert as_views.member == f"objects[{index}].{member}[{component}]"
    good = codec_for(VisionSensor).encode(VisionSensor(id=1, timestamp=POSIXTimestamp(s=1, ns=2),
                                                       objects=[vision_object(i) for i in range(10)]))
    assert validation.check(codec_for(VisionSensor).decode(good, views=True)) is None


@pytest.mark.parametrize("words,bad", [
    ({"count": -1, "ratio": 1.5, "range": 2.0}, None),  # -1 reads as a NaN float32 word: only a look, not a problem
    ({"count": 0x7F800000, "ratio": 0.0, "range": -0.0}, None),  # an integer with the bits of +inf
    ({"count": 3, "ratio": math.inf, "range": 2.0}, "ratio"),
    ({"count": 3, "ratio": 1.0, "range": math.nan}, "range"),  # a float64 NaN: its high word is a float32 NaN
    ({"count": 3, "ratio": 1.0, "range": 1e308}, None),  # a float64 far beyond float32's range, finite
])
@pytest.mark.parametrize("length", [3, 100])  # summed by Python (up to SMALL_ARRAY_BYTES) and by numpy
def test_struct_arrays_are_checked_in_one_sum_without_false_problems(words: dict[str, float], bad: str | None,
                                                                     length: int) -> None:
    """The one-sum look at a structured array (its words read as float32) never misses a non-finite float field and
    never reports an integer or a large float64 whose words merely look non-finite."""
    from automotive.bus import validation

    dtype = np.dtype([("count", "<i4"), ("ratio", "<f4"), ("range", "<f8"), ("pad", "<i4")])
    values = np.zeros(length, dtype)
    assert (values.nbytes <= validation.SMALL_ARRAY_BYTES) == (length == 3)
    for name, value in words.items():
        values[name][1] = value
    problem = validation._check_struct_array(values, "items")
    assert (problem.member if problem else None) == (None if bad is None else f"items[1].{bad}")
    assert validation._check_struct_array(values[::2], "items") is None  # a strided view: field by field
    # A big-endian writer's sample, viewed in its own byte order: the same verdict (its words are other numbers).
    swapped = validation._check_struct_array(values.astype(dtype.newbyteorder(">")), "items")
    assert (swapped.member if swapped else None) == (None if bad is None else f"items[1].{bad}")


def test_checked_reader_gives_views(bus: Databus) -> None:
    writer = bus.writer("VisionTopic", VisionSensor, "Vision")
    reader = bus.reader("VisionTopic", VisionSensor, "Vision")
    reader.use_views()  # type: ignore[attr-defined]
    wait_until(lambda: bool(matched_subscriptions(writer)), what="the writer to match")
    sample = VisionSensor(id=3, timestamp=POSIXTimestamp(s=1, ns=2), objects=[vision_object(i) for i in range(4)])
    writer.write(sample)
    taken = take_samples(reader, 1)
    assert isinstance(taken[0].objects, np.ndarray)
    assert taken[0].objects["size"][:, 1].tolist() == [2.5 + i for i in range(4)]
