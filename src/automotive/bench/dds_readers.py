"""Foreign DDS readers of the large flows, for `automotive bench system --dds-readers`.

    python -m automotive.bench.dds_readers --domain 84

A plain Cyclone DDS Python participant, outside the project's runtime (no QoS profile, no shared-memory mark, no
checked reader): one DataReader of the camera's frames (CameraImageData) and one of the LiDAR's clouds
(rt/LidarTopic), each on Cyclone's default QoS, as `cyclonedds subscribe` or any other vendor's default reader joins
a topic. The writers on its host see a DDS reader they must serve on DDS. It takes (and deserializes, as such a reader
does) every sample that comes, prints ``reading`` once both readers matched a writer, and on SIGTERM or Ctrl-C one
line ``dds_readers camera_frames=N lidar_clouds=M`` and exits 0.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.domain import DomainParticipant
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from automotive.bus.errors import ConfigError
from automotive.cyclone.matched import matched_publications
from automotive.tools.support.children import exit_on_sigterm
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.wire.camera import frame_type

READY_LINE = "reading"
WAIT_S = 0.2


def read(domain: int, image_size: str) -> dict[str, int]:
    participant = DomainParticipant(domain)
    readers: dict[str, DataReader[Any]] = {
        "camera_frames": DataReader(participant, Topic(participant, "CameraImageData", frame_type(image_size))),
        "lidar_clouds": DataReader(participant, Topic(participant, "rt/LidarTopic", PointCloud2_)),
    }
    waitset = WaitSet(participant)
    for reader in readers.values():
        waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any))
    counts = dict.fromkeys(readers, 0)
    ready = False
    try:
        while True:
            waitset.wait(duration(seconds=WAIT_S))
            for name, reader in readers.items():
                counts[name] += sum(1 for sample in reader.take(N=16) if sample.sample_info.valid_data)
            if not ready and all(matched_publications(reader) for reader in readers.values()):
                ready = True
                print(READY_LINE, flush=True)
    except (KeyboardInterrupt, SystemExit):
        return counts


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m automotive.bench.dds_readers", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--domain", type=int, default=0, help="DDS domain id (default 0)")
    parser.add_argument("--image-size", default="full", help="the camera's config.imageSize (default full)")
    args = parser.parse_args(argv)
    try:
        frame_type(args.image_size, "--image-size")
    except ConfigError as error:
        print(f"{parser.prog}: {error}", file=sys.stderr)
        return 2
    with exit_on_sigterm():
        counts = read(args.domain, args.image_size)
    print("dds_readers " + " ".join(f"{name}={count}" for name, count in counts.items()), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
