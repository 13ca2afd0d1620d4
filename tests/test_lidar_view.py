"""The LiDAR view a person looks at: the picture (legend, axes in metres, a title that stays put) and its window.

The picture is checked in-process through its matplotlib objects and pixels (automotive.tools.cloudview), then the
running view (``python -m automotive.tools.lidar_view.lidar_view``) with a running LiDAR: its window on a private X
display of a laptop's size (xwininfo for the geometry and the caption, screenshots for the pixels) and its --snapshot
PNG, whose title, legend and axes must be pixel for pixel those of the in-process figure. And no window without a
display: ``--ui window`` is refused in one line before the view joins the bus, ``--ui auto`` logs the clouds and says
why.

Where the clouds come from (issue 32): a LiDAR on the view's host sends them through shared memory (iceoryx2) and
writes none on DDS for the view, which reads each one in place (:func:`read_cloud`); with ``config.transport=udp``
the view gets them on DDS. Bad bytes in shared memory are reported like bad DDS samples. Every test that runs a
LiDAR or the view names its iceoryx2 files with a prefix of its own (the ``prefix`` fixture), so that it meets
no other process on this machine in shared memory and leaves nothing in /dev/shm.
"""

from __future__ import annotations

import dataclasses
import os
import re
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from apprunner import Child, command_of
from cyclonedds.idl._support import Endianness
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
from shm_helpers import files_of

from automotive.bus.endpoints import Databus
from automotive.cyclone.matched import matched_subscriptions
from automotive.sim.scene import BACKGROUND_RGB, GROUND_RGB, SHAPE_RGB, LidarScene, ScanGrid
from automotive.tools.cloudview import DEFAULT_SIZE, CloudFigure
from automotive.tools.lidar_view.lidar_view import WINDOW_TITLE, CloudRate, cloud_points, fit_to_screen, status_line
from automotive.types.automotive import ShapeType
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_, PointField_
from automotive.wire.pointcloud import FLOAT32, decode_point_cloud2, read_cloud
from automotive.wire.shm import SharedMemory, SharedWriter

RED, MAGENTA = SHAPE_RGB["RED"], SHAPE_RGB["MAGENTA"]
TITLE = f"{WINDOW_TITLE}: rt/LidarTopic"  # what the view shows as its title and window caption
Box = tuple[int, int, int, int]  # left, top, right, bottom pixels
TIMEOUT = 60.0  # starting Python, Cyclone and iceoryx2 on a loaded 2-core machine can take a while
CLOUD_LINE = r"lidar_view: cloud (\d+): cloud stamped (\d+\.\d{9}), frame 'map': 11520 points \(64 x 180\)$"
SHARED_COUNTS = re.compile(r"shared memory: (\d+) clouds sent, (\d+) written on DDS")




def private(prefix: str) -> list[str]:
    """The arguments that give a LiDAR or the view this test's iceoryx2 files (``config.shmPrefix``)."""
    return ["-D", f"config.shmPrefix={prefix}"]


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

@pytest.mark.parametrize("size", [(1000, 500), (800, 400), (1600, 900), (1280, 720)], ids=str)
def test_every_axis_title_is_inside_the_picture(size: tuple[int, int]) -> None:
    """Issue 38: at 1000x500 the z axis's title fell off the picture's left edge."""
    figure = CloudFigure(size, title=TITLE)
    xyz, rgb = scene_cloud(1, RED=(3, 1, 60))
    figure.render(xyz, rgb, "cloud 1")
    renderer = figure.figure.canvas.get_renderer()  # type: ignore[attr-defined]
    z_title = figure.perspective.zaxis.label if figure.perspective.zaxis.label.get_visible() else figure.z_title
    assert z_title.get_text() == "z (m)" and z_title.get_visible()
    for label in (figure.perspective.xaxis.label, figure.perspective.yaxis.label, z_title,
                  figure.top.xaxis.label, figure.top.yaxis.label):
        box = label.get_window_extent(renderer)
        assert 0 <= box.x0 and box.x1 <= size[0] and 0 <= box.y0 and box.y1 <= size[1], (label.get_text(), box)


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
    wait_until(lambda: len(matched_subscriptions(writer)) == 1, what="the test's reader")
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


# -- a serialized cloud, read in place -------------------------------------------------------------------------------

