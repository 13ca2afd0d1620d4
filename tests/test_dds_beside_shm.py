"""A DDS reader beside the shared-memory readers of a large flow changes nothing for them (issue 37, part 2).

- The DDS copies of a shared-memory writer's samples are dropped by their writer before they are decoded, and they
  are not counted: a checked reader's decoder never sees them, sensor fusion counts rt/LidarTopic at the LiDAR's 20/s
  while a DDS reader of another locality makes the LiDAR write on DDS too, and takes every cloud once.
- The camera's frame is the same bytes with the same source timestamp on DDS as in shared memory (it is written on DDS
  after the shared sample is sent, from the pattern, not from the loan).
- The monitor reads the LiDAR and the camera of its host through shared memory: its presence makes them write nothing
  on DDS (their exit lines say so), and it shows rt/LidarTopic at 20/s.

Latency figures are the benchmark's (`automotive bench system --dds-readers`), not judged here.
"""

from __future__ import annotations

import json
import re
import signal
import subprocess
import time
from pathlib import Path

from cyclonedds.qos import Policy, Qos
from dds_helpers import make_bus, wait_until
from lidar_helpers import Clouds
from shm_helpers import files_of

from automotive.bus import checkedreader
from automotive.bus import stats as records
from automotive.bus.checkedreader import CheckedReader
from automotive.cyclone.matched import matched_publications, matched_subscriptions
from automotive.sim.lfsr import FramePattern
from automotive.tools.support.children import program_command
from automotive.types.automotive import ShapeType
from automotive.types.CameraImage import CameraImageData_64KiB
from automotive.wire import shm
from automotive.wire.camera import FrameWriter
from automotive.wire.rawsample import RawReader

TIMEOUT = 120.0
STATUS = re.compile(r"status: in [^;]*rt/LidarTopic ([0-9.]+)/s")
LIDAR_SENT = r"shared memory: (\d+) clouds sent, (\d+) written on DDS"
CAMERA_SENT = r"shared memory: (\d+) frames sent, (\d+) written on DDS"
# Twice the LiDAR's 20/s is what a reader counting each cloud's DDS copy too shows; the LiDAR never bursts near it.
MOST_PER_S = 30.0


def last_counts(output: str, pattern: str) -> tuple[int, int]:
    found = re.findall(pattern, output)
    assert found, output[-3000:]
    sent, written = found[-1]
    return int(sent), int(written)


def test_a_checked_reader_drops_the_samples_of_skipped_writers_before_decoding_them(domain_id: int) -> None:
    """The mark a shared-memory writer's DDS endpoint carries is what LocalWriters recognises: its samples never reach
    the decoder (nor the take's result); a writer without the mark is decoded as ever."""
    key = "0123456789abcdef"
    decoded: list[bytes] = []

    def counting(data: bytes) -> ShapeType:
        decoded.append(data)
        return ShapeType.deserialize(data)

    bus = make_bus(domain_id)
    checkedreader.set_decoder(ShapeType, counting)
    try:
        mark = Policy.Userdata(shm.USER_DATA_TAG + key.encode())  # what a shared-memory endpoint's USER_DATA says
        reader = bus.reader("Circle", ShapeType, "Shapes", overrides=(mark,))
        assert isinstance(reader, CheckedReader)
        reader.skip_writers(shm.LocalWriters(reader, key).is_local)
        local = bus.writer("Circle", ShapeType, "Shapes", overrides=(mark,))
        other = bus.writer("Circle", ShapeType, "Shapes")
        wait_until(lambda: len(matched_publications(reader)) == 2, what="both writers matched")
        for x in range(5):
            local.write(ShapeType(color="LOCAL", x=x, y=0, shapesize=1))
        other.write(ShapeType(color="OTHER", x=1, y=2, shapesize=3))
        # One participant: Cyclone delivers to its own readers inside write(), so all six are there, in order.
        taken = [s for s in reader.take(N=16) if isinstance(s, ShapeType)]
        assert [s.color for s in taken] == ["OTHER"], taken
        assert len(decoded) == 1, f"{len(decoded)} samples decoded, expected only the other writer's"
    finally:
        checkedreader.set_decoder(ShapeType, None)
        bus.close()


def test_a_camera_frame_is_the_same_bytes_and_source_timestamp_on_dds_as_in_shared_memory(domain_id: int) -> None:
    bus = make_bus(domain_id)
    try:
        writer = bus.writer("CameraImageData_64KiB", CameraImageData_64KiB, "Camera")
        raw = RawReader(bus.reader("CameraImageData_64KiB", CameraImageData_64KiB, "Camera"), zero_copy=False)
        wait_until(lambda: bool(matched_subscriptions(writer)), what="the reader matched")
        frames = FrameWriter(writer, FramePattern(65536))
        shared = bytearray(frames.serialized_length)
        stamp = frames.build_pattern_frame(memoryview(shared), 3, 41)  # what goes into the loan
        assert frames.write_pattern(3, 41, stamp) == stamp  # and on DDS afterwards
        taken: list = []
        wait_until(lambda: bool(taken.extend(raw.take()) or taken), what="the frame on DDS")
        assert bytes(taken[0].data) == bytes(shared)
        assert taken[0].source_timestamp == stamp
    finally:
        bus.close()


