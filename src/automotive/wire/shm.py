"""Large samples through shared memory on one host (iceoryx2), beside DDS: ``config.transport=shm``.

No Cyclone DDS build installable here moves Python samples through shared memory
(docs/measurements/cyclone-shared-memory.md), so this transport sits beside DDS rather than inside it, the way RTI's
Zero Copy does for a same-host reader:
* The shared-memory sample holds exactly the bytes of the DDS sample (encapsulation, header fields, image). The
  publisher builds the frame in place in memory it loans from iceoryx2; a subscriber decodes it with the same
  :class:`~automotive.wire.camera.FrameCodec` as a DDS sample and views the image in place, read-only.
* One iceoryx2 publish-subscribe service per DDS topic and domain (:func:`service_name`), plus two event services:
  the publisher's "frame sent" / "leaving" notifications wake the subscribers (no polling), and the subscribers'
  "frame consumed" notifications drive the publisher's flow control.
* The DDS writer stays: frames also go out on DDS whenever a DDS reader is matched (a remote viewer, an RTI tool, a
  recorder); with none matched, nothing is serialized or sent on UDP.
* Queueing follows the endpoint's QoS profile. A subscriber keeps the last ``depth`` frames (history depth, or
  ``max_samples_per_instance`` for keep-all); an older frame is overwritten (``enable_safe_overflow``) and shows
  up as a gap. A reliable keep-all writer whose subscribers hold a full window of unconsumed frames waits until
  half of them are consumed, at most ``max_blocking_time``: the flow control of a reliable DDS stream. iceoryx2's own
  blocking back-pressure is not used: it holds the GIL while it waits and never returns once a subscriber died.
* Stale files of processes that died without cleaning up (SIGKILL) are removed when a node starts; a clean stop
  removes ours.

iceoryx2's Python API changes between releases: pyproject.toml pins 0.10.0, which this module was written against.
"""

from __future__ import annotations

import ctypes
import logging
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import iceoryx2 as iox2
from cyclonedds.qos import Policy, Qos

from automotive.bus.errors import ConfigError
from automotive.bus.properties import Properties
from automotive.wire.camera import Frame, FrameCodec, FrameWriter, TakenFrames
from automotive.wire.rawsample import release_lent_views

TRANSPORTS = ("dds", "shm")
DEFAULT_PREFIX = "iox2_"  # iceoryx2's own default prefix
MAX_SUBSCRIBERS = 4
MAX_DEPTH = 8  # per subscriber; the publisher's shared memory holds about MAX_SUBSCRIBERS * (MAX_DEPTH + 2) frames
DEFAULT_DEPTH = 8  # keep-all without a resource limit
BORROWED = 2  # frames a subscriber holds at once (it releases each after verifying it)
ACK_IDS = 4096  # "consumed" event ids are seqnum modulo this; a window never comes near it
FRAME_SENT, LEAVING = 0, 1  # event ids of the publisher's notifications
WAIT_SLICE_S = 0.2  # longest single wait, so that a stop signal is noticed promptly

_log = logging.getLogger(__name__)


class FrameNotSent(Exception):
    """A frame that was not published (the application stopped while flow control held it back)."""


def transport(props: Properties) -> str:
    """``config.transport``: ``dds`` (default) or ``shm``."""
    return props.get_choice("config.transport", TRANSPORTS, "dds")


def service_name(domain_id: int, topic: str) -> str:
    """The iceoryx2 service of a DDS topic: systems on different domains of one host never mix."""
    return f"dds/domain{domain_id}/{topic}"


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
        raise ConfigError(f"{what}: iceoryx2 refused ({error!r})") from None


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