def odd_cloud(xyz: npt.NDArray[np.float32], rgb: npt.NDArray[np.uint8]) -> PointCloud2_:
    """A cloud of these points (64 x 180) in another publisher's layout: fields in another order, 20-byte points,
    rows padded, big-endian data."""
    height, width, step, row_step = 64, 180, 20, 180 * 20 + 8
    rows = np.zeros((height, row_step), dtype=np.uint8)
    points = rows[:, :width * step].reshape(height, width, step)
    packed = (rgb[:, 0].astype(np.uint32) << 16) | (rgb[:, 1].astype(np.uint32) << 8) | rgb[:, 2]
    points[:, :, 0:4] = packed.astype(">u4").reshape(height, width, 1).view(np.uint8)
    for axis in range(3):
        points[:, :, 8 + 4 * axis:12 + 4 * axis] = xyz[:, axis].astype(">f4").reshape(height, width, 1).view(np.uint8)
    cloud = LidarScene(ScanGrid()).point_cloud2(1_700_000_000, 5, "velodyne_top")
    fields = [PointField_(name_="rgb", offset_=0, datatype_=FLOAT32, count_=1),
              *(PointField_(name_=name, offset_=8 + 4 * axis, datatype_=FLOAT32, count_=1)
                for axis, name in enumerate("xyz"))]
    return dataclasses.replace(cloud, fields_=fields, is_bigendian_=True, point_step_=step, row_step_=row_step,
                               data_=rows.tobytes(), is_dense_=False)


@pytest.mark.parametrize("endianness", [Endianness.Little, Endianness.Big], ids=["little", "big"])
@pytest.mark.parametrize("version_2", [False, True], ids=["xcdr1", "xcdr2"])
def test_a_serialized_cloud_is_read_in_place_as_the_deserializer_reads_it(version_2: bool,
                                                                         endianness: Endianness) -> None:
    """XCDR1 (what our LiDAR sends) and XCDR2, either byte order: the header and layout that read_cloud reads from
    the bytes are those of the deserialized cloud, and its points those decode_point_cloud2 gives."""
    points = scene_cloud(3, RED=(3, 1, 60))
    for cloud in (LidarScene(ScanGrid(), seed=2).point_cloud2(1_700_000_000, 7, "map"), odd_cloud(*points)):
        serialized = memoryview(cloud.serialize(use_version_2=version_2, endianness=endianness)).toreadonly()
        read, data = read_cloud(serialized)
        assert data is not None  # read in place, not deserialized
        assert read.data_ == []
        assert dataclasses.replace(read, data_=bytes(serialized[data])) == dataclasses.replace(
            PointCloud2_.deserialize(bytes(serialized)), data_=bytes(cloud.data_))
        xyz, rgb = cloud_points(read, data, serialized)
        expected_xyz, expected_rgb = decode_point_cloud2(cloud)
        assert np.array_equal(xyz, expected_xyz) and np.array_equal(rgb, expected_rgb)
        serialized.release()  # nothing kept a view of it (raises BufferError otherwise)
    assert np.array_equal(xyz, points[0]) and np.array_equal(rgb, points[1])  # the odd layout's points, as sent


def test_bytes_that_are_not_a_point_cloud_are_one_value_error() -> None:
    good = LidarScene(ScanGrid(azimuth_steps=8, polar_steps=4)).point_cloud2(1_700_000_000, 0).serialize(
        use_version_2=False)
    five_fields = bytearray(good)
    five_fields[28] = 5  # the count of fields: after the encapsulation, stamp, frame_id "map", height and width
    assert good[28:32] == b"\x04\x00\x00\x00"
    cases = [
        (good[:2], r"^2 bytes, too few for an encapsulation header$"),
        (good[:100], r"^100 bytes, ending inside the member at byte \d+$"),
        (good[:-200], rf"^{len(good) - 200} bytes, too few for the 512 bytes at byte \d+$"),
        (bytes(five_fields), r"^5 fields \(a PointCloud2 has at most 4\)$"),
        (b"\x00\x42\x00\x00" + good[4:], r"^encapsulation 0x0042: "),
    ]
    for data, message in cases:
        with pytest.raises(ValueError, match=message):
            read_cloud(memoryview(data))


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


