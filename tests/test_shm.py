"""The large flows through shared memory on one host (automotive/wire/shm.py, sharedflow.py, iceoryx2), DDS elsewhere.

What issue 32 asks of the camera pair (camera_pub -> camera_sub) and the LiDAR (lidar -> sensor_fusion), tested as
processes: with the shipped transport (``config.transport=auto``) they meet in shared memory and write nothing on DDS;
``udp`` keeps them on DDS and out of /dev/shm; the QoS of the flows holds (flow control, gaps, deadlines, no sample
twice beside an RTI reader); and the faults: a process killed with SIGKILL and restarted in either order is picked up
again, a dead process's files are removed when an application starts, a clean stop leaves nothing in /dev/shm, and a
host whose /dev/shm is full or missing (a mount namespace of the test's own) falls back to DDS with one line
(``config.transport=shm``: exit 2 with one line). One unit test looks at a shared-memory sample from the inside.

Every test names its iceoryx2 files with a prefix of its own (``config.shmPrefix``, the ``prefix`` fixture) and looks
only at those: other processes on this machine may use iceoryx2 at the same time. DDS traffic stays on loopback, a
private domain per test.
"""

from __future__ import annotations

import logging
import re
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from apprunner import AppProcess, AppRunner, CommandProcess
from cyclonedds.core import GuardCondition, WaitSet
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.topic import Topic
from rti_peer import RtiPeer
from shm_helpers import files_of
from test_camera import BEST_EFFORT_QOS, published_total, totals

from automotive.bus import stats
from automotive.bus.qos import WRITER_REPRESENTATION
from automotive.cyclone import serdata
from automotive.sim import lfsr
from automotive.tools.support.children import program_command
from automotive.types.CameraImage import CameraImageData_64KiB
from automotive.wire.camera import FrameWriter, shared_frames
from automotive.wire.shm import DeadlineWatch, SharedFirstWaitSet, SharedMemory, SharedReader, SharedWriter

ROOT = Path(__file__).resolve().parent.parent
PROPERTIES = ROOT / "src" / "automotive" / "config" / "properties"
SHORT_BLOCKING_QOS = ROOT / "tests" / "data" / "camera_short_blocking_qos.xml"
TIMEOUT = 120.0  # starting Python, Cyclone and iceoryx2 on a loaded 2-core machine can take a while
SMALL_FRAMES = ["-D", "config.imageSize=64KiB"]  # 64 KiB frames: the module's run time stays short
# What camera_sub and camera_pub say when they use shared memory (and DDS with everyone else).
VIEWER_ON_SHM = r"\(shared memory with publishers on this host, keeping the last {depth}; DDS with the others\)"
PUBLISHER_ON_SHM = "; shared memory with subscribers on this host, DDS with the others"
CLOUD = re.compile(r"lidar sample stamped (\d+)\.(\d{9}): \d+ points")  # sensor fusion, at DEBUG (the tests' log level)
LIDAR_SENT = r"shared memory: (\d+) clouds sent, (\d+) written on DDS"


def shm_args(domain_id: int, prefix: str, *more: str) -> list[str]:
    """Shared memory forced (``config.transport=shm``: an application stops rather than fall back to DDS)."""
    return ["--domain", str(domain_id), "-D", "config.transport=shm", "-D", f"config.shmPrefix={prefix}", *more]


def shipped_args(domain_id: int, prefix: str, *more: str) -> list[str]:
    """The shipped transport (no config.transport at all: auto), with this test's prefix."""
    return ["--domain", str(domain_id), "-D", f"config.shmPrefix={prefix}", *more]


def viewer_on_shm(depth: int = 8) -> str:
    return VIEWER_ON_SHM.format(depth=depth)


# -- the camera pair -----------------------------------------------------------------------------------------------

@pytest.mark.fast
def test_a_shared_memory_deadline_is_overdue_once_its_period_passed_without_a_sample() -> None:
    """What a flow reader asks at each wake-up before it asks Cyclone for its writers (FlowReader.check_deadline)."""
    reported: list[object] = []
    watch = DeadlineWatch(0.5, reported.append)
    assert not watch.overdue(now=0.0)  # no instance yet
    watch.sample("cloud", now=10.0)
    assert not watch.overdue(now=10.4) and watch.overdue(now=10.5)
    watch.check(now=10.5)
    assert len(reported) == 1 and not watch.overdue(now=10.6)  # reported once a period
    watch.forget()
    assert not watch.overdue(now=99.0)
    assert not DeadlineWatch(None, reported.append).overdue()  # no deadline asked


def test_camera_pair_over_shared_memory_verifies_every_frame_at_full_speed(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                                            prefix: str) -> None:
    """Full-size frames as fast as possible: the reliable Camera profile's flow control loses none."""
    frames = 60
    sub = apps.start("camera_sub", *shm_args(domain_id, prefix, "--count", str(frames)))
    sub.wait_for(f"viewing CameraImageData frames of 4196352 bytes {viewer_on_shm()}", timeout=TIMEOUT)
    pub = apps.start("camera_pub", *shm_args(domain_id, prefix, "--count", str(frames),
                                             "-D", "config.pubInterval=0"))
    assert pub.wait_exit(timeout=TIMEOUT) == 0, pub.output
    assert sub.wait_exit(timeout=TIMEOUT) == 0, sub.output
    assert f"shared memory: {frames} frames sent, 0 written on DDS" in pub.output  # no DDS reader: no DDS cost
    result = totals(sub.output)
    assert (result["samples"], result["size"], result["mismatches"], result["gaps"]) == (
        str(frames), "4196352", "0", "0"), sub.output


