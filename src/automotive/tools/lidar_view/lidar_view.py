"""Point-cloud viewer: subscribes rt/LidarTopic and shows each cloud as a perspective view and a top view.

    automotive lidar-view --snapshot cloud.png [--count N] [--timeout S]   # a PNG of the Nth cloud
    automotive lidar-view [--ui auto|window|none]         # a live window, or log lines

Data flow:  sensor_msgs::msg::dds_::PointCloud2_ on rt/LidarTopic  -->  PNG file, window or log lines

Where the clouds go: ``--snapshot`` writes a PNG and needs no display. Otherwise ``--ui window`` shows them in a
window, and without a usable display (automotive.bus.display: no DISPLAY or WAYLAND_DISPLAY, one SDL cannot open,
or SDL's offscreen or dummy driver, which show no window) is bad input: one line, exit code 2, before the view joins
the bus. ``--ui none`` logs a line per config.logEvery clouds and the status line. ``--ui auto`` (the default) is the
window where a display can show one, and else those log lines, which is what the view can still do without a
display: it says why in one line, and that ``--snapshot FILE`` gives a picture without one.

The clouds of a LiDAR on this host come through shared memory (automotive.wire.sharedflow, iceoryx2), those of any
other on DDS (``config.transport=udp``: all on DDS). A shared cloud is read in place: its header and layout from the
serialized bytes (:func:`read_cloud`), its points straight into the picture's arrays, and only the newest of those
waiting when the view wakes up is drawn (every one is counted for the log lines and the rate).

The picture (automotive.tools.cloudview) has axes in metres, a legend of the LiDAR's colours (Shapes Demo circles
are spheres in their own colour; grey: the background sphere; dark grey: the ground) and a title that stays put;
the cloud number, point count, rate and stamp are in a status box. The window keeps the title as its caption and is
made smaller (same proportions) when config.imageWidth x config.imageHeight would not fit the screen.

Any PointCloud2 with x, y, z and rgb (or rgba) fields is shown, whatever its layout (offsets, point_step, padded rows,
byte order), so clouds of other publishers show too; one without them is reported (once per interval, as bad samples
are) and not shown, and ``--snapshot`` takes the next cloud instead. The reader's QoS profile (qos.Lidar.Profile,
LidarView by default) is best effort with no deadline and a generous latency budget, so it matches our LiDAR's writer
and the default writers of other DDS and ROS 2 publishers alike.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from automotive.bus import badsamples
from automotive.bus.app import Application, build_parser, run
from automotive.bus.badsamples import BadSample
from automotive.bus.checkedreader import CheckedReader
from automotive.bus.cli import EXIT_BAD_INPUT, output_file
from automotive.bus.display import NoWindow, open_pygame_display, open_window
from automotive.bus.errors import ConfigError
from automotive.bus.properties import PropertyKeys
from automotive.tools.cloudview import MIN_SIZE, CloudFigure
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.wire.pointcloud import decode_point_cloud2, read_cloud
from automotive.wire.sharedflow import FlowReader
from automotive.wire.shm import SharedSample

# The property keys it reads beyond the runtime's (automotive.bus.app.RUNTIME_KEYS): any other is refused at start.
PROPERTY_KEYS = PropertyKeys.of("config.imageWidth", "config.imageHeight", "config.pointRadius", "config.windowRate",
                                "config.logEvery", "config.transport", "config.shmPrefix", roles=["Lidar"])

NAME = "lidar_view"
COMMAND = "automotive lidar-view"
WINDOW_TITLE = "LiDAR point cloud"
SNAPSHOT_HINT = "--snapshot FILE writes a picture without a display"
# Room a window leaves on its screen: its decorations (title bar, borders) and a desktop panel. A 1280x720 screen
# takes pictures of up to 1256x640.
SCREEN_MARGIN = (24, 80)
RATE_WINDOW = 20  # the rate shown is over the last this many clouds received
TAKE_LIMIT = 16  # clouds taken at once
SHARED_WRITER = "a writer on this host (shared memory)"  # who sent a shared cloud, in a bad-sample line


def fit_to_screen(size: tuple[int, int], screen: tuple[int, int]) -> tuple[int, int]:
    """``size``, or smaller in the same proportions so that a window of it fits ``screen`` with SCREEN_MARGIN."""
    room = (screen[0] - SCREEN_MARGIN[0], screen[1] - SCREEN_MARGIN[1])
    scale = min(1.0, room[0] / size[0], room[1] / size[1])
    return max(MIN_SIZE[0], int(size[0] * scale)), max(MIN_SIZE[1], int(size[1] * scale))


@dataclass(frozen=True)
class Display:
    """Where the live view goes: pygame with its display open for the window, or None and why there is no window
    ("" when none was wanted: --ui none, --snapshot)."""

    pygame: Any | None
    why_no_window: str = ""


def open_display(choice: str, snapshot: Path | None) -> Display:
    """The display for ``--ui``; raises NoWindow for ``--ui window`` without a usable one."""
    if snapshot is not None or choice == "none":
        return Display(None)
    try:
        return Display(open_pygame_display())
    except NoWindow as reason:
        if choice == "window":
            raise
        return Display(None, str(reason))


class CloudWindow:
    """An SDL2 window (pygame) showing the latest picture, under a caption that does not change. Opened on a display
    of :func:`automotive.bus.display.open_pygame_display`; raises NoWindow if SDL cannot open the window there."""

    def __init__(self, pygame: Any, size: tuple[int, int], title: str):
        self.pygame = pygame
        screens = pygame.display.get_desktop_sizes()
        self.size = fit_to_screen(size, screens[0]) if screens else size
        self.screen = open_window(pygame, self.size)
        pygame.display.set_caption(title)

    def show(self, image: npt.NDArray[np.uint8]) -> None:
        height, width = image.shape[:2]
        surface = self.pygame.image.frombuffer(np.ascontiguousarray(image).data, (width, height), "RGB")
        self.screen.blit(surface, (0, 0))
        self.pygame.display.flip()

    def pump(self) -> None:
        for event in self.pygame.event.get():
            if event.type == self.pygame.QUIT:
                raise KeyboardInterrupt

    def close(self) -> None:
        self.pygame.display.quit()


def make_window(app: Application, display: Display, size: tuple[int, int],
                title: str) -> tuple[CloudWindow | None, str]:
    """The window on ``display``, or None and why not ("" when none was wanted)."""
    if display.pygame is None:
        return None, display.why_no_window
    try:
        return CloudWindow(display.pygame, size, title), ""
    except NoWindow as reason:  # the display opened but refused the window: rare, and only known now
        if app.args.ui == "window":
            raise ConfigError(f"--ui window: {reason}") from None
        return None, str(reason)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--snapshot", type=output_file, default=None, metavar="FILE",
                        help="write a PNG of the first cloud (the Nth with --count N) and exit")
    parser.add_argument("--timeout", type=float, default=0.0, metavar="S",
                        help="with --snapshot: give up (exit 2) if no cloud came within S seconds (0: wait forever)")
    parser.add_argument("--ui", choices=["auto", "window", "none"], default="auto",
                        help="live window: when a display can show one (auto; else log lines), always (an error "
                             "without a usable display), or never (log lines only)")


def describe(cloud: PointCloud2_) -> str:
    stamp = cloud.header_.stamp_
    return (f"cloud stamped {stamp.sec_}.{stamp.nanosec_:09d}, frame '{cloud.header_.frame_id_}': "
            f"{cloud.width_ * cloud.height_} points ({cloud.height_} x {cloud.width_})")


def cloud_points(cloud: PointCloud2_, data: slice | None,
                 serialized: memoryview) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """x, y, z and r, g, b of a cloud that :func:`read_cloud` read, its data taken from ``serialized`` in place
    (copied once: into these arrays). Raises ValueError for a cloud this view cannot draw."""
    if data is None:
        return decode_point_cloud2(cloud)
    return decode_point_cloud2(dataclasses.replace(cloud, data_=serialized[data]))


# -- the clouds of each wake-up --------------------------------------------------------------------------------------

class CloudRate:
    """Clouds received a second, over the last RATE_WINDOW clouds.

    Timed by the writer's source timestamps: one wake-up may take several clouds at once, so the time they are taken
    says little about how far apart they were sent."""

    def __init__(self) -> None:
        self.stamps_ns: deque[int] = deque(maxlen=RATE_WINDOW + 1)

    def received(self, cloud: PointCloud2_) -> None:
        info = getattr(cloud, "sample_info", None)
        self.stamped(info.source_timestamp if info is not None else None)

    def stamped(self, source_ns: int | None) -> None:
        """A cloud with this source timestamp (ns; None: not known) was received."""
        if source_ns is not None:
            self.stamps_ns.append(source_ns)

    def per_second(self) -> float | None:
        if len(self.stamps_ns) < 2 or self.stamps_ns[-1] <= self.stamps_ns[0]:
            return None
        return (len(self.stamps_ns) - 1) * 1e9 / (self.stamps_ns[-1] - self.stamps_ns[0])


def status_line(number: int, cloud: PointCloud2_, rate: float | None) -> str:
    """What changes from cloud to cloud, in fixed-width fields: the status box keeps its size and place."""
    stamp = cloud.header_.stamp_
    per_second = f"{rate:5.1f}" if rate is not None else "    -"
    return (f"cloud {number:<7d} {cloud.width_ * cloud.height_:>6d} points  {per_second} clouds/s  "
            f"stamp {stamp.sec_}.{stamp.nanosec_:09d}  frame '{cloud.header_.frame_id_}'")


@dataclass(frozen=True)
class Picture:
    """A cloud to draw: its number (clouds received so far), its header and layout, and its points."""

    number: int
    cloud: PointCloud2_
    xyz: npt.NDArray[np.float32]
    rgb: npt.NDArray[np.uint8]


class CloudIntake:
    """Takes the clouds of a wake-up, through shared memory and on DDS: counts each one (log lines, rate, --count)
    and gives the one to draw, decoded: the ``wanted``-th for a snapshot, else the newest when a picture is due.

    A shared cloud is read in place inside its ``with`` block and nothing of it outlives the block but copies (its
    header and layout, its points): the publisher reuses the memory once the block gives it back."""

    def __init__(self, app: Application, flow: FlowReader, log_every: int, wanted: int):
        self.app = app
        self.flow = flow
        self.log_every = log_every
        self.wanted = wanted  # the cloud a snapshot shows; 0: no snapshot
        self.received = 0
        self.rate = CloudRate()

    def take(self, draw: bool) -> tuple[int, Picture | None]:
        """(the clouds taken, the picture to draw or None); ``draw``: a picture is due (else none is decoded)."""
        taken = 0
        picture: Picture | None = None
        while self.app.running:  # every cloud waiting in shared memory, the newest drawn
            with self.flow.take_shared(TAKE_LIMIT) as samples:
                if not samples:
                    break
                taken += len(samples)
                picture = self._shared(samples, draw) or picture
            if picture is not None and self.wanted:
                return taken, picture
        clouds = [cloud for cloud in self.flow.reader.take(N=TAKE_LIMIT) if isinstance(cloud, PointCloud2_)
                  and not self.flow.from_shared(cloud.sample_info.publication_handle)]  # those came in shared memory
        taken += len(clouds)
        return taken, self._dds(clouds, draw) or picture

    def _count(self, source_ns: int | None) -> int:
        self.received += 1
        self.rate.stamped(source_ns)
        if not self.wanted:
            self.app.tick()
        return self.received

    def _is_wanted(self, number: int, draw: bool, last: bool) -> bool:
        return number == self.wanted if self.wanted else draw and last

    def _log(self, number: int, cloud: PointCloud2_) -> None:
        if self._logged(number):
            self.app.log.info("cloud %d: %s", number, describe(cloud))

    def _logged(self, number: int) -> bool:
        return bool(self.log_every) and (number == 1 or number % self.log_every == 0)

    def _shared(self, samples: list[SharedSample], draw: bool) -> Picture | None:
        picture = None
        for index, sample in enumerate(samples):
            try:
                cloud, data = read_cloud(sample.data)  # its header and layout: a few members, read in place
            except ValueError as error:
                self._report_shared(BadSample("", str(error), "a serialized PointCloud2"), "ignored")
                continue
            number = self._count(sample.source_timestamp)
            self._log(number, cloud)
            if not self._is_wanted(number, draw, index == len(samples) - 1):
                continue
            try:
                picture = Picture(number, cloud, *cloud_points(cloud, data, sample.data))
            except ValueError as error:
                self._report_shared(cannot_draw(error), "not shown")
                self._not_drawn()
                continue
            if self.wanted:
                break
        return picture

    def _dds(self, clouds: list[PointCloud2_], draw: bool) -> Picture | None:
        picture = None
        for index, cloud in enumerate(clouds):
            number = self._count(cloud.sample_info.source_timestamp)
            self._log(number, cloud)
            if not self._is_wanted(number, draw, index == len(clouds) - 1):
                continue
            try:
                picture = Picture(number, cloud, *decode_point_cloud2(cloud))
            except ValueError as error:  # a valid cloud this view cannot draw (no rgb...): said once per interval
                reader = self.flow.reader
                if isinstance(reader, CheckedReader):
                    reader.report(cannot_draw(error), cloud.sample_info, action="not shown")
                else:
                    self.app.log.warning("cannot show a cloud: %s", error)
                self._not_drawn()
                continue
            if self.wanted:
                break
        return picture

    def _not_drawn(self) -> None:
        """The cloud to draw could not be: a snapshot shows the next one."""
        if self.wanted:
            self.wanted += 1

    def _report_shared(self, problem: BadSample, action: str) -> None:
        """A bad cloud from shared memory (a writer on this host), reported as the DDS reader reports its own."""
        reporter = getattr(self.flow.reader, "reporter", None) or badsamples.reporter()
        reporter.report(self.flow.topic, problem, SHARED_WRITER, action)


def cannot_draw(error: ValueError) -> BadSample:
    return BadSample("fields_", str(error), "x, y, z and rgb fields this view can draw")


@dataclass(frozen=True)
class Settings:
    """What the view's properties and command line ask for."""

    size: tuple[int, int]
    point_radius: int
    max_rate: float
    log_every: int
    snapshot: Path | None
    timeout_s: float
    wanted: int  # the cloud a snapshot shows; 0: no snapshot


