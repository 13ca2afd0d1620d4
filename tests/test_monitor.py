"""``automotive monitor``: who talks to whom on a domain and why a writer and a reader do not match.

Why: "my tool does not see the data" is the first question of every DDS user, and this project answered it by hand
(an asynchronous writer's latency budget, RTI's requested lease, Fast DDS 2.9's XCDR1). The monitor answers it from
discovery data by the DDS request-offered rules.

- The rules and their words (automotive.tools.monitoring.rules) and the analysis (automotive.tools.monitoring.model)
  are checked without DDS, with records made by hand: every RxO policy, partitions, the hints, discovery data with
  absurd values (a 64 KB name, an unknown vendor, QoS at its limits), flows from /diagnostics reports.
- With the real applications (vision, lidar with the asynchronous LidarAsync writer, sensor_fusion,
  collision_avoidance, hmi, vehicle_platform) on the module's domain, ``automotive monitor --once --json`` (run until
  what is asserted shows, bounded) names every application's participant with its writers and readers, the matched
  pairs and the flows with non-zero rates; an RTI Connector reader requesting RELIABLE from our best-effort vision
  writer shows with its reason in words and vendor RTI; a Cyclone reader whose latency budget is 0 shows the latency
  budget reason against the asynchronous LiDAR writer; a reader with no writer and a topic with no reader are said;
  ``--once`` prints readable text; bad flags end with one line and exit code 2.
"""

from __future__ import annotations

import json
import logging
import os
import re
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from apprunner import AppProcess, AppRunner
from cyclonedds.qos import Policy

from automotive import config
from automotive.bus.endpoints import Databus
from automotive.bus.network import NetworkConfig
from automotive.bus.qos import QosProfiles
from automotive.tools.children import program_command
from automotive.tools.monitoring.model import (
    STALE_AFTER_S,
    EndpointRecord,
    ParticipantRecord,
    ProgramReport,
    analyse,
    flows,
)
from automotive.tools.monitoring.rules import (
    INFINITE_NS,
    RULES,
    VENDOR_CYCLONE,
    VENDOR_FASTDDS,
    VENDOR_RTI,
    EndpointQos,
    duration_words,
    hints,
    mismatch_reasons,
    participant_hint,
    partitions_meet,
    reader_defaults,
)
from automotive.tools.monitoring.text import NAME_WIDTH, render
from automotive.types.automotive import ShapeType
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_

ROOT = Path(__file__).resolve().parent.parent
WAIT_S = "2"  # the monitor's discovery window per run: the system is already up when it starts
TIMEOUT = 90.0
APPLICATIONS = ("vision", "sensor_fusion", "collision_avoidance", "hmi", "vehicle_platform", "lidar")
# The system's matched pairs: (topic, writer's participant, reader's participant).
SYSTEM_PAIRS = {("VisionTopic", "vision", "sensor_fusion"), ("rt/LidarTopic", "lidar", "sensor_fusion"),
                ("SensorObjects", "sensor_fusion", "collision_avoidance"),
                ("AlertTopic", "collision_avoidance", "hmi"),
                ("PlatformControl", "collision_avoidance", "vehicle_platform"),
                ("PlatformStatus", "vehicle_platform", "collision_avoidance")}
PERIODIC_FLOWS = ("VisionTopic", "rt/LidarTopic", "SensorObjects", "PlatformControl", "PlatformStatus")


# -- the rules, without DDS -------------------------------------------------------------------------------------------
def words(writer: EndpointQos, reader: EndpointQos) -> list[str]:
    return [reason.words for reason in mismatch_reasons(writer, reader)]


@pytest.mark.fast
def test_the_specification_defaults_match_and_every_rule_has_words() -> None:
    assert mismatch_reasons(EndpointQos(), reader_defaults()) == []
    assert len(RULES) == 12 and all(rule.summary and rule.policy for rule in RULES)
    assert len({rule.policy for rule in RULES}) == len(RULES)


