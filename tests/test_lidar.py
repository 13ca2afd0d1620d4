"""The LiDAR, shapes and lidar_view applications as processes: Shapes Demo circles in, PointCloud2 out, pictures.

Clouds are checked in-process with a reader of the project's own runtime (tests/lidar_helpers.Clouds) and decoded
with decode_point_cloud2. The view's picture and window have their own tests (test_lidar_view.py).
"""

from __future__ import annotations

import re
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.util import duration
from dds_helpers import wait_until, write_until
from lidar_helpers import Clouds, circle, colours_of, points_of, stamp_s
from PIL import Image

from automotive.bus.endpoints import Databus
from automotive.bus.qos import WRITER_REPRESENTATION
from automotive.cyclone.matched import matched_subscriptions
from automotive.sim.scene import BACKGROUND_RGB, GROUND_RGB, SHAPE_RGB
from automotive.tools.cloudview import CloudFigure
from automotive.types.automotive import ShapeType
from automotive.types.builtin_interfaces.msg.dds_ import Time_
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_, PointField_
from automotive.types.std_msgs.msg.dds_ import Header_
from automotive.wire.pointcloud import FLOAT32, decode_point_cloud2

BLUE, GREEN, RED = (SHAPE_RGB[c] for c in ("BLUE", "GREEN", "RED"))
DEFAULT_OBSERVER = np.array([0.0, 0.0, 1.0])


def domain_args(domain_id: int) -> list[str]:
    return ["--domain", str(domain_id)]


def test_shapes_publisher_feeds_the_lidar(apps, domain_id: int, bus: Databus) -> None:  # type: ignore[no-untyped-def]
    clouds = Clouds(bus)
    lidar = apps.start("lidar", *domain_args(domain_id))
    watcher = apps.start("shapes", "subscribe", *domain_args(domain_id))
    shapes = apps.start("shapes", "publish", "--color", "BLUE", *domain_args(domain_id))

    lidar.wait_for(r"shape BLUE appeared at \(\d+, \d+\), size 30")
    watcher.wait_for(r"new shape: Circle BLUE")
    positions = [watcher.wait_for(r"Circle BLUE x=\d+ y=\d+ size=30$", count=n).split("Circle BLUE ")[1]
                 for n in (2, 5)]
    assert positions[0] != positions[1]  # the circle moves
    blue = clouds.next(lambda c: len(points_of(c, BLUE)) > 0, "with blue points")[0]
    hits = points_of(blue, BLUE)
    # A circle of size 30 is a sphere of radius 0.5 m resting on the ground, inside the 8.5 m background sphere.
    assert (hits[:, 2] >= 0).all() and (hits[:, 2] <= 1.0 + 0.1).all()
    assert (np.linalg.norm(hits - DEFAULT_OBSERVER, axis=1) < 8.5).all()
    lidar.wait_for(r"frame \d+: 11520 points, 1 sphere\(s\) BLUE, render [\d.]+ ms, write [\d.]+ ms")

    shapes.stop()  # SIGTERM: the application deletes its writer, which disposes the circle
    lidar.wait_for(r"shape BLUE removed \(disposed\)")
    removed = time.time()
    watcher.wait_for(r"Circle BLUE disposed")
    assert all(len(points_of(c, BLUE)) == 0 for c in clouds.after(removed))