def body(app: Application, display: Display) -> None:
    width = app.props.get_int("config.imageWidth", 1600, minimum=MIN_SIZE[0], maximum=8192)
    height = app.props.get_int("config.imageHeight", 800, minimum=MIN_SIZE[1], maximum=8192)
    point_radius = app.props.get_int("config.pointRadius", 1, minimum=0, maximum=10)
    max_rate = app.props.get_float("config.windowRate", 10, minimum=0.1)
    log_every = app.props.get_int("config.logEvery", 20, minimum=0)
    snapshot: Path | None = app.args.snapshot
    timeout_s: float = app.args.timeout
    if timeout_s < 0:
        raise ConfigError(f"--timeout {timeout_s:g}: expected 0 (wait forever) or a number of seconds")
    # Count clouds for the snapshot ourselves: the runtime's --count would stop the loop before the picture.
    wanted = max(app.count, 1) if snapshot is not None else 0
    if snapshot is not None:
        app.count = 0
    settings = Settings((width, height), point_radius, max_rate, log_every, snapshot, timeout_s, wanted)
    flow = FlowReader.of_role(app, "Lidar", PointCloud2_, "rt/LidarTopic")
    try:
        view(app, display, flow, settings)
    finally:
        flow.close()


def view(app: Application, display: Display, flow: FlowReader, settings: Settings) -> None:
    """Take the clouds of ``flow`` and draw them (window), write one (snapshot) or log them, until stopped."""
    snapshot, size, topic = settings.snapshot, settings.size, flow.topic
    title = f"{WINDOW_TITLE}: {topic}"
    window, why_no_window = make_window(app, display, size, title)
    figure: CloudFigure | None = None
    if snapshot is not None:
        app.log.info("lidar view: waiting for cloud %d on %s for %s", settings.wanted, topic, snapshot)
    elif window is not None:
        app.log.info("lidar view: window on %s (%dx%d)", topic, *window.size)
    else:
        app.log.info("lidar view: log lines only on %s%s", topic,
                     f" (no window: {why_no_window}; {SNAPSHOT_HINT})" if why_no_window else "")
    if window is not None:
        figure = CloudFigure(window.size, settings.point_radius, title)
        window.show(figure.render(np.empty((0, 3)), np.empty((0, 3), dtype=np.uint8),
                                  f"waiting for a point cloud on {topic}"))

    started = time.monotonic()
    intake = CloudIntake(app, flow, settings.log_every, settings.wanted)
    next_view = 0.0
    try:
        for _ in app.wake_ups(flow.waitset(), timeout_s=0.05 if window else 0.5):
            if window is not None:
                window.pump()
            draw = snapshot is not None or (window is not None and time.monotonic() >= next_view)
            taken, picture = intake.take(draw)
            flow.check_deadline()
            if (not taken and snapshot is not None and settings.timeout_s
                    and time.monotonic() - started > settings.timeout_s):
                raise SnapshotTimeout(f"--snapshot: no point cloud on {topic} within {settings.timeout_s:g} s")
            if picture is None:
                continue
            status = status_line(picture.number, picture.cloud, intake.rate.per_second())
            if snapshot is not None:
                figure = CloudFigure(size, settings.point_radius, title)
                try:
                    figure.save_png(figure.render(picture.xyz, picture.rgb, status), snapshot)
                except OSError as error:  # checked at start, but a folder can turn read-only or full since
                    raise ConfigError(f"--snapshot {snapshot}: cannot write it ({error.strerror or error})") from None
                app.log.info("snapshot of cloud %d written to %s (%dx%d): %s", picture.number, snapshot, *size,
                             describe(picture.cloud))
                app.stop()
                return
            assert window is not None and figure is not None
            window.show(figure.render(picture.xyz, picture.rgb, status))
            next_view = time.monotonic() + 1 / settings.max_rate
    finally:
        if window is not None:
            window.close()


class SnapshotTimeout(ConfigError):
    """No cloud came in time: reported like bad input, one line and a non-zero exit."""


def main(argv: list[str] | None = None) -> int:
    description = __doc__ or ""
    # The display is opened before the view exists: a window that cannot be shown is bad input, refused before the
    # view creates its DDS participant. (The command line is parsed again by run: the same parser.)
    parser = build_parser(NAME, description, add_arguments, COMMAND)
    args = parser.parse_args(argv)
    try:
        display = open_display(args.ui, args.snapshot)
    except NoWindow as reason:
        print(f"{parser.prog}: --ui window: {reason}", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        return run(NAME, description, lambda app: body(app, display), argv, add_arguments, command=COMMAND,
                   keys=PROPERTY_KEYS)
    finally:
        if display.pygame is not None:  # the window's close did it, unless the view ended before its window
            display.pygame.display.quit()


if __name__ == "__main__":
    sys.exit(main())
