#!/usr/bin/env python3
"""Record the whole running system for a minute and say what the recorder kept, lost and cost.

    scripts/bench-record [--seconds 60] [--domain 86] [--compression none|lz4|zstd] [--keep FILE]

Starts automotive.tools.record, then every application of the system on a private domain, loopback only: vision, lidar
(a log line per frame), sensor_fusion, collision_avoidance, vehicle_platform, hmi (console), camera_pub at 30 frames/s
of 4 MiB (it waits for its two readers: camera_sub and the recorder) with camera_sub, and a Shapes Demo circle. After
--seconds the producers are stopped, then the recorder (Ctrl-C: it finishes its file).

Per topic: samples published (the producer's own numbered log lines, counted from the moment the recorder matched
that producer; "-" where the producer does not number what it writes), samples recorded, MB and MB/s; then the
recorder's CPU (1.00 = one core busy), the file size, the compression ratio (message bytes / file bytes) and
MB/s written.
Lost samples on reliable flows (LiDAR, camera, alerts), each counted once: the camera frames missing from the file
(their seqnums must run without a gap), the LiDAR clouds published after the match but not recorded (less one: the
first frame logged after the match may have been written before it), and the alerts
the recorder counted as lost (its queue was full, or DDS reported samples lost). The last line is
`record_lost=<samples lost on reliable flows> record_MBps=<MB/s written to the file>`.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from datetime import datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from automotive.bus.cli import ArgumentParser, run_in_project_venv  # noqa: E402

run_in_project_venv(__file__, sys.argv[1:])  # Cyclone DDS, mcap and the applications' dependencies are in .venv

TICKS = os.sysconf("SC_CLK_TCK")
START_TIMEOUT = 120.0  # ten Python processes starting on a busy 2-core machine

# The producers, and the log line each prints per sample written (its number in group 1) with the topic written.
PRODUCERS: dict[str, tuple[list[str], str | None, str]] = {
    "vision": ([], r"published sample (\d+)", "VisionTopic"),
    "lidar": (["-D", "config.logEvery=1"], r"frame (\d+):", "rt/LidarTopic"),
    "vehicle_platform": ([], r"status (\d+):", "PlatformStatus"),
    "shapes": (["publish", "--color", "RED"], None, "Circle"),  # logs one sample in many
    "camera_pub": (["-D", "config.waitSubscribers=2"], None, "CameraImageData"),
}
REACTIVE: dict[str, tuple[list[str], str | None, str]] = {
    "sensor_fusion": ([], r"published list (\d+)", "SensorObjects"),
    "collision_avoidance": ([], r"command (\d+):", "PlatformControl"),
}
CONSUMERS = {"hmi": ["--ui", "console"], "camera_sub": []}


class Proc:
    """A child process whose output lines are kept as they arrive."""

    def __init__(self, name: str, command: list[str]):
        self.name = name
        self.popen = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                      bufsize=1, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self.lines: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.popen.stdout is not None
        for line in self.popen.stdout:
            self.lines.append(line.rstrip("\n"))

    def wait_for(self, pattern: str, timeout: float = START_TIMEOUT) -> str:
        regex = re.compile(pattern)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for line in list(self.lines):
                if regex.search(line):
                    return line
            if self.popen.poll() is not None:
                break
            time.sleep(0.1)
        raise RuntimeError(f"{self.name}: no /{pattern}/ within {timeout:.0f} s; last output:\n"
                           + "\n".join(self.lines[-10:]))

    def cpu_seconds(self) -> float:
        fields = Path(f"/proc/{self.popen.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / TICKS

    def stop(self, timeout: float = 30.0) -> None:
        if self.popen.poll() is None:
            self.popen.send_signal(signal.SIGINT)
            try:
                self.popen.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait()


def stamp(line: str) -> float:
    """Seconds of the day of an application log line (HH:MM:SS.mmm at its start)."""
    clock = datetime.strptime(line[:12], "%H:%M:%S.%f")
    return clock.hour * 3600 + clock.minute * 60 + clock.second + clock.microsecond / 1e6


def published_after(proc: Proc, pattern: str, since: float) -> int:
    """Samples a producer logged as written after ``since`` (seconds of the day)."""
    regex = re.compile(pattern)
    return sum(1 for line in list(proc.lines) if regex.search(line) and stamp(line) > since)


def file_checks(path: Path) -> tuple[int, int]:
    """(camera frames missing between the first and last recorded seqnum, camera frames recorded)."""
    from mcap.reader import make_reader

    from automotive.types.CameraImage import CameraImageData
    from automotive.wire.camera import FrameCodec

    codec = FrameCodec(CameraImageData)
    seqnums = []
    with open(path, "rb") as stream:
        for _, _, message in make_reader(stream).iter_messages(topics=["CameraImageData"], log_time_order=False):
            seqnums.append(codec.decode(message.data).seqnum)
    if not seqnums:
        return 0, 0
    return (max(seqnums) - min(seqnums) + 1) - len(set(seqnums)), len(seqnums)


def main() -> int:
    parser = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=60.0, help="how long the system is recorded (default 60)")
    parser.add_argument("--domain", type=int, default=86, help="DDS domain id (default 86)")
    parser.add_argument("--compression", choices=["lz4", "zstd", "none"], default="none")
    parser.add_argument("--keep", type=Path, default=None, help="keep the recording in this file")
    args = parser.parse_args()
    os.environ.pop("CYCLONEDDS_URI", None)  # the applications' own loopback configuration (camera: large data)
    workdir = Path(tempfile.mkdtemp(prefix="bench-record-"))
    output = args.keep or workdir / "system.mcap"
    domain = ["--domain", str(args.domain)]

    def app(name: str, extra: list[str]) -> Proc:
        return Proc(name, [sys.executable, "-m", f"apps.{name}", *domain, *extra])

    recorder = app("record", ["--output", str(output), "--overwrite", "-D", f"config.compression={args.compression}"])
    processes: dict[str, Proc] = {}
    try:
        recorder.wait_for(r"recording \d+ topic")
        for name, extra in CONSUMERS.items():
            processes[name] = app(name, extra)
        for name, (extra, _, _) in {**REACTIVE, **PRODUCERS}.items():
            processes[name] = app(name, extra)
        processes["camera_sub"].wait_for(r"samples=\d+ size=")
        print(f"system running; recording {args.seconds:g} s to {output}", flush=True)
        cpu_start, start = recorder.cpu_seconds(), time.monotonic()
        next_status = start + 10
        while time.monotonic() - start < args.seconds:
            time.sleep(0.5)
            if time.monotonic() >= next_status:
                status = [line for line in recorder.lines if "recorded=" in line]
                print(f"  {time.monotonic() - start:4.0f} s: {status[-1].split(': ', 1)[-1] if status else '-'}",
                      flush=True)
                next_status += 10
        for name in [*PRODUCERS, *REACTIVE, *CONSUMERS]:
            processes[name].stop()
        cpu = (recorder.cpu_seconds() - cpu_start) / (time.monotonic() - start)
        elapsed = time.monotonic() - start
        recorder.stop(timeout=120)
    finally:
        for proc in [*processes.values(), recorder]:
            proc.stop()

    pattern = r"summary (\S+): messages=(\d+) changes=\d+ MB=([\d.]+) lost=(\d+) dds_lost=(\d+)"
    summary = {m.group(1): (int(m.group(2)), float(m.group(3)), int(m.group(4)), int(m.group(5)))
               for m in (re.search(pattern, line) for line in recorder.lines) if m}
    if not summary:
        print("the recorder printed no summary:\n" + "\n".join(recorder.lines[-20:]))
        return 1
    matched = {m.group(2): stamp(m.group(0)) for m in (
        re.search(r"^(\S+) record: \[(\S+)\] reader matched a writer", line) for line in recorder.lines) if m}
    published: dict[str, int | None] = {}
    for name, (_, pattern, topic) in {**PRODUCERS, **REACTIVE}.items():
        if pattern is None:
            total = re.findall(r"published (\d+) frames in total", "\n".join(processes[name].lines))
            published[topic] = int(total[-1]) if total and name == "camera_pub" else None
        elif topic in matched:
            published[topic] = published_after(processes[name], pattern, matched[topic] + 0.005)
        else:
            published[topic] = None
    camera_gaps, camera_recorded = file_checks(output)
    size = output.stat().st_size
    message_bytes = sum(mb for _, mb, _, _ in summary.values()) * 1e6

    print(f"{'topic':<18} {'published':>9} {'recorded':>9} {'MB':>9} {'MB/s':>7} {'lost':>5} {'dds lost':>8}")
    # Each loss counted once: the camera's by the gaps in the file, the LiDAR's by what was published and not
    # recorded (both include what the recorder's queue refused), the alerts' by the recorder's own counts.
    lost = camera_gaps
    for topic, (messages, mb, queue_lost, dds_lost) in summary.items():
        sent = published.get(topic)
        print(f"{topic:<18} {'-' if sent is None else sent:>9} {messages:>9} {mb:>9.1f} {mb / elapsed:>7.2f} "
              f"{queue_lost:>5} {dds_lost:>8}")
        if topic == "rt/LidarTopic":  # the first frame logged after the match may have been written before it
            lost += max(0, sent - 1 - messages) if sent is not None else queue_lost + dds_lost
        elif topic == "AlertTopic":
            lost += queue_lost + dds_lost
    print(f"camera frames recorded {camera_recorded}, missing seqnums in the file {camera_gaps}")
    mbps = size / 1e6 / elapsed
    print(f"recorder CPU {cpu:.2f}, file {size / 1e6:.1f} MB in {elapsed:.1f} s, compression {args.compression} "
          f"ratio {message_bytes / size if size else 0:.2f}")
    if args.keep is None:
        shutil.rmtree(workdir)  # a minute of the system is about 8 GB
    print(f"record_lost={lost} record_MBps={mbps:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