def test_camera_frames_go_through_shared_memory_with_the_shipped_transport(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                                           prefix: str) -> None:
    """No config.transport anywhere (the shipped properties say auto): the pair meets in shared memory and the
    publisher writes no frame on DDS, as nobody but the viewer (same host) reads them."""
    for program in ("camera_pub", "camera_sub"):
        settings = (PROPERTIES / f"{program}.properties").read_text().splitlines()
        assert "config.transport=auto" in settings, program
    frames = 50
    args = shipped_args(domain_id, prefix, *SMALL_FRAMES)
    sub = apps.start("camera_sub", *args, "--count", str(frames))
    sub.wait_for(f"viewing CameraImageData_64KiB frames of 65536 bytes {viewer_on_shm()}", timeout=TIMEOUT)
    pub = apps.start("camera_pub", *args, "--count", str(frames), "-D", "config.pubInterval=10")
    assert pub.wait_exit(timeout=TIMEOUT) == 0, pub.output
    assert sub.wait_exit(timeout=TIMEOUT) == 0, sub.output
    assert PUBLISHER_ON_SHM in pub.output
    assert f"shared memory: {frames} frames sent, 0 written on DDS" in pub.output
    result = totals(sub.output)
    assert (result["samples"], result["mismatches"], result["gaps"]) == (str(frames), "0", "0"), sub.output


def test_transport_udp_keeps_camera_and_lidar_on_dds_and_out_of_dev_shm(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                                         prefix: str, tmp_path: Path) -> None:
    """``config.transport=udp`` on both ends: no file of ours in /dev/shm while the flows run, and everything the
    readers get came on DDS."""
    args = shipped_args(domain_id, prefix, "-D", "config.transport=udp")
    sub = apps.start("camera_sub", *args, *SMALL_FRAMES, "--exit-with-publisher")
    fusion = start_fusion(apps, args, tmp_path / "fusion.jsonl")
    sub.wait_for("viewing CameraImageData_64KiB frames of 65536 bytes, until the publisher leaves$", timeout=TIMEOUT)
    pub = apps.start("camera_pub", *args, *SMALL_FRAMES, "-D", "config.pubInterval=20")
    lidar = start_lidar(apps, args)
    sub.wait_for(r"samples=\d+ size=65536", timeout=TIMEOUT)  # frames arrive
    fusion.wait_for(CLOUD.pattern, count=5, timeout=TIMEOUT)  # and clouds
    assert files_of(prefix, include_global=True) == set()  # not even iceoryx2's node file: no node at all
    assert pub.stop(signal.SIGTERM) == 0, pub.output
    assert lidar.stop(signal.SIGTERM) == 0, lidar.output
    assert sub.wait_exit(timeout=TIMEOUT) == 0, sub.output
    assert fusion.stop(signal.SIGTERM) == 0, fusion.output
    published = published_total(pub.output)
    assert "not all acknowledged" not in pub.output, pub.output  # every one acknowledged
    result = totals(sub.output)
    assert (result["samples"], result["mismatches"], result["gaps"]) == (str(published), "0", "0"), sub.output
    for process in (pub, sub, lidar, fusion):
        assert "shared memory" not in process.output, process.output
    assert files_of(prefix, include_global=True) == set()


def test_gaps_are_counted_when_the_subscriber_falls_behind(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                          prefix: str) -> None:
    """Best effort, keep last 1: the viewer frozen (SIGSTOP) while frames go by finds only the last one."""
    qos = ["-D", f"qos.File={BEST_EFFORT_QOS}", "-D", "qos.Library=CameraTests",
           "-D", "qos.Camera.Profile=CameraBestEffort", *SMALL_FRAMES]
    sub = apps.start("camera_sub", *shm_args(domain_id, prefix, "--exit-with-publisher", *qos))
    sub.wait_for(viewer_on_shm(1), timeout=TIMEOUT)
    # No --count: 400 frames (2 s) once ran out before the publisher's next per-second line, which the frozen
    # viewer waits for, came.
    pub = apps.start("camera_pub", *shm_args(domain_id, prefix, "-D", "config.pubInterval=5", *qos))
    sub.wait_for(r"samples=\d+ size=65536", timeout=TIMEOUT)  # frames are arriving
    with sub.frozen():
        pub.wait_for_more(r"published \d+ frames:", 1, timeout=TIMEOUT)  # a second or more goes by
    assert pub.stop(signal.SIGTERM) == 0, pub.output
    assert sub.wait_exit(timeout=TIMEOUT) == 0, sub.output  # it noticed the publisher leave
    result = totals(sub.output)
    assert int(result["gaps"]) > 0, sub.output
    assert int(result["samples"]) + int(result["gaps"]) <= published_total(pub.output), sub.output
    assert result["mismatches"] == "0", sub.output


