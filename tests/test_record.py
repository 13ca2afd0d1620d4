"""automotive.tools.record.record: a recording read back with the official `mcap` library and with `rosbags` (an
independent reader), every field of known samples equal; a killed recorder's file; Ctrl-C and SIGTERM; a full disk (a
small tmpfs of the test's own, in a mount namespace); bad input."""

from __future__ import annotations

import os
import re
import shutil
import signal
import struct
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from alert_sequence import alert_for, number_of
from dds_helpers import wait_until
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Channel, Schema
from mcap.writer import CompressionType, Writer
from rosbags.highlevel import AnyReader

from automotive.bus.endpoints import Databus
from automotive.cyclone.matched import matched_subscriptions
from automotive.sim.scene import LidarScene, ScanGrid
from automotive.tools.flows import system_flows
from automotive.tools.record.record import EXIT_WRITE_FAILED, file_end, index_chunks
from automotive.tools.support.children import Child, program_command
from automotive.types.Alerts import DriverAlerts
from automotive.types.Common import ClassificationEnum, POSIXTimestamp
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.types.Vision import VisionObject, VisionSensor

TIMEOUT = 60.0
MCAP_MAGIC = b"\x89MCAP0\r\n"  # first and last bytes of a finished MCAP file
STAMP = 1_763_800_000_123_456_789  # the writers' source timestamp

VISION = VisionSensor(id=4, timestamp=POSIXTimestamp(s=1_763_800_000, ns=5), objects=[
    VisionObject(classification=ClassificationEnum.CLASSIFICATION_TRUCK, position=[20.0, -1.5, 0.25],
                 velocity=[1.5, 0.0, -0.5], size=[10.0, 3.5, 2.5])])
ALERT = DriverAlerts(blindSpotDriver=True, blindSpotPassenger=False, frontCollision=True, backCollision=False,
                     parkingCollision=False, driverAttention=True)


def wire(sample: Any) -> bytes:
    """A sample's bytes on the wire: XCDR1, padded with zeros to whole 4-byte units as Cyclone Python writes it."""
    serialized = sample.serialize(use_version_2=False)
    return serialized + bytes(-len(serialized) % 4)


def cloud() -> PointCloud2_:
    return LidarScene(ScanGrid(azimuth_steps=12, polar_steps=4), seed=3).point_cloud2(1_763_800_000, 77)


def start_recorder(apps: Any, domain_id: int, output: Path, *args: str) -> Any:
    recorder = apps.start("record", "--domain", str(domain_id), "--output", str(output), *args)
    recorder.wait_for(r"recording \d+ topic", timeout=TIMEOUT)
    return recorder


def matched_writer(bus: Databus, recorder: Any, topic: str, data_type: type[Any], profile: str) -> Any:
    """A writer matched both ways with the recorder's reader (a best-effort sample written before the reader
    matched the writer would be lost)."""
    writer = bus.writer(topic, data_type, profile)
    wait_until(lambda: bool(matched_subscriptions(writer)), TIMEOUT, f"the recorder to match {topic}")
    recorder.wait_for(rf"\[{re.escape(topic)}\] reader matched a writer", timeout=TIMEOUT)
    return writer


def write_until_recorded(recorder: Any, writer: Any, sample: Any, topic: str, timestamp: int | None = None) -> None:
    """Write a best-effort sample until the recorder has it: the first samples after matching can miss a reader that
    the writer already matched (seen now and then on this machine), and best effort does not repair that."""
    deadline = time.monotonic() + TIMEOUT
    while not recorded_count(recorder, topic):
        assert time.monotonic() < deadline, f"the recorder never got a {topic} sample:\n{recorder.output[-3000:]}"
        writer.write(sample, timestamp=timestamp)
        recorder.wait_for_more(r"record: recorded=", 1, timeout=TIMEOUT)


