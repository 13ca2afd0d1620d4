"""Camera frames through shared memory (config.transport=shm, automotive/shm.py, iceoryx2).

Every test names its iceoryx2 files with a prefix of its own (``config.shmPrefix``) and looks only at those: other
processes on this machine may use iceoryx2 at the same time. DDS traffic stays on loopback, a private domain per test.
"""

from __future__ import annotations

import itertools
import os
import re
import signal
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from apprunner import AppProcess
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.topic import Topic
from rti_peer import RtiPeer
from test_camera import BEST_EFFORT_QOS, totals

from automotive.bus.qos import WRITER_REPRESENTATION
from automotive.sim import lfsr
from automotive.types.CameraImage import CameraImageData_64KiB
from automotive.wire.camera import FrameWriter
from automotive.wire.shm import SharedFrameReader, SharedFrameWriter, SharedMemory

ROOT = Path(__file__).resolve().parent.parent
SHORT_BLOCKING_QOS = ROOT / "tests" / "data" / "camera_short_blocking_qos.xml"
TIMEOUT = 120.0  # starting Python, Cyclone and iceoryx2 on a loaded 2-core machine can take a while
GLOBAL_FILE = re.compile(r"node\.[\d_]+\.global_mgmt$")  # iceoryx2's one shared file per prefix, not a service's
_prefixes = itertools.count(1)


@pytest.fixture
def prefix() -> Iterator[str]:
    """A file-name prefix for this test's iceoryx2 files only; whatever remains of it is removed afterwards."""
    name = f"autotest{os.getpid()}x{next(_prefixes)}_"
    yield name
    for path in files_of(name, include_global=True):
        path.unlink(missing_ok=True)


def files_of(prefix: str, include_global: bool = False) -> set[Path]:
    """This prefix's files in /dev/shm and under iceoryx2's folder /tmp/iceoryx2."""
    found = set(Path("/dev/shm").glob(f"{prefix}*"))
    root = Path("/tmp/iceoryx2")
    if root.is_dir():
        found |= {path for path in root.rglob(f"{prefix}*") if not path.is_dir()}  # files and event sockets
    return found if include_global else {path for path in found if not GLOBAL_FILE.search(path.name)}


def shm_args(domain_id: int, prefix: str, *more: str) -> list[str]:
    return ["--domain", str(domain_id), "-D", "config.transport=shm", "-D", f"config.shmPrefix={prefix}", *more]


def test_camera_pair_over_shared_memory_verifies_every_frame_at_full_speed(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                                            prefix: str) -> None:
    """Full-size frames as fast as possible: the reliable Camera profile's flow control loses none."""
    frames = 60
    sub = apps.start("camera_sub", *shm_args(domain_id, prefix, "--count", str(frames)))
    sub.wait_for("viewing CameraImageData frames of 4196352 bytes through shared memory", timeout=TIMEOUT)
    pub = apps.start("camera_pub", *shm_args(domain_id, prefix, "--count", str(frames),
                                             "-D", "config.pubInterval=0"))
    assert pub.wait_exit(timeout=TIMEOUT) == 0, pub.output
    assert sub.wait_exit(timeout=TIMEOUT) == 0, sub.output
    assert f"shared memory: {frames} frames sent, 0 written on DDS" in pub.output  # no DDS reader: no DDS cost
    result = totals(sub.output)
    assert (result["samples"], result["size"], result["mismatches"], result["gaps"]) == (
        str(frames), "4196352", "0", "0"), sub.output


def test_gaps_are_counted_when_the_subscriber_falls_behind(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                          prefix: str) -> None:
    """Best effort, keep last 1: the viewer frozen (SIGSTOP) while frames go by finds only the last one."""
    qos = ["-D", f"qos.File={BEST_EFFORT_QOS}", "-D", "qos.Library=CameraTests",
           "-D", "qos.Camera.Profile=CameraBestEffort", "-D", "config.imageSize=64KiB"]
    sub = apps.start("camera_sub", *shm_args(domain_id, prefix, "--exit-with-publisher", *qos))
    sub.wait_for("through shared memory \\(keeping the last 1\\)", timeout=TIMEOUT)
    pub = apps.start("camera_pub", *shm_args(domain_id, prefix, "--count", "400", "-D", "config.pubInterval=5", *qos))
    sub.wait_for(r"samples=\d+ size=65536", timeout=TIMEOUT)  # frames are arriving
    with sub.frozen():
        pub.wait_for_more(r"published \d+ frames:", 1, timeout=TIMEOUT)  # a second or more goes by
    assert pub.wait_exit(timeout=TIMEOUT) == 0, pub.output
    assert sub.wait_exit(timeout=TIMEOUT) == 0, sub.output  # it noticed the publisher leave
    result = totals(sub.output)
    assert int(result["gaps"]) > 0, sub.output
    assert int(result["samples"]) + int(result["gaps"]) <= 400
    assert result["mismatches"] == "0", sub.output