def test_a_stalled_or_dead_subscriber_holds_a_reliable_publisher_back_at_most_max_blocking_time(  # type: ignore[no-untyped-def]
        apps, domain_id: int, prefix: str) -> None:
    """Reliable keep-all with max_blocking_time 0.5 s: a frozen viewer (SIGSTOP) stops the flow only that long and
    then loses what overflows its queue (gaps, never wrong bytes); a killed one (SIGKILL) is found dead while flow
    control waits for it, and the flow goes on."""
    qos = ["-D", f"qos.File={SHORT_BLOCKING_QOS}", "-D", "qos.Library=CameraTests",
           "-D", "qos.Camera.Profile=CameraShortBlocking", *SMALL_FRAMES]
    args = shm_args(domain_id, prefix, *qos)
    stalled = apps.start("camera_sub", *args, "--exit-with-publisher")
    stalled.wait_for(viewer_on_shm(8), timeout=TIMEOUT)
    pub = apps.start("camera_pub", *args, "-D", "config.pubInterval=5")
    stalled.wait_for(r"samples=\d+ size=65536", timeout=TIMEOUT)
    with stalled.frozen():
        pub.wait_for(r"shared memory: no sample consumed for 0.5 s", timeout=TIMEOUT)
        pub.wait_for_more(r"published \d+ frames:", 2, timeout=TIMEOUT)  # the flow goes on
    stalled.wait_for_more(r"samples=\d+ size=65536", 1, timeout=TIMEOUT)  # it catches up
    dead = apps.start("camera_sub", *args)
    dead.wait_for(r"samples=\d+ size=65536", timeout=TIMEOUT)
    dead.stop(signal.SIGKILL)
    pub.wait_for_more(r"published \d+ frames:", 2, timeout=TIMEOUT)  # the flow goes on
    assert pub.stop(signal.SIGTERM) == 0, pub.output
    assert stalled.wait_exit(timeout=TIMEOUT) == 0, stalled.output
    result = totals(stalled.output)
    assert int(result["gaps"]) > 0 and result["mismatches"] == "0", stalled.output


def test_the_last_frame_of_a_count_waits_for_room_and_is_sent_like_any_other(  # type: ignore[no-untyped-def]
        apps, domain_id: int, prefix: str) -> None:
    """``--count 9`` with flow control's window of 8 and a subscriber that takes nothing before the publisher exits:
    the 9th frame, the last, waits for room (max_blocking_time, 0.5 s) and is sent, as any other would be. (The end
    of ``--count`` used to stop the application before its last frame was written, and flow control gave that frame
    up as if a signal had stopped it: a loaded run sent 2,999 frames of 3,000.)"""
    qos = ["-D", f"qos.File={SHORT_BLOCKING_QOS}", "-D", "qos.Library=CameraTests",
           "-D", "qos.Camera.Profile=CameraShortBlocking", *SMALL_FRAMES]
    memory = SharedMemory("test", domain_id, "CameraImageData", prefix)
    reader = SharedReader(memory, Qos(Policy.History.KeepLast(8)))
    try:
        pub = apps.start("camera_pub", *shm_args(domain_id, prefix, "--count", "9", "-D", "config.pubInterval=0",
                                                 "-D", "config.waitSubscribers=0", *qos))
        assert pub.wait_exit(timeout=TIMEOUT) == 0, pub.output
        assert "not written" not in pub.output, pub.output
        assert "shared memory: no sample consumed for 0.5 s" in pub.output, pub.output  # it did wait for room
        assert "shared memory: 9 frames sent, 0 written on DDS" in pub.output, pub.output
    finally:
        reader.close()
        memory.close()


def test_a_keep_last_subscriber_never_holds_a_reliable_keep_all_publisher_back(
        domain_id: int, prefix: str, caplog: pytest.LogCaptureFixture) -> None:
    """A subscriber that keeps only the newest sample (the samples before it overwritten in its queue) acknowledges
    those it never got, as a DDS reader acknowledges what its history replaced: the publisher's window of 8 never
    fills with them, so it never waits (which would end in its "no sample consumed" warning after 1 s)."""
    memory = SharedMemory("test", domain_id, "KeepLast", prefix)
    writer_qos = Qos(Policy.Reliability.Reliable(10**9), Policy.History.KeepAll,
                     Policy.ResourceLimits(max_samples=8, max_instances=1, max_samples_per_instance=8))
    writer = SharedWriter(memory, 8, writer_qos, lambda: True)
    reader = SharedReader(memory, Qos(Policy.History.KeepLast(1)))
    newest: list[int] = []

    def fill(view: memoryview) -> int:
        view[:] = bytes(8)
        return 1
    try:
        with caplog.at_level(logging.WARNING):
            for number in range(1, 41):
                writer.publish(8, fill)
                if number % 5 == 0:  # every fifth: only the newest is still queued
                    with reader.take() as samples:
                        newest.extend(sample.sequence for sample in samples)
        assert newest == [5, 10, 15, 20, 25, 30, 35, 40]
        assert "no sample consumed" not in caplog.text
    finally:
        writer.close()
        reader.close()
        memory.close()