def recorded_count(recorder: Any, topic: str) -> int:
    """Samples of ``topic`` the recorder's last status line counts."""
    lines = [line for line in list(recorder.lines) if "record: recorded=" in line]
    found = re.search(rf" {re.escape(topic)}=(\d+)/", lines[-1]) if lines else None
    return int(found.group(1)) if found else 0


def read_mcap(path: Path) -> tuple[Any, list[tuple[Any, Any, Any]]]:
    with open(path, "rb") as stream:
        reader = make_reader(stream)
        return reader.get_header(), list(reader.iter_messages())


def test_round_trip_with_mcap_and_rosbags(apps, bus: Databus, domain_id: int, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    output = tmp_path / "drive.mcap"
    recorder = start_recorder(apps, domain_id, output, "--topics", "VisionTopic,AlertTopic,rt/LidarTopic")
    vision = matched_writer(bus, recorder, "VisionTopic", VisionSensor, "Vision")
    alerts = matched_writer(bus, recorder, "AlertTopic", DriverAlerts, "HMI")
    lidar = matched_writer(bus, recorder, "rt/LidarTopic", PointCloud2_, "Lidar")
    before = time.time_ns()
    alerts.write(ALERT, timestamp=STAMP + 1)
    lidar.write(cloud(), timestamp=STAMP + 2)
    write_until_recorded(recorder, vision, VISION, "VisionTopic", timestamp=STAMP)
    recorder.wait_for(r"recorded=3 ", timeout=TIMEOUT)
    assert recorder.stop(signal.SIGINT) == 0, recorder.output
    assert "Traceback" not in recorder.output

    header, messages = read_mcap(output)
    assert header.profile == "ros2"
    by_topic = {channel.topic: (schema, channel, message) for schema, channel, message in messages}
    assert set(by_topic) == {"VisionTopic", "AlertTopic", "rt/LidarTopic"}
    expected = {"VisionTopic": (VISION, "Vision::VisionSensor", "omgidl", STAMP),
                "AlertTopic": (ALERT, "Alerts::DriverAlerts", "omgidl", STAMP + 1),
                "rt/LidarTopic": (cloud(), "sensor_msgs/msg/PointCloud2", "ros2msg", STAMP + 2)}
    for topic, (sample, schema_name, encoding, stamp) in expected.items():
        schema, channel, message = by_topic[topic]
        assert channel.message_encoding == "cdr"
        assert (schema.name, schema.encoding) == (schema_name, encoding)
        assert channel.metadata["dds_type"] == type(sample).__idl__.idl_transformed_typename
        assert "reliability:" in channel.metadata["offered_qos_profiles"]
        assert message.data == wire(sample)  # the wire bytes, header included
        assert message.publish_time == stamp
        assert before <= message.log_time <= time.time_ns()

    # rosbags registers the IDL type Vision::VisionSensor as Vision/VisionSensor, and drops IDL enums (so it cannot
    # decode the types with an enum member: vision, sensor objects, platform); the alert and the cloud it decodes.
    with AnyReader([output]) as reader:
        decoded = {connection.topic: reader.deserialize(raw, connection.msgtype.replace("::", "/"))
                   for connection, _, raw in reader.messages() if connection.topic != "VisionTopic"}
        [qos] = next(c for c in reader.connections if c.topic == "AlertTopic").ext.offered_qos_profiles
    assert (qos.history.name, qos.depth, qos.reliability.name, qos.durability.name, qos.liveliness.name,
            qos.liveliness_lease_duration.sec) == ("KEEP_LAST", 1, "RELIABLE", "TRANSIENT_LOCAL", "AUTOMATIC", 60)
    seen = VisionSensor.deserialize(by_topic["VisionTopic"][2].data)
    assert seen == VISION
    seen = decoded["AlertTopic"]
    for member in ("blindSpotDriver", "blindSpotPassenger", "frontCollision", "backCollision", "parkingCollision",
                   "driverAttention"):
        assert getattr(seen, member) == getattr(ALERT, member)
    seen, sent = decoded["rt/LidarTopic"], cloud()
    assert (seen.header.stamp.sec, seen.header.stamp.nanosec, seen.header.frame_id) == (
        sent.header_.stamp_.sec_, sent.header_.stamp_.nanosec_, sent.header_.frame_id_)
    assert (seen.height, seen.width, seen.point_step, seen.row_step, seen.is_bigendian, seen.is_dense) == (
        sent.height_, sent.width_, sent.point_step_, sent.row_step_, sent.is_bigendian_, sent.is_dense_)
    assert [(f.name, f.offset, f.datatype, f.count) for f in seen.fields] == [
        (f.name_, f.offset_, f.datatype_, f.count_) for f in sent.fields_]
    assert np.asarray(seen.data, dtype=np.uint8).tobytes() == bytes(sent.data_)


def test_disposals_are_recorded_on_their_own_channel(apps, bus: Databus, domain_id: int, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    output = tmp_path / "drive.mcap"
    recorder = start_recorder(apps, domain_id, output, "--topics", "AlertTopic")
    alerts = matched_writer(bus, recorder, "AlertTopic", DriverAlerts, "HMI")
    alerts.write(ALERT)
    recorder.wait_for(r"recorded=1 ", timeout=TIMEOUT)
    alerts.dispose(ALERT)
    recorder.wait_for(r"recorded=2 ", timeout=TIMEOUT)
    assert recorder.stop(signal.SIGTERM) == 0, recorder.output
    _, messages = read_mcap(output)
    assert [(channel.topic, channel.metadata["dds_sample_kind"]) for _, channel, _ in messages] == [
        ("AlertTopic", "data"), ("AlertTopic/dispose", "dispose")]
    assert messages[0][2].data == wire(ALERT)
    assert not any(vars(DriverAlerts.deserialize(messages[1][2].data)).values())  # keyless: a default sample


def test_a_killed_recorder_leaves_a_readable_file(apps, bus: Databus, domain_id: int, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    output = tmp_path / "killed.mcap"
    recorder = start_recorder(apps, domain_id, output, "--topics", "AlertTopic")
    alerts = matched_writer(bus, recorder, "AlertTopic", DriverAlerts, "HMI")
    numbers = range(1, 21)
    for number in numbers:
        alerts.write(alert_for(number))
        assert alerts.wait_for_acks(int(TIMEOUT * 1e9))  # keep last 1: each alert reaches the recorder before the next
    recorder.wait_for(rf"on_disk={len(numbers)} ", timeout=TIMEOUT)  # the chunk holding them was handed to the OS
    assert recorder.stop(signal.SIGKILL) == -signal.SIGKILL
    assert not output.read_bytes().endswith(MCAP_MAGIC)  # no summary, no footer: an unfinished file...
    recorded = []
    with open(output, "rb") as stream:
        try:
            for _, _, message in NonSeekingReader(stream).iter_messages(log_time_order=False):  # up to the end
                recorded.append(number_of(DriverAlerts.deserialize(message.data)))
        except (McapError, EOFError):
            pass  # the tail after the last complete record
    assert recorded == list(numbers)

    # Issue 38: the usual readers want the file's end; `automotive record --recover` writes a copy they all read.
    copy = tmp_path / "killed.recovered.mcap"
    recovered = subprocess.run([*program_command("record"), "--recover", str(output)], capture_output=True,
                               text=True, timeout=60)
    assert recovered.returncode == 0 and recovered.stderr == "", recovered.stderr
    assert recovered.stdout == (f"{output}: 20 message(s) of 1 topic(s) (AlertTopic=20) copied to {copy}; its "
                                f"unfinished end left out ({recovered.stdout.split('left out (')[1]}"), recovered.stdout
    assert copy.read_bytes().endswith(MCAP_MAGIC)
    with open(copy, "rb") as stream:
        assert [number_of(DriverAlerts.deserialize(message.data))
                for _, _, message in make_reader(stream).iter_messages()] == list(numbers)
    with AnyReader([copy]) as reader:
        assert len(list(reader.messages())) == len(numbers)
        assert next(c for c in reader.connections if c.topic == "AlertTopic").ext.offered_qos_profiles


def test_recover_refuses_what_it_cannot_copy_in_one_line(tmp_path: Path) -> None:
    not_mcap = tmp_path / "notes.mcap"
    not_mcap.write_text("hello")
    for args, message in [([str(tmp_path / "missing.mcap")], "no such file"),
                          ([str(not_mcap)], "not an MCAP file"),
                          ([str(not_mcap), "-o", str(not_mcap)], "is the recording itself")]:
        result = subprocess.run([*program_command("record"), "--recover", *args], capture_output=True, text=True,
                                timeout=60)
        assert result.returncode == 2 and len(result.stderr.splitlines()) == 1, result.stderr
        assert message in result.stderr and "Traceback" not in result.stderr


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM])
def test_stopping_finishes_a_valid_file(apps, bus: Databus, domain_id: int, tmp_path: Path,  # type: ignore[no-untyped-def]
                                        stop: signal.Signals) -> None:
    output = tmp_path / "stopped.mcap"
    recorder = start_recorder(apps, domain_id, output, "--topics", "AlertTopic")
    alerts = matched_writer(bus, recorder, "AlertTopic", DriverAlerts, "HMI")
    alerts.write(ALERT)
    recorder.wait_for(r"recorded=1 ", timeout=TIMEOUT)
    assert recorder.stop(stop) == 0, recorder.output
    recorder.wait_for(r"summary: recorded=1 ")
    with open(output, "rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == 1
        assert [message.data for _, _, message in reader.iter_messages()] == [wire(ALERT)]


def test_duration_ends_the_recording(apps, domain_id: int, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    # Its own /diagnostics off: nothing on the bus at all (a status of its own could come in the second).
    result = apps.run("record", "--domain", str(domain_id), "--output", str(tmp_path / "d.mcap"), "--duration", "1",
                      "-D", "config.diagnosticsInterval=0", timeout=TIMEOUT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "summary: recorded=0 " in result.stdout


@pytest.mark.parametrize("args, message", [
    (["--output", "{tmp}/missing/x.mcap"],
     r"^(automotive )?record: argument --output/-o: .*/missing/x.mcap: folder .*/missing does not exist"),
    (["--output", "{tmp}"], r"^(automotive )?record: argument --output/-o: .*: is a folder, not a file"),
    (["--output", "{tmp}/exists.mcap"],
     r"^(automotive )?record: --output .*/exists.mcap: the file exists \(add --overwrite"),
    (["--output", "{tmp}/x.mcap", "--topics", "VisionTopic,Nope"],
     r"^(automotive )?record: --topics: unknown topic\(s\) Nope \(known: VisionTopic, rt/LidarTopic, .*Circle, "
     r"rt/diagnostics\)"),
    (["--output", "{tmp}/x.mcap", "-D", "config.compression=brotli"], r"^(automotive )?record: .*config.compression"),
    # checked at start even when no flow read goes through shared memory
    (["--output", "{tmp}/x.mcap", "--topics", "AlertTopic", "-D", "config.transport=tcp"],
     r"^(automotive )?record: .*config.transport"),
    (["--output", "{tmp}/x.mcap", "-D", "config.shmPrefix=a/b"], r"^(automotive )?record: .*config.shmPrefix = 'a/b'"),
])
def test_bad_input_is_one_line(apps, domain_id: int, tmp_path: Path, args: list[str], message: str) -> None:  # type: ignore[no-untyped-def]
    (tmp_path / "exists.mcap").write_bytes(b"keep me")
    result = apps.run("record", "--domain", str(domain_id), *[arg.format(tmp=tmp_path) for arg in args],
                      timeout=TIMEOUT)
    assert result.returncode == 2, result.stdout + result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert re.search(message, result.stderr), result.stderr
    assert (tmp_path / "exists.mcap").read_bytes() == b"keep me"
    assert not (tmp_path / "x.mcap").exists()  # refused before anything was written



# -- a write that fails ----------------------------------------------------------------------------------------------
# The recorder in a mount namespace of its own, writing into a 4 MB tmpfs mounted there (the test's network namespace
# is shared: DDS on loopback reaches it); the shell copies the file out once the recorder has ended, before the
# namespace and its tmpfs go.
FULL_DISK = """
disk=$1 out=$2
shift 2
mount -t tmpfs -o size=4m tmpfs "$disk" || exit 90
"$@" 2>"$out/stderr"
status=$?
cp "$disk/drive.mcap" "$out/drive.mcap"
exit $status
"""
TMPFS_BYTES = 4 * 1024 * 1024
ENDED = re.compile(r"(automotive )?record: (?P<path>\S+): No space left on device; recording stopped: the file ends "
                   r"(properly|with a footer but no index) with (?P<held>\d+) message\(s\) of 1 topic\(s\) "
                   r"\(rt/LidarTopic=(?P=held)\), (?P<size>\d+) bytes; (?P<left>\d+) received sample\(s\) are not in "
                   r"it")


def test_a_full_disk_stops_the_recorder_with_a_file_both_readers_read_to_its_end(  # type: ignore[no-untyped-def]
        bus: Databus, domain_id: int, tmp_path: Path) -> None:
    disk, out = tmp_path / "disk", tmp_path / "out"
    disk.mkdir()
    out.mkdir()
    recorder = Child("record-on-a-full-disk", [
        "unshare", "--mount", "--propagation", "private", "sh", "-c", FULL_DISK, "full-disk", str(disk), str(out),
        *program_command("record", "--domain", str(domain_id), "--topics", "rt/LidarTopic", "--output",
                         str(disk / "drive.mcap"))], new_session=True)
    try:
        recorder.wait_for(r"recording 1 topic", timeout=TIMEOUT)
        lidar = matched_writer(bus, recorder, "rt/LidarTopic", PointCloud2_, "Lidar")
        sample = LidarScene(ScanGrid(azimuth_steps=180, polar_steps=32), seed=3).point_cloud2(1_763_800_000, 0)
        assert len(sample.data_) == 92_160  # 4 MB fill after some 45 clouds
        sent = 0
        deadline = time.monotonic() + TIMEOUT
        while recorder.poll() is None:  # numbered clouds, each acknowledged before the next: none lost, in order
            assert time.monotonic() < deadline, f"the recorder never stopped:\n{recorder.output[-3000:]}"
            sent += 1
            sample.header_.stamp_.nanosec_ = sent
            lidar.write(sample)
            lidar.wait_for_acks(int(TIMEOUT * 1e9))  # at once when the recorder has gone
        status = recorder.wait_exit(timeout=TIMEOUT)
    finally:
        recorder.stop(group=True)  # the shell and the recorder both, if the test ends early
    stderr = (out / "stderr").read_text()
    assert status == EXIT_WRITE_FAILED, f"{recorder.output}\n{stderr}"
    assert "Traceback" not in stderr + recorder.output, f"{recorder.output}\n{stderr}"
    assert len(stderr.strip().splitlines()) == 1, stderr
    ended = ENDED.fullmatch(stderr.strip())
    assert ended, stderr
    held, left = int(ended["held"]), int(ended["left"])
    assert ended["path"] == str(disk / "drive.mcap")
    copy = out / "drive.mcap"
    assert copy.stat().st_size == int(ended["size"]) <= TMPFS_BYTES
    assert 30 <= held and held + left <= sent  # most of the disk holds clouds; what came after is counted
    # Every message the recorder said was on disk (in a whole chunk) before the failure is in the file.
    on_disk = [int(found) for found in re.findall(r" record: recorded=\d+ on_disk=(\d+) ", recorder.output)]
    assert on_disk and held >= max(on_disk), recorder.output

    with open(copy, "rb") as stream:
        stamps = [PointCloud2_.deserialize(message.data).header_.stamp_.nanosec_
                  for _, _, message in make_reader(stream).iter_messages()]
    assert stamps == list(range(1, held + 1))
    with AnyReader([copy]) as reader:
        stamps = [reader.deserialize(raw, connection.msgtype).header.stamp.nanosec
                  for connection, _, raw in reader.messages()]
    assert stamps == list(range(1, held + 1))


def test_a_file_cut_after_a_chunk_and_ended_there_reads_as_a_finished_one(tmp_path: Path) -> None:
    """What the recorder does after a failed write, on a file mcap's own writer made: cut after a whole chunk, then
    ended with the summary rebuilt from the chunks' record headers (the index equal to the writer's), or with the
    footer alone (the ending that needs 50 bytes); both readers read exactly the messages before the cut."""
    flows = {flow.topic: flow for flow in system_flows()}
    finished = tmp_path / "finished.mcap"
    writer = Writer(str(finished), chunk_size=4096, compression=CompressionType.LZ4)
    writer.start(profile="ros2", library="test")
    schemas, channels = [], []
    for topic in ("AlertTopic", "rt/LidarTopic"):
        schema = flows[topic].schema
        schemas.append(Schema(id=writer.register_schema(schema.name, schema.encoding, schema.data), name=schema.name,
                              encoding=schema.encoding, data=schema.data))
        channels.append(Channel(id=writer.register_channel(topic, "cdr", schemas[-1].id), topic=topic,
                                message_encoding="cdr", metadata={}, schema_id=schemas[-1].id))
    sent = []
    for number in range(1, 121):  # alerts, and a cloud every tenth: some chunks hold both channels
        channel, data = ((channels[1], wire(cloud())) if number % 10 == 0 else
                         (channels[0], wire(alert_for(number % 63 + 1))))
        writer.add_message(channel.id, log_time=STAMP + number, data=data, publish_time=STAMP + number)
        sent.append((channel.topic, data))
    writer.finish()
    with open(finished, "rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and len(summary.chunk_indexes) >= 5
    data = finished.read_bytes()
    data_start = len(MCAP_MAGIC) + 9 + struct.unpack_from("<Q", data, len(MCAP_MAGIC) + 1)[0]  # after the header
    keep = len(summary.chunk_indexes) - 2
    last = summary.chunk_indexes[keep - 1]
    cut = last.chunk_start_offset + last.chunk_length + last.message_index_length
    for indexed in (True, False):
        ended = tmp_path / f"ended-{indexed}.mcap"
        shutil.copyfile(finished, ended)
        fd = os.open(ended, os.O_RDWR)
        try:
            chunks = index_chunks(fd, data_start, cut)
            assert [chunk.index for chunk in chunks] == summary.chunk_indexes[:keep]
            os.ftruncate(fd, cut)
            os.pwrite(fd, file_end(cut, schemas, channels, chunks if indexed else None), cut)
        finally:
            os.close(fd)
        expected = sent[:sum(sum(chunk.messages.values()) for chunk in chunks)]
        assert expected and len(expected) < len(sent)
        with open(ended, "rb") as stream:
            reader = make_reader(stream)
            assert (reader.get_summary() is not None) == indexed
            assert [(channel.topic, message.data) for _, channel, message in reader.iter_messages()] == expected
        with AnyReader([ended]) as bag:
            assert [(connection.topic, raw) for connection, _, raw in bag.messages()] == expected


def test_a_disk_full_from_the_start_is_one_line(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    """/dev/full refuses every write with ENOSPC: not even the header is written."""
    result = apps.run("record", "--domain", str(domain_id), "--output", "/dev/full", "--overwrite", "--duration", "5",
                      timeout=TIMEOUT)
    assert result.returncode == EXIT_WRITE_FAILED, result.stdout + result.stderr
    assert "Traceback" not in result.stdout + result.stderr
    assert re.fullmatch(r"(automotive )?record: /dev/full: No space left on device; recording stopped: not even the "
                        r"file's header could be written \(the file is empty\); 0 received sample\(s\) are not in it\n",
                        result.stderr), result.stderr
