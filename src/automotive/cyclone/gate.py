"""The version gate of the fast paths: Cyclone DDS Python's private internals are used only on the tested version.

The fast paths (octet members in one block, raw samples through Cyclone's C layer, lent received buffers) reach into
modules of cyclonedds that are not its public API: ``cyclonedds._clayer``, ``cyclonedds.internal``, the
``cyclonedds.idl._*`` serializer machinery, and ctypes prototypes of ``dds_takecdr`` / ``ddsi_serdata_*`` written
for libddsc 11. Those change between releases (hundreds of lines between 0.10.5 and 11.0.1): a renamed class would
break every application at import, and a ctypes signature that no longer matches would crash rather than raise.

So they are used only when all of these hold, checked once per process:

- the installed cyclonedds distribution's version is :data:`TESTED_VERSION`;
- every internal module and symbol the fast paths use is there;
- the environment does not turn them off (``AUTOMOTIVE_FAST_PATHS=off``, used by the tests that compare the two).

Otherwise every fast path falls back to Cyclone's public API (slower, same samples) and one warning line says so.
"""

from __future__ import annotations

import importlib
import logging
import os
import threading
from functools import cache
from pathlib import Path

TESTED_VERSION = "11.0.1"
SWITCH = "AUTOMOTIVE_FAST_PATHS"
_OFF_VALUES = ("0", "off", "false", "no")

# (module, attributes) the fast paths use; a missing one closes the gate.
INTERNALS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("cyclonedds._clayer", ("ddspy_take", "ddspy_take_handle", "ddspy_read", "ddspy_read_handle", "ddspy_write",
                            "ddspy_write_ts", "ddspy_dispose", "ddspy_dispose_ts", "ddspy_unregister_instance",
                            "ddspy_unregister_instance_ts")),
    ("cyclonedds.internal", ("dds_c_t", "load_cyclonedds")),
    ("cyclonedds.idl._builder", ("Builder",)),
    ("cyclonedds.idl._machinery", ("ByteArrayMachine", "PlainCdrV2SequenceOfPrimitiveMachine", "StructMachine",
                                   "DelimitedCdrAppendableStructMachine", "PLCdrMutableStructMachine",
                                   "UnionMachine", "DelimitedCdrAppendableUnionMachine", "OptionalMachine",
                                   "ArrayMachine", "SequenceMachine", "KeyEnabled", "Machine")),
    ("cyclonedds.idl._main", ("IDL",)),
    ("cyclonedds.idl._support", ("Buffer", "DeserializeKind", "SerializeKind")),
    ("cyclonedds.idl._type_normalize", ("get_extended_type_hints",)),
)

_log = logging.getLogger("automotive.cyclone")
_lock = threading.Lock()
_warned = False


@cache  # the gate and the codec hook both ask, once each per process
def cyclone_version() -> str:
    """The installed cyclonedds distribution's version. Read from its METADATA beside the package when pip laid it out
    so (one ``cyclonedds-*.dist-info``): what ``importlib.metadata.version`` reads, without importing
    importlib.metadata and searching every path entry at each program's start (10-25 ms of CPU here)."""
    import cyclonedds

    found = list(Path(cyclonedds.__file__).resolve().parent.parent.glob("cyclonedds-*.dist-info/METADATA"))
    if len(found) == 1:
        with found[0].open(encoding="utf-8") as lines:
            for line in lines:
                if line.startswith("Version:"):
                    return line.partition(":")[2].strip()
                if not line.strip():  # the headers end at the first empty line
                    break
    import importlib.metadata  # laid out otherwise (two dist-info folders, an egg): the standard library decides

    try:
        return importlib.metadata.version("cyclonedds")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


@cache
def why_off() -> str | None:
    """Why the fast paths are off in this process, or None when they are on."""
    switch = os.environ.get(SWITCH, "").strip().lower()
    if switch in _OFF_VALUES:
        return f"{SWITCH}={os.environ[SWITCH]}"
    version = cyclone_version()
    if version != TESTED_VERSION:
        return f"cyclonedds {version} is not the tested {TESTED_VERSION}"
    for module_name, attributes in INTERNALS:
        try:
            module = importlib.import_module(module_name)
        except Exception as error:  # any failure to import is a reason to stay on the public API
            return f"{module_name} cannot be imported ({error})"
        missing = [name for name in attributes if not hasattr(module, name)]
        if missing:
            return f"{module_name} lacks {', '.join(missing)}"
    return None


def enabled(log: logging.Logger | None = None) -> bool:
    """True when the fast paths may be used; the first time they may not, one warning line says why."""
    reason = why_off()
    if reason is not None:
        warn_once(reason, log)
    return reason is None


def warn_once(reason: str, log: logging.Logger | None = None) -> None:
    global _warned
    with _lock:
        if _warned:
            return
        _warned = True
    (log or _log).warning("cyclone: fast paths off (%s): Cyclone's public API is used instead, slower", reason)
