"""The octet fast path: same bytes on the wire as Cyclone's own serializer, one block in and out, bounds enforced.

Every comparison is made against Cyclone's unmodified machines (``fastpath.disable()`` restores them), in XCDR1 and
XCDR2, both byte orders, both ways (our bytes read by Cyclone's reader, Cyclone's bytes read by ours).
"""

# No "from __future__ import annotations" here: cyclonedds resolves string annotations of the IDL classes below by
# module lookup, which fails for names like "types.uint8".
import array
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Optional

import cyclonedds.idl.annotations as annotate
import cyclonedds.idl.types as types
import numpy as np
import pytest
from cyclonedds._clayer import ddspy_take
from cyclonedds.core import InstanceState, SampleState, ViewState
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl._machinery import PlainCdrV2SequenceOfPrimitiveMachine
from cyclonedds.idl._support import Endianness
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from dds_helpers import make_bus, take_samples, wait_until

from automotive.cyclone import fastpath
from automotive.cyclone.bounds import BoundError
from automotive.types.builtin_interfaces.msg.dds_ import Time_
from automotive.types.CameraImage import CameraImageData_64KiB
from automotive.types.sensor_msgs.msg.dds_ import POINT_CLOUD_MAX_DATA, PointCloud2_, PointField_
from automotive.types.std_msgs.msg.dds_ import Header_


@dataclass
@annotate.final
class SmallOctets(IdlStruct, typename="fastpath_test.SmallOctets"):
    head: types.uint8  # the sequence's length word needs padding after it
    data: types.sequence[types.uint8, 16]
    tail: types.uint64  # aligned to 8 in XCDR1, 4 in XCDR2, after an odd number of bytes


@dataclass
@annotate.appendable
class AppendableOctets(IdlStruct, typename="fastpath_test.AppendableOctets"):
    head: types.uint16
    data: types.sequence[types.uint8]
    extra: Optional[types.sequence[types.uint8, 8]]  # noqa: UP045 - cyclonedds reads typing.Optional
    tail: types.uint32


@dataclass
@annotate.mutable
class MutableOctets(IdlStruct, typename="fastpath_test.MutableOctets"):
    data: types.sequence[types.uint8]
    chunks: types.sequence[types.sequence[types.uint8, 8], 4]
    blob: types.array[types.uint8, 5]
    tail: types.int16


def cloud(data: Any) -> PointCloud2_:
    size = data.size if isinstance(data, np.ndarray) else len(data)
    return PointCloud2_(
        header_=Header_(stamp_=Time_(sec_=12, nanosec_=34), frame_id_="lidar"), height_=1, width_=size // 16,
        fields_=[PointField_(name_=n, offset_=4 * i, datatype_=7, count_=1) for i, n in enumerate("xyz")],
        is_bigendian_=False, point_step_=16, row_step_=size, data_=data, is_dense_=True)


def small(data: Any) -> SmallOctets:
    return SmallOctets(head=0xAB, data=data, tail=0x0102030405060708)


def appendable(data: Any) -> AppendableOctets:
    return AppendableOctets(head=7, data=data, extra=bytes(data[:3]) if len(data) % 2 else None, tail=9)


def mutable(data: Any) -> MutableOctets:
    return MutableOctets(data=data, chunks=[bytes(data[:8]), b"", b"\x01"], blob=b"12345", tail=-3)


def camera(data: Any) -> CameraImageData_64KiB:
    return CameraImageData_64KiB(id=3, sec_=5, nanosec_=6, seqnum=7, data=data)


MEMBER = {PointCloud2_: "data_", SmallOctets: "data", AppendableOctets: "data", MutableOctets: "data",
          CameraImageData_64KiB: "data"}

# (sample factory, payload sizes): empty, one byte, odd, bound (or large, for unbounded test members)
CASES: dict[str, tuple[Callable[[Any], Any], list[int]]] = {
    "PointCloud2_": (cloud, [0, 1, 1001, 184_320, POINT_CLOUD_MAX_DATA]),
    "SmallOctets": (small, [0, 1, 7, 16]),
    "AppendableOctets": (appendable, [0, 1, 13, 70_001]),
    "MutableOctets": (mutable, [0, 1, 9, 4096]),
    "CameraImageData_64KiB": (camera, [65_536]),
}


