"""automotive bench system: the whole system's cost (issue 32's benchmark). Its arithmetic and report on made-up
records and figures; its options refused in one line; and two short runs for real, one with the shipped transport and
one with --transport udp, which print every application, the camera's and the LiDAR's lines and the last line, and
leave no namespace, folder or shared-memory file behind; and one with --dds-readers and the C reference. The figures
themselves are a benchmark's, not a test's: nothing here asserts a time or a CPU share.
"""

from __future__ import annotations

import argparse
import importlib
import json
import re
from pathlib import Path

import pytest
from shm_helpers import files_of
from test_bench_edges import NAMESPACES, bench, left_behind, left_in

from automotive.bench import system
from automotive.bench.ddsperf import OneWay
from automotive.bench.soak import LAUNCHER
from automotive.tools.support.children import APPS
from automotive.wire import shm

ROW = re.compile(r"^(\w+)\s+(\d+\.\d\d|-)(\s|$)")
LAST_LINE = re.compile(r"system_cpu_pct=(\d+\.\d\d)")


def window(t: float, samples: int = 30, latency: str = "0.100/0.200/0.900", gaps: int = 0,
           mismatches: int = 0) -> dict[str, object]:
    return {"t": t, "program": "camera_sub", "kind": "window", "samples": samples, "size": 4194304, "seconds": 1.0,
            "latency_ms": latency, "mb_per_s": 125.8, "mismatches": mismatches, "gaps": gaps}


def figures(seconds: float = 60.0, cpu: float = 1.0, p50: float = 0.3, p99: float = 1.5, rate_frames: int = 1800,
            lidar_p50: float = 0.2) -> system.Figures:
    camera = system.Camera(frames=rate_frames, seconds=60.0, mean_ms=0.3, max_ms=1.9, p50_ms=p50, p99_ms=p99,
                           total_frames=2250, total_seconds=75.0)
    lidar = system.Lidar(clouds=1200, seconds=60.0, p50_ms=lidar_p50, p99_ms=0.8)
    return system.Figures("auto", seconds, {name: cpu for name in APPS}, 0.5, camera, lidar)


# -- arithmetic ------------------------------------------------------------------------------------------------------

def test_the_transport_goes_to_the_four_applications_that_read_it_and_only_to_them() -> None:
    readers = {name for name in APPS
               if importlib.import_module(f"automotive.apps.{name}").PROPERTY_KEYS.covers("config.transport")}
    assert set(system.SHARED_FLOW_APPS) == readers
    assert set(system.TRANSPORTS) == set(shm.TRANSPORTS)
    args = system.launch_overrides("udp")
    assert args == [arg for app in system.SHARED_FLOW_APPS for arg in ("-D", f"{app}:config.transport=udp")]
    with_prefix = system.launch_overrides("auto", "mine_")
    assert with_prefix[:4] == ["-D", "lidar:config.transport=auto", "-D", "lidar:config.shmPrefix=mine_"]
    assert len(with_prefix) == 4 * len(system.SHARED_FLOW_APPS)


def test_camera_figures_over_the_measurement_and_percentiles_from_its_totals() -> None:
    records = [window(99.0, samples=5, latency="50.000/80.000/150.000", gaps=3),  # warm-up: outside
               window(101.0), window(102.0, samples=29, latency="0.100/0.300/1.900", gaps=1),
               window(104.0, samples=31, latency="0.100/0.100/0.400", mismatches=2),  # a second without frames before
               window(105.5),  # after the end: outside
               {"t": 106.0, "kind": "totals", "samples": 2250, "seconds": 75.2,
                "latency_ms": {"min": 0.1, "avg": 0.3, "p50": 0.25, "p99": 1.25, "max": 150.0}}]
    camera = system.Camera.of(records, 100.0, 105.0)
    assert (camera.frames, camera.gaps, camera.mismatches) == (90, 1, 2)
    assert camera.seconds == pytest.approx(4.0)  # from 100.0 (101.0 - its 1 s) to 104.0, the empty second included
    assert camera.rate == pytest.approx(22.5)
    assert camera.mean_ms == pytest.approx((30 * 0.2 + 29 * 0.3 + 31 * 0.1) / 90)
    assert camera.max_ms == pytest.approx(1.9)
    assert (camera.p50_ms, camera.p99_ms, camera.total_frames) == (0.25, 1.25, 2250)
    assert "22.5 frames/s, 90 frames, 1 gaps, 2 mismatches" in camera.line()
    assert "p50 0.250 / p99 1.250 ms over camera_sub's whole run (2,250 frames in 75 s" in camera.line()
    nothing = system.Camera.of([], 100.0, 105.0)
    assert (nothing.rate, nothing.mean_ms, nothing.p50_ms) == (0.0, None, None)
    assert "p50 - / p99 -" in nothing.line()
    assert system.window_latency_ms("-/-/-") is None and system.window_latency_ms("1/2/3") == (1.0, 2.0, 3.0)


