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

The large flows (the camera's frames, the LiDAR's clouds: ``Flow.shared``) go through shared memory to the readers on
their writer's host (automotive.wire.sharedflow). The recorder and the live bridge read every flow through
:class:`FlowInput`: serialized samples as received, those of a shared flow from shared memory when its writer is on
this host (the same CDR bytes and source timestamp as its DDS samples) and on DDS from any other writer, never one
sample twice.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from cyclonedds.core import InstanceState, WaitSet
from cyclonedds.qos import DataReaderQos, DataWriterQos
from cyclonedds.sub import DataReader

from automotive import config
from automotive.bus.app import Application
from automotive.bus.diagnostics import DIAGNOSTICS_TOPIC, ROS2_TYPE
from automotive.bus.errors import ConfigError
from automotive.bus.properties import Properties
from automotive.bus.qos import ROS2_DEFAULT_PROFILE, profile_name
from automotive.bus.status import EventHook
from automotive.cyclone.bounds import type_name  # re-exported: the name tools and tests use
from automotive.types.Alerts import DriverAlerts
from automotive.types.automotive import ShapeType
from automotive.types.diagnostic_msgs.msg.dds_ import DiagnosticArray_
from automotive.types.Platform import PlatformControl, PlatformStatus
from automotive.types.Sensor import SensorObjectList
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.types.Vision import VisionSensor
from automotive.wire import shm
from automotive.wire.camera import frame_type
from automotive.wire.filteredraw import filtered_raw_reader
from automotive.wire.rawsample import RawSample, SampleKind
from automotive.wire.sharedflow import FlowReader

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
    shared: bool = False  # written through shared memory to the readers on the writer's host (FlowWriter)


SOURCES = (
    FlowSource("vision", "Vision", "VisionTopic", VisionSensor),
    FlowSource("lidar", "Lidar", "rt/LidarTopic", PointCloud2_, shared=True),
    FlowSource("sensor_fusion", "SensorObjects", "SensorObjects", SensorObjectList),
    FlowSource("collision_avoidance", "Alerts", "AlertTopic", DriverAlerts),
    FlowSource("collision_avoidance", "PlatformControl", "PlatformControl", PlatformControl),
    FlowSource("vehicle_platform", "PlatformStatus", "PlatformStatus", PlatformStatus),
    FlowSource("camera_pub", "Camera", "CameraImageData", None, shared=True),
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
    shared: bool = False  # through shared memory from a writer on this host (see FlowInput)

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
        flows.append(Flow(topic, data_type, profile, source.shared))
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


class FlowInput:
    """One flow as the recorder and the live bridge read it: serialized samples as received, never deserialized.

    A DDS reader with the reader side of the flow's profile and the tool's ``overrides`` (a recorder keeps every
    sample, the bridge the newest), read raw (automotive.wire.rawsample; filtered when the topic has a content filter).
    A shared flow (``Flow.shared``) also has its shared memory (automotive.wire.sharedflow.FlowReader): the samples of
    writers on this host come from there (exactly the bytes of their DDS samples, with the same source timestamp), and
    the DDS copies of those writers' samples are dropped, so that no sample is taken twice. The shared-memory
    subscriber's QoS (its depth and deadline) is the profile's reader QoS with ``shared_overrides`` (by default the DDS
    reader's ``overrides``).
    """

    def __init__(self, app: Application, flow: Flow, overrides: tuple[Any, ...] = (), hook: EventHook | None = None,
                 shared_overrides: tuple[Any, ...] | None = None):
        self.flow = flow

        def make_reader(marking: tuple[Any, ...]) -> DataReader[Any]:
            return app.bus.reader(flow.topic, flow.data_type, flow.profile, hook, overrides=(*overrides, *marking))

        self.shared: FlowReader | None = None
        if flow.shared:
            qos = DataReaderQos(*(overrides if shared_overrides is None else shared_overrides),
                                base=app.profiles.reader_qos(app.library, flow.profile))
            self.shared = FlowReader(app, flow.topic, qos, make_reader)
            reader = self.shared.reader
        else:
            reader = make_reader(())
        self.raw = filtered_raw_reader(reader, app.filters.predicate(flow.topic, flow.data_type))
        self.from_shared_memory = 0  # samples taken from shared memory
        self.dropped = 0  # DDS samples of writers that sent them through shared memory too (left out)

    @property
    def reader(self) -> DataReader[Any]:
        return self.raw.reader

    @property
    def on_shared_memory(self) -> bool:
        """Whether samples of writers on this host come through shared memory (else all come on DDS)."""
        return self.shared is not None and self.shared.shared is not None

    def attach(self, waitset: WaitSet) -> None:
        """Have ``waitset`` (woken by the DDS reader) woken by samples in shared memory too."""
        if self.shared is not None:
            self.shared.attach(waitset)

    def drain(self, limit: int = 64) -> Iterator[tuple[RawSample, int]]:
        """Take until nothing is left, yielding each sample with its reception time (ns since the epoch): first those
        of shared memory (copied: valid after the loan ends), then DDS's, less the DDS copies of shared ones."""
        shared = self.shared
        if shared is not None:
            while True:
                with shared.take_shared(limit) as lent:
                    if not lent:
                        break
                    receive_ns = time.time_ns()
                    copies = [(bytes(sample.data), sample.source_timestamp) for sample in lent]
                self.from_shared_memory += len(copies)
                for data, stamp in copies:
                    # through the raw reader's own path, so that its content filter (if any) applies alike
                    for sample in self.raw.samples_of(data, _shared_info(stamp)):
                        yield sample, receive_ns
        for sample, receive_ns in self.raw.drain(limit):
            if shared is not None and sample.kind is SampleKind.DATA and shared.from_shared(sample.writer):
                self.dropped += 1
                continue
            yield sample, receive_ns

    def shared_counts(self) -> str:
        """What came through shared memory and what DDS copies were left out ("" for a flow without)."""
        if self.shared is None:
            return ""
        return f"shared_memory={self.from_shared_memory} dds_copies_left_out={self.dropped}"

    def check_deadline(self) -> None:
        """Report a missed deadline of the samples that come through shared memory (after each wake-up)."""
        if self.shared is not None:
            self.shared.check_deadline()

    def close(self) -> None:
        if self.shared is not None:
            self.shared.close()


def _shared_info(source_timestamp: int) -> SimpleNamespace:
    """What DDS's sample info would say of a sample that came through shared memory: valid data of a live instance
    (no writer handle: the DDS reader never saw it)."""
    return SimpleNamespace(source_timestamp=source_timestamp, publication_handle=0, instance_handle=0,
                           instance_state=InstanceState.Alive, valid_data=True, sample_rank=0)


def check_transport(props: Properties) -> None:
    """config.transport and config.shmPrefix checked at start (a bad value is one line even when no flow read uses
    shared memory)."""
    shm.transport(props)
    shm.prefix_of(props)


def open_inputs(app: Application, flows: list[Flow], overrides: tuple[Any, ...] = (), hook: EventHook | None = None,
                shared_overrides: tuple[Any, ...] | None = None) -> list[FlowInput]:
    """A FlowInput of each flow (all closed again when one cannot be made); says which come through shared memory."""
    inputs: list[FlowInput] = []
    try:
        for flow in flows:
            inputs.append(FlowInput(app, flow, overrides, hook, shared_overrides))
    except BaseException:
        for made in inputs:
            made.close()
        raise
    shared = [flow_input for flow_input in inputs if flow_input.on_shared_memory]
    if shared:
        app.log.info("%s: shared memory with writers on this host, DDS with the others",
                     ", ".join(flow_input.flow.topic for flow_input in shared))
    return inputs
