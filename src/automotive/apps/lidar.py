"""Simulated LiDAR: publishes a point cloud of a scene made of the Shapes Demo circles it sees.

Data flow:  ShapeType on Circle (Shapes Demo, keyed by color)  -->  scene (automotive.wire.pointcloud)
            scene  -->  sensor_msgs::msg::dds_::PointCloud2_ on rt/LidarTopic, every config.pubInterval ms

Readers on this host (sensor fusion, the LiDAR view, the recorder, the Foxglove bridge) get each cloud through shared
memory (automotive.wire.shm), every other reader (RViz2, RTI, Fast DDS, another host) on DDS: the same bytes.

Each circle is a sphere of its Shapes Demo colour; YELLOW moves the observer instead. A circle whose instance is
disposed, or whose writers are all gone, disappears. The scan grid comes from config.azimStart, config.azimRange,
config.azimSteps, config.polarStart, config.polarRange and config.polarSteps (degrees; ROS 2 layout: x, y, z, rgb
float32, 16 bytes a point, one row per polar angle).
"""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np
from cyclonedds.core import InstanceState
from cyclonedds.sub import DataReader

from automotive.bus.app import Application, run
from automotive.bus.badsamples import BadSample
from automotive.bus.checkedreader import CheckedReader
from automotive.bus.clock import now_seconds_nanoseconds
from automotive.bus.errors import ConfigError
from automotive.bus.properties import PropertyKeys
from automotive.sim.scene import LidarScene, ScanGrid
from automotive.types.automotive import ShapeType
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.wire.pointcloud import FRAME_ID, POINT_DTYPE, CloudBuffer, to_point_cloud2
from automotive.wire.sharedflow import FlowWriter

# The property keys it reads beyond the runtime's (automotive.bus.app.RUNTIME_KEYS): any other is refused at start.
PROPERTY_KEYS = PropertyKeys.of("config.azimStart", "config.azimRange", "config.azimSteps", "config.polarStart",
                               "config.polarRange", "config.polarSteps", "config.pubInterval", "config.noise",
                               "config.logEvery", "config.frameId", "config.transport", "config.shmPrefix",
                               roles=["Lidar", "Shapes"])

# Each circle costs a ray-casting step per frame: a writer inventing colours must not make frames slower without end
# (Shapes Demo has eight colours). A circle beyond this many is reported and left out until one leaves.
MAX_SHAPES = 32

GONE_STATES = {
    InstanceState.NotAliveDisposed: "disposed",
    InstanceState.NotAliveNoWriters: "no writers left",
}


SCAN_KEYS = ("config.azimStart", "config.azimRange", "config.azimSteps", "config.polarStart", "config.polarRange",
             "config.polarSteps")


def scan_grid(app: Application) -> ScanGrid:
    props = app.props
    values = {
        "azimuth_start": props.get_float("config.azimStart", 0.0),
        "azimuth_range": props.get_float("config.azimRange", 360.0),
        "azimuth_steps": props.get_int("config.azimSteps", 180),
        "polar_start": props.get_float("config.polarStart", 70.0),
        "polar_range": props.get_float("config.polarRange", 100.0),
        "polar_steps": props.get_int("config.polarSteps", 64),
    }
    try:
        grid = ScanGrid(**values)  # type: ignore[arg-type]
        grid.check_wire_bound()
    except ConfigError as error:  # the grid names the key(s); say where the first of them was set
        named = [key for key in SCAN_KEYS if key in str(error)]
        raise ConfigError(f"{props.where(named[0]) if named else props.source}: {error}") from None
    return grid


class ShapeTracker:
    """Applies the Circle samples of one take to the scene: valid data moves a shape, a gone instance removes it."""

    def __init__(self, scene: LidarScene, app: Application, reader: CheckedReader[ShapeType] | None = None):
        self.scene = scene
        self.log = app.log
        self.reader = reader  # reports circles over MAX_SHAPES
        self.colors: dict[int, str] = {}  # instance handle -> colour, for samples without a usable key

    def apply(self, samples: list[Any]) -> None:
        for sample in samples:
            info = sample.sample_info
            if info.valid_data:
                color = sample.color
                if color not in self.scene.shape_colors and len(self.scene.shape_colors) >= MAX_SHAPES:
                    if self.reader is not None:
                        self.reader.report(BadSample("color", repr(color), f"one of at most {MAX_SHAPES} circles "
                                                     "(the scene is full)"), info)
                    continue
                self.colors[info.instance_handle] = color
                if color not in self.scene.shape_colors:
                    self.log.info("shape %s appeared at (%d, %d), size %d", color, sample.x, sample.y,
                                  sample.shapesize)
                self.scene.update_shape(color, sample.x, sample.y, sample.shapesize)
            gone = GONE_STATES.get(info.instance_state)
            if gone is None:
                continue
            # An invalid sample carries only the key; its colour comes with it, else from an earlier sample.
            key = getattr(sample, "key_sample", sample)
            color = getattr(key, "color", None) or self.colors.get(info.instance_handle)
            self.colors.pop(info.instance_handle, None)
            if color is not None and color in self.scene.shape_colors:
                self.scene.remove_shape(color)
                self.log.info("shape %s removed (%s)", color, gone)


