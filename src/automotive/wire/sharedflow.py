"""One large flow of an application (camera frames, LiDAR clouds) over shared memory and DDS at once.

:class:`FlowWriter` and :class:`FlowReader` put together what :mod:`automotive.wire.shm` provides for one endpoint of
an :class:`~automotive.bus.app.Application`: the DDS endpoint with the role's QoS profile (marked with the locality's
USER_DATA when shared memory is used), the iceoryx2 port, which of the matched peers shared memory serves, the
deadline of the samples that come through it, the console's traffic counts and the latency of the samples taken
(automotive.bus.latency.recent, as the checked readers record theirs). The applications and tools write
and read serialized samples (CDR, as DDS carries them) through them and never ask which way a sample goes.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, TypeVar

from cyclonedds.core import GuardCondition, WaitSet
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Qos
from cyclonedds.sub import DataReader

from automotive.bus import console, latency
from automotive.bus.app import Application
from automotive.bus.checkedreader import CheckedReader
from automotive.bus.status import EventHook
from automotive.cyclone import serdata
from automotive.cyclone.matched import matched_publications, matched_subscriptions
from automotive.wire import shm
from automotive.wire.rawsample import RawWriter

T = TypeVar("T")
LOCAL_FIRST_S = 0.005  # the longest a DDS write waits for the shared-memory readers to release the sample


def _listener_report(endpoint: DataWriter[Any] | DataReader[Any], event: str) -> Callable[[Any], None]:
    """A deadline status reported through the endpoint's own status listener, as Cyclone reports one."""
    def report(status: Any) -> None:
        listener = endpoint.get_listener()
        handler = getattr(listener, f"on_{event}", None)
        if handler is not None:
            handler(endpoint, status)
    return report


P = TypeVar("P", shm.SharedWriter, shm.SharedReader)


class _SharedEnd:
    """What a flow's writer and reader share: the topic's shared memory and this process's port in it, or neither
    when shared memory cannot be used (``config.transport=udp``, no room in /dev/shm, iceoryx2 refusing)."""

    memory: shm.SharedMemory | None
    shared: Any

    def _open(self, app: Application, topic: str, port: Callable[[shm.SharedMemory], P]) -> P | None:
        self.memory = shm.open_for(app.props, app.name, app.domain_id, topic, app.log)
        if self.memory is None:
            return None
        try:
            return port(self.memory)
        except shm.Unavailable as error:
            self.memory.close()
            self.memory = None
            shm.unavailable(app.props, topic, str(error), app.log)
            return None

    @property
    def user_data(self) -> tuple[Any, ...]:
        """The policies that mark the DDS endpoint as this locality's (none without shared memory)."""
        return (self.memory.user_data,) if self.memory is not None else ()

    @property
    def key(self) -> str | None:
        return self.memory.key if self.memory is not None else None

    def close(self) -> None:
        if self.shared is not None:
            self.shared.close()
            self.shared = None
        if self.memory is not None:
            self.memory.close()
            self.memory = None


