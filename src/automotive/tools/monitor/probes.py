"""The monitor's own best-effort raw readers: how each of the system's flows moves, and the vehicle's state.

One reader per flow of the system (automotive.tools.flows: the topic names and types of the applications' properties)
takes the serialized samples without decoding them (automotive.wire.rawsample, Cyclone's buffers lent, no copy): it
counts samples and bytes per topic and notes when the last one arrived. Only what the monitor shows is decoded, and
only when a snapshot asks for it (at most once per new sample): the driver alert (AlertTopic), the platform's status
and commands (speed, steer, blinker), the number of fused objects (SensorObjects) and the newest LiDAR cloud, kept at
most every LIDAR_EVERY_S (2 s: within the issue's "at most 1 Hz"; drawing one costs about 50 ms) and drawn by the
LiDAR view's renderer (automotive.tools.cloudview) only when its picture is asked for (:meth:`Probes.lidar_png`). The
camera's frames are read only when asked (``--camera``): even lent, 4 MiB frames cost their reception.

The large flows (the camera's frames, the LiDAR's clouds: ``Flow.shared``) are read through shared memory from the
writers on the monitor's host, as the recorder and the bridge read them (automotive.wire.shm), when the monitor is given
its properties: its DDS readers of those flows carry the locality's mark, so a writer on this host writes nothing on
DDS for the monitor, and their DDS copies of such a writer's samples are left out uncounted. Writers of other hosts and
vendors are still read over DDS. A shared-memory subscriber is drained by a thread of its own as samples arrive: the
camera's reliable writer waits for its subscribers, and one taken only at each poll would hold it back.

The readers never slow a writer down and make no writer warn: a writer tells each reader whose request it cannot
meet (an incompatible QoS, in its /diagnostics), so each asks for less than any writer offers: best effort (a reliable
writer never waits for it), volatile, any latency budget (an asynchronous writer's too), both data representations, a
bounded history and bounded instances. Ownership must be equal on both sides, so a reader is made for each ownership
kind the topic's writers offer, once discovery shows them (:meth:`Probes.follow`): in redundant mode the exclusive one
also tells which instance owns the alerts. The alert's reader is reliable and transient local (the state from before
the monitor started) when every writer of its kind offers that. They are not the program's endpoints
(automotive.bus.endpoints): in no /diagnostics report of the monitor, no match report, no console line; the analysis
leaves them out of the mismatches and notices (automotive.tools.monitor.model).

Call :meth:`Probes.poll` at least every second (each reader keeps POLL_DEPTH samples per instance between two polls).
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from cyclonedds.core import DDSException
from cyclonedds.qos import DataReaderQos, Policy
from cyclonedds.sub import DataReader

from automotive.bus import alerts
from automotive.bus.checkedreader import decoder
from automotive.bus.endpoints import Databus
from automotive.bus.properties import Properties
from automotive.bus.qos import READER_REPRESENTATION
from automotive.tools.flows import Flow, system_flows
from automotive.tools.monitor.model import (
    STALE_AFTER_S,
    EndpointRecord,
    MeasuredFlow,
    ProgramReport,
    Vehicle,
    _number,
    say_once,
)
from automotive.types.Alerts import DriverAlerts
from automotive.types.Platform import PlatformControl, PlatformStatus
from automotive.types.Sensor import SensorObjectList
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.wire import shm
from automotive.wire.rawsample import RawReader, SampleKind

INFINITE_NS = 2**63 - 1
POLL_DEPTH = 64  # samples kept per instance between two polls: a second of a 60 Hz flow
CAMERA_DEPTH = 2  # the camera's frames are counted, never kept
MAX_INSTANCES = 1024  # instances per reader: a writer inventing keys without end cannot grow the monitor
RATE_WINDOW_S = 5.0  # rates are over about this long (the checkpoints of the polls within it)
# No rate over less: the first take of a new probe may bring the samples its reader kept while the monitor was busy,
# and over half a second those few made a 20/s flow look like more than 30/s (the monitor beside a whole test suite).
MIN_RATE_WINDOW_S = 1.0
LIDAR_EVERY_S = 2.0  # the LiDAR picture changes at most every 2 s (drawing it costs about 50 ms)
LIDAR_SIZE = (640, 320)
TAKE_LIMIT = 256
# camera_sub's /diagnostics figure: "N frames, latency p50 X ms, ..."
CAMERA_LATENCY = re.compile(r"latency p50 ([0-9.]+) ms")
SHOWN = (DriverAlerts, PlatformStatus, PlatformControl, SensorObjectList)


@dataclass
class Counter:
    """One topic's samples and bytes taken so far, and checkpoints of them at each poll, for the rates."""

    samples: int = 0
    bytes: int = 0
    last_at: float | None = None  # time.monotonic() of the last sample taken
    checkpoints: deque[tuple[float, int, int]] = field(default_factory=lambda: deque(maxlen=64))

    def checkpoint(self, now: float) -> None:
        self.checkpoints.append((now, self.samples, self.bytes))
        while len(self.checkpoints) > 2 and now - self.checkpoints[1][0] >= RATE_WINDOW_S:
            self.checkpoints.popleft()

    def rates(self) -> tuple[float, float] | None:
        """(samples/s, bytes/s) over the checkpoints kept; None until they span MIN_RATE_WINDOW_S."""
        if len(self.checkpoints) < 2:
            return None
        (first, samples, size), (last, samples_now, size_now) = self.checkpoints[0], self.checkpoints[-1]
        if last - first < MIN_RATE_WINDOW_S:
            return None
        return (samples_now - samples) / (last - first), (size_now - size) / (last - first)


