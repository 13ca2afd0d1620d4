"""Vision sensor: publishes the objects it sees, one row of its CSV file every interval.

Data flow:  dataFile (CSV)  -->  Vision::VisionSensor on VisionTopic (keyed by config.sensorId)

With ``--stats FILE`` each sample is a ``sample`` record with its DDS source timestamp (``src``, ns since the epoch),
where automotive.bench.alert_latency starts following it.
"""

from __future__ import annotations

import sys
import time

from automotive.bus.app import Application, run
from automotive.bus.clock import timestamp_of
from automotive.bus.properties import PropertyKeys
from automotive.sim.csvdata import cycle_rows, load_vision_rows
from automotive.types.Vision import VisionSensor

# The property keys it reads beyond the runtime's (automotive.bus.app.RUNTIME_KEYS): any other is refused at start.
PROPERTY_KEYS = PropertyKeys.of("config.sensorId", "config.pubInterval", "dataFile", roles=["Vision"])


def body(app: Application) -> None:
    sensor_id = app.props.get_int("config.sensorId", 1, minimum=0, maximum=2**31 - 1)
    interval_s = app.props.get_int("config.pubInterval", 100, minimum=1) / 1000
    rows = load_vision_rows(app.props.get_path("dataFile"), app.log)
    writer = app.writer("Vision", VisionSensor, "VisionTopic")
    app.log.info("vision sensor %d: %d rows, publishing every %.0f ms", sensor_id, len(rows), interval_s * 1000)
    last = {"sample": 0, "objects": 0}
    app.status_figure = lambda: f"sample {last['sample']}: {last['objects']} object(s)"

    for iteration, objects in zip(app.periodic(interval_s), cycle_rows(rows)):
        stamp = time.time_ns()  # the data's timestamp is the DDS source timestamp: the latency records link them
        writer.write(VisionSensor(id=sensor_id, timestamp=timestamp_of(stamp), objects=objects), timestamp=stamp)
        app.log.debug("published sample %d: %d object(s)", iteration, len(objects))
        last.update(sample=iteration, objects=len(objects))
        app.stats.record("sample", number=iteration, objects=len(objects), src=stamp)


def main(argv: list[str] | None = None) -> int:
    return run("vision", __doc__ or "", body, argv, keys=PROPERTY_KEYS)


if __name__ == "__main__":
    sys.exit(main())
