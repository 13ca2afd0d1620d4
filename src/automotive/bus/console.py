"""What a program prints on its console: one line per state change and a periodic status, every sample only on
request.

- :func:`setup_logging`: a program's log lines on stdout, ``HH:MM:SS.mmm name: message``. INFO is what a person
  follows (start, matches and losses, liveliness, owner changes, deadlines, bad samples, alerts, the status line);
  DEBUG adds every sample (``-v``, or ``AUTOMOTIVE_LOG_LEVEL=debug`` in the environment: the launcher sets it for
  its children so that their log files keep every line, and shows only the rest). A line of another level than INFO
  carries it after the name (``vision debug: ...``, ``hmi WARNING: ...``), so a reader of the output (the launcher)
  can tell them apart.
- A closed standard output (``automotive-vision | head -5``) ends the program quietly: the first write that fails
  points stdout at /dev/null and calls the program's stop, instead of a "Logging error" traceback per later line.
- A terminal is written by a thread of its own (:class:`OutputQueue`): a terminal paused with Ctrl-S or a stalled
  ssh session holds that thread only, never the program's readers and writers (a recorder that stopped taking would
  hold back the camera for every reader). The launcher's console uses the same queue.
- :class:`Traffic`: samples in and out per topic, counted where every sample passes (the runtime's checked readers
  and writers, and the raw paths that bypass them), for the status line.
"""

from __future__ import annotations

import atexit
import collections
import logging
import os
import re
import sys
import threading
import time
from collections.abc import Callable
from typing import Generic, TextIO, TypeVar, cast

LOG_LEVEL_VARIABLE = "AUTOMOTIVE_LOG_LEVEL"
STATUS_INTERVAL_S = 5.0  # the status line's period (config.statusInterval)
LEVELS = {"debug": logging.DEBUG, "info": logging.INFO, "warning": logging.WARNING}
TIME_FORMAT = "%H:%M:%S"
# The level names a line carries after the program's name (INFO carries none: it is most lines).
LEVEL_TAGS = {logging.DEBUG: " debug", logging.INFO: "", logging.WARNING: " WARNING", logging.ERROR: " ERROR",
              logging.CRITICAL: " CRITICAL"}
# A program's terminal (stdout a tty): how many lines may wait for it before those below WARNING are left out (and
# counted), and how long the program's end waits for a terminal that is not read.
TERMINAL_QUEUE_LINES = 2000
TERMINAL_CLOSE_WAIT_S = 5.0
# How a reader of the output recognises a DEBUG line: ``12:00:01.234 vision debug: ...``.
DEBUG_LINE_PATTERN = r"^\d\d:\d\d:\d\d\.\d{3} \S+ debug: "
# A DEBUG record wherever it starts in a line: glued to the text of another writer of the same output that left its
# line open (print() writes its text and its newline apart; a C library writes in pieces), the record comes after it.
DEBUG_RECORD = re.compile(DEBUG_LINE_PATTERN.removeprefix("^"))


class LevelFormatter(logging.Formatter):
    """``HH:MM:SS.mmm name level: message``. A line without a traceback is put together here, its clock made once a
    second: logging.Formatter's general path (a strftime and a %-format of the record's dictionary for every line)
    cost half of a DEBUG line per sample, 40 of 100 us on a cold cache."""

    def __init__(self) -> None:
        super().__init__("%(asctime)s.%(msecs)03d %(name)s%(level_tag)s: %(message)s", TIME_FORMAT)
        self._clock = (-1, "")  # (a whole second since the epoch, its HH:MM:SS)

    def format(self, record: logging.LogRecord) -> str:
        tag = record.level_tag = LEVEL_TAGS.get(record.levelno, f" {record.levelname}")
        if record.exc_info or record.exc_text or record.stack_info:
            return super().format(record)
        second = int(record.created)
        clock = self._clock
        if clock[0] != second:  # one tuple: another thread sees the old pair or the new one, never a mix
            clock = (second, time.strftime(TIME_FORMAT, self.converter(record.created)))
            self._clock = clock
        record.message = record.getMessage()
        return f"{clock[1]}.{int(record.msecs):03d} {record.name}{tag}: {record.message}"


