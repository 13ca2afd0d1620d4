"""Rear-view camera: publishes frames of a 32-bit LFSR test pattern that the subscriber verifies byte by byte.

Data flow:  LFSR pattern (automotive.sim.lfsr)  -->  CameraImage::CameraImageData on CameraImageData (keyed by
config.ddsId), one frame every config.pubInterval ms (0: as fast as flow control allows), seqnum 1, 2, 3, ...
Subscribers on this host get the frames through shared memory (iceoryx2, automotive.wire.shm), every other reader
(another host, another vendor's tool) on DDS, which writes only while such a reader is matched; config.transport=udp
sends on DDS only.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable
from typing import Any

from cyclonedds.core import DDSException

from automotive.bus.app import Application, run
from automotive.bus.endpoints import wait_for_acks
from automotive.bus.properties import PropertyKeys
from automotive.bus.stats import Every
from automotive.sim.lfsr import FramePattern
from automotive.wire.camera import (
    FrameWriter,
    frame_size,
    frame_type,
    max_frame_length,
    tune_process_for_large_frames,
)
from automotive.wire.sharedflow import FlowWriter
from automotive.wire.shm import SampleNotSent

# The property keys it reads beyond the runtime's (automotive.bus.app.RUNTIME_KEYS): any other is refused at start.
PROPERTY_KEYS = PropertyKeys.of("config.ddsId", "config.pubInterval", "config.imageSize", "config.waitSubscribers",
                               "config.transport", "config.shmPrefix", roles=["Camera"])

ACK_TIMEOUT_S = 10.0  # at the end: how long reliable readers get to acknowledge the last frames


class SubscriberCount:
    """The writer's matched-reader count, fed by the status listener's hook."""

    def __init__(self) -> None:
        self.current = 0
        self.changed = threading.Condition()

    def hook(self, event: str, topic: str, status: Any) -> None:
        if event == "publication_matched":
            with self.changed:
                self.current = status.current_count
                self.changed.notify_all()

    def wait_for(self, app: Application, minimum: int) -> bool:
        """Wait until ``minimum`` readers matched (on DDS: a shared-memory subscriber has its DDS reader too) or the
        application is stopped; True if they did."""
        if minimum <= 0:
            return True
        app.log.info("waiting for %d subscriber(s)", minimum)
        with self.changed:
            while app.running and self.current < minimum:
                self.changed.wait(0.2)  # bounded, so that a stop signal is noticed
            return self.current >= minimum


def body(app: Application) -> None:
    camera_id = app.props.get_int("config.ddsId", 1, minimum=0, maximum=2**32 - 1)
    interval_ms = app.props.get_float("config.pubInterval", 33, minimum=0)
    data_type = frame_type(app.props.get_str("config.imageSize", "full"), f"{app.props.source}: config.imageSize")
    wait_subscribers = app.props.get_int("config.waitSubscribers", 1, minimum=0)
    size = frame_size(data_type)

    subscribers = SubscriberCount()
    flow = FlowWriter(app, "Camera", data_type, "CameraImageData", max_frame_length(data_type), subscribers.hook)
    # The pattern stream is generated once; each frame is a window of it, written without a copy.
    writer = FrameWriter(flow.writer, FramePattern(size))

    def write(id: int, seqnum: int) -> int:
        # On DDS the frame is written from the pattern stream (no copy), after it went through shared memory, with
        # the same header and source timestamp: the same bytes on both paths.
        return flow.publish(writer.serialized_length, lambda view: writer.build_pattern_frame(view, id, seqnum),
                            lambda stamp: writer.write_pattern(id, seqnum, stamp))

    tune_process_for_large_frames()
    app.ready()
    app.log.info("camera %d: %s frames of %d bytes, %s%s", camera_id, data_type.__name__, size,
                 f"one every {interval_ms:g} ms" if interval_ms else "as fast as flow control allows",
                 "; shared memory with subscribers on this host, DDS with the others" if flow.shared else "")
    try:
        if subscribers.wait_for(app, wait_subscribers):
            publish(app, writer, write, camera_id, interval_ms / 1000)
    finally:
        if flow.shared is not None:
            app.log.info("shared memory: %d frames sent, %d written on DDS", flow.sent_shared, flow.sent_dds)
        flow.close()


def publish(app: Application, writer: FrameWriter, write: Callable[[int, int], int], camera_id: int,
            interval_s: float) -> None:
    size = writer.codec.size
    written = 0
    every_second, window_frames = Every(), 0
    app.status_figure = lambda: f"{written} frames of {size} bytes published"
    for seqnum in app.periodic(interval_s):
        try:
            write(camera_id, seqnum)
        except (DDSException, SampleNotSent) as error:  # a reliable write blocked past max_blocking_time, or a stop
            app.log.warning("frame %d not written: %s", seqnum, error)
            continue
        written += 1
        window_frames += 1
        elapsed = every_second.due()
        if elapsed is not None:
            rate = window_frames / elapsed
            app.log.debug("published %d frames: %.1f frames/s, %.1f MB/s", written, rate, rate * size / 1e6)
            window_frames = 0

    acknowledged = wait_for_acks(writer.writer, int(ACK_TIMEOUT_S * 1e9)) if written else True
    app.stats.record("totals", published=written, acknowledged=acknowledged)
    app.log.info("published %d frames in total%s", written,
                 "" if acknowledged else f" (not all acknowledged within {ACK_TIMEOUT_S:g} s)")


def main(argv: list[str] | None = None) -> int:
    return run("camera_pub", __doc__ or "", body, argv, keys=PROPERTY_KEYS)


if __name__ == "__main__":
    sys.exit(main())
