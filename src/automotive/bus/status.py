"""One listener that reports every DDS status event of an endpoint as one readable line naming its topic.

Events that a remote writer can repeat without end (a deadline missed per instance and period, samples lost or
rejected one by one: a flood of instances or of samples from a hostile or broken writer) are rate-limited like bad
samples (automotive.bus.badsamples): the first line at once, then one count per interval. Matches, liveliness and
incompatible QoS come once per remote endpoint and are always logged.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Callable
from typing import Any

from cyclonedds.core import DDSException, Listener
from cyclonedds.qos import Policy

from automotive.bus.badsamples import BadSampleReporter
from automotive.bus.stats import Stats

# DDS QoS policy ids, as in the DDS specification and Cyclone's dds_public_qosdefs.h.
QOS_POLICY_NAMES = {
    1: "USER_DATA", 2: "DURABILITY", 3: "PRESENTATION", 4: "DEADLINE", 5: "LATENCY_BUDGET", 6: "OWNERSHIP",
    7: "OWNERSHIP_STRENGTH", 8: "LIVELINESS", 9: "TIME_BASED_FILTER", 10: "PARTITION", 11: "RELIABILITY",
    12: "DESTINATION_ORDER", 13: "HISTORY", 14: "RESOURCE_LIMITS", 15: "ENTITY_FACTORY",
    16: "WRITER_DATA_LIFECYCLE", 17: "READER_DATA_LIFECYCLE", 18: "TOPIC_DATA", 19: "GROUP_DATA",
    20: "TRANSPORT_PRIORITY", 21: "LIFESPAN", 22: "DURABILITY_SERVICE", 23: "PROPERTY",
    24: "TYPE_CONSISTENCY_ENFORCEMENT", 25: "DATA_REPRESENTATION",
}
REJECTED_REASONS = {0: "not rejected", 1: "instance limit", 2: "sample limit", 3: "samples-per-instance limit"}

# Called with (event name, topic name, status) after the line is logged, for applications that react to events.
EventHook = Callable[[str, str, Any], None]
REPEATING_EVENTS = frozenset({"offered_deadline_missed", "requested_deadline_missed", "sample_lost",
                              "sample_rejected"})


def policy_name(policy_id: int) -> str:
    return QOS_POLICY_NAMES.get(policy_id, f"policy #{policy_id}")


def _seconds(duration_ns: int) -> str:
    return "infinite" if duration_ns >= 2**63 - 1 else f"{duration_ns / 1e9:g} s"


def qos_of(entity: Any) -> Any | None:
    """An endpoint's QoS, or None when it is being deleted: Cyclone then calls a listener with None for the entity
    (seen in the monitor's tests), or its get_qos fails."""
    if entity is None:
        return None
    try:
        return entity.get_qos()
    except DDSException:
        return None


def own_side(policy_id: int, qos: Any | None, reader: bool) -> str:
    """What this endpoint asks (a reader) or offers (a writer) of the policy that failed a match, in words, and what
    the other side must then have done: the mismatch's cause as far as this side can tell (Cyclone's status names the
    policy, not the remote endpoint; ``automotive monitor --once`` shows both sides)."""
    verb, other = ("requests", "the writer offers") if reader else ("offers", "the reader requests")
    name = policy_name(policy_id)
    if qos is None:  # the endpoint is being deleted: its QoS can no longer be had
        return f"{other} another {name.lower().replace('_', ' ')}"
    try:
        if name == "OWNERSHIP":
            kind = "EXCLUSIVE" if Policy.Ownership.Exclusive in qos else "SHARED"
            return f"this {'reader' if reader else 'writer'} {verb} {kind} ownership; {other} " + (
                "SHARED" if kind == "EXCLUSIVE" else "EXCLUSIVE") + ": redundant mode on one side only?"
        if name == "RELIABILITY" and reader:
            return "this reader requests RELIABLE; the writer offers BEST_EFFORT"
        if name == "RELIABILITY":
            return "this writer offers BEST_EFFORT; the reader requests RELIABLE"
        if name == "DURABILITY":
            kind = (re.sub(r"(?<!^)(?=[A-Z])", "_", str(qos[Policy.Durability]).rsplit(".", 1)[-1]).upper()
                    if Policy.Durability in qos else "VOLATILE")
            return f"this {'reader' if reader else 'writer'} {verb} {kind} durability; {other} " + (
                "less" if reader else "more")
        if name == "DEADLINE":
            period = getattr(qos[Policy.Deadline], "deadline", None) if Policy.Deadline in qos else None
            words = _seconds(period) if isinstance(period, int) else "infinite"
            return f"this {'reader' if reader else 'writer'} {verb} a deadline of {words}; {other} " + (
                "a longer one or none" if reader else "a shorter one")
        if name == "LIVELINESS":
            lease = getattr(qos[Policy.Liveliness], "lease_duration", None) if Policy.Liveliness in qos else None
            words = _seconds(lease) if isinstance(lease, int) else "infinite"
            return f"this {'reader' if reader else 'writer'} {verb} a liveliness lease of {words}; {other} " + (
                "a longer one or a weaker kind" if reader else "a shorter one or a stronger kind")
        if name == "LATENCY_BUDGET":
            return ("the writer's latency budget is larger than this reader's (an asynchronous writer?)" if reader
                    else "this writer's latency budget is larger than the reader's (an asynchronous writer)")
        if name == "DATA_REPRESENTATION":
            return "the writer's data representation (XCDR1 or XCDR2) is not one the reader accepts"
    except (KeyError, TypeError):  # a QoS without the policy: only its name is said
        pass
    return f"{other} another {name.lower().replace('_', ' ')}"


class EventCounts:
    """How many of each status event every topic of a program had, and when the last one came, with its line (the
    program's health on /diagnostics: automotive.bus.diagnostics). Thread-safe: listener threads add, another reads."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self.clock = clock
        self._lock = threading.Lock()
        self._counts: dict[tuple[str, str], int] = {}
        self._last: dict[tuple[str, str], tuple[float, str]] = {}
        self._not_alive: dict[str, str] = {}

    def add(self, topic: str, event: str, message: str, count: int = 1) -> None:
        with self._lock:
            self._counts[(topic, event)] = self._counts.get((topic, event), 0) + max(count, 1)
            self._last[(topic, event)] = (self.clock(), message)

    def count(self, topic: str, *events: str) -> int:
        with self._lock:
            return sum(self._counts.get((topic, event), 0) for event in events)

    def recent_events(self, within_s: float, *events: str) -> list[tuple[str, str, str]]:
        """(topic, event, line) of the latest event of each topic and kind among ``events`` in the last ``within_s``
        seconds."""
        since = self.clock() - within_s
        with self._lock:
            return [(topic, event, message) for (topic, event), (at, message) in self._last.items()
                    if event in events and at >= since]

    def liveliness(self, topic: str, not_alive: int, message: str) -> None:
        """A reader's writers not alive now, and the line that said so."""
        with self._lock:
            if not_alive:
                self._not_alive[topic] = message
            else:
                self._not_alive.pop(topic, None)

    def not_alive(self) -> list[str]:
        """The line of each topic whose reader has a writer not alive now."""
        with self._lock:
            return list(self._not_alive.values())


def event_count(event: str, status: Any) -> int:
    """How many events one callback stands for (Cyclone may fold several deadlines or lost samples into one)."""
    if event in ("offered_deadline_missed", "requested_deadline_missed", "sample_lost", "sample_rejected",
                 "liveliness_lost"):
        return int(getattr(status, "total_count_change", 1) or 1)
    return 1


class StatusListener(Listener):
    """Logs matched/unmatched, deadline missed, liveliness, incompatible QoS, sample lost and rejected events."""

    def __init__(self, topic_name: str, log: logging.Logger, hook: EventHook | None = None, exclusive: bool = False,
                 stats: Stats | None = None, reporter: BadSampleReporter | None = None,
                 counts: EventCounts | None = None):
        super().__init__()
        self.stats = stats
        self.counts = counts  # every event counted by kind, for the program's /diagnostics
        self.topic_name = topic_name
        # Cyclone counts every sample an EXCLUSIVE reader drops because a stronger writer owns the instance as
        # "sample lost": with a hot standby that is each of its samples, by design. Such readers report owner
        # changes instead (automotive.bus.ownership).
        self.exclusive = exclusive
        self.log = log
        self.hook = hook
        self.reporter = reporter  # rate-limits the REPEATING_EVENTS; None: every event logged

    def _report(self, event: str, status: Any, message: str, level: int = logging.INFO) -> None:
        if self.counts is not None:
            line = f"[{self.topic_name}] {message}"
            self.counts.add(self.topic_name, event, line, event_count(event, status))
            if event == "liveliness_changed":
                self.counts.liveliness(self.topic_name, status.not_alive_count, line)
        if self.reporter is not None and event in REPEATING_EVENTS:
            self.reporter.repeated_event(self.topic_name, event, message)
        else:
            self.log.log(level, "[%s] %s", self.topic_name, message)
        if self.hook is not None:
            self.hook(event, self.topic_name, status)

    def _matched(self, endpoint: str, status: Any) -> None:
        if self.stats is not None:
            self.stats.record("matched", topic=self.topic_name, endpoint=endpoint, count=status.current_count,
                              change=status.current_count_change)

    def on_publication_matched(self, writer: Any, status: Any) -> None:
        verb = "matched" if status.current_count_change > 0 else "unmatched"
        self._matched("writer", status)
        # A match is said once at INFO, by the reader's side (its writer is found); a writer's side says a reader
        # lost, and its matches at DEBUG: the console shows each match once.
        self._report("publication_matched", status, f"writer {verb} a reader: {status.current_count} reader(s) now",
                     logging.INFO if status.current_count_change < 0 else logging.DEBUG)

    def on_subscription_matched(self, reader: Any, status: Any) -> None:
        verb = "matched" if status.current_count_change > 0 else "unmatched"
        self._matched("reader", status)
        self._report("subscription_matched", status,
                     f"reader {verb} a writer: {status.current_count} writer(s) now")

    def on_offered_deadline_missed(self, writer: Any, status: Any) -> None:
        self._report("offered_deadline_missed", status,
                     f"offered deadline missed: the writer was late (total {status.total_count})", logging.WARNING)

    def on_requested_deadline_missed(self, reader: Any, status: Any) -> None:
        self._report("requested_deadline_missed", status,
                     f"requested deadline missed: no data in time (total {status.total_count})", logging.WARNING)

    def on_liveliness_lost(self, writer: Any, status: Any) -> None:
        self._report("liveliness_lost", status,
                     f"liveliness lost: this writer did not assert itself (total {status.total_count})",
                     logging.WARNING)

    def on_liveliness_changed(self, reader: Any, status: Any) -> None:
        if status.not_alive_count_change > 0:
            message, level = "liveliness LOST of a writer", logging.WARNING
        elif status.alive_count_change > 0 and status.not_alive_count_change < 0:
            message, level = "liveliness regained: a writer is alive", logging.INFO
        elif status.alive_count_change > 0:  # a writer just matched: the matched line said so already
            message, level = "a new writer is alive", logging.DEBUG
        else:
            message, level = "liveliness changed", logging.DEBUG
        if self.stats is not None:
            self.stats.record("liveliness", topic=self.topic_name, alive=status.alive_count,
                              not_alive=status.not_alive_count, lost=status.not_alive_count_change > 0)
        self._report("liveliness_changed", status,
                     f"{message} ({status.alive_count} alive, {status.not_alive_count} not alive)", level)

    def on_offered_incompatible_qos(self, writer: Any, status: Any) -> None:
        policy = status.last_policy_id
        self._report("offered_incompatible_qos", status,
                     f"a reader was seen but does not match: incompatible QoS {policy_name(policy)} "
                     f"({own_side(policy, qos_of(writer), reader=False)})", logging.WARNING)

    def on_requested_incompatible_qos(self, reader: Any, status: Any) -> None:
        policy = status.last_policy_id
        self._report("requested_incompatible_qos", status,
                     f"a writer was seen but does not match: incompatible QoS {policy_name(policy)} "
                     f"({own_side(policy, qos_of(reader), reader=True)})", logging.WARNING)

    def on_sample_lost(self, reader: Any, status: Any) -> None:
        if self.exclusive:
            return
        self._report("sample_lost", status,
                     f"sample lost: {status.total_count_change} more (total {status.total_count})", logging.WARNING)

    def on_sample_rejected(self, reader: Any, status: Any) -> None:
        reason = REJECTED_REASONS.get(status.last_reason, str(status.last_reason))
        self._report("sample_rejected", status,
                     f"sample rejected ({reason}): total {status.total_count}", logging.WARNING)
