"""Rear-view camera viewer: takes each frame, measures its latency, verifies every byte and counts lost frames.

Data flow:  CameraImage::CameraImageData on CameraImageData  -->  one statistics line a second (samples, size,
latency min/avg/max, MB/s, mismatches, gaps), the totals on exit, and with --plot FILE a PNG of the latencies.

Latency is the receive time minus the frame's sec_/nanosec_ stamp, both on this host's clock (publisher and
subscriber on one host, or hosts with synchronised clocks). Each image is compared with the LFSR pattern that the
publisher sent for its seqnum (automotive.sim.lfsr); a jump in seqnum counts the frames missing in between as gaps.
Frames of a publisher on this host come through shared memory (automotive.wire.shm), viewed in place and read-only,
and the publisher writes none on DDS for us; those of any other publisher come on DDS (config.transport=udp: all).
"""

from __future__ import annotations

import argparse
import sys
import time
from array import array
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cyclonedds.core import GuardCondition

from automotive.bus import console
from automotive.bus.app import Application, Waits, run
from automotive.bus.badsamples import BadSample
from automotive.bus.cli import output_file
from automotive.bus.latency import LatencyHistogram
from automotive.bus.properties import PropertyKeys
from automotive.bus.stats import Every, Stats
from automotive.sim.lfsr import FramePattern
from automotive.wire.camera import (
    Frame,
    FrameCodec,
    FrameReader,
    TakenFrames,
    frame_size,
    frame_type,
    shared_frames,
    tune_process_for_large_frames,
)
from automotive.wire.sharedflow import FlowReader

# The property keys it reads beyond the runtime's (automotive.bus.app.RUNTIME_KEYS): any other is refused at start.
PROPERTY_KEYS = PropertyKeys.of("config.imageSize", "config.transport", "config.shmPrefix", roles=["Camera"])

TAKE_LIMIT = 16  # samples per take: a burst is handled in one call without holding many frames at once


@dataclass
class Window:
    """Counters over one reporting period (or the whole run)."""

    samples: int = 0
    bytes: int = 0
    latency_sum_ns: int = 0
    latency_min_ns: int | None = None
    latency_max_ns: int | None = None
    mismatches: int = 0
    mismatched_bytes: int = 0
    gaps: int = 0

    def add(self, size: int, latency_ns: int) -> None:
        self.samples += 1
        self.bytes += size
        self.latency_sum_ns += latency_ns
        if self.latency_min_ns is None or latency_ns < self.latency_min_ns:
            self.latency_min_ns = latency_ns
        if self.latency_max_ns is None or latency_ns > self.latency_max_ns:
            self.latency_max_ns = latency_ns

    def latency_ms(self) -> str:
        if not self.samples or self.latency_min_ns is None or self.latency_max_ns is None:
            return "-/-/-"
        average = self.latency_sum_ns / self.samples
        return f"{self.latency_min_ns / 1e6:.3f}/{average / 1e6:.3f}/{self.latency_max_ns / 1e6:.3f}"