def take_all(reader: DataReader[ShapeType]) -> list[Any]:
    samples: list[Any] = []
    while True:
        batch = reader.take(N=256)
        samples.extend(batch)
        if len(batch) < 256:
            return samples


def body(app: Application) -> None:
    interval_ms = app.props.get_float("config.pubInterval", 50, minimum=1)
    grid = scan_grid(app)
    noise_m = app.props.get_float("config.noise", 0.02, minimum=0)
    log_every = app.props.get_int("config.logEvery", 20, minimum=0)
    frame_id = app.props.get_str("config.frameId", FRAME_ID)
    scene = LidarScene(grid, noise_m=noise_m)
    # frame_id is the one field of unbounded length; 1 KiB holds the rest of a cloud beside its points
    flow = FlowWriter(app, "Lidar", PointCloud2_, "rt/LidarTopic", grid.sample_bytes + 1024 + len(frame_id.encode()))
    circles = app.reader("Shapes", ShapeType, "Circle", optional=True)  # spheres only while Shapes Demo runs
    tracker = ShapeTracker(scene, app, circles if isinstance(circles, CheckedReader) else None)
    app.log.info("lidar: %d azimuth x %d polar steps, %d points, %d bytes a cloud, every %g ms",
                 grid.width, grid.height, grid.point_count, grid.sample_bytes, interval_ms)

    app.status_figure = lambda: (f"{grid.point_count} points, {len(scene.spheres)} sphere(s)"
                                 + (f" {','.join(sphere.color for sphere in scene.spheres)}" if scene.spheres else ""))
    try:
        scan(app, flow, scene, tracker, circles, frame_id, interval_ms, log_every)
    finally:
        if flow.shared is not None:
            app.log.info("shared memory: %d clouds sent, %d written on DDS", flow.sent_shared, flow.sent_dds)
        flow.close()


def scan(app: Application, flow: FlowWriter, scene: LidarScene, tracker: ShapeTracker, circles: DataReader[ShapeType],
         frame_id: str, interval_ms: float, log_every: int) -> None:
    grid = scene.grid
    render_s = write_s = 0.0
    frames = 0  # since the last log line
    # Every scan has the same layout: it is rendered straight into one serialized cloud, restamped each time.
    blank = to_point_cloud2(np.zeros((grid.height, grid.width), POINT_DTYPE), 0, 0, frame_id)
    cloud = CloudBuffer(flow.serialize(blank))
    for frame in app.periodic(interval_ms / 1000):
        tracker.apply(take_all(circles))
        sec, nanosec = now_seconds_nanoseconds()
        start = time.perf_counter()
        cloud.stamp(sec, nanosec)
        scene.render(out=cloud.points)
        rendered = time.perf_counter()
        flow.publish_serialized(cloud.data)
        written = time.perf_counter()
        render_s += rendered - start
        write_s += written - rendered
        frames += 1
        app.stats.record("frame", number=frame)
        if log_every and (frame == 1 or frame % log_every == 0):
            spheres = [sphere.color for sphere in scene.spheres]
            app.log.debug("frame %d: %d points, %d sphere(s)%s, render %.2f ms, write %.2f ms (mean of %d)",
                          frame, grid.point_count, len(spheres), f" {','.join(spheres)}" if spheres else "",
                         render_s * 1e3 / frames, write_s * 1e3 / frames, frames)
            render_s = write_s = 0.0
            frames = 0


def main(argv: list[str] | None = None) -> int:
    return run("lidar", __doc__ or "", body, argv, keys=PROPERTY_KEYS)


if __name__ == "__main__":
    sys.exit(main())
