"""Vehicle platform (CAN bus): executes commands and reports the vehicle's state.

Data flow:  Platform::PlatformControl on PlatformControl  --+-->  Platform::PlatformStatus on PlatformStatus
            dataFile (CSV)  -----------------------------------/

The status copies blinker and steering angle from the last command; speed, velocity, yaw rate and gas pedal come from
the rows of the CSV file, wrapping around.
"""

from __future__ import annotations

import sys

from automotive.app import Application, run
from automotive.clock import format_timestamp, now_timestamp
from automotive.csvdata import cycle_rows, load_platform_rows
from automotive.types.Common import IndicatorStatusEnum
from automotive.types.Platform import PlatformControl, PlatformStatus


def body(app: Application) -> None:
    interval_s = app.props.get_int("config.pubInterval", 100, minimum=1) / 1000
    rows = load_platform_rows(app.props.get_path("dataFile"), app.log)
    control_reader = app.reader("PlatformControl", PlatformControl, "PlatformControl")
    status_writer = app.writer("PlatformStatus", PlatformStatus, "PlatformStatus")
    app.log.info("vehicle platform: %d rows, status every %.0f ms", len(rows), interval_s * 1000)

    steer_angle = 0.0
    blinker = IndicatorStatusEnum.INDICATOR_OFF
    for iteration, row in zip(app.periodic(interval_s), cycle_rows(rows)):
        for command in control_reader.take(N=1000):
            if not isinstance(command, PlatformControl):
                continue
            app.log.info("command %d stamped %s: speed %.2f, steer %.2f, blinker %s", command.sample_id,
                         format_timestamp(command.timestamp), command.speed, command.vehicleSteerAngle,
                         IndicatorStatusEnum(command.blinkerStatus).name)
            steer_angle = command.vehicleSteerAngle
            blinker = IndicatorStatusEnum(command.blinkerStatus)
        status_writer.write(PlatformStatus(
            timestamp=now_timestamp(), vehSpd=row.vehSpd, blinkerStatus=blinker, posGasPedal=row.posGasPedal,
            velocity=row.velocity, yawRate=row.yawRate, vehicleSteerAngle=steer_angle))
        app.log.info("status %d: %.1f km/h, blinker %s, steer %.2f", iteration, row.vehSpd, blinker.name, steer_angle)


def main(argv: list[str] | None = None) -> int:
    return run("vehicle_platform", __doc__ or "", body, argv)


if __name__ == "__main__":
    sys.exit(main())
