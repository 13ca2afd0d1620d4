"""Large samples through shared memory on one host (iceoryx2), beside DDS, chosen per flow without a property.

``config.transport``: ``auto`` (the default) uses shared memory with the readers and writers on this host and DDS
with every other one; ``udp`` uses DDS only; ``shm`` is ``auto`` that stops with one line when shared memory cannot
be used. No Cyclone DDS build installable here moves Python samples through shared memory
(docs/measurements/cyclone-shared-memory.md), so this transport sits beside DDS rather than inside it, the way RTI's
Zero Copy does for a same-host reader:

* **Who is on this host.** Processes share shared memory when they share the boot, the network namespace, the
  ``/dev/shm`` file system and the file prefix (:func:`locality_key`). Each shared-memory endpoint says so in its DDS
  endpoint's USER_DATA (``automotive.shm:<key>``), and its iceoryx2 service carries the same key in its name
  (:func:`service_name`), so only endpoints of one locality ever meet in shared memory.
* **The writer** sends every sample through shared memory when a same-host subscriber is there, and writes it on DDS
  only while a DDS reader without its key is matched (:class:`DdsReaders`: another host, another vendor, a tool):
  with none, nothing is serialized or sent on UDP. Its DDS writer stays, with its QoS, so that readers match,
  liveliness is watched and late readers anywhere are served.
* **A reader** keeps its DDS reader (marked with its key) and drops DDS samples of writers of its own locality
  (:class:`LocalWriters`): those samples came through shared memory already, so no sample arrives twice.
* The shared-memory sample holds exactly the bytes of the DDS sample (encapsulation and all); its iceoryx2 user header
  (:class:`SampleHeader`) carries the source timestamp, as DDS's sample info does.
* **QoS kept.** A subscriber keeps the last ``depth`` samples (history depth, or ``max_samples_per_instance`` for
  keep-all); an older one is overwritten (``enable_safe_overflow``) and shows up as a gap. A reliable keep-all writer
  whose subscribers hold a full window of unconsumed samples waits until half of them are consumed, at most
  ``max_blocking_time``: the flow control of a reliable DDS stream. iceoryx2's own blocking back-pressure is not
  used: it holds the GIL while it waits and never returns once a subscriber died. Deadlines are watched for the
  samples that come through shared memory (:class:`DeadlineWatch`) and reported as DDS reports them.
* Stale files of processes that died without cleaning up (SIGKILL) are removed when a node starts; a clean stop
  removes ours. ``/dev/shm`` missing, unwritable or without room for a publisher's samples: DDS with one line.

iceoryx2's Python API changes between releases: pyproject.toml pins 0.10.0, which this module was written against.
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import os
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import iceoryx2 as iox2
from cyclonedds.core import GuardCondition, WaitSet
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader

from automotive.bus.checkedreader import CheckedReader, WriterNames
from automotive.bus.errors import ConfigError
from automotive.bus.properties import Properties
from automotive.cyclone.matched import matched_publications, matched_subscriptions
from automotive.wire.rawsample import release_lent_views

TRANSPORTS = ("auto", "shm", "udp")
DEFAULT_PREFIX = "iox2_"  # iceoryx2's own default prefix
SHM_ROOT = Path("/dev/shm")  # where iceoryx2 keeps its segments on Linux
MAX_SUBSCRIBERS = 8  # a topic's same-host subscribers: redundant fusion twice, a viewer, a recorder, a bridge, ...
MAX_DEPTH = 8  # per subscriber; the publisher's segment holds about MAX_SUBSCRIBERS * (MAX_DEPTH + 2) samples
DEFAULT_DEPTH = 8  # keep-all without a resource limit
BORROWED = 2  # samples a subscriber holds at once (it releases each after using it)
ACK_IDS = 4096  # "consumed" event ids are sequence numbers modulo this; a window never comes near it
SAMPLE_SENT, LEAVING = 0, 1  # event ids of the publisher's notifications
WAIT_SLICE_S = 0.2  # longest single wait, so that a stop signal is noticed promptly
# How often a subscriber looks up which participants write through shared memory, for its latencies' label: a lookup
# asks Cyclone for the reader's matched writers, a call that at every take came before the application had the sample.
WRITER_LOOK_S = 1.0
USER_DATA_TAG = b"automotive.shm:"

_log = logging.getLogger(__name__)


class Unavailable(Exception):
    """Shared memory cannot be used here (no /dev/shm, no room, iceoryx2 refused): DDS carries the flow."""


class SampleNotSent(Exception):
    """A sample that was not published (the application stopped while flow control held it back)."""


class SampleHeader(ctypes.Structure):
    """The iceoryx2 user header of every sample: what DDS's sample info would say about it."""

    _fields_ = [("source_timestamp", ctypes.c_int64),  # ns since the epoch, as the writer stamped it
                ("sequence", ctypes.c_uint64)]  # the publisher's own count, 1, 2, 3, ... (flow control's acks)

    @staticmethod
    def type_name() -> str:
        return "automotive::SharedSampleHeader"


