"""The CSV readers of the vision and platform data, on the project's own data files and on malformed input."""

from __future__ import annotations

import logging
import subprocess
import sys
from itertools import islice
from pathlib import Path

import pytest

from automotive import config
from automotive.bus.errors import ConfigError
from automotive.sim.csvdata import (
    PLATFORM_COLUMNS,
    VISION_COLUMNS,
    DataFileError,
    PlatformRow,
    cycle_rows,
    load_platform_rows,
    load_vision_rows,
)
from automotive.types.Common import ClassificationEnum
from automotive.types.Vision import VisionObject

ROOT = Path(__file__).resolve().parent.parent
DATA = config.properties_dir() / "data"
ALERT_SIZE = 2.0  # collision avoidance's default config.alertSize

VISION_HEADER = ",".join(
    ["Timestamp", "timeStamp"]
    + [f"object[{i}].{field}" for i in range(10) for field in
       ("id", "classification", *(f"{name}[{j}]" for name in ("position", "velocity", "size") for j in range(3)))]
    + ["numObjects"])
PLATFORM_HEADER = "Timestamp,timeStamp,velocity,yawRate,vehSpd,posGasPedal"
STAMP = "Tue May 14 09:30:00 2024,1.71568E+15"


def vision_line(objects: list[list[float]], count: int | None = None) -> str:
    """One vision row; each object is [id, classification, 3 positions, 3 velocities, 3 sizes]."""
    cells = [str(value) for obj in objects for value in obj]
    cells += ["0"] * (11 * (10 - len(objects)))
    cells.append(str(len(objects) if count is None else count))
    return f"{STAMP},{','.join(cells)}"


CAR = [1, 5, 20.0, 0.0, 0.75, -1.0, 0.0, 0.0, 4.5, 1.8, 1.5]
TRUCK = [2, 6, 18.0, 3.0, 1.75, -12.0, 0.0, 0.0, 9.0, 2.5, 3.5]


def write(path: Path, header: str, lines: list[str]) -> Path:
    path.write_text("\n".join([header, *lines]) + "\n")
    return path


def episodes(flags: list[bool]) -> list[tuple[int, int]]:
    """(first row, length) of each run of consecutive True."""
    runs: list[tuple[int, int]] = []
    for index, flag in enumerate(flags):
        if flag and (index == 0 or not flags[index - 1]):
            runs.append((index, 1))
        elif flag:
            runs[-1] = (runs[-1][0], runs[-1][1] + 1)
    return runs


# --- the project's data files ----------------------------------------------------------------------------------------

def test_vision_data_file_shape() -> None:
    messages: list[str] = []
    rows = load_vision_rows(DATA / "vision.csv", messages.append)
    assert messages == []
    assert len(rows) == 1000
    assert all(len(row) <= 10 for row in rows)
    assert sum(map(len, rows)) / len(rows) > 2  # a busy scene, not an empty road
    for obj in (obj for row in rows for obj in row):
        assert isinstance(obj, VisionObject)
        assert isinstance(obj.classification, ClassificationEnum)
        assert len(obj.position) == len(obj.velocity) == len(obj.size) == 3
    seen = {obj.classification for row in rows for obj in row}
    assert {ClassificationEnum.CLASSIFICATION_CAR, ClassificationEnum.CLASSIFICATION_PEDESTRIAN,
            ClassificationEnum.CLASSIFICATION_TRUCK, ClassificationEnum.CLASSIFICATION_BARRIER} <= seen
    # Same layout as the original: header, then rows of 113 columns.
    lines = (DATA / "vision.csv").read_text().splitlines()
    assert lines[0] == VISION_HEADER
    assert {len(line.split(",")) for line in lines} == {VISION_COLUMNS}


def test_vision_data_alert_episodes() -> None:
    """Collision avoidance's rule fires about once every 200 rows, for a handful of rows, and clears in between."""
    rows = load_vision_rows(DATA / "vision.csv")
    alert = [any(obj.size[1] > ALERT_SIZE for obj in row) for row in rows]
    runs = episodes(alert)
    assert len(runs) == 5, runs
    assert all(3 <= length <= 10 for _, length in runs), runs
    assert 25 <= sum(alert) <= 45
    starts = [start for start, _ in runs]
    # The gap across the wrap-around (last episode to the first one of the next pass) counts too.
    gaps = [b - a for a, b in zip(starts, starts[1:], strict=False)] + [starts[0] + len(rows) - starts[-1]]
    assert all(150 <= gap <= 250 for gap in gaps), gaps
    # Only trucks and barriers are that wide.
    wide = {obj.classification for row in rows for obj in row if obj.size[1] > ALERT_SIZE}
    assert wide <= {ClassificationEnum.CLASSIFICATION_TRUCK, ClassificationEnum.CLASSIFICATION_BARRIER}


