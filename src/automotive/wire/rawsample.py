"""Serialized samples: take a sample's CDR bytes from a reader without deserializing it, write CDR bytes to a writer
without serializing them. Used by the camera pair, the recorder, the replayer and the bridge.

A raw sample is what travels on the wire: the 4-byte encapsulation header (XCDR1 or XCDR2, either byte order)
followed by the body. Taking one keeps what DDS says about it: the source timestamp, the writer (publication
handle), the instance and its state. A disposal or an unregistration (an "invalid" sample: no data, only a key) is
taken too; its bytes are turned into a whole sample of the type that carries the key (the other members at their
defaults), which is what a writer's dispose and unregister take, so it can be recorded and replayed like data.

Two ways to take:

- :meth:`RawReader.take` copies each sample's bytes into a ``bytes`` (for queues and files), keys included;
- :meth:`RawReader.lend` lends Cyclone's own received buffers as ``memoryview``s, valid inside a ``with`` block
  (``dds_takecdr`` + ``ddsi_serdata_to_ser_ref``): no copy at all, for 4 MiB camera frames.

How the bytes get in and out of Cyclone is :mod:`automotive.cyclone.serdata`'s business (Cyclone's C layer on the
tested version, its public API otherwise).
"""

from __future__ import annotations

import ctypes
import enum
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from cyclonedds.core import InstanceState
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader

from automotive.bus import badsamples
from automotive.bus.checkedreader import WriterNames, undecodable
from automotive.cyclone import serdata
from automotive.cyclone.bounds import type_name

ANY_STATE = serdata.ANY_STATE
Buffer = bytes | bytearray | memoryview


class SampleKind(enum.Enum):
    """What a taken sample says: new data, or that its instance was disposed or lost its last writer."""

    DATA = "data"
    DISPOSE = "dispose"
    UNREGISTER = "unregister"


@dataclass
class RawSample:
    """One taken sample: its CDR bytes (encapsulation header included) and what DDS says about it."""

    data: Buffer
    kind: SampleKind
    source_timestamp: int  # ns since the epoch, as stamped by the writer
    writer: int  # the writer's instance handle, as DataReader.get_matched_publications lists it
    instance: int  # the instance handle
    instance_state: int  # an InstanceState value: alive, disposed, no writers


_EMPTY_KEY = b"\x00\x01\x00\x00"  # an XCDR1 little-endian header and no key: the key of a keyless type


def signed_handle(value: int) -> int:
    """An instance handle as Cyclone Python's API gives them (a signed 64-bit number), whatever way it was read."""
    return ctypes.c_int64(value).value


def _state_change(instance_state: int) -> SampleKind:
    return SampleKind.DISPOSE if instance_state == InstanceState.NotAliveDisposed else SampleKind.UNREGISTER


def key_to_sample(data_type: type[Any], key_cdr: Buffer, xcdr2: bool = False) -> bytes:
    """A whole serialized sample of ``data_type`` holding the key of ``key_cdr`` (a key-only CDR stream, as an
    invalid sample carries), the other members at their defaults: what dispose and unregister take."""
    key = bytes(key_cdr) if len(key_cdr) >= 4 else _EMPTY_KEY  # Cyclone lends no bytes for a keyless type's key
    return bytes(data_type.deserialize_key(key).serialize(use_version_2=xcdr2))


def release_lent_views(views: list[memoryview], arrays: list[ctypes.Array[ctypes.c_char]], what: str,
                       copy_hint: str) -> None:
    """Release our views of lent buffers (``arrays``: Cyclone's received samples, shared memory) before the buffers
    go back to their owner.

    Every view of a lent buffer (a memoryview, a numpy array made from one) keeps its ctypes array alive. With ours
    released, the list, the comprehension's variable and getrefcount's argument must be the only references left;
    otherwise something still reads the buffer, and giving it back would let that read freed (or rewritten) memory:
    keep it (a leak) and say so.
    """
    for view in views:
        view.release()
    views.clear()
    if any(count > 3 for count in [sys.getrefcount(array) for array in arrays]):
        raise RuntimeError(f"{what} is still in use after its 'with' block; copy it first ({copy_hint}) to keep it")
    arrays.clear()


class LentSamples:
    """Samples taken in one call whose ``data`` are views of Cyclone's buffers, valid inside a ``with`` block.

    Leaving the block releases the views (using one afterwards raises ValueError instead of reading freed memory)
    and returns the buffers to Cyclone.
    """

    def __init__(self, samples: list[RawSample], release: Callable[[], None] | None = None):
        self.samples = samples
        self._release = release

    def __enter__(self) -> list[RawSample]:
        return self.samples

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._release is not None:
            release, self._release = self._release, None
            release()


