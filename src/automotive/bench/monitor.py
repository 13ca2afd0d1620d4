"""What `automotive monitor` costs while the whole system runs, camera included: its CPU in % of one core.

    automotive bench monitor                           the whole system and the monitor, 60 s after a 15 s warm-up
    automotive bench monitor --seconds 120 --text      the monitor's text form (--text) instead of its page
    automotive bench monitor --monitor-arg=--camera    the monitor also reading the camera's frames
    automotive bench monitor -- --redundant            more arguments for the launcher, after --

The system runs as `automotive launch` starts it (every application, camera included; background mode, the HMI's
console box, --quiet: the applications' lines go to their log files only). Beside it runs `automotive monitor` on the
same domain: its page (on a free port of 127.0.0.1), which a viewer watches as a browser does: this program asks for
/snapshot.json and /lidar.png once a second (what a page asks for: a snapshot a second and the LiDAR picture), so the
monitor makes a snapshot a second and draws the LiDAR; or, with --text, its text form (a snapshot every 0.5 s,
printed on changes). psutil reads the monitor process's CPU time at the start and end of each phase (the warm-up,
--warmup, then the measurement, --seconds) and every 10 s for a progress line. Each phase ends with a JSON line of
its figures; the processes' output goes to a temporary work folder, removed at the end (also on an error, Ctrl-C or
SIGTERM), or to --log-dir DIR, kept.

Goal: the monitor's CPU at most 5 % of one core over 60 s of the whole system (the issue's bound). A shorter run
prints its figures and "too short to judge". The last line is monitor_cpu_pct=<% of one core over --seconds>.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time
import urllib.error
import urllib.request
from dataclasses import dataclass
from pathlib import Path

import psutil

from automotive.bus.cli import ArgumentParser, add_domain_option, add_log_dir_option, output_folder_problem
from automotive.tools.launch.display import RUNNING_LINE
from automotive.tools.support.children import Child, keep_outputs, program_command, stop_all, work_folder

PROG = "automotive bench monitor"
GOAL_CPU_PCT = 5.0
GOAL_SECONDS = 60.0
PROGRESS_S = 10.0
VIEW_EVERY_S = 1.0  # a page's cadence: a snapshot and the LiDAR picture a second
URL_LINE = re.compile(r"the page is on (http://\S+)")
START_TIMEOUT_S = 120.0


@dataclass
class Phase:
    name: str
    seconds: float
    cpu_s: float
    rss_mb: float
    views: int
    view_failures: int

    @property
    def cpu_pct(self) -> float:
        return 100 * self.cpu_s / self.seconds if self.seconds > 0 else float("nan")

    def record(self) -> str:
        return json.dumps({"phase": self.name, "seconds": round(self.seconds, 1), "monitor_cpu_s": round(self.cpu_s, 3),
                           "monitor_cpu_pct": round(self.cpu_pct, 2), "monitor_rss_mb": round(self.rss_mb, 1),
                           "views": self.views, "view_failures": self.view_failures})


class Viewer:
    """Asks the page for what a browser watching it asks for, once a second."""

    def __init__(self, url: str | None):
        self.base = url.split("?", 1)[0].rstrip("/") + "/" if url else None
        self.query = "?" + url.split("?", 1)[1] if url and "?" in url else ""
        self.views = 0
        self.failures = 0
        self.last_error = ""
        self.next_at = 0.0

    def tick(self) -> None:
        if self.base is None or time.monotonic() < self.next_at:
            return
        self.next_at = time.monotonic() + VIEW_EVERY_S
        for path in ("snapshot.json", "lidar.png"):
            try:
                with urllib.request.urlopen(self.base + path + self.query, timeout=10) as response:
                    response.read()
                self.views += path == "snapshot.json"
            except (urllib.error.URLError, OSError) as error:
                if not (isinstance(error, urllib.error.HTTPError) and error.code == 404 and path == "lidar.png"):
                    self.failures += 1
                    self.last_error = f"{path}: {error}"


def cpu_s(process: psutil.Process) -> float:
    times = process.cpu_times()
    return float(times.user + times.system)


def run_phase(name: str, seconds: float, process: psutil.Process, viewer: Viewer, monitor: Child,
              total_s: float, offset_s: float) -> Phase:
    """Watch for ``seconds``: the monitor's CPU over the phase, a progress line every PROGRESS_S."""
    started, cpu_start = time.monotonic(), cpu_s(process)
    views, failures = viewer.views, viewer.failures
    next_progress, last_cpu, last_t = started + PROGRESS_S, cpu_start, started
    while (now := time.monotonic()) < started + seconds:
        if monitor.poll() is not None:
            raise SystemExit(f"{PROG}: the monitor ended (exit {monitor.poll()}):\n{monitor.output[-2000:]}")
        viewer.tick()
        if now >= next_progress:
            cpu = cpu_s(process)
            print(f"  {offset_s + now - started:5.0f} s of {total_s:g} ({name}): monitor CPU "
                  f"{100 * (cpu - last_cpu) / (now - last_t):.1f} % over the last {now - last_t:.0f} s, RSS "
                  f"{process.memory_info().rss / 1e6:.1f} MB, {viewer.views} views", flush=True)
            next_progress, last_cpu, last_t = now + PROGRESS_S, cpu, now
        time.sleep(max(0.0, min(started + seconds, next_progress, viewer.next_at or now + 0.2) - time.monotonic()))
    elapsed = time.monotonic() - started
    return Phase(name, elapsed, cpu_s(process) - cpu_start, process.memory_info().rss / 1e6,
                 viewer.views - views, viewer.failures - failures)


