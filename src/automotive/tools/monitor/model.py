"""The snapshot of a domain: what ``automotive monitor`` prints and what its page renders.

:func:`analyse` builds a :class:`Snapshot` from plain records: the participants and endpoints discovery gives
(:class:`ParticipantRecord`, :class:`EndpointRecord`) and the programs' latest /diagnostics reports
(:class:`ProgramReport`). It needs no DDS, so every case (absurd names, unknown vendors, QoS at its limits) is tested
with records made by hand. :meth:`Snapshot.to_dict` / :meth:`Snapshot.to_json` is the document a page renders and
``--json`` prints.

Which pairs match is the monitor's judgement by the DDS rules (automotive.tools.monitor.rules): Cyclone tells the
matched endpoints of its *own* readers and writers only, never whether two other programs' endpoints matched.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from automotive.bus.diagnostics import (
    DIAGNOSTICS_TOPIC,
    LATENCY_FROM,
    LATENCY_P50,
    LATENCY_P99,
    LATENCY_SAMPLES,
)
from automotive.tools.monitor.rules import (
    INFINITE_NS,
    EndpointQos,
    Reason,
    hints,
    mismatch_reasons,
    participant_hint,
)

UNKNOWN = "unknown"
LEVELS = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}
STALE_AFTER_S = 5.0  # a program whose last report is older than this is STALE (it reports every second)
MAX_PROBLEMS = 100  # problems the monitor says (each once): a bus that keeps failing must not grow the list


def say_once(problems: list[str], problem: str) -> None:
    """Add ``problem`` to ``problems`` unless it is there already or the list holds MAX_PROBLEMS."""
    if problem not in problems and len(problems) < MAX_PROBLEMS:
        problems.append(problem)


# RTPS vendor ids (the OMG's list), found in the first two bytes of a GUID prefix, as the RTPS specification
# recommends and Cyclone DDS, RTI Connext 6 and Fast DDS do.
VENDORS = {
    0x0101: "RTI Connext DDS", 0x0102: "ADLINK OpenSplice", 0x0103: "OCI OpenDDS", 0x0104: "MilSoft Mil-DDS",
    0x0105: "Kongsberg InterCOM DDS", 0x0106: "Twin Oaks CoreDX DDS", 0x0107: "Lakota Technical Solutions",
    0x0108: "ICOUP Consulting", 0x0109: "ETRI Diamond DDS", 0x010A: "RTI Connext DDS Micro",
    0x010B: "ADLINK Vortex Cafe", 0x010C: "PrismTech", 0x010D: "ADLINK Vortex Lite", 0x010E: "Technicolor Qeo",
    0x010F: "eProsima Fast DDS", 0x0110: "Eclipse Cyclone DDS", 0x0111: "GurumNetworks GurumDDS",
    0x0112: "Atostek RustDDS", 0x0113: "Nanjing Zhenrong ZRDDS", 0x0114: "S2E Software Dust DDS",
}


def vendor_name(vendor_id: int | None) -> str:
    if vendor_id is None:
        return UNKNOWN
    return VENDORS.get(vendor_id, UNKNOWN)


@dataclass(frozen=True)
class ParticipantRecord:
    """One participant as discovery gives it (None: not told)."""

    key: str
    name: str | None = None
    vendor_id: int | None = None
    host: str | None = None
    pid: str | None = None
    process: str | None = None
    own: bool = False  # the monitor's own participant


@dataclass(frozen=True)
class EndpointRecord:
    """One writer or reader as discovery gives it."""

    key: str
    participant: str
    kind: str  # "writer" | "reader"
    topic: str
    qos: EndpointQos
    name: str | None = None


@dataclass(frozen=True)
class ProgramReport:
    """One program's latest /diagnostics status and how long ago it arrived."""

    name: str
    host: str
    level: int
    message: str
    values: tuple[tuple[str, str], ...]
    age_s: float

    def value(self, key: str) -> str | None:
        return next((value for name, value in self.values if name == key), None)


