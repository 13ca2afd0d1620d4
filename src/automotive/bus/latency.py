"""Latency percentiles: exact ones of a list (``percentile``, the benchmarks) and, in fixed memory however many
samples, a histogram of logarithmic bins (``LatencyHistogram``, a viewer that runs for hours). Both take the sample of
rank ``int(fraction * count)`` in sorted order, so their figures compare.

A viewer that runs for hours cannot keep every latency (camera_sub kept two numbers per frame: +143 kB a minute,
docs/measurements/memory.md). In the bus layer so that every program that measures latency (camera_sub, the benchmarks)
shares it. Written here rather than taken from the `hdrhistogram` package, which does this job but requires
setuptools >= 83 at run time: that setuptools has no `pkg_resources`, which RTI's Connector (the tests' RTI peer)
imports, so installing it broke the RTI tests.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

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
        self.counts = np.zeros(_BINS, dtype=np.int64)
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
        index = int(np.searchsorted(np.cumsum(self.counts), rank, side="right"))
        return LOWEST_NS * math.exp((index + 0.5) * _LOG_STEP)
