"""automotive.tools.record.replay: a recorded drive replayed into sensor fusion and collision avoidance gives the
recorded alerts; an RTI Connext reader receives replayed samples as it received the live ones; channels that are not the
system's are
skipped; bad input."""

from __future__ import annotations

import re
import signal
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from dds_helpers import take_samples, wait_until
from mcap.reader import make_reader
from mcap.writer import Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Rosbag2Writer
from rosbags.typesys import Stores, get_typestore
from rti_peer import RtiPeer
from test_record import cloud, recorded_count, wire, write_until_recorded
from test_system import CAR, HEADER, TRUCK, vision_row

from automotive import config
from automotive.bus.endpoints import Databus
from automotive.cyclone.matched import matched_subscriptions
from automotive.types.Alerts import DriverAlerts
from automotive.types.Common import ClassificationEnum, POSIXTimestamp
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.types.Vision import VisionObject, VisionSensor

TIMEOUT = 60.0
ROWS = 40
TALL_ROWS = (range(10, 14), range(25, 29))  # a truck taller than 2 m leads twice: two alerts, two all-clears
EVENT_FUSION = ["-D", "config.mode=event"]  # one object list per vision sample


def two_alert_scene(path: Path) -> Path:
    car = (CAR, [12.5, -1.5, 0.0], [3.25, 0.5, -0.25], [4.5, 1.5, 1.75])
    truck = (TRUCK, [20.0, 0.0, 0.0], [1.5, 0.0, 0.0], [10.0, 3.5, 2.5])
    rows = [vision_row([truck, car] if any(row in tall for tall in TALL_ROWS) else [car]) for row in range(ROWS)]
    path.write_text("\n".join([HEADER, *rows]) + "\n")
    return path


def messages(path: Path, topic: str) -> list[bytes]:
    with open(path, "rb") as stream:
        return [message.data for _, _, message in make_reader(stream).iter_messages(topics=[topic])]


def alert_states(path: Path) -> list[bytes]:
    """The recorded alerts, each run of equal alerts counted once (the HMI shows a change of state). How many equal
    alerts a run holds depends on how many object lists fusion wrote while the truck led: timing, not behaviour."""
    states: list[bytes] = []
    for data in messages(path, "AlertTopic"):
        if not states or states[-1] != data:
            states.append(data)
    return states


def stop_after_quiet(recorder: Any) -> None:
    """Let the recorder see two more status lines (the last alerts are on their way), then stop it with Ctrl-C."""
    recorder.wait_for_more(r"record: recorded=", 2, timeout=TIMEOUT)
    assert recorder.stop(signal.SIGINT) == 0, recorder.output


def decision_apps(apps: Any, domain: list[str]) -> list[Any]:
    fusion = apps.start("sensor_fusion", *domain, *EVENT_FUSION)
    avoidance = apps.start("collision_avoidance", *domain)
    avoidance.wait_for(r"\[SensorObjects\] reader matched a writer", timeout=TIMEOUT)
    fusion.wait_for(r"\[SensorObjects\] writer matched a reader", timeout=TIMEOUT)
    return [fusion, avoidance]


def test_replayed_drive_gives_the_recorded_alerts(apps, domain_id: int, other_domain_id: int,  # type: ignore[no-untyped-def]
                                                  tmp_path: Path) -> None:
    # The replay on a domain of its own, apart from the live drive's (and from every other test's)
    live, replayed = ["--domain", str(domain_id)], ["--domain", str(other_domain_id)]
    drive = tmp_path / "drive.mcap"
    recorder = apps.start("record", *live, "--output", str(drive), "--topics", "VisionTopic,AlertTopic")
    _, avoidance = decision_apps(apps, live)
    recorder.wait_for(r"\[AlertTopic\] reader matched a writer", timeout=TIMEOUT)
    apps.start("vision", *live, "-D", "config.pubInterval=100", "-D",
               f"dataFile={two_alert_scene(tmp_path / 'scene.csv')}", "--count", str(ROWS))
    avoidance.wait_for(r"all clear", count=3, timeout=TIMEOUT)  # its first verdict, then after each alert
    stop_after_quiet(recorder)
    recorded = alert_states(drive)
    attention = DriverAlerts(blindSpotDriver=False, blindSpotPassenger=False, frontCollision=False,
                             backCollision=False, parkingCollision=False, driverAttention=True)
    assert [DriverAlerts.deserialize(data).driverAttention for data in recorded] == [False, True, False, True, False]
    assert DriverAlerts.deserialize(recorded[1]) == attention
    assert len(messages(drive, "VisionTopic")) >= ROWS - 5  # best effort: the first rows may precede discovery

    again = tmp_path / "again.mcap"
    recorder = apps.start("record", *replayed, "--output", str(again), "--topics", "AlertTopic")
    _, avoidance = decision_apps(apps, replayed)
    recorder.wait_for(r"\[AlertTopic\] reader matched a writer", timeout=TIMEOUT)
    replay = apps.start("replay", str(drive), *replayed, "--topics", "VisionTopic", "--wait-readers", "1")
    assert replay.wait_exit(timeout=TIMEOUT) == 0, replay.output
    avoidance.wait_for(r"all clear", count=3, timeout=TIMEOUT)
    stop_after_quiet(recorder)
    assert alert_states(again) == recorded


