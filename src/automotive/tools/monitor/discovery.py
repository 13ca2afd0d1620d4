"""The DDS side of the monitor: Cyclone's built-in discovery readers and a reader of rt/diagnostics, turned into the
records of automotive.tools.monitor.model.

What discovery tells, measured with Cyclone DDS 11 (the built-in topics DCPSParticipant, DCPSPublication,
DCPSSubscription):

- every participant's GUID, whose first two bytes are its vendor id (0x0110 Cyclone, 0x0101 RTI Connext, 0x010f
  Fast DDS: the RTPS specification's recommendation, which these follow), its EntityName when it gives one, and its
  property list: Cyclone sends ``__Hostname``, ``__Pid``, ``__ProcessName``; RTI Connext 6 sends
  ``dds.sys_info.hostname``, ``dds.sys_info.process_id``, ``dds.sys_info.executable_filepath``; Fast DDS sends
  ``fastdds.physical_data.host`` and ``...process`` when configured to;
- every writer and reader with its topic and type names, its QoS (Cyclone fills the specification's defaults for
  what a remote endpoint leaves out) and whether it sent XTypes type information.

The monitor writes no data: its readers are these built-in ones and the reader of rt/diagnostics (the framework
gives it its own /diagnostics writer, as every program has).
"""

from __future__ import annotations

import re
import threading
import time
from pathlib import PurePath
from typing import Any

from cyclonedds.builtin import (
    BuiltinDataReader,
    BuiltinTopicDcpsParticipant,
    BuiltinTopicDcpsPublication,
    BuiltinTopicDcpsSubscription,
)
from cyclonedds.core import DDSException, InstanceState, ReadCondition, SampleState, ViewState
from cyclonedds.qos import Policy

from automotive.bus.diagnostics import DIAGNOSTICS_TOPIC
from automotive.bus.endpoints import Databus
from automotive.bus.properties import Properties
from automotive.bus.qos import ROS2_DEFAULT_PROFILE
from automotive.tools.monitor.model import (
    STALE_AFTER_S,
    EndpointRecord,
    ParticipantRecord,
    ProgramReport,
    Snapshot,
    analyse,
    say_once,
)
from automotive.tools.monitor.probes import Probes
from automotive.tools.monitor.rules import INFINITE_NS, XCDR1, XCDR2, EndpointQos
from automotive.types.diagnostic_msgs.msg.dds_ import DiagnosticArray_

CHUNK = 256  # samples per read or take of a built-in topic
MAX_REPORTS = 1000  # programs remembered (a name that comes and goes under new names cannot grow it past this)
FORGET_AFTER_S = 300.0  # a program silent this long is forgotten
MAX_VALUES = 500  # key/values kept per report
MAX_TEXT = 4096  # characters kept of a report's strings
HOST_KEYS = ("__Hostname", "dds.sys_info.hostname", "fastdds.physical_data.host")
PID_KEYS = ("__Pid", "dds.sys_info.process_id", "fastdds.physical_data.process")
PROCESS_KEYS = ("__ProcessName", "dds.sys_info.executable_filepath")
BUILTIN_TYPE_PREFIX = "org::eclipse::cyclonedds::builtin::"
FOLLOW_S = 1.0  # how often a poll looks for writers of the flows the probes read


def _kind(policy: Any) -> str:
    """``Policy.Durability.TransientLocal`` -> ``TRANSIENT_LOCAL``."""
    name = type(policy).__name__.split(".")[-1]
    return re.sub(r"(?<!^)(?=[A-Z])", "_", name).upper()


def _ns(value: Any, default: int) -> int:
    return value if isinstance(value, int) else default


def endpoint_qos(qos: Any, type_name: str, type_information: bool, reader: bool) -> EndpointQos:
    """The matching facts of an endpoint's QoS as Cyclone gives it (a missing policy: the specification's default)."""
    policies = {getattr(policy, "__scope__", ""): policy for policy in qos}
    facts: dict[str, Any] = {"type_name": type_name, "type_information": type_information,
                             "reliability": "BEST_EFFORT" if reader else "RELIABLE"}
    for scope, name in (("Reliability", "reliability"), ("Durability", "durability"), ("Ownership", "ownership"),
                        ("DestinationOrder", "destination_order"), ("Liveliness", "liveliness"),
                        ("PresentationAccessScope", "presentation")):
        if scope in policies:
            facts[name] = _kind(policies[scope])
    if "Liveliness" in policies:
        facts["lease_ns"] = _ns(getattr(policies["Liveliness"], "lease_duration", None), INFINITE_NS)
    if "PresentationAccessScope" in policies:
        facts["coherent_access"] = bool(getattr(policies["PresentationAccessScope"], "coherent_access", False))
        facts["ordered_access"] = bool(getattr(policies["PresentationAccessScope"], "ordered_access", False))
    for scope, name, attribute, default in (("Deadline", "deadline_ns", "deadline", INFINITE_NS),
                                            ("LatencyBudget", "latency_budget_ns", "budget", 0),
                                            ("Lifespan", "lifespan_ns", "lifespan", INFINITE_NS),
                                            ("TimeBasedFilter", "time_based_filter_ns", "filter_time", 0)):
        if scope in policies:
            facts[name] = _ns(getattr(policies[scope], attribute, None), default)
    if "Partition" in policies:
        facts["partitions"] = tuple(str(name) for name in getattr(policies["Partition"], "partitions", ()))
    if "OwnershipStrength" in policies:
        facts["ownership_strength"] = _ns(getattr(policies["OwnershipStrength"], "strength", None), 0)
    if "History" in policies:
        history = policies["History"]
        depth = getattr(history, "depth", None)
        facts["history"] = f"KEEP_LAST {depth}" if depth is not None else _kind(history)
    representation = policies.get("DataRepresentation")
    if representation is not None:
        # Discovery gives the set, not its order: a writer offering both is taken to write XCDR1, its first by
        # convention (Cyclone's and ours).
        chosen = tuple(name for name, on in ((XCDR1, representation.use_cdrv0_representation),
                                             (XCDR2, representation.use_xcdrv2_representation)) if on)
        facts["representations"] = chosen or ("other",)
    return EndpointQos(**facts)


