"""Cyclone DDS's own log lines, rate-limited: a sample Cyclone drops is one report line, not one line per sample.

Cyclone checks every received sample against the reader's type in C (enum values, string and sequence bounds,
truncation) and drops one that fails, with a warning on stderr for EACH sample (measured, Cyclone 11.0.1 and a Fast
DDS 2.9 writer of enum value 99: 29 samples, 29 lines):

    1795463914.888568 [151]       recv: data(application, vendor 1.15): 10f7f01:c848d0dd:0:103 #2: deserialization
        PlatformControl/Platform::PlatformControl failed (for reasons unknown)

A hostile writer would fill the log without end. :func:`install` gives Cyclone a log sink (``dds_set_log_sink``) that
turns these warnings into reports of the process's bad-sample reporter (automotive.badsamples: one line per topic and
interval, naming the writer's GUID and vendor) and passes every other line through to stderr, also rate-limited
per kind of line (numbers and GUIDs left out), so that a flood of any other warning is summarised too.

Cyclone internals, kept to this module: the pip wheel's ``libddsc`` (11.0.1) does not export ``dds_set_log_sink``
(it is a local symbol of the library's symbol table; only ``dds_set_log_mask`` and ``dds_log`` are exported). Its
address is worked out from the library file's ELF symbol table and the load address of an exported neighbour, and
used only when two exported functions confirm that load address. Otherwise :func:`install` returns False and
Cyclone logs as it always did (one line per dropped sample).

The sink is called from Cyclone's own threads (the receive thread), holding Cyclone's log lock and possibly a proxy
writer's lock; it takes the GIL, formats and logs, and never calls into DDS (no participant name lookup there, which
is why these reports name the writer by GUID and vendor only).
"""

from __future__ import annotations

import atexit
import ctypes
import re
import struct
import sys
import threading
from pathlib import Path
from typing import Any

from automotive.badsamples import BadSample, BadSampleReporter, RateLimitedLines

# Cyclone's log categories (dds/ddsrt/log.h).
LC_FATAL, LC_ERROR, LC_WARNING = 1, 2, 4

# DDSI vendor ids (the OMG's list) of the stacks this system meets.
VENDORS = {
    (1, 1): "RTI Connext DDS",
    (1, 2): "OpenSplice",
    (1, 3): "OpenDDS",
    (1, 15): "eProsima Fast DDS",
    (1, 16): "Eclipse Cyclone DDS",
}

_DROPPED = re.compile(r"data\(application, vendor (\d+)\.(\d+)\): ([0-9a-fA-F:]+) #\d+: "
                      r"deserialization (.*)/([^/]*) failed \((.*)\)$")
_NUMBERS = re.compile(r"[0-9A-Fa-f:.]*\d[0-9A-Fa-f:.]*")


class _LogData(ctypes.Structure):
    """dds_log_data_t of Cyclone 11 (dds/ddsrt/log.h)."""

    _fields_ = [("priority", ctypes.c_uint32), ("domid", ctypes.c_uint32), ("file", ctypes.c_char_p),
                ("line", ctypes.c_uint32), ("function", ctypes.c_char_p), ("message", ctypes.c_void_p),
                ("size", ctypes.c_size_t), ("hdrsize", ctypes.c_size_t)]


_LogWrite = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.POINTER(_LogData))


def elf_function_offsets(path: Path, names: set[str]) -> dict[str, int]:
    """The symbol-table values (offsets from the load address) of the named functions in a 64-bit little-endian ELF
    shared library, from its full symbol table (``.symtab``: local symbols included). Empty when not found."""
    data = path.read_bytes()
    if data[:4] != b"\x7fELF" or data[4] != 2 or data[5] != 1:  # ELFCLASS64, ELFDATA2LSB
        return {}
    section_offset, = struct.unpack_from("<Q", data, 0x28)
    entry_size, count = struct.unpack_from("<HH", data, 0x3A)
    sections = [struct.unpack_from("<IIQQQQIIQQ", data, section_offset + index * entry_size) for index in range(count)]
    found: dict[str, int] = {}
    for _, kind, _, _, offset, size, link, _, _, symbol_size in sections:
        if kind != 2 or not symbol_size:  # SHT_SYMTAB
            continue
        strings = sections[link][4]
        for start in range(offset, offset + size, symbol_size):
            name_at, info, _, _, value, _ = struct.unpack_from("<IBBHQQ", data, start)
            if info & 0xF != 2 or not value:  # STT_FUNC, defined
                continue
            end = data.index(b"\0", strings + name_at)
            name = data[strings + name_at:end].decode("ascii", "replace")
            if name in names:
                found[name] = value
    return found