def payload(size: int) -> bytes:
    return bytes((i * 7 + 3) % 256 for i in range(size))


@pytest.fixture(autouse=True, scope="module")
def fast_path_on() -> Iterator[None]:
    was_enabled = fastpath.enabled()
    fastpath.enable()
    yield
    if not was_enabled:
        fastpath.disable()


@contextmanager
def unmodified() -> Iterator[None]:
    """Cyclone's own machines for the duration."""
    fastpath.disable()
    try:
        yield
    finally:
        fastpath.enable()


def as_list(value: Any) -> list[int]:
    return list(value) if value is not None else []


CASE_PARAMS = [(name, size) for name, (_, sizes) in CASES.items() for size in sizes]


@pytest.mark.parametrize("endianness", [Endianness.Little, Endianness.Big], ids=["le", "be"])
@pytest.mark.parametrize("xcdr2", [False, True], ids=["xcdr1", "xcdr2"])
@pytest.mark.parametrize("name,size", CASE_PARAMS)
def test_same_bytes_as_the_unmodified_serializer_both_ways(name: str, size: int, xcdr2: bool,
                                                          endianness: Endianness) -> None:
    make, _ = CASES[name]
    data = payload(size)
    sample = make(data)
    data_type = type(sample)
    member = MEMBER[data_type]
    assert fastpath.uses_fast_path(data_type, member)

    fast = sample.serialize(use_version_2=xcdr2, endianness=endianness)
    with unmodified():
        assert not fastpath.uses_fast_path(data_type, member)
        reference = make(list(data)).serialize(use_version_2=xcdr2, endianness=endianness)
        read_by_cyclone = data_type.deserialize(fast)
    assert fast == reference

    read_by_us = data_type.deserialize(reference)
    assert isinstance(getattr(read_by_us, member), bytes)
    assert getattr(read_by_us, member) == data
    assert as_list(getattr(read_by_cyclone, member)) == list(data)
    # every other member decodes the same through both
    for other in data_type.__dataclass_fields__:
        if other != member:
            assert as_list_if_octets(getattr(read_by_us, other)) == as_list_if_octets(getattr(read_by_cyclone, other))


def as_list_if_octets(value: Any) -> Any:
    if isinstance(value, (bytes, bytearray)):
        return list(value)
    if isinstance(value, list) and value and isinstance(value[0], (bytes, bytearray, list)):
        return [list(v) for v in value]
    return value


def input_kinds(data: bytes) -> dict[str, Any]:
    rows = next(r for r in (7, 256, 1) if len(data) % r == 0)
    array_2d = np.frombuffer(data, dtype=np.uint8).reshape(rows, -1)
    strided = np.zeros(2 * len(data), dtype=np.uint8)
    strided[::2] = np.frombuffer(data, dtype=np.uint8)
    return {
        "bytes": data,
        "bytearray": bytearray(data),
        "memoryview": memoryview(data),
        "memoryview slice": memoryview(b"xx" + data)[2:],
        "numpy uint8": np.frombuffer(data, dtype=np.uint8).copy(),
        "numpy uint8 2-D": array_2d,
        "numpy uint8 strided": strided[::2],
        "array.array B": array.array("B", data),
        "list of ints": list(data),
        "tuple of ints": tuple(data),
        "numpy int64": np.array(list(data), dtype=np.int64),
    }


@pytest.mark.parametrize("kind", sorted(input_kinds(payload(7))))
@pytest.mark.parametrize("name,size", [("PointCloud2_", 1001), ("SmallOctets", 7), ("CameraImageData_64KiB", 65_536)])
def test_written_in_one_block_from_any_byte_buffer(name: str, size: int, kind: str) -> None:
    make, _ = CASES[name]
    data = payload(size)
    with unmodified():
        reference = make(data).serialize()
    before = fastpath.counts(type(make(data)), MEMBER[type(make(data))])
    assert make(input_kinds(data)[kind]).serialize() == reference
    after = fastpath.counts(type(make(data)), MEMBER[type(make(data))])
    assert after.writes == before.writes + 1