@dataclass
class Latest:
    """The newest sample of a shown topic: its bytes (a copy), when it came, who wrote it; decoded once, on demand."""

    data: bytes
    at: float
    writer: int
    exclusive: bool
    sequence: int
    wall: float  # time.time() when it came
    decoded: Any = None
    decoded_sequence: int = -1


@dataclass
class Probe:
    flow: Flow
    raw: RawReader
    exclusive: bool
    strong: bool  # reliable and transient local (the alert's state from before the monitor started)
    keep_latest: bool
    local: shm.LocalWriters | None = None  # a shared flow's: the writers whose samples come through shared memory


class SharedProbe:
    """The monitor's shared-memory subscriber of one flow, drained on a thread of its own as samples arrive."""

    def __init__(self, memory: shm.SharedMemory, reader: shm.SharedReader,
                 taken: Callable[[list[shm.SharedSample]], None]):
        self.memory = memory
        self.reader = reader
        self._taken = taken
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"monitor-shm {memory.topic}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            if not self.reader.wait(shm.WAIT_SLICE_S):
                continue
            while not self._stop.is_set():
                with self.reader.take(shm.BORROWED) as samples:
                    if not samples:
                        break
                    self._taken(samples)

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.reader.close()
        self.memory.close()


STRONG_DURABILITY = ("TRANSIENT_LOCAL", "TRANSIENT", "PERSISTENT")


def reader_qos(depth: int, exclusive: bool, strong: bool) -> DataReaderQos:
    """What matches every writer of its ownership kind with no incompatible QoS on either side (the request below
    every offer), except ``strong``: reliable and transient local, for writers that all offer that."""
    return DataReaderQos(
        Policy.Reliability.Reliable(0) if strong else Policy.Reliability.BestEffort,
        Policy.Durability.TransientLocal if strong else Policy.Durability.Volatile,
        Policy.History.KeepLast(depth),
        Policy.ResourceLimits(max_samples=-1, max_instances=MAX_INSTANCES, max_samples_per_instance=depth),
        Policy.LatencyBudget(INFINITE_NS),
        Policy.Ownership.Exclusive if exclusive else Policy.Ownership.Shared,
        READER_REPRESENTATION)


