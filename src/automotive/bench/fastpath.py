"""Time serialize and deserialize of large octet members with and without automotive.cyclone.fastpath (prints, no
checks).

Rows: a 4 MiB unbounded sequence<octet> (a type declared here), PointCloud2_ at POINT_CLOUD_MAX_DATA, and the
4 MiB camera frame (octet[N] array, already one block in Cyclone; the fast path saves a copy when reading).
Per row and representation: median milliseconds over --repeat runs (fewer for the slow stock path), and the ratio.
"""

import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

# No "from __future__ import annotations": cyclonedds resolves the annotations of the IDL class below itself.
import cyclonedds.idl.annotations as annotate
import cyclonedds.idl.types as types
from cyclonedds.idl import IdlStruct

from automotive import cyclone
from automotive.bus.cli import ArgumentParser
from automotive.types.builtin_interfaces.msg.dds_ import Time_
from automotive.types.CameraImage import CameraImageData_4MiB
from automotive.types.sensor_msgs.msg.dds_ import POINT_CLOUD_MAX_DATA, PointCloud2_, PointField_
from automotive.types.std_msgs.msg.dds_ import Header_

PROG = "automotive bench fastpath"
MIB4 = 4 << 20


@dataclass
@annotate.final
class Blob(IdlStruct, typename="bench.Blob"):
    data: types.sequence[types.uint8]  # type: ignore[type-arg]  # Cyclone's IDL annotation


def payload(size: int) -> bytes:
    return bytes(range(256)) * (size // 256) + bytes(size % 256)


def cloud(data: bytes) -> PointCloud2_:
    return PointCloud2_(
        header_=Header_(stamp_=Time_(sec_=1, nanosec_=2), frame_id_="lidar"), height_=1, width_=len(data) // 16,
        fields_=[PointField_(name_=n, offset_=4 * i, datatype_=7, count_=1) for i, n in enumerate("xyz")],
        is_bigendian_=False, point_step_=16, row_step_=len(data), data_=data, is_dense_=True)


ROWS: list[tuple[str, Callable[[], Any]]] = [
    ("sequence<octet> 4 MiB", lambda: Blob(data=payload(MIB4))),  # type: ignore[arg-type]
    (f"PointCloud2_ {POINT_CLOUD_MAX_DATA} B", lambda: cloud(payload(POINT_CLOUD_MAX_DATA))),
    ("octet[4194304] camera", lambda: CameraImageData_4MiB(id=1, sec_=2, nanosec_=3, seqnum=4, data=payload(MIB4))),
]


def median_ms(action: Callable[[], Any], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        action()
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e3


def measure(sample: Any, xcdr2: bool, repeat: int) -> tuple[float, float]:
    data = sample.serialize(use_version_2=xcdr2)
    write = median_ms(lambda: sample.serialize(use_version_2=xcdr2), repeat)
    read = median_ms(lambda: type(sample).deserialize(data), repeat)
    return write, read


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--repeat", type=int, default=10, help="runs per measurement with the fast path")
    parser.add_argument("--stock-repeat", type=int, default=3, help="runs per measurement without it")
    args = parser.parse_args(argv)
    if args.repeat < 1 or args.stock_repeat < 1:
        print(f"{PROG}: --repeat and --stock-repeat must be at least 1", file=sys.stderr)
        return 2
    if not cyclone.start():
        print(f"{PROG}: the fast path is off ({cyclone.why_off()}): nothing to compare", file=sys.stderr)
        return 2
    from automotive.cyclone import fastpath

    print(f"{'':24} {'repr':5} {'stock write':>12} {'fast write':>11} {'x':>6}  "
          f"{'stock read':>11} {'fast read':>10} {'x':>6}   (median ms)")
    ratios = []
    for label, make in ROWS:
        sample = make()
        for xcdr2 in (False, True):
            fastpath.disable()
            stock = measure(sample, xcdr2, args.stock_repeat)
            fastpath.enable()
            fast = measure(sample, xcdr2, args.repeat)
            print(f"{label:24} {'XCDR2' if xcdr2 else 'XCDR1':5} {stock[0]:12.2f} {fast[0]:11.2f} "
                  f"{stock[0] / fast[0]:6.1f}  {stock[1]:11.2f} {fast[1]:10.2f} {stock[1] / fast[1]:6.1f}")
            ratios.append(stock[0] / fast[0])
    print(f"fastpath_write_speedup_sequence_4MiB={ratios[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