# -- the snapshot -----------------------------------------------------------------------------------------------------
@dataclass
class Participant:
    key: str
    name: str
    vendor: str
    vendor_id: str
    host: str
    pid: str
    process: str
    own: bool
    health: str | None = None  # the level of its program's /diagnostics, when one reports under its name
    writers: list[str] = field(default_factory=list)
    readers: list[str] = field(default_factory=list)
    hints: list[str] = field(default_factory=list)
    # The name, and where another participant has the same name, what tells them apart: "hmi (pid 4242)", or the
    # host when the pids do not ("hmi (pid 4242 on car)"). Set by analyse().
    label: str = ""


@dataclass
class Endpoint:
    key: str
    participant: str
    participant_name: str
    kind: str
    topic: str
    type_name: str
    name: str | None
    qos: EndpointQos
    matched: list[str] = field(default_factory=list)  # the keys of the endpoints it matches (by the rules)

    def to_dict(self) -> dict[str, Any]:
        return {"key": self.key, "participant": self.participant, "participant_name": self.participant_name,
                "kind": self.kind, "topic": self.topic, "type_name": self.type_name, "name": self.name,
                "qos": self.qos.to_dict(), "matched": self.matched}


@dataclass
class Topic:
    name: str
    type_names: list[str]
    writers: list[str]
    readers: list[str]


@dataclass
class Match:
    topic: str
    writer: str
    reader: str
    writer_participant: str
    reader_participant: str
    hints: list[str] = field(default_factory=list)


@dataclass
class Mismatch:
    topic: str
    writer: str
    reader: str
    writer_participant: str
    reader_participant: str
    reasons: list[Reason]
    hints: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"topic": self.topic, "writer": self.writer, "reader": self.reader,
                "writer_participant": self.writer_participant, "reader_participant": self.reader_participant,
                "reasons": [reason.to_dict() for reason in self.reasons], "hints": self.hints}


@dataclass
class Notice:
    """A reader with no writer of its topic, a reader that matched none of its topic's writers, a topic with writers
    and no reader."""

    kind: str  # "reader without writer" | "reader matched no writer" | "topic without reader"
    topic: str | None
    subject: str | None  # the endpoint or participant key
    words: str


@dataclass
class Flow:
    """One topic's traffic as the programs' /diagnostics report it and the monitor's own raw readers measure it."""

    topic: str
    rate: float  # samples/s: what its writers report writing (else the most any reader reports reading, else what
    # the monitor's own reader measures)
    writers: dict[str, float]  # program -> samples out/s
    readers: dict[str, float]  # program -> samples in/s
    last_sample_age_s: float | None  # since a report showed it moving or the monitor took a sample; None: never seen
    deadline_missed: int
    liveliness_changes: int
    samples_lost: int
    incompatible_qos: int
    bytes_per_s: float | None = None  # serialized bytes/s the monitor's own reader takes; None: not read by it
    monitor_rate: float | None = None  # samples/s the monitor's own reader takes; None: not read by it
    # reader program -> its latency of the topic over the last 10 s (Latency's fields but topic, writer and reader)
    latency: dict[str, dict[str, Any]] = field(default_factory=dict)
    # Expected to move all the time: a writer offers (or a reader requests) a finite deadline. A topic written on
    # change (the driver alerts, Shapes Demo's Circle) has none, and is quiet by design at 0 samples/s.
    periodic: bool = False


# Whether the two ends of a latency share a clock: on one host they do; across hosts each writer stamps with its own
# clock (a figure then is off by the hosts' clock difference, and is shown marked, never as if exact).
CLOCK_SHARED, CLOCK_NOT_SHARED, CLOCK_UNKNOWN = "shared", "not shared", "unknown host"


@dataclass
class Latency:
    """A topic's latency as one reader program measured it over the last 10 s (its /diagnostics): reception minus
    the writer's source timestamp; from one writer participant (a pair) or from all of them (``writer`` None)."""

    topic: str
    writer: str | None  # the writer's participant name (several joined by '+': shared memory from two writers)
    reader: str  # the reader's program (its participant has the same name)
    p50_ms: float
    p99_ms: float
    samples: int  # in the last 10 s
    clock: str  # CLOCK_SHARED: writer and reader on one host; CLOCK_NOT_SHARED; CLOCK_UNKNOWN: a host not known
    writer_host: str | None = None
    reader_host: str | None = None


