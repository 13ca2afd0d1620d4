"""Large samples on one host: our camera pair (two Python processes) over UDP and over shared memory, against
Cyclone's C tool ddsperf, side by side.

For each sample size (64 KiB, 1 MiB, 4 MiB by default) and round, runs our camera_pub + camera_sub over DDS
(loopback UDP), the same pair over shared memory (config.transport=shm: iceoryx2, automotive.wire.shm), and
`ddsperf pub size S` + `ddsperf sub`, all reliable and keep-all, as fast as flow control allows, for the same
duration, in an order that alternates between rounds, so that machine noise hits all alike. The DDS runs use the
same Cyclone configuration (CYCLONEDDS_URI): loopback only, a private domain, and the large-data settings below
unless --cyclone-defaults.

Measured the same way for all: throughput over the steady state (from the first once-a-second report after data
started to the last one before the publisher is stopped, counted by the subscriber); CPU of each process over that
same window, from psutil (1.00 = one core busy). Latency (receive time minus the sample's source stamp) comes from
camera_sub (its --stats records: one a second and the totals); ddsperf's pub/sub mode does not measure it. Lost samples
are our gaps and ddsperf's "lost"; camera_sub compares every byte of every frame with the publisher's pattern
(mismatches).

Then the shared-memory pair runs at 30 frames/s (4 MiB frames), for the latency of a camera-like stream.

Prints one table and writes a PNG chart of throughput against size. The last lines are machine-readable:
`ratio_4MiB=<ours over UDP / ddsperf, MB/s at 4 MiB>`, `ratio_shm_4MiB=<ours over shared memory / ddsperf>` (the
medians of the rounds) and `shm_p99_ms_30fps=<p99 latency of the shared-memory pair at 30 frames/s, in ms>`.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from automotive.bus import stats
from automotive.bus.cli import ArgumentParser, add_domain_option, output_file
from automotive.bus.network import NetworkConfig
from automotive.tools.support.children import Child, RunFailed, StatsChild, program_command, work_folder

PROG = "automotive bench large-data"
SIZES = {"64KiB": 64 * 1024, "1MiB": 1024 * 1024, "4MiB": 4 * 1024 * 1024}
START_TIMEOUT = 90.0  # starting Python and Cyclone on a busy 2-core machine can take long
SHM_PREFIX = f"benchlarge{os.getpid()}_"  # our iceoryx2 files only; removed at the end
TOOLS = ("ours", "ours-shm", "ddsperf")


# Loopback only, no multicast; every participant on this host is found through 127.0.0.1.
def cyclone_uri(defaults: bool, buffer: str, fragment: int, c_tool: bool = False) -> str:
    """The same loopback configuration for both tools: the runtime's own, with or without its large-data settings
    (for the C tool without what its older Cyclone does not know; two processes find each other at once, so
    probing forever does not matter here)."""
    return NetworkConfig(large_data=not defaults, fragment_size=fragment, socket_buffer=buffer,
                         cyclone_0_10=c_tool).cyclone_xml()


def _wait_line(proc: Child, pattern: str, timeout: float) -> None:
    try:
        proc.wait_for(pattern, timeout)
    except AssertionError as error:
        raise RunFailed(str(error)) from None


@dataclass
class Result:
    tool: str
    size: int
    samples_per_s: float = float("nan")
    mb_per_s: float = float("nan")
    p50_ms: float | None = None
    p99_ms: float | None = None
    cpu_pub: float = float("nan")
    cpu_sub: float = float("nan")
    lost: int | None = None
    mismatches: int | None = None
    note: str = ""
    extra: dict[str, str] = field(default_factory=dict)


def steady_rate(points: list[tuple[float, int]], start: float, end: float) -> float:
    """Samples per second between the first and the last cumulative count reported within [start, end]."""
    inside = [(t, count) for t, count in points if start <= t <= end]
    if len(inside) < 2 or inside[-1][0] <= inside[0][0]:
        return float("nan")
    return (inside[-1][1] - inside[0][1]) / (inside[-1][0] - inside[0][0])


def measure_window(pub: Child, sub: Child, duration: float) -> tuple[float, float, float, float]:
    """Sleep through the measured window (the benchmark's fixed duration); return it and each process's CPU use."""
    cpu_pub, cpu_sub, start = pub.cpu_seconds(), sub.cpu_seconds(), time.monotonic()
    time.sleep(duration)
    end = time.monotonic()
    elapsed = end - start
    return start, end, (pub.cpu_seconds() - cpu_pub) / elapsed, (sub.cpu_seconds() - cpu_sub) / elapsed


def run_ours(size_name: str, duration: float, domain: int, env: dict[str, str], qos_file: Path | None,
             workdir: Path, shared_memory: bool = False, interval_ms: float = 0,
             launcher: list[str] | None = None) -> Result:
    size = SIZES[size_name]
    result = Result("ours-shm" if shared_memory else "ours", size)
    common = ["--domain", str(domain), "-D", f"config.imageSize={size_name}"]
    if qos_file is not None:
        common += ["-D", f"qos.File={qos_file.resolve()}"]
    # "ours" is the pair over UDP: shared memory is the default on one host, so it is turned off by name
    common += ["-D", f"config.transport={'shm' if shared_memory else 'udp'}", "-D", f"config.shmPrefix={SHM_PREFIX}"]
    handle, name = tempfile.mkstemp(prefix="camera_sub-", suffix=".jsonl", dir=workdir)
    os.close(handle)  # camera_sub writes it: only its name is needed here
    figures = Path(name)
    sub = Child("camera_sub", program_command("camera_sub", *common, "--exit-with-publisher", "--stats",
                                              str(figures), python=launcher or ()), env=env)
    pub: Child | None = None
    try:
        _wait_line(sub, "viewing", START_TIMEOUT)
        pub = Child("camera_pub", program_command("camera_pub", *common, "-D", f"config.pubInterval={interval_ms:g}",
                                                  python=launcher or ()), env=env)
        # the first once-a-second report: data flows
        StatsChild(sub, figures).wait_record("window", START_TIMEOUT)
        start, end, result.cpu_pub, result.cpu_sub = measure_window(pub, sub, duration)
        pub.stop(signal.SIGINT, timeout=30)
        _wait(sub, 60)  # camera_sub stops by itself once the publisher has left
        sub.stop(signal.SIGINT, timeout=30)
    except RunFailed as error:
        return _failed(result, error, pub, sub)
    finally:
        _stop_left(pub, sub)  # on the way out of the run (Ctrl-C, SIGTERM), before their folder is removed
    # The windows' records carry the wall clock: measure_window's monotonic window, shifted onto it.
    shift = time.time() - time.monotonic()
    points, total = [], 0
    for record in stats.read(figures, "window"):
        total += int(record["samples"])
        points.append((float(record["t"]) - shift, total))
    result.samples_per_s = steady_rate(points, start, end)
    result.mb_per_s = result.samples_per_s * size / 1e6
    totals = next(stats.read(figures, "totals"), None)
    if totals is None:
        result.note = "camera_sub wrote no totals"
        return result
    result.p50_ms = totals["latency_ms"]["p50"]
    result.p99_ms = totals["latency_ms"]["p99"]
    result.lost = int(totals["gaps"])
    result.mismatches = int(totals["mismatches"])
    return result


def _failed(result: Result, error: RunFailed, *procs: Child | None) -> Result:
    """A run that did not get to its measurement: the reason noted in its result, its programs stopped."""
    result.note = str(error).splitlines()[0]
    for proc in procs:
        if proc is not None:
            proc.stop(signal.SIGTERM)
    return result


def _stop_left(*procs: Child | None) -> None:
    """Stop what still runs (nothing, when the run went its way)."""
    for proc in procs:
        if proc is not None and proc.poll() is None:
            proc.stop(signal.SIGTERM)


def _wait(proc: Child, timeout: float) -> bool:
    try:
        proc.process.wait(timeout=timeout)
        return True
    except subprocess.TimeoutExpired:
        return False


DDSPERF_LINE = re.compile(r"size (\d+) total (\d+) lost (\d+) delta (\d+)")


def run_ddsperf(size_name: str, duration: float, domain: int, env: dict[str, str], ddsperf: str) -> Result:
    size = SIZES[size_name]
    result = Result("ddsperf", size)
    # stdbuf: ddsperf's stdio is block-buffered on a pipe; each line must arrive when it is printed.
    prefix = ["stdbuf", "-oL"] if shutil.which("stdbuf") else []
    common = [ddsperf, "-i", str(domain), "-k", "all"]
    sub = Child("ddsperf sub", [*prefix, *common, "sub"], env=env)
    pub: Child | None = None
    try:
        _wait_line(sub, "participant .*: new", START_TIMEOUT)
        pub = Child("ddsperf pub", [*prefix, *common, "pub", "size", str(size)], env=env)
        _wait_line(sub, r"size \d+ total [1-9]", START_TIMEOUT)
        start, end, result.cpu_pub, result.cpu_sub = measure_window(pub, sub, duration)
        pub.stop(signal.SIGINT, timeout=30)
        _wait_line(sub, r"participant .*: gone", 30)
        sub.stop(signal.SIGINT, timeout=30)
    except RunFailed as error:
        return _failed(result, error, pub, sub)
    finally:
        _stop_left(pub, sub)
    points, lost = [], 0
    for line in list(sub.records):
        arrived = line.time
        match = DDSPERF_LINE.search(line.text)
        if match and int(match.group(1)) >= size:
            points.append((arrived, int(match.group(2))))
            lost = int(match.group(3))
    result.samples_per_s = steady_rate(points, start, end)
    result.mb_per_s = result.samples_per_s * size / 1e6
    result.lost = lost
    return result


def ensure_ddsperf() -> str:
    found = shutil.which("ddsperf")
    if found:
        return found
    print("ddsperf not found: installing Debian's cyclonedds-tools with apt-get", flush=True)
    install = ["apt-get", "install", "-y", "--no-install-recommends", "cyclonedds-tools"]
    if subprocess.run(install).returncode != 0:
        subprocess.run(["apt-get", "update"], check=False)
        subprocess.run(install, check=True)
    found = shutil.which("ddsperf")
    if not found:
        sys.exit(f"{PROG}: cyclonedds-tools installed, but no ddsperf on PATH")
    return found


def fmt(value: float | None, digits: int = 1) -> str:
    if value is None or value != value:  # None or NaN
        return "-"
    return f"{value:.{digits}f}"


def median(values: list[float]) -> float:
    values = [v for v in values if v == v]
    return statistics.median(values) if values else float("nan")


def summarise(results: list[Result], sizes: list[str]) -> tuple[list[str], dict[tuple[str, str], float]]:
    """The table's rows, and (tool, size) -> median MB/s of that tool / median MB/s of ddsperf."""
    rows = [f"{'size':>6} {'tool':<10} {'samples/s':>10} {'MB/s':>8} {'lat p50 ms':>10} {'lat p99 ms':>10} "
            f"{'CPU pub':>7} {'CPU sub':>7} {'lost':>5} {'mism.':>5} {'/ ddsperf':>9}"]
    ratios: dict[tuple[str, str], float] = {}
    for name in sizes:
        size = SIZES[name]
        reference = median([r.mb_per_s for r in results if r.size == size and r.tool == "ddsperf"])
        for tool in TOOLS:
            runs = [r for r in results if r.size == size and r.tool == tool]
            if not runs:
                continue
            mb = median([r.mb_per_s for r in runs])
            lost = sum(r.lost for r in runs if r.lost is not None) if any(r.lost is not None for r in runs) else None
            mismatches = (sum(r.mismatches for r in runs if r.mismatches is not None)
                          if any(r.mismatches is not None for r in runs) else None)
            p50 = median([r.p50_ms for r in runs if r.p50_ms is not None])
            p99 = median([r.p99_ms for r in runs if r.p99_ms is not None])
            ratio = ""
            if tool != "ddsperf":
                ratios[(tool, name)] = mb / reference if reference == reference and reference > 0 else float("nan")
                ratio = fmt(ratios[(tool, name)], 2)
            lost_text = "-" if lost is None else str(lost)
            mismatch_text = "-" if mismatches is None else str(mismatches)
            rows.append(f"{name:>6} {tool:<10} {fmt(median([r.samples_per_s for r in runs])):>10} {fmt(mb):>8} "
                        f"{fmt(p50, 2):>10} {fmt(p99, 2):>10} {fmt(median([r.cpu_pub for r in runs]), 2):>7} "
                        f"{fmt(median([r.cpu_sub for r in runs]), 2):>7} {lost_text:>5} {mismatch_text:>5} {ratio:>9}")
    return rows, ratios


def write_chart(path: Path, results: list[Result], sizes: list[str], title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(7, 4.5))
    for tool, marker in (("ours", "o"), ("ours-shm", "^"), ("ddsperf", "s")):
        xs, ys = [], []
        for name in sizes:
            mb = median([r.mb_per_s for r in results if r.tool == tool and r.size == SIZES[name]])
            if mb == mb:
                xs.append(SIZES[name])
                ys.append(mb)
        label = {"ours": "camera_pub/camera_sub (Python), UDP", "ours-shm": "camera_pub/camera_sub (Python), SHM",
                 "ddsperf": "ddsperf (C), UDP"}[tool]
        axes.plot(xs, ys, marker=marker, label=label)
    axes.set_xscale("log", base=2)
    axes.set_xticks([SIZES[name] for name in sizes], sizes)
    axes.set_xlabel("sample size")
    axes.set_ylabel("throughput (MB/s)")
    axes.set_ylim(bottom=0)
    axes.set_title(title, fontsize=10)
    axes.grid(True, alpha=0.3)
    axes.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--sizes", default="64KiB,1MiB,4MiB", help=f"comma-separated, of {', '.join(SIZES)}")
    parser.add_argument("--duration", type=float, default=5.0, help="measured seconds per run (default 5)")
    parser.add_argument("--rounds", type=int, default=1, help="runs of each tool per size; the median is shown")
    add_domain_option(parser, 75, "DDS domain id of the runs")
    parser.add_argument("--chart", type=output_file, default="bench-large-data.png", help="PNG chart to write")
    parser.add_argument("--socket-buffer", default="4MiB",
                        help="largest socket buffers to ask for (the kernel caps them at net.core.rmem_max)")
    parser.add_argument("--fragment-size", type=int, default=62000,
                        help="Cyclone's FragmentSize in bytes (datagrams of up to 1500 bytes more, at most 65500)")
    parser.add_argument("--qos-file", type=Path, default=None,
                        help="another QoS file for our camera pair (profile AutomotiveLibrary::Camera)")
    parser.add_argument("--cyclone-defaults", action="store_true",
                        help="Cyclone's default fragment and socket buffer sizes (loopback only) for both tools")
    parser.add_argument("--latency-seconds", type=float, default=10.0,
                        help="seconds of the shared-memory run at 30 frames/s (default 10)")
    parser.add_argument("--realtime", action="store_true",
                        help="run the 30 frames/s pair with real-time scheduling (chrt --fifo 10; needs the right)")
    args = parser.parse_args(argv)
    sizes = [name.strip() for name in args.sizes.split(",") if name.strip()]
    unknown = [name for name in sizes if name not in SIZES]
    if unknown or args.duration <= 0 or args.rounds < 1 or not 1024 <= args.fragment_size <= 64000:
        parser.error(f"sizes must be among {', '.join(SIZES)}; duration and rounds positive; "
                     "fragment size 1024..64000")
    ddsperf = ensure_ddsperf()
    env = dict(os.environ, CYCLONEDDS_URI=cyclone_uri(args.cyclone_defaults, args.socket_buffer, args.fragment_size))
    c_env = dict(env, CYCLONEDDS_URI=cyclone_uri(args.cyclone_defaults, args.socket_buffer, args.fragment_size,
                                                 c_tool=True))
    config = ("Cyclone defaults" if args.cyclone_defaults
              else f"{args.fragment_size}-byte fragments, socket buffers <= {args.socket_buffer}")
    print(f"loopback, reliable keep-all, {args.duration:g} s per run, {args.rounds} round(s), {config}", flush=True)
    # camera_sub's status records in a temporary folder, and iceoryx2's files of this run: removed at the end, also
    # on an error, Ctrl-C or SIGTERM (which ends the run as Ctrl-C does, the pairs stopped first).
    try:
        with work_folder("bench-large-data-") as workdir:
            results, camera_rate = measure(args, sizes, ddsperf, env, c_env, workdir)
    finally:
        remove_shared_memory_files()
    report(args, results, camera_rate, sizes, config)
    return 0


def measure(args: argparse.Namespace, sizes: list[str], ddsperf: str, env: dict[str, str], c_env: dict[str, str],
            workdir: Path) -> tuple[list[Result], Result]:
    """Every round of every size and tool, then the shared-memory pair at 30 frames/s."""
    results: list[Result] = []
    for round_number in range(1, args.rounds + 1):
        for name in sizes:
            for tool in TOOLS if round_number % 2 else tuple(reversed(TOOLS)):
                if tool == "ddsperf":
                    result = run_ddsperf(name, args.duration, args.domain, c_env, ddsperf)
                else:
                    result = run_ours(name, args.duration, args.domain, env, args.qos_file, workdir, tool == "ours-shm")
                results.append(result)
                print(f"  round {round_number} {name:>5} {tool:<8} {fmt(result.mb_per_s):>8} MB/s "
                      f"CPU pub {fmt(result.cpu_pub, 2)} sub {fmt(result.cpu_sub, 2)} "
                      f"lost {result.lost if result.lost is not None else '-'}"
                      f"{'  ' + result.note if result.note else ''}", flush=True)

    scheduling = "SCHED_FIFO 10" if args.realtime else "default scheduling"
    print(f"  shared memory, 4MiB frames at 30 frames/s for {args.latency_seconds:g} s, {scheduling}", flush=True)
    camera_rate = run_ours("4MiB", args.latency_seconds, args.domain, env, args.qos_file, workdir, True, 1000 / 30,
                           ["chrt", "--fifo", "10"] if args.realtime else None)
    return results, camera_rate


def report(args: argparse.Namespace, results: list[Result], camera_rate: Result, sizes: list[str],
           config: str) -> None:
    """The table, the chart and the last lines."""
    scheduling = "SCHED_FIFO 10" if args.realtime else "default scheduling"
    rows, ratios = summarise(results, sizes)
    print()
    print("\n".join(rows))
    print(f"\nshared memory at 30 frames/s, 4MiB, {scheduling}: latency p50 {fmt(camera_rate.p50_ms, 3)} ms, "
          f"p99 {fmt(camera_rate.p99_ms, 3)} ms, lost {camera_rate.lost}, mismatches {camera_rate.mismatches}"
          f"{'  ' + camera_rate.note if camera_rate.note else ''}")
    write_chart(args.chart, results, sizes, f"One host, reliable keep-all, as fast as possible\n({config})")
    print(f"chart: {args.chart}")
    print(f"ratio_4MiB={ratios.get(('ours', '4MiB'), float('nan')):.3f}")
    print(f"ratio_shm_4MiB={ratios.get(('ours-shm', '4MiB'), float('nan')):.3f}")
    p99 = camera_rate.p99_ms if camera_rate.p99_ms is not None else float("nan")
    print(f"shm_p99_ms_30fps={p99:.3f}")


def remove_shared_memory_files() -> None:
    """What iceoryx2 keeps under this run's own prefix once the pairs stopped (its one global file per prefix)."""
    for folder in (Path("/dev/shm"), Path("/tmp/iceoryx2")):
        if folder.is_dir():
            for path in folder.rglob(f"{SHM_PREFIX}*"):
                if not path.is_dir():  # files and event sockets
                    path.unlink(missing_ok=True)


if __name__ == "__main__":
    sys.exit(main())
