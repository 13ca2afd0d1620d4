"""Where a running process's memory goes: a diagnostic probe that the environment turns on.

``AUTOMOTIVE_MEMTRACE=DIR`` makes an application (every program that uses :func:`automotive.bus.app.run`) start
:mod:`tracemalloc` and write one JSON line every ``AUTOMOTIVE_MEMTRACE_INTERVAL`` seconds (60) to
``DIR/<name>-<pid>.jsonl``, with the figures that tell the layers apart:

- ``rss_kB``: what the kernel charges the process (``/proc/self/status``);
- ``python_traced_kB``: every live allocation of the Python interpreter (objects, buffers) as tracemalloc counts it;
- ``malloc``: glibc's ``mallinfo2`` (all arenas): ``in_use_kB`` (blocks handed out: Cyclone's, numpy's, Python's
  large objects), ``free_kB`` (kept by malloc for reuse), ``mmapped_kB`` (blocks above the mmap threshold),
  ``arenas``; a C library that is not Python's shows as ``malloc.in_use_kB`` growing while ``python_traced_kB`` does
  not (Python's small objects live in its own arenas, mmapped directly, outside malloc);
- ``smaps_kB``: resident kilobytes by kind of mapping (``heap``, ``anon`` for anonymous mappings: malloc's per-thread
  arenas, mmapped blocks, Python's arenas; ``stack``, ``file``);
- ``gc``: the cyclic collector's counts and per-generation collections;
- ``top``: the source lines whose live Python allocations grew most since the first snapshot (after one interval,
  so set-up is not counted), and ``types``: the Python types whose live object count grew most.

``AUTOMOTIVE_MEMTRACE_FRAMES=0`` is the light probe: no tracemalloc (no ``python_traced_kB``, ``top``, ``types``),
only the figures that cost nothing between records, for watching RSS itself; ``python_blocks`` (live blocks of
Python's allocator) then stands for the Python heap. With tracemalloc, allocation is slower and a trace is kept per
live block, and the snapshots themselves take memory: a diagnostic, not for production runs.
"""

from __future__ import annotations

import collections
import ctypes
import functools
import gc
import json
import os
import re
import sys
import threading
import time
import tracemalloc
from pathlib import Path
from typing import Any

ENV_DIR = "AUTOMOTIVE_MEMTRACE"
ENV_INTERVAL = "AUTOMOTIVE_MEMTRACE_INTERVAL"
ENV_FRAMES = "AUTOMOTIVE_MEMTRACE_FRAMES"
TOP_LINES = 15


class _MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]


@functools.cache
def _libc() -> ctypes.CDLL | None:
    """The C library, loaded once: each CDLL object makes classes of its own, which only a full collection frees."""
    try:
        libc = ctypes.CDLL(None)
        libc.mallinfo2.restype = _MallInfo2
        libc.open_memstream.restype = ctypes.c_void_p
        libc.malloc_info.argtypes = [ctypes.c_int, ctypes.c_void_p]
        libc.fclose.argtypes = [ctypes.c_void_p]
        libc.free.argtypes = [ctypes.c_void_p]
    except (OSError, AttributeError):  # not glibc >= 2.33
        return None
    return libc


def malloc_figures() -> dict[str, int] | None:
    """glibc's allocator, summed over its arenas (kB), or None where there is no mallinfo2 (not glibc >= 2.33)."""
    libc = _libc()
    if libc is None:
        return None
    info = libc.mallinfo2()
    return {
        "in_use_kB": (info.uordblks + info.hblkhd) // 1024,  # handed out: in the arenas plus mmapped blocks
        "free_kB": info.fordblks // 1024,  # free in the arenas, kept for reuse
        "arena_kB": info.arena // 1024,  # the arenas' size (sbrk heap and per-thread arenas)
        "mmapped_kB": info.hblkhd // 1024,
        "mmapped_blocks": info.hblks,
        "top_free_kB": info.keepcost // 1024,  # releasable at the top of the main heap
    }


