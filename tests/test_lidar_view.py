"""The LiDAR view a person looks at: the picture (legend, axes in metres, a title that stays put) and its window.

The picture is checked in-process through its matplotlib objects and pixels (automotive.tools.cloudview), then the
running view (``python -m automotive.tools.lidar_view``) with a running LiDAR: its window on a private X display of a
laptop's size (xwininfo for the geometry and the caption, screenshots for the pixels) and its --snapshot PNG, whose
title, legend and axes must be pixel for pixel those of the in-process figure. And no window without a display:
``--ui window`` is refused in one line before the view joins the bus, ``--ui auto`` logs the clouds and says why.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from apprunner import command_of
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.util import duration
from dds_helpers import take_samples, wait_until
from display_helpers import free_x_display, run_without_display
from lidar_helpers import circle
from matplotlib.artist import Artist
from matplotlib.colors import to_rgb
from matplotlib.lines import Line2D
from PIL import Image, ImageGrab

from automotive.bus.endpoints import Databus
from automotive.sim.scene import BACKGROUND_RGB, GROUND_RGB, SHAPE_RGB, LidarScene, ScanGrid
from automotive.tools.cloudview import DEFAULT_SIZE, CloudFigure
from automotive.tools.lidar_view import WINDOW_TITLE, CloudRate, fit_to_screen, status_line
from automotive.types.automotive import ShapeType
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.wire.pointcloud import decode_point_cloud2

RED, MAGENTA = SHAPE_RGB["RED"], SHAPE_RGB["MAGENTA"]
TITLE = f"{WINDOW_TITLE}: rt/LidarTopic"  # what the view shows as its title and window caption
Box = tuple[int, int, int, int]  # left, top, right, bottom pixels


def scene_cloud(frame: int, **circles: tuple[float, float, int]) -> tuple[npt.NDArray[np.float32],
                                                                         npt.NDArray[np.uint8]]:
    """A cloud of the simulated LiDAR (its default scan) with circles at ground positions in metres and a size."""
    scene = LidarScene(ScanGrid(), seed=frame)
    for colour, (x, y, size) in circles.items():
        scene.update_shape(colour, *circle(x, y), size)
    return decode_point_cloud2(scene.point_cloud2(1_700_000_000, frame))


def count(pixels: npt.NDArray[np.uint8], box: Box, colour: tuple[int, int, int]) -> int:
    left, top, right, bottom = box
    return int((pixels[top:bottom, left:right] == np.array(colour, dtype=np.uint8)).all(axis=2).sum())


def rgb_of(artist: Artist | None) -> tuple[int, ...]:
    assert isinstance(artist, Line2D)
    return tuple(round(channel * 255) for channel in to_rgb(artist.get_color()))


def chrome_mask(figure: CloudFigure, status_box: Box) -> npt.NDArray[np.bool_]:
    """True where the picture is neither a panel (points) nor the status box: title, legend, axes, labels."""
    mask = np.ones((figure.height, figure.width), dtype=bool)
    for left, top, right, bottom in [*figure.panels.values(), status_box]:
        mask[max(top, 0):bottom, max(left, 0):right] = False
    return mask


# -- the picture, in-process -----------------------------------------------------------------------------------------

def test_the_picture_says_what_the_points_are() -> None:
    figure = CloudFigure(DEFAULT_SIZE, title=TITLE)
    xyz, rgb = scene_cloud(1, RED=(3, 1, 60))
    pixels = figure.render(xyz, rgb, "cloud 1")
    assert pixels.shape == (DEFAULT_SIZE[1], DEFAULT_SIZE[0], 3)
    labels = [text.get_text() for text in figure.legend.get_texts()]
    assert len(labels) == 3
    assert "Shapes Demo circles (spheres)" in labels[0]
    assert "background" in labels[1] and "8.5 m" in labels[1] and "ground" in labels[2]
    # The circles' entry shows the circles' colours, red first; the others the grey of their points.
    assert [rgb_of(handle) for handle in figure.legend.legend_handles] == [RED, BACKGROUND_RGB, GROUND_RGB]
    assert figure.title.get_text() == TITLE
    assert (figure.top.get_xlabel(), figure.top.get_ylabel()) == ("x (m)", "y (m)")
    assert (figure.perspective.get_xlabel(), figure.perspective.get_ylabel(), figure.perspective.get_zlabel()) == (
        "x (m)", "y (m)", "z (m)")
    # The top view's axes are metres: the red sphere (1 m radius, centre 3 m along x, 1 m along y) lies around there.
    left, top, right, bottom = figure.panels["top"]
    rows, cols = np.nonzero((pixels[top:bottom, left:right] == np.array(RED, dtype=np.uint8)).all(axis=2))
    x, y = figure.top.transData.inverted().transform(
        np.column_stack([left + cols + 0.5, figure.height - (top + rows + 0.5)])).T
    assert len(x) > 50 and 1.8 < x.mean() < 3.2 and 0.6 < y.mean() < 1.4, (x.mean(), y.mean())
    assert count(pixels, figure.panels["perspective"], RED) > 50
    for colour in (BACKGROUND_RGB, GROUND_RGB):
        assert count(pixels, figure.panels["perspective"], colour) > 500
        assert count(pixels, figure.panels["top"], colour) > 500


def test_title_legend_and_axes_stay_put_from_frame_to_frame() -> None:
    figure = CloudFigure((1000, 520), title=TITLE)
    statuses = ["cloud 1          11520 points      - clouds/s", "cloud 2 11520 points 20.0 clouds/s stamp 1.5",
                "cloud 123456 11520 points 19.5 clouds/s stamp 1700000000.000000005 frame 'velodyne_top'"]
    frames, boxes = [], []
    for number, status in enumerate(statuses):
        xyz, rgb = scene_cloud(number, BLUE=(2 - number, -3, 40))  # noise and a moving circle
        frames.append(figure.render(xyz, rgb, status))
        boxes.append(figure.status_box())
        assert figure.title.get_text() == TITLE
    assert boxes[0] == boxes[1] == boxes[2]  # the status box does not grow or move with its text
    chrome = chrome_mask(figure, boxes[0])
    for frame in frames[1:]:
        assert np.array_equal(frame[chrome], frames[0][chrome])  # title, legend, axes, ticks: not one pixel moved
        assert not np.array_equal(frame, frames[0])  # while the points and the status changed
    left, top, right, bottom = boxes[0]
    assert not np.array_equal(frames[1][top:bottom, left:right], frames[2][top:bottom, left:right])


def test_pictures_for_windows_fit_the_screen() -> None:
    assert DEFAULT_SIZE[0] <= 1260 and DEFAULT_SIZE[1] <= 680
    for screen in [(1280, 720), (800, 600), (1366, 768)]:
        width, height = fit_to_screen((1600, 800), screen)
        assert width <= screen[0] - 20 and height <= screen[1] - 40, screen
        assert abs(width / height - 2) < 0.01  # same proportions
    assert fit_to_screen((640, 320), (1280, 720)) == (640, 320)  # small enough already


def test_status_line_keeps_its_width_and_rate_follows_the_writers_stamps(bus: Databus) -> None:
    """The rate is clouds per second of the writer's source timestamps, whenever the view takes them."""
    topic = bus.topic("rt/LidarTopic", PointCloud2_)
    writer = DataWriter(bus.publisher, topic)
    reader = DataReader(bus.participant, topic, qos=Qos(Policy.Reliability.Reliable(duration(seconds=1)),
                                                         Policy.History.KeepAll))
    wait_until(lambda: len(writer.get_matched_subscriptions()) == 1, what="the test's reader")
    scene = LidarScene(ScanGrid(azimuth_steps=8, polar_steps=4))
    start_ns = 1_700_000_000 * 10**9
    for frame in range(6):  # stamped 50 ms apart, written at once
        writer.write(scene.point_cloud2(1_700_000_000, frame), timestamp=start_ns + frame * 50_000_000)
    clouds = take_samples(reader, 6)
    assert len(clouds) == 6
    rate = CloudRate()
    rate.received(clouds[0])
    assert rate.per_second() is None
    for cloud in clouds[1:]:
        rate.received(cloud)
    assert rate.per_second() == pytest.approx(20.0)
    lines = [status_line(number, clouds[0], value) for number, value in [(1, None), (1234567, 19.96), (99, 120.5)]]
    assert len({len(line) for line in lines}) == 1, lines
    assert "cloud 1234567" in lines[1] and " 20.0 clouds/s" in lines[1] and "32 points" in lines[1]
    assert "stamp 1700000000.000000000" in lines[0] and "frame 'map'" in lines[0]