@dataclass
class ChainHop:
    topic: str
    writer: str  # the application that writes it
    reader: str  # the application that reads it
    latency: Latency | None  # the reader's figure for the topic (the slowest reader's, when several); None: none


CHAIN_HOPS = (("VisionTopic", "vision", "sensor_fusion"), ("SensorObjects", "sensor_fusion", "collision_avoidance"),
              ("AlertTopic", "collision_avoidance", "hmi"))
CHAIN_BASIS = ("the sum of the hops' p50 and of their p99 (vision -> sensor_fusion -> collision_avoidance -> hmi), "
               "each hop from its writer's source timestamp to its reader's take (a wait in the reader's queue "
               "counts); the time each application takes between its take and its next write is not in it, and a "
               "sum of p99s is not the p99 of the sum: an estimate, not an end-to-end measurement")


@dataclass
class Chain:
    """The alert chain from vision to the driver's alert, as the sum of its hops' latencies (CHAIN_BASIS)."""

    hops: list[ChainHop]
    p50_ms: float | None  # over the hops that have a figure (``missing`` names the others); None: none has
    p99_ms: float | None
    clock: str  # CLOCK_SHARED only when every hop's is
    missing: list[str] = field(default_factory=list)  # the hops' topics without a sample in the last 10 s
    basis: str = CHAIN_BASIS

    def to_dict(self) -> dict[str, Any]:
        return {"hops": [{"topic": hop.topic, "writer": hop.writer, "reader": hop.reader,
                          "latency": None if hop.latency is None else vars(hop.latency)} for hop in self.hops],
                "p50_ms": self.p50_ms, "p99_ms": self.p99_ms, "clock": self.clock, "missing": self.missing,
                "basis": self.basis}


@dataclass
class MeasuredFlow:
    """What the monitor's own raw reader measured of a topic (None: not yet, or not read)."""

    samples_per_s: float | None
    bytes_per_s: float | None
    last_sample_age_s: float | None


@dataclass
class Vehicle:
    """The vehicle's state as the monitor's readers last saw it; None where unknown (no sample yet, not read)."""

    alert: list[str] | None = None  # the active alerts (DriverAlerts' member names); []: all clear
    alert_texts: list[str] | None = None  # the same as the HMI words them
    alert_age_s: float | None = None  # since the alert state was taken
    redundant: bool | None = None  # the alert came through the exclusive reader (redundant mode)
    alert_owner: str | None = None  # redundant mode: the instance that owns the alerts (its writer's entity name)
    alert_owner_strength: int | None = None
    speed_kmh: float | None = None  # PlatformStatus.vehSpd
    steer_angle: float | None = None  # PlatformStatus.vehicleSteerAngle
    blinker: str | None = None  # PlatformStatus.blinkerStatus (INDICATOR_OFF, _LEFT, _RIGHT, _HAZARD)
    status_age_s: float | None = None
    command_speed: float | None = None  # PlatformControl: what collision avoidance commands
    command_steer_angle: float | None = None
    command_blinker: str | None = None
    command_age_s: float | None = None
    fused_objects: int | None = None  # objects in the newest SensorObjects list
    fused_objects_age_s: float | None = None
    lidar_points: int | None = None
    lidar_image_at: float | None = None  # time.time() of the cloud the LiDAR picture shows (changes at most every 2 s)
    lidar_age_s: float | None = None
    camera_program: str | None = None  # the camera_sub whose /diagnostics the camera figures come from
    camera_rate: float | None = None  # frames/s camera_sub receives
    camera_latency_ms: float | None = None  # camera_sub's median latency, ms

    def to_dict(self) -> dict[str, Any]:
        found = dict(vars(self))
        at = self.lidar_image_at
        found["lidar_image_at"] = None if at is None else (
            time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(at)) + f".{int(at * 1000) % 1000:03d}Z")
        return found


@dataclass
class ProgramHealth:
    name: str
    host: str
    level: str
    message: str
    report_age_s: float
    pid: str | None
    values: dict[str, str]


