"""Soak: the whole system for a long time, each application's resident memory and CPU sampled, the trend fitted.

    automotive bench soak                              30 minutes
    automotive bench soak --minutes 120 --chart soak-2h.png
    automotive bench soak --minutes 10 --warmup 2      a short look (figures only: too short for the goal)
    automotive bench soak --memtrace DIR               also the applications' memory probe (automotive.bus.memtrace)
    automotive bench soak --samples FILE --work DIR    keep what a report needs: every sample and the work folder
    automotive bench soak --report FILE --work DIR     the table, chart and goal again, from a run's --samples FILE
                                                       and its work folder (the camera's and the HMI's records)

Starts the system as `automotive launch` does (every application, camera included, shipped properties; background
mode, hmi on the console) in a network namespace that this run creates and deletes, so its traffic is private
(needs root). From when the camera subscriber and the HMI have opened their records (an application may still be
starting when the launcher says "running"), every --interval seconds (10) psutil samples each application's RSS and
CPU time; a progress line comes every minute. The camera subscriber and the HMI write their status records
(--stats, through the launcher's --stats-dir): frames, gaps and mismatches; the alerts shown to the driver and the
alert source lost. They and the launcher's logs go to a temporary work folder, removed at the end (also on an
error, Ctrl-C or SIGTERM), or to --work DIR, a new or empty folder that is kept.

At the end, per application: RSS (kB) at the end of the warm-up (--warmup, 5 min), at the end and its peak; the
slope of a least-squares line through the samples after the warm-up, in kB per hour; the highest RSS held for 90 s
(every sample of 90 seconds at or above it) in the 10 minutes after the warm-up and in the last 10 minutes; CPU in %
of one core. Held, not the single highest sample: what a process keeps, not a frame or a burst in flight at the
moment of a sample, which the applications give back within their trim interval (config.mallocTrim, 60 s); a step
that stays is held. The launcher is shown too (it reads every line the applications print), outside the goal. A
PNG (--chart) shows the curves and the fitted lines.

Goal: every application's slope at most 200 kB/h, its highest RSS held in the last 10 minutes no higher
than in the 10 minutes after the warm-up (by more than a receive buffer, 256 KiB, whose fill moves RSS up and down),
0 camera gaps and mismatches. It needs a run of the warm-up and 20 minutes (both windows whole, one after the other):
a shorter one prints its figures and "too short to judge" instead of a verdict (a verdict still when an application
ended or the camera lost or mangled a frame, which no length undoes). The last line is
rss_slope_kB_per_h_max=<the largest slope> app=<its application> verdict=<met, not-met or too-short>; the exit code
is 0 once the report is printed, whatever the verdict.
"""

from __future__ import annotations

import argparse
import bisect
import json
import os
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np
import psutil

from automotive.bus import stats as status_records
from automotive.bus.cli import ArgumentParser, add_domain_option, output_file, output_folder
from automotive.tools.launch.display import RUNNING_LINE
from automotive.tools.support import netlab
from automotive.tools.support.children import Child, program_command, work_folder

PROG = "automotive bench soak"
LAUNCHER = "launch"
STOP_TIMEOUT_S = 10.0
SLOPE_GOAL_KB_PER_H = 200.0
COMPARE_WINDOW_S = 600.0  # "minutes 5-15" and "the last 10 minutes"
# The windows' peaks are levels held this long: longer than the applications' trim interval (config.mallocTrim, 60 s)
# plus a sample, so what the next trim gives back does not count and a step that stays does.
HELD_S = 90.0
# The last 10 minutes may hold a level this much above minutes 5-15: one of Cyclone's receive buffers
# (automotive.bus.network.RECEIVE_BUFFER_SIZE), whose pages are resident as far as datagrams have filled it, so that a
# process's RSS rises by up to a buffer and falls when the next one starts (docs/measurements/memory.md, cause 2), for
# minutes at a time in a process that receives little: a level that moves, not a trend. A step bigger than that fails;
# the slope is the trend.
PEAK_TOLERANCE_KB = 256