class FlowWriter(_SharedEnd):
    """The writer of a large flow: shared memory to this host's subscribers, DDS to every other reader.

    ``max_length`` bounds a serialized sample (the publisher's slots are that big). Shared memory that cannot be used
    (``config.transport=udp``, no room in /dev/shm, iceoryx2 refusing) leaves a plain DDS writer.
    """

    def __init__(self, app: Application, role: str, data_type: type[T], default_topic: str, max_length: int,
                 hook: EventHook | None = None):
        self.app = app
        self.topic = app.topic_name(role, default_topic)
        qos = app.profiles.writer_qos(app.library, app.profile(role))
        self.shared: shm.SharedWriter | None = self._open(
            app, self.topic, lambda memory: shm.SharedWriter(memory, max_length, qos, lambda: not app.interrupted))
        self.dds_readers = shm.DdsReaders(self.key)

        def on_event(event: str, topic: str, status: Any) -> None:
            self.dds_readers.hook(event, topic, status)
            if hook is not None:
                hook(event, topic, status)

        self.writer: DataWriter[Any] = app.writer(role, data_type, default_topic, on_event, self.user_data)
        self.dds_readers.writer = self.writer
        self.raw = RawWriter(self.writer)
        # The offered deadline of samples that go through shared memory only (DDS watches those it writes).
        self.deadline = shm.DeadlineWatch(shm.deadline_s(qos), _listener_report(self.writer, "offered_deadline_missed"))
        self.sent_shared = 0  # samples sent through shared memory
        self.sent_dds = 0  # samples written on DDS
        # The last sample written on DDS by publish_sample, while its instance is registered there: once no reader
        # outside shared memory is left, the instance is unregistered, or the DDS readers of this host (which drop
        # its samples) would see their deadline missed while its samples come on through shared memory.
        self._registered: bytes | None = None

    @property
    def subscribers(self) -> int:
        """Readers of the flow: DDS readers matched, plus shared-memory subscribers of readers without DDS."""
        return len(matched_subscriptions(self.writer))

    def publish(self, length: int, fill: Callable[[memoryview], int], write_dds: Callable[[int | None], int]) -> int:
        """Publish one sample: ``fill(view)`` writes its ``length`` serialized bytes into shared memory and returns
        its source timestamp (ns); ``write_dds(stamp)`` writes the same bytes on DDS, with that source timestamp
        (None: it stamps them itself), and returns the timestamp. Return the timestamp (now when nobody reads it).

        With subscribers in shared memory and DDS readers both, the shared sample is sent first, and the sample is
        written on DDS once the subscribers released it (at most LOCAL_FIRST_S later), from the caller's own bytes
        (never from the loan, which is the subscribers' once sent): a DDS reader joining on the host (another vendor,
        a tool) costs the shared-memory readers no latency."""
        dds_readers = self.dds_readers.count()
        if not dds_readers:
            self._unregister()
        shared = self.shared
        if shared is not None and shared.subscribers:
            stamp = shared.publish(length, fill)
            self.sent_shared += 1
            if dds_readers:
                # The DDS write (a 4 MiB copy, its UDP fragments, the DDS readers' reception) would compete for the
                # CPU with the local readers' wake-up: it waits until they have the sample, a few ms at most.
                shared.wait_consumed(LOCAL_FIRST_S)
                write_dds(stamp)
                self.sent_dds += 1
        elif dds_readers:
            stamp = write_dds(None)
            self.sent_dds += 1
        else:
            stamp = time.time_ns()
        console.traffic.count_out(self.topic)  # samples bypass the checked writer: counted here
        if not dds_readers:
            self.deadline.check()
        self.deadline.sample(None)
        return stamp

    def _unregister(self) -> None:
        if self._registered is not None:
            self.raw.unregister(self._registered)
            self._registered = None

    def has_readers(self) -> bool:
        """Whether anyone reads the flow now (in shared memory or on DDS): without, a sample need not be serialized."""
        return bool((self.shared is not None and self.shared.subscribers) or self.dds_readers.count())

    def publish_sample(self, sample: Any) -> int:
        """Publish a sample object: serialized once, the same bytes in shared memory and on DDS, and not at all
        while nobody reads the flow; return its source timestamp (ns)."""
        if not self.has_readers():
            self._unregister()
            console.traffic.count_out(self.topic)
            return time.time_ns()
        return self.publish_serialized(self.serialize(sample))

    def serialize(self, sample: Any) -> bytes:
        """``sample`` serialized as this flow sends it (its writer's data representation)."""
        return serdata.serialize(self.writer, sample)

    def publish_serialized(self, data: bytes | bytearray | memoryview) -> int:
        """Publish a serialized sample (as :func:`automotive.cyclone.serdata.serialize` makes it), the same bytes in
        shared memory and on DDS; return its source timestamp (ns). The caller may reuse ``data`` afterwards."""

        # Stamped as DDS stamps a write, once the sample is serialized: here once it is in the loaned memory too.
        def fill(view: memoryview) -> int:
            view[:] = data
            return time.time_ns()

        def write_dds(stamp: int | None) -> int:
            stamp = time.time_ns() if stamp is None else stamp
            self.raw.write(data, stamp)
            return stamp

        written = self.sent_dds
        stamp = self.publish(len(data), fill, write_dds)
        if self.sent_dds > written and self._registered is None:  # any sample of the instance unregisters it
            self._registered = bytes(data)
        return stamp


