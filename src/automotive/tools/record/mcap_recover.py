"""``automotive record --recover FILE``: a readable copy of a recording whose recorder was killed outright.

A recorder killed with SIGKILL (or by the kernel's OOM killer, or a power cut) leaves its file without summary,
footer and end magic. Only a reader that reads a file through, record by record, gets its messages: mcap's usual
``make_reader`` (the indexed reader) raises at the unfinished end and yields nothing, rosbags wants the footer, and
Foxglove's indexed reader the summary. This reads the file through with mcap's stream reader up to its last complete
record, and writes every schema, channel and message it finds into a new file that mcap's Writer ends properly, so
that every reader reads it. The original is left as it is.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from mcap.exceptions import McapError
from mcap.records import Channel, Chunk, Header, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

MCAP_MAGIC = b"\x89MCAP0\r\n"
COMPRESSIONS = {"": CompressionType.NONE, "lz4": CompressionType.LZ4, "zstd": CompressionType.ZSTD}


class NotRecoverable(Exception):
    """The file is not an MCAP recording (one line for the user)."""


@dataclass
class Recovered:
    messages: dict[str, int] = field(default_factory=dict)  # per topic
    complete: bool = False  # the original already ended properly
    problem: str = ""  # what ended the reading (the unfinished tail), "" at a proper end

    @property
    def total(self) -> int:
        return sum(self.messages.values())


def ends_properly(path: Path) -> bool:
    with open(path, "rb") as stream:
        stream.seek(0, 2)
        if stream.tell() < 2 * len(MCAP_MAGIC):
            return False
        stream.seek(-len(MCAP_MAGIC), 2)
        return stream.read() == MCAP_MAGIC


def recover(source: Path, target: Path) -> Recovered:
    """Copy every complete record's schema, channel and message of ``source`` into ``target``, ended properly."""
    result = Recovered(complete=ends_properly(source))
    with open(source, "rb") as stream:
        if stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise NotRecoverable("not an MCAP file (its first bytes are not MCAP's magic)")
        stream.seek(0)
        records = StreamReader(stream, emit_chunks=False)
        writer: Writer | None = None
        schemas: dict[int, int] = {}  # the source's ids to the copy's
        channels: dict[int, int] = {}
        topics: dict[int, str] = {}
        profile, library, compression = "", "", CompressionType.NONE
        with open(target, "wb") as output:
            try:
                for record in records.records:
                    if isinstance(record, Header):
                        profile, library = record.profile, record.library
                    elif isinstance(record, Chunk) and writer is None:
                        compression = COMPRESSIONS.get(record.compression, CompressionType.NONE)
                    if writer is None and isinstance(record, (Schema, Channel, Message)):
                        writer = Writer(output, compression=compression)
                        writer.start(profile=profile, library=library)
                    if isinstance(record, Schema) and writer is not None and record.id not in schemas:
                        schemas[record.id] = writer.register_schema(record.name, record.encoding, record.data)
                    elif isinstance(record, Channel) and writer is not None and record.id not in channels:
                        channels[record.id] = writer.register_channel(
                            record.topic, record.message_encoding, schemas.get(record.schema_id, 0),
                            dict(record.metadata))
                        topics[record.id] = record.topic
                    elif isinstance(record, Message) and writer is not None and record.channel_id in channels:
                        writer.add_message(channels[record.channel_id], record.log_time, record.data,
                                           record.publish_time, record.sequence)
                        topic = topics[record.channel_id]
                        result.messages[topic] = result.messages.get(topic, 0) + 1
            except (McapError, EOFError, ValueError) as error:  # the unfinished tail of a killed recorder
                result.problem = str(error) or type(error).__name__
            if writer is None:
                writer = Writer(output)
                writer.start(profile=profile, library=library)
            writer.finish()
    return result
