"""The recorder and the Foxglove bridge take the camera's frames and the LiDAR's clouds from shared memory when their
writer is on the same host (issue 32), and what they record or forward is what DDS carries, byte for byte.

Why: with the shipped defaults (config.transport=auto) the camera and the LiDAR send to same-host readers through
iceoryx2 only, and write on DDS only while a DDS reader of another locality is matched. A tool that read DDS alone
would record nothing of them, or make the writers pay for DDS again; a tool that read both would record every sample
twice. The recordings are read back with the `mcap` library and with `rosbags` (independent readers, not ours); the
bridge's messages with Foxglove's own npm decoders (tests/foxglove_node.py).

Every test uses a private DDS domain (the ``domain_id`` fixture) and a private iceoryx2 file prefix
(``config.shmPrefix``, the ``prefix`` fixture), and checks that nothing of that prefix is left in /dev/shm.
"""

from __future__ import annotations

import base64
import re
import signal
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
from foxglove_node import FoxgloveDecoder, install, json_lines
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from shm_helpers import files_of
from test_bridge import start_bridge
from test_foxglove import compare, sha256

from automotive import config
from automotive.sim.lfsr import FramePattern
from automotive.types.CameraImage import CameraImageData_64KiB
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_

TIMEOUT = 120.0  # Python, Cyclone and iceoryx2 starting on a loaded 2-core machine
FRAME_BYTES = 65_536
CAMERA_TOPIC = "CameraImageData"
LIDAR_TOPIC = "rt/LidarTopic"
SHM_WARNING = "goes over DDS only"  # shm.unavailable's line: shared memory could not be used


def assert_no_files(prefix: str) -> None:
    """A clean stop of every process leaves no service of ours (iceoryx2's one global file per prefix aside)."""
    left = files_of(prefix)
    assert not left, f"left in shared memory: {sorted(map(str, left))}"


@pytest.fixture
def small_frames(tmp_path: Path) -> Path:
    """An exported copy of the configuration whose camera sends 64 KiB frames: the tools read the camera's frame
    size from camera_pub.properties beside their own properties file."""
    folder = tmp_path / "config"
    config.export(folder)
    camera = folder / "properties" / "camera_pub.properties"
    text = camera.read_text()
    assert "config.imageSize=full\n" in text
    camera.write_text(text.replace("config.imageSize=full\n", "config.imageSize=64KiB\n"))
    return folder / "properties"


def shm_args(properties: Path, program: str, domain_id: int, prefix: str, *more: str) -> list[str]:
    return ["--properties", str(properties / f"{program}.properties"), "--domain", str(domain_id),
            "-D", f"config.shmPrefix={prefix}", *more]


def sent_line(child: Any, what: str) -> tuple[int, int]:
    """(sent through shared memory, written on DDS) from a writer's last line."""
    found = re.search(rf"shared memory: (\d+) {what} sent, (\d+) written on DDS", child.output)
    assert found, child.output[-3000:]
    return int(found.group(1)), int(found.group(2))


def mcap_messages(path: Path, topic: str) -> list[Any]:
    """The messages of ``topic`` in a recording, read with the official mcap library."""
    with open(path, "rb") as stream:
        return [message for _, channel, message in make_reader(stream).iter_messages() if channel.topic == topic]


def by_key(messages: list[Any], key: Any) -> dict[Any, Any]:
    """Messages by their sample's key (camera seqnum, LiDAR stamp); no key twice (no sample recorded twice)."""
    keys = [key(message.data) for message in messages]
    twice = [value for value, count in Counter(keys).items() if count > 1]
    assert not twice, f"recorded twice: {twice[:5]}"
    return dict(zip(keys, messages, strict=True))


def frame_seqnum(data: bytes) -> int:
    return int(CameraImageData_64KiB.deserialize(data).seqnum)


