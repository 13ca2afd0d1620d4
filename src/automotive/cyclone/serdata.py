"""Serialized samples in and out of Cyclone without the Python (de)serializer, and received buffers lent in place.

With the gate open (:mod:`automotive.cyclone.gate`):

- :func:`take` hands over each sample's CDR bytes as Cyclone received them (``cyclonedds._clayer.ddspy_take``);
- :func:`write`, :func:`dispose`, :func:`unregister` hand CDR bytes to the writer (``ddspy_write*``);
- :func:`lender` gives :class:`Lender`, which takes samples with ``dds_takecdr`` and lends their serialized bytes
  (``ddsi_serdata_to_ser_ref``) as memoryviews: no copy at all, for 4 MiB camera frames.

With the gate closed the same functions go through Cyclone's public API: :func:`take` takes deserialized samples and
serializes them again (XCDR1, what this system's writers write), the writes deserialize the bytes and write the
sample, and there is no lender (callers take with a copy). Slower, the same samples.
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from cyclonedds.core import DDSException, InstanceState, QueryCondition, ReadCondition, SampleState, ViewState
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader

from automotive.cyclone import gate

ANY_STATE = SampleState.Any | ViewState.Any | InstanceState.Any
Buffer = bytes | bytearray | memoryview

_clayer: Any = None  # cyclonedds._clayer, imported once the gate was first found open


def _c_layer() -> Any:
    """Cyclone's C layer (``cyclonedds._clayer``) while the gate is open, else None. Imported once: an import
    statement at every take costs a cold wake-up tens of microseconds."""
    global _clayer
    if not gate.enabled():
        return None
    if _clayer is None:
        from cyclonedds import _clayer as clayer

        _clayer = clayer
    return _clayer


@dataclass
class Taken:
    """One taken sample: its CDR bytes and Cyclone's sample info.

    For a disposal or an unregistration (``info.valid_data`` false) ``data`` is the key only, as Cyclone carries it
    (``whole_key_sample`` False), or already a whole sample of the type holding the key (True: the public API's take).
    """

    data: Buffer
    info: Any
    whole_key_sample: bool = False


def take(reader: DataReader[Any], limit: int) -> list[Taken]:
    """Take up to ``limit`` samples of any state, as CDR bytes."""
    fetched = fetch(reader, True, limit)
    if fetched is not None:
        return [Taken(serialized, info) for serialized, info in fetched]
    taken = []
    for sample in reader.take(N=limit):
        if sample.sample_info.valid_data:
            taken.append(Taken(sample.serialize(use_version_2=False), sample.sample_info))
        else:  # an InvalidSample: the key as a whole sample of the type
            taken.append(Taken(sample.key_sample.serialize(use_version_2=False), sample.sample_info, True))
    return taken


def fetch(reader: DataReader[Any], take: bool, count: int, condition: Any = None,
          instance_handle: int | None = None) -> list[tuple[bytes, Any]] | None:
    """The serialized samples (and their infos) a ``DataReader.take`` (or ``read``) with these arguments would
    deserialize, chosen as it chooses them; None with the gate closed (then only the public take and read remain)."""
    clayer = _c_layer()
    if clayer is None:
        return None
    entity, mask = reader._ref, ANY_STATE
    if condition is not None:
        if isinstance(condition, ReadCondition):
            entity, mask = condition.reader._ref, condition.mask
        elif isinstance(condition, QueryCondition):
            entity, mask = condition._ref, condition.mask
    if instance_handle is None:
        result = (clayer.ddspy_take if take else clayer.ddspy_read)(entity, mask, count)
    else:
        result = (clayer.ddspy_take_handle if take else clayer.ddspy_read_handle)(entity, mask, count,
                                                                                  instance_handle)
    if isinstance(result, int):
        raise DDSException(result, f"Occurred while {'taking' if take else 'reading'} data in {reader!r}")
    return list(result)


def _check(writer: DataWriter[Any], result: int | None, doing: str) -> None:
    if result is not None and result < 0:
        raise DDSException(result, f"Occurred while {doing} a serialized sample in {writer!r}")


def serialize(writer: DataWriter[Any], sample: Any) -> bytes:
    """``sample`` serialized as ``writer.write`` would send it (its data representation, padded to 4-byte units): the
    bytes a writer sends through shared memory and on DDS alike."""
    data: bytes = sample.serialize(use_version_2=getattr(writer, "_use_version_2", None))
    return data.ljust((len(data) + 3) & ~3, b"\0")


def write(writer: DataWriter[Any], data: Buffer, timestamp: int | None = None) -> None:
    """Write a serialized sample (CDR with its header, a whole number of 4-byte units)."""
    clayer = _c_layer()
    if clayer is not None:
        _check(writer, clayer.ddspy_write(writer._ref, data) if timestamp is None
               else clayer.ddspy_write_ts(writer._ref, data, timestamp), "writing")
        return
    writer.write(writer.data_type.deserialize(bytes(data)), timestamp)


def dispose(writer: DataWriter[Any], data: Buffer, timestamp: int | None = None) -> None:
    """Dispose the instance whose key ``data`` (a whole serialized sample) holds."""
    clayer = _c_layer()
    if clayer is not None:
        _check(writer, clayer.ddspy_dispose(writer._ref, data) if timestamp is None
               else clayer.ddspy_dispose_ts(writer._ref, data, timestamp), "disposing")
        return
    writer.dispose(writer.data_type.deserialize(bytes(data)), timestamp)


def unregister(writer: DataWriter[Any], data: Buffer, timestamp: int | None = None) -> None:
    """Unregister the instance whose key ``data`` (a whole serialized sample) holds."""
    clayer = _c_layer()
    if clayer is not None:
        _check(writer, clayer.ddspy_unregister_instance(writer._ref, data) if timestamp is None
               else clayer.ddspy_unregister_instance_ts(writer._ref, data, timestamp), "unregistering")
        return
    writer.unregister_instance(writer.data_type.deserialize(bytes(data)), timestamp)


class _IoVec(ctypes.Structure):
    _fields_ = [("base", ctypes.c_void_p), ("length", ctypes.c_size_t)]  # struct iovec (ddsrt_iovec_t)


@dataclass
class LentBuffer:
    """One taken sample's serialized bytes, lent by Cyclone: ``array`` is valid until the loan is given back."""

    array: ctypes.Array[ctypes.c_char] | None  # None: Cyclone lends no bytes (a disposal's key)
    info: Any


class Lender:
    """Cyclone's C functions that lend a taken sample's serialized bytes (libddsc 11; used only on the tested
    version: a prototype that no longer matches would crash, not raise)."""

    def __init__(self) -> None:
        from cyclonedds.internal import dds_c_t, load_cyclonedds

        library = load_cyclonedds()
        self.sample_info = dds_c_t.sample_info
        self.takecdr = library.dds_takecdr
        self.takecdr.argtypes = [ctypes.c_int32, ctypes.POINTER(ctypes.c_void_p), ctypes.c_uint32,
                                 ctypes.POINTER(dds_c_t.sample_info), ctypes.c_uint32]
        self.takecdr.restype = ctypes.c_int32
        self.size = library.ddsi_serdata_size
        self.size.argtypes = [ctypes.c_void_p]
        self.size.restype = ctypes.c_uint32
        self.to_ser_ref = library.ddsi_serdata_to_ser_ref
        self.to_ser_ref.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_size_t, ctypes.POINTER(_IoVec)]
        self.to_ser_ref.restype = ctypes.c_void_p
        self.to_ser_unref = library.ddsi_serdata_to_ser_unref
        self.to_ser_unref.argtypes = [ctypes.c_void_p, ctypes.POINTER(_IoVec)]
        self.to_ser_unref.restype = None
        self.unref = library.ddsi_serdata_unref
        self.unref.argtypes = [ctypes.c_void_p]
        self.unref.restype = None

    def lend(self, reader: DataReader[Any], limit: int) -> tuple[list[LentBuffer], Callable[[], None]]:
        """Take up to ``limit`` samples; their lent bytes, and the function that gives them back to Cyclone (call it
        once every view of the arrays is released)."""
        pointers = (ctypes.c_void_p * limit)()
        infos = (self.sample_info * limit)()
        count = self.takecdr(reader._ref, pointers, limit, infos, ANY_STATE)
        if count < 0:
            raise DDSException(count, f"Occurred while taking serialized samples in {reader!r}")
        taken = [int(pointers[index] or 0) for index in range(count)]
        lent: list[tuple[int, _IoVec]] = []

        def give_back() -> None:
            for pointer, iov in lent:
                self.to_ser_unref(pointer, ctypes.byref(iov))
            for pointer in taken:
                self.unref(pointer)
            lent.clear()
            taken.clear()

        buffers: list[LentBuffer] = []
        try:
            for index, pointer in enumerate(taken):
                iov = _IoVec()
                self.to_ser_ref(pointer, 0, self.size(pointer), ctypes.byref(iov))
                lent.append((pointer, iov))
                array = (ctypes.c_char * iov.length).from_address(iov.base) if iov.length else None
                buffers.append(LentBuffer(array, infos[index]))
        except BaseException:
            buffers.clear()
            give_back()
            raise
        return buffers, give_back


_lender: Lender | None = None


def lender() -> Lender | None:
    """The lender of received buffers, or None (gate closed, or this Cyclone build lacks the C functions)."""
    global _lender
    if not gate.enabled():
        return None
    if _lender is None:
        try:
            _lender = Lender()
        except (AttributeError, ImportError, OSError):
            return None
    return _lender