@dataclass
class Snapshot:
    domain: int
    taken_at: float  # time.time()
    participants: list[Participant]
    topics: list[Topic]
    endpoints: list[Endpoint]
    matches: list[Match]
    mismatches: list[Mismatch]
    notices: list[Notice]
    flows: list[Flow]
    programs: list[ProgramHealth]
    vehicle: Vehicle = field(default_factory=Vehicle)
    latencies: list[Latency] = field(default_factory=list)  # per pair: writer participant -> reader program
    chain: Chain | None = None

    def participant(self, key: str) -> Participant | None:
        return next((p for p in self.participants if p.key == key), None)

    def endpoint(self, key: str) -> Endpoint | None:
        return next((e for e in self.endpoints if e.key == key), None)

    def to_dict(self) -> dict[str, Any]:
        return {
            "domain": self.domain,
            "taken_at": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(self.taken_at)) + "Z",
            "participants": [vars(p) for p in self.participants],
            "topics": [vars(t) for t in self.topics],
            "endpoints": [e.to_dict() for e in self.endpoints],
            "matches": [vars(m) for m in self.matches],
            "mismatches": [m.to_dict() for m in self.mismatches],
            "notices": [vars(n) for n in self.notices],
            "flows": [vars(f) for f in self.flows],
            "programs": [vars(p) for p in self.programs],
            "vehicle": self.vehicle.to_dict(),
            "latencies": [vars(latency) for latency in self.latencies],
            "chain": None if self.chain is None else self.chain.to_dict(),
        }

    def to_json(self, indent: int | None = 2) -> str:
        return json.dumps(self.to_dict(), indent=indent, ensure_ascii=False)


# -- the analysis -----------------------------------------------------------------------------------------------------
def _participant(record: ParticipantRecord) -> Participant:
    return Participant(key=record.key, name=record.name or UNKNOWN, vendor=vendor_name(record.vendor_id),
                       vendor_id=UNKNOWN if record.vendor_id is None else f"0x{record.vendor_id:04x}",
                       host=record.host or UNKNOWN, pid=record.pid or UNKNOWN, process=record.process or UNKNOWN,
                       own=record.own)


