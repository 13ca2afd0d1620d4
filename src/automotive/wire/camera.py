"""Camera frames on the wire: the frame types by size, and a codec that moves a frame's bytes in one block.

``CameraImage::CameraImageData`` and its sized variants share one layout (``@appendable``): ``@key uint32 id``,
``int32 sec_``, ``uint32 nanosec_``, ``uint32 seqnum``, ``octet data[N]``. Cyclone Python's generic serializer
treats ``data`` as one block already, but it grows its buffer from 512 bytes by doubling and copies the result
twice more (about 11 ms for a 4 MiB frame); reading copies the sample three times (about 3.5 ms). For this one
fixed layout the codec writes the CDR stream itself into a buffer allocated once (the 16 header bytes packed with
``struct``, the image copied in by one ``memcpy``) and hands it to Cyclone's C layer as the writer's serialized
sample (``automotive.wire.rawsample``), and on the reading side it parses the 16 header bytes and returns the image as
a ``memoryview`` of the received buffer, without a copy. ``tests/test_camera.py`` checks that the bytes are those of
Cyclone's serializer, in XCDR1 and XCDR2, both byte orders.

Being the decoder of these samples, the codec also holds them to their type (a writer of another stack may declare
the frame differently under the same type name): the sample's length is the header and the image of exactly the
type's size (a longer one, which Cyclone accepts as an appendable type's extension, is refused) and an XCDR2
sample's DHEADER says that length; then :meth:`FrameCodec.check` wants a well-formed stamp. :class:`FrameReader`
reports a frame that breaks either (automotive.bus.badsamples) and leaves it out.
"""

from __future__ import annotations

import gc
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy
from cyclonedds.sub import DataReader

from automotive.bus import badsamples, latency, memtune
from automotive.bus.badsamples import BadSample, BadSampleError
from automotive.bus.checkedreader import WriterNames, undecodable
from automotive.bus.errors import ConfigError
from automotive.bus.validation import timestamp_problem
from automotive.types.CameraImage import (
    CameraImageData,
    CameraImageData_1MiB,
    CameraImageData_4MiB,
    CameraImageData_64KiB,
)
from automotive.wire.rawsample import RawReader, RawWriter, SampleKind
from automotive.wire.shm import LentShared

# config.imageSize values: the IDL's frame (1366 x 768 x 4 bytes) and the sized variants for trying other sizes.
FRAME_TYPES: dict[str, type[Any]] = {
    "full": CameraImageData,
    "64KiB": CameraImageData_64KiB,
    "1MiB": CameraImageData_1MiB,
    "4MiB": CameraImageData_4MiB,
}

# Encapsulation identifiers (DDS-XTypes 7.6.3.1.2); the low bit is "little endian".
_CDR_BE, _CDR_LE = 0x0000, 0x0001  # XCDR1: no header in front of an appendable struct
_D_CDR2_BE, _D_CDR2_LE = 0x0008, 0x0009  # XCDR2 appendable: a 4-byte DHEADER (the body's length) comes first
_HEADER_FIELDS = 16  # id, sec_, nanosec_, seqnum
_LITTLE_FIELDS = struct.Struct("<IiII")
_BIG_FIELDS = struct.Struct(">IiII")


# The camera processes' glibc thresholds (automotive.bus.memtune): 4 MiB frames stay in the heap for reuse.
_MMAP_THRESHOLD_BYTES = 64 * 1024 * 1024
_KEEP_HEAP_BYTES = 256 * 1024 * 1024


def tune_process_for_large_frames() -> None:
    """Cheaper memory management for a process that allocates and frees several 4 MiB buffers per frame.

    Cyclone allocates each sample (and the Python layer a bytes object per received sample). With glibc's defaults
    a freed 4 MiB block goes back to the kernel (munmap, or a heap trim), and the next one is paid again in page
    faults: about a quarter of the camera processes' time in a profile. Raising the mmap and trim thresholds keeps
    freed blocks in the heap for reuse. ``gc.freeze`` moves the objects of the set-up (modules, types) out of the
    cyclic collector's way, so the collections that the per-sample objects trigger stay short.
    """
    gc.freeze()
    memtune.set_malloc_thresholds(_MMAP_THRESHOLD_BYTES, _KEEP_HEAP_BYTES)  # not glibc: nothing to tune


class FrameSource(Protocol):
    """Frames that are windows of one byte stream (the camera's test pattern, :mod:`automotive.sim.lfsr`): frame
    ``seqnum`` is ``stream[offset(seqnum):offset(seqnum) + size]``, so a writer can send it without a copy."""

    size: int
    stream: bytes

    def offset(self, seqnum: int) -> int: ...

    def frame(self, seqnum: int) -> memoryview: ...


