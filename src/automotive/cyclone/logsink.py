"""Cyclone DDS's log sink: where Cyclone's own log lines go (``dds_set_log_sink``), for automotive.bus.cyclonelog.

Cyclone internals, kept to this layer and behind the version gate (automotive.cyclone.gate): the pip wheel's
``libddsc`` (11.0.1) does not export ``dds_set_log_sink`` (it is a local symbol of the library's symbol table; only
``dds_set_log_mask`` and ``dds_log`` are exported). Its address is worked out from the library file's ELF symbol
table and the load address of an exported neighbour, and used only when two exported functions confirm that load
address. Otherwise :func:`install` returns False and Cyclone logs as it always did (to stderr).

The handler is called from Cyclone's own threads (the receive thread), holding Cyclone's log lock and possibly a
proxy writer's lock: it must not call into DDS. Nothing it raises reaches Cyclone.
"""

from __future__ import annotations

import atexit
import ctypes
import struct
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from automotive.cyclone import gate

# Cyclone's log categories (dds/ddsrt/log.h).
LC_FATAL, LC_ERROR, LC_WARNING = 1, 2, 4

Handler = Callable[[int, str, str], None]  # (priority, header, message)


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


def sink_setter() -> Any:
    """Cyclone's dds_set_log_sink as a ctypes function, or None when it cannot be found and confirmed (or the gate is
    closed)."""
    if not gate.enabled():
        return None
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


def set_log_mask(mask: int) -> bool:
    """Let Cyclone log only the categories of ``mask`` (LC_FATAL | LC_ERROR: its warnings off); False when the gate is
    closed or the library has no dds_set_log_mask (Cyclone logs as before)."""
    if not gate.enabled():
        return False
    try:
        from cyclonedds.internal import load_cyclonedds

        load_cyclonedds().dds_set_log_mask(ctypes.c_uint32(mask))
    except (AttributeError, OSError, ImportError):
        return False
    return True


class _Sink:
    def __init__(self, handler: Handler, setter: Any):
        self.handler = handler
        self.setter = setter
        self.callback = _LogWrite(self._write)  # kept referenced as long as Cyclone may call it

    def _write(self, _: Any, data_pointer: Any) -> None:
        try:
            data = data_pointer.contents
            message = ctypes.string_at(data.message, data.size).decode("utf-8", "replace")
            header = ctypes.string_at(data.message - data.hdrsize, data.hdrsize).decode("utf-8", "replace")
            self.handler(data.priority, header, message)
        except BaseException:  # noqa: BLE001  (nothing may propagate into Cyclone's C thread)
            pass


_lock = threading.Lock()
_installed: _Sink | None = None


def install(handler: Handler) -> bool:
    """Send Cyclone's log lines to ``handler`` (once per process; a later call replaces the handler); False if
    Cyclone's sink setter cannot be reached (Cyclone keeps logging every line to stderr)."""
    global _installed
    with _lock:
        if _installed is not None:
            _installed.handler = handler
            return True
        setter = sink_setter()
        if setter is None:
            return False
        sink = _Sink(handler, setter)
        setter(sink.callback, None)  # ctypes releases the GIL: a log call in flight can finish meanwhile
        _installed = sink
    return True


def uninstall() -> bool:
    """Give Cyclone back its default sink (stderr); True if a sink was installed."""
    global _installed
    with _lock:
        sink, _installed = _installed, None
    if sink is None:
        return False
    sink.setter(_LogWrite(), None)  # a null pointer: Cyclone's default sink; waits for calls in progress
    return True


def installed() -> bool:
    return _installed is not None


atexit.register(uninstall)  # never leave Cyclone a sink into a finishing interpreter
