"""Record the whole running system for a minute and say what the recorder kept, lost and cost.

    automotive bench record [--seconds 60] [--domain 86] [--compression none|lz4|zstd] [--keep FILE]

Starts automotive.tools.record.record, then every application of the system on a private domain, loopback only: vision,
lidar (a log line per frame), sensor_fusion, collision_avoidance, vehicle_platform, hmi (console), camera_pub at 30
frames/s of 4 MiB (it waits for its two readers: camera_sub and the recorder) with camera_sub, and a Shapes Demo circle.
After --seconds the producers are stopped, then the recorder (Ctrl-C: it finishes its file).

Per topic: samples published (the producer's own numbered status records, --stats, counted from the moment the
recorder matched that producer; "-" where the producer does not number what it writes), samples recorded, MB and MB/s;
then the recorder's CPU (1.00 = one core busy), the file size, the compression ratio (message bytes / file bytes;
with --compression lz4 or zstd) and MB/s written.
Lost samples on reliable flows (LiDAR, camera, alerts), each counted once: the camera frames missing from the file
(their seqnums must run without a gap), the LiDAR clouds published after the match but not recorded (less one: the
first frame logged after the match may have been written before it), and the alerts
the recorder counted as lost (its queue was full, or DDS reported samples lost). The last line is
`record_lost=<samples lost on reliable flows> record_MBps=<MB/s written to the file>`.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from automotive.bus.cli import ArgumentParser, add_domain_option, output_file
from automotive.tools.support.children import StatsChild, work_folder

PROG = "automotive bench record"
START_TIMEOUT = 120.0  # ten Python processes starting on a busy 2-core machine

# The producers, and the status record each writes per sample written (kind) with the topic written.
PRODUCERS: dict[str, tuple[list[str], str | None, str]] = {
    "vision": ([], "sample", "VisionTopic"),
    "lidar": ([], "frame", "rt/LidarTopic"),
    "vehicle_platform": ([], "status", "PlatformStatus"),
    "shapes": (["publish", "--color", "RED"], None, "Circle"),  # does not number its samples
    "camera_pub": (["-D", "config.waitSubscribers=2"], None, "CameraImageData"),
}
REACTIVE: dict[str, tuple[list[str], str | None, str]] = {
    "sensor_fusion": ([], "list", "SensorObjects"),
    "collision_avoidance": ([], "command", "PlatformControl"),
}
CONSUMERS = {"hmi": ["--ui", "console"], "camera_sub": []}


def start_program(name: str, extra: list[str], domain: int, workdir: Path) -> StatsChild:
    """A program of the system with its status records (--stats) in ``workdir``."""
    return StatsChild.start(name, name, ["--domain", str(domain), *extra], workdir / f"{name}.jsonl")


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


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=60.0, help="how long the system is recorded (default 60)")
    add_domain_option(parser, 86, "DDS domain id")
    parser.add_argument("--compression", choices=["lz4", "zstd", "none"], default="none")
    parser.add_argument("--keep", type=output_file, default=None, help="keep the recording in this file")
    args = parser.parse_args(argv)
    os.environ.pop("CYCLONEDDS_URI", None)  # the applications' own loopback configuration (camera: large data)
    # The status records, and the recording unless --keep: a minute of the system is about 8 GB. Removed at the end,
    # also on an error, Ctrl-C or SIGTERM (which ends the run as Ctrl-C does, the programs stopped first).
    with work_folder("bench-record-") as workdir:
        return run(args, workdir)


def run(args: argparse.Namespace, workdir: Path) -> int:
    output = args.keep or workdir / "system.mcap"

    recorder = start_program("record", ["--output", str(output), "--overwrite",
                                        "-D", f"config.compression={args.compression}"], args.domain, workdir)
    processes: dict[str, StatsChild] = {}
    try:
        recorder.wait_record("ready", START_TIMEOUT)
        for name, extra in CONSUMERS.items():
            processes[name] = start_program(name, extra, args.domain, workdir)
        for name, (extra, _, _) in {**REACTIVE, **PRODUCERS}.items():
            processes[name] = start_program(name, extra, args.domain, workdir)
        processes["camera_sub"].wait_record("window", START_TIMEOUT)
        print(f"system running; recording {args.seconds:g} s to {output}", flush=True)
        cpu_start, start = recorder.child.cpu_seconds(), time.monotonic()
        next_status = start + 10
        while time.monotonic() - start < args.seconds:
            time.sleep(0.5)
            if time.monotonic() >= next_status:
                status = recorder.records("status")
                print(f"  {time.monotonic() - start:4.0f} s: "
                      + (f"recorded={status[-1]['recorded']} lost={status[-1]['lost']}" if status else "-"), flush=True)
                next_status += 10
        for name in [*PRODUCERS, *REACTIVE, *CONSUMERS]:
            processes[name].stop()
        cpu = (recorder.child.cpu_seconds() - cpu_start) / (time.monotonic() - start)
        elapsed = time.monotonic() - start
        recorder.stop(timeout=120)
    finally:
        for program in [*processes.values(), recorder]:
            program.stop()

    summaries = recorder.records("summary")
    if not summaries:
        print("the recorder wrote no summary:\n" + "\n".join(recorder.child.lines[-20:]))
        return 1
    topics = summaries[-1]["topics"]
    matched = {record["topic"]: float(record["t"]) for record in reversed(recorder.records("matched"))
               if record["endpoint"] == "reader" and record["change"] > 0}  # the first match of each topic
    published: dict[str, int | None] = {}
    for name, (_, kind, topic) in {**PRODUCERS, **REACTIVE}.items():
        if kind is None:
            totals = processes[name].records("totals")
            published[topic] = int(totals[-1]["published"]) if totals and name == "camera_pub" else None
        elif topic in matched:
            published[topic] = sum(1 for record in processes[name].records(kind)
                                   if record["t"] > matched[topic] + 0.005)
        else:
            published[topic] = None
    camera_gaps, camera_recorded = file_checks(output)
    size = output.stat().st_size
    message_bytes = sum(int(counts["bytes"]) for counts in topics.values())

    print(f"{'topic':<18} {'published':>9} {'recorded':>9} {'MB':>9} {'MB/s':>7} {'lost':>5} {'dds lost':>8}")
    # Each loss counted once: the camera's by the gaps in the file, the LiDAR's by what was published and not
    # recorded (both include what the recorder's queue refused), the alerts' by the recorder's own counts.
    lost = camera_gaps
    for topic, counts in topics.items():
        messages, mb = int(counts["messages"]), int(counts["bytes"]) / 1e6
        queue_lost, dds_lost = int(counts["lost"]), int(counts["dds_lost"])
        sent = published.get(topic)
        print(f"{topic:<18} {'-' if sent is None else sent:>9} {messages:>9} {mb:>9.1f} {mb / elapsed:>7.2f} "
              f"{queue_lost:>5} {dds_lost:>8}")
        if topic == "rt/LidarTopic":  # the first frame recorded after the match may have been written before it
            lost += max(0, sent - 1 - messages) if sent is not None else queue_lost + dds_lost
        elif topic == "AlertTopic":
            lost += queue_lost + dds_lost
    print(f"camera frames recorded {camera_recorded}, missing seqnums in the file {camera_gaps}")
    mbps = size / 1e6 / elapsed
    # A ratio only where there is compression: an uncompressed file's "ratio" would be MCAP's own overhead.
    compression = (f"compression {args.compression}, ratio {message_bytes / size:.2f}"
                   if args.compression != "none" and size else "uncompressed")
    print(f"recorder CPU {cpu:.2f}, file {size / 1e6:.1f} MB in {elapsed:.1f} s, {compression}")
    print(f"record_lost={lost} record_MBps={mbps:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