def writes_xcdr2(writer: DataWriter[Any]) -> bool:
    """Whether ``writer`` writes XCDR2, by the rule of Cyclone's DataWriter.write: XCDR1 when its data
    representation allows only XCDR1, XCDR2 when it allows only XCDR2, else the type's own (XCDR2 for the
    appendable frame types)."""
    qos = writer.get_qos()
    if Policy.DataRepresentation not in qos:
        return True
    policy = qos[Policy.DataRepresentation]
    return not (policy.use_cdrv0_representation and not policy.use_xcdrv2_representation)


def frame_size(data_type: type[Any]) -> int:
    """The image size in bytes of a frame type (the bound of its ``data`` array)."""
    return int(data_type.__annotations__["data"].__metadata__[0].length)


def frame_type(value: str, where: str = "config.imageSize") -> type[Any]:
    """The frame type named by a ``config.imageSize`` value: a name of :data:`FRAME_TYPES` or its size in bytes."""
    text = value.strip()
    for name, data_type in FRAME_TYPES.items():
        if text.lower() == name.lower() or text == str(frame_size(data_type)):
            return data_type
    choices = ", ".join(f"{name} ({frame_size(data_type)} bytes)" for name, data_type in FRAME_TYPES.items())
    raise ConfigError(f"{where} = '{value}' is not a known frame size (expected one of: {choices})")


def max_frame_length(data_type: type[Any]) -> int:
    """The longest serialized frame of a type: XCDR2's header (encapsulation, DHEADER, fields), the image, padding."""
    return 4 + 4 + _HEADER_FIELDS + frame_size(data_type) + 3


@dataclass
class Frame:
    """A received frame: the header fields and the image as a view of the received buffer (no copy)."""

    id: int
    sec_: int
    nanosec_: int
    seqnum: int
    data: memoryview
    writer: int = 0  # the DDS writer's instance handle (0: not from DDS)

    @property
    def timestamp_ns(self) -> int:
        return self.sec_ * 1_000_000_000 + self.nanosec_


class FrameCodec:
    """CDR encoding and decoding of one frame type's samples.

    A serialized sample is ``header_length`` bytes (encapsulation, the DHEADER in XCDR2, the four header fields)
    followed by the image. Writing the header in front of an image that already sits in a buffer is all that
    encoding takes.
    """

    def __init__(self, data_type: type[Any], xcdr2: bool = False, little_endian: bool = True):
        self.data_type = data_type
        self.size = frame_size(data_type)
        self.xcdr2 = xcdr2
        self.little_endian = little_endian
        order = "<" if little_endian else ">"
        encapsulation = (_D_CDR2_BE if xcdr2 else _CDR_BE) | (1 if little_endian else 0)
        self._prefix = struct.pack(">HH", encapsulation, 0)  # the encapsulation identifier is big-endian
        if xcdr2:
            self._prefix += struct.pack(f"{order}I", _HEADER_FIELDS + self.size)
        self._fields = _LITTLE_FIELDS if little_endian else _BIG_FIELDS
        self.header_length = len(self._prefix) + _HEADER_FIELDS

    def pack_header(self, buffer: bytearray | memoryview, start: int, id: int, sec: int, nanosec: int,
                    seqnum: int) -> None:
        """Write the header at ``buffer[start:start + header_length]``; the image follows it."""
        buffer[start:start + len(self._prefix)] = self._prefix
        self._fields.pack_into(buffer, start + len(self._prefix), id, sec, nanosec, seqnum)

    def encode(self, id: int, sec: int, nanosec: int, seqnum: int, image: bytes | bytearray | memoryview) -> bytes:
        """A complete serialized sample (padded to whole 4-byte units, as DataWriter.write pads)."""
        if len(image) != self.size:
            raise ValueError(f"image of {len(image)} bytes for a {self.size}-byte frame")
        buffer = bytearray((self.header_length + self.size + 3) & ~3)
        self.pack_header(buffer, 0, id, sec, nanosec, seqnum)
        buffer[self.header_length:self.header_length + self.size] = image
        return bytes(buffer)

    def decode(self, serialized: bytes | bytearray | memoryview) -> Frame:
        """Parse a serialized sample of this type in any of XCDR1/XCDR2, either byte order."""
        view = memoryview(serialized)
        if len(view) < 4:
            raise ValueError(f"a {len(view)}-byte sample is too short for a CDR header")
        encapsulation = (view[0] << 8) | view[1]
        if encapsulation in (_CDR_BE, _CDR_LE):
            offset = 4
        elif encapsulation in (_D_CDR2_BE, _D_CDR2_LE):
            offset = 8
        else:
            raise ValueError(f"unexpected CDR encapsulation {encapsulation:#06x} for {self.data_type.__name__}")
        fields = _LITTLE_FIELDS if encapsulation & 1 else _BIG_FIELDS
        start = offset + _HEADER_FIELDS
        image = len(view) - start
        # Cyclone pads a serialized sample to whole 4-byte units: up to 3 bytes after the image are padding.
        if not self.size <= image <= self.size + 3:
            what = "too short" if image < self.size else "too long"
            raise BadSampleError(BadSample("data", f"{max(image, 0)} bytes, {what}",
                                           f"a frame of {self.size} bytes ({self.data_type.__name__})"))
        if offset == 8:  # XCDR2: the DHEADER gives the body's length
            body, = struct.unpack_from("<I" if encapsulation & 1 else ">I", view, 4)
            if body != _HEADER_FIELDS + self.size:
                raise BadSampleError(BadSample("DHEADER", str(body), f"{_HEADER_FIELDS + self.size} bytes"))
        id_, sec, nanosec, seqnum = fields.unpack_from(view, offset)
        return Frame(id_, sec, nanosec, seqnum, view[start:start + self.size])

    @staticmethod
    def check(frame: Frame) -> BadSample | None:
        """The rule a decoded frame must follow: a well-formed stamp (automotive.bus.validation's timestamp rule)."""
        return timestamp_problem(frame.sec_, frame.nanosec_, "", "sec_", "nanosec_")


