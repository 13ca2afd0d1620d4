"""Sensor fusion against N vision sensors on one host (loopback): discovery time, fusion CPU, objects per fused list.

    automotive bench scale                      N = 1, 10, 50
    automotive bench scale --sizes 1,20 --window 10 --domain 85

For each N: sensor_fusion starts and creates its reader; then N vision processes (python -m automotive.apps.vision,
config.sensorId 1..N, as `automotive launch --vision-sensors N` starts them)
start at once (or --stagger S seconds apart).
Measured, from each process's status records (--stats, JSON lines with wall-clock times):
  start       seconds from starting the N processes until every one has created its writer (its "ready" record)
  discovery   milliseconds from the last writer created until sensor fusion's reader has matched all N (its
              "matched" record with count N); negative when the match came first (a sensor records "ready" just
              after creating its writer)
  ready       seconds from starting the N processes until all N are matched (start + discovery)
Then over --window seconds of steady running:
  fusion CPU  sensor_fusion's user+system CPU time over the window (psutil), in % of one core
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
import shutil
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

from automotive.bus.cli import ArgumentParser, add_domain_option, add_log_dir_option, output_folder_problem
from automotive.bus.network import NetworkConfig
from automotive.bus.ports import MAX_PARTICIPANTS
from automotive.tools.support.children import StatsChild, stop_all, work_folder
from automotive.types.Sensor import SENSOR_OBJECT_LIST_MAX_SIZE

PROG = "automotive bench scale"


def start_process(name: str, module: str, args: list[str], env: dict[str, str], workdir: Path) -> StatsChild:
    """A program of the system with its status records (--stats) in ``workdir``."""
    return StatsChild.start(name, module, args, workdir / f"{name}.jsonl", env=env)


def udp_receive_buffer_drops() -> int:
    """UDP datagrams the kernel dropped because a socket's receive buffer was full (whole host, since boot)."""
    lines = [line.split() for line in Path("/proc/net/snmp").read_text().splitlines() if line.startswith("Udp:")]
    return int(lines[1][lines[0].index("RcvbufErrors")]) if len(lines) >= 2 else 0