@pytest.mark.parametrize("value", [[1, 2, 256], [1, -1], "abc", 5, np.array([0.5], dtype=np.float32)],
                         ids=["int over 255", "negative", "str", "int", "float32"])
def test_values_that_are_not_octets_are_refused(value: Any) -> None:
    with pytest.raises(fastpath.OctetValueError) as error:
        small(value).serialize()
    assert "fastpath_test::SmallOctets.data" in str(error.value)


def test_received_buffer_is_viewed_by_numpy_without_copy() -> None:
    for sample in (cloud(payload(184_320)), camera(payload(65_536))):
        member = MEMBER[type(sample)]
        for xcdr2 in (False, True):
            received = getattr(type(sample).deserialize(sample.serialize(use_version_2=xcdr2)), member)
            view = np.frombuffer(received, dtype=np.uint8)
            assert view.base is received and not view.flags.owndata
            assert np.shares_memory(view, np.frombuffer(received, dtype=np.uint8))
            assert view.tobytes() == getattr(sample, member)


def test_bounded_sequence_over_its_bound_is_refused() -> None:
    small(payload(16)).serialize()
    for value in (payload(17), np.zeros(17, dtype=np.uint8), list(payload(17))):
        with pytest.raises(fastpath.OctetBoundError) as error:
            small(value).serialize()
        message = str(error.value)
        assert "fastpath_test::SmallOctets.data" in message and "17 bytes" in message and "bound of 16" in message
        assert isinstance(error.value, BoundError) and len(message) < 200


def test_point_cloud_over_its_max_data_is_refused_with_member_and_bound() -> None:
    cloud(payload(POINT_CLOUD_MAX_DATA)).serialize(use_version_2=False)
    for xcdr2 in (False, True):
        with pytest.raises(fastpath.OctetBoundError) as error:
            cloud(payload(POINT_CLOUD_MAX_DATA + 1)).serialize(use_version_2=xcdr2)
        message = str(error.value)
        assert "sensor_msgs::msg::dds_::PointCloud2_.data_" in message and str(POINT_CLOUD_MAX_DATA) in message
        assert len(message) < 200  # Cyclone's own wrapper would print the whole value


def test_octet_array_of_the_wrong_size_is_refused() -> None:
    with pytest.raises(fastpath.OctetValueError) as error:
        camera(payload(65_535)).serialize()
    assert "CameraImage::CameraImageData_64KiB.data" in str(error.value) and "65536" in str(error.value)


@dataclass
@annotate.final
class Unbounded(IdlStruct, typename="fastpath_test.Unbounded"):
    data: types.sequence[types.uint8]


def test_enforce_bound_applies_at_once_and_the_smaller_bound_wins() -> None:
    Unbounded(data=payload(100)).serialize()  # machines built before the bound is registered
    fastpath.enforce_bound(Unbounded, "data", 64)
    Unbounded(data=payload(64)).serialize()
    with pytest.raises(fastpath.OctetBoundError, match=r"fastpath_test::Unbounded\.data holds 65 bytes"):
        Unbounded(data=payload(65)).serialize()
    fastpath.enforce_bound(SmallOctets, "data", 1000)  # the IDL bound (16) is smaller and stays
    with pytest.raises(fastpath.OctetBoundError, match="bound of 16"):
        small(payload(17)).serialize()
    with pytest.raises(KeyError, match="no member 'nope'"):
        fastpath.enforce_bound(Unbounded, "nope", 10)
    with pytest.raises(ValueError, match="positive int"):
        fastpath.enforce_bound(Unbounded, "data", 0)


@dataclass
@annotate.final
class BuiltEarly(IdlStruct, typename="fastpath_test.BuiltEarly"):
    data: types.sequence[types.uint8]


@dataclass
@annotate.final
class BuiltLate(IdlStruct, typename="fastpath_test.BuiltLate"):
    data: types.sequence[types.uint8]


def test_types_built_before_enable_are_converted_too() -> None:
    with unmodified():
        BuiltEarly(data=b"ab").serialize()
        assert not fastpath.uses_fast_path(BuiltEarly, "data")
    assert fastpath.uses_fast_path(BuiltEarly, "data")  # converted by enable()
    assert BuiltEarly.deserialize(BuiltEarly(data=b"ab").serialize()).data == b"ab"
    assert not BuiltLate.__idl__._populated
    assert fastpath.uses_fast_path(BuiltLate, "data")  # built by the patched builder
    fastpath.enable()  # idempotent
    assert fastpath.uses_fast_path(BuiltLate, "data") and fastpath.uses_fast_path(PointCloud2_, "data_")
    assert not fastpath.uses_fast_path(PointCloud2_, "row_step_")


