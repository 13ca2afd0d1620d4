"""Machine-readable status: JSON lines, one object a line, for benchmarks and tests (``--stats FILE``).

Log lines are for people and may change wording; what a program counts goes here too, under stable names. Every
record has ``t`` (seconds since the epoch), ``program`` (the instance name) and ``kind`` (what the record is:
``window`` and ``totals`` of camera_sub, ``matched`` of every endpoint, ``list`` of sensor_fusion...), then fields of
its own. Writes are line-buffered and thread-safe (listener threads report too); a reader of the file sees whole
lines. The file's folder is checked before the program starts (a missing or read-only one is bad input); a write
that fails later (a full disk) is said once on stderr and ends the records, not the program.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from automotive.bus.cli import output_file_problem
from automotive.bus.errors import ConfigError


class Every:
    """A once-every-``seconds`` report (the status lines and records of the programs): :meth:`due` says when."""

    def __init__(self, seconds: float = 1.0):
        self.seconds = seconds
        self.start = time.monotonic()

    def due(self, force: bool = False) -> float | None:
        """The seconds since the last report when the next one is due (or ``force``), and start a new period; else
        None."""
        now = time.monotonic()
        elapsed = now - self.start
        if elapsed < self.seconds and not force:
            return None
        self.start = now
        return elapsed


class Stats:
    """Where a program's status records go; without a file, nowhere (every call costs nothing)."""

    def __init__(self, path: Path | None, program: str):
        self.path = path
        self.program = program
        self._lock = threading.Lock()
        self._stream: IO[str] | None = None
        # The threads whose records wait (deferred), each with its records: (time made, kind, fields).
        self._deferred: dict[int, list[tuple[float, str, dict[str, Any]]]] = {}
        if path is not None:
            problem = output_file_problem(path)
            if problem:
                raise ConfigError(f"--stats {path}: {problem}")
            try:
                self._stream = open(path, "a", encoding="utf-8", buffering=1)
            except OSError as error:
                raise ConfigError(f"--stats {path}: cannot write ({error.strerror})") from None

    @property
    def enabled(self) -> bool:
        return self._stream is not None

    def record(self, kind: str, **fields: Any) -> None:
        if self._stream is None:
            return
        waiting = self._deferred.get(threading.get_ident())
        if waiting is not None:
            waiting.append((time.time(), kind, fields))
            return
        self._write(time.time(), kind, fields)

    @contextmanager
    def deferred(self, log: logging.Logger | None = None) -> Iterator[Callable[[], None]]:
        """Within, this thread's records wait for the function it gives, which the caller calls once it has written
        its outputs (an application's wake-up loop: a record, JSON and a write, would delay the outputs that the
        alert chain waits for); each keeps the time it was made. They are written before any line this thread says
        through ``log`` too: whoever reads a line finds the records made before it. At the end, what is left is
        written. Other threads' records are written at once."""
        thread = threading.get_ident()
        self._deferred[thread] = []
        before_saying = _RecordsBeforeLines(self, thread)
        handlers = list(log.handlers) if log is not None else []
        for handler in handlers:
            handler.addFilter(before_saying)
        try:
            yield lambda: self._write_deferred(thread)
        finally:
            for handler in handlers:
                handler.removeFilter(before_saying)
            self._write_deferred(thread)
            del self._deferred[thread]

    def _write_deferred(self, thread: int) -> None:
        waiting = self._deferred[thread]
        if waiting:
            self._deferred[thread] = []
            for made, kind, fields in waiting:
                self._write(made, kind, fields)

    def _write(self, made: float, kind: str, fields: dict[str, Any]) -> None:
        line = json.dumps({"t": round(made, 6), "program": self.program, "kind": kind, **fields},
                          separators=(",", ":"))
        with self._lock:
            if self._stream is not None:
                try:
                    self._stream.write(line + "\n")
                except OSError as error:
                    self._give_up(error)

    def _give_up(self, error: OSError) -> None:
        """A write failed: say so once and write no more (the program's work goes on; what the buffer still holds
        cannot be written either, so the stream is dropped without a flush)."""
        print(f"{self.program}: --stats {self.path}: {error.strerror or error}; no more status records",
              file=sys.stderr)
        stream, self._stream = self._stream, None
        if stream is not None:
            try:
                stream.close()
            except OSError:
                pass  # the same failure, once more, on the buffered rest

    def close(self) -> None:
        with self._lock:
            if self._stream is not None:
                try:
                    self._stream.close()
                except OSError as error:
                    self._give_up(error)
                self._stream = None


class _RecordsBeforeLines(logging.Filter):
    """A log handler's filter that writes the waiting records of one thread (:meth:`Stats.deferred`) before the
    thread's next line; it lets every line through."""

    def __init__(self, stats: Stats, thread: int):
        super().__init__()
        self.stats = stats
        self.thread = thread

    def filter(self, record: logging.LogRecord) -> bool:
        if threading.get_ident() == self.thread:
            self.stats._write_deferred(self.thread)
        return True


class Follower:
    """The records of a stats file that another process appends to, read as they come: each call reads only what was
    appended since the last one, and a last line still being written waits for the next call. A benchmark waiting on
    a record polls the file: read whole at every poll, its cost grew with the file (`automotive bench failover`, 30 s
    into the run: 6.4 % of a core against 0.6 %)."""

    def __init__(self, path: Path):
        self.path = path
        self._offset = 0  # bytes of the file read so far
        self._partial = b""  # the start of a line whose end was not written yet
        self._all: list[dict[str, Any]] = []
        self._by_kind: dict[str, list[dict[str, Any]]] = {}

    def records(self, kind: str | None = None) -> list[dict[str, Any]]:
        """Every record so far (of one ``kind``), in the order written."""
        self._read_new()
        return list(self._all if kind is None else self._by_kind.get(kind, ()))

    def _read_new(self) -> None:
        try:
            with open(self.path, "rb") as stream:
                if os.fstat(stream.fileno()).st_size < self._offset:  # written anew: read from its start
                    self._offset, self._partial = 0, b""
                    self._all.clear()
                    self._by_kind.clear()
                stream.seek(self._offset)
                data = stream.read()
        except FileNotFoundError:
            return
        self._offset += len(data)
        lines = (self._partial + data).split(b"\n")
        self._partial = lines.pop()
        for line in lines:
            try:
                record = json.loads(line)
            except ValueError:  # not JSON (nor UTF-8): not a record
                continue
            if isinstance(record, dict):
                self._all.append(record)
                kind = record.get("kind")
                if isinstance(kind, str):
                    self._by_kind.setdefault(kind, []).append(record)


def read(path: Path, kind: str | None = None) -> Iterator[dict[str, Any]]:
    """The records of a stats file (of one ``kind``), skipping a last line still being written."""
    yield from Follower(path).records(kind)