class FrameWriter:
    """Writes frames through a DataWriter of a frame type, bypassing the generic serializer.

    ``write`` copies the image once into a buffer allocated once. ``write_pattern`` copies nothing: the frames of a
    :class:`FrameSource` are windows of one stream, so the writer keeps that stream with room for a header in
    front, writes the header over the bytes just before the frame, hands that span to Cyclone (which copies it
    into its own sample before returning) and puts the borrowed bytes back.
    """

    def __init__(self, writer: DataWriter[Any], pattern: FrameSource | None = None):
        self.writer = writer
        self._raw = RawWriter(writer)
        self.codec = FrameCodec(writer.data_type, xcdr2=writes_xcdr2(writer))
        length = self.codec.header_length + self.codec.size
        self._padded_length = (length + 3) & ~3  # Cyclone takes whole 4-byte units, as DataWriter.write pads
        self._buffer = bytearray(self._padded_length)
        self._view = memoryview(self._buffer)
        self.pattern = pattern
        if pattern is not None:
            if pattern.size != self.codec.size:
                raise ValueError(f"a {pattern.size}-byte pattern for {self.codec.size}-byte frames")
            padding = self._padded_length - length
            self._stream = bytearray(self.codec.header_length) + pattern.stream + bytes(padding)
            self._stream_view = memoryview(self._stream)

    def write(self, id: int, seqnum: int, image: bytes | bytearray | memoryview) -> int:
        """Write one frame (one copy of the image); return its timestamp (ns), taken just before the write."""
        if len(image) != self.codec.size:
            raise ValueError(f"image of {len(image)} bytes for a {self.codec.size}-byte frame")
        start = self.codec.header_length
        self._view[start:start + self.codec.size] = image
        return self._write_span(self._view, 0, id, seqnum)

    def write_pattern(self, id: int, seqnum: int, stamp: int | None = None) -> int:
        """Write the pattern's frame for ``seqnum`` without copying it, stamped ``stamp`` (ns; None: now, just before
        the write); return its timestamp. With the stamp :meth:`build_pattern_frame` gave, the bytes are the same."""
        if self.pattern is None:
            raise ValueError("this FrameWriter has no pattern")
        start = self.pattern.offset(seqnum)  # the frame's image begins header_length bytes further on
        end = start + self.codec.header_length
        borrowed = bytes(self._stream_view[start:end])
        try:
            return self._write_span(self._stream_view, start, id, seqnum, stamp)
        finally:
            self._stream_view[start:end] = borrowed

    @property
    def serialized_length(self) -> int:
        """Bytes of one serialized frame as this writer writes it (header, image, padding)."""
        return self._padded_length

    def build_pattern_frame(self, target: memoryview, id: int, seqnum: int) -> int:
        """Build the pattern's frame for ``seqnum`` as a complete serialized sample in ``target`` (loaned shared
        memory, ``serialized_length`` bytes): one copy of the image; return its timestamp (ns)."""
        if self.pattern is None:
            raise ValueError("this FrameWriter has no pattern")
        start, end = self.codec.header_length, self.codec.header_length + self.codec.size
        target[start:end] = self.pattern.frame(seqnum)
        target[end:self._padded_length] = bytes(self._padded_length - end)
        stamp = time.time_ns()
        self.codec.pack_header(target, 0, id, *divmod(stamp, 1_000_000_000), seqnum)
        return stamp

    def write_serialized(self, view: memoryview) -> None:
        """Write a complete serialized frame (as :meth:`build_pattern_frame` makes) on DDS."""
        self._raw.write(view)

    def _write_span(self, view: memoryview, start: int, id: int, seqnum: int, stamp: int | None = None) -> int:
        stamp = time.time_ns() if stamp is None else stamp
        sec, nanosec = divmod(stamp, 1_000_000_000)
        self.codec.pack_header(view, start, id, sec, nanosec, seqnum)
        self._raw.write(view[start:start + self._padded_length], stamp)
        return stamp