# (policy, writer's offer, reader's request, the words expected)
MISMATCHES = [
    ("type", {"type_name": "Vision::VisionSensor"}, {"type_name": "VisionSensor"},
     "type: offered Vision::VisionSensor, requested VisionSensor (the type names must be equal"),
    ("data representation", {"representations": ("XCDR2",)}, {"representations": ("XCDR1",)},
     "data representation: offered XCDR2, requested XCDR1 (the reader must accept"),
    ("reliability", {"reliability": "BEST_EFFORT"}, {"reliability": "RELIABLE"},
     "reliability: offered BEST_EFFORT, requested RELIABLE (a RELIABLE reader matches only RELIABLE writers)"),
    ("durability", {"durability": "VOLATILE"}, {"durability": "TRANSIENT_LOCAL"},
     "durability: offered VOLATILE, requested TRANSIENT_LOCAL"),
    ("deadline", {"deadline_ns": 2_000_000_000}, {"deadline_ns": 1_000_000_000},
     "deadline: offered 2 s, requested 1 s"),
    ("latency budget", {"latency_budget_ns": 1_000_000}, {"latency_budget_ns": 0},
     "latency budget: offered 1 ms, requested 0 (the writer's budget must be at most the reader's"),
    ("liveliness kind", {"liveliness": "AUTOMATIC"}, {"liveliness": "MANUAL_BY_TOPIC"},
     "liveliness kind: offered AUTOMATIC, requested MANUAL_BY_TOPIC"),
    ("liveliness lease", {"lease_ns": INFINITE_NS}, {"lease_ns": 300_000_000},
     "liveliness lease: offered infinite, requested 300 ms"),
    ("ownership", {"ownership": "SHARED"}, {"ownership": "EXCLUSIVE"},
     "ownership: offered SHARED, requested EXCLUSIVE"),
    ("presentation", {"presentation": "INSTANCE"}, {"presentation": "TOPIC"},
     "presentation: offered INSTANCE, requested TOPIC"),
    ("presentation", {"presentation": "GROUP"}, {"presentation": "GROUP", "coherent_access": True},
     "presentation: offered coherent access off, requested coherent access on"),
    ("destination order", {"destination_order": "BY_RECEPTION_TIMESTAMP"},
     {"destination_order": "BY_SOURCE_TIMESTAMP"},
     "destination order: offered BY_RECEPTION_TIMESTAMP, requested BY_SOURCE_TIMESTAMP"),
    ("partition", {"partitions": ("a",)}, {"partitions": ("b",)}, "partition: offered 'a', requested 'b'"),
]


@pytest.mark.fast
@pytest.mark.parametrize(("policy", "offered", "requested", "expected"), MISMATCHES,
                         ids=[f"{case[0]}-{index}" for index, case in enumerate(MISMATCHES)])
def test_each_rule_says_offered_against_requested_and_passes_the_other_way(
        policy: str, offered: dict[str, Any], requested: dict[str, Any], expected: str) -> None:
    reasons = mismatch_reasons(EndpointQos(**offered), reader_defaults(**requested))
    assert [reason.policy for reason in reasons] == [policy]
    assert reasons[0].words.startswith(expected), reasons[0].words
    # The stronger offer against the weaker request matches (a type or an ownership does not order).
    if policy not in ("type", "ownership", "partition", "data representation"):
        assert mismatch_reasons(EndpointQos(**requested), reader_defaults(**offered)) == []


@pytest.mark.fast
def test_offers_above_the_request_match() -> None:
    strong = EndpointQos(reliability="RELIABLE", durability="PERSISTENT", deadline_ns=1, latency_budget_ns=0,
                         liveliness="MANUAL_BY_TOPIC", lease_ns=1, presentation="GROUP", coherent_access=True,
                         ordered_access=True, destination_order="BY_SOURCE_TIMESTAMP")
    assert mismatch_reasons(strong, reader_defaults(reliability="RELIABLE", durability="TRANSIENT_LOCAL",
                                                    deadline_ns=10, latency_budget_ns=5, lease_ns=10,
                                                    presentation="TOPIC", ordered_access=True)) == []
    # Several reasons at once, in the table's order.
    assert [r.policy for r in mismatch_reasons(EndpointQos(reliability="BEST_EFFORT", deadline_ns=INFINITE_NS),
                                               reader_defaults(reliability="RELIABLE", deadline_ns=10))] == [
        "reliability", "deadline"]


@pytest.mark.fast
def test_data_representation_the_writer_writes_its_first_and_the_reader_accepts_any() -> None:
    assert mismatch_reasons(EndpointQos(representations=("XCDR1",)),
                            reader_defaults(representations=("XCDR1", "XCDR2"))) == []
    assert words(EndpointQos(representations=("XCDR2",)), reader_defaults(representations=("XCDR1", "XCDR2"))) == []
    assert words(EndpointQos(representations=("XCDR1",)), reader_defaults(representations=("XCDR2",))) == [
        "data representation: offered XCDR1, requested XCDR2 (the reader must accept the representation the writer "
        "writes)"]


