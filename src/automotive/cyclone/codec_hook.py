"""The generated codecs (automotive.cyclone.codecs) plugged into Cyclone DDS Python's own serialize and deserialize.

Cyclone DDS Python serializes every sample through the ``IDL`` object of its type (``cls.__idl__``):
``DataWriter.write`` calls ``sample.serialize()`` and ``DataReader.take`` calls ``cls.deserialize(data)``, both of
which end in ``cls.__idl__.serialize`` / ``.deserialize``. :func:`enable` gives the ``IDL`` object of every type that
has a codec its own ``serialize`` and ``deserialize`` (instance attributes, so nothing else of Cyclone changes) that:

- serialize a whole sample with the codec (what writers do), and hand anything else (key-only serialization for
  dispose and instance lookup, a caller's own buffer) to Cyclone's serializer;
- deserialize a whole sample with its encapsulation header with the codec, anything else (keys) with Cyclone's;
- raise the same :class:`~automotive.cyclone.bounds.BoundError` as :func:`automotive.cyclone.bounds.check` for an
  over-bound value (a writer leaves the bounds of such a type to it), also for a sample it hands to Cyclone;
- degrade to Cyclone's serializer for anything else the codec refuses (Cyclone then writes it or raises its own
  error), so the bytes and the errors are never other than Cyclone's own.

This is the only module that touches Cyclone's serializer internals for the codecs, and it is behind the version gate
(automotive.cyclone.gate; :func:`automotive.cyclone.start` calls :func:`enable` when the gate is open): with a
cyclonedds other than the tested one, a missing internal, ``AUTOMOTIVE_FAST_PATHS=off``, or a changed signature of
Cyclone's ``IDL.serialize``/``deserialize``, it logs one warning line and changes nothing: Cyclone's serializer is
used. ``AUTOMOTIVE_CODECS=off`` turns off only the codecs (to compare). The private modules are imported only once the
gate is open. Types with octet sequences or arrays (the LiDAR cloud, the camera frames) keep
automotive.cyclone.fastpath, which already moves their payload as one block and whose counters and errors the
large-data flows rely on.
"""

from __future__ import annotations

import inspect
import logging
import os
import sys
import threading
from typing import Any

from automotive.cyclone import bounds, gate
from automotive.cyclone.bounds import BoundError
from automotive.cyclone.codecs import Codec, CodecError, codec_for, codecs

__all__ = ["TESTED_CYCLONEDDS", "disable", "enable", "enabled", "installed", "writable"]

TESTED_CYCLONEDDS = ("11.0.1",)
_SERIALIZE_PARAMETERS = ["self", "object", "use_version_2", "buffer", "endianness", "serialize_kind", "prepend_header"]
_DESERIALIZE_PARAMETERS = ["self", "data", "has_header", "use_version_2", "deserialize_kind"]
_NATIVE_BIG = sys.byteorder == "big"

_lock = threading.Lock()
_installed: dict[type, Codec] = {}
_refused: str | None = None  # why enable() left Cyclone's serializer alone (said once)


def _why_not() -> str | None:
    """None when the hook can be installed, else the reason it cannot."""
    if os.environ.get("AUTOMOTIVE_CODECS", "on").lower() in ("off", "0", "false", "no"):
        return "AUTOMOTIVE_CODECS=off"
    reason = gate.why_off()
    if reason is not None:
        return reason
    version = gate.cyclone_version()
    if version not in TESTED_CYCLONEDDS:
        return f"cyclonedds {version} is not the tested {', '.join(TESTED_CYCLONEDDS)}"
    from cyclonedds.idl._main import IDL

    for function, expected in ((IDL.serialize, _SERIALIZE_PARAMETERS), (IDL.deserialize, _DESERIALIZE_PARAMETERS)):
        parameters = inspect.signature(function).parameters
        forwards = any(p.kind is inspect.Parameter.VAR_POSITIONAL for p in parameters.values())  # a wrapper's
        if not forwards and list(parameters) != expected:
            return f"Cyclone's IDL.{function.__name__} changed"
    return None


def _make_serialize(idl: Any, codec: Codec) -> Any:
    from cyclonedds.idl._support import Endianness, SerializeKind

    def serialize(object: Any, use_version_2: bool | None = None, buffer: Any = None,
                  endianness: Endianness | None = None, serialize_kind: SerializeKind = SerializeKind.DataSample,
                  prepend_header: bool = True) -> bytes:
        if buffer is None and prepend_header and serialize_kind is SerializeKind.DataSample:
            if use_version_2 is None:
                if not idl._populated:
                    idl.populate()
                use_version_2 = idl.default_version == 2
            big = endianness is Endianness.Big if endianness is not None else _NATIVE_BIG
            try:
                return codec.encode(object, use_version_2, big)
            except BoundError:
                raise
            except CodecError:
                # Cyclone's serializer decides: it writes the value or raises its own error; the bounds first,
                # which the codec checks as it encodes and so may not have reached (writers leave them to it)
                bounds.check(object)
        return type(idl).serialize(idl, object, use_version_2, buffer, endianness, serialize_kind, prepend_header)

    return serialize


def _make_deserialize(idl: Any, codec: Codec) -> Any:
    from cyclonedds.idl._support import Buffer, DeserializeKind

    def deserialize(data: Any, has_header: bool = True, use_version_2: bool | None = None,
                    deserialize_kind: DeserializeKind = DeserializeKind.DataSample) -> Any:
        if has_header and use_version_2 is None and deserialize_kind is DeserializeKind.DataSample \
                and not isinstance(data, Buffer):
            try:
                return codec.decode(data)
            except CodecError:
                pass  # Cyclone's deserializer decides
        return type(idl).deserialize(idl, data, has_header, use_version_2, deserialize_kind)

    return deserialize


def enable(log: logging.Logger | None = None) -> bool:
    """Serialize and deserialize every type that has a codec (except octet-block types) with it. Idempotent.

    Returns False, after one warning line (the first time), when the codecs cannot be plugged in; then Cyclone's
    serializer stays in use.
    """
    global _refused
    with _lock:
        reason = _why_not()
        if reason is not None:
            if _refused != reason:
                _refused = reason
                (log or logging.getLogger(__name__)).warning("codecs: %s; Cyclone's serializer is used", reason)
            return False
        for data_type, codec in codecs().items():
            if codec.has_octet_blocks or data_type in _installed:
                continue
            idl = data_type.__idl__  # type: ignore[attr-defined]
            idl.serialize = _make_serialize(idl, codec)
            idl.deserialize = _make_deserialize(idl, codec)
            _installed[data_type] = codec
        return True


def disable() -> None:
    """Cyclone's own serialize and deserialize for every type again (for comparisons and benchmarks). Idempotent."""
    with _lock:
        for data_type in list(_installed):
            idl = data_type.__idl__  # type: ignore[attr-defined]
            for name in ("serialize", "deserialize"):
                if name in vars(idl):
                    delattr(idl, name)
            del _installed[data_type]


def enabled() -> bool:
    return bool(_installed)


def installed(data_type: type) -> bool:
    """True when ``data_type`` is serialized and deserialized by its codec."""
    return data_type in _installed


def writable(sample: Any) -> Any:
    """``sample`` as the writer's serializer takes it: numpy arrays in it become dataclasses when its type's codec is
    not plugged in (Cyclone's serializer knows only those)."""
    data_type = type(sample)
    if data_type in _installed:
        return sample
    codec = codec_for(data_type)
    return codec.with_dataclasses(sample) if codec is not None and codec.view_members else sample