def test_a_stalled_or_dead_subscriber_holds_a_reliable_publisher_back_at_most_max_blocking_time(  # type: ignore[no-untyped-def]
        apps, domain_id: int, prefix: str) -> None:
    """Reliable keep-all with max_blocking_time 0.5 s: a frozen viewer (SIGSTOP) stops the flow only that long and
    then loses what overflows its queue (gaps, never wrong bytes); a killed one (SIGKILL) does not stop it at all."""
    qos = ["-D", f"qos.File={SHORT_BLOCKING_QOS}", "-D", "qos.Library=CameraTests",
           "-D", "qos.Camera.Profile=CameraShortBlocking", "-D", "config.imageSize=64KiB"]
    args = shm_args(domain_id, prefix, *qos)
    stalled = apps.start("camera_sub", *args, "--exit-with-publisher")
    stalled.wait_for(r"through shared memory \(keeping the last 8\)", timeout=TIMEOUT)
    pub = apps.start("camera_pub", *args, "-D", "config.pubInterval=5")
    stalled.wait_for(r"samples=\d+ size=65536", timeout=TIMEOUT)
    with stalled.frozen():
        pub.wait_for(r"shared memory: no frame consumed for 0.5 s", timeout=TIMEOUT)
        pub.wait_for_more(r"published \d+ frames:", 2, timeout=TIMEOUT)  # the flow goes on
    stalled.wait_for_more(r"samples=\d+ size=65536", 1, timeout=TIMEOUT)  # it catches up
    dead = apps.start("camera_sub", *args)
    dead.wait_for(r"samples=\d+ size=65536", timeout=TIMEOUT)
    dead.stop(signal.SIGKILL)
    pub.wait_for_more(r"no frame consumed for 0.5 s", 1, timeout=TIMEOUT)  # the dead one's queue filled
    pub.wait_for_more(r"published \d+ frames:", 2, timeout=TIMEOUT)
    assert pub.stop(signal.SIGTERM) == 0, pub.output
    assert stalled.wait_exit(timeout=TIMEOUT) == 0, stalled.output
    result = totals(stalled.output)
    assert int(result["gaps"]) > 0 and result["mismatches"] == "0", stalled.output


def test_frames_are_read_only_views_of_shared_memory_that_end_with_their_block(domain_id: int, prefix: str) -> None:
    participant = DomainParticipant(domain_id)
    memory = SharedMemory("test", domain_id, "CameraFrames", prefix)
    qos = Qos(Policy.Reliability.Reliable(10**9), Policy.History.KeepLast(4))
    reader = SharedFrameReader(memory, CameraImageData_64KiB, qos)
    dds = DataWriter(participant, Topic(participant, "CameraFrames", CameraImageData_64KiB),
                     qos=Qos(WRITER_REPRESENTATION, base=qos))
    pattern = lfsr.FramePattern(65536)
    writer = SharedFrameWriter(memory, FrameWriter(dds, pattern), qos, lambda: 0, lambda: True)
    try:
        assert writer.count_subscribers() == 1
        for seqnum in (1, 2, 3):
            writer.write_pattern(5, seqnum)
        assert (writer.sent_shared, writer.sent_dds) == (3, 0)
        with reader.take(1) as frames:
            frame = frames[0]
            assert (frame.id, frame.seqnum) == (5, 1)
            assert frame.data.readonly and frame.data == pattern.frame(1)
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
            with reader.take(1) as frames:
                kept = np.frombuffer(frames[0].data, np.uint8)  # outlives the block: refused, not given back
        assert kept is not None and bytes(kept) == bytes(pattern.frame(2))
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


def flowing_pair(apps, args: list[str]) -> tuple[AppProcess, AppProcess]:  # type: ignore[no-untyped-def]
    """camera_sub, then camera_pub (64 KiB frames, 50 a second, until stopped), once frames arrive."""
    sub = apps.start("camera_sub", *args)
    sub.wait_for("through shared memory", timeout=TIMEOUT)
    pub = apps.start("camera_pub", *args, "-D", "config.pubInterval=20")
    sub.wait_for(r"samples=\d+ size=65536", timeout=TIMEOUT)
    return sub, pub