def _properties(qos: Any) -> dict[str, str]:
    return {policy.key: policy.value for policy in qos if isinstance(policy, Policy.Property)}


def _entity_name(qos: Any) -> str | None:
    return next((policy.name for policy in qos if isinstance(policy, Policy.EntityName)), None)


def participant_record(sample: Any, own_key: str) -> ParticipantRecord:
    properties = _properties(sample.qos)
    key_bytes = sample.key.bytes
    process = next((properties[key] for key in PROCESS_KEYS if key in properties), None)
    return ParticipantRecord(
        key=str(sample.key), name=_entity_name(sample.qos), vendor_id=int.from_bytes(key_bytes[:2], "big"),
        host=next((properties[key] for key in HOST_KEYS if key in properties), None),
        pid=next((properties[key] for key in PID_KEYS if key in properties), None),
        process=PurePath(process).name if process and "/" in process else process, own=str(sample.key) == own_key)


def endpoint_record(sample: Any, kind: str) -> EndpointRecord:
    type_name = str(sample.type_name)
    return EndpointRecord(str(sample.key), str(sample.participant_key), kind, str(sample.topic_name),
                          endpoint_qos(sample.qos, type_name, sample.type_id is not None, kind == "reader"),
                          _entity_name(sample.qos))


class DomainView:
    """The monitor's view of its domain, kept up to date by :meth:`poll`; :meth:`snapshot` analyses it."""

    def __init__(self, bus: Databus, camera: bool = False, probes: bool = True, props: Properties | None = None):
        self.bus = bus
        self.lock = threading.RLock()  # a page's server may snapshot from one thread and draw the LiDAR from another
        participant = bus.participant
        self.own_key = str(participant.guid)
        self.readers = {name: BuiltinDataReader(participant, topic) for name, topic in (
            ("participant", BuiltinTopicDcpsParticipant), ("writer", BuiltinTopicDcpsPublication),
            ("reader", BuiltinTopicDcpsSubscription))}
        any_sample = SampleState.Any | ViewState.Any
        self._fresh = {name: ReadCondition(reader, SampleState.NotRead | ViewState.Any | InstanceState.Alive)
                       for name, reader in self.readers.items()}
        self._known: dict[str, dict[int, ParticipantRecord | EndpointRecord | None]] = {
            name: {} for name in self.readers}  # instance handle -> its record
        self._gone = {name: ReadCondition(reader, any_sample | InstanceState.NotAliveDisposed
                                          | InstanceState.NotAliveNoWriters)
                      for name, reader in self.readers.items()}
        # Every program's health; history deep enough for a second of every program's report between two polls.
        self.diagnostics = bus.reader(DIAGNOSTICS_TOPIC, DiagnosticArray_, ROS2_DEFAULT_PROFILE,
                                      overrides=(Policy.History.KeepLast(256),))
        self.reports: dict[tuple[str, str, str], tuple[Any, float]] = {}  # (name, host, pid) -> (report, received)
        self.moved: dict[str, float] = {}  # topic -> when a report last showed it moving (monotonic)
        self.problems: list[str] = []  # discovery data that could not be read, said once each
        # The monitor's own raw readers of the system's flows (the camera's only with ``camera``).
        self.probes = Probes(bus, camera, props=props) if probes else None  # props: shared memory too
        self._followed = -FOLLOW_S

    def _current(self, name: str) -> list[Any]:
        """The records of the live instances of one built-in topic (ParticipantRecord, EndpointRecord; None for the
        built-in endpoints), kept between calls by instance: only what is new or changed is read and converted. The
        departed instances are taken, and forgotten, so that a participant that comes and goes a thousand times
        leaves nothing behind. Read in chunks: Cyclone allocates what a read of N samples may return."""
        reader, known = self.readers[name], self._known[name]
        try:
            while True:
                gone = reader.take(N=CHUNK, condition=self._gone[name])
                for sample in gone:
                    known.pop(sample.sample_info.instance_handle, None)
                if len(gone) < CHUNK:
                    break
            while True:
                fresh = reader.read(N=CHUNK, condition=self._fresh[name])
                for sample in fresh:
                    if sample.sample_info.valid_data:
                        known[sample.sample_info.instance_handle] = self._record(name, sample)
                if len(fresh) < CHUNK:
                    break
        except (DDSException, ValueError, TypeError, UnicodeError) as error:
            self._problem(f"cannot read the built-in {name} topic: {error}")
        return [record for record in known.values() if record is not None]

    def _record(self, name: str, sample: Any) -> ParticipantRecord | EndpointRecord | None:
        try:
            if name == "participant":
                return participant_record(sample, self.own_key)
            if str(sample.type_name).startswith(BUILTIN_TYPE_PREFIX):
                return None
            return endpoint_record(sample, name)
        except (ValueError, TypeError, UnicodeError, AttributeError, KeyError) as error:
            self._problem(f"cannot read a {name} of the built-in topic: {error}")
            return None

    def _problem(self, problem: str) -> None:
        say_once(self.problems, problem)

    def close(self) -> None:
        """Stop what runs beside the participant (the probes' shared-memory subscribers)."""
        if self.probes is not None:
            self.probes.close()

    def poll(self) -> None:
        """Take the probes' samples and the /diagnostics reports that arrived; call it at least every second. The
        reports last: a report's age is counted from its take, and what the probes do first (make readers, take the
        samples) must not count as the reports' age (with everything STALE after a slow step)."""
        with self.lock:
            if self.probes is not None:
                now = time.monotonic()
                if now - self._followed >= FOLLOW_S:  # the writers of the flows it reads: which readers to have
                    self._followed = now
                    self.probes.follow(self._current("writer"))
                self.probes.poll()
            self._poll()

    def _poll(self) -> None:
        now = time.monotonic()
        while True:
            samples = self.diagnostics.take(N=256)
            if not samples:
                break
            for sample in samples:
                for status in getattr(sample, "status_", ()):
                    self._report(status, now)
        for key, (_, received) in list(self.reports.items()):
            if now - received > FORGET_AFTER_S:
                del self.reports[key]
        for topic, at in list(self.moved.items()):
            if now - at > FORGET_AFTER_S:
                del self.moved[topic]

    def _report(self, status: Any, now: float) -> None:
        values = tuple((str(pair.key_)[:MAX_TEXT], str(pair.value_)[:MAX_TEXT]) for pair in status.values_[:MAX_VALUES])
        report = ProgramReport(str(status.name_)[:MAX_TEXT], str(status.hardware_id_)[:MAX_TEXT], int(status.level_),
                               str(status.message_)[:MAX_TEXT], values, 0.0)
        # Two programs of one name on one host (another system on the same domain) are two; a program restarted
        # (a new pid) replaces its own stale report.
        key = (report.name, report.host, report.value("pid") or "")
        for other in [other for other, (_, received) in self.reports.items()
                      if other[:2] == key[:2] and other != key and now - received > STALE_AFTER_S]:
            del self.reports[other]
        if key not in self.reports and len(self.reports) >= MAX_REPORTS:
            oldest = min(self.reports, key=lambda item: self.reports[item][1])
            del self.reports[oldest]
        self.reports[key] = (report, now)
        for name, value in values:
            for suffix in (" out/s", " in/s"):
                if name.endswith(suffix):
                    try:
                        moving = float(value) > 0
                    except ValueError:
                        moving = False
                    if moving:
                        self.moved[name[:-len(suffix)]] = now

    def records(self) -> tuple[list[ParticipantRecord], list[EndpointRecord]]:
        participants = [record for record in self._current("participant") if isinstance(record, ParticipantRecord)]
        endpoints = [record for kind in ("writer", "reader") for record in self._current(kind)
                     if isinstance(record, EndpointRecord)]
        return participants, endpoints

    def snapshot(self) -> Snapshot:
        with self.lock:
            self.poll()
            now = time.monotonic()
            participants, endpoints = self.records()
            reports = [ProgramReport(report.name, report.host, report.level, report.message, report.values,
                                     now - received) for report, received in self.reports.values()]
            moved_ago = {topic: now - at for topic, at in self.moved.items()}
            if self.probes is not None:
                self.probes.follow(endpoints)
                self._followed = now
            measured = self.probes.measured() if self.probes is not None else {}
            vehicle = self.probes.vehicle(reports) if self.probes is not None else None
            if self.probes is not None:
                for problem in self.probes.problems:
                    say_once(self.problems, problem)
            return analyse(self.bus.domain_id, participants, endpoints, reports, moved_ago, measured=measured,
                           vehicle=vehicle)

    def lidar_png(self) -> bytes | None:
        """The newest LiDAR cloud as a PNG (it changes at most every 2 s: ``vehicle.lidar_image_at``); None
        before the first cloud. For a page's ``/lidar.png``. Drawn without the view's lock: a snapshot does not wait
        for a picture (the probes keep their own)."""
        if self.probes is None:
            return None
        return self.probes.lidar_png()
