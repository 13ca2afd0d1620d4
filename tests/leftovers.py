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


def _process_table() -> dict[int, tuple[int, str]]:
    """Every process of the machine: pid -> (parent pid, state letter), from /proc/PID/stat. What psutil's
    ``children()`` reads too, once here for a whole check (psutil's read it at each of three calls a test: about a
    tenth of py-spy's samples of the suite's workers, 2026-11-28)."""
    table: dict[int, tuple[int, str]] = {}
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            with open(f"/proc/{entry.name}/stat", "rb") as stat:
                fields = stat.read().rpartition(b")")[2].split(None, 2)  # the name may hold spaces and parentheses
        except OSError:  # ended meanwhile
            continue
        table[int(entry.name)] = (int(fields[1]), fields[0].decode())
    return table


def _descendants_in(table: dict[int, tuple[int, str]]) -> dict[int, int]:
    """This process's descendants in ``table``: pid -> parent pid."""
    children: dict[int, list[int]] = {}
    for pid, (parent, _) in table.items():
        children.setdefault(parent, []).append(pid)
    found: dict[int, int] = {}
    pending = [os.getpid()]
    while pending:
        parent = pending.pop()
        for child in children.get(parent, ()):
            found[child] = parent
            pending.append(child)
    return found


def descendants() -> set[int]:
    return set(_descendants_in(_process_table()))


def _check(before: set[int]) -> tuple[list[int], list[int]]:
    """(descendants not there before, and not started by one that was: a module's system stays the module's, alive;
    this process's new children that ended and wait to be reaped), from one read of the process table."""
    table = _process_table()
    tree = _descendants_in(table)
    running, ended = [], []
    for pid, parent in tree.items():
        if pid in before:
            continue
        if table[pid][1] == "Z":
            if parent == os.getpid():
                ended.append(pid)
            continue
        ancestor = parent
        while ancestor in tree and ancestor not in before:
            ancestor = tree[ancestor]
        if ancestor not in before:  # reached this process: started during the test
            running.append(pid)
    return running, ended


def _alive(pids: list[int]) -> list[psutil.Process]:
    found = []
    for pid in pids:
        try:
            found.append(psutil.Process(pid))
        except psutil.NoSuchProcess:
            continue
    return found


def _describe(process: psutil.Process) -> str:
    try:
        return f"{process.pid} {' '.join(process.cmdline())[:200]}"
    except psutil.Error:
        return str(process.pid)


def _reap(pids: list[int]) -> None:
    """Reap the test's ended children that nobody waited for: adopted orphans (the test's own Popen objects are done
    with by now, and Python's subprocess takes a child reaped elsewhere in its stride)."""
    for pid in pids:
        try:
            os.waitpid(pid, os.WNOHANG)
        except ChildProcessError:
            continue


def stop_leftovers(before: set[int], grace_s: float = GRACE_S) -> list[str]:
    """The processes that outlived the test (started since ``before``), after a grace for those on their way out;
    each is killed. Empty when none did. The test's ended children are reaped."""
    deadline = time.monotonic() + grace_s
    running, ended = _check(before)
    while running and time.monotonic() < deadline:
        psutil.wait_procs(_alive(running), timeout=min(1.0, max(0.0, deadline - time.monotonic())))
        running, ended = _check(before)
    leftovers = _alive(running)
    named = [_describe(process) for process in leftovers]
    for process in leftovers:
        try:
            process.send_signal(signal.SIGKILL)
        except psutil.Error:
            pass
    if leftovers:
        psutil.wait_procs(leftovers, timeout=5.0)
        ended = _check(before)[1]
    _reap(ended)
    return named
