"""Readers for the pre-canned CSV data of the vision sensor and the vehicle platform (the original example's formats).

Vision file: a header line, then per row two timestamp columns (ignored), ten objects of eleven columns each
(id, classification, position[0..2], velocity[0..2], size[0..2]) and numObjects, how many of the ten are real.
Platform file: a header line, then two timestamp columns (ignored), velocity, yawRate, vehSpd, posGasPedal.

A malformed row is reported once (file, line, problem) and skipped; a file that cannot be read or has no usable row
raises DataFileError, which the application layer shows as one line on stderr.
"""

from __future__ import annotations

import csv
import logging
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

from automotive.bus.errors import ConfigError
from automotive.types.Common import ClassificationEnum
from automotive.types.Vision import VISION_OBJECT_LIST_MAX_SIZE, VisionObject

T = TypeVar("T")

TIMESTAMP_COLUMNS = 2
VISION_OBJECT_COLUMNS = 11
VISION_COLUMNS = TIMESTAMP_COLUMNS + VISION_OBJECT_LIST_MAX_SIZE * VISION_OBJECT_COLUMNS + 1
PLATFORM_FIELDS = ("velocity", "yawRate", "vehSpd", "posGasPedal")
PLATFORM_COLUMNS = TIMESTAMP_COLUMNS + len(PLATFORM_FIELDS)

# Past this many listed rows a file is clearly not in the expected format; the rest are only counted, so that a wrong
# file does not flood the log.
MAX_LISTED_PROBLEMS = 20

# The values end up in IDL float fields; a larger magnitude cannot be serialized.
FLOAT32_MAX = 3.4028234663852886e38

_CLASSIFICATION_LAST = max(member.value for member in ClassificationEnum)

Reporter = logging.Logger | Callable[[str], None] | None
_log = logging.getLogger(__name__)


class DataFileError(ConfigError):
    """A data file that cannot be used at all: missing, unreadable, or without a single usable row."""


@dataclass(frozen=True)
class PlatformRow:
    velocity: float  # m/s
    yawRate: float  # rad/s
    vehSpd: float  # km/h
    posGasPedal: float  # 0..100 %


class _RowError(ValueError):
    """One problem with one row; its message says what is wrong (file and line are added by the reader)."""


def _number(cells: list[str], index: int, header: list[str]) -> float:
    text = cells[index].strip()
    name = header[index].strip() if index < len(header) and header[index].strip() else f"column {index + 1}"
    try:
        value = float(text)
    except ValueError:
        raise _RowError(f"{name} = {text!r} is not a number") from None
    if not math.isfinite(value) or abs(value) > FLOAT32_MAX:
        raise _RowError(f"{name} = {text!r} is not a finite 32-bit float")
    return value


def _numbers(cells: list[str], start: int, stop: int, header: list[str]) -> list[float]:
    """The cells ``start..stop-1`` as numbers; the first that is none, or not a finite 32-bit float, named."""
    try:
        values = [float(cell) for cell in cells[start:stop]]  # float() ignores the blanks around a number
    except ValueError:
        values = []
    # One sum of magnitudes checks them all at once (NaN and infinity fail it); otherwise cell by cell, which names
    # the first bad one (or, for a sum of large good values, accepts them all).
    if len(values) == stop - start and sum(map(abs, values)) <= FLOAT32_MAX:
        return values
    return [_number(cells, i, header) for i in range(start, stop)]


def _whole(value: float, what: str, low: int, high: int) -> int:
    if value != int(value):
        raise _RowError(f"{what} {value:g} is not a whole number in {low}..{high}")
    if not low <= value <= high:
        raise _RowError(f"{what} {value:g} is outside {low}..{high}")
    return int(value)


def _check_width(cells: list[str], expected: int) -> list[str]:
    # A spreadsheet may leave empty cells after the last column; anything else is a wrong row.
    while len(cells) > expected and not cells[-1].strip():
        cells = cells[:-1]
    if len(cells) != expected:
        raise _RowError(f"{len(cells)} columns, expected {expected}")
    return cells


