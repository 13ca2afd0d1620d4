"""The LiDAR's cloud as ROS 2 sees it: its serialized samples, taken off the wire, decode with an independent ROS 2
implementation (the `rosbags` library's Humble type store) as sensor_msgs/msg/PointCloud2, every field equal, and
that implementation serializes the same message to the same bytes.

The reader here is what RViz2 creates for a PointCloud2 display (reliable, volatile, keep last 5, no latency budget)
on the DDS topic of the ROS 2 topic /LidarTopic: rt/LidarTopic.
"""

from __future__ import annotations

import time

import numpy as np
from cyclonedds._clayer import ddspy_take
from cyclonedds.core import InstanceState, SampleState, ViewState
from cyclonedds.domain import DomainParticipant
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from dds_helpers import wait_until
from rosbags.typesys import Stores, get_typestore

from automotive.cyclone.matched import matched_publications
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.wire.pointcloud import decode_point_cloud2

RVIZ2_READER = Qos(Policy.Reliability.Reliable(0), Policy.Durability.Volatile, Policy.History.KeepLast(5),
                   Policy.DataRepresentation(use_cdrv0_representation=True))


def take_serialized(reader: DataReader[PointCloud2_], count: int, timeout: float = 30.0) -> list[bytes]:
    raw: list[bytes] = []
    deadline = time.monotonic() + timeout
    while len(raw) < count and time.monotonic() < deadline:
        taken = ddspy_take(reader._ref, SampleState.Any | ViewState.Any | InstanceState.Any, count)
        raw.extend(bytes(data) for data, info in taken if info.valid_data)
        time.sleep(0.02)
    return raw


def test_lidar_clouds_decode_as_ros2_point_cloud2_every_field_equal(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    participant = DomainParticipant(domain_id)
    try:
        reader = DataReader(participant, Topic(participant, "rt/LidarTopic", PointCloud2_), qos=RVIZ2_READER)
        lidar = apps.start("lidar", "--domain", str(domain_id))
        wait_until(lambda: len(matched_publications(reader)) == 1, timeout=30, what="the LiDAR writer")
        raw = take_serialized(reader, 2)
    finally:
        participant.__del__()
    assert len(raw) >= 2, f"received {len(raw)} clouds; lidar output:\n{lidar.output}"
    assert "incompatible QoS" not in lidar.output

    store = get_typestore(Stores.ROS2_HUMBLE)
    for serialized in raw:
        assert serialized[:4] == b"\x00\x01\x00\x00"  # XCDR1 little endian: what ROS 2's middlewares read
        ros = store.deserialize_cdr(serialized, "sensor_msgs/msg/PointCloud2")
        ours = PointCloud2_.deserialize(serialized)
        assert ros.header.frame_id == ours.header_.frame_id_ == "map"
        assert (ros.header.stamp.sec, ros.header.stamp.nanosec) == (ours.header_.stamp_.sec_,
                                                                    ours.header_.stamp_.nanosec_)
        assert abs(ros.header.stamp.sec - time.time()) < 60
        assert (ros.height, ros.width, ros.is_bigendian, ros.point_step, ros.row_step, ros.is_dense) == \
            (ours.height_, ours.width_, ours.is_bigendian_, ours.point_step_, ours.row_step_, ours.is_dense_) == \
            (64, 180, False, 16, 180 * 16, True)
        assert [(f.name, f.offset, f.datatype, f.count) for f in ros.fields] == \
            [(f.name_, f.offset_, f.datatype_, f.count_) for f in ours.fields_] == \
            [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("rgb", 12, 7, 1)]
        assert ros.data.tobytes() == bytes(ours.data_)
        xyz, _ = decode_point_cloud2(ours)
        assert np.array_equal(np.frombuffer(ros.data.tobytes(), np.float32).reshape(-1, 4)[:, :3], xyz)
        # The other way: the ROS 2 implementation writes the very bytes our writer put on the wire.
        reserialized = bytes(store.serialize_cdr(ros, "sensor_msgs/msg/PointCloud2"))
        assert serialized[:len(reserialized)] == reserialized and len(serialized) - len(reserialized) < 4
