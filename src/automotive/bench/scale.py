#!/usr/bin/env python3
"""Sensor fusion against N vision sensors on one host (loopback): discovery time, fusion CPU, objects per fused list.

    scripts/bench-scale                      N = 1, 10, 50
    scripts/bench-scale --sizes 1,20 --window 10 --domain 85

For each N: sensor_fusion starts and creates its reader; then N vision processes (python -m automotive.apps.vision,
config.sensorId 1..N, as `scripts/launch --vision-sensors N` starts them) start at once (or --stagger S seconds apart).
Measured, from each process's output as it arrives:
  start       seconds from starting the N processes until every one has created its writer ("vision sensor i:")
  discovery   milliseconds from the last writer created until sensor fusion's reader has matched all N
              ("[VisionTopic] reader matched a writer: N writer(s) now"); negative when the match was seen first
              (the sensor logs its line just after creating its writer, and the pipes race)
  ready       seconds from starting the N processes until all N are matched (start + discovery)
Then over --window seconds of steady running:
  fusion CPU  sensor_fusion's user+system CPU time over the window, in % of one core
  vision CPU  the N vision processes together, in % of one core
  lists/s, samples/list, offered/list (objects the sensors published per list interval), objects/list (mean and
  max, bounded by Sensor::SensorObjectList's 128), full (lists at the bound: objects were cut)
  UDP drops   datagrams the kernel dropped on full socket receive buffers during the run (whole host: RcvbufErrors)

All traffic stays on loopback (CYCLONEDDS_URI: interface lo, multicast off, peer 127.0.0.1). This runs N + 1 Python
processes: on a small machine N = 50 takes a minute and most of its CPU.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import statistics
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from automotive.bus.cli import ArgumentParser, run_in_project_venv  # noqa: E402

run_in_project_venv(__file__, sys.argv[1:])  # Cyclone DDS and numpy are in the project's .venv

from automotive.bus.network import NetworkConfig  # noqa: E402
from automotive.types.Sensor import SENSOR_OBJECT_LIST_MAX_SIZE  # noqa: E402

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
LIST_LINE = re.compile(r"published list \d+: (\d+) object\(s\) from (\d+) vision sample\(s\)")
MATCHED_LINE = re.compile(r"\[VisionTopic\] reader (?:un)?matched a writer: (\d+) writer")
SAMPLE_LINE = re.compile(r"published sample \d+: (\d+) object\(s\)")


@dataclass
class Process:
    name: str
    popen: subprocess.Popen[str]
    lines: list[tuple[float, str]] = field(default_factory=list)

    def start_reading(self) -> None:
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.popen.stdout is not None
        for line in self.popen.stdout:
            self.lines.append((time.monotonic(), line.rstrip("\n")))

    def first(self, pattern: re.Pattern[str]) -> float | None:
        for stamp, line in list(self.lines):
            if pattern.search(line):
                return stamp
        return None

    def between(self, pattern: re.Pattern[str], start: float, end: float) -> list[re.Match[str]]:
        return [match for stamp, line in list(self.lines) if start <= stamp < end and (match := pattern.search(line))]

    def cpu_seconds(self) -> float:
        try:
            fields = Path(f"/proc/{self.popen.pid}/stat").read_text().rpartition(")")[2].split()
        except OSError:
            return 0.0
        return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS  # utime, stime


def udp_receive_buffer_drops() -> int:
    """UDP datagrams the kernel dropped because a socket's receive buffer was full (whole host, since boot)."""
    lines = [line.split() for line in Path("/proc/net/snmp").read_text().splitlines() if line.startswith("Udp:")]
    return int(lines[1][lines[0].index("RcvbufErrors")]) if len(lines) >= 2 else 0


