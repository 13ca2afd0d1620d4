"""Memory does not grow with the events a running application handles: a guard without timing.

Each test drives a piece of the runtime through thousands of events in-process (camera frames taken, verified and
counted; vision samples written and taken; status events: matches, unmatches, liveliness), after a warm-up that
fills every cache, and then checks that the live objects of the project's own types are the same in number, and
that the Python heap (tracemalloc) and glibc's blocks in use (Cyclone's allocations) grew by less than a small
bound that a per-event leak of a few bytes would exceed. automotive bench soak measures the same over time on the
whole system (automotive bench soak).
"""

from __future__ import annotations

import collections
import gc
import itertools
import json
import logging
import random
import subprocess
import sys
import threading
import time
import tracemalloc
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

from automotive import config
from automotive.apps.camera_sub import CameraStats
from automotive.bus import memtrace, memtune
from automotive.bus.clock import now_timestamp
from automotive.bus.endpoints import Databus
from automotive.bus.latency import KEPT_PER_SECOND, MAX_SOURCES, WINDOW_S, LatencyHistogram, RecentLatencies, percentile
from automotive.bus.network import RECEIVE_BUFFER_SIZE, NetworkConfig, PeerPlan
from automotive.bus.qos import QosProfiles
from automotive.sim.csvdata import cycle_rows, load_vision_rows
from automotive.sim.lfsr import FramePattern
from automotive.types.CameraImage import CameraImageData_64KiB
from automotive.types.Vision import VisionSensor
from automotive.wire.camera import FrameReader, FrameWriter

PROJECT_MODULES = ("automotive",)
BATCH = 4  # frames written before they are taken: within the Camera profile's window of 8


def silent_log() -> logging.Logger:
    """A logger that keeps nothing: pytest's log capture would hold every record (memory that is not ours)."""
    log = logging.getLogger("test_memory.silent")
    log.handlers[:] = [logging.NullHandler()]
    log.propagate = False
    return log


def project_objects() -> collections.Counter[str]:
    """Live objects of the project's own types (automotive.*, the generated types included), by type."""
    gc.collect()
    counts: collections.Counter[str] = collections.Counter()
    for obj in gc.get_objects():
        kind = type(obj)
        module = getattr(kind, "__module__", None)  # a descriptor, not a name, on some types of other libraries
        if isinstance(module, str) and module.split(".", 1)[0] in PROJECT_MODULES:
            counts[f"{module}.{kind.__qualname__}"] += 1
    return counts


class HeapWatch:
    """The project's live objects, the Python heap and malloc's blocks in use, now and after the events."""

    def __init__(self) -> None:
        self.objects = project_objects()
        self.python_bytes = tracemalloc.get_traced_memory()[0]
        malloc = memtrace.malloc_figures()
        self.malloc_kB = malloc["in_use_kB"] if malloc else 0

    def growth(self) -> tuple[dict[str, int], int, int]:
        """(object count growth by type, Python heap growth in bytes, malloc in-use growth in kB). Only growth: an
        object an earlier test of the worker left, freed meanwhile (a bad-sample log window that expired), is no
        object kept by the events watched."""
        objects = project_objects()
        changes = {name: objects[name] - self.objects[name] for name in objects if objects[name] > self.objects[name]}
        malloc = memtrace.malloc_figures()
        return (changes, tracemalloc.get_traced_memory()[0] - self.python_bytes,
                (malloc["in_use_kB"] if malloc else 0) - self.malloc_kB)


@pytest.fixture
def traced() -> Iterator[None]:
    started = not tracemalloc.is_tracing()
    if started:
        tracemalloc.start()
    try:
        yield
    finally:
        if started:
            tracemalloc.stop()


@pytest.fixture
def quiet_bus(domain_id: int) -> Iterator[Databus]:
    bus = Databus(domain_id, QosProfiles(config.qos_file()), "AutomotiveLibrary", silent_log(), NetworkConfig())
    try:
        yield bus
    finally:
        bus.close()


