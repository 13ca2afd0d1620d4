"""Processes that outlive the test that started them.

A test's processes must be gone when it ends: the domain ids are handed out again, in turn, to the worker's later tests
(tests/domain_ids.py), and a program still running on one would meet them. A process whose parent ended before it
(a launcher's application, a shell's command) would be adopted by init and lost to sight; each pytest process
therefore adopts its own orphans (PR_SET_CHILD_SUBREAPER), so that every descendant stays in its process tree."""

from __future__ import annotations

import ctypes
import os
import signal
import time

import psutil

PR_SET_CHILD_SUBREAPER = 36  # <linux/prctl.h>
GRACE_S = 20.0  # for a process that was told to stop with its parent and is on its way out


def adopt_orphans() -> None:
    """Make this process the reaper of its descendants' orphans (Linux; nothing elsewhere)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)
    except (OSError, AttributeError):
        pass


def descendants() -> set[int]:
    return {process.pid for process in psutil.Process().children(recursive=True)}


def _running_after(before: set[int]) -> list[psutil.Process]:
    """Descendants not there before, and not started by one that was (a module's system stays the module's)."""
    found = []
    for process in psutil.Process().children(recursive=True):
        try:
            if process.pid in before or process.status() == psutil.STATUS_ZOMBIE:
                continue
            if any(parent.pid in before for parent in process.parents()):
                continue
            found.append(process)
        except psutil.NoSuchProcess:
            continue
    return found


def _describe(process: psutil.Process) -> str:
    try:
        return f"{process.pid} {' '.join(process.cmdline())[:200]}"
    except psutil.Error:
        return str(process.pid)


def _reap_new_zombies(before: set[int]) -> None:
    """Reap the test's ended children that nobody waited for: adopted orphans (the test's own Popen objects are done
    with by now, and Python's subprocess takes a child reaped elsewhere in its stride)."""
    for process in psutil.Process().children():
        try:
            if process.pid not in before and process.status() == psutil.STATUS_ZOMBIE:
                os.waitpid(process.pid, os.WNOHANG)
        except (psutil.Error, ChildProcessError):
            continue


def stop_leftovers(before: set[int], grace_s: float = GRACE_S) -> list[str]:
    """The processes that outlived the test (started since ``before``), after a grace for those on their way out;
    each is killed. Empty when none did. The test's ended children are reaped."""
    deadline = time.monotonic() + grace_s
    leftovers = _running_after(before)
    while leftovers and time.monotonic() < deadline:
        psutil.wait_procs(leftovers, timeout=min(1.0, max(0.0, deadline - time.monotonic())))
        leftovers = _running_after(before)
    named = [_describe(process) for process in leftovers]
    for process in leftovers:
        try:
            process.send_signal(signal.SIGKILL)
        except psutil.Error:
            pass
    psutil.wait_procs(leftovers, timeout=5.0)
    _reap_new_zombies(before)
    return named