def wanted_readers(writers: list[EndpointRecord], strong_wanted: bool) -> set[tuple[bool, bool]]:
    """The readers (exclusive, strong) that match these writers of one topic without an incompatible QoS at any of
    them (a writer tells every reader it cannot serve: the monitor must not make the system warn): one per ownership
    kind offered; strong only when every writer of that kind offers reliable and transient local."""
    wanted = set()
    for exclusive in (False, True):
        kind = [writer for writer in writers if (writer.qos.ownership == "EXCLUSIVE") == exclusive]
        if kind:
            strong = strong_wanted and all(writer.qos.reliability == "RELIABLE"
                                           and writer.qos.durability in STRONG_DURABILITY for writer in kind)
            wanted.add((exclusive, strong))
    return wanted


def writer_name(reader: DataReader[Any], handle: int) -> tuple[str | None, int | None]:
    """The entity name and ownership strength a writer's discovery data gives (None where it does not)."""
    try:
        data = reader.get_matched_publication_data(handle)
    except DDSException:  # already gone
        return None, None
    if data is None:
        return None, None
    qos = data.qos
    name = str(qos[Policy.EntityName].name) if Policy.EntityName in qos else None
    strength = int(qos[Policy.OwnershipStrength].strength) if Policy.OwnershipStrength in qos else None
    return name, strength


