"""automotive bench soak's arithmetic and report on made-up samples (the benchmark itself runs the whole system for
half an hour: not a test)."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import psutil
import pytest

from automotive.bench import soak
from automotive.bus.network import RECEIVE_BUFFER_SIZE


def series(name: str, rss_kB: list[int], interval_s: float = 10.0) -> soak.Series:
    one = soak.Series(name, psutil.Process(os.getpid()))
    one.times_s = [index * interval_s for index in range(len(rss_kB))]
    one.rss_kB = rss_kB
    one.cpu_s = [index * 0.5 for index in range(len(rss_kB))]  # half a second of CPU every 10 s: 5 %
    return one


def write_records(path: Path, *records: dict[str, object]) -> None:
    path.write_text("".join(json.dumps({"t": 0, "program": path.stem, **record}) + "\n" for record in records))


def test_slope_after_the_warm_up_in_kB_per_hour() -> None:
    # 60 s of warm-up climbing fast, then +1 kB every 10 s: 360 kB/h
    one = series("vision", [1000, 1100, 1200, 1300, 1400, 1500] + [2000 + n for n in range(30)])
    slope = one.slope_kB_per_h(60.0)
    assert slope == pytest.approx(360.0)
    assert one.cpu_percent() == pytest.approx(5.0)
    assert series("hmi", [1000, 1000]).slope_kB_per_h(0.0) is None  # too few samples for a line


def test_held_peak_counts_a_level_that_stays_not_a_burst_the_next_trim_returns() -> None:
    # a 4 MB burst for 60 s (six samples: one trim interval) at minute 2, a 300 kB step for good at minute 4
    rss = [5000] * 12 + [9000] * 6 + [5000] * 6 + [5300] * 12
    one = series("camera_pub", rss)
    assert one.held_peak(0.0, 230.0) == 5000  # the burst is not held for 90 s
    assert one.held_peak(240.0, 350.0) == 5300  # the step is
    assert one.held_peak(300.0, 350.0) is None  # no 90-s span fits in 50 s
    assert series("vision", [5000] * 12 + [9000] * 10).held_peak(0.0, 210.0) == 9000  # 100 s above is held
    # samples come a little late, each by its own amount: the same levels
    late = series("camera_pub", rss)
    late.times_s = [t + (0.02 if index % 2 else 0.05) for index, t in enumerate(late.times_s)]
    assert late.held_peak(0.0, 230.0) == 5000 and late.held_peak(240.0, 350.0) == 5300


def test_camera_and_hmi_figures_from_their_status_records(tmp_path: Path) -> None:
    camera, hmi = tmp_path / "camera_sub.jsonl", tmp_path / "hmi.jsonl"
    write_records(camera, {"kind": "window", "samples": 30, "gaps": 0, "mismatches": 0},
                  {"kind": "window", "samples": 29, "gaps": 1, "mismatches": 2})
    write_records(hmi, {"kind": "shown", "state": "alert", "texts": ["x"]},
                  {"kind": "shown", "state": "clear", "texts": []},
                  {"kind": "source", "alive": False}, {"kind": "source", "alive": True},
                  {"kind": "matched", "count": 1})
    seen = soak.Seen.read(camera, hmi)
    assert (seen.frames, seen.gaps, seen.mismatches) == (59, 1, 2)
    assert (seen.alerts, seen.clears, seen.source_lost) == (1, 1, 1)
    # once camera_sub has written its totals (at the end), they count instead of the windows' sum
    with camera.open("a") as out:
        out.write(json.dumps({"kind": "totals", "samples": 60, "gaps": 1, "mismatches": 2}) + "\n")
    assert soak.Seen.read(camera, hmi).frames == 60
    assert soak.Seen.read(tmp_path / "none.jsonl", tmp_path / "none.jsonl") == soak.Seen()


def test_report_table_chart_and_last_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # 21 minutes with a 1-minute warm-up: the shortest run the goal judges (minutes 1-11 and 11-21)
    args = argparse.Namespace(minutes=21.0, warmup=1.0, chart=tmp_path / "soak.png")
    flat = [5000] * 127
    climbing = [5000 + 10 * n for n in range(127)]  # +10 kB every 10 s: 3,600 kB/h
    everyone = [series("vision", flat), series("camera_sub", climbing), series(soak.LAUNCHER, climbing)]
    assert soak.report(everyone, soak.Seen(frames=100), args) == 0
    out = capsys.readouterr().out.splitlines()
    # the launcher is outside the goal
    assert out[-1] == "rss_slope_kB_per_h_max=3600 app=camera_sub verdict=not-met"
    assert out[-2].startswith("goal NOT met: camera_sub: slope 3,600 kB/h > 200; camera_sub: held in the last 10 min")
    assert args.chart.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    assert soak.report([series("vision", flat)], soak.Seen(frames=100), args) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[-2:] == ["goal met", "rss_slope_kB_per_h_max=0 app=vision verdict=met"]


def test_a_run_too_short_gives_its_figures_and_no_verdict_but_what_no_length_undoes(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # 6 minutes: the slope is there, and far above the goal, but says nothing of hours
    args = argparse.Namespace(minutes=6.0, warmup=1.0, chart=tmp_path / "soak.png")
    climbing = [5000 + 10 * n for n in range(37)]
    assert soak.report([series("camera_sub", climbing)], soak.Seen(), args) == 0  # no frame yet: too short too
    out = capsys.readouterr().out.splitlines()
    assert out[-2:] == ["too short to judge: the goal needs at least 21 minutes (this run: 6)",
                        "rss_slope_kB_per_h_max=3600 app=camera_sub verdict=too-short"]
    assert not any(line.startswith("goal") for line in out)
    row = next(line for line in out if line.startswith("camera_sub"))
    assert row.split()[4] == "3,600" and row.split()[5:7] == ["-", "-"]  # the slope; no window covered whole

    # an application that ended, a frame lost: no longer run makes up for them (the slope is still not judged)
    ended = series("vision", [5000] * 9)
    ended.ended = "ended at 1.5 min (NoSuchProcess)"
    assert soak.report([ended, series("camera_sub", climbing)], soak.Seen(frames=100, gaps=1), args) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[-3:] == ["too short to judge: the goal needs at least 21 minutes (this run: 6)",
                        "goal NOT met: vision ended at 1.5 min (NoSuchProcess); camera: 1 gaps, 0 mismatches",
                        "rss_slope_kB_per_h_max=3600 app=camera_sub verdict=not-met"]


    # 26 minutes, flat but for a burst returned within a minute in the last 10 minutes, and a step held there
    args = argparse.Namespace(minutes=26.0, warmup=5.0, chart=tmp_path / "soak.png")
    burst = [5000] * 157
    burst[140:146] = [9000] * 6
    step = [5000] * 130 + [5300] * 27
    assert soak.report([series("camera_pub", burst), series("hmi", step)], soak.Seen(frames=100), args) == 0
    out = capsys.readouterr().out.splitlines()
    goal = next(line for line in out if line.startswith("goal"))
    assert "hmi: held in the last 10 min 5,300 kB > 5,000 kB + 256 kB" in goal
    assert "camera_pub: held" not in goal  # (the burst does count in its fitted slope)
    assert out[-1].endswith(" verdict=not-met")


def test_the_peak_tolerance_is_one_receive_buffer() -> None:
    assert f"{soak.PEAK_TOLERANCE_KB}KiB" == RECEIVE_BUFFER_SIZE


def test_report_again_from_a_samples_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    samples, work = tmp_path / "samples.jsonl", tmp_path / "work"
    work.mkdir()
    write_records(work / "camera_sub.jsonl", {"kind": "totals", "samples": 600, "gaps": 0, "mismatches": 0})
    write_records(work / "hmi.jsonl", {"kind": "shown", "state": "alert", "texts": ["x"]})
    samples.write_text("".join(json.dumps({"t_s": 10.0 * n + 0.03, "app": app, "rss_kB": 5000 + (n % 3),
                                           "cpu_s": n * 0.1}) + "\n"
                               for n in range(157) for app in ("vision", "camera_sub")))
    assert soak.main(["--report", str(samples), "--work", str(work), "--chart", str(tmp_path / "again.png")]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "camera: 600 frames, 0 gaps, 0 mismatches; HMI: 1 alerts shown" in "\n".join(out)
    assert out[-2] == "goal met" and out[-1].startswith("rss_slope_kB_per_h_max=") and out[-1].endswith(" verdict=met")
    assert (tmp_path / "again.png").read_bytes()[:4] == b"\x89PNG"
    samples.write_text('{"t_s": 0, "app": "vision"}\n')
    with pytest.raises(SystemExit) as ended:
        soak.main(["--report", str(samples), "--work", str(work)])
    assert ended.value.code == 2
    assert f"--report {samples}, line 1: expected a JSON object" in capsys.readouterr().err


def test_bad_arguments_are_one_line_and_exit_code_2(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as ended:
        soak.main(["--minutes", "5", "--warmup", "5"])
    assert ended.value.code == 2
    assert "--warmup from 0 to below --minutes" in capsys.readouterr().err