@dataclass
class Series:
    """One process's samples: seconds since the start, RSS in kB, CPU seconds used so far."""

    name: str
    process: psutil.Process
    times_s: list[float] = field(default_factory=list)
    rss_kB: list[int] = field(default_factory=list)
    cpu_s: list[float] = field(default_factory=list)
    ended: str = ""
    reported: bool = False  # its end was printed

    def sample(self, t: float) -> bool:
        """Take one sample at ``t`` seconds; False once the process is gone."""
        if self.ended:
            return False
        try:
            with self.process.oneshot():
                rss = self.process.memory_info().rss // 1024
                cpu = self.process.cpu_times()
        except psutil.Error as error:
            self.ended = f"ended at {t / 60:.1f} min ({type(error).__name__})"
            return False
        self.times_s.append(t)
        self.rss_kB.append(rss)
        self.cpu_s.append(cpu.user + cpu.system)
        return True

    def held_peak(self, start_s: float, end_s: float, held_s: float = HELD_S) -> int | None:
        """The highest RSS that every sample of ``held_s`` seconds stayed at or above, over the spans that start at a
        sample from ``start_s`` and end by ``end_s``; None when no whole span fits."""
        peak = None
        for first, t in enumerate(self.times_s):
            if t < start_s or t + held_s > end_s:
                continue
            last = bisect.bisect_right(self.times_s, t + held_s) - 1  # the span's last sample (times ascend)
            span = self.rss_kB[first:last + 1]
            # Whole: a sample follows the span, or its last one is held_s after the first (samples come a little
            # late, never exactly on the second: the span is the samples within held_s, not ones held_s apart).
            whole = last + 1 < len(self.times_s) or self.times_s[last] >= t + held_s - 1e-6
            if whole and (peak is None or min(span) > peak):
                peak = min(span)
        return peak

    def fit(self, warmup_s: float) -> tuple[float, float] | None:
        """(slope in kB/s, intercept in kB) of the least-squares line through the samples after the warm-up."""
        points = [(t, rss) for t, rss in zip(self.times_s, self.rss_kB) if t >= warmup_s]
        if len(points) < 3:
            return None
        t, rss = np.array(points, dtype=float).T
        slope, intercept = np.polyfit(t, rss, 1)
        return float(slope), float(intercept)

    def slope_kB_per_h(self, warmup_s: float) -> float | None:
        fitted = self.fit(warmup_s)
        return None if fitted is None else fitted[0] * 3600

    def cpu_percent(self) -> float:
        if len(self.times_s) < 2 or self.times_s[-1] <= self.times_s[0]:
            return 0.0
        return 100 * (self.cpu_s[-1] - self.cpu_s[0]) / (self.times_s[-1] - self.times_s[0])


@dataclass
class Seen:
    """What the camera subscriber and the HMI recorded (their --stats files)."""

    frames: int = 0
    gaps: int = 0
    mismatches: int = 0
    alerts: int = 0
    clears: int = 0
    source_lost: int = 0

    @classmethod
    def read(cls, camera: Path, hmi: Path) -> Seen:
        seen = cls()
        totals = next(status_records.read(camera, "totals"), None)  # at the end; until then the windows' sum
        for record in [totals] if totals is not None else status_records.read(camera, "window"):
            seen.frames += int(record.get("samples", 0))
            seen.gaps += int(record.get("gaps", 0))
            seen.mismatches += int(record.get("mismatches", 0))
        for record in status_records.read(hmi):
            if record.get("kind") == "shown":
                if record.get("state") == "alert":
                    seen.alerts += 1
                else:
                    seen.clears += 1
            # a writer that left (the system's own stop, collision avoidance ending first) is no loss of liveliness
            elif (record.get("kind") == "source" and record.get("alive") is False
                  and "liveliness" in str(record.get("reason", "liveliness"))):
                seen.source_lost += 1
        return seen