def test_disposed_shape_and_shape_without_writers_disappear(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                            bus: Databus) -> None:
    clouds = Clouds(bus)
    writer = bus.writer("Circle", ShapeType, "Shapes")
    # A second writer that only unregisters when deleted (no auto-dispose): its instance ends NOT_ALIVE_NO_WRITERS.
    keeper = DataWriter(bus.publisher, bus.topic("Circle", ShapeType),
                        qos=Qos(Policy.Reliability.Reliable(duration(milliseconds=100)),
                                Policy.WriterDataLifecycle(autodispose=False), WRITER_REPRESENTATION))
    lidar = apps.start("lidar", *domain_args(domain_id), "-D", "config.noise=0")
    wait_until(lambda: len(matched_subscriptions(writer)) == 1 and len(matched_subscriptions(keeper)) == 1,
               what="the LiDAR's Circle reader")
    # The LiDAR's reader is best effort, as Shapes Demo's: until it has matched a writer itself, that writer's
    # samples are lost; a Shapes Demo writer repeats its shapes, and so do these until the LiDAR saw them.
    write_until(lidar, r"shape GREEN appeared at \(216, 135\), size 60",
                lambda: writer.write(ShapeType("GREEN", *circle(4, 0), 60)))  # radius 1 m, centre 1 m up, 4 m ahead
    write_until(lidar, r"shape RED appeared at \(120, 27\), size 60",
                lambda: keeper.write(ShapeType("RED", *circle(0, -4), 60)))  # 4 m along -y
    both = clouds.next(lambda c: len(points_of(c, GREEN)) > 0 and len(points_of(c, RED)) > 0, "with green and red")[0]
    green = points_of(both, GREEN)
    assert np.allclose(np.linalg.norm(green - np.array([4.0, 0.0, 1.0]), axis=1), 1.0, atol=1e-3)  # on the sphere
    bearing = np.degrees(np.arctan2(green[:, 1], green[:, 0]))
    assert abs(np.median(bearing)) < 3
    red = points_of(both, RED)
    assert abs(np.median(np.degrees(np.arctan2(red[:, 1], red[:, 0]))) + 90) < 3

    writer.dispose(ShapeType("GREEN", *circle(4, 0), 60))
    lidar.wait_for(r"shape GREEN removed \(disposed\)")
    disposed = time.time()
    for cloud in clouds.after(disposed):
        assert len(points_of(cloud, GREEN)) == 0 and len(points_of(cloud, RED)) > 0

    keeper.__del__()  # the writer is gone: RED's instance has no writers left
    lidar.wait_for(r"shape RED removed \(no writers left\)")
    gone = time.time()
    for cloud in clouds.after(gone):
        assert colours_of(cloud) <= {BACKGROUND_RGB, GROUND_RGB}


def foreign_cloud() -> PointCloud2_:
    """A cloud as another publisher might send it: other offsets, rgba, 32-byte points, padded rows, big-endian.

    Two rows of 50 points: a green ring of radius 4 m on the ground and a red cluster 3 m above its centre."""
    rows, width, point_step, row_step = 2, 50, 32, 50 * 32 + 16
    layout = np.dtype({"names": ["intensity", "x", "y", "z", "rgba"], "formats": [">f4", ">f4", ">f4", ">f4", ">u4"],
                       "offsets": [0, 4, 8, 12, 20], "itemsize": point_step})
    points = np.zeros((rows, width), dtype=layout)
    angle = np.linspace(0, 2 * np.pi, width, endpoint=False)
    points["x"][0], points["y"][0], points["rgba"][0] = 4 * np.cos(angle), 4 * np.sin(angle), 0xFF00FF00
    points["x"][1], points["y"][1], points["z"][1] = 0.1 * np.cos(angle), 0.1 * np.sin(angle), 3.0
    points["rgba"][1] = 0xFFFF0000
    data = bytearray(row_step * rows)
    for row in range(rows):
        data[row * row_step:row * row_step + width * point_step] = points[row].tobytes()
    # The original IDL bounds fields_ to 4: the intensity bytes are there but not declared.
    fields = [PointField_("x", 4, FLOAT32, 1), PointField_("y", 8, FLOAT32, 1), PointField_("z", 12, FLOAT32, 1),
              PointField_("rgba", 20, 6, 1)]  # 6: UINT32
    return PointCloud2_(header_=Header_(stamp_=Time_(1, 2), frame_id_="velodyne"), height_=rows, width_=width,
                        fields_=fields, is_bigendian_=True, point_step_=point_step, row_step_=row_step,
                        data_=bytes(data), is_dense_=True)  # type: ignore[arg-type]


def test_lidar_view_shows_clouds_of_other_publishers(apps, domain_id: int, bus: Databus,  # type: ignore[no-untyped-def]
                                                     tmp_path: Path) -> None:
    # A writer with Cyclone's default QoS, as a ROS 2 node's default publisher: reliable, no deadline, no latency
    # budget, XCDR2 (Cyclone's choice for this appendable type). The Lidar profile's reader would not match it
    # (its 2 s deadline); lidar_view's LidarView profile does.
    writer = DataWriter(bus.publisher, bus.topic("rt/LidarTopic", PointCloud2_))
    picture = tmp_path / "foreign.png"
    view = apps.start("lidar_view", *domain_args(domain_id), "--snapshot", str(picture), "--timeout", "30",
                      "-D", "config.imageWidth=600", "-D", "config.imageHeight=300", "-D", "config.pointRadius=2")
    view.wait_for(r"\[rt/LidarTopic\] reader matched a writer")
    cloud = foreign_cloud()
    deadline = time.monotonic() + 30
    while view.process.poll() is None and time.monotonic() < deadline:
        writer.write(cloud)  # the viewer's reader is best effort: repeat until it has taken one and exited
        try:
            view.process.wait(timeout=0.05)
        except subprocess.TimeoutExpired:
            pass
    assert view.wait_exit(10) == 0, view.output
    view.wait_for(r"snapshot of cloud 1 written .*: cloud stamped 1\.000000002, frame 'velodyne': 100 points "
                  r"\(2 x 50\)")
    with Image.open(picture) as image:
        assert image.size == (600, 300)
        pixels = np.asarray(image.convert("RGB"))
    # The legend shows red and green too: only the panels (the perspective view and the top view) count.
    for left, top, right, bottom in CloudFigure((600, 300)).panels.values():
        for colour in ((0, 255, 0), (255, 0, 0)):
            assert (pixels[top:bottom, left:right] == np.array(colour, dtype=np.uint8)).all(axis=2).sum() > 20, colour