@dataclass
class CameraStats:
    """What the viewer saw: per-second windows, totals, a latency histogram of fixed size (for percentiles: a viewer
    running for hours does not grow with the frames it saw) and, only with ``keep_samples`` (the plot), every receive
    time and latency."""

    size: int
    keep_samples: bool = False
    window: Window = field(default_factory=Window)
    total: Window = field(default_factory=Window)
    every_second: Every = field(default_factory=Every)
    first_receive_ns: int | None = None
    last_receive_ns: int | None = None
    latency_histogram: LatencyHistogram = field(default_factory=LatencyHistogram)
    receive_times_ns: array[int] = field(default_factory=lambda: array("q"))
    latencies_ns: array[int] = field(default_factory=lambda: array("q"))
    last_seqnum: dict[int, int] = field(default_factory=dict)

    def received(self, frame: Frame, receive_ns: int, log: Any, pattern: FramePattern,
                 mismatch: Callable[[Frame, int], None] | None = None) -> None:
        """Count a frame; ``mismatch(frame, wrong_bytes)`` reports one that differs from the pattern (default: a log
        line)."""
        latency = receive_ns - frame.timestamp_ns
        if self.first_receive_ns is None:
            self.first_receive_ns = receive_ns
        self.last_receive_ns = receive_ns
        self.latency_histogram.record(latency)
        if self.keep_samples:
            self.receive_times_ns.append(receive_ns)
            self.latencies_ns.append(latency)
        for window in (self.window, self.total):
            window.add(len(frame.data), latency)
        if not pattern.matches(frame.seqnum, frame.data):
            wrong = pattern.mismatched_bytes(frame.seqnum, frame.data)
            if mismatch is not None:
                mismatch(frame, wrong)
            else:
                log.warning("frame %d of camera %d: %d of %d bytes differ from the pattern", frame.seqnum, frame.id,
                            wrong, self.size)
            for window in (self.window, self.total):
                window.mismatches += 1
                window.mismatched_bytes += wrong
        previous = self.last_seqnum.get(frame.id)
        if previous is not None:
            if frame.seqnum > previous + 1:
                for window in (self.window, self.total):
                    window.gaps += frame.seqnum - previous - 1
            elif frame.seqnum <= previous:
                log.info("camera %d: seqnum went back from %d to %d (publisher restarted?)", frame.id, previous,
                         frame.seqnum)
        self.last_seqnum[frame.id] = frame.seqnum

    def report_window(self, log: Any, force: bool = False, stats: Stats | None = None) -> None:
        """Log the statistics line once a second (or now, with ``force``), if frames arrived."""
        elapsed = self.every_second.due(force)
        if elapsed is None:
            return
        window = self.window
        if window.samples:
            if stats is not None:
                stats.record("window", samples=window.samples, size=self.size, seconds=round(elapsed, 6),
                             latency_ms=window.latency_ms(), mb_per_s=window.bytes / elapsed / 1e6 if elapsed else 0.0,
                             mismatches=window.mismatches, gaps=window.gaps)
            log.debug("samples=%d size=%d latency_ms(min/avg/max)=%s MB/s=%.1f mismatches=%d gaps=%d",
                     window.samples, self.size, window.latency_ms(), window.bytes / elapsed / 1e6 if elapsed else 0.0,
                     window.mismatches, window.gaps)
        self.window = Window()

    def percentile_ms(self, fraction: float) -> float | None:
        """The latency at ``fraction`` (0.5, 0.99) of the frames in ms, to 0.1 %; None before the first frame."""
        value_ns = self.latency_histogram.percentile_ns(fraction)
        low, high = self.total.latency_min_ns, self.total.latency_max_ns
        if value_ns is None or low is None or high is None:
            return None
        # The histogram's value is exact to 0.1 %; the true percentile lies between the exact extremes.
        return min(high, max(low, value_ns)) / 1e6

    def totals(self) -> dict[str, Any]:
        """The whole run's figures: what totals_line says, as numbers (None where no frame came)."""
        total = self.total
        seconds = 0.0
        if self.first_receive_ns is not None and self.last_receive_ns is not None:
            seconds = (self.last_receive_ns - self.first_receive_ns) / 1e9
        rate = (total.samples - 1) / seconds if seconds > 0 else 0.0
        percentile = self.percentile_ms
        return {"samples": total.samples, "size": self.size, "seconds": seconds, "samples_per_s": rate,
                "mb_per_s": rate * self.size / 1e6,
                "latency_ms": {"min": total.latency_min_ns / 1e6 if total.latency_min_ns is not None else None,
                               "avg": total.latency_sum_ns / total.samples / 1e6 if total.samples else None,
                               "p50": percentile(0.5), "p99": percentile(0.99),
                               "max": total.latency_max_ns / 1e6 if total.latency_max_ns is not None else None},
                "mismatches": total.mismatches, "mismatched_bytes": total.mismatched_bytes, "gaps": total.gaps}

    def totals_line(self) -> str:
        total = self.total
        seconds = 0.0
        if self.first_receive_ns is not None and self.last_receive_ns is not None:
            seconds = (self.last_receive_ns - self.first_receive_ns) / 1e9
        # N frames arriving over `seconds` are N - 1 intervals: the first frame's arrival starts the clock.
        rate = (total.samples - 1) / seconds if seconds > 0 else 0.0

        def percentile(fraction: float) -> str:
            value = self.percentile_ms(fraction)
            return "-" if value is None else f"{value:.3f}"

        average = f"{total.latency_sum_ns / total.samples / 1e6:.3f}" if total.samples else "-"
        low = f"{total.latency_min_ns / 1e6:.3f}" if total.latency_min_ns is not None else "-"
        high = f"{total.latency_max_ns / 1e6:.3f}" if total.latency_max_ns is not None else "-"
        return (f"totals: samples={total.samples} size={self.size} seconds={seconds:.3f} samples/s={rate:.1f} "
                f"MB/s={rate * self.size / 1e6:.1f} latency_ms: min={low} avg={average} p50={percentile(0.5)} "
                f"p99={percentile(0.99)} max={high} mismatches={total.mismatches} "
                f"mismatched_bytes={total.mismatched_bytes} gaps={total.gaps}")