class FlowReader(_SharedEnd):
    """The reader of a large flow: a DDS reader (marked when shared memory is used) and a shared-memory subscriber,
    woken by one WaitSet. DDS samples of writers on this host's shared memory are dropped (:meth:`from_shared`):
    they came through shared memory. A checked reader drops them itself, before decoding or counting them."""

    def __init__(self, app: Application, topic: str, reader_qos: Qos,
                 make_reader: Callable[[tuple[Any, ...]], DataReader[Any]]):
        """The flow of ``topic``, whose DDS reader (with ``reader_qos``) ``make_reader(overrides)`` creates with the
        given policies in place of its profile's (the locality's USER_DATA). :meth:`of_role` serves applications."""
        self.app = app
        self.topic = topic
        self.shared: shm.SharedReader | None = self._open(app, topic,
                                                          lambda memory: shm.SharedReader(memory, reader_qos))
        self.reader = make_reader(self.user_data)
        self.local = shm.LocalWriters(self.reader, self.key)
        if isinstance(self.reader, CheckedReader) and self.key is not None:
            # the DDS copies of this host's shared-memory writers' samples: dropped before they are decoded or counted
            self.reader.skip_writers(self.from_shared)
        self.guard = GuardCondition(app.bus.participant)  # set by the shared memory's wake thread (attach)
        self.deadline = shm.DeadlineWatch(shm.deadline_s(reader_qos),
                                          _listener_report(self.reader, "requested_deadline_missed"))

    @classmethod
    def of_role(cls, app: Application, role: str, data_type: type[T], default_topic: str,
                hook: EventHook | None = None, optional: bool = False) -> FlowReader:
        """The flow an application reads as ``role`` (its topic and QoS profile from its properties)."""
        return cls(app, app.topic_name(role, default_topic), app.profiles.reader_qos(app.library, app.profile(role)),
                   lambda overrides: app.reader(role, data_type, default_topic, hook, optional, overrides))

    @property
    def depth(self) -> int | None:
        return self.shared.depth if self.shared is not None else None

    def waitset(self, *others: DataReader[Any]) -> WaitSet:
        """The application's WaitSet for this flow's DDS reader, its shared memory, and ``others``."""
        waitset = self.app.waitset(self.reader, *others)
        self.attach(waitset)
        return waitset

    def attach(self, waitset: WaitSet) -> None:
        """Have ``waitset`` woken by samples in shared memory too (through :attr:`guard`, set by a thread that waits
        on shared memory)."""
        if self.shared is not None:
            self.shared.wake(self.guard)
        waitset.attach(self.guard)

    def shared_first_waitset(self) -> WaitSet | shm.SharedFirstWaitSet:
        """For a flow whose samples come through shared memory (its DDS samples come from other hosts, or from a
        tool that writes on DDS): the taking thread waits on shared memory itself, woken once by a sample as a plain
        iceoryx2 subscriber is; the DDS reader and the stop signal wake it through a thread of their own. Without
        shared memory, :meth:`waitset`."""
        if self.shared is None:
            return self.waitset()
        return shm.SharedFirstWaitSet(self.shared, self.app.waitset(self.reader))

    def from_shared(self, writer_handle: int) -> bool:
        """A DDS sample of this writer came through shared memory too: drop it."""
        return self.local.is_local(writer_handle)

    def take_shared(self, limit: int = 16) -> shm.LentShared:
        """Samples from shared memory (none without it), valid inside ``with flow.take_shared() as samples:``."""
        if self.shared is None:
            return shm.LentShared([], lambda: None)
        if self.shared.wakes:
            self.guard.take()
        lent = self.shared.take(limit)
        if lent.samples:
            self.deadline.sample(None)
            console.traffic.count_in(self.topic, len(lent.samples))  # bypass the checked reader: counted here
            latency.recent.record(self.topic, self.local.shared_writer(), [s.source_timestamp for s in lent.samples])
        return lent

    def check_deadline(self) -> None:
        """Report a missed deadline of the shared-memory samples (call after each wake-up)."""
        # No writer left (it stopped, or DDS found it dead when its lease ended): no instance is expected any more,
        # as DDS stops watching an instance without writers. Asked only of a miss: the question is two calls into
        # Cyclone, and the LiDAR's reader comes here 20 times a second.
        if not self.deadline.overdue():
            return
        if not self.memory_publishers() or not matched_publications(self.reader):
            self.deadline.forget()
        self.deadline.check()

    def memory_publishers(self) -> int:
        return self.memory.publishers if self.memory is not None else 0
