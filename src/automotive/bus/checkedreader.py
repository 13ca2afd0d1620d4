"""The checked take: every sample decoded on its own and checked before the application sees it.

Cyclone Python's ``DataReader.take`` deserializes a whole batch in one loop; one sample it cannot decode (a string
that is not UTF-8, say) raises out of ``take`` and out of the application's loop, and the good samples of that batch
are lost with it. :class:`CheckedReader` (every reader the runtime creates, automotive.bus.endpoints) takes the
serialized samples instead and, for each one:

1. decodes it with the type's decoder (:func:`decoder`: Cyclone's deserializer unless another one is registered with
   :func:`set_decoder`, one replaceable function per type);
2. checks it (automotive.bus.validation: finite floats, well-formed timestamps, the type's semantic rule);
3. hands it to the application if both passed; otherwise reports it once per kind (automotive.bus.badsamples: topic,
   writer, member, value, what was expected) and leaves it out. A bad sample that also says its instance was disposed
   or lost its writers still passes that on, as a sample without data (``InvalidSample`` with ``valid_data`` false,
   as Cyclone gives a disposal), so no state change is lost; its ``key_sample`` is None when not even the key decodes.

Applications keep calling ``reader.take(N=...)`` and filtering ``isinstance(sample, Type)``; a take never raises for
what a remote writer sent.

Each take also records the latency of the samples it gives (its one clock read minus each writer's source timestamp,
per writer participant: :func:`record_latencies`), which /diagnostics reports (automotive.bus.latency.recent), and
counts them (automotive.bus.console.traffic). Inside :func:`deferred_bookkeeping` (an application's wake-up loop,
automotive.bus.app) both wait, with the take's clock read, until the application has written what the samples made:
after an idle wake-up every piece of Python costs several times its warm price, and the next hop of a chain waits for
none of it (docs/measurements/alert-latency.md).

:meth:`CheckedReader.use_views` makes one reader decode its sequences of fixed-size structs (the vision objects, the
fused object list) as read-only numpy structured arrays with the generated codec (automotive.cyclone.codecs), without
one Python object per element; their float fields are checked in bulk (automotive.bus.validation).
"""

from __future__ import annotations

import dataclasses
import struct
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsParticipant
from cyclonedds.core import InstanceState
from cyclonedds.qos import Policy
from cyclonedds.sub import DataReader, InvalidSample

from automotive.bus import badsamples, console, latency, validation
from automotive.bus.badsamples import BadSample, BadSampleReporter
from automotive.cyclone import codec_hook, serdata
from automotive.cyclone.bounds import type_name
from automotive.cyclone.codecs import codec_for

T = TypeVar("T")
Decoder = Callable[[bytes], Any]

_DECODERS: dict[type, Decoder] = {}
_WRITER_CACHE = 64  # writer descriptions kept per reader; cleared when full (a writer is looked up again, no more)
_PARTICIPANT_CACHE = 1024  # participant names kept per reader, the same way
_DEFERRED_TAKES = 64  # takes whose bookkeeping waits, at most; beyond, it is done at once (a loop that never flushes)


def set_decoder(data_type: type, decode: Decoder | None) -> None:
    """Decode samples of ``data_type`` with ``decode`` (serialized bytes, encapsulation header included, to a
    sample); None restores Cyclone's deserializer. A decoder raises any Exception for bytes it cannot decode."""
    if decode is None:
        _DECODERS.pop(data_type, None)
    else:
        _DECODERS[data_type] = decode


def decoder(data_type: type) -> Decoder:
    """The decoder of a type: the registered one, else Cyclone's ``data_type.deserialize``."""
    return _DECODERS.get(data_type) or data_type.deserialize  # type: ignore[attr-defined]


def undecodable(error: Exception, what: str) -> BadSample:
    return BadSample("", f"undecodable ({type(error).__name__}: {error})", what)


def format_guid(guid: Any) -> str:
    """A GUID as Cyclone prints it in its own log lines (four 32-bit words in hex): ``10f7f01:c848d0dd:0:103``."""
    return ":".join(f"{word:x}" for word in struct.unpack(">4I", guid.bytes))