def test_a_subscriber_that_takes_every_sample_acknowledges_each_once(domain_id: int, prefix: str) -> None:
    """Taking every sample, a subscriber skipped none: the publisher hears one "consumed" per sample and no other (an
    acknowledgement of a sample not yet taken would let a reliable publisher's flow control run ahead of it)."""
    memory = SharedMemory("test", domain_id, "EveryOne", prefix)
    qos = Qos(Policy.Reliability.Reliable(10**9), Policy.History.KeepAll,
              Policy.ResourceLimits(max_samples=8, max_instances=1, max_samples_per_instance=8))
    writer = SharedWriter(memory, 8, qos, lambda: True)
    reader = SharedReader(memory, qos)

    def fill(view: memoryview) -> int:
        view[:] = bytes(8)
        return 1
    try:
        for number in range(1, 31):
            writer.publish(8, fill)
            with reader.take() as samples:
                assert [sample.sequence for sample in samples] == [number]
            heard: dict[int, int] = {}
            activations = writer.acks.try_wait()
            for activation in activations:
                heard[activation.id.as_value] = heard.get(activation.id.as_value, 0) + activation.count
            writer._collect(activations)  # looked at here, still counted by its flow control
            assert heard == {number: 1}, f"sample {number}"
    finally:
        writer.close()
        reader.close()
        memory.close()


def test_a_shared_first_waitset_wakes_on_a_sample_and_on_the_dds_side_once_a_round(domain_id: int, prefix: str) -> None:
    """The taking thread waits on shared memory itself; the DDS side (here a guard condition in the Cyclone WaitSet)
    wakes it through its thread: once per wait while it stays true, never again once it is taken; nothing: a
    timeout (0)."""
    memory = SharedMemory("test", domain_id, "SharedFirst", prefix)
    qos = Qos(Policy.History.KeepLast(8))
    writer = SharedWriter(memory, 8, qos, lambda: True)
    reader = SharedReader(memory, qos)
    participant = DomainParticipant(domain_id)
    dds_side = GuardCondition(participant)
    dds = WaitSet(participant)
    dds.attach(dds_side)
    waits = SharedFirstWaitSet(reader, dds)

    def fill(view: memoryview) -> int:
        view[:] = bytes(8)
        return 1
    try:
        assert waits.wait(int(0.2e9)) == 0  # nothing yet
        writer.publish(8, fill)
        assert waits.wait(int(30e9)) >= 1
        with reader.take() as samples:
            assert [sample.sequence for sample in samples] == [1]
        assert waits.wait(int(0.2e9)) == 0  # the sample's wake-up was used up
        dds_side.set(True)
        assert waits.wait(int(30e9)) >= 1
        assert waits.wait(int(30e9)) >= 1  # still true: the next round wakes again
        dds_side.take()
        waits.wait(int(0.2e9))  # (a round that began before the take may still come)
        assert waits.wait(int(0.2e9)) == 0
        # one way of waiting per subscriber
        with pytest.raises(RuntimeError, match="already waited on by a SharedFirstWaitSet"):
            SharedFirstWaitSet(reader, dds)
        with pytest.raises(RuntimeError, match="already waited on by a SharedFirstWaitSet"):
            reader.wake(GuardCondition(participant))
    finally:
        writer.close()
        reader.close()  # closes the waitset first (its thread ends)
        memory.close()
    assert not waits._thread.is_alive()


def test_frames_are_read_only_views_of_shared_memory_that_end_with_their_block(domain_id: int, prefix: str) -> None:
    """A shared-memory sample is the DDS sample's bytes, read in place in the publisher's segment, read-only, with
    its source timestamp and sequence in the header; it is given back when its ``with`` block ends, and refused back
    while something still holds a view of it."""
    participant = DomainParticipant(domain_id)
    memory = SharedMemory("test", domain_id, "CameraFrames", prefix)
    qos = Qos(Policy.Reliability.Reliable(10**9), Policy.History.KeepLast(4))
    reader = SharedReader(memory, qos)
    dds = DataWriter(participant, Topic(participant, "CameraFrames", CameraImageData_64KiB),
                     qos=Qos(WRITER_REPRESENTATION, base=qos))
    pattern = lfsr.FramePattern(65536)
    frames = FrameWriter(dds, pattern)
    length = frames.serialized_length
    writer = SharedWriter(memory, length, qos, lambda: True)

    def frame_of(seqnum: int) -> Callable[[memoryview], int]:
        return lambda view: frames.build_pattern_frame(view, 5, seqnum)

    try:
        assert writer.subscribers == 1
        stamps = [writer.publish(length, frame_of(seqnum)) for seqnum in (1, 2, 3)]
        assert writer.sent == 3
        with reader.take(1) as samples:
            sample = samples[0]
            assert (sample.sequence, sample.source_timestamp) == (1, stamps[0])
            sec, nanosec = divmod(stamps[0], 1_000_000_000)
            expected = CameraImageData_64KiB(id=5, sec_=sec, nanosec_=nanosec, seqnum=1,
                                             data=list(bytes(pattern.frame(1))))
            assert bytes(sample.data) == serdata.serialize(dds, expected)  # exactly what DDS would carry
            del sample
        with shared_frames(reader.take(1), frames.codec) as taken:
            frame = taken[0]
            assert (frame.id, frame.seqnum, frame.timestamp_ns) == (5, 2, stamps[1])
            assert frame.data.readonly and frame.data == pattern.frame(2)
            array = np.frombuffer(frame.data, np.uint8)
            assert not array.flags.writeable
            with pytest.raises(ValueError, match="read-only"):
                array[0] = 1
            with pytest.raises(TypeError):
                frame.data[0] = 1
            address = array.__array_interface__["data"][0]
            assert mapped_file(address).startswith(f"/dev/shm/{prefix}")  # zero copy: the publisher's segment
            del array
        with pytest.raises(ValueError, match="released"):
            bytes(frame.data)
        kept = None
        with pytest.raises(RuntimeError, match="still in use"):
            with shared_frames(reader.take(1), frames.codec) as taken:
                kept = np.frombuffer(taken[0].data, np.uint8)  # outlives the block: refused, not given back
        assert kept is not None and bytes(kept) == bytes(pattern.frame(3))
        with reader.take(1) as samples:
            assert samples == []
        with pytest.raises(ValueError, match="at most"):
            writer.publish(length + 1, frame_of(4))
    finally:
        writer.close()
        reader.close()
        memory.close()
        participant.__del__()