def _log_sink_setter() -> Any:
    """Cyclone's dds_set_log_sink as a ctypes function, or None when it cannot be found and confirmed."""
    try:
        from cyclonedds.internal import load_cyclonedds

        library = load_cyclonedds()
        offsets = elf_function_offsets(Path(library._name), {"dds_set_log_sink", "dds_set_log_mask", "dds_log"})
        if set(offsets) != {"dds_set_log_sink", "dds_set_log_mask", "dds_log"}:
            return None
        bases = {ctypes.cast(getattr(library, name), ctypes.c_void_p).value - offsets[name]  # type: ignore[operator]
                 for name in ("dds_set_log_mask", "dds_log")}
        if len(bases) != 1:  # the file is not the library that is loaded, or its table lies
            return None
        setter = ctypes.CFUNCTYPE(None, _LogWrite, ctypes.c_void_p)(bases.pop() + offsets["dds_set_log_sink"])
    except (OSError, AttributeError, ValueError, ImportError, struct.error):
        return None
    return setter


class _Sink:
    def __init__(self, reporter: BadSampleReporter, setter: Any):
        self.reporter = reporter
        self.setter = setter
        self.others = RateLimitedLines(self._to_stderr, reporter.interval_s)
        self.callback = _LogWrite(self._write)  # kept referenced as long as Cyclone may call it

    @staticmethod
    def _to_stderr(line: str) -> None:
        sys.stderr.write(line + "\n")
        sys.stderr.flush()

    def _write(self, _: Any, data_pointer: Any) -> None:
        try:
            data = data_pointer.contents
            message = ctypes.string_at(data.message, data.size).decode("utf-8", "replace")
            header = ctypes.string_at(data.message - data.hdrsize, data.hdrsize).decode("utf-8", "replace")
            self.handle(data.priority, header, message)
        except BaseException:  # noqa: BLE001  (nothing may propagate into Cyclone's C thread)
            pass

    def handle(self, priority: int, header: str, message: str) -> None:
        dropped = _DROPPED.search(message)
        if dropped is not None:
            vendor = (int(dropped[1]), int(dropped[2]))
            name = VENDORS.get(vendor, "")
            writer = f"writer {dropped[3]} (vendor {vendor[0]}.{vendor[1]}{' ' + name if name else ''})"
            problem = BadSample("", f"not deserializable ({dropped[6]})",
                                f"a valid {dropped[5]}: enum values in the enum, strings and sequences within their "
                                "bounds, nothing truncated")
            self.reporter.report(dropped[4], problem, writer, action="dropped by Cyclone DDS")
            return
        line = f"{header}{message}"
        if priority & LC_FATAL:  # Cyclone aborts right after: said as is
            self._to_stderr(line)
            return
        shape = _NUMBERS.sub("#", message)
        self.others.add(shape, line, line, f"Cyclone DDS: {shape}", "cyclonedds: ")


_lock = threading.Lock()
_installed: _Sink | None = None


def install(reporter: BadSampleReporter) -> bool:
    """Route Cyclone's log lines through the rate limits (once per process); False if Cyclone's sink setter cannot be
    reached (Cyclone keeps logging every line to stderr)."""
    global _installed
    with _lock:
        if _installed is not None:
            _installed.reporter = reporter
            return True
        setter = _log_sink_setter()
        if setter is None:
            return False
        sink = _Sink(reporter, setter)
        setter(sink.callback, None)  # ctypes releases the GIL: a log call in flight can finish meanwhile
        _installed = sink
    return True


def uninstall() -> None:
    """Give Cyclone back its default sink (stderr) and emit what the rate limits still count."""
    global _installed
    with _lock:
        sink, _installed = _installed, None
    if sink is None:
        return
    sink.setter(_LogWrite(), None)  # a null pointer: Cyclone's default sink; waits for calls in progress
    sink.others.close()


def installed() -> bool:
    return _installed is not None


atexit.register(uninstall)  # never leave Cyclone a sink into a finishing interpreter