class Probes:
    """The raw readers of the system's flows on ``bus`` (the camera's only with ``camera``); see the module's doc.

    A reader is made once discovery shows a writer of its flow (:meth:`follow`), with what matches that writer's
    ownership kind and no more."""

    def __init__(self, bus: Databus, camera: bool = False, log: logging.Logger | None = None,
                 props: Properties | None = None):
        """``props``: the monitor's properties (config.transport, config.shmPrefix): the large flows of this host are
        then read through shared memory; None: everything on DDS."""
        self.bus = bus
        self.props = props
        self.shared: dict[str, SharedProbe | None] = {}  # topic -> its shared-memory subscriber (None: cannot be)
        self.log = log or logging.getLogger("automotive")
        self.lock = threading.RLock()
        # The LiDAR picture's own: drawing it takes up to seconds (the first time the renderer's import too), and the
        # samples, the snapshot's poll and the shared-memory thread must not wait for it under self.lock.
        self._drawing = threading.Lock()
        self.problems: list[str] = []
        self.probes: list[Probe] = []
        self.counters: dict[str, Counter] = {}
        self.latest: dict[str, Latest] = {}  # shown topic -> its newest sample
        self.topics: dict[type[Any], str] = {}  # shown type -> its topic
        self._sequence = 0
        self._lidar_kept_at = 0.0
        self._lidar_png: tuple[int, bytes] | None = None  # (the cloud's sequence, its picture)
        self._figure: Any = None
        flows = system_flows()
        self.camera_topic = next((flow.topic for flow in flows if flow.profile.startswith("Camera")), None)
        self.flows: dict[str, Flow] = {}
        for flow in flows:
            if flow.topic == "Circle" or (flow.topic == self.camera_topic and not camera):
                continue  # the Shapes Demo's is no flow of the vehicle; the camera's only when asked
            self.flows[flow.topic] = flow
            if flow.data_type in SHOWN:
                self.topics[flow.data_type] = flow.topic
            self.counters[flow.topic] = Counter()

    def follow(self, writers: list[EndpointRecord]) -> None:
        """Make (or remake) the readers the writers discovery shows call for; those no writer calls for stay."""
        with self.lock:
            by_topic: dict[str, list[EndpointRecord]] = {}
            for writer in writers:
                if writer.kind == "writer" and writer.topic in self.flows:
                    by_topic.setdefault(writer.topic, []).append(writer)
            for topic, found in by_topic.items():
                flow = self.flows[topic]
                wanted = wanted_readers(found, flow.data_type is DriverAlerts)
                have = {(probe.exclusive, probe.strong): probe for probe in self.probes if probe.flow.topic == topic}
                for key, probe in have.items():
                    if key not in wanted and (key[0], not key[1]) in wanted:
                        self._delete(probe)  # the same ownership kind, now the other strength
                for exclusive, strong in wanted - set(have):
                    self._make(flow, exclusive, strong)

    def _make(self, flow: Flow, exclusive: bool, strong: bool) -> None:
        depth = CAMERA_DEPTH if flow.topic == self.camera_topic else 1 if strong else POLL_DEPTH
        qos = reader_qos(depth, exclusive, strong)
        shared = self._shared(flow, qos)
        if shared is not None:  # marked: a writer on this host serves it through shared memory, not on DDS
            qos = DataReaderQos(shared.memory.user_data, base=qos)
        try:
            reader: DataReader[Any] = DataReader(self.bus.subscriber, self.bus.topic(flow.topic, flow.data_type),
                                                 qos=qos)
        except Exception as error:  # noqa: BLE001  (a reader Cyclone refuses: said, the others still read)
            problem = f"cannot read {flow.topic}: {error}"
            say_once(self.problems, problem)
            return
        keep = flow.data_type in SHOWN or flow.data_type is PointCloud2_
        local = shm.LocalWriters(reader, shared.memory.key) if shared is not None else None
        self.probes.append(Probe(flow, RawReader(reader), exclusive, strong, keep, local))

    def _shared(self, flow: Flow, qos: DataReaderQos) -> SharedProbe | None:
        """The shared-memory subscriber of a shared flow (made once; None without shared memory)."""
        if not flow.shared or self.props is None:
            return None
        if flow.topic not in self.shared:
            self.shared[flow.topic] = None
            memory = shm.open_for(self.props, self.bus.name, self.bus.domain_id, flow.topic, self.log)
            if memory is not None:
                try:
                    reader = shm.SharedReader(memory, qos)
                except shm.Unavailable as error:
                    memory.close()
                    shm.unavailable(self.props, flow.topic, str(error), self.log)
                else:
                    self.shared[flow.topic] = SharedProbe(memory, reader,
                                                          lambda samples: self._take_shared(flow, samples))
        return self.shared[flow.topic]

    def _take_shared(self, flow: Flow, samples: list[shm.SharedSample]) -> None:
        """Count samples that came through shared memory (the LiDAR's newest kept, a copy, as from DDS)."""
        with self.lock:
            now = time.monotonic()
            counter = self.counters[flow.topic]
            counter.samples += len(samples)
            counter.bytes += sum(len(sample.data) for sample in samples)
            counter.last_at = now
            if flow.data_type is PointCloud2_:
                self._keep_data(flow, samples[-1].data, 0, False, now)

    def close(self) -> None:
        """Stop the shared-memory subscribers (the DDS readers go with the participant)."""
        for shared in self.shared.values():
            if shared is not None:
                shared.close()
        self.shared.clear()

    def _delete(self, probe: Probe) -> None:
        self.probes.remove(probe)
        try:
            probe.raw.reader.__del__()
        except DDSException:
            pass

    # -- taking -------------------------------------------------------------------------------------------------------
    def poll(self) -> None:
        """Take what arrived: count it, keep the newest sample of each shown topic (the LiDAR's at most every
        LIDAR_EVERY_S)."""
        with self.lock:
            now = time.monotonic()
            for probe in self.probes:
                topic = probe.flow.topic
                counter = self.counters[topic]
                try:
                    while True:
                        with probe.raw.lend(TAKE_LIMIT) as samples:
                            if not samples:
                                break
                            newest = None
                            for sample in samples:
                                if probe.local is not None and probe.local.is_local(sample.writer):
                                    continue  # came through shared memory: counted there
                                if sample.kind is SampleKind.DATA:
                                    counter.samples += 1
                                    counter.bytes += len(sample.data)
                                    newest = sample
                            if newest is not None:
                                counter.last_at = now
                                if probe.keep_latest:
                                    self._keep(probe, newest, now)
                        if len(samples) < TAKE_LIMIT:
                            break
                except (DDSException, RuntimeError, ValueError) as error:
                    problem = f"cannot take {topic}: {error}"
                    say_once(self.problems, problem)
            for counter in self.counters.values():
                counter.checkpoint(now)

    def _keep(self, probe: Probe, sample: Any, now: float) -> None:
        self._keep_data(probe.flow, sample.data, sample.writer, probe.exclusive, now)

    def _keep_data(self, flow: Flow, data: Any, writer: int, exclusive: bool, now: float) -> None:
        if flow.data_type is PointCloud2_:
            if now - self._lidar_kept_at < LIDAR_EVERY_S:
                return
            self._lidar_kept_at = now
        self._sequence += 1
        self.latest[flow.topic] = Latest(bytes(data), now, writer, exclusive, self._sequence, time.time())

    # -- what it measured ---------------------------------------------------------------------------------------------
    def measured(self) -> dict[str, MeasuredFlow]:
        with self.lock:
            now = time.monotonic()
            found = {}
            for topic, counter in self.counters.items():
                rates = counter.rates()
                found[topic] = MeasuredFlow(None if rates is None else round(rates[0], 3),
                                        None if rates is None else round(rates[1], 1),
                                        None if counter.last_at is None else round(now - counter.last_at, 1))
            return found

    def _decoded(self, data_type: type[Any]) -> tuple[Any, Latest] | None:
        """The newest sample of a shown type, decoded (once per sample); None when none came or it does not decode."""
        topic = self.topics.get(data_type) if data_type is not PointCloud2_ else self.lidar_topic
        latest = self.latest.get(topic) if topic else None
        if latest is None:
            return None
        if latest.decoded_sequence != latest.sequence:
            latest.decoded_sequence = latest.sequence
            try:
                latest.decoded = decoder(data_type)(latest.data)
            except Exception as error:  # noqa: BLE001  (whatever a decoder raises for bytes it cannot decode)
                latest.decoded = None
                problem = f"a sample of {topic} does not decode: {error}"
                say_once(self.problems, problem)
        return (latest.decoded, latest) if latest.decoded is not None else None

    @property
    def lidar_topic(self) -> str | None:
        return next((probe.flow.topic for probe in self.probes if probe.flow.data_type is PointCloud2_), None)

    def vehicle(self, reports: list[ProgramReport]) -> Vehicle:
        """The vehicle's state from the newest samples and camera_sub's /diagnostics; None for what is unknown."""
        with self.lock:
            now = time.monotonic()
            vehicle = Vehicle()
            alert = self._decoded(DriverAlerts)
            if alert is not None:
                sample, latest = alert
                vehicle.alert = alerts.raised(sample)
                vehicle.alert_texts = alerts.alert_texts(sample)
                vehicle.alert_age_s = round(now - latest.at, 1)
                vehicle.redundant = latest.exclusive
                if latest.exclusive:
                    probe = next((p for p in self.probes if p.exclusive and p.flow.data_type is DriverAlerts), None)
                    if probe is not None:
                        vehicle.alert_owner, vehicle.alert_owner_strength = writer_name(probe.raw.reader,
                                                                                        latest.writer)
            status = self._decoded(PlatformStatus)
            if status is not None:
                sample, latest = status
                vehicle.speed_kmh = _finite(sample.vehSpd)
                vehicle.steer_angle = _finite(sample.vehicleSteerAngle)
                vehicle.blinker = _enum_name(sample.blinkerStatus)
                vehicle.status_age_s = round(now - latest.at, 1)
            control = self._decoded(PlatformControl)
            if control is not None:
                sample, latest = control
                vehicle.command_speed = _finite(sample.speed)
                vehicle.command_steer_angle = _finite(sample.vehicleSteerAngle)
                vehicle.command_blinker = _enum_name(sample.blinkerStatus)
                vehicle.command_age_s = round(now - latest.at, 1)
            objects = self._decoded(SensorObjectList)
            if objects is not None:
                sample, latest = objects
                vehicle.fused_objects = len(sample.objects)
                vehicle.fused_objects_age_s = round(now - latest.at, 1)
            lidar_topic = self.lidar_topic
            cloud = self.latest.get(lidar_topic) if lidar_topic else None
            if cloud is not None:
                vehicle.lidar_image_at = cloud.wall
                vehicle.lidar_age_s = round(now - cloud.at, 1)
                decoded = self._decoded(PointCloud2_)
                if decoded is not None:
                    vehicle.lidar_points = int(decoded[0].width_) * int(decoded[0].height_)
            camera_program(reports, self.camera_topic, vehicle)
            return vehicle

    def lidar_png(self) -> bytes | None:
        """The newest LiDAR cloud kept (at most one every LIDAR_EVERY_S) as a PNG by the LiDAR view's renderer; drawn
        once per cloud, when asked, outside self.lock; None before the first cloud (or when it cannot be drawn)."""
        with self._drawing:
            with self.lock:
                decoded = self._decoded(PointCloud2_)
                if decoded is None:
                    return None
                cloud, latest = decoded
                sequence, topic = latest.sequence, self.lidar_topic
                if self._lidar_png is not None and self._lidar_png[0] == sequence:
                    return self._lidar_png[1]
            import io

            from automotive.tools.cloudview import CloudFigure
            from automotive.wire.pointcloud import decode_point_cloud2

            try:
                xyz, rgb = decode_point_cloud2(cloud)
            except ValueError as error:
                with self.lock:
                    problem = f"cannot draw a cloud of {topic}: {error}"
                    say_once(self.problems, problem)
                return None
            if self._figure is None:
                self._figure = CloudFigure(LIDAR_SIZE, 1, f"LiDAR point cloud: {topic}")
            stamp = cloud.header_.stamp_
            image = self._figure.render(xyz, rgb, f"{len(xyz):>6d} points  stamp {stamp.sec_}.{stamp.nanosec_:09d}  "
                                                  f"frame '{str(cloud.header_.frame_id_)[:32]}'")
            from PIL import Image

            buffer = io.BytesIO()
            Image.fromarray(image).save(buffer, format="PNG", compress_level=1)
            self._lidar_png = (sequence, buffer.getvalue())
            return self._lidar_png[1]


def _finite(value: Any) -> float | None:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return round(number, 3) if number == number and abs(number) != float("inf") else None


def _enum_name(value: Any) -> str | None:
    name = getattr(value, "name", None)
    return str(name) if name is not None else None if value is None else str(value)


def camera_program(reports: list[ProgramReport], camera_topic: str | None, vehicle: Vehicle) -> None:
    """The camera's rate (frames in per second) and latency (p50, ms) as camera_sub reports them on /diagnostics."""
    for report in sorted(reports, key=lambda r: (r.age_s, r.name)):
        if not report.name.startswith("camera_sub") or report.age_s > STALE_AFTER_S:
            continue
        vehicle.camera_program = report.name
        rate = report.value(f"{camera_topic} in/s") if camera_topic else None
        if rate is None:  # another frame size's topic: the first one it reads
            rate = next((value for key, value in report.values if key.startswith("CameraImage")
                         and key.endswith(" in/s")), None)
        vehicle.camera_rate = _number(rate) if rate is not None else None
        latency = report.value("latency p50 ms")
        if latency is None:
            found = CAMERA_LATENCY.search(report.value("figure") or "")
            latency = found.group(1) if found else None
        vehicle.camera_latency_ms = _number(latency) if latency is not None else None
        return