def analyse(domain: int, participant_records: Iterable[ParticipantRecord], endpoint_records: Iterable[EndpointRecord],
            reports: Iterable[ProgramReport] = (), moved_ago: dict[str, float] | None = None,
            taken_at: float | None = None, measured: dict[str, MeasuredFlow] | None = None,
            vehicle: Vehicle | None = None) -> Snapshot:
    """The snapshot of the domain: ``moved_ago``: per topic, seconds since a report last showed it moving;
    ``measured``: per topic, what the monitor's own readers measured; ``vehicle``: the vehicle's state.

    The monitor's own readers of the flows (its participant's: ``own``; its rt/diagnostics reader is a reader like
    any) are in the graph and the matches, but in no mismatch and no notice: they are probes that read whatever they
    can, not what a user has to fix; nor do they count as a topic's reader."""
    participants = {record.key: _participant(record) for record in participant_records}
    endpoints: list[Endpoint] = []
    for record in endpoint_records:
        owner = participants.get(record.participant)
        if owner is None:  # an endpoint whose participant is not (or no longer) known: shown under "unknown"
            owner = participants[record.participant] = _participant(ParticipantRecord(record.participant))
        endpoint = Endpoint(record.key, record.participant, owner.name, record.kind, record.topic,
                            record.qos.type_name, record.name, record.qos)
        endpoints.append(endpoint)
        (owner.writers if record.kind == "writer" else owner.readers).append(record.key)
    endpoints.sort(key=lambda e: (e.topic, e.kind, e.participant_name, e.key))

    topics: dict[str, Topic] = {}
    for endpoint in endpoints:
        topic = topics.setdefault(endpoint.topic, Topic(endpoint.topic, [], [], []))
        if endpoint.type_name not in topic.type_names:
            topic.type_names.append(endpoint.type_name)
        (topic.writers if endpoint.kind == "writer" else topic.readers).append(endpoint.key)

    by_key = {endpoint.key: endpoint for endpoint in endpoints}
    matches: list[Match] = []
    mismatches: list[Mismatch] = []
    notices: list[Notice] = []
    for topic in topics.values():
        for reader_key in topic.readers:
            reader = by_key[reader_key]
            own = participants[reader.participant].own and topic.name != DIAGNOSTICS_TOPIC  # its probes
            reader_vendor = participants[reader.participant].vendor
            for writer_key in topic.writers:
                writer = by_key[writer_key]
                writer_vendor = participants[writer.participant].vendor
                reasons = mismatch_reasons(writer.qos, reader.qos)
                said = hints(writer.qos, reader.qos, writer_vendor, reader_vendor, reasons)
                if reasons and own:
                    continue
                if reasons:
                    mismatches.append(Mismatch(topic.name, writer.key, reader.key, writer.participant_name,
                                               reader.participant_name, reasons, said))
                else:
                    matches.append(Match(topic.name, writer.key, reader.key, writer.participant_name,
                                         reader.participant_name, said))
                    writer.matched.append(reader.key)
                    reader.matched.append(writer.key)
            if own:
                continue
            if not topic.writers:
                notices.append(Notice("reader without writer", topic.name, reader.key,
                                      f"{reader.participant_name} reads {topic.name}: no writer of this topic "
                                      "in the domain"))
            elif not reader.matched:
                notices.append(Notice("reader matched no writer", topic.name, reader.key,
                                      f"{reader.participant_name} reads {topic.name}: none of its "
                                      f"{len(topic.writers)} writer(s) matches (see the mismatches)"))
        if topic.writers and all(participants[by_key[key].participant].own and topic.name != DIAGNOSTICS_TOPIC
                                 for key in topic.readers):
            names = sorted({by_key[key].participant_name for key in topic.writers})
            notices.append(Notice("topic without reader", topic.name, None,
                                  f"{topic.name} is written ({', '.join(names)}) and read by nobody"))

    label_participants(participants.values())
    hosts: dict[str, int] = {}
    for participant in participants.values():
        hosts[participant.host] = hosts.get(participant.host, 0) + 1
    for participant in participants.values():
        hint = participant_hint(participant.vendor, hosts.get(participant.host, 1) - 1)
        if hint:  # said with the participant, not as a notice: it is what may be, not what is
            participant.hints.append(hint)

    report_list = list(reports)
    programs = [_health(report) for report in report_list]
    for program in programs:  # a participant and the program reporting under its name, host and process
        for participant in participants.values():
            if participant.name == program.name and participant.host in (program.host, UNKNOWN) and (
                    program.pid is None or participant.pid in (program.pid, UNKNOWN)):
                participant.health = program.level
    hosts_of: dict[str, set[str]] = {}  # participant name -> the hosts of the participants of that name
    for participant in participants.values():
        if participant.host != UNKNOWN:
            hosts_of.setdefault(participant.name, set()).add(participant.host)
    measured_latencies = latencies(report_list, hosts_of)
    found_flows = flows(report_list, moved_ago or {}, measured or {})
    periodic = {endpoint.topic for endpoint in endpoints
                if endpoint.qos.deadline_ns < INFINITE_NS and not participants[endpoint.participant].own}
    for item in found_flows:
        item.periodic = item.topic in periodic
        item.latency = {latency.reader: {"p50_ms": latency.p50_ms, "p99_ms": latency.p99_ms,
                                         "samples": latency.samples, "clock": latency.clock}
                        for latency in measured_latencies if latency.topic == item.topic and latency.writer is None}
    return Snapshot(domain, time.time() if taken_at is None else taken_at,
                    sorted(participants.values(), key=lambda p: (p.own, p.name, p.key)),
                    sorted(topics.values(), key=lambda t: t.name), endpoints, matches, mismatches, notices,
                    found_flows, sorted(programs, key=lambda p: p.name), vehicle or Vehicle(),
                    [latency for latency in measured_latencies if latency.writer is not None],
                    chain(measured_latencies))


