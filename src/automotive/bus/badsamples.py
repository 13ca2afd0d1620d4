"""Reports of bad samples from the bus: one line per kind, then a count once per interval, in bounded memory.

A writer of another system can send samples that are valid CDR but nonsense (NaN, a malformed timestamp, a point
cloud whose sizes disagree...). The runtime ignores each such sample (automotive.bus.checkedreader) and reports it here.
A hostile or broken writer may send thousands a second, so the report is rate-limited per kind, a kind being (topic,
what is wrong: the member with its indexes left out, and the rule it breaks), never per value:

    [PlatformControl] bad sample ignored: speed = nan (expected a finite number), from writer 10f7f01:c848d0dd:0:103 ...
    [PlatformControl] 57 more bad sample(s) like this in the last 10 s (speed: expected a finite number); the latest:
        speed = inf, from writer 10f7f01:c848d0dd:0:103 ...

The first sample of a kind is reported at once; the others of the same interval are only counted, and a summary line
follows when the interval ends (a timer thread, so the summary comes even if the flood stops), or at close. A kind
that stays quiet for a whole interval is forgotten, so the state holds only the kinds seen in the last interval, and
never more than ``max_kinds`` of them (further kinds share one catch-all entry): memory stays bounded whatever
arrives. The same mechanism rate-limits Cyclone's own repeated log lines (automotive.bus.cyclonelog).
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field

DEFAULT_INTERVAL_S = 10.0
DEFAULT_MAX_KINDS = 256  # a few per member of the topic types and per rule: far more than any real flood shows
MAX_VALUE_CHARS = 80  # a value is shown shortened: a hostile string may be long
OVERFLOW_KEY = ("*", "other kinds")

_INDEX = re.compile(r"\[\d+\]")


def shorten(text: str, limit: int = MAX_VALUE_CHARS) -> str:
    return text if len(text) <= limit else text[:limit - 3] + "..."


@dataclass(frozen=True)
class BadSample:
    """What is wrong with a sample: the member (a path such as ``objects[3].size[1]``; empty for the whole sample), its
    value as text, and what was expected."""

    member: str
    value: str
    expected: str

    @property
    def kind(self) -> str:
        """The member without its indexes, and the rule: what groups reports (``objects[].size[]: a finite number``)."""
        return f"{_INDEX.sub('[]', self.member) or 'sample'}: {self.expected}"

    def brief(self) -> str:
        """The member and its value (``speed = nan``)."""
        return f"{self.member} = {shorten(self.value)}" if self.member else shorten(self.value)

    def describe(self) -> str:
        """The member, its value and what was expected."""
        return f"{self.brief()} (expected {self.expected})"


class BadSampleError(ValueError):
    """Raised by a decoder that found a sample breaking a rule of its type (automotive.wire.camera's frame codec)."""

    def __init__(self, problem: BadSample):
        super().__init__(problem.describe())
        self.problem = problem


@dataclass
class _Window:
    start: float
    suppressed: int = 0
    latest: str = ""
    kind: str = ""
    prefix: str = ""


@dataclass
class RateLimitedLines:
    """Lines grouped by a key: the first of a key is emitted at once, the others of the interval counted, and one
    summary per interval emitted while they keep coming. Thread-safe; state bounded by ``max_kinds``."""

    emit: Callable[[str], None]
    interval_s: float = DEFAULT_INTERVAL_S
    max_kinds: int = DEFAULT_MAX_KINDS
    clock: Callable[[], float] = time.monotonic
    timer: bool = True  # a thread emits the summaries when their interval ends (tests drive flush() themselves)
    _windows: dict[Hashable, _Window] = field(default_factory=dict)
    _lock: threading.Condition = field(default_factory=threading.Condition)
    _thread: threading.Thread | None = None
    _closed: bool = False

    def add(self, key: Hashable, line: str, latest: str, kind: str, prefix: str = "") -> None:
        """One occurrence: ``line`` is emitted if it is the first of ``key`` in the interval; ``latest`` (a short
        description of this occurrence) and ``kind`` (what the key stands for) go into the summary."""
        with self._lock:
            window = self._windows.get(key)
            if window is None and len(self._windows) >= self.max_kinds:
                key, kind = OVERFLOW_KEY, "of other kinds (too many kinds to tell apart)"
                window = self._windows.get(key)
                line = f"{line} [further kinds are counted together]"
            if window is None:
                self._windows[key] = _Window(self.clock(), kind=kind, prefix=prefix)
                self._start_timer()
                self._lock.notify()
            else:
                window.suppressed += 1
                window.latest = latest
                window.kind = kind
                return
        self.emit(line)

    def flush(self, final: bool = False) -> None:
        """Emit the summaries whose interval ended (all of them with ``final``); forget the kinds that were quiet."""
        lines = []
        with self._lock:
            now = self.clock()
            for key, window in list(self._windows.items()):
                elapsed = now - window.start
                if elapsed < self.interval_s and not final:
                    continue
                if window.suppressed:
                    lines.append(f"{window.prefix}{window.suppressed} more like this in the last {elapsed:.0f} s "
                                 f"({window.kind}); the latest: {window.latest}")
                    window.start, window.suppressed = now, 0
                else:
                    del self._windows[key]
            if final:
                self._windows.clear()
        for line in lines:
            self.emit(line)

    @property
    def kinds(self) -> int:
        """How many kinds the state holds now (bounded by ``max_kinds`` + 1)."""
        with self._lock:
            return len(self._windows)

    def _start_timer(self) -> None:
        if not self.timer or self._thread is not None or self._closed:
            return
        self._thread = threading.Thread(target=self._run, name="bad-sample-report", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            with self._lock:
                if self._closed:
                    return
                if not self._windows:
                    self._lock.wait()
                    continue
                due = min(window.start for window in self._windows.values()) + self.interval_s
                delay = due - self.clock()
                if delay > 0:
                    self._lock.wait(delay)
                    continue
            self.flush()

    def close(self) -> None:
        """Emit what is still counted and stop the timer."""
        with self._lock:
            self._closed = True
            self._lock.notify_all()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=5)
        self.flush(final=True)


class BadSampleReporter:
    """Reports bad samples from the bus, one line per (topic, kind) and interval (see the module's doc)."""

    def __init__(self, log: logging.Logger, interval_s: float = DEFAULT_INTERVAL_S,
                 max_kinds: int = DEFAULT_MAX_KINDS, clock: Callable[[], float] = time.monotonic, timer: bool = True):
        self.log = log
        self.interval_s = interval_s
        self.lines = RateLimitedLines(self._emit, interval_s, max_kinds, clock, timer)
        self.reported = 0  # every bad sample, reported in full or counted

    def _emit(self, line: str) -> None:
        self.log.warning("%s", line)

    def report(self, topic: str, problem: BadSample, writer: str, action: str = "ignored") -> None:
        """One bad sample of ``topic`` from ``writer`` (its description: GUID, names)."""
        self.reported += 1
        prefix = f"[{topic}] "
        line = (f"{prefix}bad sample {action}: {problem.describe()}, from {writer}; more like it are counted and "
                f"reported every {self.interval_s:g} s")
        self.lines.add((topic, problem.kind), line, f"{problem.brief()}, from {writer}", problem.kind, prefix)

    def repeated_event(self, topic: str, event: str, message: str) -> None:
        """A DDS status event that a remote writer can repeat without end (a deadline missed, a sample lost or
        rejected): rate-limited like bad samples, one line per (topic, event) and interval."""
        prefix = f"[{topic}] "
        line = f"{prefix}{message}; repeats are counted and reported every {self.interval_s:g} s"
        self.lines.add((topic, event), line, message, event.replace("_", " "), prefix)

    @property
    def kinds(self) -> int:
        return self.lines.kinds

    def flush(self, final: bool = False) -> None:
        self.lines.flush(final)

    def close(self) -> None:
        self.lines.close()


# The process's reporter: the application's runtime configures it with its logger and interval (config.badSamples).
_reporter: BadSampleReporter | None = None
_reporter_lock = threading.Lock()


def configure(log: logging.Logger, interval_s: float = DEFAULT_INTERVAL_S) -> BadSampleReporter:
    """Make the process's reporter (replacing, and closing, a previous one)."""
    global _reporter
    with _reporter_lock:
        previous, _reporter = _reporter, BadSampleReporter(log, interval_s)
    if previous is not None:
        previous.close()
    return _reporter


def reporter() -> BadSampleReporter:
    """The process's reporter; one logging to the ``automotive`` logger when no application configured one."""
    global _reporter
    with _reporter_lock:
        if _reporter is None:
            _reporter = BadSampleReporter(logging.getLogger("automotive"))
        return _reporter