def cloud_stamp(data: bytes) -> tuple[int, int]:
    stamp = PointCloud2_.deserialize(data).header_.stamp_
    return int(stamp.sec_), int(stamp.nanosec_)


def test_a_recording_from_shared_memory_is_byte_for_byte_the_one_from_dds(  # type: ignore[no-untyped-def]
        apps, domain_id: int, prefix: str, small_frames: Path, tmp_path: Path) -> None:
    """Two recorders at once: one on the default transport (same host: the camera and the LiDAR reach it through
    shared memory), one with config.transport=udp (DDS). The camera's and the LiDAR's messages are the same bytes with
    the same source timestamps in both files, none twice in either; rosbags reads the same clouds."""
    frames = 60
    via_shm, via_dds = tmp_path / "shm.mcap", tmp_path / "dds.mcap"
    topics = f"--topics={CAMERA_TOPIC},{LIDAR_TOPIC}"
    shm_recorder = apps.start("record", *shm_args(small_frames, "record", domain_id, prefix, topics,
                                                  "--output", str(via_shm)))
    dds_recorder = apps.start("record", *shm_args(small_frames, "record", domain_id, prefix, topics,
                                                  "--output", str(via_dds), "-D", "config.transport=udp"))
    shm_recorder.wait_for(rf"{CAMERA_TOPIC}, {re.escape(LIDAR_TOPIC)}: shared memory with writers on this host",
                          timeout=TIMEOUT)
    for recorder in (shm_recorder, dds_recorder):
        recorder.wait_for(r"recording 2 topic", timeout=TIMEOUT)
    # The camera starts once both recorders' readers matched it. The LiDAR's first clouds may reach only the recorder
    # on shared memory (it writes on DDS once it matched the other one): it runs until the other one has some.
    lidar = apps.start("lidar", *shm_args(small_frames, "lidar", domain_id, prefix, "-D", "config.pubInterval=200"))
    camera = apps.start("camera_pub", *shm_args(small_frames, "camera_pub", domain_id, prefix, "--count", str(frames),
                                                "-D", "config.pubInterval=20", "-D", "config.waitSubscribers=2"))
    assert camera.wait_exit(timeout=TIMEOUT) == 0, camera.output[-3000:]
    assert sent_line(camera, "frames") == (frames, frames)  # shared memory for one recorder, DDS for the other
    dds_recorder.wait_for(rf" {re.escape(LIDAR_TOPIC)}=([3-9]|\d\d+)/", timeout=TIMEOUT)
    assert lidar.stop(signal.SIGTERM) == 0, lidar.output[-3000:]
    clouds, clouds_dds = sent_line(lidar, "clouds")
    assert 3 <= clouds_dds <= clouds
    # Once a recorder's readers saw the writers go, everything DDS delivered is in their caches; the stop takes it.
    for recorder in (shm_recorder, dds_recorder):
        for topic in (CAMERA_TOPIC, LIDAR_TOPIC):
            recorder.wait_for(rf"\[{re.escape(topic)}\] reader unmatched a writer: 0 writer", timeout=TIMEOUT)
        assert recorder.stop(signal.SIGINT) == 0, recorder.output[-3000:]
        assert "Traceback" not in recorder.output and SHM_WARNING not in recorder.output, recorder.output[-3000:]
    assert "shared memory with writers on this host" not in dds_recorder.output
    # The one on shared memory took every sample from there, and left out the DDS copies that the other recorder
    # made the writers send (the camera's keep-all writer holds at most 8 frames unacknowledged).
    copies = shm_recorder.wait_for(rf"summary {CAMERA_TOPIC}: messages={frames} .* shared_memory={frames} "
                                   r"dds_copies_left_out=\d+$")
    assert frames - 8 <= int(copies.rsplit("=", 1)[1]) <= frames, copies
    copies = shm_recorder.wait_for(rf"summary {re.escape(LIDAR_TOPIC)}: messages={clouds} .* shared_memory={clouds} "
                                   r"dds_copies_left_out=\d+$")
    assert int(copies.rsplit("=", 1)[1]) <= clouds_dds, copies

    pattern = FramePattern(FRAME_BYTES)
    for topic, key, expected in ((CAMERA_TOPIC, frame_seqnum, frames), (LIDAR_TOPIC, cloud_stamp, clouds)):
        shared, dds = by_key(mcap_messages(via_shm, topic), key), by_key(mcap_messages(via_dds, topic), key)
        assert len(shared) == expected, sorted(shared)
        # every frame (reliable keep-all, acknowledged before the camera ends); the clouds written on DDS at most
        assert set(dds) <= set(shared)
        assert len(dds) == frames if topic == CAMERA_TOPIC else 3 <= len(dds) <= clouds_dds
        for sample in dds:
            assert shared[sample].data == dds[sample].data, f"{topic} {sample}: the bytes differ"
            assert shared[sample].publish_time == dds[sample].publish_time, f"{topic} {sample}: source timestamps"
            assert shared[sample].log_time >= shared[sample].publish_time
    assert sorted(by_key(mcap_messages(via_shm, CAMERA_TOPIC), frame_seqnum)) == list(range(1, frames + 1))
    for message in mcap_messages(via_shm, CAMERA_TOPIC):
        frame = CameraImageData_64KiB.deserialize(message.data)
        assert bytes(frame.data) == bytes(pattern.frame(frame.seqnum))
    # rosbags, an independent reader, reads the same clouds (with their header stamps) from both files
    decoded: dict[Path, dict[tuple[int, int], bytes]] = {}
    for path in (via_shm, via_dds):
        with AnyReader([path]) as bag:
            connections = [c for c in bag.connections if c.topic == LIDAR_TOPIC]
            decoded[path] = {}
            for connection, _, raw in bag.messages(connections=connections):
                cloud = bag.deserialize(raw, connection.msgtype)
                decoded[path][(cloud.header.stamp.sec, cloud.header.stamp.nanosec)] = bytes(cloud.data)
    assert len(decoded[via_shm]) == clouds and len(decoded[via_dds]) == len(mcap_messages(via_dds, LIDAR_TOPIC))
    assert all(decoded[via_shm][stamp] == data for stamp, data in decoded[via_dds].items())
    assert_no_files(prefix)