def _vision_row(cells: list[str], header: list[str]) -> list[VisionObject]:
    cells = _check_width(cells, VISION_COLUMNS)
    values = _numbers(cells, TIMESTAMP_COLUMNS, VISION_COLUMNS, header)
    count = _whole(values[-1], "numObjects", 0, VISION_OBJECT_LIST_MAX_SIZE)
    objects = []
    for i in range(count):
        # Columns of one object: id (not part of VisionObject), classification, position, velocity, size.
        v = values[i * VISION_OBJECT_COLUMNS:(i + 1) * VISION_OBJECT_COLUMNS]
        classification = _whole(v[1], f"object[{i}].classification", 0, _CLASSIFICATION_LAST)
        objects.append(VisionObject(classification=ClassificationEnum(classification),
                                    position=v[2:5], velocity=v[5:8], size=v[8:11]))
    return objects


def _platform_row(cells: list[str], header: list[str]) -> PlatformRow:
    cells = _check_width(cells, PLATFORM_COLUMNS)
    values = _numbers(cells, TIMESTAMP_COLUMNS, PLATFORM_COLUMNS, header)
    return PlatformRow(*values)


def _emit(report: Reporter, message: str) -> None:
    if report is None:
        _log.warning("%s", message)
    elif isinstance(report, logging.Logger):
        report.warning("%s", message)
    else:
        report(message)


def _load(path: Path | str, parse: Callable[[list[str], list[str]], T], report: Reporter) -> list[T]:
    name = str(path)
    rows: list[T] = []
    skipped = 0
    try:
        # utf-8-sig: files saved by spreadsheet programs often start with a byte-order mark.
        with open(path, newline="", encoding="utf-8-sig") as stream:
            reader = csv.reader(stream)
            header = next(reader, None)
            if header is None:
                raise DataFileError(f"{name}: the data file is empty (expected a header line and data rows)")
            for cells in reader:
                if not any(cell.strip() for cell in cells):
                    continue  # blank lines carry no row
                try:
                    rows.append(parse(cells, header))
                except _RowError as problem:
                    skipped += 1
                    if skipped <= MAX_LISTED_PROBLEMS:
                        _emit(report, f"{name}:{reader.line_num}: {problem}; row skipped")
    except OSError as error:
        raise DataFileError(f"{name}: cannot read the data file: {error.strerror or error}") from None
    except UnicodeDecodeError:
        raise DataFileError(f"{name}: not a text (UTF-8) CSV file") from None
    except csv.Error as error:
        raise DataFileError(f"{name}: not a readable CSV file: {error}") from None
    if skipped > MAX_LISTED_PROBLEMS:
        _emit(report, f"{name}: {skipped - MAX_LISTED_PROBLEMS} more malformed row(s) skipped without listing")
    if not rows:
        detail = f" ({skipped} malformed row(s) skipped)" if skipped else ""
        raise DataFileError(f"{name}: no usable data row{detail}")
    return rows


def load_vision_rows(path: Path | str, report: Reporter = None) -> list[list[VisionObject]]:
    """Each usable row of a vision CSV file as its list of (at most 10) objects; object ids are dropped.

    Malformed rows go to `report` (a logger's warning, or a callable taking one line) and are skipped.
    Raises DataFileError when the file cannot be read or has no usable row.
    """
    return _load(path, _vision_row, report)


def load_platform_rows(path: Path | str, report: Reporter = None) -> list[PlatformRow]:
    """Each usable row of a platform CSV file; malformed rows are reported and skipped as for load_vision_rows."""
    return _load(path, _platform_row, report)


def cycle_rows(rows: Sequence[T]) -> Iterator[T]:
    """The rows in order, forever: after the last comes the first again."""
    if not rows:
        raise ValueError("cycle_rows needs at least one row")
    while True:
        yield from rows