def test_lidar_hops_are_those_received_during_the_measurement() -> None:
    records = [{"kind": "lidar", "src": 0, "at": at, "hop_ns": hop}
               for at, hop in ((5, 9_000_000), (10, 100_000), (11, 300_000), (12, 200_000), (20, 400_000),
                               (21, 8_000_000))]
    records.append({"kind": "take", "at": 12})
    lidar = system.Lidar.of(records, 10, 20)
    assert lidar.clouds == 4
    assert lidar.p50_ms == pytest.approx(0.3) and lidar.p99_ms == pytest.approx(0.4)
    assert system.Lidar.of([], 0, 2_000_000_000).line() == \
        "LiDAR to sensor fusion: 0.0 clouds/s, 0 clouds; hop p50 - / p99 - ms over the measurement"


def test_goals_met_not_met_and_too_short() -> None:
    assert [goal.met for goal in figures().goals(judge=True)] == [True, True, True]
    assert [goal.met for goal in figures().goals(judge=False)] == [None, None, None]
    # 8 applications at 1.6 %: 12.8 % of a core (the goal: 8); p99 too high; the LiDAR slower than the camera
    missed = figures(cpu=1.6, p99=2.5, lidar_p50=0.4)
    assert [goal.met for goal in missed.goals(judge=True)] == [False, False, False]
    assert not figures(rate_frames=1500).goals(judge=True)[1].met  # 25 frames/s is not 30
    # the LiDAR against the camera to the microsecond, as printed (the camera's histogram is exact to 0.1 %)
    assert figures(p50=0.3029, lidar_p50=0.3034).goals(judge=True)[2].met
    assert not figures(p50=0.3029, lidar_p50=0.3046).goals(judge=True)[2].met
    lost = figures()
    lost.camera.gaps = 1
    assert not lost.goals(judge=True)[1].met
    # an application that ended: the sum misses it, the goal is not met however low
    ended = figures()
    del ended.cpu_pct["hmi"]
    ended.ended["hmi"] = "ended at 0.2 min (NoSuchProcess)"
    cpu_goal = ended.goals(judge=True)[0]
    assert not cpu_goal.met and "hmi ended at 0.2 min" in cpu_goal.text
    assert ended.missing == ["hmi"]


def test_report_table_goals_and_last_line(capsys: pytest.CaptureFixture[str]) -> None:
    one = figures(cpu=0.75)
    assert system.report(one, as_json=False) == 0
    out = capsys.readouterr().out.splitlines()
    rows = {match.group(1): match.group(2) for line in out if (match := ROW.match(line))}
    assert {name: rows[name] for name in APPS} == {name: "0.75" for name in APPS}
    assert rows[LAUNCHER] == "0.50"
    assert any(line.startswith("whole system") and "6.00" in line for line in out)
    assert sum(1 for line in out if line.startswith("goal met: ")) == 3
    assert out[-8:] == ["camera_p50_ms=0.300", "camera_p99_ms=1.500", "c_one_way_p50_ms=-", "c_one_way_p99_ms=-",
                        "camera_vs_c_p50=-", "camera_vs_c_p99=-", "system_vs_c_cpu=-", "system_cpu_pct=6.00"]

    beside = figures(cpu=0.75)
    beside.reference = OneWay(p50_ms=0.6, p99_ms=3.0, max_ms=9.0, cpu_pct=4.0)
    beside.dds_readers = "camera_frames=10 lidar_clouds=1200"
    beside.written = {"lidar": "1,500 clouds through shared memory, 1,490 written on DDS"}
    assert system.report(beside, as_json=False) == 0
    out = capsys.readouterr().out.splitlines()
    assert "foreign DDS readers on the host: camera_frames=10 lidar_clouds=1200" in out
    assert "lidar: 1,500 clouds through shared memory, 1,490 written on DDS" in out
    assert any(line.startswith("goal met: the camera's p50 with foreign DDS readers") for line in out), out
    assert "reference: ddsperf's ping and pong used 4.00 % of one core; the whole system over it: 1.50" in out
    assert out[-6:-1] == ["c_one_way_p50_ms=0.600", "c_one_way_p99_ms=3.000", "camera_vs_c_p50=0.50",
                          "camera_vs_c_p99=0.50", "system_vs_c_cpu=1.50"]

    assert system.report(figures(seconds=8.0), as_json=True) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 2 and out[-1] == "system_cpu_pct=8.00"
    record = json.loads(out[0])
    assert record["system_cpu_pct"] == 8.0 and set(record["cpu_pct"]) == set(APPS)
    assert record["camera"]["latency_p50_ms"] == 0.3 and record["lidar"]["hop_p50_ms"] == 0.2
    assert record["goals"] == {"system_cpu": None, "camera_latency": None, "lidar_hop": None}
    assert record["c_one_way_ms"] is None and record["camera_vs_c"] == {"p50": None, "p99": None}
    assert record["c_cpu_pct"] is None and record["system_vs_c_cpu"] is None