class RawReader:
    """Takes serialized samples from a DataReader of any type, never deserializing their data (on the tested
    Cyclone version; see :mod:`automotive.cyclone.serdata`)."""

    def __init__(self, reader: DataReader[Any], zero_copy: bool = True):
        self.reader = reader
        self.data_type: type[Any] = reader.topic.data_type
        self.data_type.__idl__.populate()  # Cyclone Python works out a type's keys on first use
        self._keyless = bool(self.data_type.__idl__.keyless)
        self._lender = serdata.lender() if zero_copy else None
        self._writer_names = WriterNames(reader)

    @property
    def zero_copy(self) -> bool:
        return self._lender is not None

    def samples_of(self, data: Buffer, info: Any, whole_key_sample: bool = False) -> list[RawSample]:
        """The sample(s) one taken sample stands for.

        A disposal or unregistration that arrives while its instance still holds unread data produces no sample of
        its own: Cyclone changes the instance state of that data instead. The newest sample of such an instance
        (sample rank 0) is therefore followed by the state change, carrying the data's key and timestamp."""
        stamp, writer, instance, state = (info.source_timestamp, signed_handle(info.publication_handle),
                                          signed_handle(info.instance_handle), info.instance_state)
        if not info.valid_data:
            if whole_key_sample:
                key = bytes(data)
            else:
                try:
                    key = key_to_sample(self.data_type, data) if data or self._keyless else b""
                except Exception as error:  # a key our types cannot hold (a string that is not UTF-8): reported
                    problem = undecodable(error, f"a key that decodes as {type_name(self.data_type)}")
                    reporter = getattr(self.reader, "reporter", None) or badsamples.reporter()
                    reporter.report(self.reader.topic.get_name(), problem, self._writer_names.describe(writer))
                    return []
            return [RawSample(key, _state_change(state), stamp, writer, instance, state)]
        samples = [RawSample(data, SampleKind.DATA, stamp, writer, instance, state)]
        if state != InstanceState.Alive and info.sample_rank == 0:
            samples.append(RawSample(bytes(data), _state_change(state), stamp, writer, instance, state))
        return samples

    def take(self, limit: int = 64) -> list[RawSample]:
        """Take up to ``limit`` samples, each with its own copy of the bytes."""
        samples = []
        for taken in serdata.take(self.reader, limit):
            samples.extend(self.samples_of(taken.data, taken.info, taken.whole_key_sample))
        return samples

    def drain(self, limit: int = 64) -> Iterator[tuple[RawSample, int]]:
        """Take until the reader is empty, yielding each sample with its reception time (ns since the epoch: when
        the batch it came in was taken)."""
        while True:
            samples = self.take(limit)
            if not samples:
                return
            receive_ns = time.time_ns()
            for sample in samples:
                yield sample, receive_ns

    def lend(self, limit: int = 16) -> LentSamples:
        """Take up to ``limit`` samples lending Cyclone's buffers: ``with reader.lend() as samples: ...``.

        Cyclone lends no key with a disposal or unregistration: for a keyed type its data is then empty (use
        :meth:`take` where the key matters). Without a lender (see :mod:`automotive.cyclone.serdata`) the samples
        are taken with a copy."""
        if self._lender is None:
            return LentSamples(self.take(limit))
        buffers, give_back = self._lender.lend(self.reader, limit)
        samples: list[RawSample] = []
        arrays: list[ctypes.Array[ctypes.c_char]] = []
        views: list[memoryview] = []

        def release() -> None:
            for sample in samples:
                if isinstance(sample.data, memoryview):
                    sample.data.release()
            release_lent_views(views, arrays, "a lent sample's data", "bytes(sample.data)")
            give_back()

        try:
            self._view_lent(buffers, samples, arrays, views)
        except BaseException:
            buffers.clear()
            release()
            raise
        return LentSamples(samples, release)

    def _view_lent(self, buffers: list[serdata.LentBuffer], samples: list[RawSample],
                   arrays: list[ctypes.Array[ctypes.c_char]], views: list[memoryview]) -> None:
        """Views of the lent buffers; ``arrays`` and ``views`` become the only holders of them (a function of its
        own, so that no loop variable keeps a buffer alive past the release check)."""
        for buffer in buffers:
            if buffer.array is not None:
                arrays.append(buffer.array)
                views.append(memoryview(buffer.array).cast("B"))
                samples.extend(self.samples_of(views[-1], buffer.info))
            else:  # a disposal or unregistration: Cyclone lends no key
                samples.extend(self.samples_of(b"", buffer.info))
        buffers.clear()


class RawWriter:
    """Writes serialized samples (CDR with its encapsulation header) through a DataWriter of their type.

    Cyclone copies the bytes into its own sample before returning. Without ``timestamp`` the source timestamp is
    now; with it (ns since the epoch), that one.
    """

    def __init__(self, writer: DataWriter[Any]):
        self.writer = writer

    def write(self, data: Buffer, timestamp: int | None = None) -> None:
        serdata.write(self.writer, data, timestamp)

    def dispose(self, data: Buffer, timestamp: int | None = None) -> None:
        """Dispose the instance whose key ``data`` (a whole serialized sample) holds."""
        serdata.dispose(self.writer, data, timestamp)

    def unregister(self, data: Buffer, timestamp: int | None = None) -> None:
        """Unregister the instance whose key ``data`` (a whole serialized sample) holds."""
        serdata.unregister(self.writer, data, timestamp)

    def put(self, sample: RawSample, timestamp: int | None = None) -> None:
        """Write, dispose or unregister, as ``sample.kind`` says."""
        {SampleKind.DATA: self.write, SampleKind.DISPOSE: self.dispose,
         SampleKind.UNREGISTER: self.unregister}[sample.kind](sample.data, timestamp)