def write_chart(path: Path, series: list[Series], warmup_s: float, title: str) -> None:
    """Left: RSS in MB over the run; right: each application's change since the warm-up in kB, where a trend of a
    few hundred kB per hour shows."""
    import matplotlib

    matplotlib.use("Agg")  # no display needed
    import matplotlib.pyplot as plt

    figure, (absolute, change) = plt.subplots(1, 2, figsize=(15, 6.5))
    for one in series:
        if not one.times_s:
            continue
        times = np.array(one.times_s)
        rss = np.array(one.rss_kB, dtype=float)
        line, = absolute.plot(times / 60, rss / 1024, label=one.name, linewidth=1.2)
        after = times >= warmup_s
        fitted = one.fit(warmup_s)
        if not after.any() or fitted is None:
            continue
        base = rss[after][0]
        slope, intercept = fitted
        change.plot(times[after] / 60, rss[after] - base, color=line.get_color(), linewidth=1.2,
                    label=f"{one.name}: {round(slope * 3600):+,} kB/h")
        change.plot(times[after] / 60, slope * times[after] + intercept - base, "--", color=line.get_color(),
                    linewidth=0.8)
    absolute.axvspan(0, warmup_s / 60, color="grey", alpha=0.12, label="warm-up")
    absolute.set_ylabel("resident memory (MB)")
    absolute.set_title("RSS")
    change.set_ylabel("RSS change since the end of the warm-up (kB)")
    change.set_title("after the warm-up (dashed: least-squares line)")
    for axes in (absolute, change):
        axes.set_xlabel("minutes since the system started")
        axes.grid(True, alpha=0.3)
        axes.legend(fontsize=8, loc="upper left")
    figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def sample_until(series: list[Series], args: argparse.Namespace, camera: Path, hmi: Path,
                 samples_out: IO[str] | None) -> None:
    """Sample every --interval seconds until --minutes have passed (or every process is gone); a line a minute."""
    duration_s, interval_s = args.minutes * 60, args.interval
    started = time.monotonic()
    next_sample, next_progress = 0.0, 60.0
    while True:
        elapsed = time.monotonic() - started
        if elapsed >= next_sample:
            for one in series:
                if one.sample(elapsed) and samples_out is not None:
                    samples_out.write(json.dumps({"t_s": round(elapsed, 1), "app": one.name,
                                                  "rss_kB": one.rss_kB[-1], "cpu_s": one.cpu_s[-1]}) + "\n")
            if samples_out is not None:
                samples_out.flush()
            next_sample += interval_s
        if elapsed >= next_progress:
            seen = Seen.read(camera, hmi)
            rss = " ".join(f"{one.name}={one.rss_kB[-1] / 1024:.1f}" for one in series if one.rss_kB)
            print(f"  {elapsed / 60:4.0f} min of {args.minutes:g}: RSS MB {rss}; camera {seen.frames} frames, "
                  f"{seen.gaps} gaps, {seen.mismatches} mismatches; {seen.alerts} alerts", flush=True)
            for one in series:
                if one.ended and not one.reported:
                    print(f"  {one.name} {one.ended}", flush=True)
                    one.reported = True
            next_progress += 60.0
        if elapsed >= duration_s or all(one.ended for one in series):
            return
        time.sleep(max(0.0, min(next_sample, next_progress, duration_s) - (time.monotonic() - started)))


def wait_for_records(series: list[Series], paths: Sequence[Path], timeout_s: float = 120.0) -> None:
    """Until the applications that keep records have opened them: the launcher says "running" once every process is
    started, and on a busy machine an application may still be importing its modules then. The clock of the run
    starts after, so that a short run is not over before the camera subscriber and the HMI are up."""
    deadline = time.monotonic() + timeout_s
    while not all(path.exists() for path in paths):
        ended = [one.name for one in series if not one.process.is_running()]
        if ended or time.monotonic() > deadline:
            missing = ", ".join(path.name for path in paths if not path.exists())
            because = f"{', '.join(ended)} ended" if ended else f"not within {timeout_s:g} s"
            raise SystemExit(f"{PROG}: {missing} not opened by the applications ({because}); see the logs in "
                             f"{paths[0].parent / 'logs'}")
        time.sleep(0.1)  # the applications create the files: nothing to wait on but the folder