# -- options ---------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize(("args", "message"), [
    (["--seconds", "0"], "--seconds 0 and --warmup 15: expected more than 0 and 0 or more"),
    (["--warmup", "-1"], "--seconds 60 and --warmup -1: expected more than 0 and 0 or more"),
    (["--seconds", "nan"], "expected more than 0"),
    (["--transport", "tcp"], "argument --transport: invalid choice: 'tcp'"),
    (["--shm-prefix", "a/b"], "argument --shm-prefix: --shm-prefix: config.shmPrefix = 'a/b' is not a valid"),
    (["--domain", "232"], "argument --domain: expected a domain id 0..231"),
    (["--bogus"], "unrecognized arguments: --bogus"),
], ids=lambda value: " ".join(value) if isinstance(value, list) else None)
def test_bad_options_are_one_line_and_exit_code_2(args: list[str], message: str,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as ended:
        system.main(args)
    assert ended.value.code == 2
    captured = capsys.readouterr()
    assert captured.out == "" and len(captured.err.splitlines()) == 1, captured.err
    assert captured.err.startswith(f"{system.PROG}: ") and message in captured.err, captured.err


def test_a_work_folder_with_a_run_in_it_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "camera_sub.jsonl").write_text("{}\n")
    with pytest.raises(SystemExit) as ended:
        system.main(["--work", str(tmp_path)])
    assert ended.value.code == 2
    assert f"--work {tmp_path}: expected a new or empty folder" in capsys.readouterr().err


# -- for real --------------------------------------------------------------------------------------------------------

def check_short_run(out: list[str]) -> dict[str, float]:
    """The lines every run prints; the applications' CPU figures."""
    rows = {match.group(1): match.group(2) for line in out if (match := ROW.match(line))}
    assert set(APPS) <= set(rows), out
    cpu = {name: float(rows[name]) for name in APPS}  # every application has a figure (none ended)
    assert any(line.startswith("warm-up over: measuring 8 s") for line in out), out
    assert any(line.startswith("camera: ") and " frames/s, " in line for line in out), out
    assert any(line.startswith("LiDAR to sensor fusion: ") for line in out), out
    assert "too short to judge: the goals are over 60 s (this run: 8 s)" in out
    match = LAST_LINE.fullmatch(out[-1])
    assert match, out[-1]
    assert float(match.group(1)) == pytest.approx(sum(cpu.values()), abs=0.05)
    return cpu


def check_transport_given(work: Path, transport: str, prefix: str) -> None:
    """The launcher gave the transport and the prefix to the four applications of the large flows, and only to them
    (its log names each application's command line)."""
    started = {match.group(1): match.group(2) for match in
               re.finditer(r"started (\w+) \(pid \d+\): (.*)", (work / "logs" / "launch.log").read_text())}
    assert set(started) == set(APPS), started
    for name, command in started.items():
        if name in system.SHARED_FLOW_APPS:
            assert f"-D config.transport={transport} -D config.shmPrefix={prefix}" in command, command
        else:
            assert "config.transport" not in command and "config.shmPrefix" not in command, command