@pytest.mark.fast
def test_partitions_default_wildcards_on_one_side_only() -> None:
    assert partitions_meet((), ())
    assert partitions_meet((), ("",)) and not partitions_meet((), ("a",))
    assert partitions_meet(("sensors/*",), ("sensors/front",)) and partitions_meet(("x", "bc"), ("b?",))
    assert not partitions_meet(("a*",), ("a*x",))  # two wildcard names never match each other
    assert partitions_meet(("a*",), ("a*",)) is False
    assert words(EndpointQos(), reader_defaults(partitions=("x",))) == [
        "partition: offered the default partition '', requested 'x' (the writer's publisher and the reader's "
        "subscriber must share a partition)"]


@pytest.mark.fast
def test_type_names_with_type_information_on_both_sides_say_what_the_monitor_cannot_judge() -> None:
    reasons = mismatch_reasons(EndpointQos(type_name="A", type_information=True),
                               reader_defaults(type_name="B", type_information=True))
    assert "XTypes may still match assignable types" in reasons[0].words


@pytest.mark.fast
def test_unknown_kinds_are_shown_raw_and_never_crash() -> None:
    reasons = mismatch_reasons(EndpointQos(reliability="KIND_42"), reader_defaults(reliability="RELIABLE"))
    assert reasons[0].words.startswith("reliability: offered KIND_42, requested RELIABLE")
    assert mismatch_reasons(EndpointQos(durability="ODD"), reader_defaults(durability="ODD")) == []


@pytest.mark.fast
def test_durations_in_words() -> None:
    assert [duration_words(ns) for ns in (0, 1, 250_000, 100_000_000, 1_500_000_000, INFINITE_NS, 2**64, -5)] == [
        "0", "1 ns", "250 us", "100 ms", "1.5 s", "infinite", "infinite", "-5 ns"]


@pytest.mark.fast
def test_hints_latency_budget_fast_dds_xcdr1_rti_lease_and_participant_indexes() -> None:
    asynchronous = EndpointQos(latency_budget_ns=1_000_000)
    reader = reader_defaults()
    said = hints(asynchronous, reader, VENDOR_CYCLONE, VENDOR_CYCLONE, mismatch_reasons(asynchronous, reader))
    assert said and "asynchronous writer" in said[0] and "at least 1 ms" in said[0]
    xcdr2 = EndpointQos(representations=("XCDR2",))
    said = hints(xcdr2, reader, VENDOR_CYCLONE, VENDOR_FASTDDS, mismatch_reasons(xcdr2, reader))
    assert said == ["Fast DDS 2.9 speaks XCDR1 only: the other side must write (or accept) XCDR1"]
    leased = EndpointQos(lease_ns=300_000_000)
    said = hints(leased, reader, VENDOR_CYCLONE, VENDOR_RTI, [])
    assert said and said[0].startswith("RTI readers judge a writer lost by the lease they request (infinite)")
    assert hints(leased, reader, VENDOR_CYCLONE, VENDOR_CYCLONE, []) == []
    assert participant_hint(VENDOR_RTI, 4) is None
    assert "RTI probes participant indexes 0-4 only" in (participant_hint(VENDOR_RTI, 5) or "")
    assert participant_hint(VENDOR_CYCLONE, 50) is None


# -- the analysis, without DDS ----------------------------------------------------------------------------------------
def record(key: str, participant: str, kind: str, topic: str, **qos: Any) -> EndpointRecord:
    made = EndpointQos(**qos) if kind == "writer" else reader_defaults(**qos)
    return EndpointRecord(key, participant, kind, topic, made)


