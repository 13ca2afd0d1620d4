"""glibc's allocator set once per process, so that a running application's resident memory settles and stays flat.

What glibc does by default (measured here, docs/measurements/memory.md): a block of 128 kB or more is mmapped, and
freeing such a block raises that threshold to the block's size (up to 32 MiB) and the trim threshold to twice that.
Cyclone's receive buffers (automotive.bus.network.RECEIVE_BUFFER_SIZE) are such blocks: the first two are mmapped, each
new one's pages become resident as datagrams fill it and are returned when it is freed; only after that does the
threshold rise and the next buffers come from the receive thread's arena, whose pages are then reused. So a process
that receives little saw-toothed for several buffers' worth of traffic before it settled. With fixed thresholds, set
before the participant (and its first receive buffer) exists, every buffer comes from the arena from the start and
two buffers' pages are all the receive path ever touches.

Fixed values, not glibc's moving ones. MMAP_THRESHOLD (1 MiB) is above a receive buffer, so buffers come from the
arena; blocks of 1 MiB or more are still mmapped and returned whole when freed. TRIM_THRESHOLD (1 MiB) is above what
the receive path keeps free at the top of its arena (two buffers), so those pages are reused and not given back each
time; a burst larger than that (several LiDAR clouds queued while the process was descheduled) is given back when it
is over instead of staying resident: with glibc's dynamic rule the trim threshold reaches twice the largest block
ever freed (2 MiB after the first receive buffer), so every burst below that became a permanent step in RSS. Camera
processes raise both further for their 4 MiB frames (automotive.wire.camera.tune_process_for_large_frames, through
:func:`set_malloc_thresholds`).

Thresholds act only at the top of an arena. Memory freed below a live block (a burst of LiDAR clouds or camera
frames queued while the process was descheduled, freed in another order than allocated) stays resident however low
the trim threshold is: such bursts were the steps left in the 2-hour soak (docs/measurements/memory.md, cause 5). So
every application looks once a minute whether its resident memory grew and then gives its free memory back
(:class:`PeriodicTrim`, glibc's ``malloc_trim``, which since glibc 2.8 returns the free pages inside every arena and
the main heap's top beyond the trim threshold, though not a thread arena's top): what a burst leaves is resident for
a minute at most. Only when it grew, and only beyond the trim threshold at the top: a trim every minute regardless
also returned the pages that the process reuses all the time (the receive thread's spare buffer, a camera frame kept
at the top of the heap), which then came back, so RSS moved by a receive buffer or a frame from minute to minute.

This is the C library's allocator, not Cyclone's internals: it lives in the bus layer, beside the participant it is
set up for (automotive.bus.endpoints.Databus calls :func:`settle_malloc` before creating it; an application starts
its :class:`PeriodicTrim` when its set-up is done).
"""

from __future__ import annotations

import ctypes
import functools
import os
import sys
import threading
from collections.abc import Callable
from typing import Any

# glibc mallopt parameters (malloc.h)
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 1024 * 1024
TRIM_THRESHOLD = 1024 * 1024
# How often an application looks whether to give its free memory back (config.mallocTrim): once a minute costs
# nothing measurable and bounds a burst's stay to a minute.
TRIM_INTERVAL_S = 60.0
# What makes PeriodicTrim trim: the main heap (where the Python thread's bursts go: decoded LiDAR clouds, frames)
# resident by this much more than after the last trim, or the whole process by GROWTH_KB more. The receive path's
# spare buffer (256 KiB, refilled after a trim) stays under the second; a Python burst shows in the first.
HEAP_GROWTH_KB = 64
GROWTH_KB = 1024

# The trim threshold this process runs with (set_malloc_thresholds): a trim keeps that much free at the top of the
# main heap, as free() does, so the camera processes' frames stay there for reuse.
_trim_threshold_bytes = TRIM_THRESHOLD