def test_a_sigkilled_publisher_restarted_is_picked_up(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                     prefix: str) -> None:
    args = shm_args(domain_id, prefix, "-D", "config.imageSize=64KiB")
    sub, first = flowing_pair(apps, args)
    first.stop(signal.SIGKILL)
    second = apps.start("camera_pub", *args, "-D", "config.pubInterval=20")
    sub.wait_for(r"seqnum went back from \d+ to 1 \(publisher restarted\?\)", timeout=TIMEOUT)
    sub.wait_for_more(r"samples=\d+ size=65536", 1, timeout=TIMEOUT)  # the new publisher's frames flow
    assert second.stop(signal.SIGTERM) == 0, second.output
    assert sub.stop(signal.SIGTERM) == 0, sub.output
    result = totals(sub.output)
    assert result["mismatches"] == "0" and int(result["samples"]) > 0, sub.output


def test_a_clean_stop_leaves_nothing_in_dev_shm(apps, domain_id: int, prefix: str) -> None:  # type: ignore[no-untyped-def]
    args = shm_args(domain_id, prefix, "-D", "config.imageSize=64KiB")
    sub = apps.start("camera_sub", *args, "--exit-with-publisher")
    sub.wait_for("through shared memory", timeout=TIMEOUT)
    pub = apps.start("camera_pub", *args, "--count", "20", "-D", "config.pubInterval=10")
    pub.wait_for(r"published \d+ frames in total", timeout=TIMEOUT)
    assert pub.wait_exit(timeout=TIMEOUT) == 0, pub.output
    assert sub.wait_exit(timeout=TIMEOUT) == 0, sub.output
    assert totals(sub.output)["samples"] == "20", sub.output
    assert files_of(prefix) == set()


def test_stale_files_of_dead_processes_are_removed_on_start(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                           prefix: str) -> None:
    args = shm_args(domain_id, prefix, "-D", "config.imageSize=64KiB")
    sub, pub = flowing_pair(apps, args)
    pub.stop(signal.SIGKILL)
    sub.stop(signal.SIGKILL)
    stale = files_of(prefix)
    assert any(path.name.endswith(".data") for path in stale), stale  # the publisher's frames, left behind
    fresh = apps.start("camera_sub", *args)
    fresh.wait_for("shared memory: removed the files of 2 dead process", timeout=TIMEOUT)
    fresh.wait_for("through shared memory", timeout=TIMEOUT)
    # Gone: the dead processes' frames, connections and node records; the services' descriptions (*.service) are
    # the same files again, reopened by the new subscriber.
    assert {path for path in stale & files_of(prefix) if not path.name.endswith(".service")} == set()
    assert fresh.stop(signal.SIGTERM) == 0, fresh.output
    assert files_of(prefix) == set()


def test_shared_memory_subscriber_and_rti_reader_at_once(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                        prefix: str) -> None:
    """The hybrid, with the shipped QoS: frames through shared memory to our viewer and, because a DDS reader is
    matched, on DDS to an RTI reader."""
    frames = 20
    args = shm_args(domain_id, prefix, "-D", "config.imageSize=64KiB", "-D", "topic.Camera=CameraImageData_64KiB")
    with RtiPeer(domain_id, readers=["Camera64KiB"]) as rti:
        sub = apps.start("camera_sub", *args, "--count", str(frames))
        sub.wait_for("through shared memory", timeout=TIMEOUT)
        pub = apps.start("camera_pub", *args, "--count", str(frames), "-D", "config.pubInterval=50",
                         "-D", "config.waitSubscribers=2")  # the RTI reader and our viewer
        received = rti.take_until("Camera64KiB", frames, timeout=TIMEOUT)
        assert pub.wait_exit(timeout=TIMEOUT) == 0, pub.output
        assert sub.wait_exit(timeout=TIMEOUT) == 0, sub.output
    assert f"shared memory: {frames} frames sent, {frames} written on DDS" in pub.output
    result = totals(sub.output)
    assert (result["samples"], result["mismatches"], result["gaps"]) == (str(frames), "0", "0"), sub.output
    pattern = lfsr.FramePattern(65536)
    assert [sample["seqnum"] for sample in received] == list(range(1, frames + 1))
    assert all(bytes(sample["data"]) == bytes(pattern.frame(sample["seqnum"])) for sample in received)


@pytest.mark.parametrize("setting", ["config.transport=tcp", "config.transport=SHM", "config.shmPrefix=a/b"])
def test_bad_transport_settings_are_one_line_on_stderr(apps, setting: str) -> None:  # type: ignore[no-untyped-def]
    key, value = setting.split("=")
    extra = ["-D", "config.transport=shm"] if key == "config.shmPrefix" else []
    for app in ("camera_pub", "camera_sub"):
        result = apps.run(app, "--domain", "81", *extra, "-D", setting, timeout=TIMEOUT)
        assert result.returncode == 2, result.stdout + result.stderr
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and f"{key} = '{value}'" in lines[0], result.stderr
        assert "Traceback" not in result.stdout + result.stderr
