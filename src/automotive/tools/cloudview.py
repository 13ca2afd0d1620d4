"""Pictures of a point cloud: a perspective view and a top view side by side, as an RGB array or a PNG file.

Points are splatted into a numpy image (a small square per point, the nearest point winning each pixel) and the
image is written with Pillow, so a frame costs a few milliseconds and a live window can show the same array.
Points keep their exact rgb colour (no shading), so what a picture shows can be checked pixel by pixel.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import numpy.typing as npt
from PIL import Image, ImageDraw

BACKGROUND = (16, 16, 20)
GRID = (48, 48, 58)
SEPARATOR = (90, 90, 90)
LABEL = (170, 170, 170)
RING_SPACING_M = 2.0
MAX_RINGS = 100  # a cloud of a huge extent (a point thousands of km away) gets wider rings, not millions of them
_CAMERA_AZIMUTH_DEG = 200.0  # behind the sensor (which looks along +x), a little to its right
_CAMERA_ELEVATION_DEG = 35.0
_CAMERA_FOV_DEG = 60.0
_NEAR_M = 0.05


def _splat(image: npt.NDArray[np.uint8], u: npt.NDArray[np.float64], v: npt.NDArray[np.float64],
           depth: npt.NDArray[np.float64], rgb: npt.NDArray[np.uint8], radius: int) -> None:
    """Draw each point as a (2 radius + 1)-pixel square at (u, v); where squares overlap the smallest depth wins."""
    height, width = image.shape[:2]
    if len(depth) == 0:
        return
    order = np.argsort(depth, kind="stable")
    # Far points project far off the picture; clipped first, their pixel indexes stay valid integers.
    col = np.rint(np.clip(u[order], -1e9, 1e9)).astype(np.int64)
    row = np.rint(np.clip(v[order], -1e9, 1e9)).astype(np.int64)
    colours = rgb[order]
    offsets = np.arange(-radius, radius + 1)
    # (points, offsets^2) pixel coordinates, point-major, so that flattening keeps the nearest-first order.
    cols = (col[:, None, None] + offsets[None, None, :]).repeat(len(offsets), axis=1).reshape(len(col), -1)
    rows = (row[:, None, None] + offsets[None, :, None]).repeat(len(offsets), axis=2).reshape(len(row), -1)
    inside = (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
    pixel = (rows * width + cols)[inside]
    source = np.broadcast_to(np.arange(len(col))[:, None], inside.shape)[inside]
    # np.unique returns the first occurrence of each pixel: the nearest point that covers it.
    pixel, first = np.unique(pixel, return_index=True)
    # Index by (row, column): a panel is a strided view of the whole picture, which a reshape would copy.
    image[pixel // width, pixel % width] = colours[source[first]]


def ring_spacing(extent: float) -> float:
    """RING_SPACING_M, or a power of ten times it when the region shown would need more than MAX_RINGS rings."""
    spacing = RING_SPACING_M
    while extent / spacing > MAX_RINGS:
        spacing *= 10
    return spacing


def _rings(center: npt.NDArray[np.float64], extent: float) -> npt.NDArray[np.float64]:
    """Points along ground circles every ring_spacing(extent) around the centre, as a faint range scale."""
    spacing = ring_spacing(extent)
    radii = np.arange(spacing, extent + 1e-9, spacing)
    if radii.size == 0:
        return np.empty((0, 3))
    angles = np.linspace(0.0, 2 * math.pi, 720, endpoint=False)
    ring = np.empty((radii.size, angles.size, 3))
    ring[..., 0] = center[0] + radii[:, None] * np.cos(angles)[None, :]
    ring[..., 1] = center[1] + radii[:, None] * np.sin(angles)[None, :]
    ring[..., 2] = 0.0
    return ring.reshape(-1, 3)


def _extent(xyz: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], float]:
    """Centre (middle of the x, y bounds, on the ground) and half-size of the region to show."""
    if len(xyz) == 0:
        return np.zeros(3), 1.0
    low, high = xyz.min(axis=0), xyz.max(axis=0)
    center = np.array([(low[0] + high[0]) / 2, (low[1] + high[1]) / 2, 0.0])
    half = max(float(high[0] - low[0]), float(high[1] - low[1])) / 2
    return center, max(half, 1.0)


def _top_view(panel: npt.NDArray[np.uint8], xyz: npt.NDArray[np.float64], rgb: npt.NDArray[np.uint8],
              center: npt.NDArray[np.float64], half: float, radius: int) -> None:
    height, width = panel.shape[:2]
    scale = 0.47 * min(width, height) / half
    cu, cv = width / 2, height / 2
    rings = _rings(center, half)
    grid_rgb = np.broadcast_to(np.array(GRID, dtype=np.uint8), (len(rings), 3))
    _splat(panel, cu + scale * (rings[:, 0] - center[0]), cv - scale * (rings[:, 1] - center[1]),
           np.zeros(len(rings)), grid_rgb, 0)
    # Seen from above: the highest point wins a pixel.
    _splat(panel, cu + scale * (xyz[:, 0] - center[0]), cv - scale * (xyz[:, 1] - center[1]), -xyz[:, 2], rgb, radius)


def _perspective_view(panel: npt.NDArray[np.uint8], xyz: npt.NDArray[np.float64], rgb: npt.NDArray[np.uint8],
                      center: npt.NDArray[np.float64], half: float, radius: int) -> None:
    height, width = panel.shape[:2]
    azimuth, elevation = math.radians(_CAMERA_AZIMUTH_DEG), math.radians(_CAMERA_ELEVATION_DEG)
    focal = (width / 2) / math.tan(math.radians(_CAMERA_FOV_DEG) / 2)
    # Far enough back that the whole region fits the narrower side of the panel.
    distance = 0.8 * half / math.tan(math.radians(_CAMERA_FOV_DEG) / 2 * min(1.0, height / width)) + half
    target = center + np.array([0.0, 0.0, 0.5])
    camera = target + distance * np.array([math.cos(elevation) * math.cos(azimuth),
                                           math.cos(elevation) * math.sin(azimuth), math.sin(elevation)])
    forward = (target - camera) / np.linalg.norm(target - camera)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    basis = np.stack([right, up, forward], axis=1)

    def draw(points: npt.NDArray[np.float64], colours: npt.NDArray[np.uint8], size: int) -> None:
        camera_xyz = (points - camera) @ basis
        ahead = camera_xyz[:, 2] > _NEAR_M
        cam = camera_xyz[ahead]
        _splat(panel, width / 2 + focal * cam[:, 0] / cam[:, 2], height / 2 - focal * cam[:, 1] / cam[:, 2],
               cam[:, 2], colours[ahead], size)

    rings = _rings(center, half)
    draw(rings, np.broadcast_to(np.array(GRID, dtype=np.uint8), (len(rings), 3)), 0)
    draw(xyz, rgb, radius)


def render_image(xyz: npt.ArrayLike, rgb: npt.ArrayLike, size: tuple[int, int] = (1600, 800),
                 point_radius: int = 1) -> npt.NDArray[np.uint8]:
    """An RGB image (height x width x 3) of size (width, height): perspective view left, top view right."""
    width, height = int(size[0]), int(size[1])
    if width < 32 or height < 16:
        raise ValueError(f"image size {width}x{height}: expected at least 32x16 pixels")
    points = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    colours = np.asarray(rgb, dtype=np.uint8).reshape(-1, 3)
    if len(points) != len(colours):
        raise ValueError(f"{len(points)} points but {len(colours)} colours")
    finite = np.isfinite(points).all(axis=1)
    points, colours = points[finite], colours[finite]
    image = np.empty((height, width, 3), dtype=np.uint8)
    image[:] = BACKGROUND
    left = width // 2
    center, half = _extent(points)
    # Views of a numpy array: the panels draw straight into the image.
    _perspective_view(image[:, :left], points, colours, center, half, point_radius)
    _top_view(image[:, left + 1:], points, colours, center, half, point_radius)
    image[:, left] = SEPARATOR
    return image


def render_png(xyz: npt.ArrayLike, rgb: npt.ArrayLike, path: str | Path, size: tuple[int, int] = (1600, 800),
               point_radius: int = 1) -> None:
    """Write :func:`render_image` as a PNG of exactly ``size`` (width, height) pixels."""
    image = Image.fromarray(render_image(xyz, rgb, size, point_radius))
    points = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    _, half = _extent(points[np.isfinite(points).all(axis=1)])
    draw = ImageDraw.Draw(image)
    draw.text((8, 6), "perspective", fill=LABEL)
    draw.text((size[0] // 2 + 9, 6), f"top view (x right, y up; rings every {ring_spacing(half):g} m)", fill=LABEL)
    # Fast compression: these pictures are mostly flat background and are written often.
    image.save(path, format="PNG", compress_level=1)