@pytest.mark.fast
def test_analysis_matches_mismatches_and_notices() -> None:
    participants = [ParticipantRecord("p1", "vision", 0x0110, "car", "11", "python"),
                    ParticipantRecord("p2", "rti-tool", 0x0101, "car", "12", "python3.11"),
                    ParticipantRecord("p3", "fusion", 0x0110, "car", "13", "python")]
    endpoints = [record("w1", "p1", "writer", "VisionTopic", type_name="V", reliability="BEST_EFFORT"),
                 record("r1", "p3", "reader", "VisionTopic", type_name="V"),
                 record("r2", "p2", "reader", "VisionTopic", type_name="V", reliability="RELIABLE"),
                 record("r3", "p3", "reader", "Nobody", type_name="N"),
                 record("w2", "p1", "writer", "Orphan", type_name="O")]
    snapshot = analyse(7, participants, endpoints)
    assert [(m.topic, m.writer_participant, m.reader_participant) for m in snapshot.matches] == [
        ("VisionTopic", "vision", "fusion")]
    (mismatch,) = snapshot.mismatches
    assert (mismatch.writer, mismatch.reader) == ("w1", "r2")
    assert [reason.words for reason in mismatch.reasons] == [
        "reliability: offered BEST_EFFORT, requested RELIABLE (a RELIABLE reader matches only RELIABLE writers)"]
    assert {(notice.kind, notice.topic) for notice in snapshot.notices} == {
        ("reader matched no writer", "VisionTopic"), ("reader without writer", "Nobody"),
        ("topic without reader", "Orphan")}
    assert snapshot.participant("p2").vendor == VENDOR_RTI  # type: ignore[union-attr]
    assert snapshot.endpoint("w1").matched == ["r1"]  # type: ignore[union-attr]
    document = json.loads(snapshot.to_json())
    assert document["mismatches"][0]["reasons"][0]["offered"] == "BEST_EFFORT"
    assert document["endpoints"][0]["qos"]["deadline"] == "infinite"
    text = render(snapshot)
    assert "  VisionTopic: vision -> fusion" in text
    assert "  VisionTopic: writer vision (Eclipse Cyclone DDS) -> reader rti-tool (RTI Connext DDS)" in text
    assert "    reliability: offered BEST_EFFORT, requested RELIABLE" in text
    assert "  Orphan is written (vision) and read by nobody" in text


@pytest.mark.fast
def test_absurd_discovery_data_shows_unknown_or_the_raw_value_and_cuts_long_names() -> None:
    huge = "N" * 65536
    participants = [ParticipantRecord("p1", huge, 0xBEEF, huge, None, "\x00\x1b[31m"),
                    ParticipantRecord("p2", None, None)]
    endpoints = [record("w1", "p1", "writer", huge, type_name=huge, deadline_ns=2**63 - 1, lease_ns=-1,
                        latency_budget_ns=2**62, history="KEEP_LAST 2147483647", partitions=("*" * 1000,),
                        representations=("other",), reliability="KIND_9"),
                 record("r1", "p2", "reader", huge, type_name=huge, deadline_ns=0),
                 record("r2", "ghost", "reader", "T", type_name="T")]  # a participant discovery has not told
    snapshot = analyse(0, participants, endpoints)
    first, second = snapshot.participant("p1"), snapshot.participant("p2")
    assert first is not None and second is not None and snapshot.participant("ghost") is not None
    assert (first.vendor, first.vendor_id, first.pid) == ("unknown", "0xbeef", "unknown")
    assert (second.name, second.vendor, second.vendor_id, second.host) == ("unknown",) * 4
    assert snapshot.mismatches and json.loads(snapshot.to_json())["participants"][0]["name"] in (huge, "unknown")
    text = render(snapshot)
    assert max(len(line) for line in text.splitlines()) < 1000
    assert huge not in text and "N" * (NAME_WIDTH - 3) + "..." in text and "\x1b" not in text
    assert "deadline: offered infinite, requested 0" in text


