"""Rules a received sample must follow before an application sees it: generic ones, derived from the type's
annotations, and semantic ones, written by the module that knows the data.

Generic rules, for every type, found by walking its members (nested structs, arrays and sequences included):

- every ``float32``/``float64`` member is finite (no NaN, no infinity): nothing in this system means "unknown" by
  NaN, and one NaN silently turns comparisons false (an object of NaN metres is never "taller than 2 m");
- every timestamp (a member of a type of :data:`TIMESTAMP_MEMBERS`) is well formed: nanoseconds 0..999,999,999,
  seconds 0 or more. Old and future times are NOT errors here: a replayed recording carries its original data
  timestamps, and what "too old" means depends on the use (redundant mode's StallGuard judges the writers' source
  timestamps against its lease; see automotive.bus.ownership).

What Cyclone already checks in C on reception (measured with Cyclone 11.0.1 and Fast DDS 2.9): enum values outside
the enum, strings and sequences over their IDL bounds, truncated samples. Such a sample never reaches Python; Cyclone
drops it and logs a warning, which automotive.bus.cyclonelog rate-limits. Bounds that only our writers enforce
(automotive.bus.bounds.EXTRA_BOUNDS, e.g. the 368,640-byte cloud of RTI's IDL) are not applied to what we read: ROS 2's
PointCloud2 is unbounded and larger clouds of other publishers are valid.

A sequence of fixed-size structs decoded as a numpy structured array (automotive.bus.checkedreader's views) has its
float fields checked in bulk; its elements' types have no timestamp or semantic rule.

Semantic rules, one function per type in the module that knows the data (:data:`SEMANTIC_CHECKS`): a PointCloud2's
geometry and a Shapes Demo circle's size and position (automotive.bus.samplerules). Camera frames
are decoded by their own codec, which checks their length and header (automotive.wire.camera).

:func:`check` returns the first problem found (a :class:`BadSample`) or None. Rules are compiled once per type.
"""

from __future__ import annotations

import math
import typing
from collections.abc import Callable
from functools import cache
from typing import TYPE_CHECKING, Any

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, sequence, typedef

from automotive.bus import samplerules
from automotive.bus.badsamples import BadSample
from automotive.cyclone.bounds import member_types
from automotive.cyclone.codecs import numpy_if_loaded
from automotive.types.automotive import ShapeType
from automotive.types.builtin_interfaces.msg.dds_ import Time_
from automotive.types.Common import POSIXTimestamp
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_

if TYPE_CHECKING:
    import numpy as np

# Timestamp types and their (seconds, nanoseconds) members.
TIMESTAMP_MEMBERS: dict[type, tuple[str, str]] = {
    POSIXTimestamp: ("s", "ns"),
    Time_: ("sec_", "nanosec_"),
}

# Per type: the rule of the module that knows the data. Applied to every sample of the type, nested ones too.
SEMANTIC_CHECKS: dict[type, Callable[[Any], BadSample | None]] = {
    PointCloud2_: samplerules.check_point_cloud2,
    ShapeType: samplerules.check_shape,
}

NANOSECONDS = 1_000_000_000
# A structured array up to this size has its float words summed by Python, a larger one by numpy (faster from about
# 128 words on, warm): a vision sample holds at most 10 objects (520 bytes), a fused list in event mode a few.
SMALL_ARRAY_BYTES = 1024
FINITE = "a finite number"

Checker = Callable[[Any, str], "BadSample | None"]


def timestamp_problem(seconds: int, nanoseconds: int, path: str, seconds_name: str,
                      nanoseconds_name: str) -> BadSample | None:
    """A malformed timestamp (nanoseconds outside 0..999,999,999, negative seconds), or None."""
    if not 0 <= nanoseconds < NANOSECONDS:
        return BadSample(_join(path, nanoseconds_name), str(nanoseconds), "nanoseconds 0..999999999")
    if seconds < 0:
        return BadSample(_join(path, seconds_name), str(seconds), "seconds since 1970, 0 or more")
    return None


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


def _is_float(hint: Any) -> bool:
    if hint is float:
        return True
    if typing.get_origin(hint) is typing.Annotated:
        args = typing.get_args(hint)
        return args[0] is float
    return False


def _check_float(value: float, path: str) -> BadSample | None:
    if math.isfinite(value):
        return None
    return BadSample(path, repr(value), FINITE)


