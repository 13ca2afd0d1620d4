"""Recorder: every flow of the running system, as received, into an MCAP file (the format of rosbag2 and Foxglove).

Data flow:  every topic of the system (automotive.tools.flows; --topics to choose), each read with the reader side of
its writer's QoS profile and a history that keeps every sample  -->  serialized samples, never deserialized
(automotive.wire.rawsample)  -->  a bounded queue  -->  the writer thread: MCAP chunks (compressed with
config.compression=lz4|zstd; none by default), on disk every second  -->  --output FILE

The file: MCAP profile ``ros2``, one channel per topic, message encoding ``cdr``: the bytes exactly as received
(encapsulation header included); log time = reception, publish time = the writer's source timestamp; disposals and
unregistrations on channels ``<topic>/dispose`` and ``<topic>/unregister`` (a sample carrying the instance's key).
A sample that finds the queue full is counted as lost, never dropped silently. A status line every second; Ctrl-C,
SIGTERM or --duration end the file properly (summary and index); a recorder killed outright leaves a file that
readers read up to its last complete chunk.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import os
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from cyclonedds.qos import DataWriterQos, Policy
from mcap.writer import CompressionType, Writer

from automotive.bus.app import Application, run
from automotive.bus.errors import ConfigError
from automotive.bus.stats import Every
from automotive.tools.flows import Flow, channel_metadata, select, system_flows
from automotive.wire.filteredraw import FilteredRawReader, filtered_raw_reader
from automotive.wire.rawsample import RawSample, SampleKind

TAKE_LIMIT = 64  # samples per take
FLUSH_INTERVAL_S = 1.0  # finish the open chunk and hand it to the OS at least this often: what a SIGKILL can cost
COMPRESSIONS = {"lz4": CompressionType.LZ4, "zstd": CompressionType.ZSTD, "none": CompressionType.NONE}


@dataclass
class TopicCounts:
    messages: int = 0  # samples of data
    changes: int = 0  # disposals and unregistrations
    bytes: int = 0
    lost: int = 0  # samples the queue had no room for
    dds_lost: int = 0  # samples DDS reported lost before they reached the reader (best-effort flows)


class Recording:
    """The MCAP file and the thread that writes it from a queue bounded in bytes."""

    def __init__(self, path: Path, stream: BinaryIO, flows: list[Flow], writer_qos: dict[str, DataWriterQos],
                 compression: str, chunk_size: int, queue_bytes: int):
        self.path = path
        self.stream = stream
        self.flows = {flow.topic: flow for flow in flows}
        self.writer_qos = writer_qos
        self.counts = {flow.topic: TopicCounts() for flow in flows}
        self.queue_bytes = queue_bytes
        self.queued_bytes = 0
        self._queue: collections.deque[tuple[str, RawSample, int]] = collections.deque()
        self._changed = threading.Condition()
        self._closing = False
        self.on_disk = 0  # messages handed to the OS
        self.writer = Writer(stream, chunk_size=chunk_size, compression=COMPRESSIONS[compression])
        self.writer.start(profile="ros2", library="automotive-databus automotive.tools.record")
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, SampleKind], int] = {}
        self._sequence: dict[int, int] = {}
        for flow in flows:
            self._channel(flow.topic, SampleKind.DATA)  # every topic listed, even one that stays silent
        self._thread = threading.Thread(target=self._write_loop, name="mcap-writer", daemon=True)
        self._thread.start()

    def _channel(self, topic: str, kind: SampleKind) -> int:
        channel = self._channels.get((topic, kind))
        if channel is None:
            flow = self.flows[topic]
            schema = flow.schema
            if schema.name not in self._schemas:
                self._schemas[schema.name] = self.writer.register_schema(schema.name, schema.encoding, schema.data)
            name = topic if kind is SampleKind.DATA else f"{topic}/{kind.value}"
            channel = self.writer.register_channel(name, "cdr", self._schemas[schema.name],
                                                   channel_metadata(flow, self.writer_qos[topic], kind.value))
            self._channels[(topic, kind)] = channel
            self._sequence[channel] = 0
        return channel

    def offer(self, topic: str, sample: RawSample, receive_ns: int) -> bool:
        """Queue a sample for writing; False (and counted as lost) when the queue is full."""
        size = len(sample.data)
        with self._changed:
            if self.queued_bytes + size > self.queue_bytes and self._queue:
                self.counts[topic].lost += 1
                return False
            self._queue.append((topic, sample, receive_ns))
            self.queued_bytes += size
            self._changed.notify()
        return True

    def _write_loop(self) -> None:
        last_flush = time.monotonic()
        unflushed = 0
        while True:
            with self._changed:
                while not self._queue and not self._closing:
                    if not self._changed.wait(FLUSH_INTERVAL_S / 4):
                        break  # timed out: time to check whether a flush is due
                item = self._queue.popleft() if self._queue else None
                if item is None and self._closing:
                    return
            if item is not None:
                topic, sample, receive_ns = item
                channel = self._channel(topic, sample.kind)
                self._sequence[channel] += 1
                self.writer.add_message(channel, log_time=receive_ns, data=bytes(sample.data),
                                        publish_time=sample.source_timestamp, sequence=self._sequence[channel])
                with self._changed:
                    self.queued_bytes -= len(sample.data)
                counts = self.counts[topic]
                if sample.kind is SampleKind.DATA:
                    counts.messages += 1
                else:
                    counts.changes += 1
                counts.bytes += len(sample.data)
                unflushed += 1
            if unflushed and time.monotonic() - last_flush >= FLUSH_INTERVAL_S:
                self.writer.flush()  # the open chunk goes out whole: a reader of a killed recording gets it
                self.on_disk += unflushed
                unflushed, last_flush = 0, time.monotonic()

    def file_size(self) -> int:
        try:
            return os.stat(self.path).st_size
        except OSError:
            return 0

    def close(self) -> None:
        """Write what is queued, then the summary and index."""
        with self._changed:
            self._closing = True
            self._changed.notify()
        self._thread.join()
        self.writer.finish()
        self.on_disk = sum(counts.messages + counts.changes for counts in self.counts.values())
        self.stream.close()

    def totals(self) -> str:
        total = sum(c.messages + c.changes for c in self.counts.values())
        size = sum(c.bytes for c in self.counts.values())
        lost = sum(c.lost + c.dds_lost for c in self.counts.values())
        return (f"recorded={total} on_disk={self.on_disk} MB={size / 1e6:.2f} file_MB={self.file_size() / 1e6:.2f} "
                f"lost={lost} queue_MB={self.queued_bytes / 1e6:.1f}")

    def figures(self) -> dict[str, Any]:
        """The counts as numbers: totals and, per topic, messages, changes, bytes, lost and dds_lost."""
        return {"recorded": sum(c.messages + c.changes for c in self.counts.values()), "on_disk": self.on_disk,
                "bytes": sum(c.bytes for c in self.counts.values()),
                "lost": sum(c.lost + c.dds_lost for c in self.counts.values()), "queued_bytes": self.queued_bytes,
                "topics": {topic: dataclasses.asdict(c) for topic, c in self.counts.items()}}

    def status(self) -> str:
        """The totals and, for each topic that has seen anything, its messages and megabytes."""
        topics = " ".join(f"{topic}={c.messages}/{c.bytes / 1e6:.2f}MB" for topic, c in self.counts.items()
                          if c.messages or c.lost or c.dds_lost)
        return f"{self.totals()} | {topics}"


def open_output(path: Path, overwrite: bool) -> BinaryIO:
    if path.exists() and not overwrite:
        raise ConfigError(f"--output {path}: the file exists (add --overwrite to replace it)")
    try:
        return open(path, "wb")  # closed by Recording.close
    except OSError as error:
        raise ConfigError(f"--output {path}: cannot write ({error.strerror})") from None


def body(app: Application) -> None:
    flows = select(system_flows(app.props.folder), app.args.topics)
    if app.args.duration is not None and app.args.duration <= 0:
        raise ConfigError(f"--duration {app.args.duration:g}: expected a number of seconds above 0")
    compression = app.props.get_choice("config.compression", list(COMPRESSIONS), "none")
    chunk_size = app.props.get_int("config.chunkSize", 1024 * 1024, minimum=1024)
    queue_bytes = int(app.props.get_float("config.queueMB", 512, minimum=1) * 1e6)
    writer_qos = {flow.topic: app.profiles.writer_qos(app.library, flow.profile) for flow in flows}
    path: Path = app.args.output
    recording = Recording(path, open_output(path, app.args.overwrite), flows, writer_qos, compression, chunk_size,
                          queue_bytes)

    def on_event(event: str, topic: str, status: Any) -> None:
        if event == "sample_lost":
            recording.counts[topic].dds_lost += status.total_count_change

    # Every sample kept until taken (the profile's history could replace an untaken one); the rest of the reader
    # QoS is the profile's, so reliable flows are read reliably and the alert's transient-local state is fetched.
    # A topic with a content filter (--filter, config.filter.<Topic>) records only the samples it accepts.
    readers = [(flow.topic, filtered_raw_reader(app.bus.reader(flow.topic, flow.data_type, flow.profile, on_event,
                                                               overrides=(Policy.History.KeepAll,)),
                                                app.filters.predicate(flow.topic, flow.data_type)))
               for flow in flows]
    app.log.info("recording %d topic(s) to %s (%s, chunks of %d bytes): %s", len(flows), path, compression,
                 chunk_size, ", ".join(flow.topic for flow in flows))
    started = time.monotonic()
    deadline = started + app.args.duration if app.args.duration else None
    every_second = Every()

    def take_all() -> None:
        for topic, raw in readers:
            for sample, receive_ns in raw.drain(TAKE_LIMIT):
                recording.offer(topic, sample, receive_ns)
                app.tick()

    try:
        for _ in app.wake_ups(app.waitset(*(raw.reader for _, raw in readers)), timeout_s=0.2):
            take_all()
            now = time.monotonic()
            if every_second.due():
                app.log.info("%s", recording.status())
                app.stats.record("status", **recording.figures())
            if deadline is not None and now >= deadline:
                app.stop()
        take_all()  # what arrived since the last wake-up is recorded too
    finally:
        recording.close()
    elapsed = time.monotonic() - started
    written = sum(c.bytes for c in recording.counts.values())
    size = recording.file_size()
    app.stats.record("summary", seconds=elapsed, file_bytes=size, **recording.figures())
    filtered = {topic: raw.filtered_out for topic, raw in readers if isinstance(raw, FilteredRawReader)}
    for topic, counts in recording.counts.items():
        app.log.info("summary %s: messages=%d changes=%d MB=%.3f lost=%d dds_lost=%d%s", topic, counts.messages,
                     counts.changes, counts.bytes / 1e6, counts.lost, counts.dds_lost,
                     f" filtered_out={filtered[topic]}" if topic in filtered else "")
    app.log.info("summary: %s in %.1f s, file %s of %.2f MB (compression ratio %.2f)", recording.totals(),
                 elapsed, path, size / 1e6, written / size if size else 0.0)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--output", "-o", type=Path, required=True, help="the MCAP file to write")
    parser.add_argument("--topics", default="", help="comma-separated topics to record (default: every topic)")
    parser.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing file")


def main(argv: list[str] | None = None) -> int:
    return run("record", __doc__ or "", body, argv, add_arguments)


if __name__ == "__main__":
    sys.exit(main())
