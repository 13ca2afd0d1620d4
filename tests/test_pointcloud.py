"""The simulated LiDAR: scan geometry, shape colours, the observer, PointCloud2 encoding and decoding, the PNG view."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from PIL import Image

from automotive.bus.errors import ConfigError
from automotive.cyclone import fastpath
from automotive.sim.scene import BACKGROUND_RGB, GROUND_RGB, SHAPE_RGB, UNKNOWN_SHAPE_RGB, LidarScene, ScanGrid
from automotive.tools.cloudview import CloudFigure, render_png
from automotive.types.builtin_interfaces.msg.dds_ import Time_
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_, PointField_
from automotive.types.std_msgs.msg.dds_ import Header_
from automotive.wire.pointcloud import (
    FLOAT32,
    POINT_DTYPE,
    CloudBuffer,
    decode_point_cloud2,
    pack_rgb,
    to_point_cloud2,
)

DEFAULT_OBSERVER = np.array([0.0, 0.0, 1.0])


def scan(scene: LidarScene) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.uint8]]:
    xyz, rgb = decode_point_cloud2(scene.point_cloud2(0, 0))
    return xyz.astype(np.float64), rgb


def with_colour(xyz: npt.NDArray[np.float64], rgb: npt.NDArray[np.uint8], colour: tuple[int, int, int]
                ) -> npt.NDArray[np.float64]:
    return xyz[(rgb == np.array(colour, dtype=np.uint8)).all(axis=1)]


def circle(world_x: int, world_y: int) -> tuple[int, int]:
    """Shapes Demo canvas coordinates of a whole-metre ground position."""
    return 120 + 24 * world_x, 135 + 27 * world_y


def test_default_scan_size() -> None:
    grid = ScanGrid()
    assert (grid.height, grid.width, grid.point_count, grid.sample_bytes) == (64, 180, 11_520, 184_320)
    assert np.allclose(np.linalg.norm(grid.directions, axis=1), 1.0, atol=1e-6)
    points = LidarScene(grid).render()
    assert points.dtype == POINT_DTYPE and points.shape == (64, 180) and len(points.tobytes()) == 184_320


def test_no_shapes_sees_grey_sphere_and_darker_ground() -> None:
    xyz, rgb = scan(LidarScene(noise_m=0.0))
    wall = with_colour(xyz, rgb, BACKGROUND_RGB)
    ground = with_colour(xyz, rgb, GROUND_RGB)
    assert len(wall) + len(ground) == 11_520 and len(wall) > 2000 and len(ground) > 2000
    assert np.allclose(np.linalg.norm(wall - DEFAULT_OBSERVER, axis=1), 8.5, atol=1e-4)
    assert (wall[:, 2] >= 0).all()
    assert np.array_equal(ground[:, 2], np.zeros(len(ground)))
    assert (np.linalg.norm(ground - DEFAULT_OBSERVER, axis=1) <= 8.5 + 1e-4).all()
    assert sum(GROUND_RGB) < sum(BACKGROUND_RGB)


def test_noise_is_small_and_reproducible() -> None:
    first, second, other = LidarScene(seed=7), LidarScene(seed=7), LidarScene(seed=8)
    frames = [first.render_bytes() for _ in range(3)]
    assert frames == [second.render_bytes() for _ in range(3)]
    assert frames[0] != frames[1]  # every frame has fresh noise
    assert frames[0] != other.render_bytes()
    xyz, rgb = scan(LidarScene(seed=7))
    distance = np.linalg.norm(with_colour(xyz, rgb, BACKGROUND_RGB) - DEFAULT_OBSERVER, axis=1)
    assert 0.005 < distance.std() < 0.05 and abs(distance.mean() - 8.5) < 0.01
    assert (xyz[:, 2] >= 0).all()


@pytest.mark.parametrize(("colour", "position"), [
    ("BLUE", (4, 0)), ("GREEN", (0, 4)), ("RED", (-4, 0)), ("CYAN", (0, -4)),
    ("MAGENTA", (3, 3)), ("PURPLE", (-3, 3)), ("ORANGE", (-3, -3)), ("NOT_A_SHAPES_COLOUR", (3, -3)),
])
def test_circle_becomes_sphere_of_its_colour(colour: str, position: tuple[int, int]) -> None:
    scene = LidarScene(noise_m=0.0)
    scene.update_shape(colour, *circle(*position), 60)  # radius 1 m, centre 1 m up
    xyz, rgb = scan(scene)
    expected_rgb = SHAPE_RGB.get(colour, UNKNOWN_SHAPE_RGB)
    hits = with_colour(xyz, rgb, expected_rgb)
    assert len(hits) > 20
    centre = np.array([position[0], position[1], 1.0])
    assert np.allclose(np.linalg.norm(hits - centre, axis=1), 1.0, atol=1e-3)  # on the surface
    offset = hits - DEFAULT_OBSERVER
    bearing = np.degrees(np.arctan2(offset[:, 1], offset[:, 0]))
    expected_bearing = math.degrees(math.atan2(position[1], position[0]))
    spread = (bearing - expected_bearing + 180) % 360 - 180
    assert abs(np.median(spread)) < 3 and np.abs(spread).max() < 20  # asin(1 / 4) = 14.5 degrees each side
    nearest = np.linalg.norm(offset, axis=1).min()
    assert np.linalg.norm(centre - DEFAULT_OBSERVER) - 1.0 <= nearest < np.linalg.norm(centre - DEFAULT_OBSERVER) - 0.9
    assert len(with_colour(xyz, rgb, BACKGROUND_RGB)) < 11_520 - len(hits)  # the sphere hides some of the wall


def test_all_colours_at_once_and_nearest_hit_wins() -> None:
    scene = LidarScene(noise_m=0.0)
    scene.update_shape("RED", *circle(3, 0), 30)  # radius 0.5 m at 3 m
    scene.update_shape("BLUE", *circle(6, 0), 120)  # radius 2 m at 6 m, behind the red one
    xyz, rgb = scan(scene)
    red, blue = with_colour(xyz, rgb, SHAPE_RGB["RED"]), with_colour(xyz, rgb, SHAPE_RGB["BLUE"])
    assert len(red) > 0 and len(blue) > len(red)
    directions = ScanGrid().directions
    towards_red = np.array([3.0, 0.0, 0.5]) - DEFAULT_OBSERVER
    closest_ray = int(np.argmax(directions @ (towards_red / np.linalg.norm(towards_red))))
    assert tuple(rgb[closest_ray]) == SHAPE_RGB["RED"]  # this ray passes through both spheres; red is in front
    assert np.linalg.norm(xyz[closest_ray] - np.array([3.0, 0.0, 0.5])) == pytest.approx(0.5, abs=1e-3)


def test_yellow_moves_the_observer_and_is_not_drawn() -> None:
    scene = LidarScene(noise_m=0.0)
    scene.update_shape("YELLOW", *circle(2, -1), 90)  # observer at (2, -1), 3 m up
    scene.update_shape("RED", *circle(2, 3), 60)  # 4 m along +y from the observer
    assert scene.observer == pytest.approx((2.0, -1.0, 3.0))
    xyz, rgb = scan(scene)
    assert len(with_colour(xyz, rgb, (255, 255, 0))) == 0
    observer = np.array([2.0, -1.0, 3.0])
    wall = with_colour(xyz, rgb, BACKGROUND_RGB)
    assert np.allclose(np.linalg.norm(wall - observer, axis=1), 8.5, atol=1e-4)
    red = with_colour(xyz, rgb, SHAPE_RGB["RED"]) - observer
    assert len(red) > 0
    bearing = np.degrees(np.arctan2(red[:, 1], red[:, 0]))
    assert abs(np.median(bearing) - 90) < 3
    scene.remove_shape("YELLOW")
    assert scene.observer == pytest.approx(tuple(DEFAULT_OBSERVER))
    xyz, rgb = scan(scene)
    assert np.allclose(np.linalg.norm(with_colour(xyz, rgb, BACKGROUND_RGB) - DEFAULT_OBSERVER, axis=1), 8.5,
                       atol=1e-4)


def test_removed_shape_disappears() -> None:
    scene = LidarScene(noise_m=0.0)
    empty = scene.render_bytes()
    scene.update_shape("GREEN", *circle(0, 3), 60)
    xyz, rgb = scan(scene)
    assert len(with_colour(xyz, rgb, SHAPE_RGB["GREEN"])) > 0
    scene.update_shape("GREEN", *circle(0, -3), 60)  # moved: hits follow it
    xyz, rgb = scan(scene)
    assert (with_colour(xyz, rgb, SHAPE_RGB["GREEN"])[:, 1] < 0).all()
    scene.remove_shape("GREEN")
    xyz, rgb = scan(scene)
    assert len(with_colour(xyz, rgb, SHAPE_RGB["GREEN"])) == 0
    assert scene.render_bytes() == empty
    scene.remove_shape("GREEN")  # removing what is not there is harmless


def test_point_cloud2_layout() -> None:
    scene = LidarScene()
    msg = scene.point_cloud2(1_700_000_000, 123_456_789)
    assert isinstance(msg, PointCloud2_)
    assert msg.header_.frame_id_ == "map"
    assert (msg.header_.stamp_.sec_, msg.header_.stamp_.nanosec_) == (1_700_000_000, 123_456_789)
    assert [(f.name_, f.offset_, f.datatype_, f.count_) for f in msg.fields_] == [
        ("x", 0, FLOAT32, 1), ("y", 4, FLOAT32, 1), ("z", 8, FLOAT32, 1), ("rgb", 12, FLOAT32, 1)]
    assert FLOAT32 == 7
    assert (msg.height_, msg.width_, msg.point_step_, msg.row_step_) == (64, 180, 16, 180 * 16)
    assert isinstance(msg.data_, bytes) and len(msg.data_) == msg.row_step_ * msg.height_ == 184_320
    assert msg.is_bigendian_ is False and msg.is_dense_ is True
    flat = to_point_cloud2(scene.render().reshape(-1), 1, 2)
    assert (flat.height_, flat.width_, flat.row_step_) == (1, 11_520, 11_520 * 16)
    with pytest.raises(ValueError, match="dtype"):
        to_point_cloud2(np.zeros((4, 4), dtype=np.float32), 0, 0)


def test_rgb_is_packed_as_rviz_expects() -> None:
    scene = LidarScene(noise_m=0.0)
    scene.update_shape("ORANGE", *circle(4, 0), 60)
    raw = np.frombuffer(scene.render_bytes(), dtype="<u4").reshape(-1, 4)[:, 3]
    assert pack_rgb(*SHAPE_RGB["ORANGE"]) in set(raw.tolist())
    assert set(raw.tolist()) <= {pack_rgb(*BACKGROUND_RGB), pack_rgb(*GROUND_RGB), pack_rgb(*SHAPE_RGB["ORANGE"])}
    assert (raw >> 24 == 0).all()


def test_decode_round_trip_through_the_serializer() -> None:
    scene = LidarScene()
    scene.update_shape("PURPLE", *circle(-2, 2), 45)
    points = scene.render()
    msg = to_point_cloud2(points, 5, 6)
    xyz, rgb = decode_point_cloud2(msg)
    flat = points.reshape(-1)
    assert np.array_equal(xyz, np.stack([flat["x"], flat["y"], flat["z"]], axis=1))
    packed = flat["rgb"].view("<u4")
    assert np.array_equal(rgb, np.stack([packed >> 16, (packed >> 8) & 255, packed & 255], axis=1).astype(np.uint8))
    # Through both deserializers: the stock one gives data_ as a list of ints, the fast path as bytes.
    was_enabled = fastpath.enabled()
    try:
        for enable, kind in ((fastpath.disable, list), (fastpath.enable, bytes)):
            enable()
            received = PointCloud2_.deserialize(msg.serialize())
            assert isinstance(received.data_, kind)
            xyz2, rgb2 = decode_point_cloud2(received)
            assert np.array_equal(xyz2, xyz) and np.array_equal(rgb2, rgb)
    finally:
        (fastpath.enable if was_enabled else fastpath.disable)()


def test_decode_other_layouts_big_endian_and_padded() -> None:
    height, width, point_step, row_step = 3, 5, 24, 5 * 24 + 8
    rng = np.random.default_rng(1)
    xyz = rng.uniform(-10, 10, (height * width, 3)).astype(np.float32)
    rgb = rng.integers(0, 256, (height * width, 3), dtype=np.uint8)
    packed = (rgb[:, 0].astype(np.uint32) << 16) | (rgb[:, 1].astype(np.uint32) << 8) | rgb[:, 2]
    data = bytearray(row_step * height)
    layout = np.dtype({"names": ["rgb", "x", "y", "z"], "formats": [">u4", ">f4", ">f4", ">f4"],
                       "offsets": [0, 8, 12, 16], "itemsize": point_step})
    for row in range(height):  # a test fixture written the slow, obvious way
        block = np.zeros(width, dtype=layout)
        block["rgb"] = packed[row * width:(row + 1) * width]
        for axis, name in enumerate("xyz"):
            block[name] = xyz[row * width:(row + 1) * width, axis]
        data[row * row_step:row * row_step + width * point_step] = block.tobytes()
    fields = [PointField_("rgb", 0, FLOAT32, 1), PointField_("intensity", 4, FLOAT32, 1),
              PointField_("x", 8, FLOAT32, 1), PointField_("y", 12, FLOAT32, 1)]
    msg = PointCloud2_(header_=Header_(stamp_=Time_(0, 0), frame_id_="lidar"), height_=height, width_=width,
                       fields_=fields, is_bigendian_=True, point_step_=point_step, row_step_=row_step,
                       data_=list(data), is_dense_=True)
    with pytest.raises(ValueError, match="missing field.*z"):
        decode_point_cloud2(msg)
    msg.fields_ = [*fields[:1], *fields[2:], PointField_("z", 16, FLOAT32, 1)]
    got_xyz, got_rgb = decode_point_cloud2(msg)
    assert np.array_equal(got_xyz, xyz) and np.array_equal(got_rgb, rgb)
    msg.data_ = bytes(data[:-20])
    with pytest.raises(ValueError, match="bytes"):
        decode_point_cloud2(msg)
    msg.data_ = bytes(data)
    msg.fields_[-1] = PointField_("z", 22, FLOAT32, 1)
    with pytest.raises(ValueError, match="does not fit"):
        decode_point_cloud2(msg)


@pytest.mark.parametrize(("arguments", "key"), [
    ({"azimuth_steps": 0}, "config.azimSteps"),
    ({"polar_steps": 2.5}, "config.polarSteps"),
    ({"azimuth_range": float("nan")}, "config.azimRange"),
])
def test_bad_scan_parameters_name_the_property(arguments: dict[str, float], key: str) -> None:
    with pytest.raises(ConfigError, match=key):
        ScanGrid(**arguments)  # type: ignore[arg-type]


@pytest.mark.parametrize("size", [(1600, 800), (640, 360)])
def test_render_png_size_and_colours(tmp_path: Path, size: tuple[int, int]) -> None:
    scene = LidarScene()
    scene.update_shape("RED", *circle(3, 1), 60)
    xyz, rgb = scan(scene)
    path = tmp_path / "cloud.png"
    render_png(xyz, rgb, path, size=size)
    with Image.open(path) as image:
        assert image.format == "PNG" and image.size == size
        pixels = np.asarray(image.convert("RGB"))
    for left, top, right, bottom in CloudFigure(size).panels.values():  # the legend has these colours too
        panel = pixels[top:bottom, left:right].reshape(-1, 3)
        colours = {tuple(p) for p in np.unique(panel, axis=0).tolist()}
        assert SHAPE_RGB["RED"] in colours and BACKGROUND_RGB in colours and GROUND_RGB in colours


def brute_force_hits(grid: ScanGrid, observer: npt.NDArray[np.float64], spheres: list[tuple[float, float, float, float]]
                     ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Reference ray casting, every ray against every sphere in float64: nearest distance and sphere index (-1)."""
    d = grid.directions.astype(np.float64)
    best, which = np.full(len(d), np.inf), np.full(len(d), -1)
    for index, (x, y, z, r) in enumerate(spheres):
        v = np.array([x, y, z]) - observer
        b = d @ v
        disc = b * b - (v @ v - r * r)
        root = np.sqrt(np.maximum(disc, 0))
        t = np.where(v @ v <= r * r, b + root, b - root)
        t[(disc < 0) | (t <= 1e-4)] = np.inf
        closer = t < best
        best[closer], which[closer] = t[closer], index
    return best, which


