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

This is the C library's allocator, not Cyclone's internals: it lives in the bus layer, beside the participant it is
set up for (automotive.bus.endpoints.Databus calls :func:`settle_malloc` before creating it).
"""

from __future__ import annotations

import ctypes
import functools
import sys
from collections.abc import Callable

# glibc mallopt parameters (malloc.h)
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 1024 * 1024
TRIM_THRESHOLD = 1024 * 1024


@functools.cache
def _mallopt() -> Callable[[int, int], int] | None:
    """glibc's mallopt, loaded once; None where there is none (not Linux, or musl: no tuning to do)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return None
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return mallopt  # type: ignore[no-any-return]


def set_malloc_thresholds(mmap_bytes: int, trim_bytes: int) -> bool:
    """Fix glibc's mmap and trim thresholds for this process; False where there is no glibc (or it refused)."""
    mallopt = _mallopt()
    if mallopt is None:
        return False
    return bool(mallopt(M_MMAP_THRESHOLD, mmap_bytes)) and bool(mallopt(M_TRIM_THRESHOLD, trim_bytes))


def settle_malloc() -> bool:
    """The thresholds of every application (1 MiB each), set once and early; False where there is no glibc."""
    return set_malloc_thresholds(MMAP_THRESHOLD, TRIM_THRESHOLD)
