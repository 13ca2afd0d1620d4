"""What a content filter (automotive.bus.contentfilter) costs per sample: evaluation, the raw path, and a DDS take.

Rows:
- evaluation: nanoseconds to test one received sample against an expression (median over --repeat runs of
  --count evaluations), for filters of the Shapes type and a nested one of the vision type;
- raw path (record, bridge): a serialized sample decoded and tested (automotive.wire.filteredraw) against decoding
  alone, for a ShapeType and a LiDAR cloud of 184,320 bytes;
- DDS take: microseconds per sample taken from a reader, plain (a CheckedReader) and filtered (a FilteredReader, half
  the samples pass), --samples samples written by a writer of the same participant (loopback, reliable, keep all);
  medians of --rounds.

The last line is ``filter_ns_per_sample=<ns>``: evaluating "color = 'RED' AND x BETWEEN 10 AND 200" on a ShapeType.
"""

from __future__ import annotations

import argparse
import logging
import os
import statistics
import sys
import time
from collections.abc import Callable
from typing import Any

from cyclonedds.qos import Policy

from automotive import config, cyclone
from automotive.bus import validation
from automotive.bus.checkedreader import CheckedReader, decoder
from automotive.bus.cli import ArgumentParser, add_domain_option
from automotive.bus.contentfilter import ContentFilter
from automotive.bus.endpoints import Databus
from automotive.bus.network import NetworkConfig
from automotive.bus.qos import QosProfiles
from automotive.sim.scene import LidarScene, ScanGrid
from automotive.types.automotive import ShapeType
from automotive.types.Common import ClassificationEnum, POSIXTimestamp
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.types.Vision import VisionObject, VisionSensor

PROG = "automotive bench filter"
HEADLINE = "color = 'RED' AND x BETWEEN 10 AND 200"
SHAPE = ShapeType(color="RED", x=120, y=135, shapesize=30)
VISION = VisionSensor(id=3, timestamp=POSIXTimestamp(s=1_763_800_000, ns=5), objects=[
    VisionObject(classification=ClassificationEnum.CLASSIFICATION_CAR, position=[20.0, -1.5, 0.25],
                 velocity=[1.5, 0.0, -0.5], size=[10.0, 3.5, 2.5])] * 4)
EVALUATIONS: list[tuple[str, Any]] = [
    ("shapesize <= 20", SHAPE),
    (HEADLINE, SHAPE),
    ("color LIKE 'R%' OR (x > 100 AND NOT y < 50)", SHAPE),
    ("objects[0].classification = CLASSIFICATION_CAR AND timestamp.s > 0", VISION),
]


def median_ns(action: Callable[[], Any], count: int, repeat: int) -> float:
    runs = []
    for _ in range(repeat):
        start = time.perf_counter_ns()
        for _ in range(count):
            action()
        runs.append((time.perf_counter_ns() - start) / count)
    return statistics.median(runs)


def evaluation_rows(count: int, repeat: int) -> dict[str, float]:
    results = {}
    for expression, sample in EVALUATIONS:
        predicate = ContentFilter.parse(expression).bind(type(sample))
        results[expression] = median_ns(lambda p=predicate, s=sample: p(s), count, repeat)  # type: ignore[misc]
        print(f"evaluation  {type(sample).__name__:<13} {expression:<70} {results[expression]:8.0f} ns")
    return results