class TakenFrames:
    """Frames taken in one call, valid inside a ``with`` block.

    Zero-copy: each frame's ``data`` is a view of a lent buffer (the sample Cyclone received and reassembled, lent by
    :meth:`RawReader.lend`, or a shared-memory sample); leaving the block releases the views, then ``release``
    returns the buffers to their owner. Cyclone Python's own take copies each sample twice more (into a zeroed
    buffer, then into a ``bytes``): about 1 ms per 4 MiB frame.
    """

    def __init__(self, frames: list[Frame], release: Callable[[], None]):
        self.frames = frames
        self._release = release

    def __enter__(self) -> list[Frame]:
        return self.frames

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        for frame in self.frames:
            frame.data.release()
        self._release()


class FrameReader:
    """Takes frames from a DataReader of a frame type, without deserializing the image (and, where Cyclone's C
    library lends the received bytes, without copying them)."""

    def __init__(self, reader: DataReader[Any], zero_copy: bool = True,
                 dropped: Callable[[int], bool] = lambda writer: False):
        self.reader = reader
        self.codec = FrameCodec(reader.topic.data_type)
        self._raw = RawReader(reader, zero_copy)
        self._writer_names = WriterNames(reader)
        self.dropped = dropped  # writers whose frames come another way (shared memory): theirs are left out here

    @property
    def zero_copy(self) -> bool:
        return self._raw.zero_copy

    def take(self, limit: int = 16) -> TakenFrames:
        """Take up to ``limit`` samples: ``with reader.take() as frames: ...`` (samples without data are skipped)."""
        lent = self._raw.lend(limit)
        frames: list[Frame] = []
        stamps: dict[int, list[int]] = {}  # writer -> the source timestamps of its frames (their latency)
        try:
            for sample in lent.samples:
                if sample.kind is not SampleKind.DATA or self.dropped(sample.writer):
                    continue
                try:
                    frame = self.codec.decode(sample.data)
                except BadSampleError as error:
                    self.report(error.problem, sample.writer)
                    continue
                except Exception as error:  # any frame another writer sends: never out of the take
                    self.report(undecodable(error, f"a {self.codec.data_type.__name__} frame"), sample.writer)
                    continue
                problem = self.codec.check(frame)
                if problem is not None:
                    frame.data.release()
                    self.report(problem, sample.writer)
                    continue
                frame.writer = sample.writer
                frames.append(frame)
                stamps.setdefault(sample.writer, []).append(sample.source_timestamp)
        except BaseException:
            for frame in frames:
                frame.data.release()
            lent.close()
            raise
        now = time.time_ns()
        for writer, taken in stamps.items():
            latency.recent.record(self.reader.topic.get_name(), self._writer_names.participant(writer), taken, now)
        return TakenFrames(frames, lent.close)

    def report(self, problem: BadSample, writer: int, action: str = "ignored") -> None:
        """Report a bad frame of ``writer`` (rate-limited, automotive.bus.badsamples)."""
        reporter = getattr(self.reader, "reporter", None) or badsamples.reporter()
        reporter.report(self.reader.topic.get_name(), problem, self._writer_names.describe(writer), action)


def shared_frames(lent: LentShared, codec: FrameCodec) -> TakenFrames:
    """The frames of samples lent by shared memory (automotive.wire.shm), valid as long as ``lent``: decoded in place,
    the image a read-only view of the publisher's memory."""
    frames: list[Frame] = []
    try:
        for sample in lent.samples:
            frames.append(codec.decode(sample.data))
    except BaseException:
        for frame in frames:
            frame.data.release()
        lent.close()
        raise
    return TakenFrames(frames, lent.close)
