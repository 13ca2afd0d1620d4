"""The launcher's log files: each line of an application's output (and each of the launcher's own lines) appended as
it comes, one ``write`` a line.

A write that fails (a full disk, an I/O error) must not stop the launcher's reading of an application's output: an
application whose output nobody reads blocks at its next line once the pipe is full, and the alert chain with it.
So a failure is said once, the lines that cannot be written are counted, a write is tried again every
:data:`RETRY_S` seconds, and once one succeeds the file and the console say how many lines, from when to when, are
not in it. Nothing is lost without a word.
"""

from __future__ import annotations

import errno
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path

RETRY_S = 5.0  # how often a log file that could not be written is tried again
CLOCK = "%H:%M:%S"
APPEND = os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_CLOEXEC


class LogFile:
    """Lines appended to ``path`` (emptied first); ``report`` is given each line a person must see
    about the file itself (it cannot be written, it is written again). Thread-safe: the reader threads of an
    application's stdout and stderr write into one file."""

    def __init__(self, path: Path, report: Callable[[str], None]):
        self.path = path
        self._report = report
        self._lock = threading.Lock()
        self._said: list[str] = []  # lines for report(), said once the lock is released
        self._fd: int | None = None
        self._closed = False
        self._error = ""  # why lines are not written now ("": they are)
        self._lost = 0  # lines not written since the failure
        self._lost_from = ""  # the clock time of the first of them
        self._partial = False  # the file ends inside a line that the disk cut
        self._next_try = 0.0
        with self._lock:
            try:
                self._fd = os.open(path, APPEND | os.O_TRUNC, 0o644)
            except OSError as error:
                self._fail(error, time.monotonic(), lost=0)
            said = self._take_said()
        self._report_all(said)

    def write(self, text: str) -> None:
        """Append ``text`` as one line, or count it as not written."""
        with self._lock:
            if not self._closed:
                self._write_line(text, time.monotonic())
            said = self._take_said()
        self._report_all(said)

    def close(self, last_line: str | None = None) -> None:
        """Write ``last_line`` (if any; a write is tried for it even before the next retry), close, and say how many
        lines are not in the file if the failure lasted."""
        with self._lock:
            if self._closed:
                return
            if last_line is not None:
                self._write_line(last_line, self._next_try)
            self._closed = True
            if self._error:
                self._said.append(f"{self.path}: {self._lost} line(s) from {self._lost_from} on are not in it "
                                  f"({self._error})")
            if self._fd is not None:
                os.close(self._fd)
                self._fd = None
            said = self._take_said()
        self._report_all(said)

    # -- under the lock ------------------------------------------------------------------------------------------
    def _write_line(self, text: str, now: float) -> None:
        if self._error and not (now >= self._next_try and self._resume(now)):
            self._lost += 1
            return
        error = self._append((text + "\n").encode())
        if error is not None:
            self._fail(error, now)

    def _append(self, data: bytes) -> OSError | None:
        if self._fd is None:
            return OSError(errno.EBADF, os.strerror(errno.EBADF))
        try:
            written = os.write(self._fd, data)
        except OSError as error:
            return error
        if written < len(data):  # the disk filled inside the line: its start is in the file
            self._partial = True
            return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return None

    def _fail(self, error: OSError, now: float, lost: int = 1) -> None:
        self._error = error.strerror or str(error)
        self._lost, self._lost_from = lost, time.strftime(CLOCK)
        self._next_try = now + RETRY_S
        self._said.append(f"{self.path}: {self._error}; its lines are not kept until a write succeeds again "
                          f"(tried every {RETRY_S:g} s)")

    def _resume(self, now: float) -> bool:
        """Try again: the file says what it is missing, and so does the console. False while it still fails."""
        self._next_try = now + RETRY_S
        if self._fd is None:
            try:
                self._fd = os.open(self.path, APPEND, 0o644)
            except OSError:
                return False
        missing = f"{self._lost} line(s) from {self._lost_from} to {time.strftime(CLOCK)} ({self._error})"
        line_end = "\n" if self._partial else ""  # the cut line ends here
        if self._append(f"{line_end}--- not written here: {missing}\n".encode()) is not None:
            return False
        self._said.append(f"{self.path}: written again; {missing} are not in it")
        self._error, self._lost, self._partial = "", 0, False
        return True

    def _take_said(self) -> list[str]:
        said, self._said = self._said, []
        return said

    # -- outside it ----------------------------------------------------------------------------------------------
    def _report_all(self, said: list[str]) -> None:
        """Report what the locked part left to say, outside the lock (a report may write into another log file)."""
        for line in said:
            self._report(line)
