"""glibc's allocator set once per process, so that a running application's resident memory settles and stays flat.

What glibc does by default (measured here, docs/memory.md): a block of 128 kB or more is mmapped, and freeing such a
block raises that threshold to the block's size (up to 32 MiB) and the trim threshold to twice that. Cyclone's
receive buffers (automotive.bus.network.RECEIVE_BUFFER_SIZE) are such blocks: the first two are mmapped, each new
one's pages become resident as datagrams fill it and are returned when it is freed; only after that does the
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
the trim threshold is: such bursts were the steps left in the 2-hour soak (docs/memory.md, cause 5). So every
application also gives its free memory back once a minute (:class:`PeriodicTrim`, glibc's ``malloc_trim(0)``, which
since glibc 2.8 returns the free pages inside every arena and the main heap's top, though not a thread arena's top):
what a burst leaves is resident for a minute at most, and the pages reused between two trims are faulted in again once.

This is the C library's allocator, not Cyclone's internals: it lives in the bus layer, beside the participant it is
set up for (automotive.bus.endpoints.Databus calls :func:`settle_malloc` before creating it; an application starts
its :class:`PeriodicTrim` when its set-up is done).
"""

from __future__ import annotations

import ctypes
import functools
import sys
import threading
from collections.abc import Callable
from typing import Any

# glibc mallopt parameters (malloc.h)
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 1024 * 1024
TRIM_THRESHOLD = 1024 * 1024
# How often an application gives its free memory back (config.mallocTrim): once a minute costs nothing measurable
# (a few milliseconds of page faults afterwards in the camera processes) and bounds a burst's stay to a minute.
TRIM_INTERVAL_S = 60.0


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


def give_back_free_memory() -> bool | None:
    """Return malloc's free pages, in every arena, to the kernel (``malloc_trim(0)``).

    True when some memory was given back, False when there was none to give, None where there is no glibc. The call
    releases the GIL (ctypes), so the other Python threads go on; the allocating C threads wait for each arena's lock
    in turn, for the time of a few madvise calls.
    """
    malloc_trim = _malloc_trim()
    if malloc_trim is None:
        return None
    return bool(malloc_trim(0))


class PeriodicTrim:
    """A daemon thread that gives the process's free memory back every ``interval_s`` seconds until ``stop`` is set;
    ``trims`` counts the calls made."""

    def __init__(self, stop: threading.Event, interval_s: float = TRIM_INTERVAL_S):
        if interval_s <= 0:
            raise ValueError(f"interval {interval_s} s: expected a positive number of seconds")
        self.stop = stop
        self.interval_s = interval_s
        self.trims = 0
        self.thread = threading.Thread(target=self._run, name="malloc-trim", daemon=True)

    def start(self) -> PeriodicTrim:
        if _malloc_trim() is not None:  # not glibc: nothing to give back this way, no thread
            self.thread.start()
        return self

    def _run(self) -> None:
        while not self.stop.wait(self.interval_s):
            give_back_free_memory()
            self.trims += 1


def set_malloc_thresholds(mmap_bytes: int, trim_bytes: int) -> bool:
    """Fix glibc's mmap and trim thresholds for this process; False where there is no glibc (or it refused)."""
    mallopt = _mallopt()
    if mallopt is None:
        return False
    return bool(mallopt(M_MMAP_THRESHOLD, mmap_bytes)) and bool(mallopt(M_TRIM_THRESHOLD, trim_bytes))


def settle_malloc() -> bool:
    """The thresholds of every application (1 MiB each), set once and early; False where there is no glibc."""
    return set_malloc_thresholds(MMAP_THRESHOLD, TRIM_THRESHOLD)