def transport(props: Properties) -> str:
    """``config.transport``: ``auto`` (default), ``shm`` or ``udp``."""
    return props.get_choice("config.transport", TRANSPORTS, "auto")


def locality_key(prefix: str, shm_root: Path = SHM_ROOT) -> str:
    """What processes that can meet in shared memory share: this boot, network namespace, ``/dev/shm`` and prefix.

    The network namespace is part of it so that a host DDS sees as another one (its own addresses) is one for this
    transport too; raises :class:`Unavailable` without a usable ``/dev/shm``.
    """
    try:
        shm = shm_root.stat()
        if not os.access(shm_root, os.W_OK):
            raise Unavailable(f"{shm_root} is not writable")
        boot = Path("/proc/sys/kernel/random/boot_id").read_text().strip()
        netns = os.stat("/proc/self/ns/net").st_ino
    except FileNotFoundError as error:
        raise Unavailable(f"{error.filename} does not exist") from None
    except OSError as error:
        raise Unavailable(f"{error.filename}: {error.strerror}") from None
    text = f"{boot}|{netns}|{shm.st_dev}:{shm.st_ino}|{prefix}"
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def service_name(domain_id: int, topic: str, key: str) -> str:
    """The iceoryx2 service of a DDS topic: different domains, and different localities, never mix."""
    return f"dds/domain{domain_id}/{topic}/{key}"


def marker(qos: Qos | None) -> str | None:
    """The locality key an endpoint's USER_DATA announces, or None (not a shared-memory endpoint of ours)."""
    if qos is None:
        return None
    user_data = qos[Policy.Userdata]
    data = getattr(user_data, "data", None)
    if not isinstance(data, bytes) or not data.startswith(USER_DATA_TAG):
        return None
    return data[len(USER_DATA_TAG):].decode("ascii", "replace")


def queue_settings(qos: Qos) -> tuple[bool, int, float]:
    """(reliable keep-all, depth, max blocking time in s) of an endpoint's QoS, for its shared-memory queue."""
    history = _policy(qos, Policy.History) or Policy.History.KeepLast(1)
    reliability = _policy(qos, Policy.Reliability)
    reliable = isinstance(reliability, Policy.Reliability.Reliable)
    keep_all = history == Policy.History.KeepAll
    if keep_all:
        limits = _policy(qos, Policy.ResourceLimits)
        per_instance = limits.max_samples_per_instance if limits is not None else -1
        depth = per_instance if per_instance > 0 else DEFAULT_DEPTH
    else:
        depth = history.depth
    blocking_s = reliability.max_blocking_time / 1e9 if reliable else 0.0  # type: ignore[union-attr]
    return reliable and keep_all, max(1, min(depth, MAX_DEPTH)), blocking_s


def deadline_s(qos: Qos) -> float | None:
    """The deadline period of an endpoint's QoS in seconds, None when it has none."""
    deadline = _policy(qos, Policy.Deadline)
    if deadline is None or deadline.deadline >= 2**63 - 1:
        return None
    return float(deadline.deadline / 1e9)


def _policy(qos: Qos, policy: Any) -> Any:
    try:
        return qos[policy]
    except KeyError:
        return None


@contextmanager
def _refused(what: str) -> Iterator[None]:
    """iceoryx2's refusals (too many ports, a service of the same name with other settings) as one clear line."""
    try:
        yield
    except Exception as error:  # iceoryx2 raises one exception type per failure, all plain Exceptions
        raise Unavailable(f"{what}: iceoryx2 refused ({error!r})") from None


def _wait(listener: Any, seconds: float) -> list[Any]:
    """The listener's events within ``seconds`` (the GIL is released meanwhile); none when a signal interrupts it
    (the application's handler then runs and decides whether to stop)."""
    try:
        return list(listener.timed_wait(iox2.Duration.from_secs_f64(seconds)))
    except iox2.ListenerWaitError:
        return []


