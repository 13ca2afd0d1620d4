"""The benchmarks' edges, each benchmark run for real with its shortest options: a run too short for a goal says
"too short to judge" and exits 0; no run leaves anything in the temporary folder (TMPDIR, a fresh folder of the test's
own), whether it ends, fails, or is stopped with SIGTERM or Ctrl-C; a folder the user names is the user's.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from apprunner import DEFAULT_SIGINT, signal_state

from automotive.bench import alert_latency, soak
from automotive.tools.support import netlab
from automotive.tools.support.children import Child, work_folder

RUN_TIMEOUT_S = 300.0  # a benchmark's whole short run, many Python processes on a busy 2-core machine
START_TIMEOUT_S = 120.0
NAMESPACES = netlab.unavailable()  # the soak and the discovery benchmark run the system in a namespace of their own


@pytest.fixture
def tmpdir_of_run(tmp_path: Path) -> Path:
    """The TMPDIR of the benchmark's processes: empty at the start, and it must be at the end."""
    folder = tmp_path / "tmpdir"
    folder.mkdir()
    return folder


def bench_env(tmpdir: Path) -> dict[str, str]:
    return {**os.environ, "TMPDIR": str(tmpdir)}


def bench(module: str, *args: str, tmpdir: Path) -> subprocess.CompletedProcess[str]:
    """Run ``python -m automotive.bench.<module> args`` to its end, with its own TMPDIR."""
    result = subprocess.run([sys.executable, "-m", f"automotive.bench.{module}", *args], env=bench_env(tmpdir),
                            capture_output=True, text=True, timeout=RUN_TIMEOUT_S)
    assert result.returncode == 0, f"exit {result.returncode}\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    return result


def left_in(tmpdir: Path) -> list[str]:
    return sorted(path.name for path in tmpdir.iterdir())


def namespaces() -> str:
    return subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout


def left_behind(prefix: str) -> list[str]:
    """The network namespaces named ``<prefix><pid>`` whose process has ended: left behind. Those of a benchmark
    still running (another test run's on this host) are not."""
    names = re.findall(rf"^({re.escape(prefix)}(\d+))\b", namespaces(), re.MULTILINE)
    return [name for name, pid in names if not Path(f"/proc/{pid}").exists()]


@pytest.fixture
def started() -> Iterator[list[Child]]:
    """Benchmarks started in the background; any still running at the end is stopped."""
    children: list[Child] = []
    try:
        yield children
    finally:
        for child in children:
            child.stop(timeout=60)


# -- the work folder helper -----------------------------------------------------------------------------------------

