"""Every shipped QoS profile against the default QoS of other DDS stacks, derived from the QoS file itself.

A profile is a default when a shipped properties file (properties/*.properties) names it; any other profile of the
file is opt-in and must say so in the comment right before it ("Opt-in: ..."). Each writer profile is compared with
the readers other stacks create by default, each reader profile with their default writer, by the request-offered
rules of the DDS specification (2.2.3). A default profile may only differ where the original example's contract
needs a stronger policy that such a peer can also request (reliability, durability, deadline, liveliness); any other
mismatch (latency budget, ownership, presentation, destination order, data representation) is named in the failure.
A new profile is covered without editing this file.

The rules are checked against Cyclone's own matching: every pair is also created as real endpoints (one
participant, loopback), and Cyclone must match exactly the pairs the rules call compatible.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ElementTree
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import DataReaderQos, DataWriterQos, Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from dds_helpers import wait_until

from automotive import config
from automotive.bus.properties import Properties
from automotive.bus.qos import QosProfiles
from automotive.bus.status import policy_name
from automotive.cyclone.matched import matched_subscriptions
from automotive.types.Alerts import DriverAlerts

ROOT = Path(__file__).resolve().parent.parent
QOS_FILE = config.qos_file()
LIBRARY = "AutomotiveLibrary"
INFINITE = 0x7FFFFFFFFFFFFFFF
# What a peer with its stack's defaults can request or offer beyond the DDS defaults: the original's contract.
CONTRACT_POLICIES = {"RELIABILITY", "DURABILITY", "DEADLINE", "LIVELINESS"}

XCDR1_ONLY = Policy.DataRepresentation(use_cdrv0_representation=True)
# The DDS default QoS (DDS 1.4 2.2.3, XTypes 1.3 7.6.3.1.1: XCDR1 when nothing else is said), as RTI Connext 6 and
# Fast DDS 2.x create their endpoints by default, and a ROS 2 RViz2 PointCloud2 display's reader (reliable,
# volatile, keep last 5).
PEER_READERS = {
    "DDS default reader": DataReaderQos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, XCDR1_ONLY),
    "RViz2 reader": DataReaderQos(Policy.Reliability.Reliable(0), Policy.Durability.Volatile,
                                  Policy.History.KeepLast(5), XCDR1_ONLY),
}
PEER_WRITERS = {
    "DDS default writer": DataWriterQos(Policy.Reliability.Reliable(100_000_000), Policy.Durability.Volatile,
                                        XCDR1_ONLY),
}

_DURABILITY_ORDER = ["Volatile", "TransientLocal", "Transient", "Persistent"]
_LIVELINESS_ORDER = ["Automatic", "ManualByParticipant", "ManualByTopic"]
_ACCESS_SCOPE_ORDER = ["Instance", "Topic", "Group"]


def _kind(policy: object) -> str:
    return type(policy).__name__.rsplit(".", 1)[-1]  # Durability.Volatile -> Volatile


def _get(qos: Qos, scope: str, default: object) -> object:
    policy = getattr(Policy, scope)
    return qos[policy] if policy in qos else default


def incompatible_policies(offered: Qos, requested: Qos) -> list[str]:
    """The request-offered policies by which a writer's QoS fails a reader's, by their DDS names."""
    failed = []
    if _kind(_get(offered, "Reliability", Policy.Reliability.BestEffort)) == "BestEffort" and \
            _kind(_get(requested, "Reliability", Policy.Reliability.BestEffort)) == "Reliable":
        failed.append("RELIABILITY")
    if _DURABILITY_ORDER.index(_kind(_get(offered, "Durability", Policy.Durability.Volatile))) < \
            _DURABILITY_ORDER.index(_kind(_get(requested, "Durability", Policy.Durability.Volatile))):
        failed.append("DURABILITY")
    presentation = Policy.PresentationAccessScope.Instance(coherent_access=False, ordered_access=False)
    offered_presentation, requested_presentation = (_get(qos, "PresentationAccessScope", presentation)
                                                    for qos in (offered, requested))
    if _ACCESS_SCOPE_ORDER.index(_kind(offered_presentation)) < _ACCESS_SCOPE_ORDER.index(
            _kind(requested_presentation)) or any(
            getattr(requested_presentation, flag) and not getattr(offered_presentation, flag)
            for flag in ("coherent_access", "ordered_access")):
        failed.append("PRESENTATION")
    if _get(offered, "Deadline", Policy.Deadline(INFINITE)).deadline > \
            _get(requested, "Deadline", Policy.Deadline(INFINITE)).deadline:  # type: ignore[attr-defined]
        failed.append("DEADLINE")
    if _get(offered, "LatencyBudget", Policy.LatencyBudget(0)).budget > \
            _get(requested, "LatencyBudget", Policy.LatencyBudget(0)).budget:  # type: ignore[attr-defined]
        failed.append("LATENCY_BUDGET")
    if _kind(_get(offered, "Ownership", Policy.Ownership.Shared)) != \
            _kind(_get(requested, "Ownership", Policy.Ownership.Shared)):
        failed.append("OWNERSHIP")
    automatic = Policy.Liveliness.Automatic(INFINITE)
    offered_liveliness, requested_liveliness = (_get(qos, "Liveliness", automatic) for qos in (offered, requested))
    if _LIVELINESS_ORDER.index(_kind(offered_liveliness)) < _LIVELINESS_ORDER.index(_kind(requested_liveliness)) \
            or offered_liveliness.lease_duration > requested_liveliness.lease_duration:  # type: ignore[attr-defined]
        failed.append("LIVELINESS")
    if _kind(_get(offered, "DestinationOrder", Policy.DestinationOrder.ByReceptionTimestamp)) == \
            "ByReceptionTimestamp" and _kind(_get(requested, "DestinationOrder",
                                                  Policy.DestinationOrder.ByReceptionTimestamp)) == \
            "BySourceTimestamp":
        failed.append("DESTINATION_ORDER")
    # A writer writes its first representation (XCDR1 where it names both); the reader must accept it.
    offered_xcdr1 = _get(offered, "DataRepresentation", XCDR1_ONLY).use_cdrv0_representation  # type: ignore[attr-defined]
    requested_representation = _get(requested, "DataRepresentation", XCDR1_ONLY)
    if not (requested_representation.use_cdrv0_representation if offered_xcdr1  # type: ignore[attr-defined]
            else requested_representation.use_xcdrv2_representation):  # type: ignore[attr-defined]
        failed.append("DATA_REPRESENTATION")
    return failed


@dataclass(frozen=True)
class Profile:
    name: str
    has_writer: bool
    has_reader: bool
    comment: str  # the comment right before the profile in the file


def file_profiles(path: Path) -> list[Profile]:
    parser = ElementTree.XMLParser(target=ElementTree.TreeBuilder(insert_comments=True))
    root = ElementTree.parse(path, parser).getroot()
    profiles = []
    for library in root:
        if not str(library.tag).endswith("qos_library") or library.get("name") != LIBRARY:
            continue
        comment = ""
        for element in library:
            if element.tag is ElementTree.Comment:
                comment = " ".join((element.text or "").split())
            elif str(element.tag).endswith("qos_profile"):
                tags = {child.tag.rsplit("}", 1)[-1] for child in element}
                profiles.append(Profile(element.get("name", ""), "datawriter_qos" in tags, "datareader_qos" in tags,
                                        comment))
                comment = ""
    return profiles


def shipped_profiles() -> dict[str, list[str]]:
    """Profile name -> the properties files (and keys) that name it."""
    named: dict[str, list[str]] = {}
    for path in sorted(config.properties_dir().glob("*.properties")):
        properties = Properties.load(path)
        # A file just loaded has read none of its keys: its unused keys are all of them.
        for key in [key for key in properties.unused_keys() if re.fullmatch(r"qos\.(\w+\.)?Profile", key)]:
            named.setdefault(properties.get_str(key), []).append(f"{path.name}:{key}")
    return named


PROFILES = file_profiles(QOS_FILE)
SHIPPED = shipped_profiles()


@pytest.fixture(scope="module")
def profiles() -> QosProfiles:
    return QosProfiles(QOS_FILE)


def pairs(profile: Profile, qos_profiles: QosProfiles) -> Iterator[tuple[str, DataWriterQos, DataReaderQos]]:
    """(description, writer QoS, reader QoS) of the profile's endpoints facing the peers' default endpoints."""
    if profile.has_writer:
        for peer, reader_qos in PEER_READERS.items():
            yield f"{profile.name} writer -> {peer}", qos_profiles.writer_qos(LIBRARY, profile.name), reader_qos
    if profile.has_reader:
        for peer, writer_qos in PEER_WRITERS.items():
            yield f"{peer} -> {profile.name} reader", writer_qos, qos_profiles.reader_qos(LIBRARY, profile.name)


def test_the_shipped_properties_name_only_profiles_of_the_file() -> None:
    assert SHIPPED, "no properties file names a QoS profile"
    unknown = sorted(set(SHIPPED) - {profile.name for profile in PROFILES})
    assert not unknown, f"properties name profiles that {QOS_FILE.name} lacks: {unknown}"


@pytest.mark.parametrize("profile", PROFILES, ids=[profile.name for profile in PROFILES])
def test_profile_against_the_default_endpoints_of_other_stacks(profile: Profile, profiles: QosProfiles) -> None:
    if profile.name not in SHIPPED:
        assert profile.comment.startswith("Opt-in:"), (
            f"{profile.name} is named by no shipped properties file: mark it opt-in with a comment before it "
            f"starting 'Opt-in:' that says what it costs (which readers it loses) and what it buys")
        return
    refused = []
    for description, writer_qos, reader_qos in pairs(profile, profiles):
        beyond_contract = sorted(set(incompatible_policies(writer_qos, reader_qos)) - CONTRACT_POLICIES)
        if beyond_contract:
            refused.append(f"{description}: {', '.join(beyond_contract)}")
    assert not refused, (f"default profile {profile.name} (named by {', '.join(SHIPPED[profile.name])}) does not "
                         f"match the default QoS of other stacks: " + "; ".join(refused))


def test_asynchronous_sending_is_an_opt_in_profile_of_lidar_and_camera(profiles: QosProfiles) -> None:
    for name in ("LidarAsync", "CameraAsync"):
        assert name not in SHIPPED
        assert profiles.writer_qos(LIBRARY, name)[Policy.LatencyBudget].budget > 0
        assert incompatible_policies(profiles.writer_qos(LIBRARY, name),
                                     PEER_READERS["DDS default reader"]) == ["LATENCY_BUDGET"]
    # The default readers accept the asynchronous writers too.
    for flow in ("Lidar", "Camera"):
        assert incompatible_policies(profiles.writer_qos(LIBRARY, f"{flow}Async"),
                                     profiles.reader_qos(LIBRARY, flow)) == []


def test_the_rules_name_each_refused_policy() -> None:
    reader = PEER_READERS["DDS default reader"]
    assert incompatible_policies(DataWriterQos(XCDR1_ONLY), reader) == []
    assert incompatible_policies(DataWriterQos(Policy.LatencyBudget(1), Policy.Ownership.Exclusive,
                                               Policy.DestinationOrder.BySourceTimestamp, XCDR1_ONLY), reader) == \
        ["LATENCY_BUDGET", "OWNERSHIP"]
    assert incompatible_policies(
        DataWriterQos(Policy.DataRepresentation(use_xcdrv2_representation=True)), reader) == ["DATA_REPRESENTATION"]
    assert incompatible_policies(
        DataWriterQos(Policy.Reliability.BestEffort, XCDR1_ONLY),
        Qos(Policy.Reliability.Reliable(0), Policy.Durability.TransientLocal, Policy.Deadline(10),
                      Policy.Liveliness.ManualByTopic(5), Policy.DestinationOrder.BySourceTimestamp,
                      Policy.PresentationAccessScope.Topic(coherent_access=True, ordered_access=False),
                      XCDR1_ONLY)) == \
        ["RELIABILITY", "DURABILITY", "PRESENTATION", "DEADLINE", "LIVELINESS", "DESTINATION_ORDER"]


def test_cyclone_matches_exactly_the_pairs_the_rules_call_compatible(domain_id: int,
                                                                     profiles: QosProfiles) -> None:
    participant = DomainParticipant(domain_id)
    expected: dict[str, list[str]] = {}
    endpoints: dict[str, tuple[DataWriter[DriverAlerts], DataReader[DriverAlerts]]] = {}
    for number, (description, writer_qos, reader_qos) in enumerate(
            pair for profile in PROFILES for pair in pairs(profile, profiles)):
        topic = Topic(participant, f"QosPair{number}", DriverAlerts)  # one topic per pair: nothing else matches
        endpoints[description] = (DataWriter(participant, topic, qos=writer_qos),
                                  DataReader(participant, topic, qos=reader_qos))
        expected[description] = incompatible_policies(writer_qos, reader_qos)

    def settled() -> bool:
        return all((len(matched_subscriptions(writer)) == 1) == (not expected[description]) and (
            not expected[description] or reader.get_requested_incompatible_qos_status().total_count > 0)
            for description, (writer, reader) in endpoints.items())

    try:
        wait_until(settled, timeout=20, what="Cyclone to match or refuse every pair")
    except AssertionError:
        disagreements = [f"{description}: rules say {expected[description] or 'compatible'}, Cyclone "
                         f"{'matched' if matched_subscriptions(writer) else 'refused'}"
                         for description, (writer, reader) in endpoints.items()
                         if bool(matched_subscriptions(writer)) == bool(expected[description])]
        raise AssertionError("; ".join(disagreements) or "Cyclone reported no incompatible QoS") from None
    for description, (_, reader) in endpoints.items():
        if expected[description]:  # Cyclone names the one policy it stopped at: one of ours
            assert policy_name(reader.get_requested_incompatible_qos_status().last_policy_id) in \
                expected[description], description
