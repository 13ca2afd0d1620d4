"""The rear-view camera pair: the LFSR pattern, the frame codec, and camera_pub + camera_sub as two processes.

DDS domains 70..79 (fixed, one per test that talks DDS).
"""

from __future__ import annotations

import re
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl._support import Endianness
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from automotive.bus.errors import ConfigError
from automotive.sim import lfsr
from automotive.types.CameraImage import CameraImageData, CameraImageData_64KiB
from automotive.wire.camera import FRAME_TYPES, FrameCodec, FrameReader, FrameWriter, frame_size, frame_type

ROOT = Path(__file__).resolve().parent.parent
BEST_EFFORT_QOS = ROOT / "tests" / "data" / "camera_best_effort_qos.xml"
TIMEOUT = 120.0  # starting Python + Cyclone twice on a loaded 2-core machine can take a while


# -- the LFSR pattern ---------------------------------------------------------------------------------------------

def reference_bytes(count: int, seed: int) -> bytes:
    """The stream as the module defines it, one register step per bit: slow, obviously right."""
    state, out = seed, bytearray()
    for _ in range(count):
        byte = 0
        for bit in range(8):
            output = state & 1
            feedback = bin(state & lfsr.TAPS).count("1") & 1
            state = (state >> 1) | (feedback << 31)
            byte |= output << bit
        out.append(byte)
    return bytes(out)


def reference_state_after(steps: int, seed: int) -> int:
    state = seed
    for _ in range(steps):
        feedback = bin(state & lfsr.TAPS).count("1") & 1
        state = (state >> 1) | (feedback << 31)
    return state


@pytest.mark.parametrize("seed", [lfsr.SEED, 1, 0xFFFF_FFFF, 0x8000_0000])
@pytest.mark.parametrize("count", [1, 3, 127, 128, 129, 640])
def test_vectorised_stream_equals_the_bit_by_bit_register(seed: int, count: int) -> None:
    assert lfsr.stream_bytes(count, seed) == reference_bytes(count, seed)


def test_stream_words_are_register_states_every_32_steps() -> None:
    words = lfsr.stream_words(70, lfsr.SEED)
    for index in (0, 1, 33, 69):
        assert int(words[index]) == reference_state_after(32 * index, lfsr.SEED)


def test_frames_are_windows_of_the_stream_seeded_by_the_register_state() -> None:
    pattern = lfsr.FramePattern(300)
    for seqnum in (0, 1, 2, 17, lfsr.OFFSET_PERIOD + 5):
        offset = lfsr.frame_offset(seqnum)
        seed = reference_state_after(8 * offset, lfsr.SEED)
        assert bytes(pattern.frame(seqnum)) == reference_bytes(300, seed)


