"""Sensor fusion: aggregates the objects of every vision sensor into one object list for collision avoidance.

Data flow:  Vision::VisionSensor on VisionTopic (all sensors)  --\\
                                                                 +-->  Sensor::SensorObjectList on SensorObjects
            PointCloud2_ on rt/LidarTopic (timestamps logged)  --/

The LiDAR's clouds come through shared memory from a LiDAR on this host (automotive.wire.shm), on DDS from any other;
with --stats each cloud's hop (receive time minus the writer's source timestamp) is a ``lidar`` record.

config.mode=periodic (the original) publishes every config.pubInterval ms the objects of the vision samples received
since the last list (taken once a list, not woken by each sample); config.mode=event publishes as soon as vision data
arrives, for low latency.

The vision objects are read as numpy structured arrays (the generated codecs, automotive.cyclone.codecs) and the list
is written from one, never one Python object per object. With ``--stats FILE`` every vision sample taken and every
list written is a record linked by DDS source timestamps (``take`` and ``write``, ns since the epoch), which
automotive.bench.alert_latency follows from a vision sample to the driver alert.

Redundant mode (config.redundant=true): two instances run hot, with exclusive ownership; vision samples older than the
liveliness lease when taken (the instance was stalled) are not fused.
"""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np
from cyclonedds.sub import DataReader

from automotive.bus.app import Application, run
from automotive.bus.checkedreader import CheckedReader
from automotive.bus.clock import timestamp_of
from automotive.bus.ownership import StallGuard
from automotive.bus.properties import PropertyKeys
from automotive.cyclone.codecs import codec_for
from automotive.types.Sensor import SENSOR_OBJECT_LIST_MAX_SIZE, SensorObjectList
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.types.Vision import VisionSensor
from automotive.wire.pointcloud import read_cloud
from automotive.wire.sharedflow import FlowReader

# The property keys it reads beyond the runtime's (automotive.bus.app.RUNTIME_KEYS): any other is refused at start.
PROPERTY_KEYS = PropertyKeys.of("config.mode", "config.pubInterval", "config.transport", "config.shmPrefix",
                                roles=["Vision", "Lidar", "SensorObjects"])

SENSOR_OBJECT = codec_for(SensorObjectList).element_dtype("objects")  # type: ignore[union-attr]
# What a vision object gives a sensor object; the rest is zero: amplitude 0, rangeMode RANGE_NONE, rangeRate 0.
# Every component is copied (the original copied velocity[0] into all three).
COPIED = ("classification", "position", "velocity", "size")


def fuse(samples: list[VisionSensor]) -> np.ndarray[Any, Any]:
    """All objects of the given vision samples (numpy views), in arrival order, at most SENSOR_OBJECT_LIST_MAX_SIZE,
    as sensor objects."""
    vision_objects = []
    count = 0
    for sample in samples:
        if count >= SENSOR_OBJECT_LIST_MAX_SIZE:
            break
        if len(sample.objects):
            vision_objects.append(sample.objects)
            count += len(sample.objects)
    objects = np.zeros(min(count, SENSOR_OBJECT_LIST_MAX_SIZE), SENSOR_OBJECT)
    if not vision_objects:
        return objects
    # Field by field: concatenating plain columns is cheap; concatenating structured arrays promotes their dtypes
    # element type by element type (a few tens of microseconds per sample).
    for name in COPIED:
        column = (vision_objects[0][name] if len(vision_objects) == 1
                  else np.concatenate([array[name] for array in vision_objects]))
        objects[name] = column[:len(objects)]
    return objects


def take_lidar(app: Application, lidar: FlowReader) -> None:
    """Take the LiDAR's clouds (through shared memory from this host, on DDS from another): their stamps logged and,
    with --stats, each one's hop from the writer (receive time minus source timestamp)."""
    while True:
        with lidar.take_shared() as shared:
            if not shared:
                break
            received = time.time_ns()
            for sample in shared:
                cloud, _ = read_cloud(sample.data)  # its header and layout, read in place
                stamp = cloud.header_.stamp_
                lidar_taken(app, stamp.sec_, stamp.nanosec_, cloud.width_ * cloud.height_, sample.source_timestamp,
                            received)
    for cloud in lidar.reader.take(N=64):
        info = cloud.sample_info
        if isinstance(cloud, PointCloud2_) and not lidar.from_shared(info.publication_handle):
            stamp = cloud.header_.stamp_
            lidar_taken(app, stamp.sec_, stamp.nanosec_, cloud.width_ * cloud.height_, info.source_timestamp,
                        time.time_ns())
    lidar.check_deadline()