def test_platform_data_file() -> None:
    messages: list[str] = []
    rows = load_platform_rows(DATA / "platform.csv", messages.append)
    assert messages == []
    assert len(rows) == 1000
    assert all(isinstance(row, PlatformRow) for row in rows)
    assert (DATA / "platform.csv").read_text().splitlines()[0] == PLATFORM_HEADER
    for row in rows:
        assert 5.0 < row.velocity < 20.0
        assert row.vehSpd == pytest.approx(row.velocity * 3.6, abs=0.01)
        assert 0.0 <= row.posGasPedal <= 100.0
        assert abs(row.yawRate) < 0.1
    # The speed varies smoothly (at most 0.25 m/s per 100 ms sample, i.e. 2.5 m/s2), including across the wrap.
    steps = [abs(b.velocity - a.velocity) for a, b in zip(rows, rows[1:] + rows[:1], strict=True)]
    assert max(steps) < 0.25
    assert max(row.velocity for row in rows) - min(row.velocity for row in rows) > 2.0


@pytest.mark.not_fast  # runs the generator as its command
def test_generator_is_deterministic(tmp_path: Path) -> None:
    subprocess.run([sys.executable, "-m", "automotive.tools.support.make_scene_data", "--out", str(tmp_path)],
                   check=True, capture_output=True, timeout=60)
    for name in ("vision.csv", "platform.csv"):
        assert (tmp_path / name).read_bytes() == (DATA / name).read_bytes(), name


# --- malformed rows --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize(("bad_line", "problem"), [
    (vision_line([CAR], count=12), "numObjects 12 is outside 0..10"),
    (vision_line([CAR], count=-1), "numObjects -1 is outside 0..10"),
    (vision_line([CAR], count=1.5), "numObjects 1.5 is not a whole number in 0..10"),  # type: ignore[arg-type]
    (vision_line([[1, 9, *CAR[2:]]]), "object[0].classification 9 is outside 0..7"),
    (vision_line([[1, 5, 20.0, "abc", *CAR[4:]]]), "object[0].position[1] = 'abc' is not a number"),
    (vision_line([[1, 5, 20.0, "", *CAR[4:]]]), "object[0].position[1] = '' is not a number"),
    (vision_line([[1, 5, "nan", *CAR[3:]]]), "object[0].position[0] = 'nan' is not a finite 32-bit float"),
    (vision_line([[1, 5, "1e39", *CAR[3:]]]), "object[0].position[0] = '1e39' is not a finite 32-bit float"),
    (vision_line([CAR]).rsplit(",", 5)[0], f"108 columns, expected {VISION_COLUMNS}"),
    (vision_line([CAR]) + ",7", f"114 columns, expected {VISION_COLUMNS}"),
])
def test_malformed_vision_row_is_reported_and_skipped(tmp_path: Path, bad_line: str, problem: str) -> None:
    path = write(tmp_path / "vision.csv", VISION_HEADER,
                 [vision_line([CAR]), vision_line([CAR, TRUCK]), bad_line, vision_line([])])
    messages: list[str] = []
    rows = load_vision_rows(path, messages.append)
    assert messages == [f"{path}:4: {problem}; row skipped"]
    assert [len(row) for row in rows] == [1, 2, 0]
    assert rows[1][1].classification == ClassificationEnum.CLASSIFICATION_TRUCK
    assert list(rows[1][1].size) == [9.0, 2.5, 3.5]


def test_objects_beyond_num_objects_are_ignored(tmp_path: Path) -> None:
    # A slot past numObjects may hold leftovers, like an unknown classification; only the counted objects matter.
    path = write(tmp_path / "vision.csv", VISION_HEADER, [vision_line([CAR, [3, 42, *CAR[2:]]], count=1)])
    messages: list[str] = []
    rows = load_vision_rows(path, messages.append)
    assert messages == []
    assert len(rows) == 1 and len(rows[0]) == 1


@pytest.mark.parametrize(("bad_line", "problem"), [
    (f"{STAMP},12.5,0.01,fast,30", "vehSpd = 'fast' is not a number"),
    (f"{STAMP},12.5,0.01,45", f"5 columns, expected {PLATFORM_COLUMNS}"),
    (f"{STAMP},inf,0.01,45,30", "velocity = 'inf' is not a finite 32-bit float"),
])
def test_malformed_platform_row_is_reported_and_skipped(tmp_path: Path, bad_line: str, problem: str) -> None:
    path = write(tmp_path / "platform.csv", PLATFORM_HEADER,
                 [f"{STAMP},12.5,0.01,45,30", bad_line, f"{STAMP},13,-0.02,46.8,35"])
    messages: list[str] = []
    rows = load_platform_rows(path, messages.append)
    assert messages == [f"{path}:3: {problem}; row skipped"]
    assert rows == [PlatformRow(12.5, 0.01, 45.0, 30.0), PlatformRow(13.0, -0.02, 46.8, 35.0)]