def minutes_to_judge(warmup_min: float) -> float:
    """The shortest run the goal judges: the warm-up, then the 10 minutes after it and the last 10 minutes, whole and
    one after the other (a slope fitted over less, or levels compared over parts of windows, say nothing of hours)."""
    return warmup_min + 2 * COMPARE_WINDOW_S / 60


def report(series: list[Series], seen: Seen, args: argparse.Namespace) -> int:
    """The table, the chart, the goal (or "too short to judge") and the last line."""
    warmup_s, end_s = args.warmup * 60, args.minutes * 60
    early = (warmup_s, warmup_s + COMPARE_WINDOW_S)
    late = (end_s - COMPARE_WINDOW_S, end_s)
    long_enough = args.minutes >= minutes_to_judge(args.warmup)
    print(f"\n{'application':<20} {f'at {args.warmup:g} min':>9} {'end kB':>9} {'peak kB':>9} {'slope kB/h':>11} "
          f"{'held ' + f'{early[0] / 60:g}-{early[1] / 60:g} min':>15} {'held last 10':>13} {'CPU %':>6}")
    # Failures that any run shows (an application ended, a frame lost or mangled), and those only a run long enough
    # to judge shows (a trend, a level held, frames that take their time to start).
    worst_name, worst_slope, failures, judged = "-", float("nan"), [], []
    for one in series:
        if not one.rss_kB:
            print(f"{one.name:<20} no samples ({one.ended})")
            failures.append(f"{one.name}: no samples")
            continue
        slope = one.slope_kB_per_h(warmup_s)
        start = next((rss for t, rss in zip(one.times_s, one.rss_kB) if t >= warmup_s), one.rss_kB[0])
        early_peak = one.held_peak(*early) if end_s >= early[1] else None  # a window the run covered, or none
        late_peak = one.held_peak(*late) if long_enough else None
        print(f"{one.name:<20} {start:>9,} {one.rss_kB[-1]:>9,} {max(one.rss_kB):>9,} "
              f"{'-' if slope is None else f'{round(slope):,}':>11} "
              f"{'-' if early_peak is None else f'{early_peak:,}':>15} "
              f"{'-' if late_peak is None else f'{late_peak:,}':>13} {one.cpu_percent():>6.1f}"
              f"{'  (outside the goal)' if one.name == LAUNCHER else ''}{'  ' + one.ended if one.ended else ''}")
        if one.name == LAUNCHER:
            continue
        if one.ended:
            failures.append(f"{one.name} {one.ended}")
        if slope is not None:
            if not slope <= worst_slope:  # the first, or a larger one (worst_slope starts as NaN)
                worst_name, worst_slope = one.name, slope
            if slope > SLOPE_GOAL_KB_PER_H:
                judged.append(f"{one.name}: slope {slope:,.0f} kB/h > {SLOPE_GOAL_KB_PER_H:g}")
        if long_enough and (early_peak is None or late_peak is None):
            judged.append(f"{one.name}: no level held for {HELD_S:g} s in a window to compare")
        elif early_peak is not None and late_peak is not None and late_peak > early_peak + PEAK_TOLERANCE_KB:
            judged.append(f"{one.name}: held in the last 10 min {late_peak:,} kB > {early_peak:,} kB "
                          f"+ {PEAK_TOLERANCE_KB} kB")
    print(f"\ncamera: {seen.frames} frames, {seen.gaps} gaps, {seen.mismatches} mismatches; HMI: {seen.alerts} alerts "
          f"shown, {seen.clears} all-clears, alert source lost {seen.source_lost} time(s)")
    if seen.gaps or seen.mismatches:
        failures.append(f"camera: {seen.gaps} gaps, {seen.mismatches} mismatches")
    if not seen.frames:
        judged.append("camera: no frame received")
    write_chart(args.chart, series, warmup_s, f"{PROG}: the whole system for {args.minutes:g} min, "
                                              f"{args.warmup:g}-min warm-up")
    print(f"chart: {args.chart}")
    if not long_enough:
        print(f"too short to judge: the goal needs at least {minutes_to_judge(args.warmup):g} minutes "
              f"(this run: {args.minutes:g})")
    else:
        failures += judged
    verdict = "not-met" if failures else "met" if long_enough else "too-short"
    if failures:
        print("goal NOT met: " + "; ".join(failures))
    elif long_enough:
        print("goal met")
    # round(), not :.0f, so that a flat line's -0.0 prints as 0; NaN when no application had enough samples
    print(f"rss_slope_kB_per_h_max={'nan' if worst_slope != worst_slope else round(worst_slope)} app={worst_name} "
          f"verdict={verdict}")
    return 0