def write_plot(path: Path, stats: CameraStats, title: str) -> None:
    """Latency over time and its histogram, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")  # no display needed
    import matplotlib.pyplot as plt

    start = stats.first_receive_ns or 0
    seconds = [(t - start) / 1e9 for t in stats.receive_times_ns]
    latencies_ms = [latency / 1e6 for latency in stats.latencies_ns]
    figure, (over_time, histogram) = plt.subplots(1, 2, figsize=(12, 4.5))
    over_time.plot(seconds, latencies_ms, ".", markersize=2)
    over_time.set_xlabel("receive time (s)")
    over_time.set_ylabel("latency (ms)")
    over_time.set_title("latency over time")
    over_time.grid(True, alpha=0.3)
    histogram.hist(latencies_ms, bins=50)
    histogram.set_xlabel("latency (ms)")
    histogram.set_ylabel("frames")
    histogram.set_title("latency histogram")
    figure.suptitle(title)
    figure.tight_layout()
    # The format named: without a suffix matplotlib would write FILE.png instead of FILE.
    figure.savefig(path, dpi=100, format=path.suffix[1:].lower() or "png")
    plt.close(figure)


def plot_file(text: str) -> Path:
    """An argparse type: --plot FILE, checked when the command line is read, before anything starts (the plot is
    written on exit, so a run of an hour must not end in a traceback): its folder takes new files, matplotlib is
    installed and writes the format the suffix names (none: PNG)."""
    path = output_file(text)
    try:
        from matplotlib.backend_bases import FigureCanvasBase
    except ImportError:
        raise argparse.ArgumentTypeError(f"{text}: needs matplotlib (pip install matplotlib)") from None
    formats = FigureCanvasBase.get_supported_filetypes()
    suffix = path.suffix[1:].lower()
    if suffix and suffix not in formats:
        raise argparse.ArgumentTypeError(f"{text}: matplotlib writes no '.{suffix}' files (it writes "
                                         f"{', '.join(sorted(formats))})")
    return path


def body(app: Application) -> None:
    data_type = frame_type(app.props.get_str("config.imageSize", "full"), f"{app.props.source}: config.imageSize")
    size = frame_size(data_type)
    plot_path: Path | None = app.args.plot
    exit_with_publisher: bool = app.args.exit_with_publisher
    publisher_left = GuardCondition(app.bus.participant)
    writers_seen = 0

    def on_event(event: str, topic: str, status: Any) -> None:
        nonlocal writers_seen
        if event == "subscription_matched":
            writers_seen = max(writers_seen, status.current_count)
            if status.current_count == 0 and writers_seen and exit_with_publisher:
                publisher_left.set(True)

    flow = FlowReader.of_role(app, "Camera", data_type, "CameraImageData", hook=on_event)
    try:
        frames = FrameReader(flow.reader, dropped=flow.from_shared)
        stats = CameraStats(size, keep_samples=plot_path is not None)
        # Frames come through shared memory from a camera on this host: its wake-up is the frames' own (DDS brings
        # those of other hosts, and the publishers' leaving, through a thread of its own).
        waitset = flow.shared_first_waitset()
        waitset.attach(publisher_left)
        tune_process_for_large_frames()
        app.log.info("viewing %s frames of %d bytes%s%s", data_type.__name__, size,
                     f" (shared memory with publishers on this host, keeping the last {flow.depth}; DDS with the "
                     "others)" if flow.shared else "", ", until the publisher leaves" if exit_with_publisher else "")
        sources: list[FrameSource] = [SharedFrames(flow, frames.codec), frames]
        show(app, sources, dds_wake_ups(app, waitset, publisher_left, flow), FramePattern(size), stats, plot_path,
             data_type)
    finally:
        flow.close()


class SharedFrames:
    """The frames that come through shared memory, taken as a FrameReader's are."""

    def __init__(self, flow: FlowReader, codec: FrameCodec):
        self.flow = flow
        self.codec = codec

    def take(self, limit: int) -> TakenFrames:
        return shared_frames(self.flow.take_shared(limit), self.codec)