def wait_until(condition: Callable[[], float | None], timeout: float, what: str) -> float:
    """Poll ``condition`` until it returns a time stamp; fail after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while True:
        result = condition()
        if result is not None:
            return float(result)
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(0.05)  # polling files the other processes append to


def stop(processes: list[StatsChild], log_dir: Path | None) -> None:
    stop_all([process.child for process in processes], timeout=15)
    if log_dir is not None:
        log_dir.mkdir(parents=True, exist_ok=True)
        for process in processes:
            (log_dir / f"{process.name}.log").write_text("".join(f"{line.time:.3f} {line.text}\n"
                                                                 for line in process.child.records))
            if process.stats.is_file():
                shutil.copyfile(process.stats, log_dir / f"{process.name}.jsonl")


def run_one(n: int, domain: int, window: float, env: dict[str, str], timeout: float,
            log_dir: Path | None, stagger: float) -> dict[str, float]:
    # The status records; removed at the end, also on an error, Ctrl-C or SIGTERM (which ends the run as Ctrl-C does,
    # the processes stopped first). --log-dir gets copies.
    with work_folder(f"bench-scale-n{n}-") as workdir:
        return measure(n, domain, window, env, timeout, log_dir, stagger, workdir)


def measure(n: int, domain: int, window: float, env: dict[str, str], timeout: float, log_dir: Path | None,
            stagger: float, workdir: Path) -> dict[str, float]:
    processes: list[StatsChild] = []
    drops_before = udp_receive_buffer_drops()
    try:
        fusion = start_process("sensor_fusion", "sensor_fusion", ["--domain", str(domain)], env, workdir)
        processes.append(fusion)
        wait_until(lambda: fusion.first("ready"), timeout, "sensor fusion's reader")
        started = time.time()
        visions: list[StatsChild] = []
        for i in range(1, n + 1):
            if i > 1 and stagger > 0:
                time.sleep(stagger)  # spreading the start-up load (--stagger), not synchronisation
            visions.append(start_process(f"vision-{i}", "vision",
                                         ["--domain", str(domain), "-D", f"config.sensorId={i}"], env, workdir))
            processes.append(visions[-1])

        def all_ready() -> float | None:
            for vision in visions:
                if vision.child.poll() is not None:
                    raise RuntimeError(f"{vision.name} ended: {vision.child.lines[-3:]}")
            stamps = [vision.first("ready") for vision in visions]
            return None if None in stamps else max(s for s in stamps if s is not None)

        def matched_all() -> float | None:
            return fusion.first("matched", lambda record: record["topic"] == "VisionTopic"
                                and record["endpoint"] == "reader" and record["count"] >= n)

        last_ready = wait_until(all_ready, timeout, f"{n} vision writers")
        try:
            matched = wait_until(matched_all, timeout, f"sensor fusion matching {n} writers")
        except TimeoutError as error:
            best = max((int(record["count"]) for record in fusion.records("matched")
                        if record["topic"] == "VisionTopic"), default=0)
            alive = sum(1 for vision in visions if vision.child.poll() is None)
            drops = udp_receive_buffer_drops() - drops_before
            raise TimeoutError(f"{error} (it matched at most {best}; {alive} of {n} sensors running; "
                               f"{drops} UDP datagrams dropped on full receive buffers)") from None
        # Steady state: from the first list after everything matched, for `window` seconds.
        window_start = max(time.time(), matched) + 1.0
        time.sleep(max(0.0, window_start - time.time()))
        cpu_fusion_0 = fusion.child.cpu_seconds()
        cpu_vision_0 = sum(vision.child.cpu_seconds() for vision in visions)
        time.sleep(window)
        window_end = time.time()
        cpu_fusion = fusion.child.cpu_seconds() - cpu_fusion_0
        cpu_vision = sum(vision.child.cpu_seconds() for vision in visions) - cpu_vision_0
        time.sleep(0.5)  # the records of the window's last moments reach their files
        lists = fusion.records("list", window_start, window_end)
        objects = [int(record["objects"]) for record in lists]
        samples = [int(record["samples"]) for record in lists]
        offered = sum(int(record["objects"]) for vision in visions
                      for record in vision.records("sample", window_start, window_end))
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


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", default="1,10,50", help="numbers of vision sensors (default 1,10,50)")
    add_domain_option(parser, 85, "DDS domain id")
    parser.add_argument("--window", type=float, default=5.0, help="seconds of steady running measured (default 5)")
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds allowed for start and discovery")
    parser.add_argument("--stagger", type=float, default=0.0, metavar="S",
                        help="seconds between two vision starts (default 0: all at once)")
    add_log_dir_option(parser, help="write every process's output there (DIR/nN/NAME.log with monotonic time stamps, "
                                    "NAME.jsonl: its status records)")
    args = parser.parse_args(argv)
    if args.log_dir is not None and (problem := output_folder_problem(args.log_dir, create=True)):
        parser.error(f"--log-dir {args.log_dir}: {problem}")  # before the run, not after it
    try:
        sizes = [int(size) for size in args.sizes.split(",")]
    except ValueError:
        print(f"{PROG}: --sizes {args.sizes}: expected numbers separated by commas", file=sys.stderr)
        return 2
    if any(size < 1 for size in sizes) or args.window <= 0:
        print(f"{PROG}: sizes and --window must be positive", file=sys.stderr)
        return 2

    rows = []
    for n in sizes:
        env = dict(os.environ)
        # Loopback only; every participant on the host needs an index: N sensors, fusion, and some room.
        env["CYCLONEDDS_URI"] = NetworkConfig(max_participants=min(MAX_PARTICIPANTS, max(100, n + 20))).cyclone_xml()
        print(f"{PROG}: N = {n} ...", file=sys.stderr, flush=True)
        try:
            rows.append(run_one(n, args.domain, args.window, env, args.timeout, args.log_dir, args.stagger))
        except (TimeoutError, RuntimeError) as error:
            print(f"{PROG}: N = {n}: {error}", file=sys.stderr)
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
    print(f"scale_discovery_ms_max={max(row['discovery'] for row in rows):.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