def _check_floats(values: Any, path: str) -> BadSample | None:
    # A sum of finite float32 values cannot overflow a Python float: one test for the whole array in the usual case.
    # A NaN or infinity makes the sum non-finite; only then (or for float64 values big enough to overflow the sum)
    # is each element looked at.
    if math.isfinite(sum(values)):
        return None
    for index, value in enumerate(values):
        if not math.isfinite(value):
            return BadSample(f"{path}[{index}]", repr(value), FINITE)
    return None


@cache
def _float_fields(dtype: np.dtype[Any]) -> tuple[str, ...]:
    return tuple(name for name in dtype.names or () if dtype[name].base.kind == "f")


def _check_struct_array(values: np.ndarray[Any, Any], path: str) -> BadSample | None:
    """The float fields of a structured array (numpy views of a sequence of fixed-size structs), all at once."""
    import numpy as np  # imported already: ``values`` is numpy's

    fields = _float_fields(values.dtype)
    if fields and values.dtype.isnative and values.dtype.itemsize % 4 == 0 and values.flags.c_contiguous:
        # One sum over the whole array read as float32 words instead of one per field (a list of 2 vision objects:
        # 4 us instead of 19). A non-finite float32 or float64 field has every exponent bit of a float32 word set
        # (a float64's high word), so a finite sum proves every float field finite; other words (integers, a
        # float64's low word) may look non-finite: only then is each field looked at, as below. Not for a sample of
        # the other byte order (a big-endian writer's): its words read this way are other numbers.
        if values.nbytes <= SMALL_ARRAY_BYTES:
            # Python's sum over the words: after an idle wake-up (caches cold) it costs a third of numpy's
            # reduction, which wakes much more code (docs/measurements/alert-latency.md)
            total = sum(values.data.cast("B").cast("f"))
        else:
            total = values.view(np.float32).sum(dtype=np.float64)
        if math.isfinite(total):
            return None
    for name in fields:
        column = values[name]
        # As _check_floats: one sum for the whole column in the usual case (finite float32 values cannot overflow
        # a float64 sum); only a non-finite sum makes each element looked at.
        if math.isfinite(column.sum(dtype=np.float64)):
            continue
        finite = np.isfinite(column)
        if finite.all():
            continue
        bad = np.argwhere(~finite)[0]
        index, rest = int(bad[0]), "".join(f"[{int(i)}]" for i in bad[1:])
        return BadSample(f"{path}[{index}].{name}{rest}", repr(float(column[tuple(bad)])), FINITE)
    return None


def _elements(element: Checker) -> Checker:
    def check(values: Any, path: str) -> BadSample | None:
        numpy = numpy_if_loaded()
        if numpy is not None and isinstance(values, numpy.ndarray) and values.dtype.names is not None:
            return _check_struct_array(values, path)
        for index, value in enumerate(values):
            problem = element(value, f"{path}[{index}]")
            if problem is not None:
                return problem
        return None
    return check


def _checker(hint: Any) -> Checker | None:
    """The check of a member of this type hint, or None when nothing in it needs checking."""
    if isinstance(hint, typedef):
        return _checker(hint.subtype)
    if _is_float(hint):
        return _check_float
    if isinstance(hint, (array, sequence)):
        if _is_float(hint.subtype):
            return _check_floats
        element = _checker(hint.subtype)
        return _elements(element) if element is not None else None
    if isinstance(hint, type) and issubclass(hint, IdlStruct):
        return _struct_checker(hint)
    return None  # integers, booleans, enums, strings, octets: Cyclone's deserializer already holds them to the type


@cache
def _struct_checker(cls: type) -> Checker | None:
    members = [(name, checker) for name, hint in member_types(cls).items()
               if (checker := _checker(hint)) is not None]
    stamp = TIMESTAMP_MEMBERS.get(cls)
    semantic = SEMANTIC_CHECKS.get(cls)
    if not members and stamp is None and semantic is None:
        return None

    def check(sample: Any, path: str) -> BadSample | None:
        if stamp is not None:
            problem = timestamp_problem(getattr(sample, stamp[0]), getattr(sample, stamp[1]), path, *stamp)
            if problem is not None:
                return problem
        for name, member_check in members:
            problem = member_check(getattr(sample, name), _join(path, name))
            if problem is not None:
                return problem
        if semantic is not None:
            problem = semantic(sample)
            if problem is not None and path:
                return BadSample(_join(path, problem.member), problem.value, problem.expected)
            return problem
        return None
    return check


def check(sample: Any) -> BadSample | None:
    """The first rule ``sample`` breaks, or None."""
    checker = _struct_checker(type(sample))  # type: ignore[arg-type]
    return None if checker is None else checker(sample, "")
