"""Helpers of the LiDAR tests: Shapes Demo coordinates, colour filters and an in-process rt/LidarTopic reader."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import numpy.typing as npt
from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.sub import DataReader

from automotive.bus.endpoints import Databus
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.wire.pointcloud import decode_point_cloud2


def circle(world_x: float, world_y: float) -> tuple[int, int]:
    """Shapes Demo canvas coordinates of a ground position in metres (x' = (x - 120) / 24, y' = (y - 135) / 27)."""
    return round(120 + 24 * world_x), round(135 + 27 * world_y)


def with_colour(xyz: npt.NDArray[np.float32], rgb: npt.NDArray[np.uint8], colour: tuple[int, int, int]
                ) -> npt.NDArray[np.float32]:
    return xyz[(rgb == np.array(colour, dtype=np.uint8)).all(axis=1)]


def points_of(cloud: PointCloud2_, colour: tuple[int, int, int]) -> npt.NDArray[np.float32]:
    return with_colour(*decode_point_cloud2(cloud), colour)


def colours_of(cloud: PointCloud2_) -> set[tuple[int, int, int]]:
    _, rgb = decode_point_cloud2(cloud)
    return {tuple(c) for c in np.unique(rgb, axis=0).tolist()}


def stamp_s(cloud: PointCloud2_) -> float:
    return cloud.header_.stamp_.sec_ + cloud.header_.stamp_.nanosec_ * 1e-9


class Clouds:
    """An in-process reader of rt/LidarTopic (Lidar profile) with bounded waits for clouds that satisfy a condition.

    "After" a scene change means clouds stamped after the test saw the LiDAR log the change: the LiDAR applies the
    circles it took, then stamps and renders the frame, so such clouds show the new scene.
    """

    def __init__(self, bus: Databus):
        self.reader: DataReader[PointCloud2_] = bus.reader("rt/LidarTopic", PointCloud2_, "Lidar")
        self.waitset = WaitSet(bus.participant)
        self.waitset.attach(ReadCondition(self.reader, SampleState.Any | ViewState.Any | InstanceState.Any))

    def next(self, accept: Callable[[PointCloud2_], bool], what: str, count: int = 1,
             timeout: float = 20.0) -> list[PointCloud2_]:
        """The first ``count`` clouds (in arrival order) that ``accept`` takes; fails after ``timeout`` s."""
        found: list[PointCloud2_] = []
        deadline = time.monotonic() + timeout
        while len(found) < count:
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout:.0f} s waiting for {count} cloud(s) {what}")
            self.waitset.wait(int(0.1e9))
            found.extend(c for c in self.reader.take(N=16) if isinstance(c, PointCloud2_) and accept(c))
        return found[:count]

    def after(self, moment: float, count: int = 3, timeout: float = 20.0) -> list[PointCloud2_]:
        """``count`` clouds stamped after the wall-clock time ``moment``."""
        return self.next(lambda c: stamp_s(c) > moment, f"stamped after {moment:.3f}", count, timeout)
