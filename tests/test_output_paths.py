"""Files and folders the programs write are checked before anything starts: a missing or read-only folder of a
recording (record --output), a plot (camera_sub --plot), an application's --stats file or a benchmark's output is one
line on stderr naming the option and the path, exit code 2, no traceback, before any participant exists. Read-only
folders are tmpfs mounts made read-only in a mount namespace of the test's own (the tests run as root, who writes
through permission bits). Also the helpers of automotive.bus.cli themselves, and a --stats file that fails later.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from automotive.bus.cli import output_file_problem, output_folder_problem
from automotive.bus.stats import Stats
from automotive.tools.support.children import program_command

ROOT = Path(__file__).resolve().parent.parent
TIMEOUT = 60.0
# Mount a read-only tmpfs on $1 in a mount namespace of the command's own, then run the rest of the command line.
READ_ONLY = 'mount -t tmpfs -o ro,size=64k tmpfs "$1" && shift && exec "$@"'
UNKNOWN = "--no-such-option"  # after a path checked as it is parsed: a check that let the path pass ends here


@dataclass(frozen=True)
class Case:
    """A program's output option; ``guard``: arguments that end the program at once (exit 2, another message) if the
    check under test let the path pass, so that a broken check never starts a run."""

    command: tuple[str, ...]
    option: str
    name: str  # the file or folder given to the option, inside the folder under test
    guard: tuple[str, ...] = (UNKNOWN,)

    def args(self, path: Path) -> list[str]:
        return [*self.command, self.option, str(path), *self.guard]

    def __str__(self) -> str:
        return f"{self.command[-1]} {self.option}"


def bench(name: str) -> tuple[str, ...]:
    return (sys.executable, "-m", f"automotive.bench.{name}")


FILES = [
    Case(tuple(program_command("record", "--domain", "231")), "--output", "drive.mcap"),
    Case(tuple(program_command("camera_sub", "--domain", "231")), "--plot", "latency.png"),
    Case(tuple(program_command("vision", "--domain", "231")), "--stats", "vision.jsonl", ("--count", "1")),
    Case(tuple(program_command("lidar_view", "--domain", "231")), "--snapshot", "cloud.png"),
    Case(bench("soak"), "--chart", "soak.png"),
    Case(bench("soak"), "--samples", "samples.jsonl"),
    Case(bench("alert_latency"), "--png", "latency.png"),
    Case(bench("large_data"), "--chart", "large.png"),
    Case(bench("record"), "--keep", "kept.mcap"),
]
# Folders the programs create with their parents when missing: refused when they cannot be created.
FOLDERS = [
    Case(bench("alert_latency"), "--log-dir", "logs", ("--sensors", "x")),
    Case(bench("failover"), "--log-dir", "logs", ("--failovers", "0")),
    Case(bench("scale"), "--log-dir", "logs", ("--sizes", "x")),
    Case(bench("zenoh_bridge"), "--log-dir", "logs", ("--seconds", "0")),
    Case(bench("soak"), "--memtrace", "memtrace"),
    Case(tuple(program_command("launch", "--mode", "background")), "--log-dir", "logs",
         ("no_such_app",)),
]


def run(command: list[str], read_only: Path | None = None) -> subprocess.CompletedProcess[str]:
    if read_only is not None:
        read_only.mkdir(exist_ok=True)
        command = ["unshare", "--mount", "--propagation", "private", "sh", "-c", READ_ONLY, "read-only",
                   str(read_only), *command]
    return subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT)


def refused(result: subprocess.CompletedProcess[str], case: Case, path: Path, problem: str) -> None:
    """Exit code 2, one line naming the option, the path and the problem; nothing started."""
    assert result.returncode == 2, result.stdout + result.stderr
    assert "Traceback" not in result.stdout + result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert case.option in lines[0] and f"{path}: {problem}" in lines[0], lines[0]
    assert "network:" not in result.stdout, result.stdout  # an application logs it just before its participant


@pytest.mark.parametrize("case", FILES, ids=str)
def test_a_file_in_a_missing_folder_is_refused(case: Case, tmp_path: Path) -> None:
    path = tmp_path / "missing" / case.name
    refused(run(case.args(path)), case, path, f"folder {tmp_path / 'missing'} does not exist")


@pytest.mark.parametrize("case", FILES, ids=str)
def test_a_file_in_a_read_only_folder_is_refused(case: Case, tmp_path: Path) -> None:
    folder = tmp_path / "read-only"
    path = folder / case.name
    refused(run(case.args(path), read_only=folder), case, path,
            f"cannot create files in folder {folder} (Read-only file system)")


@pytest.mark.parametrize("case", FOLDERS, ids=str)
def test_a_folder_under_a_file_is_refused(case: Case, tmp_path: Path) -> None:
    (tmp_path / "file").write_text("")
    path = tmp_path / "file" / case.name
    refused(run(case.args(path)), case, path, f"{tmp_path / 'file'} is not a folder")


@pytest.mark.parametrize("case", FOLDERS, ids=str)
def test_a_folder_in_a_read_only_folder_is_refused(case: Case, tmp_path: Path) -> None:
    folder = tmp_path / "read-only"
    refused(run(case.args(folder / case.name), read_only=folder), case, folder / case.name,
            f"cannot create it in folder {folder} (Read-only file system)")
    refused(run(case.args(folder), read_only=folder), case, folder, "cannot create files in it (Read-only file system)")


@pytest.mark.parametrize("name, problem", [
    ("latency.xyz", "matplotlib writes no '.xyz' files (it writes "),
    ("", "is a folder, not a file"),
])
def test_a_plot_that_cannot_be_written_is_refused(name: str, problem: str, tmp_path: Path) -> None:
    case = FILES[1]
    path = tmp_path / name if name else tmp_path
    refused(run(case.args(path)), case, path, problem)


def test_the_checks_of_a_file(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("kept")
    assert output_file_problem(tmp_path / "new.mcap") is None
    assert output_file_problem(tmp_path / "file") is None  # replaced or appended to: the program says which
    assert output_file_problem(Path("/dev/null")) is None
    assert output_file_problem(Path("relative-in-the-working-folder.png")) is None
    assert output_file_problem(tmp_path) == "is a folder, not a file"
    assert output_file_problem(tmp_path / "no" / "x") == f"folder {tmp_path / 'no'} does not exist"
    assert output_file_problem(tmp_path / "file" / "x") == f"{tmp_path / 'file'} is not a folder"
    assert sorted(path.name for path in tmp_path.iterdir()) == ["file"]  # the checks leave nothing behind
    assert (tmp_path / "file").read_text() == "kept"


def test_the_checks_of_a_folder(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("")
    assert output_folder_problem(tmp_path) is None
    assert output_folder_problem(tmp_path / "new") == "no such folder"
    assert output_folder_problem(tmp_path / "new" / "deeper", create=True) is None
    assert output_folder_problem(tmp_path / "file") == "is not a folder"
    assert output_folder_problem(tmp_path / "file" / "sub", create=True) == f"{tmp_path / 'file'} is not a folder"
    assert sorted(path.name for path in tmp_path.iterdir()) == ["file"]  # nothing created by a check


def test_a_stats_file_that_fails_later_is_one_line_and_the_program_goes_on(capsys: pytest.CaptureFixture[str]) -> None:
    """/dev/full takes the file open and refuses every write (ENOSPC), as a full disk does."""
    stats = Stats(Path("/dev/full"), "probe")
    stats.record("status", count=1)
    stats.record("status", count=2)  # no more writes, no more lines
    stats.close()
    assert capsys.readouterr().err == "probe: --stats /dev/full: No space left on device; no more status records\n"
    assert not stats.enabled
