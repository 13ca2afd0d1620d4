"""The simulated LiDAR: a scene built from Shapes Demo circles and exact ray casting.

The sensor scans a fixed grid of rays (:class:`ScanGrid`): polar angles (from the +z axis, so 90 degrees is
horizontal) by azimuth angles (counter-clockwise from +x). World axes: x and y on the ground, z up, metres.
Every ray ends at the nearest of

- a background sphere of radius 8.5 m centred on the observer (grey),
- the ground plane z = 0 (a darker grey): a ray that would meet the background below the ground stops on it,
- the spheres made from Shapes Demo circles (:meth:`LidarScene.update_shape`), in their Shapes Demo colour.

Then a little range noise (reproducible: seeded) is added, and any point pushed below z = 0 is clamped onto the
ground. Each point is laid out as the PointCloud2 codec (:mod:`automotive.wire.pointcloud`) sends it: four
little-endian float32 (x, y, z, rgb), row by row: one row per polar angle (``height``), one column per azimuth angle
(``width``).

Everything is whole-array numpy; nothing loops over points in Python. The ray directions are computed once per
grid; the geometry (hit distances and colours) is recomputed only when a shape or the observer changed, so a frame
of a still scene costs only its noise and the conversion to x, y, z.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from automotive.bus.errors import ConfigError
from automotive.types.sensor_msgs.msg.dds_ import POINT_CLOUD_MAX_DATA, PointCloud2_
from automotive.wire.pointcloud import FRAME_ID, POINT_DTYPE, POINT_STEP, pack_rgb, to_point_cloud2

BACKGROUND_RADIUS_M = 8.5
BACKGROUND_RGB = (0x8C, 0x8C, 0x8C)
GROUND_RGB = (0x46, 0x46, 0x46)
UNKNOWN_SHAPE_RGB = (0xFF, 0xFF, 0xFF)
# The colours Shapes Demo draws its circles with. YELLOW is not drawn: it is the observer.
SHAPE_RGB: dict[str, tuple[int, int, int]] = {
    "BLUE": (0, 0, 255),
    "GREEN": (0, 255, 0),
    "RED": (255, 0, 0),
    "CYAN": (0, 255, 255),
    "MAGENTA": (255, 0, 255),
    "PURPLE": (128, 0, 128),
    "ORANGE": (255, 165, 0),
}
OBSERVER_COLOR = "YELLOW"
DEFAULT_OBSERVER = (0.0, 0.0, 1.0)
# The sensor never goes below this height, so that the ground stays in front of every downward ray.
MIN_OBSERVER_HEIGHT_M = 0.01
DEFAULT_NOISE_M = 0.02

# Labels of what a ray hit; shape k of the current scene is label _FIRST_SHAPE + k.
_BACKGROUND, _GROUND, _FIRST_SHAPE = 0, 1, 2
_HIT_EPSILON = 1e-4


def shape_rgb(color: str) -> tuple[int, int, int]:
    """The colour a Shapes Demo colour name is drawn with; white for a name Shapes Demo does not have."""
    return SHAPE_RGB.get(color, UNKNOWN_SHAPE_RGB)


def shapes_to_world(x: float, y: float) -> tuple[float, float]:
    """A Shapes Demo canvas position in metres on the ground plane."""
    return (x - 120.0) / 24.0, (y - 135.0) / 27.0


def _whole(value: Any, what: str, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ConfigError(f"{what}: expected a whole number of at least {low}, got {value!r}")
    return int(value)


def _angle(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value):
        raise ConfigError(f"{what}: expected an angle in degrees, got {value!r}")
    return float(value)


class ScanGrid:
    """The rays of one scan: ``polar_steps`` rows by ``azimuth_steps`` columns of unit directions.

    Angle k of a range is ``start + k * range / steps`` (k = 0 .. steps-1), in degrees as the properties give
    them (config.azimStart, config.azimRange, config.azimSteps, config.polarStart, config.polarRange,
    config.polarSteps).
    """

    def __init__(self, azimuth_start: float = 0.0, azimuth_range: float = 360.0, azimuth_steps: int = 180,
                 polar_start: float = 70.0, polar_range: float = 100.0, polar_steps: int = 64):
        self.azimuth_start = _angle(azimuth_start, "scan azimuth start (config.azimStart)")
        self.azimuth_range = _angle(azimuth_range, "scan azimuth range (config.azimRange)")
        self.azimuth_steps = _whole(azimuth_steps, "scan azimuth steps (config.azimSteps)", 1)
        self.polar_start = _angle(polar_start, "scan polar start (config.polarStart)")
        self.polar_range = _angle(polar_range, "scan polar range (config.polarRange)")
        self.polar_steps = _whole(polar_steps, "scan polar steps (config.polarSteps)", 1)
        azimuth = np.radians(self.azimuth_start + np.arange(self.azimuth_steps) * (self.azimuth_range
                                                                                   / self.azimuth_steps))
        polar = np.radians(self.polar_start + np.arange(self.polar_steps) * (self.polar_range / self.polar_steps))
        sin_p = np.sin(polar)[:, None]
        directions = np.empty((self.polar_steps, self.azimuth_steps, 3), dtype=np.float64)
        directions[..., 0] = sin_p * np.cos(azimuth)[None, :]
        directions[..., 1] = sin_p * np.sin(azimuth)[None, :]
        directions[..., 2] = np.cos(polar)[:, None]
        # float32 end to end: it is what goes on the wire and halves the memory traffic of every frame.
        self.directions: npt.NDArray[np.float32] = directions.reshape(-1, 3).astype(np.float32)
        self.directions.flags.writeable = False
        # The grid is separable: direction (j, k) = (sin p_j cos a_k, sin p_j sin a_k, cos p_j). Ray casting uses the
        # factors to work on the block of rows and columns that can see a sphere rather than on every ray.
        self.polar_rad: npt.NDArray[np.float64] = polar
        self.azimuth_rad: npt.NDArray[np.float64] = azimuth
        self.sin_polar = np.sin(polar).astype(np.float32)
        self.cos_polar = np.cos(polar).astype(np.float32)
        self.cos_azimuth = np.cos(azimuth).astype(np.float32)
        self.sin_azimuth = np.sin(azimuth).astype(np.float32)
        self._polar_in_range = bool(((polar >= 0) & (polar <= math.pi)).all())
        # x, y, z components as three contiguous arrays: numpy is several times faster on these than on the
        # 3-wide rows of `directions` when filling the 4-wide points.
        self.components: npt.NDArray[np.float32] = np.ascontiguousarray(self.directions.T)
        self.components.flags.writeable = False
        dz = directions[..., 2].reshape(-1)
        down = dz < -1e-9
        # Distance to the ground per metre of sensor height (inf for rays that never reach it).
        inv_down = np.full(dz.shape, np.inf)
        inv_down[down] = -1.0 / dz[down]
        self.ground_distance_per_metre: npt.NDArray[np.float32] = inv_down.astype(np.float32)
        self.ground_distance_per_metre.flags.writeable = False

    @property
    def height(self) -> int:
        return self.polar_steps

    @property
    def width(self) -> int:
        return self.azimuth_steps

    @property
    def point_count(self) -> int:
        return self.polar_steps * self.azimuth_steps

    @property
    def sample_bytes(self) -> int:
        return self.point_count * POINT_STEP

    def cone_block(self, axis: Sequence[float], half_angle: float) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
        """Rows and columns of the rays that may lie within ``half_angle`` radians of the direction ``axis``.

        A superset (with a small margin): the caller still tests each ray of the block exactly.
        """
        rows, cols = np.arange(self.height), np.arange(self.width)
        length = math.sqrt(sum(a * a for a in axis))
        if length == 0 or half_angle >= math.pi / 2 or not self._polar_in_range:
            return rows, cols
        margin = 1e-3
        polar = math.acos(max(-1.0, min(1.0, axis[2] / length)))
        rows = np.flatnonzero(np.abs(self.polar_rad - polar) <= half_angle + margin)
        if polar - half_angle - margin <= 0 or polar + half_angle + margin >= math.pi:
            return rows, cols  # the cone holds a pole: every azimuth
        # Widest azimuth difference on a cone of half-angle h around polar angle p: asin(sin h / sin p).
        spread = math.asin(min(1.0, math.sin(half_angle + margin) / math.sin(polar)))
        difference = (self.azimuth_rad - math.atan2(axis[1], axis[0]) + math.pi) % (2 * math.pi) - math.pi
        return rows, np.flatnonzero(np.abs(difference) <= spread + margin)

    def check_wire_bound(self, limit: int = POINT_CLOUD_MAX_DATA) -> None:
        """ConfigError unless a sample of this grid fits PointCloud2_.data_'s bound (RTI's IDL: 368,640 bytes)."""
        if self.sample_bytes > limit:
            raise ConfigError(f"scan of {self.azimuth_steps} azimuth x {self.polar_steps} polar steps "
                              f"(config.azimSteps, config.polarSteps) makes {self.sample_bytes} bytes a sample, over "
                              f"the PointCloud2 data bound of {limit} bytes ({limit // POINT_STEP} points)")

    def scaled(self, factor_azimuth: int, factor_polar: int) -> ScanGrid:
        """The same angular ranges with ``factor_azimuth`` x ``factor_polar`` times as many rays."""
        return ScanGrid(self.azimuth_start, self.azimuth_range, self.azimuth_steps * factor_azimuth,
                        self.polar_start, self.polar_range, self.polar_steps * factor_polar)


@dataclass(frozen=True)
class Sphere:
    """A drawn circle: where it is in metres (centre on the ground plus its radius up) and its colour."""

    color: str
    center: tuple[float, float, float]
    radius: float
    rgb: tuple[int, int, int]


class LidarScene:
    """What the LiDAR sees: the observer and one sphere per Shapes Demo colour, rendered on a :class:`ScanGrid`."""

    def __init__(self, grid: ScanGrid | None = None, seed: int = 0, noise_m: float = DEFAULT_NOISE_M,
                 observer: Sequence[float] = DEFAULT_OBSERVER, background_radius_m: float = BACKGROUND_RADIUS_M):
        if not (math.isfinite(noise_m) and noise_m >= 0):
            raise ConfigError(f"lidar noise: expected a distance of at least 0 m, got {noise_m!r}")
        if not (math.isfinite(background_radius_m) and background_radius_m > 0):
            raise ConfigError(f"lidar background radius: expected a distance above 0 m, got {background_radius_m!r}")
        self.grid = grid or ScanGrid()
        self.noise_m = float(noise_m)
        self.background_radius_m = float(background_radius_m)
        self.default_observer = (float(observer[0]), float(observer[1]), float(observer[2]))
        self._rng = np.random.default_rng(seed)
        self._shapes: dict[str, tuple[int, int, int]] = {}
        # Geometry of the current scene, recomputed lazily after a change: distance along each ray and what it hit.
        self._distance: npt.NDArray[np.float32] | None = None
        self._rgb: npt.NDArray[np.uint32] | None = None
        self._ground: npt.NDArray[np.bool_] | None = None
        self._noise_pool: npt.NDArray[np.float32] | None = None

    # -- the scene -------------------------------------------------------------------------------------------------

    def update_shape(self, color: str, x: int, y: int, shapesize: int) -> None:
        """A Shapes Demo circle appeared or moved (``ShapeType`` fields). YELLOW moves the observer instead."""
        value = (int(x), int(y), int(shapesize))
        if self._shapes.get(color) != value:
            self._shapes[color] = value
            self._distance = None

    def remove_shape(self, color: str) -> None:
        """A circle is gone (disposed or its writer left). Removing YELLOW puts the observer back."""
        if self._shapes.pop(color, None) is not None:
            self._distance = None

    def clear(self) -> None:
        if self._shapes:
            self._shapes.clear()
            self._distance = None

    @property
    def shape_colors(self) -> list[str]:
        return sorted(self._shapes)

    @property
    def observer(self) -> tuple[float, float, float]:
        """Where the sensor is: the YELLOW circle if there is one (height shapesize / 30), else the default."""
        yellow = self._shapes.get(OBSERVER_COLOR)
        if yellow is None:
            x, y, z = self.default_observer
        else:
            x, y = shapes_to_world(yellow[0], yellow[1])
            z = yellow[2] / 30.0
        return x, y, max(z, MIN_OBSERVER_HEIGHT_M)

    @property
    def spheres(self) -> list[Sphere]:
        """The drawn spheres: centre at the circle's ground position, radius and centre height shapesize / 60."""
        result = []
        for color in sorted(self._shapes):
            if color == OBSERVER_COLOR:
                continue
            x, y, size = self._shapes[color]
            radius = size / 60.0
            if radius <= 0:
                continue
            wx, wy = shapes_to_world(x, y)
            result.append(Sphere(color, (wx, wy, radius), radius, shape_rgb(color)))
        return result

    # -- rendering -------------------------------------------------------------------------------------------------

    def _geometry(self) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint32], npt.NDArray[np.bool_]]:
        """Noise-free distance along every ray to its nearest hit, the hit's colour, and whether it is ground."""
        if self._distance is not None and self._rgb is not None and self._ground is not None:
            return self._distance, self._rgb, self._ground
        grid = self.grid
        ox, oy, oz = self.observer
        ground_t = grid.ground_distance_per_metre * np.float32(oz)
        distance = np.minimum(ground_t, np.float32(self.background_radius_m))
        label = (ground_t < self.background_radius_m).astype(np.int32)  # _GROUND where the ground is nearer
        spheres = self.spheres
        palette = [pack_rgb(*BACKGROUND_RGB), pack_rgb(*GROUND_RGB)] + [pack_rgb(*s.rgb) for s in spheres]
        width = grid.width
        for index, sphere in enumerate(spheres):
            # Ray o + t d against sphere |p - c| = r, with |d| = 1: t = b -+ sqrt(b^2 - (|c - o|^2 - r^2)),
            # b = d . (c - o); only on the rays of the block that can see the sphere (one Python step per sphere).
            vx, vy, vz = sphere.center[0] - ox, sphere.center[1] - oy, sphere.center[2] - oz
            c = vx * vx + vy * vy + vz * vz - sphere.radius * sphere.radius
            inside = c <= 0
            half_angle = math.pi if inside else math.asin(sphere.radius / math.sqrt(c + sphere.radius ** 2))
            rows, cols = grid.cone_block((vx, vy, vz), half_angle)
            if rows.size == 0 or cols.size == 0:
                continue
            across = grid.cos_azimuth[cols] * np.float32(vx) + grid.sin_azimuth[cols] * np.float32(vy)
            b = np.multiply.outer(grid.sin_polar[rows], across)
            b += (grid.cos_polar[rows] * np.float32(vz))[:, None]
            disc = b * b - np.float32(c)
            hit = disc >= 0
            root = np.sqrt(np.maximum(disc, 0.0, dtype=np.float32))
            # Inside the sphere the near root is behind the sensor and the far one is the wall it sees.
            t = b + root if inside else b - root
            hit &= t > _HIT_EPSILON
            ray = (rows[:, None] * width + cols[None, :])[hit]
            t = t[hit]
            closer = t < distance[ray]
            ray = ray[closer]
            distance[ray] = t[closer]
            label[ray] = _FIRST_SHAPE + index
        self._distance = distance
        self._rgb = np.array(palette, dtype=np.uint32)[label]
        self._ground = label == _GROUND
        return self._distance, self._rgb, self._ground

    def _noise(self) -> npt.NDArray[np.float32] | None:
        """Range noise for one frame: a window at a random offset into a block of normal samples drawn once.

        Drawing fresh normals costs about as much as the rest of a frame; shifted windows of one larger block look
        the same in a point cloud and cost nothing. Reproducible: the block and the offsets come from the seed.
        """
        if self.noise_m <= 0:
            return None
        count = self.grid.point_count
        if self._noise_pool is None:
            self._noise_pool = self._rng.standard_normal(2 * count + 4099, dtype=np.float32) * np.float32(self.noise_m)
        start = int(self._rng.integers(0, len(self._noise_pool) - count + 1))
        return self._noise_pool[start:start + count]

    def render(self, out: npt.NDArray[np.float32] | None = None) -> npt.NDArray[Any]:
        """One scan: a structured array (``POINT_DTYPE``) of shape (height, width), a fresh array every call, or
        the points written into ``out`` (float32, shape (point_count, 4), any memory: a serialized cloud's data,
        :class:`automotive.wire.pointcloud.CloudBuffer`) and that memory returned as such an array."""
        distance, rgb, ground = self._geometry()
        grid = self.grid
        noise = self._noise()
        if noise is not None:
            distance = distance + noise
        if out is None:
            out = np.empty((grid.point_count, 4), dtype=np.float32)
        elif out.shape != (grid.point_count, 4) or out.dtype != np.float32:
            raise ValueError(f"render: expected a float32 array of shape ({grid.point_count}, 4), got {out.dtype} "
                             f"{out.shape}")
        for axis, origin in enumerate(self.observer):
            column = out[:, axis]
            np.multiply(grid.components[axis], distance, out=column)
            column += np.float32(origin)
        z = out[:, 2]
        # Noise moves ground hits off the plane and can push the lowest points of a sphere under it: clamp both.
        below = z < 0
        below |= ground
        z[below] = 0.0
        colours = out[:, 3].view(np.uint32)
        colours[:] = rgb
        colours[below] = pack_rgb(*GROUND_RGB)
        return out.view(POINT_DTYPE).reshape(grid.height, grid.width)

    def render_bytes(self) -> bytes:
        """One scan as the bytes of a PointCloud2 ``data_``."""
        return self.render().tobytes()

    def point_cloud2(self, stamp_sec: int, stamp_nanosec: int, frame_id: str = FRAME_ID) -> PointCloud2_:
        """One scan as a PointCloud2 message."""
        return to_point_cloud2(self.render(), stamp_sec, stamp_nanosec, frame_id)
