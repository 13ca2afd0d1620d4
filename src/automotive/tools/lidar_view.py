"""Point-cloud viewer: subscribes rt/LidarTopic and shows each cloud as a perspective view and a top view.

    python -m automotive.tools.lidar_view --snapshot cloud.png [--count N] [--timeout S]   # a PNG of the Nth cloud,
    then exit python -m automotive.tools.lidar_view [--ui window]                                     # a live window
    (needs a display)

Data flow:  sensor_msgs::msg::dds_::PointCloud2_ on rt/LidarTopic  -->  PNG file or window

Any PointCloud2 with x, y, z and rgb (or rgba) fields is shown, whatever its layout (offsets, point_step, padded rows,
byte order), so clouds of other publishers show too. The reader's QoS profile (qos.Lidar.Profile, LidarView by
default) is best effort with no deadline and a generous latency budget, so it matches our LiDAR's writer and the
default writers of other DDS and ROS 2 publishers alike.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from automotive.bus.app import Application, run
from automotive.bus.badsamples import BadSample
from automotive.bus.checkedreader import CheckedReader
from automotive.bus.errors import ConfigError
from automotive.tools.cloudview import render_image, render_png
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.wire.pointcloud import decode_point_cloud2

WINDOW_TITLE = "LiDAR point cloud"


class CloudWindow:
    """An SDL2 window (pygame) showing the latest picture."""

    def __init__(self, size: tuple[int, int]):
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        import pygame

        self.pygame = pygame
        pygame.display.init()
        self.screen = pygame.display.set_mode(size)
        pygame.display.set_caption(f"{WINDOW_TITLE}: waiting for data")

    def show(self, image: npt.NDArray[np.uint8], caption: str) -> None:
        height, width = image.shape[:2]
        surface = self.pygame.image.frombuffer(image.tobytes(), (width, height), "RGB")
        self.screen.blit(surface, (0, 0))
        self.pygame.display.set_caption(f"{WINDOW_TITLE}: {caption}")
        self.pygame.display.flip()

    def pump(self) -> None:
        for event in self.pygame.event.get():
            if event.type == self.pygame.QUIT:
                raise KeyboardInterrupt

    def close(self) -> None:
        self.pygame.display.quit()


def make_window(choice: str, size: tuple[int, int]) -> CloudWindow | None:
    if choice == "none":
        return None
    if choice == "auto" and not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        return None
    try:
        return CloudWindow(size)
    except Exception as error:  # no pygame, or SDL cannot open the display
        if choice == "window":
            raise ConfigError(f"--ui window: cannot open a window ({error})") from None
        return None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--snapshot", type=Path, default=None, metavar="FILE",
                        help="write a PNG of the first cloud (the Nth with --count N) and exit")
    parser.add_argument("--timeout", type=float, default=0.0, metavar="S",
                        help="with --snapshot: give up (exit 2) if no cloud came within S seconds (0: wait forever)")
    parser.add_argument("--ui", choices=["auto", "window", "none"], default="auto",
                        help="live window: when a display exists (auto), always, or never (log lines only)")


def describe(cloud: PointCloud2_) -> str:
    stamp = cloud.header_.stamp_
    return (f"cloud stamped {stamp.sec_}.{stamp.nanosec_:09d}, frame '{cloud.header_.frame_id_}': "
            f"{cloud.width_ * cloud.height_} points ({cloud.height_} x {cloud.width_})")


def latest_clouds(reader: Any) -> list[PointCloud2_]:
    return [sample for sample in reader.take(N=16) if isinstance(sample, PointCloud2_)]


def body(app: Application) -> None:
    width = app.props.get_int("config.imageWidth", 1600, minimum=32, maximum=8192)
    height = app.props.get_int("config.imageHeight", 800, minimum=16, maximum=8192)
    point_radius = app.props.get_int("config.pointRadius", 1, minimum=0, maximum=10)
    max_rate = app.props.get_float("config.windowRate", 10, minimum=0.1)
    log_every = app.props.get_int("config.logEvery", 20, minimum=0)
    snapshot: Path | None = app.args.snapshot
    timeout_s: float = app.args.timeout
    if timeout_s < 0:
        raise ConfigError(f"--timeout {timeout_s:g}: expected 0 (wait forever) or a number of seconds")
    if snapshot is not None and not snapshot.parent.is_dir():
        raise ConfigError(f"--snapshot {snapshot}: folder {snapshot.parent} does not exist")
    # Count clouds for the snapshot ourselves: the runtime's --count would stop the loop before the picture.
    wanted = max(app.count, 1) if snapshot is not None else 0
    if snapshot is not None:
        app.count = 0
    size = (width, height)

    reader = app.reader("Lidar", PointCloud2_, "rt/LidarTopic")
    window = make_window(app.args.ui, size) if snapshot is None else None
    if snapshot is not None:
        app.log.info("lidar view: waiting for cloud %d on %s for %s", wanted, reader.topic.name, snapshot)
    else:
        app.log.info("lidar view: %s on %s", "window" if window else "log lines only", reader.topic.name)

    started = time.monotonic()
    received = 0
    next_view = 0.0
    try:
        for _ in app.wake_ups(app.waitset(reader), timeout_s=0.05 if window else 0.5):
            if window is not None:
                window.pump()
            clouds = latest_clouds(reader)
            if not clouds and snapshot is not None and timeout_s and time.monotonic() - started > timeout_s:
                raise SnapshotTimeout(f"--snapshot: no point cloud on {reader.topic.name} within {timeout_s:g} s")
            show: PointCloud2_ | None = None
            for cloud in clouds:
                received += 1
                if log_every and (received == 1 or received % log_every == 0):
                    app.log.info("cloud %d: %s", received, describe(cloud))
                if snapshot is not None:
                    if received == wanted:
                        show = cloud
                        break
                else:
                    show = cloud  # the newest of this wake-up
                    app.tick()
            if show is None:
                continue
            if snapshot is None and (window is None or time.monotonic() < next_view):
                continue
            try:
                xyz, rgb = decode_point_cloud2(show)
            except ValueError as error:  # a valid cloud this view cannot draw (no rgb...): said once per interval
                problem = BadSample("fields_", str(error), "x, y, z and rgb fields this view can draw")
                if isinstance(reader, CheckedReader):
                    reader.report(problem, show.sample_info, action="not shown")
                else:
                    app.log.warning("cannot show a cloud: %s", error)
                continue
            if snapshot is not None:
                render_png(xyz, rgb, snapshot, size, point_radius)
                app.log.info("snapshot of cloud %d written to %s (%dx%d): %s", received, snapshot, width, height,
                             describe(show))
                app.stop()
                return
            assert window is not None
            window.show(render_image(xyz, rgb, size, point_radius), describe(show))
            next_view = time.monotonic() + 1 / max_rate
    finally:
        if window is not None:
            window.close()


class SnapshotTimeout(ConfigError):
    """No cloud came in time: reported like bad input, one line and a non-zero exit."""


def main(argv: list[str] | None = None) -> int:
    return run("lidar_view", __doc__ or "", body, argv, add_arguments)


if __name__ == "__main__":
    sys.exit(main())
