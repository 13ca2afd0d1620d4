"""Latency percentiles: exact ones of a list (``percentile``, the benchmarks) and, in fixed memory however many
samples, a histogram of logarithmic bins (``LatencyHistogram``, a viewer that runs for hours). Both take the sample of
rank ``int(fraction * count)`` in sorted order, so their figures compare.

:data:`recent`, the process's :class:`RecentLatencies`, keeps what every reader of the runtime measures of each
sample (its reception minus its writer's source timestamp) over the last WINDOW_S seconds, per topic and writer
participant, in bounded memory: /diagnostics reports its percentiles once a second (automotive.bus.diagnostics).

A viewer that runs for hours cannot keep every latency (camera_sub kept two numbers per frame: +143 kB a minute,
docs/measurements/memory.md). In the bus layer so that every program that measures latency (camera_sub, the benchmarks)
shares it. Written here rather than taken from the `hdrhistogram` package, which does this job but requires
setuptools >= 83 at run time: that setuptools has no `pkg_resources`, which RTI's Connector (the tests' RTI peer)
imports, so installing it broke the RTI tests.
"""

from __future__ import annotations

import math
import threading
import time
from array import array
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from itertools import accumulate

# Bins of 0.1 % relative width from 1 µs to 100 s: about 18,400 counters (147 kB), allocated once.
LOWEST_NS = 1_000
HIGHEST_NS = 100_000_000_000
RELATIVE_WIDTH = 0.001
_LOG_STEP = math.log1p(RELATIVE_WIDTH)
_BINS = int(math.log(HIGHEST_NS / LOWEST_NS) / _LOG_STEP) + 2


def percentile(values: Sequence[float], fraction: float) -> float | None:
    """The value at ``fraction`` (0.5, 0.99) of ``values``: the one of rank ``int(fraction * count)`` in sorted order;
    None when there is none."""
    if not values:
        return None
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(fraction * len(ordered)))]


class LatencyHistogram:
    """Counts of latencies (ns) in bins of 0.1 % width; values below 1 µs count as 1 µs, above 100 s as 100 s."""

    def __init__(self) -> None:
        # A plain array, not numpy's: every program imports this module, and most of them have no other use for numpy
        # (its import is about a sixth of a program's start-up).
        self.counts = array("q", bytes(8 * _BINS))
        self.total = 0

    def record(self, latency_ns: int) -> None:
        clamped = min(HIGHEST_NS, max(LOWEST_NS, latency_ns))
        self.counts[int(math.log(clamped / LOWEST_NS) / _LOG_STEP)] += 1
        self.total += 1

    def percentile_ns(self, fraction: float) -> float | None:
        """The latency at ``fraction`` (0.5, 0.99) of the recorded ones, to 0.1 %: the sample of rank
        ``int(fraction * count)`` in sorted order, as its bin's middle; None when nothing was recorded."""
        if not self.total:
            return None
        rank = min(self.total - 1, int(fraction * self.total))
        index = next(bin_ for bin_, running in enumerate(accumulate(self.counts)) if running > rank)
        return LOWEST_NS * math.exp((index + 0.5) * _LOG_STEP)


# -- the latencies of the last seconds, per topic and writer --------------------------------------------------------
WINDOW_S = 10  # the window /diagnostics reports
KEPT_PER_SECOND = 256  # latencies kept per writer and second (the first ones): a faster flow is counted, not kept
MAX_SOURCES = 64  # (topic, writer participant) pairs kept; beyond, the one heard from least recently goes


class _Window:
    """One writer's latencies (ms) of one topic: a slot per second of the last WINDOW_S, reused as time goes on."""

    __slots__ = ("seconds", "counts", "values", "last")

    def __init__(self) -> None:
        self.seconds = [-1] * WINDOW_S  # the second (time.time() // 1) each slot holds
        self.counts = [0] * WINDOW_S
        self.values = [array("d") for _ in range(WINDOW_S)]
        self.last = 0

    def add(self, second: int, latencies_ms: list[float]) -> None:
        slot = second % WINDOW_S
        values = self.values[slot]
        if self.seconds[slot] != second:
            self.seconds[slot], self.counts[slot] = second, 0
            del values[:]
        self.counts[slot] += len(latencies_ms)
        room = KEPT_PER_SECOND - len(values)
        if room > 0:
            values.extend(latencies_ms[:room])
        self.last = second

    def recent(self, second: int, into: list[float]) -> int:
        """Add the kept latencies of the last WINDOW_S seconds (``second`` included) to ``into``; their count."""
        count = 0
        for slot in range(WINDOW_S):
            if second - WINDOW_S < self.seconds[slot] <= second:
                count += self.counts[slot]
                into.extend(self.values[slot])
        return count


@dataclass(frozen=True)
class LatencySummary:
    """The latency of a topic's samples as one reader process took them over the last WINDOW_S seconds: from one
    writer participant (``writer``), or from all of them (``writer`` None)."""

    topic: str
    writer: str | None
    count: int
    p50_ms: float
    p99_ms: float


class RecentLatencies:
    """Latencies of the last WINDOW_S seconds per topic and writer participant; thread-safe (every reader of a
    process records here, /diagnostics reads once a second). A take records its whole batch with one clock read."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._windows: dict[tuple[str, str], _Window] = {}

    def record(self, topic: str, writer: str, stamps_ns: Iterable[int], now_ns: int | None = None) -> None:
        """Samples of ``topic`` from ``writer`` (its participant's name) with these source timestamps, taken now."""
        now = time.time_ns() if now_ns is None else now_ns
        latencies = [(now - stamp) * 1e-6 for stamp in stamps_ns if stamp > 0]  # 0 or less: the writer gave none
        if not latencies:
            return
        source = (topic, writer)
        with self._lock:
            window = self._windows.get(source)
            if window is None:
                if len(self._windows) >= MAX_SOURCES:
                    oldest = min(self._windows, key=lambda source: self._windows[source].last)
                    del self._windows[oldest]
                window = self._windows[source] = _Window()
            window.add(now // 1_000_000_000, latencies)

    def summaries(self, now_ns: int | None = None) -> list[LatencySummary]:
        """Per topic: all its writers together, then each writer (when it has more than one, or always: ``writer``
        says whose); topics and writers in name order. Nothing for a topic without a sample in the window."""
        second = (time.time_ns() if now_ns is None else now_ns) // 1_000_000_000
        with self._lock:
            found = []
            for (topic, writer), window in self._windows.items():
                values: list[float] = []
                count = window.recent(second, values)
                if count:
                    found.append((topic, writer, count, values))
        found.sort(key=lambda item: (item[0], item[1]))
        summaries: list[LatencySummary] = []
        for topic in dict.fromkeys(item[0] for item in found):
            of_topic = [item for item in found if item[0] == topic]
            merged = [value for item in of_topic for value in item[3]]
            summaries.append(_summary(topic, None, sum(item[2] for item in of_topic), merged))
            summaries += [_summary(topic, writer, count, values) for _, writer, count, values in of_topic]
        return summaries

    def clear(self) -> None:
        with self._lock:
            self._windows.clear()


def _summary(topic: str, writer: str | None, count: int, values: list[float]) -> LatencySummary:
    ordered = sorted(values)
    return LatencySummary(topic, writer, count, percentile(ordered, 0.5) or 0.0, percentile(ordered, 0.99) or 0.0)


recent = RecentLatencies()  # the process's: every reader of the runtime records here