def mapped_file(address: int) -> str:
    """The file mapped at ``address`` in this process (/proc/self/maps), or '' for anonymous memory."""
    for line in Path("/proc/self/maps").read_text().splitlines():
        fields = line.split(maxsplit=5)
        start, end = (int(value, 16) for value in fields[0].split("-"))
        if start <= address < end:
            return fields[5] if len(fields) > 5 else ""
    return ""


def flowing_pair(apps: AppRunner, args: list[str]) -> tuple[AppProcess, AppProcess]:
    """camera_sub, then camera_pub (64 KiB frames, 50 a second, until stopped), once frames arrive."""
    sub = apps.start("camera_sub", *args)
    sub.wait_for(viewer_on_shm(), timeout=TIMEOUT)
    pub = apps.start("camera_pub", *args, "-D", "config.pubInterval=20")
    sub.wait_for(r"samples=\d+ size=65536", timeout=TIMEOUT)
    return sub, pub


def test_a_sigkilled_camera_publisher_restarted_is_picked_up(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                             prefix: str) -> None:
    args = shipped_args(domain_id, prefix, *SMALL_FRAMES)
    sub, first = flowing_pair(apps, args)
    first.stop(signal.SIGKILL)
    second = apps.start("camera_pub", *args, "-D", "config.pubInterval=20")
    sub.wait_for(r"seqnum went back from \d+ to 1 \(publisher restarted\?\)", timeout=TIMEOUT)
    sub.wait_for_more(r"samples=\d+ size=65536", 1, timeout=TIMEOUT)  # the new publisher's frames flow
    assert second.stop(signal.SIGTERM) == 0, second.output
    assert re.search(r"shared memory: [1-9]\d* frames sent, 0 written on DDS", second.output), second.output
    assert sub.stop(signal.SIGTERM) == 0, sub.output
    result = totals(sub.output)
    assert result["mismatches"] == "0" and int(result["samples"]) > 0, sub.output


def test_a_sigkilled_camera_subscriber_restarted_is_picked_up(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                              prefix: str) -> None:
    """The viewer killed while the publisher runs (shipped QoS: its full queue holds the publisher back once, at
    most max_blocking_time), then started again: frames reach it through shared memory, none twice, none missing."""
    args = shipped_args(domain_id, prefix, *SMALL_FRAMES)
    first, pub = flowing_pair(apps, args)
    first.stop(signal.SIGKILL)
    second = apps.start("camera_sub", *args, "--exit-with-publisher")
    second.wait_for(viewer_on_shm(), timeout=TIMEOUT)
    second.wait_for(r"samples=\d+ size=65536", count=2, timeout=TIMEOUT)
    assert pub.stop(signal.SIGTERM) == 0, pub.output
    assert re.search(r"shared memory: [1-9]\d* frames sent, 0 written on DDS", pub.output), pub.output
    assert second.wait_exit(timeout=TIMEOUT) == 0, second.output
    result = totals(second.output)
    assert (result["mismatches"], result["gaps"]) == ("0", "0") and int(result["samples"]) > 0, second.output


def test_a_clean_stop_leaves_nothing_in_dev_shm(apps, domain_id: int, prefix: str) -> None:  # type: ignore[no-untyped-def]
    args = shm_args(domain_id, prefix, *SMALL_FRAMES)
    sub = apps.start("camera_sub", *args, "--exit-with-publisher")
    sub.wait_for(viewer_on_shm(), timeout=TIMEOUT)
    pub = apps.start("camera_pub", *args, "--count", "20", "-D", "config.pubInterval=10")
    pub.wait_for(r"published \d+ frames in total", timeout=TIMEOUT)
    assert pub.wait_exit(timeout=TIMEOUT) == 0, pub.output
    assert sub.wait_exit(timeout=TIMEOUT) == 0, sub.output
    assert totals(sub.output)["samples"] == "20", sub.output
    assert files_of(prefix) == set()