class ClosedPipeHandler(logging.StreamHandler):  # type: ignore[type-arg]
    """A stream handler that, when its reader has gone (EPIPE), silences the stream and calls ``on_closed`` once.

    Any other failed write (``automotive-vision > vision.log`` on a full disk) is one line on stderr, not logging's
    traceback for every record; the program goes on, its lines are tried again as they come, and the first one
    written again says so on stderr. A program that ends while its output still fails drops what its buffer holds
    (said already), rather than Python's own error at exit and exit code 120."""

    def __init__(self, stream: TextIO, on_closed: Callable[[], None] | None = None) -> None:
        super().__init__(stream)
        self.on_closed = on_closed
        self.closed_pipe = False
        self.unwritten = 0  # records that failed to be written since the last one that was
        self._failed = False  # the record being emitted failed

    def emit(self, record: logging.LogRecord) -> None:
        self._failed = False
        super().emit(record)
        if self.unwritten and not self._failed:
            _say_on_stderr(f"{record.name}: standard output written again; {self.unwritten} line(s) before may be "
                           "missing from it")
            self.unwritten = 0
            atexit.unregister(self._drop_unwritten)

    def handleError(self, record: logging.LogRecord) -> None:
        error = sys.exc_info()[1]
        if isinstance(error, BrokenPipeError) or (isinstance(error, ValueError) and self.closed_pipe):
            self.reader_gone()
            return
        if isinstance(error, OSError):
            self._failed = True
            if not self.unwritten:
                _say_on_stderr(f"{record.name}: standard output: {error.strerror or error}; its lines are lost while "
                               "it cannot be written")
                atexit.register(self._drop_unwritten)
            self.unwritten += 1
            return
        super().handleError(record)

    def _drop_unwritten(self) -> None:
        """At exit, before Python's own flush: the output still cannot take what the buffer holds."""
        try:
            self.flush()
        except (OSError, ValueError):
            silence_stdout()

    def reader_gone(self) -> None:
        if self.closed_pipe:
            return
        self.closed_pipe = True
        silence_stdout()
        if self.on_closed is not None:
            self.on_closed()


def _say_on_stderr(line: str) -> None:
    try:
        sys.stderr.write(line + "\n")
        sys.stderr.flush()
    except (OSError, ValueError):
        pass  # stderr cannot be written either: nothing else is left to say it on