FrameSource = FrameReader | SharedFrames


def show(app: Application, sources: list[FrameSource], wake_ups: Iterator[bool], pattern: FramePattern,
         stats: CameraStats, plot_path: Path | None, data_type: type[Any]) -> None:
    """Verify frames until stopped, then print the totals and write the plot."""
    app.status_figure = lambda: (f"{stats.total.samples} frames, latency p50 {stats.percentile_ms(0.5) or 0:.1f} ms, "
                                 f"{stats.total.gaps} gap(s), {stats.total.mismatches} mismatch(es)")
    view(app, sources, wake_ups, pattern, stats)
    size = stats.size
    stats.report_window(app.log, force=True, stats=app.stats)
    app.stats.record("totals", **stats.totals())
    app.log.info("%s", stats.totals_line())
    if plot_path is not None and stats.total.samples:
        write_plot(plot_path, stats, f"{data_type.__name__} ({size} bytes): {stats.total.samples} frames")
        app.log.info("latency plot written to %s", plot_path)


def dds_wake_ups(app: Application, waitset: Waits, publisher_left: GuardCondition,
                 flow: FlowReader) -> Iterator[bool]:
    """After each wake-up: True once every matched publisher has left."""
    for _ in app.wake_ups(waitset):
        yield publisher_left.read()  # read before taking: every frame it sent is then already here
        flow.check_deadline()  # once the frames are taken: their latency does not wait for it


def view(app: Application, sources: list[FrameSource], wake_ups: Iterator[bool], pattern: FramePattern,
         stats: CameraStats) -> None:
    def mismatch(frame: Frame, wrong: int) -> None:
        # Another writer's frames may all differ: one line per interval, the per-second lines count them all.
        problem = BadSample("data", f"frame {frame.seqnum} of camera {frame.id}: {wrong} of {stats.size} bytes differ",
                            "the publisher's LFSR pattern for the frame's seqnum")
        dds = [source for source in sources if isinstance(source, FrameReader)]
        if frame.writer and dds:
            dds[0].report(problem, frame.writer, action="counted as a mismatch")
        else:  # from shared memory: a publisher of ours on this host
            app.log.warning("frame %d of camera %d: %d of %d bytes differ from the pattern", frame.seqnum, frame.id,
                            wrong, stats.size)

    topic = app.topic_name("Camera", "CameraImageData")
    for leaving in wake_ups:
        for source in sources:
            while app.running:  # take until the source is empty
                with source.take(TAKE_LIMIT) as batch:  # the frames' data are views, valid inside this block
                    if not batch:
                        break
                    receive_ns = time.time_ns()
                    if isinstance(source, FrameReader):  # frames bypass the checked reader: counted here
                        console.traffic.count_in(topic, len(batch))
                    for frame in batch:
                        stats.received(frame, receive_ns, app.log, pattern, mismatch)
                        app.tick()
                        if not app.running:
                            break
        stats.report_window(app.log, stats=app.stats)
        if leaving:
            app.log.info("the publisher left")
            app.stop()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--plot", type=plot_file, default=None, metavar="FILE",
                        help="write a PNG of latency over time and its histogram on exit (keeps 16 bytes a frame "
                             "in memory until then)")
    parser.add_argument("--exit-with-publisher", action="store_true",
                        help="stop once every matched publisher has left (after taking what it sent)")


def main(argv: list[str] | None = None) -> int:
    return run("camera_sub", __doc__ or "", body, argv, add_arguments, keys=PROPERTY_KEYS)


if __name__ == "__main__":
    sys.exit(main())