def test_pictures_below_the_minimum_size_are_refused() -> None:
    with pytest.raises(ValueError, match=r"image size 200x100: expected at least 320x160 pixels"):
        CloudFigure((200, 100))


# -- the running view ------------------------------------------------------------------------------------------------

@pytest.fixture(params=[(1280, 720), (800, 600)], ids=lambda size: f"{size[0]}x{size[1]}")
def screen(request: pytest.FixtureRequest) -> Iterator[tuple[str, tuple[int, int]]]:
    """A private X display (Xvfb) of a laptop's or a small screen's size: (DISPLAY, (width, height))."""
    size: tuple[int, int] = request.param
    xvfb = shutil.which("Xvfb")
    if xvfb is None:
        pytest.fail("Xvfb is not installed (scripts/setup installs it)")
    read_fd, write_fd = os.pipe()
    # -displayfd: Xvfb picks a free display number and writes it to the pipe once it accepts connections.
    process = subprocess.Popen([xvfb, "-displayfd", str(write_fd), "-screen", "0", f"{size[0]}x{size[1]}x24",
                                "-nolisten", "tcp"], pass_fds=(write_fd,), stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
    os.close(write_fd)
    with os.fdopen(read_fd) as pipe:
        number = pipe.readline().strip()
    try:
        assert number, "Xvfb did not start"
        yield f":{number}", size
    finally:
        process.terminate()
        process.wait(timeout=10)


def window_geometry(display: str) -> Box | None:
    """The view's window, found by its caption: (left, top, right, bottom) on the screen, or None."""
    result = subprocess.run(["xwininfo", "-name", TITLE], env={**os.environ, "DISPLAY": display},
                            capture_output=True, text=True, timeout=10)
    if result.returncode != 0:
        return None
    fields = {key: int(value) for key, value in re.findall(r"^\s*(Absolute upper-left [XY]|Width|Height):\s+(-?\d+)",
                                                           result.stdout, re.MULTILINE)}
    left, top = fields["Absolute upper-left X"], fields["Absolute upper-left Y"]
    return left, top, left + fields["Width"], top + fields["Height"]


def window_captions(display: str) -> list[str]:
    tree = subprocess.run(["xwininfo", "-root", "-tree"], env={**os.environ, "DISPLAY": display},
                          capture_output=True, text=True, timeout=10).stdout
    return re.findall(r'^\s*0x[0-9a-f]+ "([^"]*LiDAR[^"]*)"', tree, re.MULTILINE)


def test_window_fits_the_screen_and_keeps_its_title(apps, domain_id: int, bus: Databus,  # type: ignore[no-untyped-def]
                                                    screen: tuple[str, tuple[int, int]], tmp_path: Path) -> None:
    display, (screen_width, screen_height) = screen
    writer = bus.writer("Circle", ShapeType, "Shapes")
    apps.start("lidar", "--domain", str(domain_id))
    # The shipped picture size (1600x800) is too big for either screen: the window shrinks to fit.
    view = apps.start("lidar_view", "--ui", "window", "--domain", str(domain_id), env={"DISPLAY": display})
    found = view.wait_for(r"lidar view: window on rt/LidarTopic \((\d+)x(\d+)\)")
    wait_until(lambda: window_geometry(display) is not None, what="the view's window")
    geometry = window_geometry(display)
    assert geometry is not None
    left, top, right, bottom = geometry
    size = (right - left, bottom - top)
    assert f"({size[0]}x{size[1]})" in found
    # Room left for the decorations a window manager adds (none here: Xvfb runs none).
    assert size[0] <= screen_width - 20 and size[1] <= screen_height - 40, size
    assert 0 <= left and right <= screen_width and 0 <= top and bottom <= screen_height, geometry
    figure = CloudFigure(size, title=TITLE)  # the same layout, in-process, for where the panels are

    red = ShapeType("RED", *circle(-3, 0), 90)  # a sphere of 1.5 m radius, 3 m behind the sensor
    shots: list[npt.NDArray[np.uint8]] = []

    def red_sphere_shown() -> bool:
        # Written until seen: a write before the LiDAR's reader matched would be lost (the Shapes QoS is volatile).
        writer.write(red)
        shot = ImageGrab.grab(xdisplay=display).convert("RGB").crop(geometry)
        shot.save(tmp_path / "window.png")  # to look at when this fails
        pixels = np.asarray(shot)
        shown = all(count(pixels, figure.panels[panel], RED) > 50 and count(pixels, figure.panels[panel],
                                                                            GROUND_RGB) > 500
                    for panel in ("perspective", "top"))
        if shown:
            shots.append(pixels)
        return shown

    wait_until(red_sphere_shown, what="the red sphere in both panels of the window")
    # Later frames (the status box changes: cloud number, stamp) leave the title, legend and axes where they were,
    # pixel for pixel, and the window's caption as it was.
    xyz, rgb = scene_cloud(1, RED=(-3, 0, 90))
    figure.render(xyz, rgb, "cloud 1")
    status = figure.status_box()
    chrome = chrome_mask(figure, status)
    s_left, s_top, s_right, s_bottom = status

    def another_frame() -> bool:
        pixels = np.asarray(ImageGrab.grab(xdisplay=display).convert("RGB").crop(geometry))
        if np.array_equal(pixels[s_top:s_bottom, s_left:s_right], shots[-1][s_top:s_bottom, s_left:s_right]):
            return False
        shots.append(pixels)
        return len(shots) >= 4

    wait_until(another_frame, what="three more frames in the window")
    for shot in shots[1:]:
        assert np.array_equal(shot[chrome], shots[0][chrome])
    # ... and they are those of the in-process figure: the window shows the title, legend and axis labels tested above.
    assert np.array_equal(shots[0][chrome], figure.render(xyz, rgb, "cloud 1")[chrome])
    assert window_captions(display) == [TITLE]
    assert window_geometry(display) == geometry


def test_snapshot_shows_the_sphere_with_title_legend_and_axes(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                             bus: Databus, tmp_path: Path) -> None:
    writer = bus.writer("Circle", ShapeType, "Shapes")
    lidar = apps.start("lidar", "--domain", str(domain_id))
    magenta = ShapeType("MAGENTA", *circle(3, 1), 90)  # radius 1.5 m

    def magenta_taken() -> bool:
        writer.write(magenta)  # until taken: a write before the LiDAR's reader matched would be lost
        return lidar.count(r"shape MAGENTA appeared") > 0

    wait_until(magenta_taken, timeout=30, what="the LiDAR to take the magenta circle")
    picture = tmp_path / "cloud.png"
    # Every cloud the viewer can receive now was rendered after the LiDAR had the shape.
    result = apps.run("lidar_view", "--domain", str(domain_id), "--snapshot", str(picture), "--count", "2",
                      "--timeout", "30", "-D", "config.imageWidth=800", "-D", "config.imageHeight=400", timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
    assert re.search(rf"snapshot of cloud 2 written to {re.escape(str(picture))} \(800x400\): cloud stamped "
                     r"\d+\.\d{9}, frame 'map': 11520 points \(64 x 180\)", result.stdout), result.stdout
    with Image.open(picture) as image:
        assert image.format == "PNG" and image.size == (800, 400)
        pixels = np.asarray(image.convert("RGB"))
    figure = CloudFigure((800, 400), title=TITLE)
    # The sphere shows in the perspective view and in the top view, with the scene.
    for panel in figure.panels.values():
        assert count(pixels, panel, MAGENTA) > 50
        for colour in (BACKGROUND_RGB, GROUND_RGB):
            assert count(pixels, panel, colour) > 300
    xyz, rgb = scene_cloud(1, MAGENTA=(3, 1, 90))
    expected = figure.render(xyz, rgb, "cloud 2")
    chrome = chrome_mask(figure, figure.status_box())
    assert np.array_equal(pixels[chrome], expected[chrome])  # title, legend, axes and their labels


# -- no window without a display -------------------------------------------------------------------------------------

NO_DISPLAY = "no display: neither DISPLAY nor WAYLAND_DISPLAY is set"
# What SDL says of a display no X server serves: it falls back to a driver that draws into memory.
UNREACHABLE = (r"SDL cannot open the display DISPLAY=':9\d\d' and fell back to SDL's '(offscreen|dummy)' video driver, "
               r"which shows no window")




@pytest.mark.parametrize("environment, reason", [
    ({}, re.escape(NO_DISPLAY)),
    ({"DISPLAY": "free"}, UNREACHABLE),
], ids=["unset", "unreachable"])
def test_window_without_a_display_is_refused_before_joining_the_bus(domain_id: int, environment: dict[str, str],
                                                                    reason: str) -> None:
    if environment.get("DISPLAY") == "free":
        environment = {"DISPLAY": free_x_display()}
    result = run_without_display("lidar_view", "window", domain_id, **environment)
    assert result.returncode == 2, result
    prog = re.escape(command_of("lidar_view"))
    assert re.fullmatch(rf"{prog}: --ui window: {reason}\n", result.stderr), result.stderr
    assert result.stdout == "", "the view got as far as logging (its network line comes before the participant)"


def test_window_on_sdl_offscreen_driver_is_refused_even_with_a_display(domain_id: int,
                                                                       virtual_display: str) -> None:
    result = run_without_display("lidar_view", "window", domain_id, DISPLAY=virtual_display,
                                 SDL_VIDEODRIVER="offscreen")
    assert result.returncode == 2, result
    assert result.stderr == (f"{command_of('lidar_view')}: --ui window: SDL_VIDEODRIVER=offscreen chose SDL's "
                             "'offscreen' video driver, which shows no window\n")
    assert result.stdout == ""
    assert window_captions(virtual_display) == []


@pytest.mark.parametrize("display, reason", [("", re.escape(NO_DISPLAY)), ("free", UNREACHABLE)],
                         ids=["unset", "unreachable"])
def test_auto_without_a_display_logs_the_clouds_and_says_why(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                            display: str, reason: str) -> None:
    apps.start("lidar", "--domain", str(domain_id))
    view = apps.start("lidar_view", "--domain", str(domain_id),
                      env={"DISPLAY": free_x_display() if display == "free" else "", "WAYLAND_DISPLAY": ""})
    view.wait_for(rf"lidar_view: lidar view: log lines only on rt/LidarTopic \(no window: {reason}; --snapshot FILE "
                  r"writes a picture without a display\)$")
    # What it can do without a display, it does: a line about the clouds it receives.
    view.wait_for(r"lidar_view: cloud 1: cloud stamped \d+\.\d{9}, frame 'map': 11520 points \(64 x 180\)$")
    assert view.stop() == 0
    assert "Traceback" not in view.output
    assert "XDG_RUNTIME_DIR" not in view.output  # SDL's probing is not shown beside the view's one line