@pytest.mark.fast
def test_flows_from_reports_rates_events_age_and_stale_programs() -> None:
    vision = ProgramReport("vision", "car", 0, "ok", (("VisionTopic out/s", "10"), ("VisionTopic deadline missed", "2"),
                                                      ("pid", "11")), 0.5)
    fusion = ProgramReport("sensor_fusion", "car", 1, "late", (
        ("VisionTopic in/s", "9.5"), ("VisionTopic samples lost", "3"), ("VisionTopic liveliness changes", "1"),
        ("Foreign in/s", "4"), ("Junk in/s", "nan"), ("Bad out/s", "x"), ("rt/diagnostics in/s", "8")), 1.0)
    gone = ProgramReport("lidar", "car", 0, "ok", (("rt/LidarTopic out/s", "20"),), STALE_AFTER_S + 1)
    found = {flow.topic: flow for flow in flows([vision, fusion, gone], {"VisionTopic": 0.26})}
    assert set(found) == {"VisionTopic", "Foreign", "Junk", "Bad"}  # no stale rate, /diagnostics is no flow
    assert (found["VisionTopic"].rate, found["VisionTopic"].readers, found["VisionTopic"].last_sample_age_s) == (
        10.0, {"sensor_fusion": 9.5}, 0.3)
    assert (found["VisionTopic"].deadline_missed, found["VisionTopic"].samples_lost,
            found["VisionTopic"].liveliness_changes) == (2, 3, 1)
    assert found["Foreign"].rate == 4.0 and found["Junk"].rate == 0.0 and found["Foreign"].last_sample_age_s is None
    snapshot = analyse(1, [ParticipantRecord("p", "vision", 0x0110, "car", "11")], [], [vision, fusion, gone])
    assert [(p.name, p.level) for p in snapshot.programs] == [("lidar", "STALE"), ("sensor_fusion", "WARN"),
                                                              ("vision", "OK")]
    assert snapshot.participants[0].health == "OK"


# -- the real system --------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def system(module_domain_id: int) -> Iterator[dict[str, AppProcess]]:
    """The applications on the module's domain; the LiDAR with the asynchronous writer (latency budget 1 ms)."""
    runner = AppRunner(ROOT)
    try:
        started = {name: runner.start(name, "--domain", str(module_domain_id),
                                      *(["-D", "qos.Lidar.Profile=LidarAsync"] if name == "lidar" else []))
                   for name in APPLICATIONS}
        yield started
    finally:
        runner.stop_all()


def run_monitor(domain: int, *args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    return subprocess.run(program_command("monitor", "--domain", str(domain), "--wait", WAIT_S, *args), cwd=cwd,
                          capture_output=True, text=True, timeout=120)


def monitor_until(domain: int, check: Callable[[dict[str, Any]], bool], what: str,
                  timeout: float = TIMEOUT) -> dict[str, Any]:
    """``automotive monitor --json`` again until its document passes ``check`` (bounded)."""
    deadline = time.monotonic() + timeout
    while True:
        result = run_monitor(domain, "--json")
        assert result.returncode == 0, result.stderr[-3000:]
        document: dict[str, Any] = json.loads(result.stdout)
        if check(document):
            return document
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}; last document:\n"
                                 f"{json.dumps(document, indent=1)[:6000]}")


# Another run of the suite on this host may use the same domain id: the checks look at this test's own processes
# (by pid) and endpoints, never at what the domain holds besides.
def names(document: dict[str, Any], system: dict[str, AppProcess]) -> dict[str, dict[str, Any]]:
    """This test's applications' participants, by name."""
    pids = {str(process.pid): name for name, process in system.items()}
    return {participant["name"]: participant for participant in document["participants"]
            if pids.get(participant["pid"]) == participant["name"]}


def pairs(document: dict[str, Any], system: dict[str, AppProcess]) -> set[tuple[str, str, str]]:
    """The matched pairs between this test's applications."""
    ours = {participant["key"]: name for name, participant in names(document, system).items()}
    owner = {endpoint["key"]: ours.get(endpoint["participant"]) for endpoint in document["endpoints"]}
    return {(m["topic"], owner[m["writer"]], owner[m["reader"]]) for m in document["matches"]  # type: ignore[misc]
            if owner.get(m["writer"]) and owner.get(m["reader"])}


def moving(document: dict[str, Any]) -> set[str]:
    return {flow["topic"] for flow in document["flows"] if flow["rate"] > 0}


def mismatch(document: dict[str, Any], topic: str, reader: str) -> dict[str, Any] | None:
    return next((m for m in document["mismatches"] if m["topic"] == topic and m["reader_participant"] == reader),
                None)