def label_participants(participants: Iterable[Participant]) -> None:
    """Each participant's label: its name, and beside a name that repeats, the pid (and the host when pids alone do
    not tell them apart; the key's end when nothing else does)."""
    by_name: dict[str, list[Participant]] = {}
    for participant in participants:
        by_name.setdefault(participant.name, []).append(participant)
    for same in by_name.values():
        if len(same) == 1:
            same[0].label = same[0].name
            continue
        pids_differ = len({(p.pid, p.host) for p in same}) == len(same) and UNKNOWN not in {p.pid for p in same}
        hosts_matter = len({p.host for p in same}) > 1
        for participant in same:
            if pids_differ:
                where = f"pid {participant.pid}" + (f" on {participant.host}" if hosts_matter else "")
            else:  # one process of several participants, or pids not told
                where = f"{participant.key[-8:]}" + (f" on {participant.host}" if participant.host != UNKNOWN else "")
            participant.label = f"{participant.name} ({where})"


def clock_of(writer: str | None, reader_host: str, hosts_of: dict[str, set[str]]) -> tuple[str, str | None]:
    """Whether a writer participant (names joined by '+': several) shares the clock of a reader on ``reader_host``
    (a writer of a host not known may not), and the writer's host when it is one known host."""
    names = [name for name in (writer or "").split("+") if name]
    hosts = set().union(*(hosts_of.get(name, set()) for name in names)) if names else set()
    writer_host = next(iter(hosts)) if len(hosts) == 1 else None
    if not names or reader_host == UNKNOWN or not all(hosts_of.get(name) for name in names):
        return CLOCK_UNKNOWN, writer_host
    return (CLOCK_SHARED if hosts == {reader_host} else CLOCK_NOT_SHARED), writer_host


def latencies(reports: list[ProgramReport], hosts_of: dict[str, set[str]]) -> list[Latency]:
    """The latencies the programs report (automotive.bus.diagnostics: per topic they read, and per writer), each
    marked with whether its writer and reader share a clock (``hosts_of``: participant name -> its hosts). A topic's
    figure over all its writers shares the clock only when each of its writers does."""
    found: dict[tuple[str, str | None, str], dict[str, float]] = {}
    hosts: dict[str, str] = {}
    for report in reports:
        if report.age_s > STALE_AFTER_S:
            continue
        hosts[report.name] = report.host
        for key, value in report.values:
            for suffix, name in ((LATENCY_P50, "p50_ms"), (LATENCY_P99, "p99_ms"), (LATENCY_SAMPLES, "samples")):
                if key.endswith(suffix):
                    topic, _, writer = key[:-len(suffix)].partition(LATENCY_FROM)  # topic names have no spaces
                    found.setdefault((topic, writer or None, report.name), {})[name] = _number(value)
                    break
    result: list[Latency] = []
    for (topic, from_writer, reader), figures in sorted(found.items(), key=lambda item: (item[0][0], item[0][2],
                                                                                           item[0][1] or "")):
        if not figures.get("samples") or topic == DIAGNOSTICS_TOPIC:  # the reports themselves are no data flow
            continue
        reader_host = hosts.get(reader, UNKNOWN)
        if from_writer is None:
            writers = [other for (other_topic, other, other_reader) in found
                       if other_topic == topic and other_reader == reader and other is not None]
            clocks = {clock_of(other, reader_host, hosts_of)[0] for other in writers} or {CLOCK_UNKNOWN}
            clock = (CLOCK_NOT_SHARED if CLOCK_NOT_SHARED in clocks else
                     CLOCK_UNKNOWN if CLOCK_UNKNOWN in clocks else CLOCK_SHARED)
            writer_host = None
        else:
            clock, writer_host = clock_of(from_writer, reader_host, hosts_of)
        result.append(Latency(topic, from_writer, reader, round(figures.get("p50_ms", 0.0), 3),
                              round(figures.get("p99_ms", 0.0), 3), int(figures["samples"]), clock, writer_host,
                              None if reader_host == UNKNOWN else reader_host))
    return result