def require_root(prog: str) -> None:
    """One line and exit code 2 unless this process may make a network namespace (root)."""
    if os.geteuid() != 0:
        print(f"{prog}: needs root (it runs the system in a network namespace of its own)", file=sys.stderr)
        raise SystemExit(2)


def system_env() -> dict[str, str]:
    """The environment of the system in its namespace: Cyclone's defaults there (no CYCLONEDDS_URI), and the HMI's
    console alert box, no window on the user's display."""
    env = {key: value for key, value in os.environ.items() if key != "CYCLONEDDS_URI"}
    env.update(DISPLAY="", WAYLAND_DISPLAY="")
    return env


@contextmanager
def system_in_namespace(prog: str, name: str, domain: int, work: Path, launch_args: Sequence[str],
                        env: Mapping[str, str]) -> Iterator[list[Series]]:
    """The whole system as `automotive launch` starts it (every application, camera included, shipped properties;
    background mode, --quiet: the applications' lines go to their log files in ``work``/logs only), in a network
    namespace ``name`` made for it, whose loopback is private. Yields a Series per application, the launcher's last,
    once every application runs (the launcher's running line, printed); on leaving, stops the launcher (which stops
    the applications) and deletes the namespace. ``launch_args``: more of the launcher's arguments (--stats-dir, -D)."""
    log_dir = work / "logs"
    command = ["--mode", "background", "--quiet", "--domain", str(domain), "--log-dir", str(log_dir),
               "--stop-timeout", f"{STOP_TIMEOUT_S:g}", *launch_args]
    try:
        namespace = netlab.Namespace(name)
    except netlab.NetlabError as error:
        raise SystemExit(f"{prog}: {error}") from None
    try:
        launcher = Child(LAUNCHER, program_command("launch", *command, python=namespace.prefix), env=dict(env))
        try:
            try:
                line = launcher.wait_for(RUNNING_LINE, timeout=120)
            except AssertionError:
                raise SystemExit(f"{prog}: the launcher ended before the system ran:\n{launcher.output[-2000:]}") \
                    from None
            print(line.split("| ", 1)[1].strip(), flush=True)
            info = json.loads((log_dir / "launch.pid").read_text())
            series = [Series(app, psutil.Process(pid)) for app, pid in info["apps"].items()]
            series.append(Series(LAUNCHER, psutil.Process(int(info["launcher"]))))
            yield series
        finally:
            launcher.stop(timeout=STOP_TIMEOUT_S + 20)
    finally:
        namespace.delete()


def bench(args: argparse.Namespace) -> int:
    require_root(PROG)
    # SIGTERM (a background run stopped with kill) ends the run as Ctrl-C does: the system stopped, the namespace and
    # the temporary work folder gone.
    with work_folder("bench-soak-", args.work) as work:
        return run(args, work)


def run(args: argparse.Namespace, work: Path) -> int:
    camera, hmi = work / "camera_sub.jsonl", work / "hmi.jsonl"
    env = system_env()
    if args.memtrace is not None:
        args.memtrace.mkdir(parents=True, exist_ok=True)
        env.update(AUTOMOTIVE_MEMTRACE=str(args.memtrace.resolve()), AUTOMOTIVE_MEMTRACE_INTERVAL="60")
    samples_out = open(args.samples, "w", encoding="utf-8") if args.samples else None
    try:
        with system_in_namespace(PROG, f"bench-soak-{os.getpid()}", args.domain, work,
                                 ["--stats-dir", f"camera_sub:{work}", "--stats-dir", f"hmi:{work}"], env) as series:
            wait_for_records(series, (camera, hmi))
            kept = f"; work folder {work}" if args.work is not None else ""
            print(f"sampling {len(series) - 1} applications and the launcher every {args.interval:g} s for "
                  f"{args.minutes:g} min (warm-up {args.warmup:g} min){kept}", flush=True)
            sample_until(series, args, camera, hmi, samples_out)
    finally:
        if samples_out is not None:
            samples_out.close()
    return report(series, Seen.read(camera, hmi), args)