@pytest.mark.parametrize("grid", [
    ScanGrid(),
    ScanGrid(azimuth_start=-90, azimuth_range=270, azimuth_steps=97, polar_start=0, polar_range=180, polar_steps=45),
    ScanGrid(azimuth_start=170, azimuth_range=40, azimuth_steps=60, polar_start=60, polar_range=60, polar_steps=50),
], ids=["default", "poles-and-partial-azimuth", "narrow-across-180"])
def test_ray_casting_matches_brute_force(grid: ScanGrid) -> None:
    """The block-wise casting finds exactly the hits of every-ray-against-every-sphere casting."""
    rng = np.random.default_rng(3)
    colours = ["BLUE", "GREEN", "RED", "CYAN", "MAGENTA", "PURPLE", "ORANGE"]
    for trial in range(12):
        scene = LidarScene(grid, noise_m=0.0)
        observer_xy = rng.integers(0, 240, 2)
        scene.update_shape("YELLOW", int(observer_xy[0]), int(observer_xy[1]), int(rng.integers(1, 90)))
        for colour in colours[:int(rng.integers(1, 8))]:
            scene.update_shape(colour, int(rng.integers(0, 240)), int(rng.integers(0, 270)), int(rng.integers(5, 200)))
        if trial % 4 == 0:  # the sensor inside a sphere; a sphere wrapping round the azimuth seam at 180 degrees
            scene.update_shape("ORANGE", int(observer_xy[0]), int(observer_xy[1]), 150)
            scene.update_shape("CYAN", int(observer_xy[0]) - 100, int(observer_xy[1]), 120)
        observer = np.array(scene.observer)
        spheres = scene.spheres
        best, which = brute_force_hits(grid, observer, [(*s.center, s.radius) for s in spheres])
        xyz, rgb = scan(scene)
        background = np.linalg.norm(xyz - observer, axis=1)
        seen = best < np.minimum(8.5, grid.ground_distance_per_metre * observer[2])
        # Rays whose sphere hit and background/ground distance differ by less than float32 rounding may go either way.
        clear = np.abs(best - np.minimum(8.5, grid.ground_distance_per_metre * observer[2])) > 1e-3
        for index, sphere in enumerate(spheres):
            mine = (rgb == np.array(sphere.rgb, dtype=np.uint8)).all(axis=1)
            expected = seen & (which == index)
            assert np.array_equal(mine[clear], expected[clear]), (trial, sphere)
            assert np.allclose(background[expected & clear], best[expected & clear], atol=2e-3)