def chain(measured: list[Latency]) -> Chain:
    """The alert chain from the readers' figures per topic (the slowest reader of a hop, when several read it:
    redundant mode's two collision avoidances). A hop without a sample in the window (no alert said: the alert
    writer writes on a change and while an alert lasts) is named in ``missing``, and the sum is of the others."""
    hops: list[ChainHop] = []
    for topic, writer, reader in CHAIN_HOPS:
        candidates = [latency for latency in measured
                      if latency.topic == topic and latency.writer is None and latency.reader.startswith(reader)]
        hops.append(ChainHop(topic, writer, reader, max(candidates, key=lambda found: found.p99_ms, default=None)))
    known = [hop.latency for hop in hops if hop.latency is not None]
    missing = [hop.topic for hop in hops if hop.latency is None]
    clocks = {latency.clock for latency in known}
    clock = CLOCK_SHARED if not missing and clocks == {CLOCK_SHARED} else (
        CLOCK_NOT_SHARED if CLOCK_NOT_SHARED in clocks else CLOCK_UNKNOWN)
    return Chain(hops, round(sum(found.p50_ms for found in known), 3) if known else None,
                 round(sum(found.p99_ms for found in known), 3) if known else None, clock, missing)


def _health(report: ProgramReport) -> ProgramHealth:
    level = LEVELS.get(report.level, f"level {report.level}")
    if report.age_s > STALE_AFTER_S:
        level = "STALE"
    return ProgramHealth(report.name, report.host, level, report.message, round(report.age_s, 1),
                         report.value("pid"), dict(report.values))


# The keys of automotive.bus.diagnostics' values, per topic: "<topic> <suffix>".
RATE_OUT, RATE_IN = " out/s", " in/s"
COUNTS = {" deadline missed": "deadline_missed", " liveliness changes": "liveliness_changes",
          " samples lost": "samples_lost", " incompatible QoS": "incompatible_qos"}


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        return 0.0
    return value if value == value and abs(value) != float("inf") else 0.0  # NaN and infinities: nothing


def flows(reports: list[ProgramReport], moved_ago: dict[str, float],
          measured: dict[str, MeasuredFlow] | None = None) -> list[Flow]:
    """The flows per topic from the programs' reports (their samples in and out per second and event counts) and
    what the monitor's own readers measured (``measured``: bytes/s, samples/s, the last sample's age)."""
    found: dict[str, Flow] = {}

    def flow(topic: str) -> Flow:
        return found.setdefault(topic, Flow(topic, 0.0, {}, {}, moved_ago.get(topic), 0, 0, 0, 0))

    for report in reports:
        if report.age_s > STALE_AFTER_S:
            continue  # a stopped program's last rates are not a flow
        for key, value in report.values:
            # Two programs of one name (another system on the domain) add up.
            if key.endswith(RATE_OUT):
                writers = flow(key[:-len(RATE_OUT)]).writers
                writers[report.name] = writers.get(report.name, 0.0) + _number(value)
            elif key.endswith(RATE_IN):
                readers = flow(key[:-len(RATE_IN)]).readers
                readers[report.name] = readers.get(report.name, 0.0) + _number(value)
            else:
                for suffix, name in COUNTS.items():
                    if key.endswith(suffix):
                        item = flow(key[:-len(suffix)])
                        setattr(item, name, getattr(item, name) + int(_number(value)))
    # /diagnostics itself is no data flow: its writers are in no program's traffic count, by design.
    found.pop(DIAGNOSTICS_TOPIC, None)
    for topic, seen in (measured or {}).items():
        if topic == DIAGNOSTICS_TOPIC or (topic not in found and seen.last_sample_age_s is None):
            continue  # a flow nobody reports and the monitor never saw is no flow
        item = flow(topic)
        item.bytes_per_s, item.monitor_rate = seen.bytes_per_s, seen.samples_per_s
        if seen.last_sample_age_s is not None and (item.last_sample_age_s is None
                                                   or seen.last_sample_age_s < item.last_sample_age_s):
            item.last_sample_age_s = seen.last_sample_age_s
    for item in found.values():
        item.rate = round(sum(item.writers.values()) if item.writers else max(item.readers.values(), default=0.0), 3)
        if not item.writers and not item.readers and item.monitor_rate is not None:
            item.rate = item.monitor_rate  # nobody reports it: what the monitor takes
        if item.last_sample_age_s is not None:
            item.last_sample_age_s = round(item.last_sample_age_s, 1)
    return sorted(found.values(), key=lambda f: f.topic)