def _dead_nodes(config: Any) -> list[Any]:
    """The iceoryx2 nodes under ``config``'s prefix whose process is gone."""
    states = iox2.Node.list(iox2.ServiceType.Ipc, config)
    return [state._0 for state in states if isinstance(state, iox2.NodeState.Dead)]


def _mapped_segments(prefix: str) -> dict[str, int]:
    """This process's mappings of iceoryx2 data segments under ``prefix``: path -> mapped bytes."""
    found: dict[str, int] = {}
    with open("/proc/self/maps") as maps:
        for line in maps:
            fields = line.split(maxsplit=5)
            if len(fields) == 6 and fields[5].startswith(f"{SHM_ROOT}/{prefix}") and fields[5].endswith(".data\n"):
                start, end = (int(value, 16) for value in fields[0].split("-"))
                path = fields[5].rstrip("\n")
                found[path] = found.get(path, 0) + end - start
    return found


class SharedMemory:
    """One process's iceoryx2 node and the services of one topic; removes dead processes' files on start."""

    def __init__(self, app_name: str, domain_id: int, topic: str, prefix: str = DEFAULT_PREFIX,
                 log: logging.Logger = _log):
        self.key = locality_key(prefix)
        self.prefix = prefix
        self.topic = topic
        self.name = service_name(domain_id, topic, self.key)
        self.log = log
        config = iox2.config.default()
        try:
            config.global_cfg.prefix = iox2.FileName.new(prefix)
            dead_before = len(_dead_nodes(config))
            self.node = (iox2.NodeBuilder.new().name(iox2.NodeName.new(app_name)).config(config)
                         # our own SIGINT/SIGTERM handling stops the application; iceoryx2 must not swallow them
                         .signal_handling_mode(iox2.SignalHandlingMode.Disabled).create(iox2.ServiceType.Ipc))
        except Exception as error:  # iceoryx2 raises its own exception types, one per failure
            raise Unavailable(f"iceoryx2 cannot create a node ({error!r})") from None
        # Creating a node removes what dead processes left (a SIGKILLed process cannot clean up); whatever it
        # could not remove at once is tried again here.
        for node in _dead_nodes(config):
            try:
                node.try_remove_stale_resources()
            except Exception as error:  # another process may be cleaning the same node right now
                _log.debug("stale node not removed: %r", error)
        self.stale_removed = max(0, dead_before - len(_dead_nodes(config)))
        with _refused(f"shared memory service '{self.name}'"):
            self._open_services()

    def _open_services(self) -> None:
        name = iox2.ServiceName.new(self.name)
        self.samples = (self.node.service_builder(name).publish_subscribe(iox2.Slice[ctypes.c_uint8])
                        .user_header(SampleHeader)
                        .max_publishers(2).max_subscribers(MAX_SUBSCRIBERS).subscriber_max_buffer_size(MAX_DEPTH)
                        .subscriber_max_borrowed_samples(BORROWED).history_size(0).enable_safe_overflow(True)
                        .open_or_create())
        self.events = self.node.service_builder(name).event().event_id_max_value(LEAVING).open_or_create()
        consumed = iox2.ServiceName.new(self.name + "/consumed")
        self.consumed = self.node.service_builder(consumed).event().event_id_max_value(ACK_IDS - 1).open_or_create()

    @property
    def user_data(self) -> Policy.Userdata:
        """The USER_DATA policy that marks this process's DDS endpoint of the topic as served by shared memory."""
        return Policy.Userdata(USER_DATA_TAG + self.key.encode())

    @property
    def subscribers(self) -> int:
        return int(self.samples.dynamic_config.number_of_subscribers)

    @property
    def publishers(self) -> int:
        return int(self.samples.dynamic_config.number_of_publishers)

    def close(self) -> None:
        """Drop the services and the node (iceoryx2 removes their files once the last reference goes)."""
        del self.consumed, self.events, self.samples, self.node