@pytest.mark.skipif(NAMESPACES is not None, reason=f"the system benchmark: {NAMESPACES}")
def test_a_short_run_shows_every_application_and_the_last_line_and_leaves_nothing(
        tmp_path: Path, domain_id: int, prefix: str) -> None:
    tmpdir, work = tmp_path / "tmpdir", tmp_path / "work"
    tmpdir.mkdir()
    out = bench("system", "--warmup", "3", "--seconds", "8", "--domain", str(domain_id), "--shm-prefix", prefix,
                "--work", str(work), tmpdir=tmpdir).stdout.splitlines()
    check_short_run(out)
    goals = [line for line in out if line.startswith("goal ")]
    assert len(goals) == 3 and all(line.startswith("goal too short to judge: ") for line in goals), goals
    check_transport_given(work, "auto", prefix)
    assert (work / "camera_sub.jsonl").is_file() and (work / "sensor_fusion.jsonl").is_file()
    assert left_in(tmpdir) == []
    assert left_behind("bench-system-") == []
    assert not files_of(prefix)  # a clean stop leaves only iceoryx2's global file of the prefix


@pytest.mark.skipif(NAMESPACES is not None, reason=f"the system benchmark: {NAMESPACES}")
def test_a_short_run_with_dds_readers_has_them_served_on_dds_and_prints_the_reference(
        tmp_path: Path, domain_id: int, prefix: str) -> None:
    """--dds-readers: the foreign readers receive, the LiDAR writes on DDS for them beside shared memory; the C
    reference's lines come before the last line (ddsperf is a dependency of the benchmarks: Debian's
    cyclonedds-tools)."""
    tmpdir, work = tmp_path / "tmpdir", tmp_path / "work"
    tmpdir.mkdir()
    # 8 s of reference: ddsperf prints a figure a second once its pong is found, which took up to 3 s here
    out = bench("system", "--dds-readers", "--reference-seconds", "8", "--warmup", "3", "--seconds", "8", "--domain",
                str(domain_id), "--shm-prefix", prefix, "--work", str(work), tmpdir=tmpdir).stdout.splitlines()
    check_short_run(out)
    readers = next((line for line in out if line.startswith("foreign DDS readers on the host: ")), "")
    clouds = re.search(r"lidar_clouds=(\d+)", readers)
    assert clouds and int(clouds.group(1)) > 0, out
    lidar = next((line for line in out if line.startswith("lidar: ")), "")
    written = re.fullmatch(r"lidar: ([\d,]+) clouds through shared memory, ([\d,]+) written on DDS", lidar)
    assert written and int(written.group(2).replace(",", "")) > 0, out
    assert any(line.startswith("reference: ddsperf (C) one way at 4,196,372 bytes, 30 Hz") for line in out), out
    assert re.fullmatch(r"camera_vs_c_p99=\d+\.\d\d", out[-3]), out
    assert re.fullmatch(r"system_vs_c_cpu=\d+\.\d\d", out[-2]), out  # ddsperf's CPU, after its discovery
    assert left_in(tmpdir) == [] and left_behind("bench-system-") == []


@pytest.mark.skipif(NAMESPACES is not None, reason=f"the system benchmark: {NAMESPACES}")
def test_a_short_run_over_udp_gives_one_json_line_and_no_shared_memory(
        tmp_path: Path, domain_id: int, prefix: str) -> None:
    tmpdir, work = tmp_path / "tmpdir", tmp_path / "work"
    tmpdir.mkdir()
    out = bench("system", "--transport", "udp", "--json", "--warmup", "3", "--seconds", "8", "--domain",
                str(domain_id), "--shm-prefix", prefix, "--work", str(work), tmpdir=tmpdir).stdout.splitlines()
    record = json.loads(out[-2])
    assert record["transport"] == "udp" and set(record["cpu_pct"]) == set(APPS) and record["ended"] == {}
    assert out[-1] == f"system_cpu_pct={record['system_cpu_pct']:.2f}"
    assert not any(line.startswith(("camera: ", "goal ")) for line in out)  # the JSON line instead
    check_transport_given(work, "udp", prefix)
    assert not files_of(prefix, include_global=True)  # config.transport=udp: iceoryx2 never opened
    assert left_in(tmpdir) == [] and left_behind("bench-system-") == []


def test_help_needs_nothing_and_a_prefix_is_checked_as_the_applications_check_it() -> None:
    with pytest.raises(SystemExit) as ended:
        system.main(["--help"])
    assert ended.value.code == 0
    assert isinstance(system.shm_prefix("iox2_"), str)
    with pytest.raises(argparse.ArgumentTypeError):
        system.shm_prefix("")