@functools.cache
def _glibc_function(name: str, *argtypes: type[Any]) -> Callable[..., int] | None:
    """glibc's function ``name`` (returning int), loaded once; None where there is none (not Linux, or musl: nothing
    to tune)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        function = getattr(ctypes.CDLL(None), name)
    except (OSError, AttributeError):
        return None
    function.argtypes = list(argtypes)
    function.restype = ctypes.c_int
    return function  # type: ignore[no-any-return]


def _mallopt() -> Callable[..., int] | None:
    return _glibc_function("mallopt", ctypes.c_int, ctypes.c_int)


def _malloc_trim() -> Callable[..., int] | None:
    return _glibc_function("malloc_trim", ctypes.c_size_t)


def give_back_free_memory(keep_top_bytes: int | None = None) -> bool | None:
    """Return malloc's free pages, in every arena, to the kernel (``malloc_trim``), but for ``keep_top_bytes`` free
    at the top of the main heap (the process's trim threshold unless given).

    True when some memory was given back, False when there was none to give, None where there is no glibc. The call
    releases the GIL (ctypes), so the other Python threads go on; the allocating C threads wait for each arena's lock
    in turn, for the time of a few madvise calls.
    """
    malloc_trim = _malloc_trim()
    if malloc_trim is None:
        return None
    return bool(malloc_trim(_trim_threshold_bytes if keep_top_bytes is None else keep_top_bytes))


def resident_bytes() -> int:
    """The whole process's resident memory, from one read of /proc/self/statm; 0 where /proc does not tell."""
    try:
        fd = os.open("/proc/self/statm", os.O_RDONLY | os.O_CLOEXEC)
        try:
            return int(os.read(fd, 256).split()[1]) * os.sysconf("SC_PAGE_SIZE")  # size, resident, ... in pages
        finally:
            os.close(fd)
    except (OSError, ValueError, IndexError):
        return 0


def resident_kB() -> tuple[int, int]:
    """(the main heap's, the whole process's) resident kB; (0, 0) where /proc does not tell.

    The main heap's from its entry in /proc/self/smaps, read only as far as that entry (it comes right after the
    executable's mappings: a few dozen lines, not the thousands of the whole file); the process's from
    /proc/self/statm (:func:`resident_bytes`).
    """
    heap_kB = 0
    process_kB = resident_bytes() // 1024
    try:
        with open("/proc/self/smaps", encoding="utf-8", errors="replace") as smaps:
            in_heap = False
            for line in smaps:
                if line.rstrip().endswith("[heap]"):
                    in_heap = True
                elif in_heap and line.startswith("Rss:"):
                    heap_kB = int(line.split()[1])
                    break
    except (OSError, ValueError, IndexError):
        pass
    return heap_kB, process_kB


class PeriodicTrim:
    """A daemon thread that looks every ``interval_s`` seconds, until ``stop`` is set, whether the process's resident
    memory grew since the last trim (the main heap by more than HEAP_GROWTH_KB, or the whole by more than GROWTH_KB)
    and then gives its free memory back. The first look always trims: what the set-up freed. ``checks`` counts the
    looks, ``trims`` the trims."""

    def __init__(self, stop: threading.Event, interval_s: float = TRIM_INTERVAL_S):
        if interval_s <= 0:
            raise ValueError(f"interval {interval_s} s: expected a positive number of seconds")
        self.stop = stop
        self.interval_s = interval_s
        self.checks = 0
        self.trims = 0
        # The least resident memory since the last trim: (main heap, process); None before the first look.
        self._lowest: tuple[int, int] | None = None
        self.thread = threading.Thread(target=self._run, name="malloc-trim", daemon=True)

    def start(self) -> PeriodicTrim:
        if _malloc_trim() is not None:  # not glibc: nothing to give back this way, no thread
            self.thread.start()
        return self

    def _run(self) -> None:
        while not self.stop.wait(self.interval_s):
            self.look()

    def look(self) -> bool:
        """One look (the thread makes one every ``interval_s``): trim when the resident memory grew since the last
        trim, or when there was no trim yet. True when it trimmed."""
        heap_kB, process_kB = resident_kB()
        lowest = self._lowest
        grew = lowest is None or heap_kB > lowest[0] + HEAP_GROWTH_KB or process_kB > lowest[1] + GROWTH_KB
        if grew:
            give_back_free_memory()
            self.trims += 1
            self._lowest = resident_kB()
        else:
            assert lowest is not None
            self._lowest = (min(lowest[0], heap_kB), min(lowest[1], process_kB))
        self.checks += 1
        return grew


def set_malloc_thresholds(mmap_bytes: int, trim_bytes: int) -> bool:
    """Fix glibc's mmap and trim thresholds for this process; False where there is no glibc (or it refused)."""
    global _trim_threshold_bytes
    mallopt = _mallopt()
    if mallopt is None:
        return False
    if bool(mallopt(M_MMAP_THRESHOLD, mmap_bytes)) and bool(mallopt(M_TRIM_THRESHOLD, trim_bytes)):
        _trim_threshold_bytes = trim_bytes
        return True
    return False


def settle_malloc() -> bool:
    """The thresholds of every application (1 MiB each), set once and early; False where there is no glibc."""
    return set_malloc_thresholds(MMAP_THRESHOLD, TRIM_THRESHOLD)