def test_a_dds_reader_that_joins_and_leaves_changes_no_count_and_no_cloud_of_sensor_fusion(  # type: ignore[no-untyped-def]
        apps, domain_id: int, prefix: str, tmp_path: Path) -> None:
    stats = tmp_path / "fusion.jsonl"
    common = ["--domain", str(domain_id), "-D", f"config.shmPrefix={prefix}"]
    fusion = apps.start("sensor_fusion", *common, "--stats", str(stats), "-D", "config.statusInterval=3")
    lidar = apps.start("lidar", *common)
    wait_until(lambda: stats.exists() and sum(1 for _ in records.read(stats, "lidar")) >= 5, TIMEOUT,
               "sensor fusion takes clouds through shared memory")

    bus = make_bus(domain_id)  # another locality's reader: the LiDAR writes on DDS for it too
    try:
        clouds = Clouds(bus)
        clouds.next(lambda cloud: True, "on DDS", count=5, timeout=TIMEOUT)
        since = fusion.count(STATUS.pattern)
        # two status periods that begin after the reader got clouds: the second lies wholly within its presence
        fusion.wait_for_more(STATUS.pattern, 2, timeout=TIMEOUT)
        clouds.next(lambda cloud: True, "on DDS still", count=5, timeout=TIMEOUT)
    finally:
        bus.close()
    rates = [float(match[1]) for match in STATUS.finditer(fusion.output)]
    within = rates[since + 1]
    assert 0 < within <= MOST_PER_S, f"sensor fusion counted rt/LidarTopic {within}/s beside a DDS reader: {rates}"

    assert lidar.stop(signal.SIGTERM) == 0, lidar.output
    sent, written = last_counts(lidar.output, LIDAR_SENT)
    assert 10 <= written < sent, (sent, written)  # on DDS while the reader was there, and only then
    assert fusion.stop(signal.SIGTERM) == 0, fusion.output
    sources = [record["src"] for record in records.read(stats, "lidar")]
    assert len(sources) >= 20 and sources == sorted(set(sources)), "a cloud taken twice or out of order"
    assert "bad sample" not in fusion.output
    assert files_of(prefix) == set()


def test_the_monitor_reads_the_lidar_and_the_camera_through_shared_memory(  # type: ignore[no-untyped-def]
        apps, domain_id: int, prefix: str) -> None:
    """Beside sensor fusion (shared memory), the monitor's readers make neither writer write on DDS; the flow shows
    20/s (sensor fusion's /diagnostics and the monitor's own count), not twice that."""
    common = ["--domain", str(domain_id), "-D", f"config.shmPrefix={prefix}"]
    fusion = apps.start("sensor_fusion", *common)
    lidar = apps.start("lidar", *common)
    camera = apps.start("camera_pub", *common, "-D", "config.pubInterval=200")  # waits for the monitor's reader
    document = {}
    deadline = time.monotonic() + TIMEOUT
    while True:
        result = subprocess.run(program_command("monitor", "--json", "--camera", "--wait", "6", *common),
                                capture_output=True, text=True, timeout=TIMEOUT)
        assert result.returncode == 0, result.stderr[-3000:]
        document = json.loads(result.stdout)
        lidar_flow = next((flow for flow in document["flows"] if flow["topic"] == "rt/LidarTopic"), {})
        camera_flow = next((flow for flow in document["flows"] if flow["topic"] == "CameraImageData"), {})
        if ((lidar_flow.get("monitor_rate") or 0) > 5 and (camera_flow.get("monitor_rate") or 0) > 0
                and lidar_flow.get("readers", {}).get("sensor_fusion")):
            break
        assert time.monotonic() < deadline, json.dumps(document)[-3000:]
    assert lidar_flow["monitor_rate"] <= MOST_PER_S, lidar_flow
    assert 0 < lidar_flow["readers"]["sensor_fusion"] <= MOST_PER_S, lidar_flow
    assert "goes over DDS only" not in result.stderr, result.stderr

    assert camera.stop(signal.SIGTERM) == 0, camera.output
    assert lidar.stop(signal.SIGTERM) == 0, lidar.output
    frames, frames_on_dds = last_counts(camera.output, CAMERA_SENT)
    clouds, clouds_on_dds = last_counts(lidar.output, LIDAR_SENT)
    assert frames > 0 and clouds > 0 and (frames_on_dds, clouds_on_dds) == (0, 0), (frames, clouds)
    assert fusion.stop(signal.SIGTERM) == 0, fusion.output
    assert files_of(prefix) == set()


def test_the_dds_write_waits_for_the_shared_memory_readers_to_release_a_sample_and_no_longer(
        domain_id: int, prefix: str) -> None:
    """What FlowWriter.publish waits on before a DDS write: the release of the sample by every subscriber it went to
    (their acknowledgements; the same for a keep-last writer, which flow control never waits for), bounded."""
    memory = shm.SharedMemory("test", domain_id, "Released", prefix)
    writer = shm.SharedWriter(memory, 8, Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(1)),
                              lambda: True)
    readers = [shm.SharedReader(memory, Qos(Policy.History.KeepLast(4))) for _ in range(2)]

    def fill(view: memoryview) -> int:
        view[:] = bytes(8)
        return 1

    try:
        writer.publish(8, fill)
        for reader in readers:
            with reader.take() as samples:
                assert len(samples) == 1
        started = time.monotonic()
        writer.wait_consumed(60.0)  # both released it already: their acknowledgements are there
        assert time.monotonic() - started < 30.0

        writer.publish(8, fill)
        with readers[0].take() as samples:  # one subscriber holds it while the writer waits: the bound ends the wait
            assert len(samples) == 1
            writer.wait_consumed(0.05)
        with readers[1].take() as samples:
            assert len(samples) == 1
    finally:
        writer.close()
        for reader in readers:
            reader.close()
        memory.close()