class DdsReaders:
    """The matched DDS readers a writer still serves on DDS: all but those of its own locality, which shared memory
    serves. Recounted (from discovery data) after a match changes, in the writing thread."""

    def __init__(self, key: str | None):
        self.key = key
        self.writer: DataWriter[Any] | None = None
        self._changed = True
        self._count = 0

    def hook(self, event: str, topic: str, status: Any) -> None:
        """The writer's status hook (a listener thread): a reader came or went."""
        if event == "publication_matched":
            self._changed = True

    def count(self) -> int:
        if self._changed and self.writer is not None:
            self._changed = False  # before counting: a change meanwhile counts again next time
            self._count = sum(1 for handle in matched_subscriptions(self.writer)
                              if self.key is None or not self._local(handle))
        return self._count

    def _local(self, handle: int) -> bool:
        assert self.writer is not None
        try:
            endpoint = self.writer.get_matched_subscription_data(handle)
        except Exception:  # gone meanwhile, or discovery data Cyclone Python cannot decode: served on DDS
            return False
        return endpoint is not None and marker(endpoint.qos) == self.key


class LocalWriters:
    """A DDS reader's view of its writers: those of its own locality send through shared memory, so their DDS
    samples (written for some other reader) are dropped here."""

    def __init__(self, reader: DataReader[Any], key: str | None):
        self.reader = reader
        self.key = key
        self._known: dict[int, bool] = {}  # publication handle (unsigned) -> of our locality
        self._matched: tuple[int, ...] = ()  # the matched writers when shared_writer last looked
        self._next_look = 0.0  # time.monotonic() of shared_writer's next look
        self._shared_writer = "unknown"
        self._names: WriterNames | None = None

    def shared_writer(self) -> str:
        """The participant name of the writer(s) of this locality (those that send through shared memory), for the
        latencies of the samples that came that way: names joined by '+' when several; "unknown" when none is known.
        Looked at once every WRITER_LOOK_S once known (at every call until then: the first samples may come through
        shared memory before DDS matched their writer), and looked up again only when the matched writers changed."""
        now = time.monotonic()
        if now < self._next_look and self._shared_writer != "unknown":
            return self._shared_writer
        self._next_look = now + WRITER_LOOK_S
        try:
            handles = tuple(matched_publications(self.reader))
        except Exception:  # the reader is being deleted
            return "unknown"
        if handles != self._matched:
            self._matched = handles
            if self._names is None:
                self._names = self.reader.writer_names if isinstance(self.reader, CheckedReader) else WriterNames(
                    self.reader)
            found = sorted({self._names.participant(handle) for handle in handles if self.is_local(handle)})
            self._shared_writer = "+".join(found) or "unknown"
        return self._shared_writer

    def is_local(self, handle: int) -> bool:
        if self.key is None:
            return False
        handle &= 0xFFFFFFFFFFFFFFFF
        local = self._known.get(handle)
        if local is None:
            try:
                endpoint = self.reader.get_matched_publication_data(handle)
            except Exception:  # discovery data Cyclone Python cannot decode: not one of ours
                endpoint = None
            local = endpoint is not None and marker(endpoint.qos) == self.key
            if endpoint is not None:
                self._known[handle] = local
        return local


class DeadlineWatch:
    """The deadline of samples that come through shared memory, per instance: missed when a sample is later than the
    period after the previous one, reported through the DDS endpoint's listener as Cyclone reports its own misses
    (a status with total_count and total_count_change), once per period that passes without a sample."""

    def __init__(self, period_s: float | None, report: Callable[[Any], None]):
        self.period_s = period_s
        self.report = report
        self._due: dict[Any, float] = {}  # instance -> monotonic time its next sample is due
        self.total = 0

    def sample(self, instance: Any, now: float | None = None) -> None:
        if self.period_s is not None:
            self._due[instance] = (time.monotonic() if now is None else now) + self.period_s

    def check(self, now: float | None = None) -> None:
        if self.period_s is None:
            return
        now = time.monotonic() if now is None else now
        missed = 0
        for instance, due in self._due.items():
            if now >= due:
                missed += 1
                self._due[instance] = now + self.period_s
        if missed:
            self.total += missed
            self.report(SimpleNamespace(total_count=self.total, total_count_change=missed))

    def overdue(self, now: float | None = None) -> bool:
        """Whether :meth:`check` would report a miss now."""
        now = time.monotonic() if now is None else now
        return self.period_s is not None and any(now >= due for due in self._due.values())

    def forget(self) -> None:
        """Every writer left: no instance is expected any more (DDS stops watching an instance without writers)."""
        self._due.clear()


