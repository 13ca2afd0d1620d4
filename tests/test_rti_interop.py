"""Interoperability of our Cyclone types and QoS with a real RTI Connext peer (RTI Connector), on loopback.

The RTI side declares the types as the original RTI example does (everything appendable, helpers at the root;
tests/rti/automotive_rti.xml). Our side uses the project's own Databus, profiles and data representation.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict
from typing import Any, TypeVar

import pytest

pytest.importorskip("rticonnextdds_connector")

from cyclonedds.core import InstanceState
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.util import duration
from dds_helpers import take_samples, wait_until
from rti_peer import RtiPeer

from automotive.bus.endpoints import Databus
from automotive.bus.qos import READER_REPRESENTATION, WRITER_REPRESENTATION
from automotive.cyclone.matched import matched_publications, matched_subscriptions
from automotive.types.Alerts import DriverAlerts
from automotive.types.automotive import ShapeType
from automotive.types.Common import ClassificationEnum, POSIXTimestamp
from automotive.types.Vision import VisionObject, VisionSensor

# Values exactly representable as float32, so a round trip through either side compares equal.
VISION_RTI = {"id": 4711, "timestamp": {"s": 1700000000, "ns": 123456789}, "objects": [
    {"classification": 5, "position": [12.5, -1.75, 0.0], "velocity": [-3.25, 0.0, 0.5], "size": [4.5, 1.875, 1.5]},
    {"classification": 3, "position": [6.0, 2.25, 0.0], "velocity": [0.0, -1.5, 0.0], "size": [0.5, 0.5, 1.75]},
]}


def vision_sample(sample_id: int) -> VisionSensor:
    return VisionSensor(sample_id, POSIXTimestamp(1700000000, 987654321), [
        VisionObject(ClassificationEnum.CLASSIFICATION_TRUCK, [30.0, 0.5, 0.0], [-2.0, 0.0, 0.0], [12.0, 2.5, 3.75]),
        VisionObject(ClassificationEnum.CLASSIFICATION_BIKE, [8.25, -3.0, 0.0], [0.0, 1.25, 0.0], [1.75, 0.625, 1.5]),
    ])


def vision_as_dict(sample: VisionSensor) -> dict[str, Any]:
    """Our sample in the shape RTI Connector returns (enums as ints)."""
    return {"id": sample.id, "timestamp": {"s": sample.timestamp.s, "ns": sample.timestamp.ns}, "objects": [
        {"classification": o.classification.value, "position": list(o.position), "velocity": list(o.velocity),
         "size": list(o.size)} for o in sample.objects]}


def test_rti_shapes_writer_reaches_our_shape_reader(bus: Databus, domain_id: int) -> None:
    """RTI Shapes Demo registers ShapeTypeExtended as "ShapeType"; our ShapeType reader reads its base members."""
    qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(8), READER_REPRESENTATION)
    reader = DataReader(bus.subscriber, bus.topic("Circle", ShapeType), qos=qos)
    with RtiPeer(domain_id, writers=["Circle"]) as peer:
        peer.wait_for_readers("Circle")
        wait_until(lambda: len(matched_publications(reader)) == 1, what="our reader to match the RTI writer")
        shapes = [("BLUE", 10, 20, 30), ("RED", 200, 100, 45), ("GREEN", 0, 255, 60)]
        for color, x, y, size in shapes:
            peer.write("Circle", {"color": color, "x": x, "y": y, "shapesize": size, "fillKind": 2, "angle": 33.5})
        received = take_samples(reader, len(shapes))
    assert sorted((s.color, s.x, s.y, s.shapesize) for s in received) == sorted(shapes)


def test_rti_dispose_of_a_shape_reaches_our_reader(bus: Databus, domain_id: int) -> None:
    """ShapeType's key is longer than 16 bytes: the RTI writer must serialize it with the dispose (see the Writer
    profile) for Cyclone to know which instance was disposed."""
    qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(8), READER_REPRESENTATION)
    reader = DataReader(bus.subscriber, bus.topic("Circle", ShapeType), qos=qos)
    with RtiPeer(domain_id, writers=["Circle"]) as peer:
        peer.wait_for_readers("Circle")
        wait_until(lambda: len(matched_publications(reader)) == 1, what="our reader to match the RTI writer")
        peer.write("Circle", {"color": "ORANGE", "x": 5, "y": 6, "shapesize": 40})
        assert [s.color for s in take_samples(reader, 1)] == ["ORANGE"]
        output = peer.output("Circle")
        output.instance.set_dictionary({"color": "ORANGE"})
        output.write(action="dispose")
        wait_until(lambda: any(s.sample_info.instance_state == InstanceState.NotAliveDisposed
                               for s in reader.take(N=8)), what="the dispose of ORANGE")


def test_our_alerts_writer_reaches_rti_reader_late_joiner_included(bus: Databus, domain_id: int) -> None:
    """HMI profile (reliable, transient local, XCDR1): an RTI reader that joins later still gets the last alert."""
    writer = bus.writer("AlertTopic", DriverAlerts, "HMI")
    writer.write(DriverAlerts(True, False, False, False, False, False))
    last = DriverAlerts(False, True, True, False, True, False)
    writer.write(last)  # history 1: the only one a late joiner gets
    with RtiPeer(domain_id, readers=["Alerts"]) as peer:
        assert peer.take_until("Alerts", 1) == [asdict(last)]
        live = DriverAlerts(False, False, False, True, False, True)
        writer.write(live)
        assert peer.take_until("Alerts", 1) == [asdict(live)]


def test_rti_alerts_writer_reaches_our_late_hmi_reader(bus: Databus, domain_id: int) -> None:
    """The reverse flow with the HMI profile's demands (transient local, a 60 s liveliness lease)."""
    with RtiPeer(domain_id, writers=["Alerts"]) as peer:
        alert = {"blindSpotDriver": False, "blindSpotPassenger": True, "frontCollision": False,
                 "backCollision": True, "parkingCollision": False, "driverAttention": True}
        peer.write("Alerts", alert)
        reader = bus.reader("AlertTopic", DriverAlerts, "HMI")  # joins after the write
        received = take_samples(reader, 1)
    assert [asdict(s) for s in received] == [alert]