def test_window_fits_the_screen_and_keeps_its_title(prefix: str, apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                    bus: Databus, screen: tuple[str, tuple[int, int]],
                                                    tmp_path: Path) -> None:
    display, (screen_width, screen_height) = screen
    writer = bus.writer("Circle", ShapeType, "Shapes")
    apps.start("lidar", "--domain", str(domain_id), *private(prefix))
    # The shipped picture size (1600x800) is too big for either screen: the window shrinks to fit.
    view = apps.start("lidar_view", "--ui", "window", "--domain", str(domain_id), *private(prefix),
                      env={"DISPLAY": display})
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


def test_snapshot_shows_the_sphere_with_title_legend_and_axes(prefix: str, apps,  # type: ignore[no-untyped-def]
                                                             domain_id: int, bus: Databus, tmp_path: Path) -> None:
    writer = bus.writer("Circle", ShapeType, "Shapes")
    lidar = apps.start("lidar", "--domain", str(domain_id), *private(prefix))
    magenta = ShapeType("MAGENTA", *circle(3, 1), 90)  # radius 1.5 m

    def magenta_taken() -> bool:
        writer.write(magenta)  # until taken: a write before the LiDAR's reader matched would be lost
        return lidar.count(r"shape MAGENTA appeared") > 0

    wait_until(magenta_taken, timeout=30, what="the LiDAR to take the magenta circle")
    picture = tmp_path / "cloud.png"
    # Every cloud the viewer can receive now was rendered after the LiDAR had the shape.
    result = apps.run("lidar_view", "--domain", str(domain_id), *private(prefix), "--snapshot", str(picture),
                      "--count", "2", "--timeout", "30", "-D", "config.imageWidth=800", "-D", "config.imageHeight=400",
                      timeout=60)
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


# -- shared memory on one host, DDS with --------------------------------------------------------------------------

def cloud_lines(view: Child) -> list[tuple[int, str]]:
    """(number, stamp) of each cloud the view logged."""
    return [(int(match[1]), match[2]) for _, match in view.matches(CLOUD_LINE)]


def test_a_lidar_on_this_host_reaches_the_view_through_shared_memory_only(prefix: str, apps,  # type: ignore[no-untyped-def]
                                                                          domain_id: int) -> None:
    """The shipped transport (auto), LiDAR and view on one host: every cloud through shared memory and none written
    on DDS (the view's DDS reader carries this host's mark), each a new one; a clean stop leaves no file of ours."""
    lidar = apps.start("lidar", "--domain", str(domain_id), *private(prefix))
    view = apps.start("lidar_view", "--ui", "none", "--domain", str(domain_id), *private(prefix),
                      "-D", "config.logEvery=1")
    view.wait_for(CLOUD_LINE, count=5, timeout=TIMEOUT)
    assert lidar.stop(signal.SIGTERM) == 0, lidar.output
    sent = SHARED_COUNTS.search(lidar.output)
    assert sent is not None and int(sent[1]) >= 5 and sent[2] == "0", lidar.output
    assert view.stop(signal.SIGINT) == 0, view.output
    clouds = cloud_lines(view)
    assert [number for number, _ in clouds] == list(range(1, len(clouds) + 1)), view.output
    stamps = [float(stamp) for _, stamp in clouds]
    assert stamps == sorted(set(stamps)), view.output  # a new cloud each time, in order
    assert "Traceback" not in view.output and "bad sample" not in view.output, view.output
    assert files_of(prefix) == set()


def test_with_transport_udp_the_view_gets_the_clouds_on_dds(prefix: str, apps,  # type: ignore[no-untyped-def]
                                                           domain_id: int) -> None:
    """``-D config.transport=udp`` on the view: it has no shared memory, so the LiDAR (shared memory by default)
    writes the clouds on DDS for it, and the view shows them."""
    lidar = apps.start("lidar", "--domain", str(domain_id), *private(prefix))
    view = apps.start("lidar_view", "--ui", "none", "--domain", str(domain_id), *private(prefix),
                      "-D", "config.transport=udp", "-D", "config.logEvery=1")
    view.wait_for(CLOUD_LINE, count=5, timeout=TIMEOUT)
    assert lidar.stop(signal.SIGINT) == 0, lidar.output
    sent = SHARED_COUNTS.search(lidar.output)
    assert sent is not None and sent[1] == "0" and int(sent[2]) >= 5, lidar.output
    assert view.stop() == 0, view.output
    assert "Traceback" not in view.output and "bad sample" not in view.output, view.output


