"""PointCloud2 on the wire (ROS 2 ``sensor_msgs/msg/PointCloud2``): the point layout this system sends, a message
from an array of points, and the points of any PointCloud2 with x, y, z and rgb fields.

A point is four little-endian float32 (x, y, z, rgb) where rgb holds the bits of the uint32 0x00RRGGBB, the packing
RViz2 reads; points are laid out row by row.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from automotive.bus.samplerules import (  # noqa: F401  (the datatypes are this codec's names too)
    DATATYPE_CODES,
    FLOAT32,
    FLOAT64,
    INT8,
    INT16,
    INT32,
    UINT8,
    UINT16,
    UINT32,
)
from automotive.types.builtin_interfaces.msg.dds_ import Time_
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_, PointField_
from automotive.types.std_msgs.msg.dds_ import Header_

# sensor_msgs/PointField datatypes (ROS 2), with the rules of received clouds (automotive.bus.samplerules).
_DATATYPE_CODES = DATATYPE_CODES

POINT_STEP = 16
# One point as it goes on the wire. rgb is declared float32 (as the PointField says) but carries uint32 bits.
POINT_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<f4")])
POINT_FIELDS: tuple[tuple[str, int], ...] = (("x", 0), ("y", 4), ("z", 8), ("rgb", 12))
FRAME_ID = "map"


def pack_rgb(r: int, g: int, b: int) -> int:
    """The uint32 0x00RRGGBB of a colour."""
    return ((int(r) & 0xFF) << 16) | ((int(g) & 0xFF) << 8) | (int(b) & 0xFF)


def stamp_from_seconds(t: float) -> tuple[int, int]:
    """(sec, nanosec) of a time in seconds, for a PointCloud2 header."""
    ns = int(round(t * 1e9))
    return ns // 1_000_000_000, ns % 1_000_000_000


# -- PointCloud2 -------------------------------------------------------------------------------------------------------


def point_fields() -> list[PointField_]:
    """x, y, z, rgb: one FLOAT32 each, at offsets 0, 4, 8, 12."""
    return [PointField_(name_=name, offset_=offset, datatype_=FLOAT32, count_=1) for name, offset in POINT_FIELDS]


def to_point_cloud2(points: npt.NDArray[Any], stamp_sec: int, stamp_nanosec: int,
                    frame_id: str = FRAME_ID) -> PointCloud2_:
    """A PointCloud2 of a rendered scan (``POINT_DTYPE``, shape (height, width) or (count,)); ``data_`` is bytes."""
    if points.dtype != POINT_DTYPE:
        raise ValueError(f"points: expected dtype {POINT_DTYPE}, got {points.dtype}")
    if points.ndim == 1:
        height, width = 1, points.shape[0]
    elif points.ndim == 2:
        height, width = points.shape
    else:
        raise ValueError(f"points: expected shape (height, width) or (count,), got {points.shape}")
    return PointCloud2_(
        header_=Header_(stamp_=Time_(sec_=int(stamp_sec), nanosec_=int(stamp_nanosec)), frame_id_=frame_id),
        height_=height,
        width_=width,
        fields_=point_fields(),
        is_bigendian_=False,
        point_step_=POINT_STEP,
        row_step_=width * POINT_STEP,
        data_=points.tobytes(),  # type: ignore[arg-type]  # one block; the serializer's fast path takes bytes
        is_dense_=True,
    )


# The encapsulations read in place, with their byte order: XCDR1 (what our writers send, automotive.bus.qos) and
# XCDR2's D_CDR2, where each appendable struct (the cloud, its header, the stamp) and the sequence of fields (structs)
# begin with a DHEADER, their length, skipped here. A cloud of any other encapsulation is deserialized whole.
_XCDR1 = {0x0000: ">", 0x0001: "<"}
_D_CDR2 = {0x0008: ">", 0x0009: "<"}
_MAX_FIELDS = 4  # PointCloud2_.fields_ is a sequence<PointField_, 4>


class _Cursor:
    """The members of a serialized sample one after the other, each aligned as CDR aligns it: from the end of the
    4-byte encapsulation header, to its own size (XCDR2 aligns to 4 at most: the same for these members)."""

    def __init__(self, data: memoryview, order: str):
        self.data = data
        self.order = order
        self.at = 4

    def _unpack(self, code: str, size: int) -> int:
        self.at += -(self.at - 4) % size
        if self.at + size > len(self.data):
            raise ValueError(f"{len(self.data)} bytes, ending inside the member at byte {self.at}")
        (value,) = struct.unpack_from(self.order + code, self.data, self.at)
        self.at += size
        return int(value)

    def uint32(self) -> int:
        return self._unpack("I", 4)

    def int32(self) -> int:
        return self._unpack("i", 4)

    def uint8(self) -> int:
        return self._unpack("B", 1)

    def skip(self, size: int) -> None:
        if self.at + size > len(self.data):
            raise ValueError(f"{len(self.data)} bytes, too few for the {size} bytes at byte {self.at}")
        self.at += size

    def string(self) -> str:
        length = self.uint32()  # with its terminating NUL
        start = self.at
        if length == 0:
            raise ValueError(f"a string of length 0 at byte {start} (at least its NUL expected)")
        self.skip(length)
        return bytes(self.data[start:start + length - 1]).decode("utf-8")  # UnicodeDecodeError is a ValueError


def read_cloud(serialized: memoryview) -> tuple[PointCloud2_, slice | None]:
    """The header and layout of a serialized PointCloud2 (CDR, its encapsulation header first), read in place: a
    PointCloud2_ whose ``data_`` is empty, and where its data lie in ``serialized``. A cloud of an encapsulation not
    read in place is deserialized whole: the cloud with its data, and None. Raises ValueError for bytes that are not
    a PointCloud2."""
    if len(serialized) < 4:
        raise ValueError(f"{len(serialized)} bytes, too few for an encapsulation header")
    encapsulation = (serialized[0] << 8) | serialized[1]
    order = _XCDR1.get(encapsulation) or _D_CDR2.get(encapsulation)
    if order is None:
        try:
            return PointCloud2_.deserialize(bytes(serialized)), None
        except Exception as error:  # whatever the deserializer raises for bytes it cannot decode
            raise ValueError(f"encapsulation 0x{encapsulation:04x}: {error}") from None
    cursor = _Cursor(serialized, order)
    dheaders = 1 if encapsulation in _D_CDR2 else 0
    for _ in range(3 * dheaders):  # the cloud's, its header's, its stamp's
        cursor.uint32()
    stamp = Time_(sec_=cursor.int32(), nanosec_=cursor.uint32())
    header = Header_(stamp_=stamp, frame_id_=cursor.string())
    height, width = cursor.uint32(), cursor.uint32()
    for _ in range(dheaders):  # the sequence of fields'
        cursor.uint32()
    count = cursor.uint32()
    if count > _MAX_FIELDS:
        raise ValueError(f"{count} fields (a PointCloud2 has at most {_MAX_FIELDS})")
    # keyword arguments are evaluated in order: the members as they are serialized
    fields = [PointField_(name_=cursor.string(), offset_=cursor.uint32(), datatype_=cursor.uint8(),
                          count_=cursor.uint32()) for _ in range(count)]
    is_bigendian = bool(cursor.uint8())
    point_step, row_step = cursor.uint32(), cursor.uint32()
    length = cursor.uint32()
    start = cursor.at
    cursor.skip(length)
    cloud = PointCloud2_(header_=header, height_=height, width_=width, fields_=fields, is_bigendian_=is_bigendian,
                         point_step_=point_step, row_step_=row_step, data_=[], is_dense_=bool(cursor.uint8()))
    return cloud, slice(start, start + length)


class CloudBuffer:
    """One serialized PointCloud2 of a fixed layout, written anew for each scan: the points rendered into its data
    (:attr:`points`) and its stamp packed into its header (:meth:`stamp`), in place.

    ``template`` is a cloud of that layout serialized as its writer sends it (``automotive.cyclone.serdata``), in
    an encapsulation :func:`read_cloud` reads in place; every scan then makes the very same bytes without a message
    object, a serializer pass or a fresh 184 KB buffer (the LiDAR at 20 Hz: about 0.7 ms a scan saved on a cold
    cache, docs/measurements/shared-memory-default.md)."""

    def __init__(self, template: bytes | bytearray):
        self.buffer = bytearray(template)
        cloud, where = read_cloud(memoryview(self.buffer))
        encapsulation = (self.buffer[0] << 8) | self.buffer[1]
        if where is None or cloud.point_step_ != POINT_STEP or len(cloud.fields_) != len(POINT_FIELDS):
            raise ValueError(f"a cloud buffer needs a cloud of {POINT_STEP}-byte points x, y, z, rgb in XCDR1 or "
                             f"D_CDR2, got encapsulation 0x{encapsulation:04x}, point_step {cloud.point_step_}")
        order = _XCDR1.get(encapsulation) or _D_CDR2[encapsulation]
        # The stamp is the first member, after the DHEADERs of the cloud, its header and the stamp (XCDR2 only).
        self._stamp_at = 4 + (12 if encapsulation in _D_CDR2 else 0)
        self._stamp = struct.Struct(order + "iI")
        self.points: npt.NDArray[np.float32] = np.frombuffer(
            self.buffer, dtype=np.float32, count=int(cloud.height_) * int(cloud.width_) * 4,
            offset=where.start).reshape(-1, 4)
        self.data = memoryview(self.buffer)

    def stamp(self, sec: int, nanosec: int) -> None:
        """Set the header's stamp."""
        self._stamp.pack_into(self.buffer, self._stamp_at, sec, nanosec)