def test_json_names_every_application_its_endpoints_the_matched_pairs_and_moving_flows(
        system: dict[str, AppProcess], module_domain_id: int) -> None:
    document = monitor_until(module_domain_id, lambda d: set(APPLICATIONS) <= set(names(d, system))
                             and all(p["health"] for p in names(d, system).values())
                             and SYSTEM_PAIRS <= pairs(d, system) and set(PERIODIC_FLOWS) <= moving(d),
                             "every application with its health, its matched pairs and its flows moving")
    found = names(document, system)
    endpoints = {endpoint["key"]: endpoint for endpoint in document["endpoints"]}
    for name, process in system.items():
        participant = found[name]
        assert participant["vendor"] == "Eclipse Cyclone DDS" and participant["vendor_id"] == "0x0110"
        assert participant["host"] == socket.gethostname() and participant["pid"] == str(process.pid)
        assert participant["health"] in ("OK", "WARN"), participant
    topics_of = {name: ({endpoints[k]["topic"] for k in p["writers"]}, {endpoints[k]["topic"] for k in p["readers"]})
                 for name, p in found.items()}
    assert topics_of["vision"] == ({"VisionTopic", "rt/diagnostics"}, set())
    assert topics_of["sensor_fusion"] == ({"SensorObjects", "rt/diagnostics"}, {"VisionTopic", "rt/LidarTopic"})
    assert topics_of["hmi"][1] == {"AlertTopic"}
    lidar = next(endpoints[key] for key in found["lidar"]["writers"] if endpoints[key]["topic"] == "rt/LidarTopic")
    assert (lidar["type_name"], lidar["qos"]["latency_budget"], lidar["qos"]["reliability"]) == (
        "sensor_msgs::msg::dds_::PointCloud2_", "1 ms", "RELIABLE")
    ours = {key for participant in found.values() for key in participant["writers"] + participant["readers"]}
    assert [m for m in document["mismatches"] if m["writer"] in ours and m["reader"] in ours] == []
    programs = {program["name"]: program for program in document["programs"]}
    assert set(APPLICATIONS) | {"monitor"} <= set(programs)
    flow = {f["topic"]: f for f in document["flows"]}
    assert flow["VisionTopic"]["writers"]["vision"] > 0 and flow["VisionTopic"]["readers"]["sensor_fusion"] > 0
    assert flow["VisionTopic"]["last_sample_age_s"] is not None and flow["VisionTopic"]["last_sample_age_s"] < 5


def test_rti_reader_requesting_reliable_from_our_best_effort_vision_shows_its_reason(
        system: dict[str, AppProcess], module_domain_id: int) -> None:
    from rti_peer import RtiPeer

    def peer(document: dict[str, Any]) -> dict[str, Any] | None:  # this test's RTI participant: in this process
        return next((p for p in document["participants"] if p["vendor"] == "RTI Connext DDS"
                     and p["pid"] == str(os.getpid())), None)

    with RtiPeer(module_domain_id, readers={"Vision": "ReliableReader"}):
        document = monitor_until(module_domain_id, lambda d: any(
            m["topic"] == "VisionTopic" and m["writer_participant"] == "vision"
            and m["reader"] in (peer(d) or {"readers": []})["readers"] for m in d["mismatches"]),
            "the RTI reader's mismatch")
    rti = peer(document)
    assert rti is not None and rti["vendor_id"] == "0x0101" and rti["host"] == socket.gethostname()
    found = mismatch(document, "VisionTopic", rti["name"])
    assert found is not None
    assert [reason["words"] for reason in found["reasons"]] == [
        "reliability: offered BEST_EFFORT, requested RELIABLE (a RELIABLE reader matches only RELIABLE writers)"]
    assert any(n["kind"] == "reader matched no writer" and n["topic"] == "VisionTopic" for n in document["notices"])
    assert SYSTEM_PAIRS <= pairs(document, system)  # the system's own pairs still match


@pytest.fixture
def own_bus(module_domain_id: int) -> Iterator[Databus]:
    """A participant of the test, named, on the module's domain (the project's QoS profiles)."""
    bus = Databus(module_domain_id, QosProfiles(config.qos_file()), "AutomotiveLibrary", logging.getLogger("test"),
                  NetworkConfig(), name="test-reader")
    try:
        yield bus
    finally:
        bus.close()


