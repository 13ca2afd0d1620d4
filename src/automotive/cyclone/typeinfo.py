"""The package's types announce their XTypes type information from a table made at build time, not computed at start.

When a topic is made, Cyclone DDS Python's ``Topic`` calls ``IDL.fill_type_data`` of its type. That builds the type's
TypeInformation and TypeMapping with Cyclone's ``XTBuilder`` and serializes them into ``IDL._xt_bytedata``, the bytes
its C layer announces the type with. The first time in a process it also builds Cyclone's serializer for the XTypes
types themselves: 30-40 ms of CPU in every program's start-up, and a few more for each further type.

:func:`enable` gives the ``IDL`` object of every type in the generated table (``automotive/types/typeinfo.py``, made by
:mod:`.typeinfogen` with Cyclone's own builder) a ``fill_type_data`` of its own (an instance attribute, as
:mod:`.codec_hook` does for ``serialize``) that sets those bytes from the table. Whoever asks for the type information
as objects (``get_type_info``, ``get_type_mapping``, ``get_type_id``) still gets Cyclone's own, built on that call.

Behind the version gate, and only when the table was made by the running cyclonedds: another version's builder may
make other bytes. ``tests/test_typeinfo.py`` compares the table with Cyclone's own computation.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from automotive.cyclone import gate

__all__ = ["enable", "installed"]

_lock = threading.Lock()
_installed: set[type] = set()


def _install(idl_class: Any, idl: Any, info: bytes, mapping: bytes) -> None:
    def fill_type_data() -> None:
        if idl._xt_bytedata[0] is None:
            if not idl._populated:
                idl.populate()
            idl._xt_bytedata = (info, mapping)

    def built(method: Callable[[Any], Any]) -> Callable[[], Any]:
        def objects() -> Any:
            idl_class.fill_type_data(idl)  # Cyclone's own objects (and the same bytes again), once
            return method(idl)

        return objects

    idl.fill_type_data = fill_type_data
    idl.get_type_info = built(idl_class.get_type_info)
    idl.get_type_mapping = built(idl_class.get_type_mapping)
    idl.get_type_id = built(idl_class.get_type_id)


def enable() -> bool:
    """Announce every type of the table with its bytes; False (and nothing changed) when the gate is closed or the
    table was made by another cyclonedds. Idempotent."""
    if gate.why_off() is not None:
        return False
    from automotive.types.typeinfo import CYCLONEDDS_VERSION, TYPE_INFO

    if CYCLONEDDS_VERSION != gate.cyclone_version():
        return False
    from cyclonedds.idl._main import IDL

    with _lock:
        for data_type, (info, mapping) in TYPE_INFO.items():
            if data_type not in _installed:
                _install(IDL, data_type.__idl__, info, mapping)
                _installed.add(data_type)
    return True


def installed(data_type: type) -> bool:
    """True when ``data_type`` announces itself with the table's bytes."""
    return data_type in _installed
