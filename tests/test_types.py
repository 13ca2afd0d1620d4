"""Every topic type: registered name, keys, round trip with full and boundary-size content, bounds refused."""

from __future__ import annotations

from typing import Any

import pytest
from cyclonedds.domain import DomainParticipant
from cyclonedds.topic import Topic

from automotive.cyclone import bounds
from automotive.types.Alerts import DriverAlerts
from automotive.types.automotive import ShapeType
from automotive.types.builtin_interfaces.msg.dds_ import Time_
from automotive.types.CameraImage import (
    MAX_IMAGE_SIZE,
    CameraImageData,
    CameraImageData_1MiB,
    CameraImageData_4MiB,
    CameraImageData_64KiB,
)
from automotive.types.Common import ClassificationEnum, IndicatorStatusEnum, POSIXTimestamp
from automotive.types.Lane import ConfidenceEnum, LaneBoundaryEnum, LaneObject, LaneSensor
from automotive.types.Lidar import MAX_POINTS, LidarSensor, PCloud, Point
from automotive.types.Platform import PlatformControl, PlatformStatus
from automotive.types.Sensor import SENSOR_OBJECT_LIST_MAX_SIZE, RangeModeEnum, SensorObject, SensorObjectList
from automotive.types.sensor_msgs.msg.dds_ import POINT_CLOUD_MAX_DATA, PointCloud2_, PointField_
from automotive.types.std_msgs.msg.dds_ import Header_
from automotive.types.Vision import VISION_OBJECT_LIST_MAX_SIZE, VisionObject, VisionSensor

STAMP = POSIXTimestamp(s=1_700_000_000, ns=123_456_789)

# topic, type, the original's registered type name, key members
TOPIC_TYPES = [
    ("VisionTopic", VisionSensor, "Vision::VisionSensor", ["id"]),
    ("SensorObjects", SensorObjectList, "Sensor::SensorObjectList", []),
    ("PlatformStatus", PlatformStatus, "Platform::PlatformStatus", []),
    ("PlatformControl", PlatformControl, "Platform::PlatformControl", []),
    ("AlertTopic", DriverAlerts, "Alerts::DriverAlerts", []),
    ("rt/LidarTopic", PointCloud2_, "sensor_msgs::msg::dds_::PointCloud2_", []),
    ("CameraImageData", CameraImageData, "CameraImage::CameraImageData", ["id"]),
    ("Circle", ShapeType, "ShapeType", ["color"]),
]


def vision_object(i: int) -> VisionObject:
    return VisionObject(classification=ClassificationEnum(i % 8), position=[i, -1.5, 0.25],
                        velocity=[0.5, i / 4, -2.0], size=[4.5, 1.75 + i, 1.5])


def sensor_object(i: int) -> SensorObject:
    return SensorObject(classification=ClassificationEnum(i % 8), position=[i, 2.0, 0.0], velocity=[1.0, 2.0, 3.0],
                        size=[1.0, 2.5, 3.0], amplitude=0.75, rangeMode=RangeModeEnum(i % 4), rangeRate=-1.25)