def test_render_image_skips_points_it_cannot_place() -> None:
    from automotive.tools.cloudview import CloudFigure, render_image

    assert render_image(np.empty((0, 3)), np.empty((0, 3), dtype=np.uint8), (320, 160)).shape == (160, 320, 3)
    figure = CloudFigure((400, 200))
    image = figure.render(np.array([[np.nan, 0, 0], [1, 2, 0.5]]), np.array([[0, 0, 0], [255, 0, 0]]))
    for left, top, right, bottom in figure.panels.values():  # the legend has red too: only the panels count
        assert (image[top:bottom, left:right] == (255, 0, 0)).all(axis=2).any()
    with pytest.raises(ValueError, match="colours"):
        render_image(np.zeros((3, 3)), np.zeros((2, 3)))


def test_wire_bound_check() -> None:
    ScanGrid().check_wire_bound()
    ScanGrid(azimuth_steps=360).check_wire_bound()  # 23,040 points: exactly the 368,640-byte bound
    with pytest.raises(ConfigError, match=r"config.azimSteps.*368640 bytes"):
        ScanGrid(azimuth_steps=361).check_wire_bound()


@pytest.mark.parametrize("xcdr2", [False, True])
@pytest.mark.parametrize("frame_id", ["map", "lidar_front_left"])
def test_a_scan_rendered_into_a_cloud_buffer_is_the_serialized_cloud_byte_for_byte(xcdr2: bool, frame_id: str) -> None:
    grid = ScanGrid(azimuth_steps=90, polar_steps=16)
    by_message, in_place = LidarScene(grid, seed=5), LidarScene(grid, seed=5)
    for scene in (by_message, in_place):
        scene.update_shape("RED", 120, 135, 60)
    blank = to_point_cloud2(np.zeros((grid.height, grid.width), POINT_DTYPE), 0, 0, frame_id)
    cloud = CloudBuffer(blank.serialize(use_version_2=xcdr2))
    for number in range(3):  # the noise differs scan by scan: each one's bytes
        cloud.stamp(1_700_000_000 + number, 999_999_999 - number)
        in_place.render(out=cloud.points)
        expected = by_message.point_cloud2(1_700_000_000 + number, 999_999_999 - number, frame_id)
        assert bytes(cloud.data) == expected.serialize(use_version_2=xcdr2)


def test_a_cloud_buffer_wants_the_layout_it_renders_and_render_the_size_of_the_grid() -> None:
    grid = ScanGrid(azimuth_steps=8, polar_steps=4)
    other = PointCloud2_(header_=Header_(stamp_=Time_(sec_=0, nanosec_=0), frame_id_="map"), height_=1, width_=2,
                         fields_=[PointField_(name_="x", offset_=0, datatype_=FLOAT32, count_=1)],
                         is_bigendian_=False, point_step_=4, row_step_=8, data_=bytes(8), is_dense_=True)
    with pytest.raises(ValueError, match="16-byte points"):
        CloudBuffer(other.serialize())
    wrong = CloudBuffer(to_point_cloud2(np.zeros((2, 8), POINT_DTYPE), 0, 0).serialize())
    with pytest.raises(ValueError, match=r"shape \(32, 4\)"):
        LidarScene(grid).render(out=wrong.points)
