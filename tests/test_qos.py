"""Every QoS profile loads with Cyclone's QosProvider and holds the policies of its data flow."""

from __future__ import annotations

import logging
from pathlib import Path
from types import SimpleNamespace

import pytest
from cyclonedds.qos import Policy, Qos

from automotive import config
from automotive.bus.errors import ConfigError
from automotive.bus.qos import QosProfiles
from automotive.bus.status import StatusListener, own_side

ROOT = Path(__file__).resolve().parent.parent
QOS_FILE = config.qos_file()
LIBRARY = "AutomotiveLibrary"
SECOND = 1_000_000_000
BEST_EFFORT_FLOWS = ["Vision", "Platform", "CollisionAvoidance", "SensorFusion"]
REDUNDANT_PROFILES = ["SensorFusionRedundant", "CollisionAvoidanceRedundant", "HMIRedundant"]  # redundant mode only


@pytest.fixture(scope="module")
def profiles() -> QosProfiles:
    return QosProfiles(QOS_FILE)


def policy(qos: Qos, scope: str) -> object:
    return qos[getattr(Policy, scope)]


def test_one_library_with_a_profile_per_data_flow(profiles: QosProfiles) -> None:
    assert sorted(profiles.names) == sorted(f"{LIBRARY}::{name}" for name in
                                            ["Lidar", "LidarAsync", "HMI", *BEST_EFFORT_FLOWS, "Camera",
                                                             "CameraAsync", "Shapes", "LidarView", *REDUNDANT_PROFILES])


def test_lidar_reliable_synchronous_with_deadlines(profiles: QosProfiles) -> None:
    writer, reader = profiles.writer_qos(LIBRARY, "Lidar"), profiles.reader_qos(LIBRARY, "Lidar")
    assert isinstance(policy(writer, "Reliability"), Policy.Reliability.Reliable)
    assert isinstance(policy(reader, "Reliability"), Policy.Reliability.Reliable)
    assert Policy.LatencyBudget not in writer  # matches readers with the default budget of 0 (RViz2, RTI apps)
    assert policy(writer, "Deadline").deadline == 1 * SECOND
    assert policy(reader, "Deadline").deadline == 2 * SECOND


def test_lidar_async_is_the_same_flow_with_an_asynchronous_writer(profiles: QosProfiles) -> None:
    writer, reader = profiles.writer_qos(LIBRARY, "LidarAsync"), profiles.reader_qos(LIBRARY, "LidarAsync")
    assert isinstance(policy(writer, "Reliability"), Policy.Reliability.Reliable)
    assert policy(writer, "LatencyBudget").budget > 0  # Cyclone's asynchronous write
    assert policy(writer, "Deadline").deadline == 1 * SECOND
    assert policy(reader, "Deadline").deadline == 2 * SECOND


def test_hmi_alerts_transient_local_last_one_with_liveliness(profiles: QosProfiles) -> None:
    for qos in (profiles.writer_qos(LIBRARY, "HMI"), profiles.reader_qos(LIBRARY, "HMI")):
        assert isinstance(policy(qos, "Reliability"), Policy.Reliability.Reliable)
        assert policy(qos, "Durability") == Policy.Durability.TransientLocal
        assert policy(qos, "History") == Policy.History.KeepLast(1)
        assert policy(qos, "Liveliness") == Policy.Liveliness.Automatic(lease_duration=60 * SECOND)


@pytest.mark.parametrize("name", BEST_EFFORT_FLOWS)
def test_best_effort_flows_with_deadlines_and_reader_history(profiles: QosProfiles, name: str) -> None:
    writer, reader = profiles.writer_qos(LIBRARY, name), profiles.reader_qos(LIBRARY, name)
    assert policy(writer, "Reliability") == Policy.Reliability.BestEffort
    assert policy(reader, "Reliability") == Policy.Reliability.BestEffort
    assert policy(writer, "Deadline").deadline == 10 * SECOND
    assert policy(reader, "Deadline").deadline == 11 * SECOND
    assert policy(reader, "History") == Policy.History.KeepLast(100)


@pytest.mark.parametrize("name,asynchronous", [("Camera", False), ("CameraAsync", True)])
def test_camera_reliable_keep_all_with_a_bounded_window(profiles: QosProfiles, name: str, asynchronous: bool) -> None:
    writer, reader = profiles.writer_qos(LIBRARY, name), profiles.reader_qos(LIBRARY, name)
    assert isinstance(policy(writer, "Reliability"), Policy.Reliability.Reliable)
    assert isinstance(policy(reader, "Reliability"), Policy.Reliability.Reliable)
    assert policy(writer, "History") == Policy.History.KeepAll
    assert policy(writer, "ResourceLimits").max_samples == 8
    assert (Policy.LatencyBudget in writer) == asynchronous


def test_writers_offer_xcdr1_for_rti_and_readers_accept_both(profiles: QosProfiles) -> None:
    assert policy(profiles.writer_qos(LIBRARY, "Vision"), "DataRepresentation") == \
        Policy.DataRepresentation(use_cdrv0_representation=True)
    assert policy(profiles.reader_qos(LIBRARY, "Vision"), "DataRepresentation") == \
        Policy.DataRepresentation(use_cdrv0_representation=True, use_xcdrv2_representation=True)


def test_unknown_profile_names_the_file_and_the_choices(profiles: QosProfiles) -> None:
    with pytest.raises(ConfigError, match=r"automotive_qos.xml: no QoS profile 'AutomotiveLibrary::Nope' "
                                          r"\(available: AutomotiveLibrary::Lidar"):
        profiles.writer_qos(LIBRARY, "Nope")
    with pytest.raises(ConfigError, match="no QoS profile 'OtherLibrary::Vision'"):
        profiles.reader_qos("OtherLibrary", "Vision")


def test_missing_and_malformed_qos_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="missing.xml: QoS file not found"):
        QosProfiles(tmp_path / "missing.xml")
    broken = tmp_path / "broken.xml"
    broken.write_text("<dds><qos_library name='L'>")
    with pytest.raises(ConfigError, match="broken.xml: not a readable QoS XML file"):
        QosProfiles(broken)


def test_an_incompatible_qos_event_for_an_endpoint_being_deleted_is_said_without_its_side(
        caplog: pytest.LogCaptureFixture) -> None:
    """Cyclone calls the listener with None for a reader or writer being deleted (seen in the monitor's tests, as an
    exception in the listener): the line names the policy, without what this side asked."""
    listener = StatusListener("VisionTopic", logging.getLogger("test.status"))
    ownership = 6  # DDS_OWNERSHIP_QOS_POLICY_ID
    with caplog.at_level(logging.WARNING, logger="test.status"):
        listener.on_requested_incompatible_qos(None, SimpleNamespace(last_policy_id=ownership, total_count=1,
                                                                     total_count_change=1))
        listener.on_offered_incompatible_qos(None, SimpleNamespace(last_policy_id=ownership, total_count=1,
                                                                   total_count_change=1))
    assert [record.getMessage() for record in caplog.records] == [
        "[VisionTopic] a writer was seen but does not match: incompatible QoS OWNERSHIP (the writer offers another "
        "ownership)",
        "[VisionTopic] a reader was seen but does not match: incompatible QoS OWNERSHIP (the reader requests another "
        "ownership)"]
    exclusive = Qos(Policy.Ownership.Exclusive)
    assert own_side(ownership, exclusive, reader=True).startswith("this reader requests EXCLUSIVE ownership")