def _cached(cache: dict[int, str], handle: int, look_up: Callable[[int], str]) -> str:
    """``look_up(handle)``, kept in ``cache`` for at most _WRITER_CACHE writers (cleared when full: a writer is
    looked up again, no more)."""
    text = cache.get(handle)
    if text is None:
        if len(cache) >= _WRITER_CACHE:
            cache.clear()
        text = cache[handle] = look_up(handle)
    return text


class WriterNames:
    """Describes the writers of a reader's samples: GUID, the writer's entity name and its participant's name
    (from discovery data, looked up when first needed and kept for a bounded number of writers)."""

    def __init__(self, reader: DataReader[Any]):
        self.reader = reader
        self._names: dict[int, str] = {}
        self._writer_participants: dict[int, str] = {}  # writer handle -> its participant's name (latencies)
        self._participants: BuiltinDataReader | None = None
        self._participant_names: dict[Any, str] = {}  # participant key -> name, from the samples taken so far

    def describe(self, handle: int) -> str:
        return _cached(self._names, handle, self._look_up)

    def participant(self, handle: int) -> str:
        """The name of the participant of a writer (its GUID prefix when it has no name; "unknown" when gone)."""
        return _cached(self._writer_participants, handle, self._participant_of)

    def _endpoint(self, handle: int) -> Any:
        """The writer's discovery data; None when it is no longer matched or cannot be read."""
        try:
            return self.reader.get_matched_publication_data(handle)
        except Exception:  # Cyclone's error, or discovery data it cannot decode (a name that is not UTF-8)
            return None

    def _participant_of(self, handle: int) -> str:
        endpoint = self._endpoint(handle)
        if endpoint is None:
            return "unknown"
        return self._participant_name(endpoint.participant_key) or format_guid(endpoint.participant_key)

    def _look_up(self, handle: int) -> str:
        endpoint = self._endpoint(handle)
        if endpoint is None:
            return f"writer {handle & 0xFFFFFFFFFFFFFFFF:x} (no longer matched)"
        text = f"writer {format_guid(endpoint.key)}"
        if Policy.EntityName in endpoint.qos:
            text += f" '{endpoint.qos[Policy.EntityName].name}'"
        participant = self._participant_name(endpoint.participant_key)
        return text + (f" of participant '{participant}'" if participant else "")

    def _participant_name(self, key: Any) -> str:
        # Taken, not read: the built-in reader then holds only what arrived since the last lookup, and participants
        # that come and go do not pile up in it; the names are kept here, bounded.
        try:
            if self._participants is None:
                self._participants = BuiltinDataReader(self.reader.participant, BuiltinTopicDcpsParticipant)  # type: ignore[arg-type]
            for participant in self._participants.take(N=256):
                known = getattr(participant, "key", None)
                if not participant.sample_info.valid_data:  # a participant that left (only its key): its name goes
                    self._participant_names.pop(known, None)
                    continue
                if known is not None and Policy.EntityName in participant.qos:
                    if len(self._participant_names) >= _PARTICIPANT_CACHE:  # a bound, should many never leave
                        self._participant_names.clear()
                    self._participant_names[known] = str(participant.qos[Policy.EntityName].name)
        except Exception:  # Cyclone's error, or a participant's discovery data it cannot decode
            pass
        return self._participant_names.get(key, "")


