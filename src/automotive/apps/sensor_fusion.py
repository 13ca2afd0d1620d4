"""Sensor fusion: aggregates the objects of every vision sensor into one object list for collision avoidance.

Data flow:  Vision::VisionSensor on VisionTopic (all sensors)  --\\
                                                                 +-->  Sensor::SensorObjectList on SensorObjects
            PointCloud2_ on rt/LidarTopic (timestamps logged)  --/

config.mode=periodic (the original) publishes every config.pubInterval ms the objects of the vision samples received
since the last list; config.mode=event publishes as soon as vision data arrives, for low latency.

Redundant mode (config.redundant=true): two instances run hot, with exclusive ownership; vision samples older than the
liveliness lease when taken (the instance was stalled) are not fused.
"""

from __future__ import annotations

import sys
import time

from cyclonedds.sub import DataReader

from automotive.bus.app import Application, run
from automotive.bus.clock import now_timestamp
from automotive.bus.ownership import StallGuard
from automotive.types.Common import ClassificationEnum
from automotive.types.Sensor import SENSOR_OBJECT_LIST_MAX_SIZE, RangeModeEnum, SensorObject, SensorObjectList
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.types.Vision import VisionObject, VisionSensor


def to_sensor_object(vision: VisionObject) -> SensorObject:
    # Every component is copied (the original copied velocity[0] into all three).
    return SensorObject(
        classification=ClassificationEnum(vision.classification),
        position=list(vision.position),
        velocity=list(vision.velocity),
        size=list(vision.size),
        amplitude=0.0,
        rangeMode=RangeModeEnum.RANGE_NONE,
        rangeRate=0.0,
    )


def fuse(samples: list[VisionSensor]) -> list[SensorObject]:
    """All objects of the given vision samples, in arrival order, at most SENSOR_OBJECT_LIST_MAX_SIZE."""
    objects = [to_sensor_object(obj) for sample in samples for obj in sample.objects]
    return objects[:SENSOR_OBJECT_LIST_MAX_SIZE]


def log_lidar_stamps(app: Application, lidar: DataReader[PointCloud2_]) -> None:
    for cloud in lidar.take(N=64):
        if isinstance(cloud, PointCloud2_):
            stamp = cloud.header_.stamp_
            app.log.info("lidar sample stamped %d.%09d: %d points", stamp.sec_, stamp.nanosec_,
                         cloud.width_ * cloud.height_)


def body(app: Application) -> None:
    mode = app.props.get_choice("config.mode", ["periodic", "event"], "periodic")
    interval_s = app.props.get_int("config.pubInterval", 100, minimum=1) / 1000
    vision = app.reader("Vision", VisionSensor, "VisionTopic")
    lidar = app.reader("Lidar", PointCloud2_, "rt/LidarTopic")
    writer = app.writer("SensorObjects", SensorObjectList, "SensorObjects")
    stall_guard = StallGuard(writer, app.log)  # redundant mode: no fusing of samples missed while stalled
    app.log.info("sensor fusion: %s mode, every %.0f ms", mode, interval_s * 1000)

    waitset = app.waitset(vision, lidar)
    pending: list[VisionSensor] = []
    next_publish = time.monotonic() + interval_s
    for _ in app.wake_ups(waitset, timeout_s=interval_s if mode == "periodic" else 1.0):
        log_lidar_stamps(app, lidar)
        pending.extend(stall_guard.fresh([s for s in vision.take(N=1000) if isinstance(s, VisionSensor)],
                                         "vision sample(s)", vision))
        if mode == "periodic":
            if time.monotonic() < next_publish:
                continue
            next_publish = max(next_publish + interval_s, time.monotonic())
        if not pending:
            continue
        sensors = sorted({sample.id for sample in pending})
        objects = fuse(pending)
        writer.write(SensorObjectList(timestamp=now_timestamp(), objects=objects))
        published = app.tick()
        app.log.info("published list %d: %d object(s) from %d vision sample(s) of sensor(s) %s",
                     published, len(objects), len(pending), ",".join(map(str, sensors)))
        app.stats.record("list", number=published, objects=len(objects), samples=len(pending), sensors=sensors)
        pending.clear()


def main(argv: list[str] | None = None) -> int:
    return run("sensor_fusion", __doc__ or "", body, argv)


if __name__ == "__main__":
    sys.exit(main())
