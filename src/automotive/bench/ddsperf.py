"""Cyclone's C tool, ddsperf, as the benchmarks' reference: what the same flow costs without Python."""

from __future__ import annotations

import math
import os
import re
import shutil
import statistics
import time
from dataclasses import dataclass

from automotive.tools.support.children import Child, stop_all, thread_cpu_by_name

# ddsperf 0.10 (Debian's) does not know every element of our NetworkConfig's XML: a plain loopback configuration.
DDSPERF_URI = ('<General><Interfaces><NetworkInterface name="lo"/></Interfaces><AllowMulticast>false</AllowMulticast>'
               '</General><Discovery><ParticipantIndex>auto</ParticipantIndex><Peers><Peer address="127.0.0.1"/>'
               '</Peers></Discovery>')
SETTLE_S = 2.0  # discovery and the first samples, left out of the window
# ddsperf's lines: "... size 300 mean 157.210us min 47.028us 50% 77.071us 90% 214.794us 99% 1872.328us max ..."
DDSPERF_LINE = re.compile(r"size (\d+) mean [\d.]+us min [\d.]+us 50% ([\d.]+)us 90% [\d.]+us 99% ([\d.]+)us "
                          r"max ([\d.]+)us cnt (\d+)")


@dataclass(frozen=True)
class OneWay:
    """ddsperf's one-way latency (round trip / 2, ms) and what its ping and pong cost (% of one core, together)."""

    p50_ms: float
    p99_ms: float
    max_ms: float
    cpu_pct: float | None  # None: the run was too short to measure it apart from discovery


def ddsperf_one_way(size: int, seconds: int, domain: int, rate_hz: int,
                    prefix: list[str] | None = None) -> OneWay | None:
    """C one-way latency at ``size`` bytes, ``rate_hz`` round trips a second (ddsperf's round trip / 2), and the CPU of
    both ddsperf processes after discovery; None without ddsperf or when it gave no figure. ``prefix``: what runs
    both ddsperf processes (``chrt --fifo 10``)."""
    ddsperf = shutil.which("ddsperf")
    if ddsperf is None:
        return None
    env = dict(os.environ, CYCLONEDDS_URI=DDSPERF_URI)
    prefix = prefix or []
    pong = Child("ddsperf-pong", [*prefix, ddsperf, "-i", str(domain), "-D", str(seconds + 5), "pong", "waitset"],
                 env=env)
    ping = Child("ddsperf-ping", [*prefix, ddsperf, "-X", "-i", str(domain), "-D", str(seconds + 1), "ping",
                                  f"{rate_hz}Hz", "size", str(size), "waitset"], env=env)
    cpu_pct = None
    try:
        window_s = seconds - SETTLE_S - 1  # ping ends after ``seconds`` + 1: measured inside, after discovery
        if window_s >= 1:
            time.sleep(SETTLE_S)
            before, start = ping.cpu_seconds() + pong.cpu_seconds(), time.monotonic()
            time.sleep(window_s)
            used = ping.cpu_seconds() + pong.cpu_seconds() - before
            if not math.isnan(used):  # NaN: one of them ended early
                cpu_pct = 100 * used / (time.monotonic() - start)
        ping.wait_exit(timeout=seconds + 30)
    finally:
        stop_all([ping, pong], timeout=5)
    rows = [match for line in ping.lines if (match := DDSPERF_LINE.search(line)) and int(match[5]) > 0]
    if not rows:
        return None
    p50 = statistics.median(float(row[2]) for row in rows)
    p99 = statistics.median(float(row[3]) for row in rows)
    worst = max(float(row[4]) for row in rows)
    return OneWay(p50 / 2000, p99 / 2000, worst / 2000, cpu_pct)


def subscriber_cpu(size: int, rate_hz: int, seconds: float, domain: int) -> dict[str, float] | None:
    """CPU of ``ddsperf sub`` (WaitSet, as the applications take) per sample, in microseconds by thread name, while
    ``ddsperf pub`` writes ``rate_hz`` samples a second of ``size`` bytes over loopback; None without ddsperf."""
    ddsperf = shutil.which("ddsperf")
    if ddsperf is None:
        return None
    env = dict(os.environ, CYCLONEDDS_URI=DDSPERF_URI)
    duration = str(round(SETTLE_S + seconds + 5))
    sub = Child("ddsperf-sub", [ddsperf, "-i", str(domain), "-D", duration, "sub", "waitset"], env=env)
    pub = Child("ddsperf-pub", [ddsperf, "-i", str(domain), "-D", duration, "pub", f"{rate_hz}Hz", "size",
                                str(size)], env=env)
    try:
        time.sleep(SETTLE_S)  # discovery: ddsperf prints nothing to wait on before its first second of figures
        before = thread_cpu_by_name([sub.pid])
        time.sleep(seconds)  # the measuring window
        after = thread_cpu_by_name([sub.pid])
    finally:
        stop_all([pub, sub], timeout=5)
    samples = rate_hz * seconds
    return {name: 1e6 * (after.get(name, 0.0) - used) / samples for name, used in before.items()}