@pytest.fixture
def no_per_element_machine(monkeypatch: pytest.MonkeyPatch) -> None:
    """Cyclone's per-element octet machine fails if anything still calls it."""

    def refuse(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("Cyclone's per-element sequence machine was used")

    monkeypatch.setattr(PlainCdrV2SequenceOfPrimitiveMachine, "serialize", refuse)
    monkeypatch.setattr(PlainCdrV2SequenceOfPrimitiveMachine, "deserialize", refuse)


def test_lidar_writes_and_reads_go_through_the_fast_path_over_dds(no_per_element_machine: None, domain_id: int) -> None:
    """One PointCloud2_ of 184,320 bytes from a writer to a reader of the project's Lidar profile (XCDR1)."""
    data = payload(184_320)
    bus = make_bus(domain_id)
    try:
        writer = bus.writer("rt/LidarTopic", PointCloud2_, "Lidar")
        reader = bus.reader("rt/LidarTopic", PointCloud2_, "Lidar")
        wait_until(lambda: writer.get_publication_matched_status().current_count > 0, what="writer matched")
        assert fastpath.uses_fast_path(PointCloud2_, "data_")
        before = fastpath.counts(PointCloud2_, "data_")
        writer.write(cloud(data))
        received = take_samples(reader, 1)
        after = fastpath.counts(PointCloud2_, "data_")
    finally:
        bus.close()
    assert len(received) == 1
    assert isinstance(received[0].data_, bytes) and received[0].data_ == data
    assert received[0].row_step_ == 184_320 and [f.name_ for f in received[0].fields_] == ["x", "y", "z"]
    assert (after.writes - before.writes, after.reads - before.reads) == (1, 1)


@pytest.mark.parametrize("xcdr2", [False, True], ids=["xcdr1", "xcdr2"])
def test_dds_wire_bytes_are_those_of_the_unmodified_serializer(xcdr2: bool, domain_id: int) -> None:
    """Raw samples taken from a reader: the encapsulation asked for, and exactly Cyclone's own serialization."""
    sample = cloud(payload(184_320))
    with unmodified():
        reference = sample.serialize(use_version_2=xcdr2)
    participant = DomainParticipant(domain_id)
    try:
        topic = Topic(participant, "rt/LidarTopic", PointCloud2_)
        both = Policy.DataRepresentation(use_cdrv0_representation=True, use_xcdrv2_representation=True)
        one = Policy.DataRepresentation(use_cdrv0_representation=not xcdr2, use_xcdrv2_representation=xcdr2)
        reliable = [Policy.Reliability.Reliable(10**9), Policy.History.KeepAll]
        reader = DataReader(participant, topic, qos=Qos(*reliable, both))
        writer = DataWriter(participant, topic, qos=Qos(*reliable, one))
        wait_until(lambda: writer.get_publication_matched_status().current_count > 0, what="writer matched")
        writer.write(sample)
        with pytest.raises(fastpath.OctetBoundError):  # a plain Cyclone writer refuses it too, with our message
            writer.write(cloud(payload(POINT_CLOUD_MAX_DATA + 1)))
        raw: list[bytes] = []
        deadline = time.monotonic() + 15
        while not raw and time.monotonic() < deadline:
            taken = ddspy_take(reader._ref, SampleState.Any | ViewState.Any | InstanceState.Any, 4)
            raw.extend(bytes(data) for data, info in taken if info.valid_data)
            time.sleep(0.02)
    finally:
        participant.__del__()
    assert len(raw) == 1
    assert raw[0][:2] == (b"\x00\x09" if xcdr2 else b"\x00\x01")  # D_CDR2_LE / CDR_LE
    assert raw[0][:len(reference)] == reference  # then the writer pads to a multiple of 4
    assert PointCloud2_.deserialize(raw[0]).data_ == sample.data_