def _field(fields: dict[str, Any], names: Sequence[str]) -> Any:
    for name in names:
        if name in fields:
            return fields[name]
    return None


def decode_point_cloud2(msg: Any) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """x, y, z (float32, N x 3) and r, g, b (uint8, N x 3) of any PointCloud2 with x, y, z and rgb (or rgba) fields.

    Offsets, point_step, row_step (rows may be padded) and byte order come from the message; ``data_`` may be bytes,
    a bytes-like object, or a list of ints. N = height * width. Raises ValueError when the message cannot hold
    such points.
    """
    fields = {f.name_: f for f in msg.fields_}
    wanted = {"x": ("x",), "y": ("y",), "z": ("z",), "rgb": ("rgb", "rgba")}
    found = {key: _field(fields, names) for key, names in wanted.items()}
    missing = [key for key, field in found.items() if field is None]
    if missing:
        have = ", ".join(sorted(fields)) or "none"
        raise ValueError(f"PointCloud2: missing field(s) {', '.join(missing)} (fields present: {have})")
    order = ">" if msg.is_bigendian_ else "<"
    height, width = int(msg.height_), int(msg.width_)
    point_step, row_step = int(msg.point_step_), int(msg.row_step_)
    names, formats, offsets = [], [], []
    for key, field in found.items():
        code = _DATATYPE_CODES.get(int(field.datatype_))
        if code is None:
            raise ValueError(f"PointCloud2: field {field.name_} has unknown datatype {field.datatype_}")
        if key == "rgb":
            if code[1] != "4":
                raise ValueError(f"PointCloud2: field {field.name_} has datatype {field.datatype_}; expected a "
                                 "4-byte type holding 0x00RRGGBB (FLOAT32, UINT32 or INT32)")
            code = "u4"  # the bits, whatever type the field claims
        if int(field.count_) not in (0, 1):  # ROS writers sometimes leave count 0 for a single value
            raise ValueError(f"PointCloud2: field {field.name_} has count {field.count_}; expected 1")
        size = int(code[1])
        if int(field.offset_) + size > point_step:
            raise ValueError(f"PointCloud2: field {field.name_} at offset {field.offset_} does not fit in "
                             f"point_step {point_step}")
        names.append(key)
        formats.append(order + code)
        offsets.append(int(field.offset_))
    if height * width == 0:
        return np.empty((0, 3), dtype=np.float32), np.empty((0, 3), dtype=np.uint8)
    if row_step < width * point_step:
        raise ValueError(f"PointCloud2: row_step {row_step} is less than width {width} x point_step {point_step}")
    data = msg.data_
    if isinstance(data, (bytes, bytearray, memoryview)):
        buffer = np.frombuffer(data, dtype=np.uint8)
    else:
        buffer = np.asarray(data, dtype=np.uint8)
    needed = row_step * (height - 1) + width * point_step
    if buffer.size < needed:
        raise ValueError(f"PointCloud2: data has {buffer.size} bytes; height {height}, width {width}, "
                         f"row_step {row_step} and point_step {point_step} need {needed}")
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step})
    points = np.ndarray((height, width), dtype=dtype, buffer=buffer, strides=(row_step, point_step)).reshape(-1)
    xyz = np.empty((points.size, 3), dtype=np.float32)
    xyz[:, 0] = points["x"]
    xyz[:, 1] = points["y"]
    xyz[:, 2] = points["z"]
    packed = points["rgb"]
    rgb = np.empty((points.size, 3), dtype=np.uint8)
    rgb[:, 0] = packed >> 16
    rgb[:, 1] = packed >> 8
    rgb[:, 2] = packed
    return xyz, rgb