class CheckedReader(DataReader[T]):
    """A DataReader whose take and read give only samples that decode and pass their type's checks (see the module's
    doc); the others are reported and left out."""

    def __init__(self, *args: Any, reporter: BadSampleReporter | None = None, **kwargs: Any):
        self.reporter = reporter  # None: the process's reporter
        self._writer_names = WriterNames(self)
        self._views_decoder: Decoder | None = None  # use_views()
        self._skip_writer: Callable[[int], bool] | None = None  # skip_writers()
        super().__init__(*args, **kwargs)

    @property
    def writer_names(self) -> WriterNames:
        """The names of this reader's writers and of their participants, as the reader knows them."""
        return self._writer_names

    def skip_writers(self, skip: Callable[[int], bool]) -> None:
        """Leave out, before decoding and uncounted, the data of the writers (publication handles) for which
        ``skip`` is true: the DDS copies of samples that reached this process another way (shared memory)."""
        self._skip_writer = skip

    def use_views(self) -> CheckedReader[T]:
        """Give this reader's samples with their sequences of fixed-size structs as read-only numpy structured
        arrays (``codec.element_dtype(member)``); the type must have a generated codec with such members."""
        codec = codec_for(self.topic.data_type)
        if codec is None or not codec.view_members:
            raise ValueError(f"{type_name(self.topic.data_type)} has no sequence of fixed-size structs to view")
        if codec_hook.installed(self.topic.data_type):
            self._views_decoder = lambda data: codec.decode(data, views=True)
        else:  # the codecs are not plugged in (AUTOMOTIVE_CODECS=off): Cyclone's deserializer, then converted
            deserialize = decoder(self.topic.data_type)
            self._views_decoder = lambda data: codec.with_views(deserialize(data))
        self._codec = codec
        return self

    def take(self, N: int = 1, condition: Any = None, instance_handle: int | None = None) -> list[Any]:
        fetched = serdata.fetch(self, True, N, condition, instance_handle)
        if fetched is None:  # Cyclone's public take, one sample at a time: one that cannot be decoded is lost alone
            samples: list[Any] = []
            for _ in range(N):  # at most N takes of one: a take that keeps failing cannot spin for ever
                batch = self._public(super().take, 1, condition, instance_handle)
                if batch is None:
                    break
                samples += batch
        else:
            samples = self._checked(fetched)
        if samples:
            now = time.time_ns()
            pending = _bookkeeping.pending
            if _bookkeeping.deferring and len(pending) < _DEFERRED_TAKES:
                pending.append((self, tuple(samples), now))
            else:
                self._book(samples, now)
        return samples

    def _book(self, samples: tuple[Any, ...] | list[Any], now_ns: int) -> None:
        """Count a take's samples and record their latencies as of ``now_ns``, the take's clock read."""
        console.traffic.count_in(self.topic.name, sum(not isinstance(sample, InvalidSample) for sample in samples))
        record_latencies(self.topic.name, samples, self._writer_names, now_ns)

    def read(self, N: int = 1, condition: Any = None, instance_handle: int | None = None) -> list[Any]:
        fetched = serdata.fetch(self, False, N, condition, instance_handle)
        if fetched is None:
            return self._public(super().read, N, condition, instance_handle) or []
        return self._checked(fetched)

    def _public(self, fetch: Callable[..., list[Any]], count: int, condition: Any,
                instance_handle: int | None) -> list[Any] | None:
        """Cyclone's public take or read, checked (the version gate is closed); None when nothing was there."""
        try:
            fetched = fetch(N=count, condition=condition, instance_handle=instance_handle)
        except Exception as error:  # Cyclone's deserializer failed on a sample of the batch: the batch is gone
            self._report_undecodable(error)
            return []
        if not fetched:
            return None
        samples: list[Any] = []
        skip = self._skip_writer
        for sample in fetched:
            if isinstance(sample, InvalidSample):
                samples.append(sample)
                continue
            if skip is not None and skip(sample.sample_info.publication_handle):
                continue  # came another way (Cyclone decoded it already: the gate is closed)
            if self._views_decoder is not None:  # the gate is closed: views made from Cyclone's dataclasses
                info = sample.sample_info
                try:
                    sample = self._codec.with_views(sample)
                except Exception as error:  # a sample the views cannot hold is a bad sample, not a crash
                    self._report_undecodable(error, info)
                    if info.instance_state != InstanceState.Alive:
                        samples.append(ended_instance(None, info))
                    continue
                sample.sample_info = info
            problem = validation.check(sample)
            if problem is None:
                samples.append(sample)
                continue
            self.report(problem, sample.sample_info)
            if sample.sample_info.instance_state != InstanceState.Alive:
                samples.append(ended_instance(sample, sample.sample_info))
        return samples

    def _checked(self, fetched: list[tuple[bytes, Any]]) -> list[Any]:
        data_type = self.topic.data_type
        decode = self._views_decoder or decoder(data_type)
        samples: list[Any] = []
        skip = self._skip_writer
        for data, info in fetched:
            if skip is not None and info.valid_data and skip(info.publication_handle):
                continue  # came another way: never decoded
            if not info.valid_data:
                samples.append(InvalidSample(self._key(data, info), info))
                continue
            sample: Any = None
            try:
                sample = decode(data)
            except Exception as error:  # whatever a decoder raises for bytes it cannot decode
                self._report_undecodable(error, info)
                if info.instance_state != InstanceState.Alive:  # the instance's end is news the application needs
                    samples.append(ended_instance(self._key(data, info, report=False), info))
                continue
            problem = validation.check(sample)
            if problem is None:
                sample.sample_info = info
                samples.append(sample)
                continue
            self.report(problem, info)
            if info.instance_state != InstanceState.Alive:
                samples.append(ended_instance(sample, info))
        return samples

    def _key(self, data: bytes, info: Any, report: bool = True) -> Any:
        """The key of a disposal or unregistration (None, reported, when it cannot be decoded)."""
        data_type = self.topic.data_type
        try:
            return data_type.deserialize_key(data)  # type: ignore[attr-defined]
        except Exception as error:  # as for samples: one bad key never breaks a take
            if report:
                self.report(undecodable(error, f"a key that decodes as {type_name(data_type)}"), info)
            return None

    def _report_undecodable(self, error: Exception, info: Any = None) -> None:
        problem = undecodable(error, f"a sample that decodes as {type_name(self.topic.data_type)}")
        # info None: a whole batch failed in Cyclone's take, no sample says which writer
        report_bad_sample(self, self._writer_names, problem, None if info is None else info.publication_handle)

    def report(self, problem: BadSample, info: Any, action: str = "ignored") -> None:
        """Report a bad sample of this reader (found by the reader, or by the application: a rule of its own)."""
        report_bad_sample(self, self._writer_names, problem, info.publication_handle, action)


