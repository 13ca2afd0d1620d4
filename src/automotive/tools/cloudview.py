"""The picture of a point cloud a person looks at: a perspective view and a top view in metres, with a legend.

One matplotlib figure (the Agg canvas: no pyplot, no display) of exactly the requested size in pixels, the same for
the live window and the PNG of ``--snapshot``::

    +------------------------------------------------------------------------------+
    | LiDAR point cloud: rt/LidarTopic          [cloud 12   11520 points  20.0 ...] |  title, status box
    |            perspective              |               top view                 |
    |   3D axes: x (m), y (m), z (m)      |   y (m) | 2D axes, one scale           |
    |                                     |         +------ x (m)                  |
    |  (o) Shapes Demo circles (spheres)   (o) background sphere   (o) ground      |  legend
    +------------------------------------------------------------------------------+

The title, axes, legend and layout never change from frame to frame; what changes (cloud number, point count, rate,
stamp) goes into the status box, a fixed-width text at a fixed place. The region shown is rounded outwards to a
coarse step, so that range noise does not make the axes breathe.

Speed: everything but the points and the status box (the "chrome") is drawn by matplotlib once per region shown.
Each frame copies that picture, splats the points into the two panels with numpy (a small square per point, the
nearest point winning each pixel, projected with the 3D axes' own matrix so that they sit on its ticks) and draws
the status box alone. Points keep their exact rgb colour (no shading), so what a picture shows can be checked pixel
by pixel inside :attr:`CloudFigure.panels`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
import numpy.typing as npt
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.legend_handler import HandlerTuple
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator
from matplotlib.transforms import Bbox
from mpl_toolkits.mplot3d import Axes3D, proj3d
from PIL import Image

from automotive.sim.scene import BACKGROUND_RADIUS_M, BACKGROUND_RGB, GROUND_RGB, SHAPE_RGB

DEFAULT_SIZE = (1240, 640)  # fits a 1280x720 screen with the window's decorations
MIN_SIZE = (320, 160)
TITLE = "LiDAR point cloud"
SHAPES_LABEL = "Shapes Demo circles (spheres), in their colour"
BACKGROUND_LABEL = f"background sphere, {BACKGROUND_RADIUS_M:g} m around the sensor (nothing nearer)"
GROUND_LABEL = "ground (z = 0 m)"
STATUS_CHARS = 88  # the status box's width in characters: a fixed-width font, padded, so that the box keeps its size

_DPI = 100
_FACE = "#101014"
_PANE = "#16161c"
_INK = "#d8d8de"
_DIM_INK = "#9a9aa4"
_GRID = "#34343f"
_STATUS_FACE = "#22222b"
_CAMERA_AZIMUTH_DEG = 200.0  # behind the sensor (which looks along +x), a little to its right
_CAMERA_ELEVATION_DEG = 35.0
_CAMERA_FOV_DEG = 60.0
_FAR_M = 1e100  # points farther than this (a float64 cloud may hold 1e308) are not shown
_BOX_ZOOM = 1.0  # larger pushes the z axis's label out of the figure


def _rgb_hex(rgb: tuple[int, int, int]) -> str:
    return "#{:02x}{:02x}{:02x}".format(*rgb)


@dataclass(frozen=True)
class Region:
    """What the axes show, in metres: a square of side 2 ``half`` around (``x``, ``y``), and ``z_low``..``z_high``."""

    x: float
    y: float
    half: float
    z_low: float
    z_high: float


def region_of(xyz: npt.NDArray[np.float64]) -> Region:
    """The region that holds every (finite) point, its bounds rounded outwards to a round step (1, 2 or 5 times a
    power of ten) of at most an eighth of its half-size, so that it is at most about a fifth larger than needed.

    Rounding keeps the region, and so the axes and their ticks, unchanged while only noise moves the points."""
    if len(xyz) == 0:
        return Region(0.0, 0.0, 1.0, 0.0, 1.0)
    # Bounded, so that the arithmetic below (and matplotlib's on the limits) stays finite; farther points fall
    # off the picture.
    low, high = np.maximum(xyz.min(axis=0), -_FAR_M), np.minimum(xyz.max(axis=0), _FAR_M)
    raw_half = max(float(high[0] - low[0]), float(high[1] - low[1]), 2.0) / 2
    target = raw_half / 8
    decade = 10.0 ** math.floor(math.log10(target))
    step = decade * max(factor for factor in (1, 2, 5) if factor * decade <= target)
    x = round(float(low[0] + high[0]) / 2 / step) * step
    y = round(float(low[1] + high[1]) / 2 / step) * step
    reach = max(x - float(low[0]), float(high[0]) - x, y - float(low[1]), float(high[1]) - y, raw_half)
    half = math.ceil(reach / step) * step
    z_low = math.floor(float(low[2]) / step) * step
    z_high = max(math.ceil(float(high[2]) / step) * step, z_low + step)
    return Region(x, y, half, z_low, z_high)


def _splat(image: npt.NDArray[np.uint8], u: npt.NDArray[np.float64], v: npt.NDArray[np.float64],
           depth: npt.NDArray[np.float64], rgb: npt.NDArray[np.uint8], radius: int) -> None:
    """Draw each point as a (2 radius + 1)-pixel square centred on pixel (u, v) (column, row; rounded); where squares
    overlap the smallest depth wins. Only the covered pixels change."""
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


def check_size(size: tuple[int, int]) -> tuple[int, int]:
    width, height = int(size[0]), int(size[1])
    if width < MIN_SIZE[0] or height < MIN_SIZE[1]:
        raise ValueError(f"image size {width}x{height}: expected at least {MIN_SIZE[0]}x{MIN_SIZE[1]} pixels")
    return width, height


class CloudFigure:
    """The figure of :mod:`cloudview`, drawn again for each cloud with :meth:`render`.

    Its matplotlib objects are public for inspection: ``figure``, ``title``, ``status``, ``legend``, ``perspective``
    (the 3D axes) and ``top`` (the 2D axes)."""

    def __init__(self, size: tuple[int, int] = DEFAULT_SIZE, point_radius: int = 1, title: str = TITLE):
        self.width, self.height = check_size(size)
        self.point_radius = point_radius
        # Fonts and margins follow the size, so that a small picture keeps the same layout as a big one.
        scale = min(self.width / DEFAULT_SIZE[0], self.height / DEFAULT_SIZE[1])

        def px(value: float) -> float:
            return value * scale

        def pt(value: float) -> float:
            return max(value * scale, 3.0)

        self.figure = Figure(figsize=(self.width / _DPI, self.height / _DPI), dpi=_DPI, facecolor=_FACE)
        self._canvas = FigureCanvasAgg(self.figure)
        width, height = self.width, self.height
        pad, title_band, legend_band = px(10), px(40), px(36)
        self.title = self.figure.text(pad / width, 1 - pad / height, title, ha="left", va="top", color=_INK,
                                      fontsize=pt(14), fontweight="bold")
        # Animated: left out of the chrome, drawn on each frame (Figure.draw_artist).
        self.status = self.figure.text(1 - pad / width, 1 - pad / height, "", ha="right", va="top", color=_INK,
                                       fontsize=pt(9), family="monospace", animated=True,
                                       bbox={"boxstyle": "round,pad=0.4", "facecolor": _STATUS_FACE,
                                             "edgecolor": _GRID})

        def swatch(rgb: tuple[int, int, int]) -> Line2D:
            return Line2D([], [], linestyle="none", marker="o", markersize=pt(6.5), markeredgewidth=0,
                          color=_rgb_hex(rgb))

        # One entry, its markers side by side; red first, the circle people use most.
        shapes = tuple(swatch(rgb) for _, rgb in sorted(SHAPE_RGB.items(), key=lambda item: item[0] != "RED"))
        handles: list[Any] = [shapes, swatch(BACKGROUND_RGB), swatch(GROUND_RGB)]
        self.legend = self.figure.legend(
            handles, [SHAPES_LABEL, BACKGROUND_LABEL, GROUND_LABEL],
            handler_map={tuple: HandlerTuple(ndivide=None, pad=0.1)}, loc="lower center", ncols=3, frameon=False,
            fontsize=pt(10), labelcolor=_INK, bbox_to_anchor=(0.5, px(2) / height), handlelength=4.2,
            columnspacing=3.0)

        panel_top, panel_bottom = height - title_band, legend_band
        axis_title, ticks_left, ticks_below = px(26), px(62), px(48)
        side = max(panel_top - panel_bottom - axis_title - ticks_below, 10.0)
        top_left = width - pad - side
        self.top = self.figure.add_axes((top_left / width, (panel_bottom + ticks_below) / height,
                                         side / width, side / height))
        self.top.set_facecolor(_PANE)
        self.top.set_title("top view", color=_INK, fontsize=pt(11))
        self.top.set_xlabel("x (m)", color=_INK, fontsize=pt(10))
        self.top.set_ylabel("y (m)", color=_INK, fontsize=pt(10))
        self.top.tick_params(colors=_DIM_INK, labelsize=pt(9))
        for axis in (self.top.xaxis, self.top.yaxis):
            axis.get_offset_text().set(color=_DIM_INK, fontsize=pt(9))  # the "1e38" of far-flung clouds
        self.top.grid(True, color=_GRID, linewidth=max(px(0.8), 0.5))
        self.top.set_axisbelow(True)
        for spine in self.top.spines.values():
            spine.set_color(_DIM_INK)

        left_width = top_left - ticks_left - pad
        # Matplotlib keeps 3D axes square. The box seen from above is wide and low, so the square is as wide as the
        # column (less room for the z axis's ticks and label, which stand left of the box seen from behind the
        # sensor) and reaches above and below the panel; points are clipped to the panel, between the bands.
        middle, left_margin = (panel_top + panel_bottom) / 2, px(48)
        cube = left_width - left_margin
        perspective = self.figure.add_axes((left_margin / width, (middle - cube / 2) / height, cube / width,
                                            cube / height), projection="3d")
        assert isinstance(perspective, Axes3D)
        self.perspective: Axes3D = perspective
        perspective.set_facecolor(_FACE)
        perspective.patch.set_visible(False)
        self._panel_rows = (math.ceil(title_band), math.floor(height - panel_bottom))  # where points may go
        # Level with the top view's title, which matplotlib puts axes.titlepad points above its axes.
        title_pad = float(matplotlib.rcParams["axes.titlepad"]) * _DPI / 72
        self.figure.text(left_width / 2 / width, (panel_bottom + ticks_below + side + title_pad) / height,
                         "perspective", color=_INK, fontsize=pt(11), ha="center", va="baseline")
        perspective.view_init(elev=_CAMERA_ELEVATION_DEG, azim=_CAMERA_AZIMUTH_DEG)
        perspective.set_proj_type("persp", focal_length=1 / math.tan(math.radians(_CAMERA_FOV_DEG) / 2))
        for axis, name in ((perspective.xaxis, "x (m)"), (perspective.yaxis, "y (m)"), (perspective.zaxis, "z (m)")):
            axis.set_pane_color(_PANE)
            axis.line.set_color(_DIM_INK)
            axis.label.set_text(name)
            axis.label.set_color(_INK)
            axis.label.set_fontsize(pt(10))
            # A 3D axis draws its grid and tick marks from this dict (the tick lengths have no other setting).
            axis._axinfo["grid"].update(color=_GRID, linewidth=max(px(0.8), 0.5))
            axis._axinfo["tick"].update(inward_factor=0.0, outward_factor=0.3)
        perspective.tick_params(colors=_DIM_INK, labelsize=pt(8))
        for axis in (perspective.xaxis, perspective.yaxis, perspective.zaxis):
            axis.get_offset_text().set(color=_DIM_INK, fontsize=pt(8))
        # Few ticks: the axes are short on screen and their labels must not run into each other.
        for axis in (perspective.xaxis, perspective.yaxis):
            axis.set_major_locator(MaxNLocator(nbins=9, steps=[1, 2, 5, 10]))
        perspective.zaxis.set_major_locator(MaxNLocator(nbins=3, steps=[1, 2, 2.5, 5, 10]))

        self._region: Region | None = None
        self._chrome: npt.NDArray[np.uint8] | None = None
        # Where the points go, (left, top, right, bottom) pixels, right and bottom excluded. The axes' rectangles are
        # fixed (the 3D one is square already, so matplotlib keeps it as it is).
        self._margin = pad  # what the z axis's title keeps from the picture's left edge and its tick labels
        # Stands in for the z axis's label where that would fall off the picture (_place_z_title).
        self.z_title = self.figure.text(0, 0.5, "z (m)", color=_INK, fontsize=pt(10), rotation=90, ha="center",
                                        va="center", visible=False)
        self.panels = {"perspective": self._perspective_panel(),
                       # Inside the frame: points do not cover the axes' lines.
                       "top": self._pixel_box(self.top.get_position().transformed(self.figure.transFigure), inset=1)}

    def _perspective_panel(self) -> tuple[int, int, int, int]:
        left, top, right, bottom = self._pixel_box(
            self.perspective.get_position().transformed(self.figure.transFigure))
        return left, max(top, self._panel_rows[0]), right, min(bottom, self._panel_rows[1])

    def _place_z_title(self) -> bool:
        """Keep the z axis's title inside the picture; whether the chrome changed. Matplotlib puts a 3D axis's label
        where the box's proportions say: for a wide, low box (a picture of 1000x500) that is past the picture's left
        edge. There the axis's own label is hidden and ``z_title`` stands in for it at the same height, moved right
        just enough (the chrome is drawn again once)."""
        label = self.perspective.zaxis.label
        box = label.get_window_extent(self._canvas.get_renderer())
        if box.x0 >= self._margin:
            return False
        label.set_visible(False)
        self.z_title.set_position(((self._margin + box.width / 2) / self.width, (box.y0 + box.y1) / 2 / self.height))
        self.z_title.set_visible(True)
        return True

    def _pixel_box(self, bbox: Bbox, inset: int = 0) -> tuple[int, int, int, int]:
        """(left, top, right, bottom) pixel indexes, top-left origin, right and bottom excluded, of a display box."""
        left, right = math.ceil(bbox.x0) + inset, math.floor(bbox.x1) - inset
        top, bottom = self.height - math.floor(bbox.y1) + inset, self.height - math.ceil(bbox.y0) - inset
        return left, top, right, bottom

    def _draw_chrome(self, region: Region) -> None:
        """Everything but the points and the status box, for this region."""
        span_z = region.z_high - region.z_low
        self.top.set_xlim(region.x - region.half, region.x + region.half)
        self.top.set_ylim(region.y - region.half, region.y + region.half)
        self.perspective.set_xlim(region.x - region.half, region.x + region.half)
        self.perspective.set_ylim(region.y - region.half, region.y + region.half)
        self.perspective.set_zlim(region.z_low, region.z_high)
        # One scale on all three axes: a sphere looks round.
        self.perspective.set_box_aspect((2 * region.half, 2 * region.half, span_z), zoom=_BOX_ZOOM)
        self.perspective.zaxis.label.set_visible(True)  # where this region's box puts it, first
        self.z_title.set_visible(False)
        self._canvas.draw()
        if self._place_z_title():
            self._canvas.draw()
        self._chrome = np.asarray(self._canvas.buffer_rgba()).copy()
        self._region = region

    def _buffer(self) -> npt.NDArray[np.uint8]:
        return np.asarray(self._canvas.buffer_rgba())

    def render(self, xyz: npt.ArrayLike, rgb: npt.ArrayLike, status: str = "") -> npt.NDArray[np.uint8]:
        """The picture of these points (metres, rgb 0..255) as an RGB array of height x width x 3."""
        points = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        colours = np.asarray(rgb, dtype=np.uint8).reshape(-1, 3)
        if len(points) != len(colours):
            raise ValueError(f"{len(points)} points but {len(colours)} colours")
        finite = np.isfinite(points).all(axis=1)
        points, colours = points[finite], colours[finite]
        region = region_of(points)
        if region != self._region:
            self._draw_chrome(region)
        assert self._chrome is not None
        buffer = self._buffer()
        np.copyto(buffer, self._chrome)
        rgb_buffer = buffer[..., :3]  # RGBA: the points are opaque, alpha stays 255

        left, top, right, bottom = self.panels["perspective"]
        # The 3D axes' own projection (set when the chrome was drawn), then its 2D display transform.
        u, v, depth = proj3d.proj_transform(points[:, 0], points[:, 1], points[:, 2], self.perspective.M)
        display = self.perspective.transData.transform(np.column_stack([u, v])) if len(points) else np.empty((0, 2))
        # Display coordinates run from the bottom-left corner of pixel (row height-1, column 0).
        _splat(rgb_buffer[top:bottom, left:right], display[:, 0] - 0.5 - left,
               self.height - display[:, 1] - 0.5 - top, np.asarray(depth, dtype=np.float64), colours,
               self.point_radius)

        left, top, right, bottom = self.panels["top"]
        display = self.top.transData.transform(points[:, :2]) if len(points) else np.empty((0, 2))
        # Seen from above: the highest point wins a pixel.
        _splat(rgb_buffer[top:bottom, left:right], display[:, 0] - 0.5 - left,
               self.height - display[:, 1] - 0.5 - top, -points[:, 2], colours, self.point_radius)

        self.status.set_text(status.ljust(STATUS_CHARS))
        self.figure.draw_artist(self.status)
        return self._buffer()[..., :3].copy()

    def status_box(self) -> tuple[int, int, int, int]:
        """Where the status box was drawn by the last :meth:`render`: (left, top, right, bottom) pixels."""
        patch = self.status.get_bbox_patch()
        assert patch is not None
        left, top, right, bottom = self._pixel_box(patch.get_window_extent(self._canvas.get_renderer()))
        # Its antialiased edge reaches into the pixels around it.
        return left - 2, top - 2, right + 2, bottom + 2

    def save_png(self, image: npt.NDArray[np.uint8], path: str | Path) -> None:
        # Fast compression: these pictures are mostly flat background and are written often.
        Image.fromarray(image).save(path, format="PNG", compress_level=1)


def render_image(xyz: npt.ArrayLike, rgb: npt.ArrayLike, size: tuple[int, int] = DEFAULT_SIZE,
                 point_radius: int = 1, status: str = "", title: str = TITLE) -> npt.NDArray[np.uint8]:
    """One picture (height x width x 3 RGB) of size (width, height). A view of many clouds keeps a CloudFigure."""
    return CloudFigure(size, point_radius, title).render(xyz, rgb, status)


def render_png(xyz: npt.ArrayLike, rgb: npt.ArrayLike, path: str | Path, size: tuple[int, int] = DEFAULT_SIZE,
               point_radius: int = 1, status: str = "", title: str = TITLE) -> None:
    """Write :func:`render_image` as a PNG of exactly ``size`` (width, height) pixels."""
    figure = CloudFigure(size, point_radius, title)
    figure.save_png(figure.render(xyz, rgb, status), path)