class SharedMemory:
    """One process's iceoryx2 node and the services of one topic; removes dead processes' files on start."""

    def __init__(self, app_name: str, domain_id: int, topic: str, prefix: str = DEFAULT_PREFIX,
                 log: logging.Logger = _log):
        self.name = service_name(domain_id, topic)
        self.log = log
        config = iox2.config.default()
        try:
            config.global_cfg.prefix = iox2.FileName.new(prefix)
            dead_before = len(_dead_nodes(config))
            self.node = (iox2.NodeBuilder.new().name(iox2.NodeName.new(app_name)).config(config)
                         # our own SIGINT/SIGTERM handling stops the application; iceoryx2 must not swallow them
                         .signal_handling_mode(iox2.SignalHandlingMode.Disabled).create(iox2.ServiceType.Ipc))
        except Exception as error:  # iceoryx2 raises its own exception types, one per failure
            raise ConfigError(f"shared memory (prefix '{prefix}'): iceoryx2 cannot create a node ({error!r})") from None
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
        self.frames = (self.node.service_builder(name).publish_subscribe(iox2.Slice[ctypes.c_uint8])
                       .max_publishers(2).max_subscribers(MAX_SUBSCRIBERS).subscriber_max_buffer_size(MAX_DEPTH)
                       .subscriber_max_borrowed_samples(BORROWED).history_size(0).enable_safe_overflow(True)
                       .open_or_create())
        self.events = self.node.service_builder(name).event().event_id_max_value(LEAVING).open_or_create()
        consumed = iox2.ServiceName.new(self.name + "/consumed")
        self.consumed = self.node.service_builder(consumed).event().event_id_max_value(ACK_IDS - 1).open_or_create()

    @property
    def subscribers(self) -> int:
        return int(self.frames.dynamic_config.number_of_subscribers)

    @property
    def publishers(self) -> int:
        return int(self.frames.dynamic_config.number_of_publishers)

    def close(self) -> None:
        """Drop the services and the node (iceoryx2 removes their files once the last reference goes)."""
        del self.consumed, self.events, self.frames, self.node


class SharedFrameWriter:
    """The publisher side: builds each frame in loaned shared memory, sends it to the shared-memory subscribers and,
    when a DDS reader is matched, writes the same bytes on DDS."""

    def __init__(self, memory: SharedMemory, dds: FrameWriter, writer_qos: Qos, dds_readers: Callable[[], int],
                 running: Callable[[], bool]):
        self.memory = memory
        self.dds = dds
        self.dds_readers = dds_readers
        self.running = running
        self.reliable, self.window, self.max_blocking_s = queue_settings(writer_qos)
        self.length = dds.serialized_length
        with _refused(f"shared memory service '{memory.name}': a publisher (at most 2)"):
            self.publisher = (memory.frames.publisher_builder().initial_max_slice_len(self.length)
                              .allocation_strategy(iox2.AllocationStrategy.Static)
                              .backpressure_strategy(iox2.BackpressureStrategy.DiscardData).create())
            self.notifier = memory.events.notifier_builder().create()
            self.acks = memory.consumed.listener_builder().create()
        self._pending: dict[int, int] = {}  # seqnum -> subscribers that have not consumed it yet
        self.sent_shared = 0  # frames sent through shared memory
        self.sent_dds = 0  # frames written on DDS (a DDS reader was matched)

    def count_subscribers(self) -> int:
        return self.memory.subscribers

    def write_pattern(self, id: int, seqnum: int) -> int:
        """Publish the pattern's frame ``seqnum`` to every subscriber of either kind; return its timestamp (ns)."""
        if not self.memory.subscribers:
            self._pending.clear()
            if not self.dds_readers():
                return time.time_ns()
            self.sent_dds += 1
            return self.dds.write_pattern(id, seqnum)
        if self.reliable:
            self._wait_for_room()
        sample = self.publisher.loan_slice_uninit(self.length)
        target = (ctypes.c_char * self.length).from_address(sample.payload_ptr)
        view = memoryview(target).cast("B")
        try:
            stamp = self.dds.build_pattern_frame(view, id, seqnum)
            if self.dds_readers():
                self.dds.write_serialized(view)
                self.sent_dds += 1
        finally:
            view.release()
        receivers = sample.assume_init().send()
        self.sent_shared += 1
        if receivers:
            self._pending[seqnum % ACK_IDS] = receivers
        self.notifier.notify_with_custom_event_id(iox2.EventId.new(FRAME_SENT))
        return stamp

    def _wait_for_room(self) -> None:
        """With ``window`` frames unconsumed, wait until half of them are (one wake-up for several frames, not one
        each), at most max_blocking_time; raise FrameNotSent when the application stops meanwhile."""
        self._collect(self.acks.try_wait())
        if len(self._pending) < self.window:
            return
        deadline = time.monotonic() + self.max_blocking_s
        while len(self._pending) > self.window // 2:
            if not self.running():
                raise FrameNotSent("stopped while the shared-memory subscribers' queues were full")
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                # Nothing consumed for max_blocking_time: a subscriber is stopped or dead. Dead ones' ports go; the
                # count starts again, and a stalled one loses the frames that overflow its queue (seen as gaps).
                self.memory.frames.try_cleanup_dead_nodes()
                self._pending.clear()
                self.memory.log.warning("shared memory: no frame consumed for %g s; not waiting for that "
                                        "subscriber any longer", self.max_blocking_s)
                return
            self._collect(_wait(self.acks, min(remaining, WAIT_SLICE_S)))

    def _collect(self, activations: list[Any]) -> None:
        for activation in activations:
            key = activation.id.as_value
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