@pytest.fixture(scope="module")
def foxglove() -> FoxgloveDecoder:
    return FoxgloveDecoder(install())


def test_the_bridge_forwards_frames_and_clouds_from_shared_memory_that_foxglove_decodes(  # type: ignore[no-untyped-def]
        apps, domain_id: int, prefix: str, small_frames: Path, foxglove: FoxgloveDecoder) -> None:
    """Only the bridge reads the camera and the LiDAR: both writers send everything through shared memory and write
    nothing on DDS; a Foxglove client gets every frame and the clouds, decoded by Foxglove's libraries equal to our
    decoding of the same bytes, the frames' images the publisher's pattern."""
    frames, clouds = 12, 6
    topics = f"--topics={CAMERA_TOPIC},{LIDAR_TOPIC}"
    bridge, port = start_bridge(apps, domain_id, *shm_args(small_frames, "bridge", domain_id, prefix, topics,
                                                           "-D", "config.backlog=256"))
    bridge.wait_for(rf"{CAMERA_TOPIC}, {re.escape(LIDAR_TOPIC)}: shared memory with writers on this host",
                    timeout=TIMEOUT)
    client = apps.start_command("decode.js ws", foxglove.command("ws", f"ws://127.0.0.1:{port}"), env=foxglove.env)
    client.wait_for(r'"kind":"open"', timeout=TIMEOUT)
    bridge.wait_for(r"client \d+ subscribed to", count=2, timeout=TIMEOUT)
    camera = apps.start("camera_pub", *shm_args(small_frames, "camera_pub", domain_id, prefix, "--count", str(frames),
                                                "-D", "config.pubInterval=50"))
    lidar = apps.start("lidar", *shm_args(small_frames, "lidar", domain_id, prefix, "--count", str(clouds),
                                          "-D", "config.pubInterval=200"))
    assert camera.wait_exit(timeout=TIMEOUT) == 0, camera.output[-3000:]
    assert lidar.wait_exit(timeout=TIMEOUT) == 0, lidar.output[-3000:]
    # Everything went through shared memory: the bridge's DDS readers (marked as this host's) made nobody write on DDS.
    assert sent_line(camera, "frames") == (frames, 0)
    assert sent_line(lidar, "clouds") == (clouds, 0)
    client.wait_for(rf'"kind":"message","topic":"{CAMERA_TOPIC}"', count=frames, timeout=TIMEOUT)
    client.wait_for(rf'"kind":"message","topic":"{re.escape(LIDAR_TOPIC)}"', count=clouds, timeout=TIMEOUT)
    assert client.stop(signal.SIGTERM) == 0, client.output[-3000:]
    assert bridge.stop(signal.SIGTERM) == 0, bridge.output[-3000:]
    assert "Traceback" not in bridge.output and SHM_WARNING not in bridge.output, bridge.output[-3000:]
    bridge.wait_for(rf"forwarded in total {CAMERA_TOPIC}={frames} {re.escape(LIDAR_TOPIC)}={clouds}$")
    bridge.wait_for(rf"{CAMERA_TOPIC}: shared_memory={frames} dds_copies_left_out=0$")
    bridge.wait_for(rf"{re.escape(LIDAR_TOPIC)}: shared_memory={clouds} dds_copies_left_out=0$")

    lines = json_lines(client.lines)
    errors = [line for line in lines if "error" in line]
    assert not errors, f"Foxglove's libraries failed: {errors[:3]}"
    channels = {line["topic"]: line for line in lines if line["kind"] == "channel"}
    assert (channels[CAMERA_TOPIC]["schemaName"], channels[LIDAR_TOPIC]["schemaName"]) == (
        "CameraImage::CameraImageData_64KiB", "sensor_msgs/msg/PointCloud2")
    messages = [line for line in lines if line["kind"] == "message"]
    pattern = FramePattern(FRAME_BYTES)
    seqnums = []
    stamps = []
    for line in messages:
        raw = base64.b64decode(line["rawBase64"])
        assert sha256(raw) == line["raw"]
        if line["topic"] == CAMERA_TOPIC:
            compare(line["value"], CameraImageData_64KiB.deserialize(raw), f"frame {line['value']['seqnum']}")
            assert line["value"]["data"] == {"bytes": FRAME_BYTES,
                                             "sha256": sha256(bytes(pattern.frame(line["value"]["seqnum"])))}
            seqnums.append(line["value"]["seqnum"])
        else:
            compare(line["value"], PointCloud2_.deserialize(raw), "cloud")
            stamps.append((line["value"]["header"]["stamp"]["sec"], line["value"]["header"]["stamp"]["nanosec"]))
    assert seqnums == list(range(1, frames + 1))  # each once, in order
    assert len(set(stamps)) == len(stamps) == clouds
    assert_no_files(prefix)