def test_stale_files_of_dead_processes_are_removed_on_start(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                           prefix: str) -> None:
    args = shm_args(domain_id, prefix, *SMALL_FRAMES)
    sub, pub = flowing_pair(apps, args)
    pub.stop(signal.SIGKILL)
    sub.stop(signal.SIGKILL)
    stale = files_of(prefix)
    assert any(path.name.endswith(".data") for path in stale), stale  # the publisher's frames, left behind
    fresh = apps.start("camera_sub", *args)
    fresh.wait_for("shared memory: removed the files of 2 dead process", timeout=TIMEOUT)
    fresh.wait_for(viewer_on_shm(), timeout=TIMEOUT)
    # Gone: the dead processes' frames, connections and node records; the services' descriptions (*.service) are
    # the same files again, reopened by the new subscriber.
    assert {path for path in stale & files_of(prefix) if not path.name.endswith(".service")} == set()
    assert fresh.stop(signal.SIGTERM) == 0, fresh.output
    assert files_of(prefix) == set()


def test_shared_memory_subscriber_and_rti_reader_at_once_get_every_frame_once(  # type: ignore[no-untyped-def]
        apps, domain_id: int, prefix: str) -> None:
    """The hybrid, with the shipped QoS and transport: frames through shared memory to our viewer and, because a DDS
    reader without our locality is matched, on DDS to an RTI reader; the viewer drops the DDS copies it also gets
    (its DDS reader matches the publisher's writer), so it sees every seqnum exactly once."""
    frames = 20
    args = shipped_args(domain_id, prefix, *SMALL_FRAMES, "-D", "topic.Camera=CameraImageData_64KiB")
    with RtiPeer(domain_id, readers=["Camera64KiB"]) as rti:
        sub = apps.start("camera_sub", *args, "--count", str(frames))
        sub.wait_for(viewer_on_shm(), timeout=TIMEOUT)
        pub = apps.start("camera_pub", *args, "--count", str(frames), "-D", "config.pubInterval=50",
                         "-D", "config.waitSubscribers=2")  # the RTI reader and our viewer
        received = rti.take_until("Camera64KiB", frames, timeout=TIMEOUT)
        assert pub.wait_exit(timeout=TIMEOUT) == 0, pub.output
        assert sub.wait_exit(timeout=TIMEOUT) == 0, sub.output
    assert f"shared memory: {frames} frames sent, {frames} written on DDS" in pub.output
    result = totals(sub.output)
    assert (result["samples"], result["mismatches"], result["gaps"]) == (str(frames), "0", "0"), sub.output
    assert "seqnum went back" not in sub.output  # a second copy of a frame would have gone back
    pattern = lfsr.FramePattern(65536)
    assert [sample["seqnum"] for sample in received] == list(range(1, frames + 1))
    assert all(bytes(sample["data"]) == bytes(pattern.frame(sample["seqnum"])) for sample in received)


@pytest.mark.parametrize("setting", ["config.transport=tcp", "config.transport=SHM", "config.transport=dds",
                                     "config.shmPrefix=a/b"])
def test_bad_transport_settings_are_one_line_on_stderr(apps, setting: str) -> None:  # type: ignore[no-untyped-def]
    """``dds`` was the old default's name: an old properties file gets a clear line too."""
    key, value = setting.split("=")
    for app in ("camera_pub", "camera_sub", "lidar", "sensor_fusion"):
        result = apps.run(app, "--domain", "81", "-D", setting, timeout=TIMEOUT)
        assert result.returncode == 2, result.stdout + result.stderr
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and f"{key} = '{value}'" in lines[0], result.stderr
        assert "Traceback" not in result.stdout + result.stderr


# -- the LiDAR and sensor fusion ------------------------------------------------------------------------------------

def start_fusion(apps: AppRunner, args: list[str], stats_file: Path | None = None) -> AppProcess:
    """sensor_fusion, once it waits for data (it logs each cloud at DEBUG, the tests' log level)."""
    fusion = apps.start("sensor_fusion", *args, *(["--stats", str(stats_file)] if stats_file else []))
    fusion.wait_for("sensor fusion: periodic mode", timeout=TIMEOUT)
    return fusion


def start_lidar(apps: AppRunner, args: list[str]) -> AppProcess:
    lidar = apps.start("lidar", *args)
    lidar.wait_for(r"lidar: \d+ azimuth x \d+ polar steps", timeout=TIMEOUT)
    return lidar


def stamp_ns(match: re.Match[str]) -> int:
    return int(match[1]) * 1_000_000_000 + int(match[2])


def wait_for_cloud_since(fusion: AppProcess, since_ns: int) -> None:
    """Wait until sensor fusion logs a cloud that the LiDAR stamped at ``since_ns`` (time.time_ns) or later."""
    deadline = time.monotonic() + TIMEOUT
    while not any(stamp_ns(match) >= since_ns for _, match in fusion.matches(CLOUD)):
        fusion.wait_for_more(CLOUD.pattern, 1, timeout=max(1.0, deadline - time.monotonic()))


def stop_lidar(lidar: AppProcess) -> tuple[int, int]:
    """Stop the LiDAR with SIGTERM; its last line's (clouds sent through shared memory, clouds written on DDS)."""
    assert lidar.stop(signal.SIGTERM) == 0, lidar.output
    found = re.findall(LIDAR_SENT, lidar.output)
    assert found, lidar.output
    sent, written = found[-1]
    return int(sent), int(written)


