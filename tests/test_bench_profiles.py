"""What the latency and codec benchmarks print about where the time goes, on made-up records and this process (the
benchmarks themselves run the applications for minutes: not tests)."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import pytest

from automotive.bench import alert_latency, codecs
from automotive.tools.support.children import thread_cpu_by_name


class Recorded:
    """Stands for an application's status records (alert_latency.Process.records)."""

    def __init__(self, **records: list[dict[str, Any]]):
        self.by_kind = records

    def records(self, kind: str) -> list[dict[str, Any]]:
        return self.by_kind.get(kind, [])


def test_each_alert_hop_splits_into_transport_and_work() -> None:
    ms = 1_000_000
    source = 10_000 * ms  # a tall vision sample (number 1), then when each application took and wrote what followed
    processes: dict[str, Any] = {
        "vision-1": Recorded(sample=[{"src": source, "number": 1}, {"src": source + 100 * ms, "number": 2}]),
        "sensor_fusion": Recorded(take=[{"src": source, "at": source + 1 * ms}],
                                  list=[{"src": source + 3 * ms, "objects": 2, "inputs": [source]}]),
        "collision_avoidance": Recorded(take=[{"src": source + 3 * ms, "at": source + 7 * ms}],
                                        write=[{"src": source + 8 * ms, "attention": True, "inputs": [source + 3 * ms]},
                                               {"src": source + 9 * ms, "inputs": [source + 3 * ms]}]),
        "hmi": Recorded(take=[{"src": source + 8 * ms, "at": source + 13 * ms}]),
        "vehicle_platform": Recorded(take=[{"src": source + 9 * ms, "at": source + 15 * ms}]),
    }
    hops, tall_samples, lost, list_objects = alert_latency.follow(processes, source, source + 200 * ms)
    assert (tall_samples, lost, list_objects) == (1, 0, 2.0)  # sample 2 is not tall
    assert hops["vision -> fusion"] == [3.0] and hops["alert total"] == [13.0] and hops["command total"] == [15.0]
    parts = {part: hops[part] for part in alert_latency.PARTS}
    assert parts == {"vision -> fusion: transport": [1.0], "fusion: work": [2.0],
                     "fusion -> collision: transport": [4.0], "collision: work": [1.0],
                     "collision -> hmi: transport": [5.0]}


def test_thread_cpu_by_name_counts_what_the_threads_use() -> None:
    name = Path("/proc/self/comm").read_text().strip()  # the main thread's (and Python's other threads') name
    before, before_thread = thread_cpu_by_name([os.getpid()]), time.thread_time()
    while time.thread_time() < before_thread + 0.3:  # some CPU to count, in this thread
        sum(range(10_000))
    after, after_thread = thread_cpu_by_name([os.getpid()]), time.thread_time()
    # (the process's threads of other names, Cyclone's of earlier tests, are not this thread's name)
    assert abs((after[name] - before[name]) - (after_thread - before_thread)) < 0.05
    assert thread_cpu_by_name([2**22 + 1]) == {}  # beyond pid_max: no such process


def test_fusion_cpu_by_thread() -> None:
    profile = codecs.FusionCpu(45.0, 500, {"python": 25.0, "recv": 18.5, "tev": 1.44, "gc": 0.06}, "python")
    assert profile.python_us() == 25.0 and profile.cyclone_us() == pytest.approx(20.0)
    assert codecs.describe_threads(profile.threads, "python") == "recv 18.5, tev 1.4"  # below 0.1 us left out


def test_the_fusion_target_is_judged_over_enough_vision_samples_only() -> None:
    # CPU time counts in clock ticks: over fewer samples, one tick is more than a tenth of the 50 us target
    fewest = codecs.MIN_FUSION_SAMPLES
    assert 1_000_000 / os.sysconf("SC_CLK_TCK") / fewest <= codecs.TARGET_FUSION_US / 10
    assert codecs.fusion_verdict(45.0, fewest) == "met" and codecs.fusion_verdict(55.0, fewest) == "NOT MET"
    assert codecs.fusion_verdict(45.0, fewest - 1) == (f"too short to judge: the target needs at least {fewest:,} "
                                                       f"vision samples (this run: {fewest - 1:,})")