def vision(sensor_id: int) -> VisionSensor:
    obj = VisionObject(classification=ClassificationEnum.CLASSIFICATION_PEDESTRIAN, position=[float(sensor_id), 2.0,
                       0.5], velocity=[0.25, 0.0, 0.0], size=[0.5, 0.5, 1.75])
    return VisionSensor(id=sensor_id, timestamp=POSIXTimestamp(s=100 + sensor_id, ns=sensor_id), objects=[obj])


def test_an_rti_reader_receives_replayed_samples_as_live_ones(apps, bus: Databus, domain_id: int,  # type: ignore[no-untyped-def]
                                                             tmp_path: Path) -> None:
    drive = tmp_path / "vision.mcap"
    recorder = apps.start("record", "--domain", str(domain_id), "--output", str(drive), "--topics", "VisionTopic")
    with RtiPeer(domain_id, readers=["Vision"]) as peer:
        writer = bus.writer("VisionTopic", VisionSensor, "Vision")
        wait_until(lambda: len(matched_subscriptions(writer)) >= 2, TIMEOUT, "the recorder and RTI to match")
        recorder.wait_for(r"\[VisionTopic\] reader matched a writer", timeout=TIMEOUT)
        peer.wait_for_writers("Vision", timeout=TIMEOUT)
        # Sample 0 opens the recording; the others follow a second later, when replayed too: by then the RTI reader
        # has matched the replaying writer (a best-effort sample written before that is not delivered).
        write_until_recorded(recorder, writer, vision(0), "VisionTopic")
        live = peer.take_until("Vision", 1, timeout=TIMEOUT)
        primers = recorded_count(recorder, "VisionTopic")
        ids = range(1, 6)
        for sensor_id in ids:
            writer.write(vision(sensor_id))
        live += peer.take_until("Vision", len(ids), timeout=TIMEOUT, accept=lambda sample: sample["id"] > 0)
        wait_until(lambda: recorded_count(recorder, "VisionTopic") == primers + len(ids), TIMEOUT,
                   "the recorder to record samples 1 to 5")
        assert recorder.stop(signal.SIGINT) == 0, recorder.output

        # The replayer starts writing once its writer has matched the RTI reader, but a best-effort reader drops
        # what arrives before it has matched the writer in turn, and discovery need not finish on both sides at
        # once. So the recording is replayed in a loop, and only what is written after the RTI reader matched the
        # replaying writer (ours is the other one it matches) counts: then every sample of the drive arrives.
        replay = apps.start("replay", str(drive), "--domain", str(domain_id), "--wait-readers", "1", "--loop")
        peer.wait_for_writers("Vision", count=2, timeout=TIMEOUT)
        peer.take("Vision")  # what arrived while the RTI reader was matching: possibly part of a pass only
        replayed: dict[int, dict[str, Any]] = {}
        deadline = time.monotonic() + TIMEOUT
        while set(replayed) != set(ids) and time.monotonic() < deadline:
            for sample in peer.take_until("Vision", 1, timeout=1.0, accept=lambda sample: sample["id"] > 0):
                replayed.setdefault(sample["id"], sample)
        assert replay.stop(signal.SIGINT) == 0, replay.output
    expected = {sample["id"]: sample for sample in live if sample["id"] > 0}
    assert sorted(expected) == list(ids)
    assert replayed == expected