def test_lidar_clouds_go_through_shared_memory_to_sensor_fusion_with_the_shipped_transport(  # type: ignore[no-untyped-def]
        apps, domain_id: int, prefix: str, tmp_path: Path) -> None:
    """No config.transport: sensor fusion gets the clouds from shared memory (its --stats records each one's hop)
    and the LiDAR writes none on DDS."""
    args = shipped_args(domain_id, prefix)
    stats_file = tmp_path / "fusion.jsonl"
    fusion = start_fusion(apps, args, stats_file)
    lidar = start_lidar(apps, args)
    fusion.wait_for(CLOUD.pattern, count=20, timeout=TIMEOUT)
    sent, written = stop_lidar(lidar)
    assert sent >= 20 and written == 0, lidar.output
    assert fusion.stop(signal.SIGTERM) == 0, fusion.output
    records = list(stats.read(stats_file, "lidar"))
    assert len(records) >= 20 and all(0 <= record["hop_ns"] < 10**10 for record in records), records[:3]
    assert len({record["src"] for record in records}) == len(records)  # no cloud twice


def test_a_sigkilled_lidar_or_sensor_fusion_restarted_is_picked_up(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                                   prefix: str) -> None:
    """The LiDAR killed and started again while sensor fusion runs, then sensor fusion killed and started again
    while the LiDAR runs: each time the clouds flow again, through shared memory."""
    args = shipped_args(domain_id, prefix)
    fusion = start_fusion(apps, args)
    first = start_lidar(apps, args)
    fusion.wait_for(CLOUD.pattern, timeout=TIMEOUT)
    first.stop(signal.SIGKILL)
    restarted = time.time_ns()
    lidar = start_lidar(apps, args)
    wait_for_cloud_since(fusion, restarted)  # the new LiDAR's clouds
    fusion.stop(signal.SIGKILL)
    fusion = start_fusion(apps, args)
    fusion.wait_for(CLOUD.pattern, count=3, timeout=TIMEOUT)
    sent, written = stop_lidar(lidar)
    assert sent > 0 and written == 0, lidar.output  # the dead sensor fusion's DDS reader is of this host too
    assert fusion.stop(signal.SIGTERM) == 0, fusion.output
    assert files_of(prefix) == set()


def test_stale_files_of_a_dead_lidar_and_sensor_fusion_are_removed_on_start(  # type: ignore[no-untyped-def]
        apps, domain_id: int, prefix: str) -> None:
    args = shipped_args(domain_id, prefix)
    fusion = start_fusion(apps, args)
    lidar = start_lidar(apps, args)
    fusion.wait_for(CLOUD.pattern, timeout=TIMEOUT)
    lidar.stop(signal.SIGKILL)
    fusion.stop(signal.SIGKILL)
    stale = files_of(prefix)
    assert any(path.name.endswith(".data") for path in stale), stale  # the LiDAR's clouds, left behind
    fresh = apps.start("lidar", *args)
    fresh.wait_for("shared memory: removed the files of 2 dead process", timeout=TIMEOUT)
    fresh.wait_for(r"lidar: \d+ azimuth x \d+ polar steps", timeout=TIMEOUT)
    assert {path for path in stale & files_of(prefix) if not path.name.endswith(".service")} == set()
    stop_lidar(fresh)
    assert files_of(prefix) == set()


def test_a_clean_stop_of_lidar_and_sensor_fusion_leaves_nothing_in_dev_shm(  # type: ignore[no-untyped-def]
        apps, domain_id: int, prefix: str) -> None:
    args = shipped_args(domain_id, prefix)
    fusion = start_fusion(apps, args)
    lidar = start_lidar(apps, args)
    fusion.wait_for(CLOUD.pattern, count=5, timeout=TIMEOUT)
    assert files_of(prefix)  # they do use shared memory
    assert fusion.stop(signal.SIGTERM) == 0, fusion.output  # the reader first, then the writer
    sent, written = stop_lidar(lidar)
    assert sent >= 5 and written == 0, lidar.output
    assert files_of(prefix) == set()


def test_a_lidar_frozen_longer_than_the_deadline_is_reported_by_sensor_fusion(  # type: ignore[no-untyped-def]
        apps, domain_id: int, prefix: str) -> None:
    """The Lidar profile's deadlines hold through shared memory: the LiDAR stopped (SIGSTOP) for longer than the
    reader's 2 s makes sensor fusion report a requested deadline missed, and the LiDAR, once it runs again, an
    offered one (1 s); then the clouds flow again."""
    args = shipped_args(domain_id, prefix)
    fusion = start_fusion(apps, args)
    lidar = start_lidar(apps, args)
    fusion.wait_for(CLOUD.pattern, count=3, timeout=TIMEOUT)
    since = len(fusion.records)
    with lidar.frozen():
        fusion.wait_for_line(r"WARNING: \[rt/LidarTopic\] requested deadline missed", timeout=TIMEOUT, since=since)
    lidar.wait_for(r"WARNING: \[rt/LidarTopic\] offered deadline missed", timeout=TIMEOUT)
    fusion.wait_for_more(CLOUD.pattern, 3, timeout=TIMEOUT)
    sent, written = stop_lidar(lidar)
    assert sent > 0 and written == 0, lidar.output  # it was shared memory's deadline, not DDS's
    assert fusion.stop(signal.SIGTERM) == 0, fusion.output