def _reserve(prefix: str, before: dict[str, int], what: str) -> None:
    """Check that ``/dev/shm`` has room for the data segments mapped since ``before``: iceoryx2 creates them sparse,
    and a page that the full file system cannot give later kills the process (SIGBUS)."""
    needed = sum(size for path, size in _mapped_segments(prefix).items() if path not in before)
    stat = os.statvfs(SHM_ROOT)
    free = stat.f_bavail * stat.f_frsize
    if needed > free:
        raise Unavailable(f"{SHM_ROOT} has {free // 1024} KiB free, {what} needs {needed // 1024} KiB")


class SharedWriter:
    """The publisher side: each sample is built (or copied) in loaned shared memory and sent to the subscribers."""

    def __init__(self, memory: SharedMemory, max_length: int, writer_qos: Qos, may_wait: Callable[[], bool]):
        """``may_wait()`` False: a write that flow control holds back gives up (the application was stopped)."""
        self.memory = memory
        self.may_wait = may_wait
        self.reliable, self.window, self.max_blocking_s = queue_settings(writer_qos)
        self.max_length = max_length
        before = _mapped_segments(memory.prefix)
        with _refused(f"shared memory service '{memory.name}': a publisher (at most 2)"):
            self.publisher = (memory.samples.publisher_builder().initial_max_slice_len(max_length)
                              .allocation_strategy(iox2.AllocationStrategy.Static)
                              .backpressure_strategy(iox2.BackpressureStrategy.DiscardData).create())
        try:
            _reserve(memory.prefix, before, f"the publisher of {memory.topic}")
            with _refused(f"shared memory service '{memory.name}': its notifier"):
                self.notifier = memory.events.notifier_builder().create()
                self.acks = memory.consumed.listener_builder().create()
        except Unavailable:
            self.publisher.delete()
            raise
        self._pending: dict[int, int] = {}  # sequence % ACK_IDS -> subscribers that have not consumed it yet
        self._last_left = 0  # subscribers that have not consumed the last sample sent yet (wait_consumed)
        self.sequence = 0
        self.sent = 0  # samples sent through shared memory

    @property
    def subscribers(self) -> int:
        return self.memory.subscribers

    def publish(self, length: int, fill: Callable[[memoryview], int]) -> int:
        """Send one sample of ``length`` bytes that ``fill(view)`` writes into loaned memory and stamps (it returns
        the source timestamp, ns); return that timestamp. Raises SampleNotSent when the application stopped while
        flow control held the sample back."""
        if length > self.max_length:
            raise ValueError(f"a {length}-byte sample for a publisher of at most {self.max_length} bytes")
        if self.reliable:
            self._wait_for_room()
        sample = self.publisher.loan_slice_uninit(length)
        target = (ctypes.c_char * length).from_address(sample.payload_ptr)
        view = memoryview(target).cast("B")
        try:
            stamp = fill(view)
        except BaseException:
            view.release()
            sample.delete()
            raise
        view.release()
        self.sequence += 1
        header = sample.user_header().contents
        header.source_timestamp = stamp
        header.sequence = self.sequence
        receivers = sample.assume_init().send()
        self.sent += 1
        self._last_left = receivers
        if receivers and self.reliable:
            self._pending[self.sequence % ACK_IDS] = receivers
        self.notifier.notify_with_custom_event_id(iox2.EventId.new(SAMPLE_SENT))
        return stamp

    def _wait_for_room(self) -> None:
        """With ``window`` samples unconsumed, wait until half of them are (one wake-up for several samples, not one
        each), at most max_blocking_time; raise SampleNotSent when the application stops meanwhile."""
        self._collect(self.acks.try_wait())
        if len(self._pending) < self.window:
            return
        deadline = time.monotonic() + self.max_blocking_s
        look_for_dead = time.monotonic() + WAIT_SLICE_S
        while len(self._pending) > self.window // 2:
            if not self.may_wait():
                raise SampleNotSent("stopped while the shared-memory subscribers' queues were full")
            if time.monotonic() >= look_for_dead:  # no acknowledgement for a while: a subscriber may have died
                look_for_dead = time.monotonic() + WAIT_SLICE_S
                if self._subscriber_died():  # its acknowledgements will never come: count again without it
                    self._pending.clear()
                    return
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                # Nothing consumed for max_blocking_time: a subscriber is stopped or dead. Dead ones' ports go; the
                # count starts again, and a stalled one loses the samples that overflow its queue (seen as gaps).
                self.memory.samples.try_cleanup_dead_nodes()
                self._pending.clear()
                self.memory.log.warning("shared memory: no sample consumed for %g s; not waiting for that "
                                        "subscriber any longer", self.max_blocking_s)
                return
            self._collect(_wait(self.acks, min(remaining, WAIT_SLICE_S)))

    def wait_consumed(self, timeout_s: float) -> None:
        """Wait at most ``timeout_s`` until every subscriber the last sample went to has released it (a blocking
        wait on their acknowledgements, not polling)."""
        self._collect(self.acks.try_wait())
        deadline = time.monotonic() + timeout_s
        while self._last_left > 0 and self.may_wait():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return
            self._collect(_wait(self.acks, min(remaining, WAIT_SLICE_S)))

    def _subscriber_died(self) -> bool:
        """Whether a subscriber's process is gone (its port is removed now): checked while flow control waits."""
        before = self.memory.subscribers
        self.memory.samples.try_cleanup_dead_nodes()
        return self.memory.subscribers < before

    def _collect(self, activations: list[Any]) -> None:
        last = self.sequence % ACK_IDS
        for activation in activations:
            key = activation.id.as_value
            if key == last:
                self._last_left -= activation.count
            left = self._pending.get(key)
            if left is None:
                continue
            if left <= activation.count:
                del self._pending[key]
            else:
                self._pending[key] = left - activation.count

    def close(self) -> None:
        self.publisher.delete()
        self.notifier.notify_with_custom_event_id(iox2.EventId.new(LEAVING))
        for entity in (self.notifier, self.acks):
            entity.delete()