def test_numbers_each_within_32_bit_floats_are_kept_whatever_their_sum(tmp_path: Path) -> None:
    # Each cell is checked on its own: values near the limit add up past it, and are all valid.
    path = write(tmp_path / "platform.csv", PLATFORM_HEADER, [f"{STAMP}, 3e38 ,-3e38,3.4e38,30"])
    messages: list[str] = []
    assert load_platform_rows(path, messages.append) == [PlatformRow(3e38, -3e38, 3.4e38, 30.0)]
    assert messages == []


def test_report_goes_to_a_logger(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = write(tmp_path / "platform.csv", PLATFORM_HEADER, [f"{STAMP},1,2,3,4", "", f"{STAMP},x,2,3,4", "  ,  "])
    log = logging.getLogger("test_csvdata")
    with caplog.at_level(logging.WARNING, logger="test_csvdata"):
        rows = load_platform_rows(path, log)
    assert len(rows) == 1
    # Blank lines are no rows and no problem; the bad row's line number counts them.
    expected = f"{path}:4: velocity = 'x' is not a number; row skipped"
    assert [record.getMessage() for record in caplog.records] == [expected]


def test_many_malformed_rows_are_summarised(tmp_path: Path) -> None:
    path = write(tmp_path / "platform.csv", PLATFORM_HEADER,
                 [f"{STAMP},1,2,3,4"] + [f"{STAMP},x,2,3,4"] * 50)
    messages: list[str] = []
    assert len(load_platform_rows(path, messages.append)) == 1
    assert len(messages) == 21
    assert messages[0] == f"{path}:3: velocity = 'x' is not a number; row skipped"
    assert messages[-1] == f"{path}: 30 more malformed row(s) skipped without listing"


# --- unusable files --------------------------------------------------------------------------------------------------

def test_no_usable_row_is_an_error(tmp_path: Path) -> None:
    path = write(tmp_path / "vision.csv", VISION_HEADER, [vision_line([CAR], count=11), vision_line([CAR], count=99)])
    messages: list[str] = []
    with pytest.raises(DataFileError) as error:
        load_vision_rows(path, messages.append)
    assert str(error.value) == f"{path}: no usable data row (2 malformed row(s) skipped)"
    assert len(messages) == 2


def test_header_only_and_empty_files_are_errors(tmp_path: Path) -> None:
    header_only = write(tmp_path / "platform.csv", PLATFORM_HEADER, [])
    with pytest.raises(DataFileError, match="no usable data row$"):
        load_platform_rows(header_only)
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    with pytest.raises(DataFileError, match="the data file is empty"):
        load_vision_rows(empty)


def test_missing_file_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "nowhere" / "vision.csv"
    with pytest.raises(DataFileError) as error:
        load_vision_rows(path)
    assert str(error.value) == f"{path}: cannot read the data file: No such file or directory"
    # The application layer shows ConfigError as one line on stderr with a non-zero exit.
    assert isinstance(error.value, ConfigError)


def test_directory_and_binary_files_are_errors(tmp_path: Path) -> None:
    with pytest.raises(DataFileError, match="cannot read the data file"):
        load_platform_rows(tmp_path)
    binary = tmp_path / "platform.csv"
    binary.write_bytes(b"\xff\xfe\x00\x81" * 100)
    with pytest.raises(DataFileError, match="not a text"):
        load_platform_rows(binary)


def test_byte_order_mark_and_crlf_are_accepted(tmp_path: Path) -> None:
    path = tmp_path / "platform.csv"
    path.write_bytes(("\ufeff" + PLATFORM_HEADER + "\r\n" + f"{STAMP},1,2,3,4\r\n").encode())
    assert load_platform_rows(path) == [PlatformRow(1.0, 2.0, 3.0, 4.0)]


# --- wrap-around -----------------------------------------------------------------------------------------------------

def test_cycle_rows_wraps_to_the_first_row(tmp_path: Path) -> None:
    path = write(tmp_path / "platform.csv", PLATFORM_HEADER, [f"{STAMP},{i},0,{3.6 * i},10" for i in range(3)])
    rows = load_platform_rows(path)
    assert [row.velocity for row in islice(cycle_rows(rows), 8)] == [0, 1, 2, 0, 1, 2, 0, 1]
    with pytest.raises(ValueError):
        next(cycle_rows([]))


def test_cycle_rows_over_the_data_file() -> None:
    rows = load_vision_rows(DATA / "vision.csv")
    cycled = list(islice(cycle_rows(rows), len(rows) + 2))
    assert cycled[len(rows)] is rows[0] and cycled[len(rows) + 1] is rows[1]