def raw_rows(count: int, repeat: int) -> None:
    cloud = LidarScene(ScanGrid(azimuth_steps=180, polar_steps=64), seed=1).point_cloud2(1, 2)
    for sample, expression in ((SHAPE, HEADLINE), (cloud, "width_ > 100 AND header_.frame_id_ = 'map'")):
        data_type = type(sample)
        data = sample.serialize(use_version_2=False)
        predicate = ContentFilter.parse(expression).bind(data_type)
        times = max(count // (100 if data_type is PointCloud2_ else 1), 10)
        decode = decoder(data_type)
        alone = median_ns(lambda d=data, f=decode: f(d), times, repeat)  # type: ignore[misc]

        def decode_check_test(d: bytes = data, p: Any = predicate, decode: Any = decode) -> bool:
            decoded = decode(d)
            return validation.check(decoded) is None and bool(p(decoded))

        tested = median_ns(decode_check_test, times, repeat)
        print(f"raw path    {data_type.__name__:<13} {len(data):>7} B: decode {alone / 1e3:8.2f} us, "
              f"decode, check and test {tested / 1e3:8.2f} us")


def take_once(bus: Databus, topic: str, samples: int, expression: str | None) -> tuple[float, int]:
    """Microseconds per available sample to take them all from a reader (filtered by ``expression``), and how many
    it delivered."""
    keep_all = (Policy.Reliability.Reliable(max_blocking_time=1_000_000_000), Policy.History.KeepAll)
    predicate = None if expression is None else ContentFilter.parse(expression, ["200"]).bind(ShapeType)
    reader = bus.reader(topic, ShapeType, "Shapes", overrides=keep_all, content_filter=predicate)
    writer = bus.writer(topic, ShapeType, "HMI")
    for x in range(samples):
        # x in 0..399, on the Shapes canvas (the reader's checks leave out the rest): half pass "x < 200"
        writer.write(ShapeType(color=f"C{x % 50}", x=x % 400, y=0, shapesize=1))
    assert isinstance(reader, CheckedReader)
    deadline = time.monotonic() + 30
    # CheckedReader's own read: every sample, matching or not
    while len(CheckedReader.read(reader, N=samples)) < samples and time.monotonic() < deadline:
        time.sleep(0.01)  # every sample in the reader before the timing starts
    start = time.perf_counter_ns()
    taken = 0
    while True:
        batch = reader.take(N=256)
        taken += len(batch)
        if len(batch) < 256:
            break
    return (time.perf_counter_ns() - start) / samples / 1e3, taken


def take_rows(domain: int, samples: int, rounds: int) -> tuple[float, float]:
    """Plain and filtered (half the samples pass) takes, alternately, ``rounds`` times; their medians."""
    bus = Databus(domain, QosProfiles(config.qos_file()), "AutomotiveLibrary", logging.getLogger("bench"),
                  NetworkConfig())
    times: dict[str, list[float]] = {"plain": [], "filtered": []}
    delivered: dict[str, int] = {}
    try:
        for round_number in range(rounds):
            for label, expression in (("plain", None), ("filtered", "x < %0")):
                per_sample, delivered[label] = take_once(bus, f"Bench{label}{round_number}", samples, expression)
                times[label].append(per_sample)
    finally:
        bus.close()
    for label in times:
        print(f"DDS take    ShapeType     {label:<9} {samples} samples available, {delivered[label]} delivered: "
              f"{statistics.median(times[label]):6.2f} us per sample taken (median of {rounds})")
    return statistics.median(times["plain"]), statistics.median(times["filtered"])


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--count", type=int, default=20000, help="evaluations per run (default 20000)")
    parser.add_argument("--repeat", type=int, default=5, help="runs per measurement (default 5)")
    parser.add_argument("--samples", type=int, default=4000, help="samples written for the DDS take rows")
    parser.add_argument("--rounds", type=int, default=5, help="plain and filtered takes, alternately (default 5)")
    add_domain_option(parser, 51, "domain id of the DDS take rows")
    args = parser.parse_args(argv)
    if args.count < 1 or args.repeat < 1 or args.rounds < 1 or args.samples < 2:
        print(f"{PROG}: --count, --repeat and --rounds must be at least 1, --samples at least 2", file=sys.stderr)
        return 2
    # Before any participant exists: all traffic of this benchmark stays on loopback.
    os.environ["CYCLONEDDS_URI"] = NetworkConfig().cyclone_xml()
    cyclone.start()
    evaluation = evaluation_rows(args.count, args.repeat)
    raw_rows(args.count, args.repeat)
    plain, filtered = take_rows(args.domain, args.samples, args.rounds)
    print(f"take_plain_us_per_sample={plain:.2f}")
    print(f"take_filtered_us_per_sample={filtered:.2f}")
    print(f"filter_ns_per_sample={evaluation[HEADLINE]:.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
