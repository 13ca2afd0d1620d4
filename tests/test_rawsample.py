"""automotive.wire.rawsample: serialized samples taken and written without (de)serializing, disposals and
unregistrations included, checked against Cyclone's own serializer and typed readers."""

from __future__ import annotations

from typing import Any

import pytest
from cyclonedds.core import InstanceState
from cyclonedds.pub import DataWriter
from cyclonedds.qos import DataWriterQos, Policy
from dds_helpers import take_samples, wait_until

from automotive.bus.endpoints import Databus
from automotive.cyclone.matched import matched_publications
from automotive.types.Alerts import DriverAlerts
from automotive.types.Common import ClassificationEnum, POSIXTimestamp
from automotive.types.Vision import VisionObject, VisionSensor
from automotive.wire.rawsample import RawReader, RawSample, RawWriter, SampleKind, key_to_sample


def vision(sensor_id: int, seconds: int = 1) -> VisionSensor:
    obj = VisionObject(classification=ClassificationEnum.CLASSIFICATION_CAR, position=[1.0, 2.0, 3.0],
                       velocity=[0.5, 0.0, 0.0], size=[4.0, 1.5, 1.75])
    return VisionSensor(id=sensor_id, timestamp=POSIXTimestamp(s=seconds, ns=7), objects=[obj])


def take_raw(reader: RawReader, count: int, timeout: float = 15.0) -> list[RawSample]:
    taken: list[RawSample] = []

    def enough() -> bool:
        taken.extend(reader.take())
        return len(taken) >= count

    wait_until(enough, timeout, f"{count} raw samples")
    return taken


def matched(bus: Databus, topic: str, data_type: type[Any], writer_qos: DataWriterQos | None = None) -> tuple[Any, Any]:
    if writer_qos is None:
        writer = bus.writer(topic, data_type, "Vision")
    else:
        writer = DataWriter(bus.publisher, bus.topic(topic, data_type), qos=writer_qos)
    reader = bus.reader(topic, data_type, "Vision")
    wait_until(lambda: bool(matched_publications(reader)), what="the reader to match the writer")
    return writer, reader


def test_take_gives_the_wire_bytes_timestamp_and_writer(bus: Databus) -> None:
    writer, reader = matched(bus, "VisionTopic", VisionSensor)
    sample = vision(7)
    writer.write(sample, timestamp=1_700_000_000_123_456_789)
    [taken] = take_raw(RawReader(reader), 1)
    assert taken.kind is SampleKind.DATA
    assert bytes(taken.data) == sample.serialize(use_version_2=False)  # XCDR1, header included
    assert taken.source_timestamp == 1_700_000_000_123_456_789
    assert taken.writer == writer.instance_handle
    assert matched_publications(reader) == [writer.instance_handle]
    assert taken.instance_state == InstanceState.Alive


def test_disposal_and_unregistration_are_taken_with_their_key(bus: Databus) -> None:
    qos = DataWriterQos(Policy.WriterDataLifecycle(autodispose=False),
                        base=bus.profiles.writer_qos(bus.library, "Vision"))
    writer, reader = matched(bus, "VisionTopic", VisionSensor, qos)
    raw = RawReader(reader)
    writer.write(vision(1))
    writer.write(vision(2))
    assert [s.kind for s in take_raw(raw, 2)] == [SampleKind.DATA, SampleKind.DATA]
    writer.dispose(vision(1))
    writer.unregister_instance(vision(2))
    changes = take_raw(raw, 2)
    assert {(s.kind, VisionSensor.deserialize(bytes(s.data)).id) for s in changes} == {
        (SampleKind.DISPOSE, 1), (SampleKind.UNREGISTER, 2)}
    # A disposal that arrives while the data is still unread changes that sample's state instead of adding a
    # sample: the disposal is then taken right after the data.
    writer.write(vision(3))
    writer.dispose(vision(3))
    taken = take_raw(raw, 2)
    assert [s.kind for s in taken] == [SampleKind.DATA, SampleKind.DISPOSE]
    assert VisionSensor.deserialize(bytes(taken[1].data)).id == 3


def test_lent_samples_are_views_released_after_the_block(bus: Databus) -> None:
    writer, reader = matched(bus, "VisionTopic", VisionSensor)
    raw = RawReader(reader)
    assert raw.zero_copy
    writer.write(vision(4))
    kept: list[RawSample] = []

    def lend() -> bool:
        with raw.lend() as samples:
            for sample in samples:
                assert isinstance(sample.data, memoryview)
                assert bytes(sample.data) == vision(4).serialize(use_version_2=False)
            kept.extend(samples)
        return bool(kept)

    wait_until(lend, what="a lent sample")
    with pytest.raises(ValueError, match="released"):
        bytes(kept[0].data)


def test_raw_writer_writes_disposes_and_unregisters_without_serializing(bus: Databus) -> None:
    qos = DataWriterQos(Policy.WriterDataLifecycle(autodispose=False),
                        base=bus.profiles.writer_qos(bus.library, "Vision"))
    writer, reader = matched(bus, "VisionTopic", VisionSensor, qos)
    raw = RawWriter(writer)
    raw.write(vision(5, seconds=9).serialize(use_version_2=False), timestamp=42_000_000_123)
    [received] = take_samples(reader, 1)
    assert received == vision(5, seconds=9)
    assert received.sample_info.source_timestamp == 42_000_000_123
    raw.write(vision(6).serialize(use_version_2=False))
    assert take_samples(reader, 1) == [vision(6)]
    raw.put(RawSample(key_to_sample(VisionSensor, vision(5).serialize()), SampleKind.DISPOSE, 0, 0, 0, 0))
    raw.unregister(vision(6).serialize(use_version_2=False))
    states: dict[int, int] = {}

    def both_changed() -> bool:
        for sample in reader.take(N=10):
            states[sample.sample_info.instance_handle] = sample.sample_info.instance_state
        return len(states) == 2

    wait_until(both_changed, what="the disposal and the unregistration")
    assert sorted(states.values()) == [InstanceState.NotAliveDisposed, InstanceState.NotAliveNoWriters]


def test_keyless_disposal_becomes_a_default_sample(bus: Databus) -> None:
    writer = bus.writer("AlertTopic", DriverAlerts, "HMI")
    reader = bus.reader("AlertTopic", DriverAlerts, "HMI")
    wait_until(lambda: bool(matched_publications(reader)), what="the alert reader to match")
    alert = DriverAlerts(blindSpotDriver=True, blindSpotPassenger=False, frontCollision=False, backCollision=False,
                         parkingCollision=False, driverAttention=True)
    raw = RawReader(reader)
    RawWriter(writer).write(alert.serialize(use_version_2=False))
    assert [bytes(s.data) for s in take_raw(raw, 1)] == [alert.serialize(use_version_2=False)]
    writer.dispose(alert)
    [disposal] = take_raw(raw, 1)
    assert disposal.kind is SampleKind.DISPOSE
    assert DriverAlerts.deserialize(bytes(disposal.data)) == DriverAlerts(
        blindSpotDriver=False, blindSpotPassenger=False, frontCollision=False, backCollision=False,
        parkingCollision=False, driverAttention=False)