def malloc_arena_count() -> int | None:
    """How many arenas glibc's malloc runs (main plus per-thread), from malloc_info's XML."""
    libc = _libc()
    if libc is None:
        return None
    # c_void_p, not c_char_p: freeing a c_char_p needs ctypes.cast, whose result is a reference cycle, so each record
    # left two objects for the cyclic collector, which an application that makes few cycles runs hardly ever: the
    # probe's own garbage was a slow climb in the soaks' RSS (about 4 Python blocks a minute in every application).
    buffer, size = ctypes.c_void_p(), ctypes.c_size_t()
    stream = libc.open_memstream(ctypes.byref(buffer), ctypes.byref(size))
    if not stream:
        return None
    libc.malloc_info(0, stream)
    libc.fclose(stream)
    text = ctypes.string_at(buffer.value or 0, size.value).decode(errors="replace")
    libc.free(buffer)
    return len(re.findall(r"<heap nr=", text))


def smaps_kB(pid: int | str = "self") -> dict[str, int]:
    """Resident kB of a process by kind of mapping: heap, anon (anonymous), stack, file (libraries, files)."""
    totals: dict[str, int] = collections.Counter()
    kind = "anon"
    try:
        with open(f"/proc/{pid}/smaps", encoding="utf-8", errors="replace") as smaps:
            for line in smaps:
                first = line.split(None, 1)[0]
                if first.endswith(":") and not re.fullmatch(r"[0-9a-f]+-[0-9a-f]+", first[:-1]):
                    if first == "Rss:":
                        totals[kind] += int(line.split()[1])
                    continue
                fields = line.split(None, 5)
                path = fields[5].strip() if len(fields) > 5 else ""
                if path == "[heap]":
                    kind = "heap"
                elif path.startswith("[stack"):
                    kind = "stack"
                elif path.startswith("/"):
                    kind = "file"
                elif path in ("", "[anon]") or path.startswith("[anon:"):
                    kind = "anon"
                else:
                    kind = "other"  # [vdso], [vvar]...
    except OSError:
        return {}
    return dict(totals)