def lidar_taken(app: Application, sec: int, nanosec: int, points: int, source_ns: int, received_ns: int) -> None:
    app.log.debug("lidar sample stamped %d.%09d: %d points", sec, nanosec, points)
    app.stats.record("lidar", src=source_ns, at=received_ns, hop_ns=received_ns - source_ns)


def body(app: Application) -> None:
    mode = app.props.get_choice("config.mode", ["periodic", "event"], "periodic")
    interval_s = app.props.get_int("config.pubInterval", 100, minimum=1) / 1000
    vision = app.reader("Vision", VisionSensor, "VisionTopic")
    if isinstance(vision, CheckedReader):
        vision.use_views()
    lidar = FlowReader.of_role(app, "Lidar", PointCloud2_, "rt/LidarTopic")
    try:
        fuse_until_stopped(app, mode, interval_s, vision, lidar)
    finally:
        lidar.close()


def fuse_until_stopped(app: Application, mode: str, interval_s: float, vision: DataReader[VisionSensor],
                       lidar: FlowReader) -> None:
    vision_topic = vision.topic.get_name()
    writer = app.writer("SensorObjects", SensorObjectList, "SensorObjects")
    stall_guard = StallGuard(writer, app.log)  # redundant mode: no fusing of samples missed while stalled
    app.log.info("sensor fusion: %s mode, every %.0f ms", mode, interval_s * 1000)

    pending: list[VisionSensor] = []
    last = {"list": 0, "objects": 0, "sensors": ""}
    app.status_figure = lambda: (f"list {last['list']}: {last['objects']} object(s) from sensor(s) {last['sensors']}"
                                 if last["list"] else "no list published yet (no vision sample)")
    next_publish = time.monotonic() + interval_s

    def until_publish() -> float:
        return next_publish - time.monotonic()

    if mode == "periodic":
        # Woken by the LiDAR (its stamps are logged; a cloud in shared memory wakes this thread itself) and by the
        # clock, not by each vision sample: the vision data is taken once a list (the reader keeps 100 samples a
        # sensor), whatever the number of sensors.
        wake_ups = app.wake_ups(lidar.shared_first_waitset(), timeout_s=until_publish)
    else:
        wake_ups = app.wake_ups(lidar.waitset(vision), timeout_s=1.0)
    def publish() -> None:
        """Take the vision samples and write their list (none when nothing is pending)."""
        nonlocal next_publish
        fresh = stall_guard.fresh([s for s in vision.take(N=1000) if isinstance(s, VisionSensor)],
                                  "vision sample(s)", vision)
        if app.stats.enabled:
            taken_ns = time.time_ns()
            for sample in fresh:
                app.stats.record("take", topic=vision_topic, src=sample.sample_info.source_timestamp, at=taken_ns,
                                 key=sample.id)
        pending.extend(fresh)
        if mode == "periodic":  # its time has come: the next one
            next_publish = max(next_publish + interval_s, time.monotonic())
        if not pending:
            return
        sensors = sorted({sample.id for sample in pending})
        objects = fuse(pending)
        stamp = time.time_ns()
        writer.write(SensorObjectList(timestamp=timestamp_of(stamp), objects=objects),  # type: ignore[arg-type]
                     timestamp=stamp)
        published = app.tick()
        app.log.debug("published list %d: %d object(s) from %d vision sample(s) of sensor(s) %s",
                      published, len(objects), len(pending), ",".join(map(str, sensors)))
        last.update(list=published, objects=len(objects), sensors=",".join(map(str, sensors)))
        app.stats.record("list", number=published, objects=len(objects), samples=len(pending), sensors=sensors,
                         src=stamp, inputs=[sample.sample_info.source_timestamp for sample in pending])
        pending.clear()

    for _ in wake_ups:
        if mode == "periodic":  # woken by the LiDAR (its hop first) or by the clock
            take_lidar(app, lidar)
            if time.monotonic() >= next_publish:
                publish()
        else:  # the vision data first: its list is the alert chain's next hop; the LiDAR's stamps can wait
            publish()
            take_lidar(app, lidar)


def main(argv: list[str] | None = None) -> int:
    return run("sensor_fusion", __doc__ or "", body, argv, keys=PROPERTY_KEYS)


if __name__ == "__main__":
    sys.exit(main())
