"""The semantic rules of received samples, per type (automotive.bus.validation applies them in the checked take).

A rule knows what its data may be: a Shapes Demo circle on its canvas, a PointCloud2 whose geometry agrees with its
data. The PointField datatypes of ROS 2 are defined here, the one place below both the rules and the PointCloud2
codec (automotive.wire.pointcloud) that use them.
"""

from __future__ import annotations

from typing import Any

from automotive.bus.badsamples import BadSample

# sensor_msgs/PointField datatypes (ROS 2) and their numpy codes.
INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = 1, 2, 3, 4, 5, 6, 7, 8
DATATYPE_CODES: dict[int, str] = {
    INT8: "i1", UINT8: "u1", INT16: "i2", UINT16: "u2", INT32: "i4", UINT32: "u4", FLOAT32: "f4", FLOAT64: "f8",
}

# The Shapes Demo canvas (pixels) and what a circle on it can be: the sizes Shapes Demo draws (automotive shapes-demo
# publishes 1..240) and positions at most one canvas beyond its edges (Shapes Demo keeps shapes inside; others may
# overshoot).
CANVAS_WIDTH, CANVAS_HEIGHT = 240, 270
MAX_SHAPE_SIZE = CANVAS_WIDTH


def check_shape(shape: Any) -> BadSample | None:
    """The semantic rule of a received Shapes Demo circle (``ShapeType``): a size of 1..MAX_SHAPE_SIZE pixels and a
    position within one canvas of the canvas. Anything else is no circle anyone drew; rendered it would put a sphere
    or the observer (YELLOW) thousands of kilometres away, or nowhere."""
    if not 1 <= shape.shapesize <= MAX_SHAPE_SIZE:
        return BadSample("shapesize", str(shape.shapesize), f"a size of 1..{MAX_SHAPE_SIZE} pixels")
    for name, value, extent in (("x", shape.x, CANVAS_WIDTH), ("y", shape.y, CANVAS_HEIGHT)):
        if not -extent <= value <= 2 * extent:
            return BadSample(name, str(value), f"{-extent}..{2 * extent}: within one canvas of the "
                             f"{CANVAS_WIDTH} x {CANVAS_HEIGHT} Shapes Demo canvas")
    return None


def check_point_cloud2(cloud: Any) -> BadSample | None:
    """The semantic rule of a received PointCloud2 (the LiDAR topic): its geometry agrees with its data, and its
    points have a position.

    As ROS 2 defines the message: ``data_`` holds ``height_`` rows of ``row_step_`` bytes, a row holds ``width_``
    points of ``point_step_`` bytes, and each field lies inside a point. A scan without x, y and z fields is no
    position at all. NaN coordinates inside ``data_`` are allowed: ROS marks rays without a return that way
    (``is_dense_`` false), and viewers skip them.
    """
    names = [field.name_ for field in cloud.fields_]
    missing = [axis for axis in ("x", "y", "z") if axis not in names]
    if missing:
        return BadSample("fields_", ",".join(names) or "none", "fields named x, y and z")
    point_step, row_step, width, height = cloud.point_step_, cloud.row_step_, cloud.width_, cloud.height_
    for index, field in enumerate(cloud.fields_):
        code = DATATYPE_CODES.get(int(field.datatype_))
        if code is None:
            return BadSample(f"fields_[{index}].datatype_", str(field.datatype_), "a PointField datatype 1..8")
        end = field.offset_ + int(code[1]) * max(field.count_, 1)
        if end > point_step:
            return BadSample(f"fields_[{index}].offset_", str(field.offset_),
                             f"field {field.name_} inside the point_step_ of {point_step} bytes")
    if row_step < width * point_step:
        return BadSample("row_step_", str(row_step), f"at least width_ x point_step_ = {width * point_step} bytes")
    if len(cloud.data_) != row_step * height:
        return BadSample("data_", f"{len(cloud.data_)} bytes", f"row_step_ x height_ = {row_step * height} bytes")
    return None