def test_a_rosbag2_recording_is_replayed(apps, bus: Databus, domain_id: int, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """A rosbag2 MCAP bag (written by rosbags as ros2 bag record writes it) of /LidarTopic reaches rt/LidarTopic."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    sent = cloud()
    types = store.types
    message = types["sensor_msgs/msg/PointCloud2"](
        header=types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](
            sec=sent.header_.stamp_.sec_, nanosec=sent.header_.stamp_.nanosec_), frame_id=sent.header_.frame_id_),
        height=sent.height_, width=sent.width_, is_bigendian=sent.is_bigendian_, point_step=sent.point_step_,
        row_step=sent.row_step_, is_dense=sent.is_dense_, data=np.frombuffer(bytes(sent.data_), np.uint8),
        fields=[types["sensor_msgs/msg/PointField"](name=f.name_, offset=f.offset_, datatype=f.datatype_,
                                                     count=f.count_) for f in sent.fields_])
    with Rosbag2Writer(tmp_path / "bag", version=8, storage_plugin=StoragePlugin.MCAP) as bag:
        connection = bag.add_connection("/LidarTopic", "sensor_msgs/msg/PointCloud2", typestore=store)
        bag.write(connection, 1_000_000_000, store.serialize_cdr(message, "sensor_msgs/msg/PointCloud2"))
    [recording] = (tmp_path / "bag").glob("*.mcap")
    reader = bus.reader("rt/LidarTopic", PointCloud2_, "Lidar")
    replay = apps.start("replay", str(recording), "--domain", str(domain_id), "--wait-readers", "1")
    [received] = take_samples(reader, 1, timeout=TIMEOUT)
    assert replay.wait_exit(timeout=TIMEOUT) == 0, replay.output
    assert wire(received) == wire(sent)


def write_mcap(path: Path, channels: list[tuple[str, str, str, bytes]]) -> None:
    """An MCAP file with a channel per (topic, schema name, schema encoding, one message)."""
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start(profile="ros2", library="test")
        for number, (topic, schema_name, encoding, data) in enumerate(channels, start=1):
            schema = writer.register_schema(schema_name, encoding, config.idl_file().read_bytes())
            channel = writer.register_channel(topic, "cdr", schema)
            for _ in range(3):
                writer.add_message(channel, log_time=number, data=data, publish_time=number)
        writer.finish()


def test_channels_that_are_not_the_systems_are_skipped_once(apps, domain_id: int, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    alert = DriverAlerts(blindSpotDriver=True, blindSpotPassenger=True, frontCollision=False, backCollision=False,
                         parkingCollision=False, driverAttention=False)
    recording = tmp_path / "mixed.mcap"
    write_mcap(recording, [("AlertTopic", "Alerts::DriverAlerts", "omgidl", alert.serialize(use_version_2=False)),
                           ("VisionTopic", "Other::Type", "omgidl", b"\x00\x01\x00\x00"),
                           ("/chatter", "std_msgs/msg/String", "ros2msg", b"\x00\x01\x00\x00")])
    result = apps.run("replay", str(recording), "--domain", str(domain_id), "--rate", "0", timeout=TIMEOUT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert len(re.findall(r"channel VisionTopic: schema Other::Type .* skipped", result.stdout)) == 1
    assert len(re.findall(r"channel /chatter: not a topic of the system, skipped", result.stdout)) == 1
    assert "replayed 3 samples: AlertTopic=3" in result.stdout


@pytest.mark.parametrize("make, message", [
    (lambda tmp: tmp / "missing.mcap", r"missing.mcap: cannot read \(No such file or directory\)"),
    (lambda tmp: (tmp / "text.mcap", (tmp / "text.mcap").write_text("hello"))[0],
     r"text.mcap: not an MCAP file"),
    (lambda tmp: truncated(tmp), r"cut.mcap: truncated MCAP file"),
])
def test_bad_recordings_are_one_line(apps, domain_id: int, tmp_path: Path, make: Any, message: str) -> None:  # type: ignore[no-untyped-def]
    result = apps.run("replay", str(make(tmp_path)), "--domain", str(domain_id), timeout=TIMEOUT)
    assert result.returncode == 2, result.stdout + result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert re.search(rf"^automotive replay: .*{message}", result.stderr), result.stderr


def truncated(tmp_path: Path) -> Path:
    whole = tmp_path / "whole.mcap"
    write_mcap(whole, [("AlertTopic", "Alerts::DriverAlerts", "omgidl", b"\x00\x01\x00\x00" + bytes(8))])
    cut = tmp_path / "cut.mcap"
    data = whole.read_bytes()
    cut.write_bytes(data[:len(data) // 2])
    return cut


def test_bad_options_are_one_line(apps, domain_id: int, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    write_mcap(tmp_path / "ok.mcap", [("AlertTopic", "Alerts::DriverAlerts", "omgidl", bytes(12))])
    for args, message in ((["--rate", "-1"], r"--rate -1: expected 0"),
                          (["--topics", "Nope"], r"--topics: unknown topic\(s\) Nope"),
                          (["--start", "5", "--end", "1"], r"--end 1 is before --start 5")):
        result = apps.run("replay", str(tmp_path / "ok.mcap"), "--domain", str(domain_id), *args, timeout=TIMEOUT)
        assert result.returncode == 2, result.stdout + result.stderr
        assert re.search(rf"^automotive replay: {message}", result.stderr), result.stderr
        assert len(result.stderr.strip().splitlines()) == 1, result.stderr
