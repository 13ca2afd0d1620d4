"""The one layer that touches Cyclone DDS Python's private internals, behind a version gate (:mod:`.gate`).

- :mod:`.fastpath`: octet sequences and arrays (de)serialized as one block (Cyclone's serializer machinery);
- :mod:`.serdata`: serialized samples taken from a reader and written to a writer without (de)serializing them, and
  Cyclone's received buffers lent without a copy (``cyclonedds._clayer``, ctypes prototypes of libddsc);
- :mod:`.bounds`: IDL bounds checked before a write, with a clear message (Cyclone's type-hint resolution);
- :mod:`.codec_hook`: the generated fast codecs (:mod:`.codecs`, ``automotive/types/codecs.py``) as the serializer
  of every type they cover (Cyclone's ``IDL.serialize``/``deserialize`` replaced per type);
- :mod:`.typeinfo`: each type's XTypes type information announced from a table made at build time, not computed by
  Cyclone Python at each program's start;
- :mod:`.liveliness`: a writer's liveliness asserted without writing (``dds_assert_liveliness``, ctypes);
- :mod:`.matched`: a writer's matched readers and a reader's matched writers, asked past a race of Cyclone DDS Python
  (public API; every program asks through it).

Each has a fallback on Cyclone's public API, used when the gate is closed (another cyclonedds version, a missing
internal, or ``AUTOMOTIVE_FAST_PATHS=off``): slower, the same samples. Liveliness has none: the writer keeps its
profile's own liveliness.
"""

from __future__ import annotations

import logging

from automotive.cyclone.gate import TESTED_VERSION, enabled, why_off

__all__ = ["TESTED_VERSION", "enabled", "start", "why_off"]


def start(log: logging.Logger | None = None) -> bool:
    """Switch the process-wide fast paths on, once, before any DDS entity is made; True when they are on.

    With the gate closed nothing is patched and one warning line (to ``log``) says why.
    """
    if not enabled(log):
        return False
    from automotive.cyclone import codec_hook, fastpath, typeinfo

    fastpath.enable()
    typeinfo.enable()
    codec_hook.enable(log)  # the generated codecs; one warning line and Cyclone's serializer if they cannot be used
    return True