# -- a host whose /dev/shm is full or missing ----------------------------------------------------------------------

# Shell commands that make, in a new mount namespace, a /dev/shm too small for a publisher's segment (1 MiB; one of
# 64 KiB frames takes some 5 MiB), or none at all: a fresh /dev holding only the devices the programs open.
DEV_SHM = {
    "full": "mount -t tmpfs -o size=1m tmpfs /dev/shm",
    "missing": "mount -t tmpfs -o size=64k,mode=755 tmpfs /dev"
               " && mknod -m 666 /dev/null c 1 3 && mknod -m 666 /dev/zero c 1 5"
               " && mknod -m 666 /dev/random c 1 8 && mknod -m 666 /dev/urandom c 1 9"
               " && ln -s /proc/self/fd /dev/fd && test ! -e /dev/shm",
}
WHY = {"full": r"/dev/shm has \d+ KiB free, the publisher of CameraImageData needs \d+ KiB",
       "missing": "/dev/shm does not exist"}


class MountNamespace:
    """A mount namespace of the test's own, held by a sleeping process; programs join it with nsenter. The real
    /dev and /dev/shm are never touched: the namespace's mounts go with its last process."""

    def __init__(self, apps: AppRunner, setup: str):
        self.holder: CommandProcess = apps.start_command("mount-namespace", [
            "unshare", "--mount", "--propagation", "private", "sh", "-c",
            f"{setup} && echo namespace ready && exec sleep infinity"])
        self.holder.wait_for("^namespace ready$", timeout=TIMEOUT)

    def command(self, program: str, *args: str) -> list[str]:
        return ["nsenter", f"--target={self.holder.pid}", "--mount", "--", *program_command(program, *args)]


def fallback_lines(process: CommandProcess) -> list[str]:
    return [line for line in process.lines if "WARNING" in line and "shared memory" in line]


@pytest.mark.parametrize("condition", ["full", "missing"])
def test_camera_frames_fall_back_to_dds_with_one_line_when_dev_shm_is(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                                      prefix: str, condition: str) -> None:
    """Publisher and viewer on a host whose /dev/shm is full or missing, with the shipped transport: the publisher
    says once why shared memory cannot carry the frames, and DDS carries every one of them."""
    namespace = MountNamespace(apps, DEV_SHM[condition])
    frames = 30
    args = shipped_args(domain_id, prefix, *SMALL_FRAMES, "--count", str(frames))
    sub = apps.start_command("camera_sub", namespace.command("camera_sub", *args))
    sub.wait_for("viewing CameraImageData_64KiB frames of 65536 bytes", timeout=TIMEOUT)
    pub = apps.start_command("camera_pub", namespace.command("camera_pub", *args, "-D", "config.pubInterval=10"))
    assert pub.wait_exit(timeout=TIMEOUT) == 0, pub.output
    assert sub.wait_exit(timeout=TIMEOUT) == 0, sub.output
    warned = fallback_lines(pub)
    assert len(warned) == 1, pub.output
    assert re.search(f"WARNING: shared memory: {WHY[condition]}; CameraImageData goes over DDS only$", warned[0])
    if condition == "missing":  # the viewer cannot use it either: one line of its own
        assert len(fallback_lines(sub)) == 1 and "/dev/shm does not exist" in fallback_lines(sub)[0], sub.output
    else:  # the viewer's own ports fit: it waits in shared memory in vain, and takes the frames from DDS
        assert fallback_lines(sub) == [] and re.search(viewer_on_shm(), sub.output), sub.output
    result = totals(sub.output)
    assert (result["samples"], result["mismatches"], result["gaps"]) == (str(frames), "0", "0"), sub.output
    assert "Traceback" not in pub.output + sub.output


@pytest.mark.parametrize("condition", ["full", "missing"])
def test_transport_shm_stops_with_one_line_when_dev_shm_is(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                           prefix: str, condition: str) -> None:
    """``config.transport=shm`` where shared memory cannot carry the frames: exit 2 and one line on stderr saying
    why, no traceback (the viewer needs no room, so only a missing /dev/shm stops it)."""
    namespace = MountNamespace(apps, DEV_SHM[condition])
    programs = ["camera_pub", "camera_sub"] if condition == "missing" else ["camera_pub"]
    for program in programs:
        result = subprocess.run(namespace.command(program, *shm_args(domain_id, prefix, *SMALL_FRAMES)),
                                cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT)
        assert result.returncode == 2, result.stdout + result.stderr
        lines = result.stderr.strip().splitlines()
        why = WHY[condition] if program == "camera_pub" else "/dev/shm does not exist"
        assert len(lines) == 1 and re.search(f"config.transport = 'shm', but shared memory cannot carry "
                                             f"CameraImageData: {why}$", lines[0]), result.stderr
        assert "Traceback" not in result.stdout + result.stderr