class SharedSample:
    """A received sample: its bytes (a read-only view of the publisher's memory) and its header's fields."""

    __slots__ = ("data", "source_timestamp", "sequence")

    def __init__(self, data: memoryview, source_timestamp: int, sequence: int):
        self.data = data
        self.source_timestamp = source_timestamp
        self.sequence = sequence


class LentShared:
    """Samples taken in one call, valid inside a ``with`` block; leaving it gives them back to the publisher."""

    def __init__(self, samples: list[SharedSample], release: Callable[[], None]):
        self.samples = samples
        self._release = release

    def __enter__(self) -> list[SharedSample]:
        return self.samples

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._release()


class SharedReader:
    """The subscriber side: lends each sample in place, read-only; a wake-up thread (:meth:`wake`) sets a guard
    condition of the application's WaitSet, so that one wait serves DDS and shared memory alike."""

    def __init__(self, memory: SharedMemory, reader_qos: Qos):
        self.memory = memory
        _, self.depth, _ = queue_settings(reader_qos)
        with _refused(f"shared memory service '{memory.name}': a subscriber (at most {MAX_SUBSCRIBERS})"):
            self.subscriber = memory.samples.subscriber_builder().buffer_size(self.depth).create()
            self.listener = memory.events.listener_builder().create()
            self.notifier = memory.consumed.notifier_builder().create()
        self._waking: threading.Thread | None = None
        self._closing: list[Callable[[], None]] = []
        self._listener_waiter: str | None = None  # what waits on the listener: one, or the two split its events
        self._stop = threading.Event()
        self._last_sequence: dict[int, int] = {}  # publisher id -> the sequence of its last sample received

    @property
    def wakes(self) -> bool:
        """Whether a thread of :meth:`wake` sets a guard condition on samples."""
        return self._waking is not None

    def wake(self, guard: GuardCondition) -> None:
        """Set ``guard`` whenever samples were sent or a publisher leaves, from a thread of its own (started once)."""
        if self._waking is not None:
            return
        self.claim_listener("a guard condition's thread (SharedReader.wake)")

        def run() -> None:
            while not self._stop.is_set():
                if _wait(self.listener, WAIT_SLICE_S):
                    guard.set(True)

        self._waking = threading.Thread(target=run, name=f"shm-wake {self.memory.topic}", daemon=True)
        self._waking.start()

    def claim_listener(self, waiter: str) -> None:
        """Make ``waiter`` the one that waits on the listener: two would each get a part of its events."""
        if self._listener_waiter is not None:
            raise RuntimeError(f"the shared-memory listener is already waited on by {self._listener_waiter}")
        self._listener_waiter = waiter

    def wait(self, seconds: float) -> bool:
        """Wait at most ``seconds`` for samples sent (or a publisher leaving): for a subscriber without :meth:`wake`
        that takes on a thread of its own."""
        return bool(_wait(self.listener, seconds))

    def take(self, limit: int = 16) -> LentShared:
        """Up to ``limit`` samples (at most BORROWED at once), valid inside ``with reader.take() as samples:``."""
        held: list[Any] = []
        arrays: list[ctypes.Array[ctypes.c_char]] = []
        views: list[memoryview] = []
        samples: list[SharedSample] = []
        try:
            while len(held) < min(limit, BORROWED):
                sample = self.subscriber.receive()
                if sample is None:
                    break
                held.append(sample)
                header = sample.user_header().contents
                # the id's value: the id object itself is new at each call, unhashable, and its repr is its address
                self._acknowledge_skipped(sample.header.publisher_id.value, int(header.sequence))
                payload = sample.payload()
                arrays.append((ctypes.c_char * payload.len()).from_address(payload.as_ptr()))
                # read-only: a write through the view (or a numpy array made from it) raises instead of crashing
                views.append(memoryview(arrays[-1]).cast("B").toreadonly())
                samples.append(SharedSample(views[-1], int(header.source_timestamp), int(header.sequence)))
        except BaseException:
            self._release(samples, views, arrays, held)
            raise
        return LentShared(samples, lambda: self._release(samples, views, arrays, held))

    def _acknowledge_skipped(self, publisher: int, sequence: int) -> None:
        """Acknowledge the samples of ``publisher`` before ``sequence`` that this subscriber never got (overwritten in
        its queue: keep-last, or a queue that overflowed), as a DDS reader acknowledges what its history replaced: a
        reliable publisher's flow control then never waits for them."""
        # Sequences start at 1. A subscriber that came later acknowledges a few samples sent before it was there:
        # flow control is a little looser once, rather than waiting for acknowledgements that never come.
        last = self._last_sequence.get(publisher, 0)
        if len(self._last_sequence) >= MAX_SUBSCRIBERS * 2:  # publishers come and go: forget the old ones
            self._last_sequence.clear()
        self._last_sequence[publisher] = sequence
        if sequence <= last + 1:  # the next one, or a restarted publisher
            return
        for skipped in range(max(last + 1, sequence - 2 * MAX_DEPTH), sequence):  # a window is never longer
            self.notifier.notify_with_custom_event_id(iox2.EventId.new(skipped % ACK_IDS))

    def _release(self, samples: list[SharedSample], views: list[memoryview],
                 arrays: list[ctypes.Array[ctypes.c_char]], held: list[Any]) -> None:
        sequences = [sample.sequence for sample in samples]
        samples.clear()
        # refuses while a view is still held: the publisher would reuse the memory
        release_lent_views(views, arrays, "a shared-memory sample's data", "bytes(sample.data)")
        for sample in held:
            sample.delete()
        for sequence in sequences:  # consumed: the publisher's flow control counts it
            self.notifier.notify_with_custom_event_id(iox2.EventId.new(sequence % ACK_IDS))
        held.clear()

    def on_close(self, close: Callable[[], None]) -> None:
        """Call ``close`` first when this subscriber closes (what waits on its listener)."""
        self._closing.append(close)

    def close(self) -> None:
        for close in self._closing:
            close()
        self._stop.set()
        if self._waking is not None:
            self._waking.join()
        for entity in (self.subscriber, self.listener, self.notifier):
            entity.delete()


