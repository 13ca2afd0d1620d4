"""Time the simulated LiDAR at the default scan size and at 4x and 16x the point count.

Per size it prints the median over many frames, in milliseconds, of
  render still   a frame of a scene that did not change (cached geometry: noise and x, y, z only)
  render moving  a frame after two circles moved (ray casting redone)
  + message      render moving, then the PointCloud2 with its data_ as one bytes block
and with --write, over loopback (two participants on --domain, a reader matched, the QoS of --profile: by default
the Lidar profile the application uses), of
  write fast     DataWriter.write of that message with automotive.cyclone.fastpath enabled (data_ in one block)
  write stock    the same with Cyclone's own serializer (data_ one element at a time; fewer frames)
  frame          circles moved, render, message, write fast: what the LiDAR application does per period
                 (without --write: render moving + message)
  rate           frames a second one core could make at that cost (1000 / frame)
  core@20Hz      the share of one core the LiDAR needs at its default 20 Hz (frame x 20 / 1000)
The last lines say how each cost grows with the point count.

The Lidar profile's writer is synchronous: its write sends the cloud in the writing thread, as every default-QoS
reader needs. --profile LidarAsync times the opt-in asynchronous writer (a latency budget: the write returns once
the sample is queued and a send thread sends it); --profile none a writer with Cyclone's default QoS.

Samples over the PointCloud2_.data_ bound (POINT_CLOUD_MAX_DATA, 368,640 bytes, from RTI's IDL) are refused by
the fast path; for the 4x and 16x rows the benchmark raises that bound for itself (a reader with RTI's bound
would not accept them).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections.abc import Callable

from automotive import config, cyclone
from automotive.bus.cli import ArgumentParser, add_domain_option
from automotive.bus.network import NetworkConfig
from automotive.bus.qos import QosProfiles
from automotive.cyclone.matched import matched_subscriptions
from automotive.sim.scene import LidarScene, ScanGrid
from automotive.types.sensor_msgs.msg.dds_ import POINT_CLOUD_MAX_DATA, PointCloud2_

PROG = "automotive bench lidar"
SIZES = (("1x", 1, 1), ("4x", 2, 2), ("16x", 4, 4))  # (label, azimuth factor, polar factor)
LIBRARY = "AutomotiveLibrary"
RATE_HZ = 20


def median_ms(samples: list[float]) -> float:
    return statistics.median(samples) * 1e3


def time_frames(frames: int, before: Callable[[int], None], body: Callable[[], object]) -> float:
    samples = []
    for i in range(frames):
        before(i)
        start = time.perf_counter()
        body()
        samples.append(time.perf_counter() - start)
    return median_ms(samples)


def make_writer(domain_id: int, profile: str, timeout_s: float = 10.0
                ) -> tuple[Callable[[PointCloud2_], None], Callable[[], None]]:
    """(write, drain): write one PointCloud2 on rt/LidarTopic to a matched reader; take what that reader holds."""
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    writer_qos = reader_qos = None
    if profile != "none":
        profiles = QosProfiles(config.qos_file())
        writer_qos, reader_qos = profiles.writer_qos(LIBRARY, profile), profiles.reader_qos(LIBRARY, profile)
    # Two participants, so that the samples go through the loopback network rather than in-process delivery.
    writer_side, reader_side = DomainParticipant(domain_id), DomainParticipant(domain_id)
    writer = DataWriter(writer_side, Topic(writer_side, "rt/LidarTopic", PointCloud2_), qos=writer_qos)
    reader = DataReader(reader_side, Topic(reader_side, "rt/LidarTopic", PointCloud2_), qos=reader_qos)
    deadline = time.monotonic() + timeout_s
    while not matched_subscriptions(writer):
        if time.monotonic() > deadline:
            raise SystemExit(f"{PROG}: no reader matched the writer on domain {domain_id} within {timeout_s} s")
        time.sleep(0.01)

    def write(msg: PointCloud2_) -> None:
        writer.write(msg)

    def drain() -> None:
        reader.take(N=16)  # keeps the reader's history small; outside the timed part

    return write, drain


def growth(rows: list[tuple[str, int, dict[str, float]]]) -> list[str]:
    """How each cost grows from the first row: the cost ratio next to the point-count ratio."""
    _, base_points, base = rows[0]
    lines = []
    for label, points, costs in rows[1:]:
        ratios = ", ".join(f"{name} x{costs[name] / base[name]:.1f}" for name in costs
                           if base.get(name) and costs[name] == costs[name])
        lines.append(f"{label}: {points / base_points:.0f}x the points -> {ratios}")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=200, help="frames per measurement at 1x (fewer when larger)")
    parser.add_argument("--write", action="store_true", help="also time DataWriter.write over loopback")
    add_domain_option(parser, 50, "domain id for --write")
    parser.add_argument("--profile", default="Lidar",
                        help="QoS profile of the writer and reader for --write (default Lidar; none: Cyclone's "
                             "defaults)")
    args = parser.parse_args(argv)
    if args.frames < 1:
        print(f"{PROG}: --frames {args.frames}: expected at least 1", file=sys.stderr)
        return 2

    # Before any participant exists: all traffic of this benchmark stays on loopback.
    os.environ["CYCLONEDDS_URI"] = NetworkConfig().cyclone_xml()
    fast_paths_on = cyclone.start()
    if args.write and not fast_paths_on:
        print(f"{PROG}: --write compares the octet fast path with Cyclone's own serializer, and the fast path is off "
              f"({cyclone.why_off()})", file=sys.stderr)
        return 2
    from automotive.cyclone import fastpath

    write = drain = None
    if args.write:
        try:
            write, drain = make_writer(args.domain, args.profile)
        except Exception as error:  # an unknown profile name, an unreadable QoS file
            print(f"{PROG}: --profile {args.profile}: {error}", file=sys.stderr)
            return 2

    print(f"times: median ms a frame; write: {'QoS profile ' + args.profile if args.write else 'not timed'}")
    print(f"{'size':>4} {'points':>7} {'bytes':>8} {'render still':>12} {'render moving':>13} {'+ message':>9}"
          f" {'write fast':>10} {'write stock':>11} {'frame':>6} {'rate':>8} {'core@20Hz':>9}")
    rows: list[tuple[str, int, dict[str, float]]] = []
    for label, fa, fp in SIZES:
        grid = ScanGrid().scaled(fa, fp)
        frames = max(5, args.frames // (fa * fp))
        scene = LidarScene(grid, seed=1)
        scene.update_shape("YELLOW", 120, 135, 30)
        scene.update_shape("BLUE", 200, 135, 60)
        scene.update_shape("ORANGE", 60, 200, 90)
        scene.update_shape("RED", 150, 60, 45)
        scene.update_shape("GREEN", 40, 100, 30)

        def move(i: int) -> None:
            scene.update_shape("RED", 150 + i % 40, 60, 45)  # noqa: B023  # the loop's own scene
            scene.update_shape("BLUE", 200, 135 + i % 30, 60)  # noqa: B023

        still = time_frames(frames, lambda i: None, scene.render)
        moving = time_frames(frames, move, scene.render)
        message = time_frames(frames, move, lambda: scene.point_cloud2(1, 0))  # noqa: B023
        fast = stock = frame = float("nan")
        if write is not None and drain is not None:
            fastpath.enforce_bound(PointCloud2_, "data_", max(POINT_CLOUD_MAX_DATA, grid.sample_bytes))
            msg = scene.point_cloud2(1, 0)

            def clear(i: int) -> None:
                drain()  # noqa: B023

            def whole_frame(i: int) -> None:
                move(i)  # noqa: B023
                write(scene.point_cloud2(1, 0))  # noqa: B023

            fast = time_frames(frames, clear, lambda: write(msg))  # noqa: B023
            frame_times = []
            for i in range(frames):
                drain()
                start = time.perf_counter()
                whole_frame(i)
                frame_times.append(time.perf_counter() - start)
            frame = median_ms(frame_times)
            fastpath.disable()
            stock = time_frames(max(3, 30 // (fa * fp)), clear, lambda: write(msg))  # noqa: B023
            fastpath.enable()
        else:
            frame = message  # no DDS: the cost of rendering the frame into its message
        columns = ["n/a" if value != value else f"{value:.2f}" for value in (fast, stock)]
        print(f"{label:>4} {grid.point_count:>7} {grid.sample_bytes:>8} {still:12.2f} {moving:13.2f} {message:9.2f}"
              f" {columns[0]:>10} {columns[1]:>11} {frame:6.2f} {1000 / frame:6.0f}/s {frame * RATE_HZ / 10:8.1f}%")
        rows.append((label, grid.point_count, {"render moving": moving, "message": message, "write fast": fast,
                                                "frame": frame}))
    print("cost growth from 1x:")
    for line in growth(rows):
        print(f"  {line}")
    if not args.write:
        print("write: run with --write to time DataWriter.write on loopback (domain --domain, default 50)")
    print(f"lidar_frame_ms={rows[0][2]['frame']:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