def measure(args: argparse.Namespace, work: Path) -> int:
    env = {**os.environ, "DISPLAY": "", "WAYLAND_DISPLAY": ""}  # the HMI's console box: no window on a display
    log_dir = work / "logs"
    command = program_command("launch", "--mode", "background", "--quiet", "--log-dir", str(log_dir),
                              "--domain", str(args.domain), *args.launch_args)
    launcher = Child("launch", command, env=env, keep=True)
    children = [launcher]
    monitor: Child | None = None
    try:
        try:
            launcher.wait_for(RUNNING_LINE, timeout=START_TIMEOUT_S)
        except AssertionError:
            raise SystemExit(f"{PROG}: the launcher ended before the system ran:\n{launcher.output[-2000:]}") from None
        mode = "text" if args.text else "page"
        extra = ["--text"] if args.text else ["--port", "0"]
        monitor = Child("monitor", program_command("monitor", "--domain", str(args.domain), *extra,
                                                   *args.monitor_args), env=env)
        children.append(monitor)
        url = None
        if not args.text:
            try:
                url = URL_LINE.search(monitor.wait_for(URL_LINE.pattern, timeout=START_TIMEOUT_S))
            except AssertionError:
                raise SystemExit(f"{PROG}: the monitor's page did not start:\n{monitor.output[-2000:]}") from None
        viewer = Viewer(url.group(1) if url else None)
        process = psutil.Process(monitor.pid)
        options = "".join(f" {arg}" for arg in args.monitor_args)
        print(f"{PROG}: the system runs with the monitor ({mode}{options}); "
              f"warm-up {args.warmup:g} s, then {args.seconds:g} s measured", flush=True)
        total = args.warmup + args.seconds
        phases = []
        if args.warmup > 0:
            phases.append(run_phase("warm-up", args.warmup, process, viewer, monitor, total, 0.0))
            print(phases[-1].record(), flush=True)
        phases.append(run_phase("measure", args.seconds, process, viewer, monitor, total, args.warmup))
        print(phases[-1].record(), flush=True)
    finally:
        stop_all(list(reversed(children)), timeout=30)
        if args.log_dir is not None:
            keep_outputs(children, args.log_dir, log_dir)
    measured = phases[-1]
    if viewer.failures:
        print(f"the viewer's requests failed {viewer.failures} time(s); the last: {viewer.last_error}")
    print(f"monitor: {measured.cpu_pct:.2f} % of one core over {measured.seconds:.0f} s ({measured.cpu_s:.2f} CPU s), "
          f"RSS {measured.rss_mb:.1f} MB, {measured.views} snapshots viewed")
    if args.seconds < GOAL_SECONDS:
        print(f"too short to judge: the goal is over {GOAL_SECONDS:g} s (this run: {args.seconds:g} s)")
    else:
        verdict = "met" if measured.cpu_pct <= GOAL_CPU_PCT else "NOT met"
        print(f"goal {verdict}: the monitor at most {GOAL_CPU_PCT:g} % of one core (this run: {measured.cpu_pct:.2f})")
    print(f"monitor_cpu_pct={measured.cpu_pct:.2f}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=GOAL_SECONDS, help="how long to measure (default 60)")
    parser.add_argument("--warmup", type=float, default=15.0,
                        help="seconds after the system runs before the measure (default 15)")
    parser.add_argument("--text", action="store_true", help="measure the monitor's text form (--text), not its page")
    parser.add_argument("--monitor-arg", dest="monitor_args", action="append", default=[], metavar="ARG",
                        help="one more argument for the monitor (repeat it), e.g. --monitor-arg=--camera")
    parser.add_argument("launch_args", nargs="*", metavar="LAUNCH_ARG",
                        help="more arguments for the launcher, after --, e.g. -- --redundant")
    add_domain_option(parser, 87, "DDS domain id of the system and the monitor")
    add_log_dir_option(parser, help="keep every process's output there (the launcher's log folder too)")
    args = parser.parse_args(argv)
    if not args.seconds > 0 or not args.warmup >= 0:
        parser.error(f"--seconds {args.seconds:g} and --warmup {args.warmup:g}: expected more than 0 and 0 or more")
    if args.log_dir is not None and (problem := output_folder_problem(args.log_dir, create=True)):
        parser.error(f"--log-dir {args.log_dir}: {problem}")  # before the run, not after it
    # SIGTERM (a background run stopped with kill) ends the run as Ctrl-C does: the system stopped, the folder gone.
    with work_folder("bench-monitor-") as work:
        return measure(args, work)


if __name__ == "__main__":
    sys.exit(main())