class SharedFrameReader:
    """The subscriber side: wakes on the publisher's notification and lends each frame in place, read-only."""

    def __init__(self, memory: SharedMemory, data_type: type[Any], reader_qos: Qos):
        self.memory = memory
        self.codec = FrameCodec(data_type)
        _, self.depth, _ = queue_settings(reader_qos)
        with _refused(f"shared memory service '{memory.name}': a subscriber (at most {MAX_SUBSCRIBERS})"):
            self.subscriber = memory.frames.subscriber_builder().buffer_size(self.depth).create()
            self.listener = memory.events.listener_builder().create()
            self.notifier = memory.consumed.notifier_builder().create()

    def wake_ups(self, running: Callable[[], bool], timeout_s: float = 1.0) -> Iterator[bool]:
        """Yield after each wake-up (frames sent, or a timeout) while ``running()``; True once the publisher left."""
        while running():
            leaving = False
            waited = 0.0
            while running() and waited < timeout_s:
                activations = _wait(self.listener, WAIT_SLICE_S)
                if activations:
                    leaving = any(activation.id.as_value == LEAVING for activation in activations)
                    break
                waited += WAIT_SLICE_S
            publishers = self.memory.publishers
            if running():
                yield leaving and publishers == 0

    def take(self, limit: int = 16) -> TakenFrames:
        """Up to ``limit`` frames, valid inside ``with reader.take() as frames:``; each is released on exit."""
        samples: list[Any] = []
        arrays: list[ctypes.Array[ctypes.c_char]] = []
        views: list[memoryview] = []
        frames: list[Frame] = []
        try:
            while len(samples) < min(limit, BORROWED):
                sample = self.subscriber.receive()
                if sample is None:
                    break
                samples.append(sample)
                payload = sample.payload()
                arrays.append((ctypes.c_char * payload.len()).from_address(payload.as_ptr()))
                # read-only: a write through the view (or a numpy array made from it) raises instead of crashing
                views.append(memoryview(arrays[-1]).cast("B").toreadonly())
                frames.append(self.codec.decode(views[-1]))
        except BaseException:
            self._release(frames, views, arrays, samples)
            raise
        return TakenFrames(frames, lambda: self._release(frames, views, arrays, samples))

    def _release(self, frames: list[Frame], views: list[memoryview], arrays: list[ctypes.Array[ctypes.c_char]],
                 samples: list[Any]) -> None:
        for frame in frames:
            frame.data.release()
        # refuses while a view is still held: the publisher would reuse the memory
        release_lent_views(views, arrays, "a taken frame's data", "bytes(frame.data)")
        for index, sample in enumerate(samples):
            sample.delete()
            if index < len(frames):  # a consumed frame: the publisher's flow control counts it
                self.notifier.notify_with_custom_event_id(iox2.EventId.new(frames[index].seqnum % ACK_IDS))
        samples.clear()

    def close(self) -> None:
        for entity in (self.subscriber, self.listener, self.notifier):
            entity.delete()


def open_for(props: Properties, program: str, domain_id: int, topic: str,
             log: logging.Logger = _log) -> SharedMemory | None:
    """The shared memory of a program's ``topic`` when its properties say ``config.transport=shm``, else None.

    ``config.shmPrefix`` names iceoryx2's files (``/dev/shm/<prefix>...``): processes see each other only under the
    same prefix (tests use a private one).
    """
    chosen = transport(props)
    prefix = props.get_str("config.shmPrefix", DEFAULT_PREFIX)
    if chosen != "shm":
        return None
    if not prefix or not prefix.replace("_", "").replace("-", "").isalnum():
        raise ConfigError(f"{props.where('config.shmPrefix')}: config.shmPrefix = '{prefix}' is not a valid file "
                          "name prefix (expected letters, digits, '_' or '-')")
    memory = SharedMemory(program, domain_id, topic, prefix, log)
    if memory.stale_removed:
        log.info("shared memory: removed the files of %d dead process(es)", memory.stale_removed)
    log.info("shared memory: iceoryx2 service '%s' (prefix %s)", memory.name, prefix)
    return memory