def test_sensor_fusion_prints_the_lidar_timestamps(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    fusion = apps.start("sensor_fusion", *domain_args(domain_id))
    apps.start("lidar", *domain_args(domain_id))
    lines = [fusion.wait_for(r"lidar sample stamped \d+\.\d{9}: 11520 points", count=n) for n in (1, 3)]
    now = time.time()
    stamps = [float(re.search(r"stamped (\d+\.\d{9})", line).group(1)) for line in lines]  # type: ignore[union-attr]
    assert all(abs(stamp - now) < 30 for stamp in stamps), (stamps, now)  # this host's clock, not a counter
    assert stamps[1] > stamps[0]


def test_point_cloud2_of_the_running_lidar(apps, domain_id: int, bus: Databus) -> None:  # type: ignore[no-untyped-def]
    clouds = Clouds(bus)
    apps.start("lidar", *domain_args(domain_id), "-D", "config.azimSteps=90", "-D", "config.polarSteps=32",
               "-D", "config.pubInterval=20")
    received = clouds.next(lambda c: True, "from the LiDAR", count=3)
    now = time.time()
    for cloud in received:
        assert cloud.header_.frame_id_ == "map"
        assert abs(stamp_s(cloud) - now) < 30
        assert [(f.name_, f.offset_, f.datatype_, f.count_) for f in cloud.fields_] == [
            ("x", 0, FLOAT32, 1), ("y", 4, FLOAT32, 1), ("z", 8, FLOAT32, 1), ("rgb", 12, FLOAT32, 1)]
        assert (cloud.height_, cloud.width_, cloud.point_step_, cloud.row_step_) == (32, 90, 16, 90 * 16)
        assert cloud.is_bigendian_ is False and cloud.is_dense_ is True
        assert isinstance(cloud.data_, bytes)  # the octet fast path delivers one block
        assert len(cloud.data_) == cloud.row_step_ * cloud.height_ == 32 * 90 * 16
        xyz, _ = decode_point_cloud2(cloud)
        assert np.isfinite(xyz).all()
        assert colours_of(cloud) == {BACKGROUND_RGB, GROUND_RGB}
    assert [stamp_s(c) for c in received] == sorted(stamp_s(c) for c in received)
    assert len({c.data_ for c in received}) == 3  # every frame has fresh noise


@pytest.mark.parametrize(("app", "args", "pattern"), [
    ("lidar", ["-D", "config.azimSteps=361"], r"config\.azimSteps.*over the PointCloud2 data bound of 368640 bytes"),
    ("lidar", ["-D", "config.polarSteps=0"], r"-D: scan polar steps \(config\.polarSteps\): expected a whole number"),
    ("lidar", ["-D", "config.azimRange=wide"], r"config\.azimRange = 'wide' is not a number"),
    ("shapes", ["publish", "--shapesize", "0"], r"--shapesize 0: expected 1\.\.240 pixels"),
    ("lidar_view", ["--snapshot", "/nonexistent-folder/cloud.png"],
     r"--snapshot: /nonexistent-folder/cloud.png: folder /nonexistent-folder does not exist"),
    ("lidar_view", ["--snapshot", "x.png", "--timeout", "0.5"], r"--snapshot: no point cloud on rt/LidarTopic within"),
])
def test_bad_input_is_one_line(apps, domain_id: int, app: str, args: list[str],  # type: ignore[no-untyped-def]
                               pattern: str, tmp_path: Path) -> None:
    args = [str(tmp_path / a) if a == "x.png" else a for a in args]
    result = apps.run(app, *domain_args(domain_id), *args)
    assert result.returncode == 2, result.stdout + result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and re.search(pattern, lines[0]), result.stderr
    assert "Traceback" not in result.stdout + result.stderr