def test_our_vision_writer_reaches_rti_reader_with_objects(bus: Databus, domain_id: int) -> None:
    """Vision profile (best effort, XCDR1); our VisionObject is @final, RTI's appendable: same bytes in XCDR1."""
    writer = bus.writer("VisionTopic", VisionSensor, "Vision")
    sample = vision_sample(4242)
    with RtiPeer(domain_id, readers=["Vision"]) as peer:
        peer.wait_for_writers("Vision")
        wait_until(lambda: len(matched_subscriptions(writer)) == 1, what="our writer to match the RTI reader")
        received = _write_until_received(lambda: writer.write(sample),
                                         lambda: peer.take_until("Vision", 1, timeout=0.2,
                                                                 accept=lambda s: s["id"] == 4242))
    assert received == vision_as_dict(sample)


def test_rti_vision_writer_reaches_our_vision_reader(bus: Databus, domain_id: int) -> None:
    """RTI writes XCDR1 with appendable nested types; our reader (Vision profile) decodes it intact."""
    reader = bus.reader("VisionTopic", VisionSensor, "Vision")
    with RtiPeer(domain_id, writers=["Vision"]) as peer:
        peer.wait_for_readers("Vision")
        wait_until(lambda: len(matched_publications(reader)) == 1, what="our reader to match the RTI writer")
        received = _write_until_received(lambda: peer.write("Vision", VISION_RTI),
                                         lambda: [s for s in take_samples(reader, 1, timeout=0.2) if s.id == 4711])
    assert vision_as_dict(received) == VISION_RTI


def test_rti_reader_matches_only_an_xcdr1_writer(bus: Databus, domain_id: int) -> None:
    """Why our writers offer XCDR1: an RTI Connext 6 reader with default QoS ignores a writer offering XCDR2
    (Cyclone's default for appendable types)."""
    topic = bus.topic("AlertTopic", DriverAlerts)
    base = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.Durability.TransientLocal,
               Policy.History.KeepLast(1))
    with RtiPeer(domain_id, readers=["Alerts"]) as peer:
        xcdr2 = DataWriter(bus.publisher, topic, qos=Qos(Policy.DataRepresentation(use_xcdrv2_representation=True),
                                                         base=base))
        xcdr2.write(DriverAlerts(True, True, True, True, True, True))
        # Created second: Cyclone announces it after the XCDR2 writer on the same reliable discovery stream, so
        # once RTI matched it, RTI has already judged the XCDR2 writer.
        xcdr1 = DataWriter(bus.publisher, topic, qos=Qos(WRITER_REPRESENTATION, base=base))
        peer.wait_for_writers("Alerts")
        xcdr1.write(DriverAlerts(False, False, False, False, False, True))
        received = peer.take_until("Alerts", 1) + peer.take("Alerts")
        assert peer.matched_writers("Alerts") == 1
    assert received == [asdict(DriverAlerts(False, False, False, False, False, True))]


T = TypeVar("T")


def _write_until_received(write: Callable[[], None], receive: Callable[[], list[T]], timeout: float = 15.0) -> T:
    """Best-effort flows: write again until the other side received one sample (bounded by ``timeout``)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        write()
        received = receive()
        if received:
            return received[0]
    raise AssertionError(f"nothing received within {timeout:.0f} s")