@pytest.mark.parametrize("writer_transport", ["auto", "udp"])
def test_a_content_filter_records_the_same_frames_from_shared_memory_as_from_dds(  # type: ignore[no-untyped-def]
        apps, domain_id: int, prefix: str, small_frames: Path, tmp_path: Path, writer_transport: str) -> None:
    """The recorder's --filter applies to the frames that come through shared memory (a camera on the default
    transport) as to those that come on DDS (a camera with config.transport=udp, which the recorder's shared memory
    never sees): the same frames are recorded either way."""
    frames = 20
    output = tmp_path / "filtered.mcap"
    recorder = apps.start("record", *shm_args(small_frames, "record", domain_id, prefix, f"--topics={CAMERA_TOPIC}",
                                              "--filter", f"{CAMERA_TOPIC}=seqnum > 10", "--output", str(output)))
    recorder.wait_for(r"recording 1 topic", timeout=TIMEOUT)
    camera = apps.start("camera_pub", *shm_args(small_frames, "camera_pub", domain_id, prefix, "--count", str(frames),
                                                "-D", "config.pubInterval=20",
                                                "-D", f"config.transport={writer_transport}"))
    assert camera.wait_exit(timeout=TIMEOUT) == 0, camera.output[-3000:]
    if writer_transport == "auto":
        assert sent_line(camera, "frames") == (frames, 0)
    else:
        assert "shared memory:" not in camera.output
    recorder.wait_for(rf" {CAMERA_TOPIC}={frames - 10}/", timeout=TIMEOUT)
    assert recorder.stop(signal.SIGINT) == 0, recorder.output[-3000:]
    shared = frames if writer_transport == "auto" else 0
    recorder.wait_for(rf"summary {CAMERA_TOPIC}: messages={frames - 10} .* filtered_out=10 shared_memory={shared} "
                      r"dds_copies_left_out=0$")
    recorded = by_key(mcap_messages(output, CAMERA_TOPIC), frame_seqnum)
    assert sorted(recorded) == list(range(11, frames + 1))
    pattern = FramePattern(FRAME_BYTES)
    for seqnum, message in recorded.items():
        assert bytes(CameraImageData_64KiB.deserialize(message.data).data) == bytes(pattern.frame(seqnum))
    assert_no_files(prefix)