def read_samples(path: Path) -> list[Series]:
    """The series of a run's --samples file, in the order the applications first appear (their processes are gone:
    the series stand for them); ValueError names the first line that is not a sample."""
    series: dict[str, Series] = {}
    with open(path, encoding="utf-8") as samples:
        for number, line in enumerate(samples, 1):
            try:
                record = json.loads(line)
                one = series.setdefault(record["app"], Series(record["app"], psutil.Process()))
                one.times_s.append(float(record["t_s"]))
                one.rss_kB.append(int(record["rss_kB"]))
                one.cpu_s.append(float(record["cpu_s"]))
            except (ValueError, KeyError, TypeError):
                raise ValueError(f"{path}, line {number}: expected a JSON object with app, t_s, rss_kB and cpu_s") \
                    from None
    return list(series.values())


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=30.0, help="how long the system runs (30)")
    parser.add_argument("--warmup", type=float, default=5.0, help="minutes left out of the fit (5)")
    parser.add_argument("--interval", type=float, default=10.0, help="seconds between samples (10)")
    add_domain_option(parser, 88, "DDS domain id")
    parser.add_argument("--chart", type=output_file, default="bench-soak.png", help="PNG of the curves to write")
    parser.add_argument("--samples", type=output_file, default=None, metavar="FILE",
                        help="also write every sample as a JSON line (t_s, app, rss_kB, cpu_s)")
    parser.add_argument("--memtrace", type=output_folder, default=None, metavar="DIR",
                        help="run the applications with their memory probe on (AUTOMOTIVE_MEMTRACE, every minute)")
    parser.add_argument("--report", type=Path, default=None, metavar="FILE",
                        help="run nothing: report a run from its --samples FILE (with --work)")
    parser.add_argument("--work", type=Path, default=None, metavar="DIR",
                        help="the run's work folder (the camera's and the HMI's records, the logs): a new or empty "
                             "folder, kept (default: a temporary one, removed at the end); with --report, a run's")
    args = parser.parse_args(argv)
    if args.report is not None:
        if args.work is None or not (args.work / "camera_sub.jsonl").is_file() or not args.report.is_file():
            parser.error("--report FILE needs the file and --work DIR, the run's work folder (with camera_sub.jsonl)")
        try:
            series = read_samples(args.report)
        except ValueError as error:
            parser.error(f"--report {error}")
        if not series or not any(one.times_s for one in series):
            parser.error(f"--report {args.report}: no samples in it")
        args.minutes = round(max(one.times_s[-1] for one in series) / 60, 1)
        if args.warmup >= args.minutes:
            parser.error(f"--report {args.report}: {args.minutes:g} min of samples, not more than --warmup")
        return report(series, Seen.read(args.work / "camera_sub.jsonl", args.work / "hmi.jsonl"), args)
    if args.minutes <= 0 or args.warmup < 0 or args.warmup >= args.minutes or args.interval <= 0:
        parser.error("--minutes must be > 0, --warmup from 0 to below --minutes, --interval > 0")
    check_work_folder(parser, args.work)
    return bench(args)


def check_work_folder(parser: argparse.ArgumentParser, work: Path | None) -> None:
    """--work DIR must be a new or empty folder: the status records are appended to, and an earlier run's would count
    in this one."""
    if work is not None and (work.exists() and not work.is_dir() or work.is_dir() and any(work.iterdir())):
        parser.error(f"--work {work}: expected a new or empty folder")


if __name__ == "__main__":
    sys.exit(main())
