"""Rear-view camera: publishes frames of a 32-bit LFSR test pattern that the subscriber verifies byte by byte.

Data flow:  LFSR pattern (automotive.sim.lfsr)  -->  CameraImage::CameraImageData on CameraImageData (keyed by
config.ddsId), one frame every config.pubInterval ms (0: as fast as flow control allows), seqnum 1, 2, 3, ...
With config.transport=shm the frames go to same-host subscribers through shared memory (automotive.wire.shm), and on DDS
only while a DDS reader is matched.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable
from typing import Any

from cyclonedds.core import DDSException

from automotive.bus import console
from automotive.bus.app import Application, run
from automotive.bus.properties import PropertyKeys
from automotive.bus.stats import Every
from automotive.sim.lfsr import FramePattern
from automotive.wire import shm
from automotive.wire.camera import (
    FrameWriter,
    frame_size,
    frame_type,
    tune_process_for_large_frames,
)

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

    def wait_for(self, app: Application, minimum: int, others: Callable[[], int] = lambda: 0) -> bool:
        """Wait until ``minimum`` readers (DDS readers plus ``others()``) matched or the application is stopped;
        True if they did."""
        if minimum <= 0:
            return True
        app.log.info("waiting for %d subscriber(s)", minimum)
        with self.changed:
            while app.running and self.current + others() < minimum:
                self.changed.wait(0.2)  # bounded, so that a stop signal (or a shared-memory subscriber) is noticed
            return self.current + others() >= minimum


def body(app: Application) -> None:
    camera_id = app.props.get_int("config.ddsId", 1, minimum=0, maximum=2**32 - 1)
    interval_ms = app.props.get_float("config.pubInterval", 33, minimum=0)
    data_type = frame_type(app.props.get_str("config.imageSize", "full"), f"{app.props.source}: config.imageSize")
    wait_subscribers = app.props.get_int("config.waitSubscribers", 1, minimum=0)
    size = frame_size(data_type)

    memory = shm.open_for(app.props, app.name, app.domain_id, app.topic_name("Camera", "CameraImageData"), app.log)

    subscribers = SubscriberCount()
    # The pattern stream is generated once; each frame is a window of it, written without a copy.
    writer = FrameWriter(app.writer("Camera", data_type, "CameraImageData", hook=subscribers.hook), FramePattern(size))
    shared: shm.SharedFrameWriter | None = None
    if memory is not None:
        writer_qos = app.profiles.writer_qos(app.library, app.profile("Camera"))
        shared = shm.SharedFrameWriter(memory, writer, writer_qos, lambda: subscribers.current, lambda: app.running)
    tune_process_for_large_frames()
    app.ready()
    app.log.info("camera %d: %s frames of %d bytes, %s%s", camera_id, data_type.__name__, size,
                 f"one every {interval_ms:g} ms" if interval_ms else "as fast as flow control allows",
                 ", through shared memory (and DDS while a DDS reader is matched)" if shared else "")
    try:
        if subscribers.wait_for(app, wait_subscribers, shared.count_subscribers if shared else lambda: 0):
            publish(app, writer, shared.write_pattern if shared else writer.write_pattern, camera_id,
                    interval_ms / 1000)
    finally:
        if shared is not None:
            app.log.info("shared memory: %d frames sent, %d written on DDS", shared.sent_shared, shared.sent_dds)
            shared.close()
        if memory is not None:
            memory.close()


def publish(app: Application, writer: FrameWriter, write: Callable[[int, int], int], camera_id: int,
            interval_s: float) -> None:
    size = writer.codec.size
    written = 0
    every_second, window_frames = Every(), 0
    app.status_figure = lambda: f"{written} frames of {size} bytes published"
    topic = app.topic_name("Camera", "CameraImageData")
    for seqnum in app.periodic(interval_s):
        try:
            write(camera_id, seqnum)
        except (DDSException, shm.FrameNotSent) as error:  # a reliable write blocked past max_blocking_time, or a stop
            app.log.warning("frame %d not written: %s", seqnum, error)
            continue
        written += 1
        window_frames += 1
        console.traffic.count_out(topic)  # frames bypass the checked writer: counted here
        elapsed = every_second.due()
        if elapsed is not None:
            rate = window_frames / elapsed
            app.log.debug("published %d frames: %.1f frames/s, %.1f MB/s", written, rate, rate * size / 1e6)
            window_frames = 0

    acknowledged = writer.writer.wait_for_acks(int(ACK_TIMEOUT_S * 1e9)) if written else True
    app.stats.record("totals", published=written, acknowledged=acknowledged)
    app.log.info("published %d frames in total%s", written,
                 "" if acknowledged else f" (not all acknowledged within {ACK_TIMEOUT_S:g} s)")


def main(argv: list[str] | None = None) -> int:
    return run("camera_pub", __doc__ or "", body, argv, keys=PROPERTY_KEYS)


if __name__ == "__main__":
    sys.exit(main())