def test_the_bridge_never_holds_the_camera_back_at_full_speed(  # type: ignore[no-untyped-def]
        apps, domain_id: int, prefix: str, small_frames: Path) -> None:
    """The camera's reliable keep-all writer counts every frame it sends through shared memory until each subscriber
    takes it; the bridge's subscriber keeps as many as the writer may have outstanding and takes them all, so frames
    as fast as flow control allows never wait for it (with a subscriber that kept only the newest frame, the overwritten
    ones were never taken and the camera stalled for its max_blocking_time, 10 s, again and again)."""
    frames = 3000
    bridge, _ = start_bridge(apps, domain_id, *shm_args(small_frames, "bridge", domain_id, prefix,
                                                        f"--topics={CAMERA_TOPIC}"))
    bridge.wait_for(rf"{CAMERA_TOPIC}: shared memory with writers on this host", timeout=TIMEOUT)
    camera = apps.start("camera_pub", *shm_args(small_frames, "camera_pub", domain_id, prefix, "--count", str(frames),
                                                "-D", "config.pubInterval=0"))
    assert camera.wait_exit(timeout=TIMEOUT) == 0, camera.output[-3000:]
    assert "consumed" not in camera.output, camera.output[-3000:]  # shm's "no sample consumed for 10 s" warning
    assert sent_line(camera, "frames") == (frames, 0), camera.output[-6000:]
    bridge.wait_for(rf"forwarded {CAMERA_TOPIC}={frames};", timeout=TIMEOUT)
    assert bridge.stop(signal.SIGTERM) == 0, bridge.output[-3000:]
    assert_no_files(prefix)


@pytest.mark.parametrize("setting, message", [
    ("config.transport=tcp", r"config.transport"),
    ("config.shmPrefix=a/b", r"config.shmPrefix = 'a/b' is not a valid file name prefix"),
], ids=["transport", "prefix"])
def test_the_bridge_refuses_a_bad_transport_setting_in_one_line(apps, domain_id: int, setting: str,  # type: ignore[no-untyped-def]
                                                                message: str) -> None:
    result = apps.run("bridge", "--domain", str(domain_id), "--port", "0", "--topics", "AlertTopic", "-D", setting,
                      timeout=TIMEOUT)
    assert result.returncode == 2, result.stdout + result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and re.search(message, result.stderr), result.stderr