def report_bad_sample(reader: DataReader[Any], writer_names: WriterNames, problem: BadSample, writer: int | None,
                      action: str = "ignored") -> None:
    """Report a bad sample of ``reader`` to its own reporter (``reader.reporter``) or else the process's, naming the
    writer that sent it (``writer``, an instance handle; None: not known)."""
    reporter = getattr(reader, "reporter", None) or badsamples.reporter()
    sender = "a writer" if writer is None else writer_names.describe(writer)
    reporter.report(reader.topic.get_name(), problem, sender, action)


class _Bookkeeping(threading.local):
    """One thread's takes whose counts and latencies wait (:func:`deferred_bookkeeping`)."""

    def __init__(self) -> None:
        self.deferring = False
        self.pending: list[tuple[CheckedReader[Any], tuple[Any, ...], int]] = []

    def flush(self) -> None:
        pending, self.pending = self.pending, []
        for reader, samples, now_ns in pending:
            reader._book(samples, now_ns)


_bookkeeping = _Bookkeeping()


@contextmanager
def deferred_bookkeeping() -> Iterator[Callable[[], None]]:
    """Within, this thread's takes leave their counts and latencies (measured at the take) to the function it gives,
    which the caller calls once it has written its outputs; at the end, what is left is done. Other threads' takes
    are booked at once."""
    _bookkeeping.deferring = True
    try:
        yield _bookkeeping.flush
    finally:
        _bookkeeping.deferring = False
        _bookkeeping.flush()


def record_latencies(topic: str, samples: tuple[Any, ...] | list[Any], writer_names: WriterNames,
                     now_ns: int) -> None:
    """Record the latency of the samples of one take (automotive.bus.latency.recent), per writer participant, with
    one clock read: ``now_ns``, the take's."""
    by_writer: dict[int, list[int]] = {}
    for sample in samples:
        info = sample.sample_info
        if info.valid_data:
            by_writer.setdefault(info.publication_handle, []).append(info.source_timestamp)
    for handle, stamps in by_writer.items():
        latency.recent.record(topic, writer_names.participant(handle), stamps, now_ns)


def ended_instance(key: Any, info: Any) -> InvalidSample:
    """The end of an instance whose last sample was bad, as a sample without data: ``valid_data`` false (consumers
    test it before they read data members), the key (or the bad sample: its key members) when it decoded, else None."""
    return InvalidSample(key, dataclasses.replace(info, valid_data=False))
