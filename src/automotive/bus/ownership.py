"""Which writer an EXCLUSIVE reader follows (redundant mode): one line at each change of owner.

With exclusive ownership a reader takes only the samples of the strongest live writer of an instance; when that
writer's liveliness is lost, the next strongest one's samples come through. The owner of a sample is its
``sample_info.publication_handle``; the writer's discovery data names it (entity name: the instance's name) and gives
its strength.
"""

from __future__ import annotations

import logging
import time
from typing import Any, Protocol, TypeVar

from cyclonedds.core import DDSException
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy
from cyclonedds.sub import DataReader

from automotive.bus.badsamples import BadSample
from automotive.bus.stats import Stats


class _Taken(Protocol):
    sample_info: Any  # a taken sample's SampleInfo


T = TypeVar("T", bound=_Taken)


class OwnerTracker:
    """Follows the writer of the samples an application takes; does nothing for a SHARED reader."""

    def __init__(self, reader: DataReader[Any], log: logging.Logger, stats: Stats | None = None):
        self.reader = reader
        self.log = log
        self.stats = stats
        self.topic_name = reader.topic.get_name()
        self.enabled = Policy.Ownership.Exclusive in reader.get_qos()
        self.owner: int | None = None
        self.owner_name = ""
        self.last_stamp_ns = 0

    def describe(self, handle: int) -> str:
        """'<instance name> (strength N)' from the writer's discovery data."""
        try:
            data = self.reader.get_matched_publication_data(handle)
        except DDSException:  # already gone
            data = None
        if data is None:
            return f"writer {handle:x}"
        qos = data.qos
        name = qos[Policy.EntityName].name if Policy.EntityName in qos else f"writer {handle:x}"
        strength = qos[Policy.OwnershipStrength].strength if Policy.OwnershipStrength in qos else 0
        return f"{name} (strength {strength})"

    def follow(self, sample: Any) -> bool:
        """Note the writer of a valid sample; report and return True when it is not the previous sample's writer."""
        if not self.enabled:
            return False
        info = sample.sample_info
        changed = info.publication_handle != self.owner
        if changed:
            name = self.describe(info.publication_handle)
            gap_ms: float | None = None
            if self.owner is None:
                self.log.info("[%s] owner: %s", self.topic_name, name)
            else:
                # Source timestamps: the gap between the writers' samples, whenever this reader takes them.
                gap_ms = (info.source_timestamp - self.last_stamp_ns) / 1e6
                self.log.warning("[%s] owner changed: %s -> %s, %.0f ms after the last sample of the previous owner",
                                 self.topic_name, self.owner_name, name, gap_ms)
            if self.stats is not None:
                self.stats.record("owner", topic=self.topic_name, previous=self.owner_name or None, owner=name,
                                  instance=name.rsplit(" (strength", 1)[0], gap_ms=gap_ms)
            self.owner, self.owner_name = info.publication_handle, name
        self.last_stamp_ns = info.source_timestamp
        return changed


class StallGuard:
    """Redundant mode: drops input that is older than this instance's liveliness lease when it is taken.

    Such input means the instance was stalled (frozen) at least one lease: the readers have followed the other
    instance meanwhile, and that one has answered it; answering it now would publish a stale state. The lease is the
    one of the instance's exclusive writer; for any other writer (the default system) nothing is dropped.

    What "old" and "future" mean here, judged on the writers' source timestamps (the data's own timestamps are not
    looked at: a replayed recording carries old ones):

    - older than the lease, stamped after this instance started: missed while stalled, dropped (``stalled``);
    - stamped before this instance started (less the lease): no stall of ours explains it, as its readers are volatile
      and matched after the start: the writer's clock is wrong (or the writer lies). Reported as a bad sample and
      dropped, without counting as a stall (which would make collision_avoidance rejoin);
    - stamped more than the lease in the future: the clocks disagree by more than the redundant mode allows (README).
      Reported as a bad sample and dropped.
    """

    def __init__(self, writer: DataWriter[Any], log: logging.Logger):
        self.log = log
        qos = writer.get_qos()
        exclusive = Policy.Ownership.Exclusive in qos and Policy.Liveliness in qos
        self.max_age_ns: int = qos[Policy.Liveliness].lease_duration if exclusive else 0
        self.started_ns = time.time_ns()
        self.stalled = False  # the last call dropped something it was late for

    def fresh(self, samples: list[T], what: str, reader: Any = None) -> list[T]:
        """The samples taken within the lease; one line for those dropped. ``reader`` (a CheckedReader) reports the
        samples whose source timestamp no stall explains."""
        if not self.max_age_ns:
            return samples
        now = time.time_ns()
        kept = []
        late = 0
        for sample in samples:
            info = sample.sample_info  # type: ignore[attr-defined]
            age = now - info.source_timestamp
            if -self.max_age_ns <= age <= self.max_age_ns:
                kept.append(sample)
            elif age > 0 and info.source_timestamp >= self.started_ns - self.max_age_ns:
                late += 1
            else:
                self._report(reader, info, age)
        self.stalled = late > 0
        if late:
            self.log.warning("skipped %d %s older than the %.0f ms lease: this instance was stalled and the other "
                             "one answered them", late, what, self.max_age_ns / 1e6)
        return kept

    def outdated(self, source_ns: int, now_ns: int) -> bool:
        """True when an output stamped ``now_ns`` would answer input stamped ``source_ns`` older than the lease (the
        instance stalled between taking it and answering it)."""
        return bool(self.max_age_ns) and now_ns - source_ns > self.max_age_ns

    def _report(self, reader: Any, info: Any, age_ns: int) -> None:
        if age_ns < 0:
            problem = BadSample("source timestamp", f"{-age_ns / 1e9:.3f} s in the future",
                                f"clocks that agree within the {self.max_age_ns / 1e6:.0f} ms lease")
        else:
            problem = BadSample("source timestamp", f"{age_ns / 1e9:.3f} s old, before this instance started",
                                "a sample written since this instance started")
        if reader is not None and hasattr(reader, "report"):
            reader.report(problem, info)
        else:
            self.log.warning("bad sample ignored: %s", problem.describe())