class SharedFirstWaitSet:
    """A WaitSet whose taking thread waits on shared memory itself: a sample sent wakes it at once, as it wakes a plain
    iceoryx2 subscriber, instead of waking a thread that then wakes it through a Cyclone guard condition (a second
    wake-up: about 0.1 ms more at the median, milliseconds at the tail on a busy machine). The DDS side (``dds``: the
    flow's DDS reader, the stop signal, whatever else is attached) is watched by a thread of its own, which wakes the
    taking thread through a pipe and then waits until that thread has come back to wait: a condition still true (a
    sample not yet taken) wakes it once per round, never in a loop.

    It stands for a Cyclone WaitSet in ``automotive.bus.app.Application.wake_ups`` (:meth:`wait`, :meth:`attach`).
    Its timeout is iceoryx2's, in whole milliseconds rounded up (epoll): a periodic wake-up comes up to 1 ms late."""

    def __init__(self, reader: SharedReader, dds: WaitSet):
        reader.claim_listener("a SharedFirstWaitSet")
        self._listener = reader.listener
        self._dds = dds
        self._read_fd, self._write_fd = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        self._waitset = (iox2.WaitSetBuilder.new().signal_handling_mode(iox2.SignalHandlingMode.Disabled)
                         .create(iox2.ServiceType.Ipc))
        self._pipe = iox2.FileDescriptor.non_owning_new(self._read_fd)
        self._from_shared = self._waitset.attach_notification(self._listener)
        self._from_dds = self._waitset.attach_notification_fd(self._pipe)
        self._back = threading.Event()  # the taking thread is back in wait(): the DDS side may wake it again
        self._back.set()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch_dds, name=f"dds-wake {reader.memory.topic}", daemon=True)
        self._thread.start()
        reader.on_close(self.close)

    def attach(self, condition: Any) -> None:
        """A further condition (a guard, a read condition) that wakes the taking thread."""
        self._dds.attach(condition)

    def _watch_dds(self) -> None:
        slice_ns = int(WAIT_SLICE_S * 1e9)
        while not self._stop.is_set():
            if not self._dds.wait(slice_ns) or self._stop.is_set():
                continue
            self._back.clear()
            try:
                os.write(self._write_fd, b"!")
            except BlockingIOError:  # the pipe is full of wake-ups the taking thread has not read yet: it will
                pass
            while not self._back.wait(WAIT_SLICE_S) and not self._stop.is_set():
                pass

    def wait(self, timeout_ns: int) -> int:
        """Wait up to ``timeout_ns`` for a sample in shared memory or a DDS wake-up; the number of sources that woke
        it (0: the timeout)."""
        self._back.set()
        try:
            woken, _ = self._waitset.wait_and_process_with_timeout(
                iox2.Duration.from_secs_f64(max(timeout_ns, 0) / 1e9))
        except iox2.WaitSetRunError:  # interrupted: the caller looks at why (a stop) and waits again
            return 0
        # Each source that woke it read empty, so that it wakes the next wait only with what comes after this one.
        for attachment in woken:
            if attachment.has_event_from(self._from_dds):
                try:
                    while os.read(self._read_fd, 4096):
                        pass
                except BlockingIOError:
                    pass
            elif attachment.has_event_from(self._from_shared):
                try:
                    self._listener.try_wait()
                except iox2.ListenerWaitError:
                    pass
        return len(woken)

    def close(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join()
        self._from_shared.delete()
        self._from_dds.delete()
        self._waitset.delete()
        os.close(self._read_fd)
        os.close(self._write_fd)


def prefix_of(props: Properties) -> str:
    """``config.shmPrefix``: names iceoryx2's files (``/dev/shm/<prefix>...``); only processes with the same prefix
    meet (tests use a private one)."""
    prefix = props.get_str("config.shmPrefix", DEFAULT_PREFIX)
    if not prefix or not prefix.replace("_", "").replace("-", "").isalnum():
        raise ConfigError(f"{props.where('config.shmPrefix')}: config.shmPrefix = '{prefix}' is not a valid file "
                          "name prefix (expected letters, digits, '_' or '-')")
    return prefix


def open_for(props: Properties, program: str, domain_id: int, topic: str,
             log: logging.Logger = _log) -> SharedMemory | None:
    """The shared memory of a program's ``topic``: None with ``config.transport=udp``, or when it cannot be used
    with ``auto`` (said in one line); ``shm`` then stops the program with that line."""
    chosen = transport(props)
    prefix = prefix_of(props)
    if chosen == "udp":
        return None
    try:
        memory = SharedMemory(program, domain_id, topic, prefix, log)
    except Unavailable as error:
        unavailable(props, topic, str(error), log)
        return None
    if memory.stale_removed:
        log.info("shared memory: removed the files of %d dead process(es)", memory.stale_removed)
    log.debug("shared memory: iceoryx2 service '%s' (prefix %s)", memory.name, prefix)
    return memory


def unavailable(props: Properties, topic: str, why: str, log: logging.Logger = _log) -> None:
    """Say why shared memory cannot carry ``topic``: one warning (``auto``: DDS carries it) or, with
    ``config.transport=shm``, a configuration error."""
    if transport(props) == "shm":
        raise ConfigError(f"{props.where('config.transport')}: config.transport = 'shm', but shared memory cannot "
                          f"carry {topic}: {why}")
    log.warning("shared memory: %s; %s goes over DDS only", why, topic)