def point_cloud(data_size: int, fields: int = 4) -> PointCloud2_:
    names = ["x", "y", "z", "rgb"]
    return PointCloud2_(
        header_=Header_(stamp_=Time_(sec_=12, nanosec_=34), frame_id_="map"),
        height_=1, width_=data_size // 16,
        fields_=[PointField_(name_=names[i % 4], offset_=4 * i, datatype_=7, count_=1) for i in range(fields)],
        is_bigendian_=False, point_step_=16, row_step_=data_size, data_=bytes(range(256)) * (data_size // 256)
        + bytes(data_size % 256), is_dense_=True)


def camera(data_type: type, size: int) -> Any:
    # bytes i % 251, made by repeating one period: every pytest worker builds these samples as it collects the tests
    return data_type(id=3, sec_=5, nanosec_=6, seqnum=7, data=(bytes(range(251)) * (size // 251 + 1))[:size])


FULL_SAMPLES = {
    "VisionSensor": VisionSensor(id=7, timestamp=STAMP, objects=[vision_object(i) for i in range(3)]),
    "VisionSensor@bound": VisionSensor(id=2**31 - 1, timestamp=STAMP,
                                       objects=[vision_object(i) for i in range(VISION_OBJECT_LIST_MAX_SIZE)]),
    "VisionSensor@empty": VisionSensor(id=0, timestamp=STAMP, objects=[]),
    "SensorObjectList": SensorObjectList(timestamp=STAMP, objects=[sensor_object(i) for i in range(5)]),
    "SensorObjectList@bound": SensorObjectList(
        timestamp=STAMP, objects=[sensor_object(i) for i in range(SENSOR_OBJECT_LIST_MAX_SIZE)]),
    "PlatformStatus": PlatformStatus(timestamp=STAMP, vehSpd=88.5, blinkerStatus=IndicatorStatusEnum.INDICATOR_HAZARD,
                                     posGasPedal=27.0, velocity=24.5, yawRate=0.015625, vehicleSteerAngle=-3.5),
    "PlatformControl": PlatformControl(sample_id=2**31 - 1, timestamp=STAMP, vehicleSteerAngle=1.5, speed=12.25,
                                       blinkerStatus=IndicatorStatusEnum.INDICATOR_LEFT),
    "DriverAlerts": DriverAlerts(blindSpotDriver=True, blindSpotPassenger=False, frontCollision=True,
                                 backCollision=False, parkingCollision=True, driverAttention=True),
    "PointCloud2_": point_cloud(184_320),
    "PointCloud2_@bound": point_cloud(POINT_CLOUD_MAX_DATA),
    "PointCloud2_@odd": point_cloud(1001, fields=1),
    "CameraImageData@bound": camera(CameraImageData, MAX_IMAGE_SIZE),
    "CameraImageData_64KiB": camera(CameraImageData_64KiB, 65536),
    "CameraImageData_1MiB": camera(CameraImageData_1MiB, 1 << 20),
    "CameraImageData_4MiB": camera(CameraImageData_4MiB, 4 << 20),
    "ShapeType": ShapeType(color="BLUE", x=120, y=135, shapesize=30),
    "ShapeType@bound": ShapeType(color="C" * 128, x=-1, y=2**31 - 1, shapesize=0),
    "LaneSensor": LaneSensor(
        left=LaneObject(isValid=True, confidence=ConfidenceEnum.CONFIDENCE_HIGH,
                        boundaryType=LaneBoundaryEnum.BOUNDRY_DOUBLEMARKER, offset=-1.75, headingAngle=0.5,
                        curvature=0.0009765625),
        right=LaneObject(isValid=False, confidence=ConfidenceEnum.CONFIDENCE_NONE,
                         boundaryType=LaneBoundaryEnum.BOUNDRY_NONE, offset=1.75, headingAngle=0.0, curvature=0.0)),
    "LidarSensor@bound": LidarSensor(timestamp=STAMP, ptCloud=PCloud(
        Location=[Point(point=[i, -i, 0.5]) for i in range(MAX_POINTS)], color=255, normal=1.0, intensity=0.5,
        count=MAX_POINTS, xLimits=[-1, 1], yLimits=[-2, 2], zLimits=[0, 3])),
}


@pytest.mark.parametrize("name", sorted(FULL_SAMPLES))
@pytest.mark.parametrize("xcdr2", [False, True], ids=["xcdr1", "xcdr2"])
def test_round_trip(name: str, xcdr2: bool) -> None:
    sample = FULL_SAMPLES[name]
    data = sample.serialize(use_version_2=xcdr2)
    decoded = type(sample).deserialize(data)
    if isinstance(sample, PointCloud2_):  # the fast path delivers data_ as a buffer, not a list
        assert bytes(decoded.data_) == bytes(sample.data_)
        decoded.data_ = sample.data_
    assert decoded == sample


OVER_BOUND = {
    "VisionSensor.objects": VisionSensor(id=1, timestamp=STAMP,
                                         objects=[vision_object(0)] * (VISION_OBJECT_LIST_MAX_SIZE + 1)),
    "SensorObjectList.objects": SensorObjectList(
        timestamp=STAMP, objects=[sensor_object(0)] * (SENSOR_OBJECT_LIST_MAX_SIZE + 1)),
    "PointCloud2_.fields_": point_cloud(64, fields=5),
    "PointCloud2_.data_": point_cloud(POINT_CLOUD_MAX_DATA + 1),
    "ShapeType.color": ShapeType(color="C" * 129, x=0, y=0, shapesize=1),
}


@pytest.mark.parametrize("member", sorted(OVER_BOUND))
def test_over_bound_is_refused_with_a_clear_message(member: str) -> None:
    sample = OVER_BOUND[member]
    with pytest.raises(bounds.BoundError) as error:
        bounds.check(sample)
    message = str(error.value)
    assert member in message and "over its IDL bound" in message
    assert len(message) < 200  # one readable line, not the whole value


# Unbounded in the generated type (Cyclone cannot express it); enforced by automotive.cyclone.bounds and
# automotive.cyclone.fastpath (test_fastpath).
UNBOUNDED_IN_THE_GENERATED_TYPE = {"PointCloud2_.data_"}


@pytest.mark.parametrize("member", sorted(set(OVER_BOUND) - UNBOUNDED_IN_THE_GENERATED_TYPE))
def test_over_bound_is_refused_by_the_serializer_too(member: str) -> None:
    """The generated types keep the IDL bounds (except the one Cyclone cannot express)."""
    with pytest.raises(Exception):  # noqa: B017 - Cyclone raises a bare Exception
        OVER_BOUND[member].serialize()


@pytest.mark.parametrize("topic_name,data_type,wire_name,keys", TOPIC_TYPES)
def test_registered_type_names_and_keys(domain_id: int, topic_name: str, data_type: type, wire_name: str,
                                        keys: list[str]) -> None:
    participant = DomainParticipant(domain_id)
    topic = Topic(participant, topic_name, data_type)
    assert topic.get_type_name() == wire_name
    declared_keys = [name for name, notes in data_type.__idl_field_annotations__.items() if notes.get("key")]
    assert declared_keys == keys
    assert data_type.__idl__.keyless == (not keys)  # populated by the Topic
    participant.__del__()


def test_an_extra_bound_and_an_idl_bound_the_smaller_applies() -> None:
    six = VisionSensor(id=1, timestamp=STAMP, objects=[vision_object(0)] * 6)
    try:
        bounds.set_extra_bound(VisionSensor, "objects", 5)
        with pytest.raises(bounds.BoundError, match="holds 6 elements, over its IDL bound of 5"):
            bounds.check(six)
        bounds.set_extra_bound(VisionSensor, "objects", 50)  # larger than the IDL's 10: the IDL's stays
        bounds.check(six)
        with pytest.raises(bounds.BoundError, match="over its IDL bound of 10"):
            bounds.check(OVER_BOUND["VisionSensor.objects"])
    finally:
        del bounds.EXTRA_BOUNDS[(VisionSensor, "objects")]
        bounds._plan.cache_clear()