def test_polynomial_is_primitive() -> None:
    """x^32 + x^22 + x^2 + x + 1 has order 2^32 - 1: the register visits every non-zero state."""
    poly = (1 << 32) | lfsr.TAPS

    def multiply(a: int, b: int) -> int:
        result = 0
        while b:
            if b & 1:
                result ^= a
            b >>= 1
            a <<= 1
            if a >> 32:
                a ^= poly
        return result

    def power(exponent: int) -> int:
        result, base = 1, 2
        while exponent:
            if exponent & 1:
                result = multiply(result, base)
            base = multiply(base, base)
            exponent >>= 1
        return result

    order = (1 << 32) - 1
    assert power(order) == 1
    for prime in (3, 5, 17, 257, 65537):  # the prime factors of 2^32 - 1
        assert power(order // prime) != 1


def test_pattern_matches_its_own_frames_and_counts_wrong_bytes() -> None:
    pattern = lfsr.FramePattern(4096)
    frame = bytearray(pattern.frame(9))
    assert pattern.matches(9, frame)
    assert not pattern.matches(10, frame)  # another seqnum's frame is another window
    assert pattern.mismatched_bytes(9, frame) == 0
    frame[0] ^= 0xFF
    frame[4095] ^= 0x01
    assert not pattern.matches(9, frame)
    assert pattern.mismatched_bytes(9, frame) == 2
    assert not pattern.matches(9, frame[:-1])
    assert pattern.mismatched_bytes(9, frame[:-1]) == 4096


def test_consecutive_frames_differ_almost_everywhere() -> None:
    pattern = lfsr.FramePattern(65536)
    first = np.frombuffer(pattern.frame(1), np.uint8)
    second = np.frombuffer(pattern.frame(2), np.uint8)
    assert np.count_nonzero(first != second) > 0.99 * 65536 * 255 / 256 - 1000


def test_a_full_size_stream_continues_the_register_to_its_end() -> None:
    """Word m of the stream is the register's state after 32*m steps: restarting the (reference-checked) short
    generator from that state must reproduce the long stream there, far beyond the bootstrap."""
    pattern = lfsr.FramePattern(frame_size(CameraImageData))
    words = np.frombuffer(pattern.stream[: len(pattern.stream) // 4 * 4], dtype="<u4")
    for m in (1000, 123_457, len(words) - 50):
        assert lfsr.stream_bytes(160, int(words[m])) == pattern.stream[4 * m:4 * m + 160]


# -- frame types and the codec -------------------------------------------------------------------------------------

def test_frame_types_by_name_and_size() -> None:
    assert frame_type("full") is CameraImageData
    assert frame_type("4196352") is CameraImageData
    assert frame_type("64kib") is CameraImageData_64KiB
    assert {name: frame_size(t) for name, t in FRAME_TYPES.items()} == {
        "full": 1366 * 768 * 4, "64KiB": 65536, "1MiB": 1 << 20, "4MiB": 4 << 20}


@pytest.mark.parametrize("value", ["2MiB", "65535", "", "big"])
def test_unknown_frame_size_is_one_clear_error(value: str) -> None:
    with pytest.raises(ConfigError, match=r"config.imageSize = '.*' is not a known frame size \(expected one of: "
                                          r"full \(4196352 bytes\), 64KiB"):
        frame_type(value)


@pytest.mark.parametrize("xcdr2", [False, True])
@pytest.mark.parametrize("little_endian", [True, False])
def test_codec_writes_and_reads_what_cyclones_serializer_does(xcdr2: bool, little_endian: bool) -> None:
    image = lfsr.FramePattern(65536).frame(3)
    sample = CameraImageData_64KiB(id=0xCAFE, sec_=-2, nanosec_=999_999_999, seqnum=3, data=bytes(image))
    reference = sample.serialize(use_version_2=xcdr2,
                                 endianness=Endianness.Little if little_endian else Endianness.Big)
    codec = FrameCodec(CameraImageData_64KiB, xcdr2, little_endian)
    assert codec.encode(0xCAFE, -2, 999_999_999, 3, image) == reference
    frame = FrameCodec(CameraImageData_64KiB).decode(reference)  # a reader decodes any representation
    assert (frame.id, frame.sec_, frame.nanosec_, frame.seqnum) == (0xCAFE, -2, 999_999_999, 3)
    assert frame.data == image
    assert frame.data.obj is reference  # a view of the received buffer, not a copy
    assert CameraImageData_64KiB.deserialize(codec.encode(0xCAFE, -2, 999_999_999, 3, image)) == sample


def test_codec_refuses_wrong_sizes_and_encodings() -> None:
    codec = FrameCodec(CameraImageData_64KiB)
    with pytest.raises(ValueError, match="65535 bytes for a 65536-byte frame"):
        codec.encode(1, 0, 0, 1, bytes(65535))
    good = codec.encode(1, 0, 0, 1, bytes(65536))
    with pytest.raises(ValueError, match="too short"):
        codec.decode(good[:-1])
    with pytest.raises(ValueError, match="encapsulation 0x0003"):
        codec.decode(b"\x00\x03" + good[2:])


# -- writing and taking frames through Cyclone, in process ---------------------------------------------------------

def take_all(reader: FrameReader, expected: int) -> list[tuple[int, int, bytes, bool]]:
    """(id, seqnum, data copy, data was a view) of ``expected`` frames, waiting for them with a bounded wait."""
    waitset = WaitSet(reader.reader.participant)
    waitset.attach(ReadCondition(reader.reader, SampleState.Any | ViewState.Any | InstanceState.Any))
    got: list[tuple[int, int, bytes, bool]] = []
    deadline = time.monotonic() + 30
    while len(got) < expected and time.monotonic() < deadline:
        waitset.wait(int(0.5e9))
        with reader.take() as frames:
            got += [(f.id, f.seqnum, bytes(f.data), isinstance(f.data, memoryview)) for f in frames]
    return got


@pytest.mark.parametrize("zero_copy", [True, False])
def test_frames_written_either_way_are_taken_intact(zero_copy: bool, domain_id: int) -> None:
    participant = DomainParticipant(domain_id)
    topic = Topic(participant, f"CameraFrames{zero_copy}", CameraImageData_64KiB)
    qos = Qos(Policy.Reliability.Reliable(10**9), Policy.History.KeepAll)
    reader = FrameReader(DataReader(participant, topic, qos=qos), zero_copy=zero_copy)
    assert reader.zero_copy is zero_copy
    plain = DataWriter(participant, topic, qos=qos)  # Cyclone's own serializer (XCDR2: the type's default)
    xcdr1 = DataWriter(participant, topic, qos=Qos(Policy.DataRepresentation(use_cdrv0_representation=True),
                                                   base=qos))
    pattern = lfsr.FramePattern(65536)
    original_stream = bytes(pattern.stream)
    plain.write(CameraImageData_64KiB(id=1, sec_=0, nanosec_=0, seqnum=1, data=bytes(pattern.frame(1))))
    frames = FrameWriter(xcdr1, pattern)
    assert not frames.codec.xcdr2
    frames.write(2, 2, pattern.frame(2))
    frames.write_pattern(2, 3)
    frames.write_pattern(2, 65_521 * 2)  # offset 0: the header borrows only the writer's headroom
    got = sorted(take_all(reader, 4))
    assert [(id_, seqnum) for id_, seqnum, _, _ in got] == [(1, 1), (2, 2), (2, 3), (2, 65_521 * 2)]
    assert all(data == bytes(pattern.frame(seqnum)) for _, seqnum, data, _ in got)
    assert pattern.stream == original_stream  # the borrowed bytes went back
    participant.__del__()


def test_a_zero_copy_frame_cannot_be_used_after_its_block(domain_id: int) -> None:
    participant = DomainParticipant(domain_id)
    topic = Topic(participant, "CameraFrames", CameraImageData_64KiB)
    qos = Qos(Policy.Reliability.Reliable(10**9), Policy.History.KeepAll)
    reader = FrameReader(DataReader(participant, topic, qos=qos))
    writer = FrameWriter(DataWriter(participant, topic, qos=qos), lfsr.FramePattern(65536))
    waitset = WaitSet(participant)
    waitset.attach(ReadCondition(reader.reader, SampleState.Any | ViewState.Any | InstanceState.Any))
    for seqnum in (1, 2):
        writer.write_pattern(7, seqnum)
    kept = []
    deadline = time.monotonic() + 30
    while not kept and time.monotonic() < deadline:
        waitset.wait(int(0.5e9))
        with reader.take(1) as frames:
            kept = list(frames)
    assert kept and kept[0].seqnum == 1
    with pytest.raises(ValueError, match="released"):
        bytes(kept[0].data)
    array = None
    with pytest.raises(RuntimeError, match="still in use"):
        while array is None and time.monotonic() < deadline:
            waitset.wait(int(0.5e9))
            with reader.take(1) as frames:
                if frames:
                    array = np.frombuffer(frames[0].data, np.uint8)  # outlives the block: refused, not freed
    assert array is not None and bytes(array) == bytes(writer.pattern.frame(2))
    participant.__del__()


# -- the two applications ------------------------------------------------------------------------------------------

def totals(output: str) -> dict[str, str]:
    line = next(line for line in output.splitlines() if "totals:" in line)
    return dict(re.findall(r"([\w/]+)=(\S+)", line))


def published_total(output: str) -> int:
    """The publisher's own count of the frames it wrote, from its last line about them."""
    counts = re.findall(r"published (\d+) frames in total", output)
    assert counts, output
    return int(counts[-1])


def test_camera_pair_verifies_every_frame(apps, tmp_path: Path, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    plot = tmp_path / "latency.png"
    frames = 40
    sub = apps.start("camera_sub", "--domain", str(domain_id), "--count", str(frames), "--plot", str(plot),
                     "-D", "config.imageSize=64KiB")
    sub.wait_for("viewing CameraImageData_64KiB frames of 65536 bytes", timeout=TIMEOUT)
    pub = apps.start("camera_pub", "--domain", str(domain_id), "--count", str(frames), "-D", "config.imageSize=64KiB",
                     "-D", "config.pubInterval=40")  # 1.6 s: at least one once-a-second statistics line
    assert pub.wait_exit(timeout=TIMEOUT) == 0, pub.output
    assert sub.wait_exit(timeout=TIMEOUT) == 0, sub.output
    assert f"published {frames} frames in total" in pub.output
    result = totals(sub.output)
    assert result["samples"] == str(frames), sub.output
    assert (result["mismatches"], result["mismatched_bytes"], result["gaps"]) == ("0", "0", "0"), sub.output
    assert float(result["MB/s"]) > 0
    assert float(result["min"]) <= float(result["p50"]) <= float(result["max"])
    stats_lines = [line for line in sub.lines if re.search(r"samples=\d+ size=65536 latency_ms\(min/avg/max\)="
                                                           r"[\d.]+/[\d.]+/[\d.]+ MB/s=[\d.]+ mismatches=0 gaps=0",
                                                           line)]
    assert stats_lines, sub.output
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_full_size_frames_as_fast_as_flow_control_allows(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    frames = 8
    sub = apps.start("camera_sub", "--domain", str(domain_id), "--count", str(frames))
    sub.wait_for("viewing CameraImageData frames of 4196352 bytes", timeout=TIMEOUT)
    pub = apps.start("camera_pub", "--domain", str(domain_id), "--count", str(frames), "-D", "config.pubInterval=0")
    assert pub.wait_exit(timeout=TIMEOUT) == 0, pub.output
    assert sub.wait_exit(timeout=TIMEOUT) == 0, sub.output
    result = totals(sub.output)
    assert (result["samples"], result["size"], result["mismatches"], result["gaps"]) == (
        str(frames), "4196352", "0", "0"), sub.output


def test_lost_frames_are_counted_as_gaps(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    """Best effort, and the viewer frozen (SIGSTOP) while about 100 MiB go by: its socket buffer must overflow."""
    qos = ["-D", f"qos.File={BEST_EFFORT_QOS}", "-D", "qos.Library=CameraTests",
           "-D", "qos.Camera.Profile=CameraBestEffort", "-D", "config.imageSize=1MiB"]
    sub = apps.start("camera_sub", "--domain", str(domain_id), "--exit-with-publisher", *qos)
    sub.wait_for("viewing CameraImageData_1MiB", timeout=TIMEOUT)
    # No --count: a count could run out before the frozen second is over on a loaded machine.
    pub = apps.start("camera_pub", "--domain", str(domain_id), "-D", "config.pubInterval=5", *qos)
    sub.wait_for(r"samples=\d+ size=1048576", timeout=TIMEOUT)  # frames are arriving
    with sub.frozen():
        pub.wait_for_more(r"published \d+ frames:", 2, timeout=TIMEOUT)  # a second or more goes by
    assert pub.stop(signal.SIGTERM) == 0, pub.output
    assert sub.wait_exit(timeout=TIMEOUT) == 0, sub.output
    result = totals(sub.output)
    assert int(result["gaps"]) > 0, sub.output
    assert int(result["samples"]) + int(result["gaps"]) <= published_total(pub.output), sub.output
    assert result["mismatches"] == "0", sub.output


def test_bad_frame_size_is_one_line_on_stderr(apps) -> None:  # type: ignore[no-untyped-def]
    for app in ("camera_pub", "camera_sub"):
        result = apps.run(app, "--domain", "73", "-D", "config.imageSize=2MiB", timeout=TIMEOUT)
        assert result.returncode == 2, result.stdout + result.stderr
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and "config.imageSize = '2MiB' is not a known frame size" in lines[0], result.stderr
        assert "Traceback" not in result.stdout + result.stderr
