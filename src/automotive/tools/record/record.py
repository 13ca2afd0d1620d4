"""Recorder: every flow of the running system, as received, into an MCAP file (the format of rosbag2 and Foxglove).

    automotive record -o drive.mcap                                   every topic, until Ctrl-C
    automotive record -o alerts.mcap --topics AlertTopic,VisionTopic --duration 30
    automotive record --recover drive.mcap                            a killed recorder's file, made readable

Data flow:  every topic of the system and every program's health, rt/diagnostics (automotive.tools.flows; --topics to
choose), each read with the reader side of its writer's QoS profile and a history that keeps every sample  -->
serialized samples, never deserialized (automotive.wire.rawsample)  -->  a bounded queue  -->  the writer thread:
MCAP chunks (compressed with config.compression=lz4|zstd; none by default), on disk every second  -->  --output FILE

The camera's frames and the LiDAR's clouds of writers on this host come through shared memory (automotive.wire.shm;
config.transport=udp: on DDS), the very bytes and source timestamp their DDS samples carry, and are recorded alike;
the DDS copies of those writers' samples are left out (automotive.tools.flows.FlowInput), so none is recorded twice.

The file: MCAP profile ``ros2``, one channel per topic, message encoding ``cdr``: the bytes exactly as received
(encapsulation header included); log time = reception, publish time = the writer's source timestamp; disposals and
unregistrations on channels ``<topic>/dispose`` and ``<topic>/unregister`` (a sample carrying the instance's key).
A sample that finds the queue full is counted as lost, never dropped silently. A status line every second; Ctrl-C,
SIGTERM or --duration end the file properly (summary and index); a recorder killed outright leaves a file without
its end, which ``automotive record --recover FILE`` copies into one that every reader reads.

--output's folder is checked before anything starts. A write that fails later (a full disk, a quota, an I/O error)
stops the recorder: the file is cut back to its last complete chunk and ended properly there, so that mcap's and
rosbags' readers read every message it holds; one line on stderr names the file, the error and what the file holds.

Exit codes: 0 stopped (Ctrl-C, SIGTERM, --duration); 1 a write failed (the file holds what was written before, ended
properly); 2 bad input (one line on stderr).
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import os
import struct
import sys
import threading
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, cast

from cyclonedds.qos import DataWriterQos, Policy
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Channel, ChunkIndex, DataEnd, Footer, McapRecord, Schema, Statistics, SummaryOffset
from mcap.writer import CompressionType, Writer

from automotive.bus.app import Application, run
from automotive.bus.cli import ArgumentParser, output_file
from automotive.bus.errors import ConfigError
from automotive.bus.properties import PropertyKeys
from automotive.bus.stats import Every
from automotive.tools.flows import (
    Flow,
    FlowInput,
    channel_metadata,
    check_transport,
    flows_with_diagnostics,
    open_inputs,
    select,
)
from automotive.tools.record import mcap_recover
from automotive.wire.filteredraw import FilteredRawReader
from automotive.wire.rawsample import RawSample, SampleKind

# The property keys it reads beyond the runtime's (automotive.bus.app.RUNTIME_KEYS): any other is refused at start.
PROPERTY_KEYS = PropertyKeys.of("config.compression", "config.chunkSize", "config.queueMB", "config.transport",
                                "config.shmPrefix")

TAKE_LIMIT = 64  # samples per take
FLUSH_INTERVAL_S = 1.0  # finish the open chunk and hand it to the OS at least this often: what a SIGKILL can cost
COMPRESSIONS = {"lz4": CompressionType.LZ4, "zstd": CompressionType.ZSTD, "none": CompressionType.NONE}
EXIT_WRITE_FAILED = 1
MCAP_MAGIC = b"\x89MCAP0\r\n"  # the first and last bytes of an MCAP file


@dataclass
class TopicCounts:
    messages: int = 0  # samples of data
    changes: int = 0  # disposals and unregistrations
    bytes: int = 0
    lost: int = 0  # samples the queue had no room for
    dds_lost: int = 0  # samples DDS reported lost before they reached the reader (best-effort flows)


class OutputFile:
    """The MCAP file without a buffer of its own: each write reaches the OS whole or raises, so when one fails the
    bytes on disk are known to the byte. (A BufferedWriter keeps an unknown part of a failed write and writes it
    again when closed, after the file was cut back.) The MCAP writer writes whole chunks: no more system calls."""

    def __init__(self, path: Path):
        self.path = path
        self.fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o666)  # read too: the chunks are indexed back
        self.position = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data)
        while view:
            written = os.write(self.fd, view)  # short on a full disk; the next call raises ENOSPC
            self.position += written
            view = view[written:]
        return len(data)

    def tell(self) -> int:
        return self.position

    def flush(self) -> None:
        """Nothing is buffered here."""

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


@dataclass
class IndexedChunk:
    """A chunk of the file as the summary indexes it, and its messages per channel id."""

    index: ChunkIndex
    messages: dict[int, int]


def index_chunks(fd: int, start: int, end: int) -> list[IndexedChunk]:
    """The chunks between ``start`` and ``end`` (whole records: each chunk followed by its message indexes), read
    from their record headers only (no chunk is read whole)."""
    chunks: list[IndexedChunk] = []
    offset = start
    while offset < end:
        opcode, length = struct.unpack("<BQ", os.pread(fd, 9, offset))
        body = offset + 9
        if opcode == Opcode.CHUNK:
            head = os.pread(fd, 64, body)  # times, sizes, CRC, compression name ("zstd" at most), compressed size
            start_time, end_time, uncompressed_size, _crc, name_length = struct.unpack_from("<QQQII", head)
            (compressed_size,) = struct.unpack_from("<Q", head, 32 + name_length)
            chunks.append(IndexedChunk(ChunkIndex(
                message_start_time=start_time, message_end_time=end_time, chunk_start_offset=offset,
                chunk_length=9 + length, message_index_offsets={}, message_index_length=0,
                compression=head[32:32 + name_length].decode(), compressed_size=compressed_size,
                uncompressed_size=uncompressed_size), {}))
        elif opcode == Opcode.MESSAGE_INDEX and chunks:
            channel, entries_length = struct.unpack("<HI", os.pread(fd, 6, body))
            chunk = chunks[-1]
            chunk.index.message_index_offsets[channel] = offset
            chunk.index.message_index_length += 9 + length
            chunk.messages[channel] = entries_length // 16  # an entry: log time and offset in the chunk
        offset = body + length
    return chunks


def file_end(offset: int, schemas: list[Schema], channels: list[Channel], chunks: list[IndexedChunk] | None) -> bytes:
    """What ends an MCAP file whose data section ends at ``offset``: data end, summary (schemas, channels,
    statistics, chunk indexes and the offsets of these groups), footer and magic, as mcap's Writer.finish writes
    them; ``chunks`` None: the footer alone (no summary: readers find the messages by reading the file through)."""
    builder = RecordBuilder()
    DataEnd(data_section_crc=0).write(builder)  # 0: no CRC of the data section (the writer computes none either)
    data_end = builder.end()
    if chunks is None:
        Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(builder)
        return data_end + builder.end() + MCAP_MAGIC
    summary_start = offset + len(data_end)
    counts: collections.Counter[int] = collections.Counter()
    for chunk in chunks:
        counts.update(chunk.messages)
    statistics = Statistics(
        message_count=sum(counts.values()), schema_count=len(schemas), channel_count=len(channels),
        attachment_count=0, metadata_count=0, chunk_count=len(chunks),
        message_start_time=min((chunk.index.message_start_time for chunk in chunks), default=0),
        message_end_time=max((chunk.index.message_end_time for chunk in chunks), default=0),
        channel_message_counts=dict(counts))
    groups: list[tuple[Opcode, list[McapRecord]]] = [
        (Opcode.SCHEMA, list(schemas)), (Opcode.CHANNEL, list(channels)), (Opcode.STATISTICS, [statistics]),
        (Opcode.CHUNK_INDEX, [chunk.index for chunk in chunks])]
    offsets = []
    for opcode, records in groups:
        group_start = builder.count
        for record in records:
            record.write(builder)
        offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + group_start,
                                     group_length=builder.count - group_start))
    summary_offset_start = summary_start + builder.count
    for summary_offset in offsets:
        summary_offset.write(builder)
    summary = builder.end()
    crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start), zlib.crc32(summary))
    Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc).write(builder)
    return data_end + summary + builder.end() + MCAP_MAGIC


def write_at(fd: int, data: bytes, offset: int) -> None:
    view = memoryview(data)
    while view:
        written = os.pwrite(fd, view, offset)
        view, offset = view[written:], offset + written


@dataclass
class Held:
    """What the file holds after a failed write."""

    messages: dict[str, int]  # per channel (topic, or topic/dispose...)
    size: int
    indexed: bool  # with its summary (else the footer alone, or nothing when even that had no room)
    ended: bool


class Recording:
    """The MCAP file and the thread that writes it from a queue bounded in bytes."""

    def __init__(self, file: OutputFile, flows: list[Flow], writer_qos: dict[str, DataWriterQos], compression: str,
                 chunk_size: int, queue_bytes: int, on_failure: Callable[[], None]):
        self.path = file.path
        self.file = file
        self.compression = compression
        self.chunk_size = chunk_size
        self.flows = {flow.topic: flow for flow in flows}
        self.writer_qos = writer_qos
        self.counts = {flow.topic: TopicCounts() for flow in flows}
        self.queue_bytes = queue_bytes
        self.queued_bytes = 0
        self._queue: collections.deque[tuple[str, RawSample, int]] = collections.deque()
        self._changed = threading.Condition()
        self._closing = False
        self.on_disk = 0  # messages in whole chunks handed to the OS
        self.failure: OSError | None = None  # the write that failed: the recording stopped there
        self.held: Held | None = None  # then, what the file holds
        self._on_failure = on_failure
        self._not_queued = 0  # samples received after the failure, or still queued then
        self._in_writer = 0  # messages handed to the writer, their chunk not yet on disk
        self._data_start: int | None = None  # where the data section begins: after the header
        self._complete = 0  # the file's length up to its last whole chunk (with the chunk's message indexes)
        self._schema_records: list[Schema] = []  # for the summary of a file ended after a failed write
        self._channel_records: list[Channel] = []
        self.writer = Writer(cast(BinaryIO, file), chunk_size=chunk_size, compression=COMPRESSIONS[compression])
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, SampleKind], int] = {}
        self._sequence: dict[int, int] = {}
        self._thread = threading.Thread(target=self._write_loop, name="mcap-writer", daemon=True)
        try:
            self.writer.start(profile="ros2", library="automotive-databus automotive.tools.record")
            self._data_start = self._complete = file.position
            for flow in flows:
                self._channel(flow.topic, SampleKind.DATA)  # every topic listed, even one that stays silent
        except OSError as error:  # a disk full from the start
            self._fail(error)
            return
        self._thread.start()

    def _channel(self, topic: str, kind: SampleKind) -> int:
        channel = self._channels.get((topic, kind))
        if channel is None:
            flow = self.flows[topic]
            schema = flow.schema
            if schema.name not in self._schemas:
                schema_id = self.writer.register_schema(schema.name, schema.encoding, schema.data)
                self._written()
                self._schemas[schema.name] = schema_id
                self._schema_records.append(Schema(id=schema_id, name=schema.name, encoding=schema.encoding,
                                                   data=schema.data))
            name = topic if kind is SampleKind.DATA else f"{topic}/{kind.value}"
            metadata = channel_metadata(flow, self.writer_qos[topic], kind.value)
            channel = self.writer.register_channel(name, "cdr", self._schemas[schema.name], metadata)
            self._written()
            self._channel_records.append(Channel(id=channel, topic=name, message_encoding="cdr", metadata=metadata,
                                                 schema_id=self._schemas[schema.name]))
            self._channels[(topic, kind)] = channel
            self._sequence[channel] = 0
        return channel

    def _written(self) -> None:
        """After a call of the writer that returned: if it wrote, it wrote whole chunks, with every message handed
        to it so far."""
        if self.file.position != self._complete:
            self._complete = self.file.position
            self.on_disk += self._in_writer
            self._in_writer = 0

    def offer(self, topic: str, sample: RawSample, receive_ns: int) -> bool:
        """Queue a sample for writing; False (and counted as lost) when the queue is full."""
        size = len(sample.data)
        with self._changed:
            if self.failure is not None:  # the recording has stopped
                self._not_queued += 1
                return False
            if self.queued_bytes + size > self.queue_bytes and self._queue:
                self.counts[topic].lost += 1
                return False
            self._queue.append((topic, sample, receive_ns))
            self.queued_bytes += size
            self._changed.notify()
        return True

    def _write_loop(self) -> None:
        try:
            self._write_queued()
        except OSError as error:
            self._fail(error)

    def _write_queued(self) -> None:
        last_flush = time.monotonic()
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
                self._in_writer += 1
                self.writer.add_message(channel, log_time=receive_ns, data=bytes(sample.data),
                                        publish_time=sample.source_timestamp, sequence=self._sequence[channel])
                self._written()
                with self._changed:
                    self.queued_bytes -= len(sample.data)
                counts = self.counts[topic]
                if sample.kind is SampleKind.DATA:
                    counts.messages += 1
                else:
                    counts.changes += 1
                counts.bytes += len(sample.data)
            if self._in_writer and time.monotonic() - last_flush >= FLUSH_INTERVAL_S:
                self.writer.flush()  # the open chunk goes out whole: a reader of a killed recording gets it
                self._written()
                last_flush = time.monotonic()

    def _fail(self, error: OSError) -> None:
        """A write failed: drop what waits, end the file at its last whole chunk, and have the recorder stop."""
        with self._changed:
            self.failure = error
            self._not_queued += len(self._queue)
            self._queue.clear()
            self.queued_bytes = 0
        try:
            self.held = self._end_at_last_chunk()
        except OSError:  # the file cannot even be read back or cut: it stays as it is, and the recorder stops
            self.held = Held({}, self.file_size(), indexed=False, ended=False)
        self.on_disk = sum(self.held.messages.values())
        self._on_failure()

    def _end_at_last_chunk(self) -> Held:
        """End the file properly after its last whole chunk, on a disk that may have no room left.

        Why cut back and end it, rather than leave it as a killed recorder does: rosbags reads an MCAP file only
        through its footer ("File end magic is invalid" without one) and mcap's indexed reader wants the summary.
        Cutting the partly written chunk off frees its space (a chunk is config.chunkSize, 1 MB by default) and the
        summary (a few tens of kB, the schemas' IDL text most of it) is written there. Space reserved up front would
        not do: the summary grows with every chunk. If even the summary has no room, the footer alone (50 bytes)
        keeps every message readable (the readers then read the file through); only if that has no room either is
        the last chunk given up, and so on: what the file holds is then counted from what remains.
        """
        fd = self.file.fd
        if self._data_start is None:  # not even the header was written: nothing to keep
            os.ftruncate(fd, 0)
            return Held({}, 0, indexed=False, ended=False)
        chunks = index_chunks(fd, self._data_start, self._complete)
        for keep in range(len(chunks), -1, -1):
            end = self._complete if keep == len(chunks) else chunks[keep].index.chunk_start_offset
            for indexed in (True, False):
                try:
                    os.ftruncate(fd, end)
                    write_at(fd, file_end(end, self._schema_records, self._channel_records,
                                          chunks[:keep] if indexed else None), end)
                except OSError:
                    continue  # no room for that ending: a smaller one, or one chunk less
                return Held(self._messages_in(chunks[:keep]), os.fstat(fd).st_size, indexed, ended=True)
        os.ftruncate(fd, self._data_start)
        return Held({}, self._data_start, indexed=False, ended=False)

    def _messages_in(self, chunks: list[IndexedChunk]) -> dict[str, int]:
        topics = {channel.id: channel.topic for channel in self._channel_records}
        counts: collections.Counter[str] = collections.Counter()
        for chunk in chunks:
            for channel, count in chunk.messages.items():
                counts[topics.get(channel, str(channel))] += count
        return dict(counts)

    def failure_line(self) -> str:
        """One line: the file, the error, what the file holds and how many received samples it does not."""
        assert self.failure is not None and self.held is not None
        held = self.held
        total = sum(held.messages.values())
        received = sum(c.messages + c.changes for c in self.counts.values()) + self._not_queued
        topics = [f"{topic}={count}" for topic, count in held.messages.items() if count]
        if self._data_start is None:
            holds = "not even the file's header could be written (the file is empty)"
        elif not held.ended:
            holds = "the file could not be ended, not even with a footer: readers may not read it"
        else:
            ending = "properly" if held.indexed else "with a footer but no index"
            listed = " (" + ", ".join(topics) + ")" if topics else ""
            holds = (f"the file ends {ending} with {total} message(s) of {len(topics)} topic(s){listed}, "
                     f"{held.size} bytes")
        return (f"{self.path}: {self.failure.strerror or self.failure}; recording stopped: {holds}; "
                f"{received - total} received sample(s) are not in it")

    def file_size(self) -> int:
        try:
            return os.stat(self.path).st_size
        except OSError:
            return 0

    def close(self) -> None:
        """Write what is queued, then the summary and index (after a failed write, the file is already ended)."""
        with self._changed:
            self._closing = True
            self._changed.notify()
        if self._thread.is_alive():
            self._thread.join()
        if self.failure is None:
            try:
                self.writer.flush()
                self._written()
                self.writer.finish()
            except OSError as error:
                self._fail(error)
        self.file.close()

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


def open_output(path: Path, overwrite: bool) -> OutputFile:
    if path.exists() and not overwrite:
        raise ConfigError(f"--output {path}: the file exists (add --overwrite to replace it)")
    try:
        return OutputFile(path)  # closed by Recording.close
    except OSError as error:
        raise ConfigError(f"--output {path}: cannot write ({error.strerror})") from None


def body(app: Application) -> None:
    flows = select(flows_with_diagnostics(app.props.folder), app.args.topics)
    if app.args.duration is not None and app.args.duration <= 0:
        raise ConfigError(f"--duration {app.args.duration:g}: expected a number of seconds above 0")
    compression = app.props.get_choice("config.compression", list(COMPRESSIONS), "none")
    chunk_size = app.props.get_int("config.chunkSize", 1024 * 1024, minimum=1024)
    queue_bytes = int(app.props.get_float("config.queueMB", 512, minimum=1) * 1e6)
    check_transport(app.props)
    writer_qos = {flow.topic: app.profiles.writer_qos(app.library, flow.profile) for flow in flows}
    path: Path = app.args.output
    recording = Recording(open_output(path, app.args.overwrite), flows, writer_qos, compression, chunk_size,
                          queue_bytes, on_failure=app.stop)

    def on_event(event: str, topic: str, status: Any) -> None:
        if event == "sample_lost":
            recording.counts[topic].dds_lost += status.total_count_change

    # Every sample kept until taken (the profile's history could replace an untaken one); the rest of the reader
    # QoS is the profile's, so reliable flows are read reliably and the alert's transient-local state is fetched.
    # A topic with a content filter (--filter, config.filter.<Topic>) records only the samples it accepts.
    try:
        inputs = open_inputs(app, flows, (Policy.History.KeepAll,), on_event)
    except BaseException:
        recording.close()
        raise
    try:
        record_until_stopped(app, recording, inputs)
    finally:
        for flow_input in inputs:
            flow_input.close()


def record_until_stopped(app: Application, recording: Recording, inputs: list[FlowInput]) -> None:
    """Record until stopped, then end the file and say what it holds."""
    flows = [flow_input.flow for flow_input in inputs]
    path = recording.path
    app.log.info("recording %d topic(s) to %s (%s, chunks of %d bytes): %s", len(flows), path,
                 recording.compression, recording.chunk_size, ", ".join(flow.topic for flow in flows))
    started = time.monotonic()
    deadline = started + app.args.duration if app.args.duration else None
    every_second = Every()

    def take_all() -> None:
        for flow_input in inputs:
            for sample, receive_ns in flow_input.drain(TAKE_LIMIT):
                recording.offer(flow_input.flow.topic, sample, receive_ns)
                app.tick()
            flow_input.check_deadline()

    waitset = app.waitset(*(flow_input.reader for flow_input in inputs))
    for flow_input in inputs:
        flow_input.attach(waitset)
    try:
        for _ in app.wake_ups(waitset, timeout_s=0.2):
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
    by_topic = {flow_input.flow.topic: flow_input for flow_input in inputs}
    for topic, counts in recording.counts.items():
        flow_input = by_topic[topic]
        filtered = (f" filtered_out={flow_input.raw.filtered_out}" if isinstance(flow_input.raw, FilteredRawReader)
                    else "")
        shared = f" {flow_input.shared_counts()}" if flow_input.shared_counts() else ""
        app.log.info("summary %s: messages=%d changes=%d MB=%.3f lost=%d dds_lost=%d%s%s", topic, counts.messages,
                     counts.changes, counts.bytes / 1e6, counts.lost, counts.dds_lost, filtered, shared)
    # a ratio only says something of a compressed file
    compression = recording.compression
    ratio = f" (compression {compression}, ratio {written / size:.2f})" if compression != "none" and size else ""
    app.log.info("summary: %s in %.1f s, file %s of %.2f MB%s", recording.totals(), elapsed, path, size / 1e6, ratio)
    if recording.failure is not None:
        app.stats.record("write_failed", error=recording.failure.strerror or str(recording.failure),
                         held=recording.held.messages if recording.held else {})
        print(f"{app.args.prog}: {recording.failure_line()}", file=sys.stderr)
        raise SystemExit(EXIT_WRITE_FAILED)  # through run(), which still closes the application


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--output", "-o", type=output_file, required=True, help="the MCAP file to write")
    parser.set_defaults(prog=parser.prog)  # the program's name as its parser gives it, for the line of a failed write
    parser.add_argument("--topics", default="", help="comma-separated topics to record (default: every topic)")
    parser.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing file")


def recover_command(argv: list[str]) -> int:
    """``automotive record --recover FILE [-o COPY]``: a readable copy of a killed recorder's file."""
    parser = ArgumentParser(prog="automotive record --recover", description=(
        "Write a readable copy of a recording whose recorder was killed outright (SIGKILL, a power cut): every "
        "message up to its last complete record, in a file that every MCAP reader reads."))
    parser.add_argument("file", type=Path, help="the recording to recover (left as it is)")
    parser.add_argument("--output", "-o", type=output_file, default=None,
                        help="the copy to write (default: FILE with .recovered.mcap in place of .mcap)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing copy")
    args = parser.parse_args(argv)
    source: Path = args.file
    target: Path = args.output or source.with_name(source.name.removesuffix(".mcap") + ".recovered.mcap")
    if not source.is_file():
        parser.error(f"{source}: no such file")
    if target.resolve() == source.resolve():
        parser.error(f"--output {target}: is the recording itself; the copy must be another file")
    if target.exists() and not args.overwrite:
        parser.error(f"--output {target}: exists (--overwrite replaces it)")
    try:
        result = mcap_recover.recover(source, target)
    except mcap_recover.NotRecoverable as error:
        target.unlink(missing_ok=True)
        parser.error(f"{source}: {error}")
    except OSError as error:
        print(f"automotive record --recover: {error.filename or target}: {error.strerror or error}", file=sys.stderr)
        return 1
    topics = ", ".join(f"{topic}={count}" for topic, count in result.messages.items())
    state = ("it already ended properly" if result.complete
             else f"its unfinished end left out ({result.problem})" if result.problem else "it had no end")
    print(f"{source}: {result.total} message(s) of {len(result.messages)} topic(s)"
          f"{' (' + topics + ')' if topics else ''} copied to {target}; {state}")
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--recover" in argv:
        where = argv.index("--recover")
        return recover_command(argv[:where] + argv[where + 1:])
    return run("record", __doc__ or "", body, argv, add_arguments, command="automotive record",
               keys=PROPERTY_KEYS)


if __name__ == "__main__":
    sys.exit(main())