def test_a_folder_of_the_user_is_kept_and_a_temporary_one_removed_also_on_an_error(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmpdir"))
    (tmp_path / "tmpdir").mkdir()
    sigterm_before = signal.getsignal(signal.SIGTERM)
    mine = tmp_path / "mine" / "run"
    with work_folder("bench-x-", mine) as folder:
        assert folder == mine
        (folder / "records.jsonl").write_text("{}\n")
    assert (mine / "records.jsonl").read_text() == "{}\n"

    with pytest.raises(RuntimeError), work_folder("bench-x-") as folder:
        assert folder.parent == tmp_path / "tmpdir" and folder.name.startswith("bench-x-")
        (folder / "records.jsonl").write_text("{}\n")
        raise RuntimeError("the run failed")
    assert left_in(tmp_path / "tmpdir") == []
    assert signal.getsignal(signal.SIGTERM) == sigterm_before  # SIGTERM as it was, outside the blocks


def test_sigterm_inside_a_work_folder_unwinds_and_removes_it(tmpdir_of_run: Path, started: list[Child]) -> None:
    program = ("import sys, time\nfrom automotive.tools.support.children import work_folder\n"
               "try:\n    with work_folder('bench-x-') as folder:\n        (folder / 'a').write_text('a')\n"
               "        print(folder, flush=True)\n        time.sleep(120)\n"
               "finally:\n    print('unwound', flush=True)\n")
    child = Child("work_folder", [sys.executable, "-c", program], env=bench_env(tmpdir_of_run))
    started.append(child)
    folder = Path(child.wait_for(r"bench-x-", timeout=START_TIMEOUT_S))
    assert folder.parent == tmpdir_of_run
    child.send_signal(signal.SIGTERM)
    assert child.wait_exit(timeout=30) == 128 + signal.SIGTERM
    assert child.lines[-1] == "unwound"
    assert left_in(tmpdir_of_run) == []


# -- the soak -----------------------------------------------------------------------------------------------------

@pytest.mark.skipif(NAMESPACES is not None, reason=f"the soak benchmark: {NAMESPACES}")
def test_a_soak_too_short_says_so_exits_0_and_leaves_no_folder(tmpdir_of_run: Path, tmp_path: Path,
                                                               domain_id: int) -> None:
    out = bench("soak", "--minutes", "0.05", "--warmup", "0", "--interval", "1", "--domain", str(domain_id),
                "--chart", str(tmp_path / "soak.png"), tmpdir=tmpdir_of_run).stdout.splitlines()
    assert "too short to judge: the goal needs at least 20 minutes (this run: 0.05)" in out
    assert not any(line.startswith("goal") for line in out)  # no verdict either way
    assert re.fullmatch(r"rss_slope_kB_per_h_max=\S+ app=\S+ verdict=too-short", out[-1]), out[-1]
    assert any(line.startswith("vision ") for line in out)  # the figures are printed all the same
    assert left_in(tmpdir_of_run) == []


@pytest.mark.skipif(NAMESPACES is not None, reason=f"the soak benchmark: {NAMESPACES}")
def test_a_soak_stopped_with_sigterm_removes_its_folder_and_namespace(tmpdir_of_run: Path, tmp_path: Path,
                                                                      domain_id: int, started: list[Child]) -> None:
    command = [sys.executable, "-m", "automotive.bench.soak", "--minutes", "5", "--warmup", "0", "--interval", "1",
               "--domain", str(domain_id), "--chart", str(tmp_path / "soak.png")]
    child = Child("soak", command, env=bench_env(tmpdir_of_run))
    started.append(child)
    child.wait_for(r"^sampling ", timeout=START_TIMEOUT_S)
    assert left_in(tmpdir_of_run) != []  # the work folder is there while it runs
    child.send_signal(signal.SIGTERM)
    assert child.wait_exit(timeout=120) == 128 + signal.SIGTERM
    assert left_in(tmpdir_of_run) == []
    assert f"bench-soak-{child.pid}" not in namespaces()
    assert not (tmp_path / "soak.png").exists()  # stopped: no report


@pytest.mark.skipif(NAMESPACES is not None, reason=f"the soak benchmark: {NAMESPACES}")
def test_a_soak_work_folder_named_by_the_user_is_kept_for_a_report(tmpdir_of_run: Path, tmp_path: Path,
                                                                   domain_id: int,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    work, samples = tmp_path / "work", tmp_path / "samples.jsonl"
    bench("soak", "--minutes", "0.1", "--warmup", "0", "--interval", "1", "--domain", str(domain_id),
          "--chart", str(tmp_path / "soak.png"), "--work", str(work), "--samples", str(samples), tmpdir=tmpdir_of_run)
    assert left_in(tmpdir_of_run) == []
    assert (work / "camera_sub.jsonl").is_file() and (work / "logs" / "launch.log").is_file()
    assert soak.main(["--report", str(samples), "--work", str(work), "--warmup", "0",
                      "--chart", str(tmp_path / "again.png")]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "too short to judge: the goal needs at least 20 minutes (this run: 0.1)" in out
    assert out[-1].endswith(" verdict=too-short")
    # a folder holding a run already: its records would add up with the next run's
    with pytest.raises(SystemExit) as ended:
        soak.main(["--work", str(work)])
    assert ended.value.code == 2
    assert f"--work {work}: expected a new or empty folder" in capsys.readouterr().err


# -- every other benchmark that keeps files while it runs -------------------------------------------------------------

@pytest.mark.skipif(NAMESPACES is not None, reason=f"the discovery benchmark: {NAMESPACES}")
def test_discovery_leaves_no_folder(tmpdir_of_run: Path, domain_id: int) -> None:
    out = bench("discovery", "--age", "0", "--window", "0.2", "--joins", "1", "--timeout", "10",
                "--domain", str(domain_id), tmpdir=tmpdir_of_run).stdout
    assert out.splitlines()[-1].startswith("late_join_p99_s=")
    assert left_in(tmpdir_of_run) == []


@pytest.mark.skipif(NAMESPACES is not None, reason=f"the discovery benchmark: {NAMESPACES}")
def test_discovery_stopped_with_ctrl_c_removes_its_folder_and_namespace(tmpdir_of_run: Path, domain_id: int,
                                                                        started: list[Child]) -> None:
    command = [*DEFAULT_SIGINT, sys.executable, "-m", "automotive.bench.discovery", "--age", "120", "--domain",
               str(domain_id)]
    child = Child("discovery", command, env=bench_env(tmpdir_of_run))
    started.append(child)
    child.wait_for(r"application\(s\) running", timeout=START_TIMEOUT_S)
    state = signal_state(child.pid)
    child.send_signal(signal.SIGINT)  # to the benchmark alone: it stops what it started
    try:
        assert child.wait_exit(timeout=120) != 0
    except subprocess.TimeoutExpired:
        raise AssertionError(f"the benchmark did not end on SIGINT (its signals when sent: {state})") from None
    assert left_in(tmpdir_of_run) == []
    assert f"bench-discovery-{child.pid}" not in namespaces()


def test_zenoh_leaves_no_folder(tmpdir_of_run: Path, domain_id: int) -> None:
    domain = min(domain_id, 231)  # it takes two
    out = bench("zenoh_bridge", "--scenarios", "direct", "--seconds", "0.5", "--domain", str(domain),
                tmpdir=tmpdir_of_run).stdout
    assert out.splitlines()[-1].startswith("zenoh_ratio_4MiB=")
    assert "logs and every process's JSON lines" not in out  # nothing kept to point at
    assert left_in(tmpdir_of_run) == []


def test_record_leaves_no_folder_and_gives_no_ratio_without_compression(tmpdir_of_run: Path, domain_id: int) -> None:
    out = bench("record", "--seconds", "0.5", "--domain", str(domain_id), tmpdir=tmpdir_of_run).stdout.splitlines()
    summary = next(line for line in out if line.startswith("recorder CPU"))
    assert summary.endswith(", uncompressed") and "ratio" not in summary
    assert out[-1].startswith("record_lost=")
    assert left_in(tmpdir_of_run) == []


@pytest.mark.skipif(shutil.which("ddsperf") is None, reason="no ddsperf (Debian's cyclonedds-tools)")
def test_large_data_leaves_no_folder(tmpdir_of_run: Path, tmp_path: Path, domain_id: int) -> None:
    out = bench("large_data", "--sizes", "64KiB", "--duration", "0.3", "--latency-seconds", "0.3",
                "--domain", str(domain_id), "--chart", str(tmp_path / "large.png"), tmpdir=tmpdir_of_run).stdout
    assert out.splitlines()[-1].startswith("shm_p99_ms_30fps=")
    assert left_in(tmpdir_of_run) == []


def test_alert_latency_too_short_says_so_and_leaves_no_folder(tmpdir_of_run: Path, domain_id: int) -> None:
    out = bench("alert_latency", "--sensors", "1", "--objects", "2", "--window", "1", "--c-seconds", "0",
                "--domain", str(domain_id), tmpdir=tmpdir_of_run).stdout.splitlines()
    assert any(line.startswith("  too short to judge: the goals need at least 100 alerts (this run: ")
               for line in out), "\n".join(out)
    assert not any(line.startswith("  goal") for line in out)
    assert out[-1].startswith("alert_p99_ms=")
    assert left_in(tmpdir_of_run) == []


def spinners_of(tmpdir: Path) -> list[int]:
    """The --busy spinners started by a benchmark run with this TMPDIR (their environment says so)."""
    found = []
    for entry in Path("/proc").iterdir():
        try:
            if (entry.name.isdigit() and alert_latency.SPINNER in (entry / "cmdline").read_text()
                    and f"TMPDIR={tmpdir}\0" in (entry / "environ").read_text()):
                found.append(int(entry.name))
        except OSError:
            continue  # ended meanwhile, or not ours to read
    return found


def test_alert_latency_busy_spins_for_the_whole_run_and_stops_the_spinner(tmpdir_of_run: Path, domain_id: int,
                                                                         started: list[Child]) -> None:
    child = Child("alert_latency", [sys.executable, "-m", "automotive.bench.alert_latency", "--busy", "--sensors",
                                    "1", "--objects", "2", "--window", "1", "--c-seconds", "1", "--domain",
                                    str(domain_id)], env=bench_env(tmpdir_of_run))
    started.append(child)
    deadline = time.monotonic() + START_TIMEOUT_S
    while not spinners_of(tmpdir_of_run):  # started before the applications
        assert child.poll() is None and time.monotonic() < deadline, child.output
        time.sleep(0.1)  # polling /proc: nothing to wait on
    child.wait_for("measuring", timeout=START_TIMEOUT_S)
    assert len(spinners_of(tmpdir_of_run)) == 1  # still spinning while the chain runs
    assert child.wait_exit(timeout=RUN_TIMEOUT_S) == 0, child.output
    out = child.lines
    assert any(line.startswith("sensor-to-alert") and "one core kept busy (--busy)" in line for line in out), out
    assert out[-1].startswith("alert_p99_ms=")
    assert spinners_of(tmpdir_of_run) == []
    assert left_in(tmpdir_of_run) == []


def test_scale_leaves_no_folder(tmpdir_of_run: Path, domain_id: int) -> None:
    out = bench("scale", "--sizes", "1", "--window", "0.3", "--domain", str(domain_id), tmpdir=tmpdir_of_run).stdout
    assert out.splitlines()[-1].startswith("scale_discovery_ms_max=")
    assert left_in(tmpdir_of_run) == []


def test_failover_too_short_says_so_and_leaves_no_folder(tmpdir_of_run: Path, domain_id: int) -> None:
    out = bench("failover", "--failovers", "1", "--domain", str(domain_id), tmpdir=tmpdir_of_run).stdout.splitlines()
    assert "  too short to judge: the goal needs at least 20 failovers (this run: 1)" in out
    assert not any(line.startswith("  goal") for line in out)
    assert out[-1].startswith("failover_p99_ms=")
    assert left_in(tmpdir_of_run) == []


def test_console_counts_the_launchers_lines_and_a_short_run_is_not_judged(tmpdir_of_run: Path,
                                                                             domain_id: int) -> None:
    result = bench("console", "--seconds", "8", "--steady", "4", "--domain", str(domain_id), "--", "vision",
                   "sensor_fusion", tmpdir=tmpdir_of_run)
    lines = result.stdout.splitlines()
    # both applications' status lines are counted (at least one each in 8 s), and no sample line
    assert re.search(r"^vision +[1-9]\d* ", result.stdout, re.MULTILINE), result.stdout
    assert re.search(r"^sensor_fusion +[1-9]\d* ", result.stdout, re.MULTILINE), result.stdout
    assert "too short to judge: the goal is over 60 s (this run: 8 s)" in lines, result.stdout
    assert re.fullmatch(r"console_lines_per_s=\d+\.\d\d", lines[-1]), lines[-1]
    assert left_in(tmpdir_of_run) == []


def test_monitor_measures_its_cpu_and_a_short_run_is_not_judged(tmpdir_of_run: Path, domain_id: int) -> None:
    # Two applications are enough to see the phases and the last line; the goal's run is the whole system's.
    result = bench("monitor", "--seconds", "3", "--warmup", "1", "--domain", str(domain_id), "--", "vision",
                   "sensor_fusion", tmpdir=tmpdir_of_run)
    lines = result.stdout.splitlines()
    phases = [json.loads(line) for line in lines if line.startswith("{")]
    assert [phase["phase"] for phase in phases] == ["warm-up", "measure"], result.stdout
    assert phases[1]["views"] >= 2 and phases[1]["view_failures"] == 0, result.stdout
    assert "too short to judge: the goal is over 60 s (this run: 3 s)" in lines, result.stdout
    assert re.fullmatch(r"monitor_cpu_pct=\d+\.\d\d", lines[-1]), lines[-1]
    assert left_in(tmpdir_of_run) == []


def test_monitor_page_times_the_page_of_the_system_and_of_a_crowd(tmpdir_of_run: Path, domain_id: int,
                                                                   other_domain_id: int) -> None:
    result = bench("monitor_page", "--tries", "1", "--crowd", "3", "--domain", str(domain_id),
                   "--crowd-domain", str(other_domain_id), tmpdir=tmpdir_of_run)
    lines = result.stdout.splitlines()
    phases = [json.loads(line) for line in lines if line.startswith("{")]
    assert [phase["phase"] for phase in phases] == ["system", "crowd"], result.stdout
    assert all(0 < phase["median_s"] < float("inf") and phase["tries"] == 1 for phase in phases), result.stdout
    assert [phase["goal_s"] for phase in phases] == [10.0, 2.0], result.stdout
    assert re.fullmatch(r"monitor_page_s=\d+\.\d\d", lines[-1]), lines[-1]
    assert float(lines[-1].split("=")[1]) == pytest.approx(phases[0]["median_s"], abs=0.01)
    assert left_in(tmpdir_of_run) == []


@pytest.mark.parametrize("args", [["--tries", "0"], ["--crowd", "-1"], ["--domain", "5", "--crowd-domain", "5"],
                                  ["--log-dir", "/proc/no-such/dir"]])
def test_monitor_page_refuses_bad_arguments_in_one_line_before_starting(args: list[str], tmpdir_of_run: Path) -> None:
    result = subprocess.run([sys.executable, "-m", "automotive.bench.monitor_page", *args],
                            env=bench_env(tmpdir_of_run), capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and result.stdout == "", result.stdout + result.stderr
    assert result.stderr.strip().splitlines()[-1].startswith("automotive bench monitor-page: "), result.stderr
    assert left_in(tmpdir_of_run) == []


@pytest.mark.parametrize("args", [["--seconds", "0"], ["--warmup", "-1"], ["--log-dir", "/proc/no-such/dir"]])
def test_monitor_refuses_bad_arguments_in_one_line_before_starting(args: list[str], tmpdir_of_run: Path) -> None:
    result = subprocess.run([sys.executable, "-m", "automotive.bench.monitor", *args], env=bench_env(tmpdir_of_run),
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and result.stdout == "", result.stdout + result.stderr
    assert result.stderr.strip().splitlines()[-1].startswith("automotive bench monitor: "), result.stderr
    assert left_in(tmpdir_of_run) == []