def test_latency_budget_0_reader_against_the_asynchronous_lidar_no_writer_and_no_reader(
        system: dict[str, AppProcess], module_domain_id: int, own_bus: Databus) -> None:
    own_bus.reader("rt/LidarTopic", PointCloud2_, "Lidar", overrides=(Policy.LatencyBudget(0),))
    own_bus.reader("MonitorTestNoWriter", ShapeType, "Shapes")
    own_bus.writer("MonitorTestNoReader", ShapeType, "Shapes")
    def ours(document: dict[str, Any]) -> dict[str, Any] | None:  # with this test's lidar
        lidar = names(document, system).get("lidar")
        return next((m for m in document["mismatches"] if m["topic"] == "rt/LidarTopic"
                     and m["reader_participant"] == "test-reader" and lidar and m["writer"] in lidar["writers"]), None)

    document = monitor_until(module_domain_id, lambda d: ours(d) is not None
                             and any(n["topic"] == "MonitorTestNoReader" for n in d["notices"]),
                             "the test reader's latency budget mismatch")
    found = ours(document)
    assert found is not None and found["writer_participant"] == "lidar"
    assert [reason["words"] for reason in found["reasons"]] == [
        "latency budget: offered 1 ms, requested 0 (the writer's budget must be at most the reader's; an "
        "asynchronous writer (budget above 0) is not matched by readers that keep the default budget 0)"]
    assert found["hints"] and "asynchronous writer hides its data" in found["hints"][0]
    notices = {(n["kind"], n["topic"]): n["words"] for n in document["notices"]}
    assert notices[("reader without writer", "MonitorTestNoWriter")] == (
        "test-reader reads MonitorTestNoWriter: no writer of this topic in the domain")
    assert notices[("topic without reader", "MonitorTestNoReader")] == (
        "MonitorTestNoReader is written (test-reader) and read by nobody")


def test_once_prints_readable_text_from_an_empty_directory(system: dict[str, AppProcess], module_domain_id: int,
                                                           tmp_path: Path) -> None:
    monitor_until(module_domain_id, lambda d: set(PERIODIC_FLOWS) <= moving(d), "the flows moving")
    deadline = time.monotonic() + TIMEOUT
    while True:
        result = run_monitor(module_domain_id, "--once", cwd=tmp_path)
        assert result.returncode == 0, result.stderr[-3000:]
        text = result.stdout
        if re.search(r"(?m)^  VisionTopic: [1-9][\d.]* samples/s, last sample", text) or time.monotonic() > deadline:
            break
    assert re.match(rf"domain {module_domain_id} at \S+ \S+: \d+ participant\(s\)", text), text
    for line in ("Participants", "Matches (by the DDS rules)", "Mismatches", "Notices",
                 "Flows (from the programs' /diagnostics)", "Programs (/diagnostics)",
                 "  VisionTopic: vision -> sensor_fusion", "  rt/LidarTopic: lidar -> sensor_fusion"):
        assert line in text.splitlines(), f"{line!r} not in:\n{text}"
    assert re.search(r"(?m)^  vision: Eclipse Cyclone DDS, host \S+, pid \d+ \(\S+\), health (OK|WARN)$", text), text
    assert re.search(r"(?m)^    writes VisionTopic \(Vision::VisionSensor\): BEST_EFFORT, VOLATILE", text), text
    assert re.search(r"(?m)^  VisionTopic: [1-9][\d.]* samples/s, last sample [\d.]+ s ago; read by sensor_fusion",
                     text), text
    assert re.search(r"(?m)^  vision: (OK|WARN) \(", text), text
    assert list(tmp_path.iterdir()) == []  # nothing written where it ran


@pytest.mark.parametrize(("args", "pattern"), [
    (["--no-such-flag"], r"^automotive monitor: unrecognized arguments: --no-such-flag"),
    (["--wait", "-1"], r"^automotive monitor: argument --wait: expected seconds from 0 to 3600, not '-1'"),
    (["--wait", "nan"], r"^automotive monitor: argument --wait: expected seconds"),
    (["--domain", "232"], r"^automotive monitor: argument --domain: expected a domain id 0..231"),
    (["-D", "config.noSuchKey=1"], r"^automotive monitor: .*config.noSuchKey"),
])
def test_bad_input_one_line_exit_2(args: list[str], pattern: str) -> None:
    result = subprocess.run([str(Path(sys.executable).parent / "automotive"), "monitor", *args],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2, result.stdout + result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and re.search(pattern, lines[0]), result.stderr
    assert result.stdout == ""


def test_help_is_on_stdout_and_says_the_page_is_not_built_yet() -> None:
    result = subprocess.run(program_command("monitor", "--help"), capture_output=True, text=True, timeout=60)
    assert result.returncode == 0 and "usage: " in result.stdout and "--once" in result.stdout, result.stderr
    assert "web page is not built yet" in " ".join(result.stdout.split())