def test_bad_clouds_in_shared_memory_are_reported_and_the_snapshot_shows_the_next(  # type: ignore[no-untyped-def]
        prefix: str, apps, domain_id: int, tmp_path: Path) -> None:
    """A writer on this host (the test, through iceoryx2 as our LiDAR writes) sends bytes that are no PointCloud2
    (reported in one line, not counted), a cloud without rgb (counted, reported, not drawn: the snapshot takes the
    next cloud) and a good one: its snapshot is written, and nothing of a shared cloud outlived its block (the view
    would stop with "still in use")."""
    picture = tmp_path / "cloud.png"
    view = apps.start("lidar_view", "--domain", str(domain_id), *private(prefix), "--snapshot", str(picture),
                      "--timeout", str(TIMEOUT), "-D", "config.imageWidth=800", "-D", "config.imageHeight=400")
    scene = LidarScene(ScanGrid())
    scene.update_shape("MAGENTA", *circle(3, 1), 90)
    good = scene.point_cloud2(1_700_000_000, 2).serialize(use_version_2=False)
    no_rgb = dataclasses.replace(scene.point_cloud2(1_700_000_000, 1), fields_=scene.point_cloud2(0, 0).fields_[:3])
    memory = SharedMemory("test", domain_id, "rt/LidarTopic", prefix)
    writer = SharedWriter(memory, len(good), Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(1)),
                          lambda: True)

    def send(data: bytes) -> None:
        def fill(target: memoryview) -> int:
            target[:] = data
            return time.time_ns()
        writer.publish(len(data), fill)

    try:
        wait_until(lambda: memory.subscribers == 1, timeout=TIMEOUT, what="the view's shared-memory subscriber")
        send(good[:100])
        view.wait_for(r"\[rt/LidarTopic\] bad sample ignored: 100 bytes, ending inside the member at byte \d+ "
                      r"\(expected a serialized PointCloud2\), from a writer on this host \(shared memory\)",
                      timeout=TIMEOUT)
        send(no_rgb.serialize(use_version_2=False))
        view.wait_for(r"\[rt/LidarTopic\] bad sample not shown: fields_ = PointCloud2: missing field\(s\) rgb .*"
                      r"from a writer on this host \(shared memory\)", timeout=TIMEOUT)
        send(good)
        assert view.wait_exit(timeout=TIMEOUT) == 0, view.output
    finally:
        writer.close()
        memory.close()
    assert re.search(rf"snapshot of cloud 2 written to {re.escape(str(picture))} \(800x400\): cloud stamped "
                     r"1700000000\.000000002, frame 'map': 11520 points \(64 x 180\)", view.output), view.output
    assert "Traceback" not in view.output, view.output
    with Image.open(picture) as image:
        pixels = np.asarray(image.convert("RGB"))
    for panel in CloudFigure((800, 400), title=TITLE).panels.values():
        assert count(pixels, panel, MAGENTA) > 50


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
def test_auto_without_a_display_logs_the_clouds_and_says_why(prefix: str, apps,  # type: ignore[no-untyped-def]
                                                            domain_id: int, display: str, reason: str) -> None:
    apps.start("lidar", "--domain", str(domain_id), *private(prefix))
    view = apps.start("lidar_view", "--domain", str(domain_id), *private(prefix),
                      env={"DISPLAY": free_x_display() if display == "free" else "", "WAYLAND_DISPLAY": ""})
    view.wait_for(rf"lidar_view: lidar view: log lines only on rt/LidarTopic \(no window: {reason}; --snapshot FILE "
                  r"writes a picture without a display\)$")
    # What it can do without a display, it does: a line about the clouds it receives.
    view.wait_for(r"lidar_view: cloud 1: cloud stamped \d+\.\d{9}, frame 'map': 11520 points \(64 x 180\)$")
    assert view.stop() == 0
    assert "Traceback" not in view.output
    assert "XDG_RUNTIME_DIR" not in view.output  # SDL's probing is not shown beside the view's one line
