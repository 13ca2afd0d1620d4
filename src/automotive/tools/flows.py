"""The data flows of the system as the recorder, the replayer, the live bridge and the Zenoh site bridge see them.

Each flow is written by one application; that application's properties file names the flow's topic and QoS
profile (``topic.<Role>``, ``qos.<Role>.Profile``), so a profile changed there is the one recorded and replayed
with: the file beside the tool's own properties file (an exported copy of the configuration), else the shipped one. A
flow's MCAP/Foxglove schema is what Foxglove, ``rosbags`` and rosbag2 decode CDR with: the LiDAR as the ROS 2 message
``sensor_msgs/msg/PointCloud2`` (``ros2msg``), every other type as OMG IDL (``omgidl``: the project's IDL text and the
type's scoped name). Channel metadata carries the writer's QoS as rosbag2 writes it (``offered_qos_profiles``) and the
DDS topic and type names.

The recorder and the live bridge also carry every program's health, ROS 2's /diagnostics (``rt/diagnostics``, the
ROS 2 message ``diagnostic_msgs/msg/DiagnosticArray``: automotive.bus.diagnostics), which is no application's data
flow: the replayer and the Zenoh site bridge leave it out.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

from cyclonedds.qos import DataWriterQos

from automotive import config
from automotive.bus.diagnostics import DIAGNOSTICS_TOPIC, ROS2_TYPE
from automotive.bus.errors import ConfigError
from automotive.bus.properties import Properties
from automotive.bus.qos import ROS2_DEFAULT_PROFILE, profile_name
from automotive.cyclone.bounds import type_name  # re-exported: the name tools and tests use
from automotive.types.Alerts import DriverAlerts
from automotive.types.automotive import ShapeType
from automotive.types.diagnostic_msgs.msg.dds_ import DiagnosticArray_
from automotive.types.Platform import PlatformControl, PlatformStatus
from automotive.types.Sensor import SensorObjectList
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.types.Vision import VisionSensor
from automotive.wire.camera import frame_type

ROS2_POINTCLOUD = "sensor_msgs/msg/PointCloud2"
# The types whose schema is the ROS 2 message (``ros2msg``), which Foxglove's ROS panels (Diagnostics) recognise.
ROS2_MESSAGES: dict[type[Any], str] = {PointCloud2_: ROS2_POINTCLOUD, DiagnosticArray_: ROS2_TYPE}


@dataclass(frozen=True)
class FlowSource:
    """Where a flow is defined: the writing application and the role its properties file gives the flow."""

    app: str
    role: str
    default_topic: str
    data_type: type[Any] | None  # None: chosen by the application's properties (the camera's frame size)


SOURCES = (
    FlowSource("vision", "Vision", "VisionTopic", VisionSensor),
    FlowSource("lidar", "Lidar", "rt/LidarTopic", PointCloud2_),
    FlowSource("sensor_fusion", "SensorObjects", "SensorObjects", SensorObjectList),
    FlowSource("collision_avoidance", "Alerts", "AlertTopic", DriverAlerts),
    FlowSource("collision_avoidance", "PlatformControl", "PlatformControl", PlatformControl),
    FlowSource("vehicle_platform", "PlatformStatus", "PlatformStatus", PlatformStatus),
    FlowSource("camera_pub", "Camera", "CameraImageData", None),
    FlowSource("shapes", "Shapes", "Circle", ShapeType),
)


@dataclass(frozen=True)
class Schema:
    name: str
    encoding: str
    data: bytes


@dataclass(frozen=True)
class Flow:
    """One topic of the system: its type and the QoS profile of its writer (whose reader side readers use)."""

    topic: str
    data_type: type[Any]
    profile: str

    @property
    def type_name(self) -> str:
        return type_name(self.data_type)

    @property
    def schema(self) -> Schema:
        return schema_of(self.data_type)  # type: ignore[arg-type]  # a class is hashable


@cache
def schema_of(data_type: type[Any]) -> Schema:
    ros2_name = ROS2_MESSAGES.get(data_type)
    if ros2_name is not None:
        from rosbags.typesys import Stores, get_typestore

        definition, _ = get_typestore(Stores.ROS2_HUMBLE).generate_msgdef(ros2_name, ros_version=2)
        return Schema(ros2_name, "ros2msg", definition.encode())
    return Schema(type_name(data_type), "omgidl", config.idl_file().read_bytes())


def system_flows(properties_dir: Path | None = None) -> list[Flow]:
    """Every flow of the system, with the topic names and profiles of the writing applications' properties files:
    those in ``properties_dir`` (the folder of the tool's own properties file), each missing one the shipped one."""
    flows = []
    for source in SOURCES:
        path = (properties_dir or config.properties_dir()) / f"{source.app}.properties"
        if not path.is_file():
            path = config.properties_file(source.app)
        props = Properties.load(path)
        topic = props.get_str(f"topic.{source.role}", source.default_topic)
        profile = profile_name(props, source.role)
        data_type = source.data_type or frame_type(props.get_str("config.imageSize", "full"),
                                                   f"{props.source}: config.imageSize")
        flows.append(Flow(topic, data_type, profile))
    return flows


def diagnostics_flow() -> Flow:
    """Every program's health, ROS 2's /diagnostics, with ROS 2's default QoS (a profile of every QoS file)."""
    return Flow(DIAGNOSTICS_TOPIC, DiagnosticArray_, ROS2_DEFAULT_PROFILE)


def flows_with_diagnostics(properties_dir: Path | None = None) -> list[Flow]:
    """What the recorder and the live bridge carry: the system's flows and /diagnostics."""
    return [*system_flows(properties_dir), diagnostics_flow()]


def select(flows: list[Flow], topics: str | None, option: str = "--topics") -> list[Flow]:
    """The flows named in ``topics`` (comma-separated; all of them when empty); an unknown name is a ConfigError
    listing the known ones."""
    names = [name for name in (topics or "").split(",") if name]
    if not names:
        return flows
    by_topic = {flow.topic: flow for flow in flows}
    unknown = [name for name in names if name not in by_topic]
    if unknown:
        raise ConfigError(f"{option}: unknown topic(s) {', '.join(unknown)} (known: {', '.join(by_topic)})")
    return [by_topic[name] for name in dict.fromkeys(names)]


# rmw enums as rosbag2 writes them (rmw/types.h): history 1 keep last, 2 keep all; reliability 1 reliable, 2 best
# effort; durability 1 transient local, 2 volatile; liveliness 1 automatic, 3 manual by topic.
_INFINITE = (2147483647, 4294967295)


def _duration(nanoseconds: int | None) -> tuple[int, int]:
    if nanoseconds is None or nanoseconds >= 2**63 - 1:
        return _INFINITE
    return divmod(nanoseconds, 1_000_000_000)


def offered_qos_profiles(qos: DataWriterQos) -> str:
    """A writer's QoS as the YAML text rosbag2 stores in an MCAP channel's ``offered_qos_profiles``."""
    policies = {policy.__scope__: policy for policy in qos}  # "History", "Reliability", ... -> the policy
    kind = {name: type(policy).__name__.split(".")[-1] for name, policy in policies.items()}

    def duration(name: str, nanoseconds: int | None) -> str:
        sec, nsec = _duration(nanoseconds)
        return f"  {name}:\n    sec: {sec}\n    nsec: {nsec}\n"

    keep_all = kind.get("History") == "KeepAll"
    return (f"- history: {2 if keep_all else 1}\n"
            f"  depth: {0 if keep_all else getattr(policies.get('History'), 'depth', 1)}\n"
            f"  reliability: {1 if kind.get('Reliability') == 'Reliable' else 2}\n"
            f"  durability: {1 if kind.get('Durability') == 'TransientLocal' else 2}\n"
            + duration("deadline", getattr(policies.get("Deadline"), "deadline", None))
            + duration("lifespan", getattr(policies.get("Lifespan"), "lifespan", None))
            + f"  liveliness: {3 if kind.get('Liveliness') == 'ManualByTopic' else 1}\n"
            + duration("liveliness_lease_duration", getattr(policies.get("Liveliness"), "lease_duration", None))
            + "  avoid_ros_namespace_conventions: false\n")


def channel_metadata(flow: Flow, writer_qos: DataWriterQos, kind: str = "data") -> dict[str, str]:
    """MCAP channel metadata: the writer's QoS (rosbag2's key), the DDS topic and type, and the sample kind."""
    return {"offered_qos_profiles": offered_qos_profiles(writer_qos), "dds_topic": flow.topic,
            "dds_type": flow.type_name, "dds_sample_kind": kind}