def spawn(name: str, module: str, args: list[str], env: dict[str, str]) -> Process:
    popen = subprocess.Popen([sys.executable, "-m", f"apps.{module}", *args], cwd=ROOT, env=env, text=True,
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    process = Process(name, popen)
    process.start_reading()
    return process


def wait_until(condition: object, timeout: float, what: str) -> float:
    """Poll ``condition`` (a callable) until it returns a time stamp; fail after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while True:
        result = condition()  # type: ignore[operator]
        if result is not None:
            return float(result)
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(0.05)


def stop(processes: list[Process], log_dir: Path | None) -> None:
    for process in processes:
        if process.popen.poll() is None:
            process.popen.send_signal(signal.SIGTERM)
    for process in processes:
        try:
            process.popen.wait(timeout=15)
        except subprocess.TimeoutExpired:
            process.popen.kill()
            process.popen.wait()
    if log_dir is not None:
        log_dir.mkdir(parents=True, exist_ok=True)
        for process in processes:
            (log_dir / f"{process.name}.log").write_text("".join(f"{stamp:.3f} {line}\n"
                                                                 for stamp, line in process.lines))


def run_one(n: int, domain: int, window: float, env: dict[str, str], timeout: float,
            log_dir: Path | None, stagger: float) -> dict[str, float]:
    processes: list[Process] = []
    drops_before = udp_receive_buffer_drops()
    try:
        fusion = spawn("sensor_fusion", "sensor_fusion", ["--domain", str(domain)], env)
        processes.append(fusion)
        wait_until(lambda: fusion.first(re.compile(r"sensor fusion: .* mode")), timeout, "sensor fusion's reader")
        started = time.monotonic()
        visions: list[Process] = []
        for i in range(1, n + 1):
            if i > 1 and stagger > 0:
                time.sleep(stagger)  # spreading the start-up load (--stagger), not synchronisation
            visions.append(spawn(f"vision-{i}", "vision", ["--domain", str(domain), "-D", f"config.sensorId={i}"],
                                 env))
            processes.append(visions[-1])
        ready_pattern = re.compile(r"vision sensor \d+: ")

        def all_ready() -> float | None:
            stamps = [vision.first(ready_pattern) for vision in visions]
            for vision in visions:
                if vision.popen.poll() is not None:
                    raise RuntimeError(f"{vision.name} ended: {vision.lines[-3:]}")
            return None if None in stamps else max(s for s in stamps if s is not None)

        last_ready = wait_until(all_ready, timeout, f"{n} vision writers")
        try:
            matched = wait_until(lambda: fusion.first(re.compile(rf"\[VisionTopic\] reader matched a writer: {n} ")),
                                 timeout, f"sensor fusion matching {n} writers")
        except TimeoutError as error:
            counts = fusion.between(MATCHED_LINE, 0, float("inf"))
            best = max((int(match.group(1)) for match in counts), default=0)
            alive = sum(1 for vision in visions if vision.popen.poll() is None)
            drops = udp_receive_buffer_drops() - drops_before
            raise TimeoutError(f"{error} (it matched at most {best}; {alive} of {n} sensors running; "
                               f"{drops} UDP datagrams dropped on full receive buffers)") from None
        # Steady state: from the first list after everything matched, for `window` seconds.
        window_start = max(time.monotonic(), matched) + 1.0
        time.sleep(max(0.0, window_start - time.monotonic()))
        cpu_fusion_0 = fusion.cpu_seconds()
        cpu_vision_0 = sum(vision.cpu_seconds() for vision in visions)
        time.sleep(window)
        window_end = time.monotonic()
        cpu_fusion = fusion.cpu_seconds() - cpu_fusion_0
        cpu_vision = sum(vision.cpu_seconds() for vision in visions) - cpu_vision_0
        lists = fusion.between(LIST_LINE, window_start, window_end)
        objects = [int(match.group(1)) for match in lists]
        samples = [int(match.group(2)) for match in lists]
        offered = sum(int(match.group(1)) for vision in visions
                      for match in vision.between(SAMPLE_LINE, window_start, window_end))
        return {
            "n": n,
            "start": last_ready - started,
            "discovery": 1000 * (matched - last_ready),
            "ready": matched - started,
            "fusion_cpu": 100 * cpu_fusion / window,
            "vision_cpu": 100 * cpu_vision / window,
            "lists_per_s": len(lists) / window,
            "samples_per_list": statistics.mean(samples) if samples else 0.0,
            "offered_per_list": offered / len(lists) if lists else 0.0,
            "objects_mean": statistics.mean(objects) if objects else 0.0,
            "objects_max": max(objects, default=0),
            "full": sum(1 for count in objects if count >= SENSOR_OBJECT_LIST_MAX_SIZE),
            "lists": len(lists),
            "udp_drops": udp_receive_buffer_drops() - drops_before,
        }
    finally:
        stop(processes, log_dir / f"n{n}" if log_dir else None)


def main() -> int:
    parser = ArgumentParser(prog="scripts/bench-scale", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", default="1,10,50", help="numbers of vision sensors (default 1,10,50)")
    parser.add_argument("--domain", type=int, default=85, help="DDS domain id (default 85)")
    parser.add_argument("--window", type=float, default=5.0, help="seconds of steady running measured (default 5)")
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds allowed for start and discovery")
    parser.add_argument("--stagger", type=float, default=0.0, metavar="S",
                        help="seconds between two vision starts (default 0: all at once)")
    parser.add_argument("--log-dir", type=Path, default=None,
                        help="write every process's output there (DIR/nN/NAME.log, monotonic time stamps)")
    args = parser.parse_args()
    try:
        sizes = [int(size) for size in args.sizes.split(",")]
    except ValueError:
        print(f"bench-scale: --sizes {args.sizes}: expected numbers separated by commas", file=sys.stderr)
        return 2
    if any(size < 1 for size in sizes) or args.window <= 0:
        print("bench-scale: sizes and --window must be positive", file=sys.stderr)
        return 2

    rows = []
    for n in sizes:
        env = dict(os.environ)
        # Loopback only; every participant on the host needs an index: N sensors, fusion, and some room.
        env["CYCLONEDDS_URI"] = NetworkConfig(max_participants=max(100, n + 20)).cyclone_xml()
        env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        env["PYTHONUNBUFFERED"] = "1"
        print(f"bench-scale: N = {n} ...", file=sys.stderr, flush=True)
        try:
            rows.append(run_one(n, args.domain, args.window, env, args.timeout, args.log_dir, args.stagger))
        except (TimeoutError, RuntimeError) as error:
            print(f"bench-scale: N = {n}: {error}", file=sys.stderr)
            return 1

    header = (f"{'N':>4} {'start s':>8} {'discov. ms':>10} {'ready s':>8} {'fusion CPU':>10} {'vision CPU':>10} "
              f"{'lists/s':>7} {'samples/list':>12} {'offered/list':>12} {'objects/list':>13} {'full':>6} "
              f"{'UDP drops':>9}")
    print(f"sensor fusion against N vision sensors, loopback, {os.cpu_count()} CPU(s), window {args.window:g} s")
    print(header)
    print("-" * len(header))
    for row in rows:
        print(f"{row['n']:>4} {row['start']:>8.2f} {row['discovery']:>10.0f} {row['ready']:>8.2f} "
              f"{row['fusion_cpu']:>9.1f}% {row['vision_cpu']:>9.1f}% {row['lists_per_s']:>7.1f} "
              f"{row['samples_per_list']:>12.1f} {row['offered_per_list']:>12.1f} "
              f"{row['objects_mean']:>7.1f}/{row['objects_max']:<5} {row['full']:>3}/{row['lists']:<3} "
              f"{row['udp_drops']:>9}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