def silence_stdout() -> None:
    """Point stdout at /dev/null: nobody reads it any more, and Python's own flush at exit must not fail on it."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass


Item = TypeVar("Item")


class OutputQueue(Generic[Item]):
    """Items for an output that may block (a terminal paused with Ctrl-S, a stalled ssh session, a pager scrolled
    back), written by a thread of its own: such an output holds that thread only, never the threads that say
    something (a DDS listener, a reader of an application's output). Beyond ``limit`` items waiting, those that may be
    left out are, and counted; ``notice(count)`` is the item that says so, queued once there is room again.

    logging.handlers' QueueHandler and QueueListener hand records over the same way, but neither leaves any out nor
    ends within a bound (QueueListener.stop waits for a blocked output for ever)."""

    def __init__(self, write: Callable[[Item], object], notice: Callable[[int], Item], limit: int, name: str) -> None:
        self._write = write
        self._notice = notice
        self._limit = limit
        self._waiting: collections.deque[Item] = collections.deque()
        self._ready = threading.Condition()
        self._left_out = 0
        self._closing = False
        self._writer = threading.Thread(target=self._write_items, name=name, daemon=True)
        self._writer.start()

    def put(self, item: Item, may_leave_out: bool = True) -> None:
        with self._ready:
            if may_leave_out and len(self._waiting) >= self._limit:
                self._left_out += 1
                return
            self._say_left_out()
            self._waiting.append(item)
            self._ready.notify()

    def _say_left_out(self) -> None:
        if self._left_out:
            self._waiting.append(self._notice(self._left_out))
            self._left_out = 0

    def _write_items(self) -> None:
        while True:
            with self._ready:
                while not self._waiting and not self._closing:
                    self._ready.wait()
                if not self._waiting:
                    return
                item = self._waiting.popleft()
            self._write(item)

    def close(self, wait_s: float) -> None:
        """The items still queued written out (the count of those left out last), unless the output still blocks
        after ``wait_s`` seconds."""
        with self._ready:
            self._say_left_out()
            self._closing = True
            self._ready.notify()
        self._writer.join(timeout=wait_s)


def flush_stdout() -> None:
    """What Python's buffer of stdout holds, written now: before a writer that bypasses it (DescriptorStream), so that
    what was printed before comes first."""
    try:
        sys.stdout.flush()
    except (OSError, ValueError):
        pass  # nobody reads it (a closed pipe, a terminal gone): the first write says so


class DescriptorStream:
    """Text written straight to a file descriptor, whole, without Python's buffer: a write that blocks holds none of
    Python's locks (an interpreter ending beside a blocked sys.stdout would fail "could not acquire lock")."""

    def __init__(self, descriptor: int) -> None:
        self.descriptor = descriptor

    def write(self, text: str) -> int:
        data = text.encode(errors="replace")
        while data:
            data = data[os.write(self.descriptor, data):]
        return len(text)

    def flush(self) -> None:
        pass


class TerminalHandler(logging.Handler):
    """A program's log records for its terminal: formatted here, written by an :class:`OutputQueue`'s thread through
    ``target`` (which says what fails to be written). WARNING and above are never left out."""

    def __init__(self, target: ClosedPipeHandler, name: str) -> None:
        super().__init__()
        self.target = target
        self.program = name
        # target.emit, not handle: the queue's one thread is its only caller, and a write blocked in it then holds no
        # handler lock for logging's shutdown at exit to wait on for ever
        self.lines: OutputQueue[logging.LogRecord] = OutputQueue(target.emit, self._left_out, TERMINAL_QUEUE_LINES,
                                                                 "terminal")
        atexit.register(self.lines.close, TERMINAL_CLOSE_WAIT_S)

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = self.format(record)
        except Exception:
            self.handleError(record)
            return
        self.lines.put(self._line(text), may_leave_out=record.levelno < logging.WARNING)

    def put_line(self, text: str) -> None:
        self.lines.put(self._line(text))

    def setStream(self, stream: TextIO) -> None:  # noqa: N802  # logging.StreamHandler's name, which callers look for
        """Write to ``stream``'s descriptor from now on (StreamHandler's method, for a caller that moves every handler
        off descriptor 1, as the Zenoh bridge does to read Zenoh's own log there)."""
        self.target.setStream(cast(TextIO, DescriptorStream(stream.fileno())))

    def _line(self, text: str) -> logging.LogRecord:
        """A record whose message is the whole line, as ``target`` writes it."""
        return logging.makeLogRecord({"name": self.program, "msg": text, "levelno": logging.INFO})

    def _left_out(self, count: int) -> logging.LogRecord:
        return self._line(f"{self.program}: {count} line(s) not shown: the terminal was not read for a while")


def level_from(verbose: bool) -> int:
    """DEBUG with ``-v``; else ``AUTOMOTIVE_LOG_LEVEL`` (debug, info, warning); else INFO."""
    if verbose:
        return logging.DEBUG
    return LEVELS.get(os.environ.get(LOG_LEVEL_VARIABLE, "").strip().lower(), logging.INFO)


def setup_logging(name: str, verbose: bool = False, on_closed: Callable[[], None] | None = None) -> logging.Logger:
    """The program's logger ``name`` on stdout, line-buffered (a launcher or a test reading a pipe sees each line at
    once); ``on_closed`` is called once if stdout's reader goes away."""
    global _terminal
    if hasattr(sys.stdout, "reconfigure"):
        sys.stdout.reconfigure(line_buffering=True)
    skip_unused_record_fields()
    handler: logging.Handler
    if _on_terminal():
        flush_stdout()
        stream = cast(TextIO, DescriptorStream(sys.stdout.fileno()))  # what StreamHandler uses of one: write, flush
        handler = _terminal = TerminalHandler(ClosedPipeHandler(stream, on_closed), name)
    else:
        handler = ClosedPipeHandler(sys.stdout, on_closed)
    handler.setFormatter(LevelFormatter())
    log = logging.getLogger(name)
    log.handlers[:] = [handler]
    log.setLevel(level_from(verbose))
    log.propagate = False
    return log


def skip_unused_record_fields() -> None:
    """Leave out of every log record what no line of ours shows: the caller's file and line (a walk up the stack per
    record), the thread's and the process's names. The logging HOWTO's "Optimization" settings: a DEBUG line per
    sample costs a third less (29 to 20 us here)."""
    logging._srcfile = None  # type: ignore[attr-defined]  # documented in the HOWTO, private by name only
    logging.logThreads = False
    logging.logProcesses = False
    logging.logMultiprocessing = False


def without_debug_record(text: str) -> str:
    """A line of a program's output without the DEBUG record it carries (from the record's start on): "" for a DEBUG
    line, the other writer's text for a record glued to it, the line itself for any other."""
    record = DEBUG_RECORD.search(text)
    return text if record is None else text[:record.start()]


_terminal: TerminalHandler | None = None  # the program's, when its stdout is a terminal


def _on_terminal() -> bool:
    try:
        return sys.stdout.isatty()
    except (OSError, ValueError):
        return False


def write_line(text: str) -> None:
    """``text`` and its newline on stdout in one write, flushed: print() writes them apart, and a log record of another
    thread (the status line, a listener's match) landing between them would be glued to the text, one line of two
    that a reader of the output (the launcher's console filter, a test's pattern) no longer tells apart. A log record
    is one write already (logging.StreamHandler). On a terminal, in turn with the log records (TerminalHandler)."""
    if _terminal is not None:
        _terminal.put_line(text)
        return
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


class Traffic:
    """Samples in and out per topic since the last :meth:`rates`, and since the start (:meth:`totals`, which
    /diagnostics reads at its own pace); thread-safe (listeners and the main loop count)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._in: dict[str, int] = {}
        self._out: dict[str, int] = {}
        self._total_in: dict[str, int] = {}
        self._total_out: dict[str, int] = {}

    def count_in(self, topic: str, samples: int = 1) -> None:
        if samples:
            with self._lock:
                self._in[topic] = self._in.get(topic, 0) + samples
                self._total_in[topic] = self._total_in.get(topic, 0) + samples

    def count_out(self, topic: str, samples: int = 1) -> None:
        with self._lock:
            self._out[topic] = self._out.get(topic, 0) + samples
            self._total_out[topic] = self._total_out.get(topic, 0) + samples

    def totals(self) -> tuple[dict[str, int], dict[str, int]]:
        """The counts since the start (in, out), per topic."""
        with self._lock:
            return dict(self._total_in), dict(self._total_out)

    def take_counts(self) -> tuple[dict[str, int], dict[str, int]]:
        """The counts since the last call (in, out), and start counting anew."""
        with self._lock:
            counts = (self._in, self._out)
            self._in, self._out = {}, {}
        return counts

    def rates(self, seconds: float, topics_in: list[str], topics_out: list[str]) -> str:
        """``in VisionTopic 10.0/s, out SensorObjects 10.0/s`` over ``seconds``; every topic of the program is named,
        those that moved nothing at 0/s (the sign of a missing peer)."""
        counts_in, counts_out = self.take_counts()
        per_s = max(seconds, 1e-9)

        def listed(direction: str, topics: list[str], counts: dict[str, int]) -> str:
            names = list(dict.fromkeys([*topics, *counts]))
            if not names:
                return ""
            return f"{direction} " + ", ".join(f"{topic} {counts.get(topic, 0) / per_s:.3g}/s" for topic in names)

        return "; ".join(part for part in (listed("in", topics_in, counts_in), listed("out", topics_out, counts_out))
                         if part)


# One process, one program: the counters every checked reader and writer of the process add to.
traffic = Traffic()
