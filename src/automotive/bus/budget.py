"""Bounded queues of samples with a per-topic budget (the site bridge, automotive.tools.zenoh.zenoh_bridge, keeps one
per topic and direction between the databus and the link).

Written here rather than taken from Zenoh: Zenoh's own downsampling (its ``downsampling`` configuration) lets the
first sample of each period through and drops the rest without counting them, where a bridge over a slow link must
send the newest sample, count every sample it drops and bound its memory while the link is down.

- :class:`Budget`: a maximum rate (samples per second) and a maximum bandwidth (bytes per second) of one topic.
  A sample may go when both allow it; bandwidth is a bucket refilled at the budget's rate that may go into debt by
  one sample, so that a sample larger than a second's worth (a 4 MiB frame at 1 MB/s) still goes, and the next one
  waits until the debt is paid.
- :class:`SampleQueue`: samples of one topic in one direction, bounded in count and bytes; when full, the oldest is
  dropped and counted. With a budget, only the newest data sample waits: a newer one replaces it, counted as
  dropped by the budget. Disposals and unregistrations are never replaced by the budget (they change state).
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Generic, TypeVar

T = TypeVar("T")
Clock = Callable[[], float]


class Budget:
    """At most ``max_rate`` samples and ``max_bytes_per_s`` bytes per second (None: no limit)."""

    def __init__(self, max_rate: float | None = None, max_bytes_per_s: float | None = None,
                 clock: Clock = time.monotonic):
        self.max_rate = max_rate
        self.max_bytes_per_s = max_bytes_per_s
        self._clock = clock
        self._next_slot = float("-inf")  # when the rate allows the next sample
        self._tokens = max_bytes_per_s or 0.0  # bytes the bandwidth allows now (negative: a debt)
        self._refilled = clock()

    @property
    def limited(self) -> bool:
        return self.max_rate is not None or self.max_bytes_per_s is not None

    def _refill(self, now: float) -> None:
        if self.max_bytes_per_s is not None:
            burst = self.max_bytes_per_s  # at most one second's worth saved up
            self._tokens = min(burst, self._tokens + (now - self._refilled) * self.max_bytes_per_s)
        self._refilled = now

    def wait_s(self) -> float:
        """Seconds until the next sample may go (0: now)."""
        now = self._clock()
        self._refill(now)
        wait = max(0.0, self._next_slot - now)
        if self.max_bytes_per_s is not None and self._tokens < 0:
            wait = max(wait, -self._tokens / self.max_bytes_per_s)
        return wait

    def spend(self, size: int) -> None:
        """A sample of ``size`` bytes went now."""
        now = self._clock()
        self._refill(now)
        if self.max_rate is not None:
            period = 1.0 / self.max_rate
            if now - self._next_slot < period:  # sent within a period of its slot: keep the schedule (no drift)
                self._next_slot += period
            else:  # idle for a while: the schedule starts again now, without a burst to catch up
                self._next_slot = now + period
        if self.max_bytes_per_s is not None:
            self._tokens -= size

    def describe(self) -> str:
        parts = []
        if self.max_rate is not None:
            parts.append(f"{self.max_rate:g} Hz")
        if self.max_bytes_per_s is not None:
            parts.append(f"{self.max_bytes_per_s * 8 / 1e6:g} Mbit/s")
        return " and ".join(parts) or "no limit"


@dataclass
class QueueCounts:
    offered: int = 0
    passed: int = 0  # handed out by next()
    passed_bytes: int = 0
    dropped_budget: int = 0  # replaced by a newer sample while waiting for the budget
    dropped_full: int = 0  # the oldest, dropped because the queue was full
    max_length: int = 0
    max_bytes: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


@dataclass
class _Entry(Generic[T]):
    item: T
    size: int
    state_change: bool


@dataclass
class SampleQueue(Generic[T]):
    """A bounded FIFO of samples (``item``, its size in bytes) with an optional :class:`Budget`."""

    max_length: int
    max_bytes: int
    budget: Budget = field(default_factory=Budget)
    counts: QueueCounts = field(default_factory=QueueCounts)
    _entries: collections.deque[_Entry[T]] = field(default_factory=collections.deque)
    _queued_bytes: int = 0
    _closed: bool = False
    _changed: threading.Condition = field(default_factory=threading.Condition)

    def __len__(self) -> int:
        return len(self._entries)

    @property
    def bytes(self) -> int:
        return self._queued_bytes

    def offer(self, item: T, size: int, state_change: bool = False) -> None:
        """Queue a sample; what no longer fits (the oldest, or the waiting sample the budget holds back) is dropped
        and counted."""
        with self._changed:
            self.counts.offered += 1
            if self.budget.limited and not state_change:
                for index, entry in enumerate(self._entries):
                    if not entry.state_change:  # the one data sample waiting for the budget: the newer one wins
                        del self._entries[index]
                        self._queued_bytes -= entry.size
                        self.counts.dropped_budget += 1
                        break
            while self._entries and (len(self._entries) >= self.max_length
                                     or self._queued_bytes + size > self.max_bytes):
                dropped = self._entries.popleft()
                self._queued_bytes -= dropped.size
                self.counts.dropped_full += 1
            self._entries.append(_Entry(item, size, state_change))
            self._queued_bytes += size
            self.counts.max_length = max(self.counts.max_length, len(self._entries))
            self.counts.max_bytes = max(self.counts.max_bytes, self._queued_bytes)
            self._changed.notify_all()

    def next(self, timeout_s: float) -> T | None:
        """The next sample once the budget lets it go; None after ``timeout_s`` or once closed."""
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while not self._closed:
                wait = None
                if self._entries:
                    head = self._entries[0]
                    wait = 0.0 if head.state_change else self.budget.wait_s()
                    if wait <= 0:
                        self._entries.popleft()
                        self._queued_bytes -= head.size
                        self.counts.passed += 1
                        self.counts.passed_bytes += head.size
                        if not head.state_change:
                            self.budget.spend(head.size)
                        return head.item
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self._changed.wait(remaining if wait is None else min(wait, remaining))
        return None

    def close(self) -> None:
        with self._changed:
            self._closed = True
            self._changed.notify_all()