def test_the_camera_receive_path_keeps_nothing_per_frame(quiet_bus: Databus, traced: None) -> None:
    """Frames written, taken without a copy, verified and counted as camera_sub does, with its statistics."""
    log = silent_log()
    pattern = FramePattern(65536)
    writer = FrameWriter(quiet_bus.writer("CameraFrames", CameraImageData_64KiB, "Camera"), pattern)
    reader = FrameReader(quiet_bus.reader("CameraFrames", CameraImageData_64KiB, "Camera"))
    waitset = WaitSet(quiet_bus.participant)
    waitset.attach(ReadCondition(reader.reader, SampleState.Any | ViewState.Any | InstanceState.Any))
    stats = CameraStats(pattern.size)
    seqnum = 0

    def frames(count: int) -> None:
        nonlocal seqnum
        for _ in range(count // BATCH):
            for _ in range(BATCH):
                seqnum += 1
                writer.write_pattern(1, seqnum)
            deadline = time.monotonic() + 30
            while stats.total.samples < seqnum:
                assert time.monotonic() < deadline, f"frame {stats.total.samples + 1} did not arrive"
                waitset.wait(int(0.5e9))
                with reader.take(16) as batch:
                    receive_ns = time.time_ns()
                    for frame in batch:
                        stats.received(frame, receive_ns, log, pattern)
            stats.report_window(log, force=True)

    frames(500)
    watch = HeapWatch()
    frames(5000)
    changes, python_bytes, malloc_kB = watch.growth()
    assert stats.total.samples == seqnum and stats.total.gaps == 0 and stats.total.mismatches == 0
    assert changes == {}, f"live objects of the project's types grew over 5,000 frames: {changes}"
    # Keeping every frame's latency and receive time (as camera_sub did) is about 400 kB over 5,000 frames.
    assert python_bytes < 64 * 1024, f"the Python heap grew by {python_bytes:,} bytes over 5,000 frames"
    assert malloc_kB < 1024, f"malloc's blocks in use grew by {malloc_kB:,} kB over 5,000 frames (327 MB moved)"


def test_the_take_loop_keeps_nothing_per_sample(quiet_bus: Databus, traced: None) -> None:
    """Vision samples of the shipped data (up to 10 objects each) written through the checked writer and taken as
    the applications take them: nothing of them stays once a take's samples are dropped."""
    rows = load_vision_rows(config.properties_dir() / "data" / "vision.csv")
    writer = quiet_bus.writer("VisionTopic", VisionSensor, "Vision")
    reader = quiet_bus.reader("VisionTopic", VisionSensor, "Vision")
    waitset = WaitSet(quiet_bus.participant)
    waitset.attach(ReadCondition(reader, SampleState.NotRead | ViewState.Any | InstanceState.Any))
    written = taken = 0

    def samples(count: int) -> None:
        nonlocal written, taken
        for objects in itertools.islice(cycle_rows(rows), count):
            written += 1
            writer.write(VisionSensor(id=written % 3, timestamp=now_timestamp(), objects=objects))
            if written % 50 == 0:  # within the Vision profile's history of 100
                deadline = time.monotonic() + 30
                while taken < written:
                    assert time.monotonic() < deadline, f"sample {taken + 1} did not arrive"
                    waitset.wait(int(0.5e9))
                    taken += sum(isinstance(sample, VisionSensor) for sample in reader.take(N=100))

    samples(500)
    watch = HeapWatch()
    samples(5000)
    changes, python_bytes, malloc_kB = watch.growth()
    assert taken == written
    assert changes == {}, f"live objects of the project's types grew over 5,000 samples: {changes}"
    assert python_bytes < 64 * 1024, f"the Python heap grew by {python_bytes:,} bytes over 5,000 samples"
    assert malloc_kB < 1024, f"malloc's blocks in use grew by {malloc_kB:,} kB over 5,000 samples"


def test_status_events_keep_nothing_per_event(quiet_bus: Databus, domain_id: int, traced: None) -> None:
    """Writers of another participant come and go: matched, unmatched and liveliness events, each logged and
    passed to the application's hook, as every application's status listener does."""
    events: collections.Counter[str] = collections.Counter()
    current = [0]

    def hook(event: str, topic: str, status: Any) -> None:
        events[event] += 1
        if event == "subscription_matched":
            current[0] = status.current_count

    quiet_bus.reader("VisionTopic", VisionSensor, "Vision", hook=hook)
    other = DomainParticipant(domain_id)
    topic = Topic(other, "VisionTopic", VisionSensor)
    writer_qos = quiet_bus.profiles.writer_qos(quiet_bus.library, "Vision")

    def come_and_go(times: int) -> None:
        for _ in range(times):
            writer = DataWriter(other, topic, qos=writer_qos)
            deadline = time.monotonic() + 15
            while current[0] != 1:
                assert time.monotonic() < deadline, "the writer did not match"
                time.sleep(0.001)
            writer.__del__()
            while current[0] != 0:
                assert time.monotonic() < deadline, "the writer did not unmatch"
                time.sleep(0.001)

    try:
        come_and_go(50)
        watch = HeapWatch()
        before = sum(events.values())
        come_and_go(1000)
        changes, python_bytes, malloc_kB = watch.growth()
    finally:
        other.__del__()
    handled = sum(events.values()) - before
    assert handled >= 2000, f"only {handled} status events: {dict(events)}"
    assert changes == {}, f"live objects of the project's types grew over {handled} status events: {changes}"
    assert python_bytes < 64 * 1024, f"the Python heap grew by {python_bytes:,} bytes over {handled} events"
    assert malloc_kB < 1024, f"malloc's blocks in use grew by {malloc_kB:,} kB over {handled} events"


def test_the_memory_probe_writes_what_tells_the_layers_apart(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    probe = memtrace.MemoryProbe(tmp_path / "probe.jsonl", 3600, frames=0)
    figures = probe.record()
    assert figures["rss_kB"] > 0 and figures["python_blocks"] > 0
    assert figures["malloc"]["in_use_kB"] > 0 and figures["malloc_arenas"] >= 1
    assert figures["smaps_kB"]["heap"] > 0 and any(region[0] == "heap" for region in figures["anon_regions"])
    json.dumps(figures)
    # A record leaves nothing for the cyclic collector: in an application that makes few cycles such garbage would
    # stay for hours and be the probe's own climb in RSS.
    gc.collect()
    gc.set_debug(gc.DEBUG_SAVEALL)
    try:
        for _ in range(5):
            probe.record()
        gc.collect()
        garbage = collections.Counter(type(obj).__name__ for obj in gc.garbage)
    finally:
        gc.set_debug(0)
        gc.garbage.clear()
    assert not garbage, f"the probe's records left reference cycles: {garbage}"
    monkeypatch.delenv(memtrace.ENV_DIR, raising=False)
    assert memtrace.start_from_environment("test") is None


def test_receive_buffers_are_small_and_malloc_settles() -> None:
    """The two settings that stop the saw-tooth (docs/measurements/memory.md): in every network mode Cyclone's receive
    buffers are 256 KiB instead of 1 MiB, and glibc's thresholds are fixed before the first buffer is allocated."""
    for network in (NetworkConfig(), NetworkConfig.from_settings(interface="eth1"),
                   NetworkConfig.from_settings(peers=["10.0.0.2"], large_data=True)):
        xml = network.cyclone_xml(PeerPlan(remote=("10.0.0.2",), route_source="10.0.0.1"))
        assert f"<Sizing><ReceiveBufferSize>{RECEIVE_BUFFER_SIZE}</ReceiveBufferSize></Sizing>" in xml
    assert RECEIVE_BUFFER_SIZE == "256KiB"
    assert memtune.settle_malloc()


def test_latency_percentiles_in_fixed_memory() -> None:
    """camera_sub's percentiles: within 0.1 % of the exact ones, from 1 µs to 100 s, in the same memory for any
    number of samples."""
    generator = random.Random(20)
    latencies = [int(generator.lognormvariate(15, 1.5)) for _ in range(20_000)] + [5, 10**12]
    histogram = LatencyHistogram()
    size = memoryview(histogram.counts).nbytes
    for latency in latencies:
        histogram.record(latency)
    clamped = [min(10**11, max(1000, latency)) for latency in latencies]
    for fraction in (0.0, 0.5, 0.9, 0.99, 0.999, 1.0):
        exact = percentile(clamped, fraction)  # the benchmarks' exact percentile: the same rank
        value = histogram.percentile_ns(fraction)
        assert exact is not None and value is not None and abs(value - exact) <= 0.001 * exact, (fraction, value, exact)
    assert memoryview(histogram.counts).nbytes == size and histogram.total == len(latencies)
    assert LatencyHistogram().percentile_ns(0.5) is None and percentile([], 0.5) is None
    assert percentile([3.0, 1.0, 2.0], 0.5) == 2.0 and percentile([3.0, 1.0, 2.0], 1.0) == 3.0


def test_recent_latencies_are_of_the_last_10_s_per_topic_and_writer_in_bounded_memory() -> None:
    """What /diagnostics reports: each topic's and each writer's percentiles over the last WINDOW_S seconds (the
    benchmarks' rank), counted in full however fast a flow is, with a bounded number of values and sources kept."""
    second = 1_000_000_000
    start = 1_700_000_000 * second
    recent = RecentLatencies()
    # vision: 1..10 ms, one a second for 20 s; only the last 10 s count
    for index in range(20):
        now = start + index * second
        recent.record("VisionTopic", "vision", [now - (index % 10 + 1) * 1_000_000], now)
    recent.record("VisionTopic", "vision_b", [start + 19 * second - 50_000_000], start + 19 * second)
    recent.record("VisionTopic", "vision", [0, -5], start + 19 * second)  # no source timestamp: not counted
    summaries = {(s.topic, s.writer): s for s in recent.summaries(start + 19 * second)}
    one = summaries[("VisionTopic", "vision")]
    assert one.count == WINDOW_S and one.p50_ms == percentile([float(i) for i in range(1, 11)], 0.5) == 6.0
    assert one.p99_ms == 10.0
    both = summaries[("VisionTopic", None)]
    assert both.count == WINDOW_S + 1 and both.p99_ms == 50.0 and both.p50_ms == 6.0
    assert [(s.topic, s.writer) for s in recent.summaries(start + 19 * second)] == [
        ("VisionTopic", None), ("VisionTopic", "vision"), ("VisionTopic", "vision_b")]
    assert recent.summaries(start + 40 * second) == []  # 10 s without a sample: nothing to report

    # A fast flow: every sample counted, at most KEPT_PER_SECOND a second kept; sources bounded.
    now = start + 100 * second
    recent.record("CameraImageData", "camera_pub", [now - 1_000_000] * 10_000, now)
    camera = next(s for s in recent.summaries(now) if s.writer == "camera_pub")
    assert camera.count == 10_000 and camera.p50_ms == camera.p99_ms == 1.0
    window = recent._windows[("CameraImageData", "camera_pub")]
    assert sum(len(values) for values in window.values) == KEPT_PER_SECOND
    for index in range(MAX_SOURCES * 3):
        recent.record(f"Topic{index}", "writer", [now - 1], now + index)
    assert len(recent._windows) == MAX_SOURCES


# A process of its own, so that no other thread allocates meanwhile: 8 MiB in 128 KiB blocks from malloc, touched,
# all freed but the block highest in memory, which keeps them below a live block where no trim threshold reaches.
_BURST_BELOW_A_LIVE_BLOCK = """
import ctypes, json
from automotive.bus import memtune
from automotive.bus.memtrace import rss_kB

libc = ctypes.CDLL(None)
libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]

assert memtune.settle_malloc()
size = 128 * 1024
blocks = [libc.malloc(size) for _ in range(65)]
for block in blocks:
    ctypes.memset(block, 1, size)
pinned = max(blocks)
touched = rss_kB()
for block in blocks:
    if block != pinned:
        libc.free(block)
freed = rss_kB()
released = memtune.give_back_free_memory()
print(json.dumps({"touched": touched, "freed": freed, "trimmed": rss_kB(), "released": released}))
"""


def test_a_burst_freed_below_a_live_block_is_given_back_by_a_trim() -> None:
    """Cause 5 of docs/measurements/memory.md: 8 MiB freed under a live block stays resident with the applications'
    thresholds (glibc trims only the top of a heap), and malloc_trim(0), which every application calls once a minute,
    returns it."""
    result = subprocess.run([sys.executable, "-c", _BURST_BELOW_A_LIVE_BLOCK], capture_output=True, text=True,
                            timeout=60, check=True)
    figures = json.loads(result.stdout)
    assert figures["freed"] > figures["touched"] - 1024, figures  # free, but still resident
    assert figures["released"] is True, figures
    assert figures["trimmed"] < figures["freed"] - 6 * 1024, figures  # most of the 8 MiB given back


# The trim's looks in a process of its own, each made by the test (not the thread's clock, so that no look falls
# between the burst's allocation and its free): the first look trims, looks without growth do not, a burst freed
# below a live block makes the next look trim it. Then the thread itself, looking every 20 ms, ends with its stop event.
_PERIODIC_TRIM = """
import ctypes, json, threading, time
from automotive.bus import memtune
from automotive.bus.memtrace import rss_kB

libc = ctypes.CDLL(None)
libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]

assert memtune.settle_malloc()
trimmer = memtune.PeriodicTrim(threading.Event(), 0.02)
first = trimmer.look()
quiet = [trimmer.look() for _ in range(5)]
size = 128 * 1024
blocks = [libc.malloc(size) for _ in range(65)]
for block in blocks:
    ctypes.memset(block, 1, size)
pinned = max(blocks)
for block in blocks:
    if block != pinned:
        libc.free(block)
freed = rss_kB()
after_burst = trimmer.look()
trimmed = rss_kB()

stop = threading.Event()
running = memtune.PeriodicTrim(stop, 0.02).start()
deadline = time.monotonic() + 60
while running.checks < 2 and time.monotonic() < deadline:
    time.sleep(0.005)
stop.set()
running.thread.join(timeout=60)
print(json.dumps({"first": first, "quiet": quiet, "after_burst": after_burst, "freed": freed, "trimmed": trimmed,
                  "thread_checks": running.checks, "alive": running.thread.is_alive()}))
"""


def test_the_periodic_trim_trims_when_memory_grew_until_its_stop_event() -> None:
    result = subprocess.run([sys.executable, "-c", _PERIODIC_TRIM], capture_output=True, text=True, timeout=180)
    assert result.returncode == 0, result.stderr
    figures = json.loads(result.stdout)
    assert figures["first"] is True, figures  # the first look trims what the set-up freed
    assert figures["quiet"] == [False] * 5, figures  # nothing grew in the five after it
    assert figures["after_burst"] is True, figures
    assert figures["trimmed"] < figures["freed"] - 6 * 1024, figures  # the burst's 8 MiB given back
    assert figures["thread_checks"] >= 2, figures  # the thread looks on its own clock
    assert figures["alive"] is False, figures  # and ends with its stop event
    with pytest.raises(ValueError):
        memtune.PeriodicTrim(threading.Event(), 0)