def anon_regions(pid: int | str = "self", min_rss_kB: int = 256) -> list[list[Any]]:
    """The anonymous mappings with at least ``min_rss_kB`` resident: [start address, size kB, resident kB, perms],
    to follow one region (the main heap, a thread's malloc arena, a large mmapped block) over time."""
    regions: list[list[Any]] = []
    current: list[Any] | None = None
    try:
        with open(f"/proc/{pid}/smaps", encoding="utf-8", errors="replace") as smaps:
            for line in smaps:
                fields = line.split()
                if re.fullmatch(r"[0-9a-f]+-[0-9a-f]+", fields[0]):
                    path = fields[5] if len(fields) > 5 else ""
                    start, end = (int(part, 16) for part in fields[0].split("-"))
                    current = [fields[0].split("-")[0], (end - start) // 1024, 0, fields[1]] \
                        if path in ("", "[heap]") else None
                    if current is not None and path == "[heap]":
                        current[0] = "heap"
                elif fields[0] == "Rss:" and current is not None:
                    current[2] = int(fields[1])
                    if current[2] >= min_rss_kB:
                        regions.append(current)
    except OSError:
        return []
    return regions


def rss_kB(pid: int | str = "self") -> int:
    try:
        with open(f"/proc/{pid}/status", encoding="utf-8") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


def type_counts() -> collections.Counter[str]:
    """Live objects that the cyclic collector tracks, by type (module.qualname)."""
    counts: collections.Counter[str] = collections.Counter()
    for obj in gc.get_objects():
        kind = type(obj)
        counts[f"{kind.__module__}.{kind.__qualname__}"] += 1
    return counts


class MemoryProbe:
    """Writes the figures of this process to a JSON-lines file every ``interval_s`` seconds (a daemon thread)."""

    def __init__(self, path: Path, interval_s: float, frames: int = 1):
        self.path = path
        self.interval_s = interval_s
        self.frames = frames
        self.started = time.monotonic()
        self.baseline: tracemalloc.Snapshot | None = None
        self.baseline_types: collections.Counter[str] | None = None
        self.stop_event = threading.Event()
        self.thread = threading.Thread(target=self._run, name="memtrace", daemon=True)

    def start(self) -> None:
        if self.frames > 0 and not tracemalloc.is_tracing():
            tracemalloc.start(self.frames)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.thread.start()

    def stop(self) -> None:
        self.stop_event.set()

    def _snapshot(self) -> tracemalloc.Snapshot:
        return tracemalloc.take_snapshot().filter_traces((
            tracemalloc.Filter(False, tracemalloc.__file__),
            tracemalloc.Filter(False, __file__),
        ))

    def record(self) -> dict[str, Any]:
        figures: dict[str, Any] = {
            "t_s": round(time.monotonic() - self.started, 1),
            "rss_kB": rss_kB(),
            "python_blocks": sys.getallocatedblocks(),  # live blocks of Python's allocator (objects, small buffers)
            "malloc": malloc_figures(),
            "malloc_arenas": malloc_arena_count(),
            "smaps_kB": smaps_kB(),
            "gc": {"counts": gc.get_count(), "collections": [s["collections"] for s in gc.get_stats()],
                   "frozen": gc.get_freeze_count()},
            "threads": threading.active_count(),
            "anon_regions": anon_regions(),
        }
        if not tracemalloc.is_tracing():  # the light probe: no tracemalloc, nothing held between records
            return figures
        traced, peak = tracemalloc.get_traced_memory()
        figures.update(python_traced_kB=traced // 1024, python_traced_peak_kB=peak // 1024,
                       tracemalloc_overhead_kB=tracemalloc.get_tracemalloc_memory() // 1024)
        counts = type_counts()  # before the snapshot, whose own tuples are objects too
        snapshot = self._snapshot()
        if self.baseline is None:
            self.baseline, self.baseline_types = snapshot, counts
        else:
            assert self.baseline_types is not None
            stats = snapshot.compare_to(self.baseline, "lineno")
            figures["top"] = [
                {"where": f"{stat.traceback[0].filename}:{stat.traceback[0].lineno}",
                 "size_diff_kB": round(stat.size_diff / 1024, 1), "count_diff": stat.count_diff,
                 "size_kB": round(stat.size / 1024, 1)}
                for stat in stats[:TOP_LINES] if stat.size_diff > 0]
            growth = counts.copy()
            growth.subtract(self.baseline_types)
            figures["types"] = {name: diff for name, diff in growth.most_common(TOP_LINES) if diff > 0}
        return figures

    def _run(self) -> None:
        while not self.stop_event.wait(self.interval_s):
            try:
                line = json.dumps(self.record())
            except Exception as error:  # a diagnostic must never take the application down
                line = json.dumps({"error": repr(error)})
            with open(self.path, "a", encoding="utf-8") as out:
                out.write(line + "\n")


def start_from_environment(name: str) -> MemoryProbe | None:
    """Start the probe if ``AUTOMOTIVE_MEMTRACE`` names a folder; None otherwise (the normal case)."""
    folder = os.environ.get(ENV_DIR)
    if not folder:
        return None
    try:
        interval_s = float(os.environ.get(ENV_INTERVAL, "60"))
        frames = int(os.environ.get(ENV_FRAMES, "1"))
    except ValueError:
        print(f"{name}: {ENV_INTERVAL} and {ENV_FRAMES} must be numbers; memory probe off", file=sys.stderr)
        return None
    probe = MemoryProbe(Path(folder) / f"{name}-{os.getpid()}.jsonl", interval_s, frames)
    probe.start()
    return probe
