"""Vehicle platform (CAN bus): executes commands and reports the vehicle's state.

Data flow:  Platform::PlatformControl on PlatformControl  --+-->  Platform::PlatformStatus on PlatformStatus
            dataFile (CSV)  -----------------------------------/

The status copies blinker and steering angle from the last command; speed, velocity, yaw rate and gas pedal come from
the rows of the CSV file, wrapping around. Commands are taken as they arrive (with ``--stats FILE``, each one a
``take`` record with its DDS source timestamp); the status goes out every config.pubInterval ms.

Redundant mode (config.redundant=true): the commands come from the stronger live of two collision_avoidance instances;
each change of owner is reported, and a command numbered at or below one already executed (stale) is ignored, until
no command writer is alive any more: an instance that starts after that numbers its commands afresh.
"""

from __future__ import annotations

import sys
import time
from typing import Any

from automotive.bus.app import Application, run
from automotive.bus.clock import format_timestamp, now_timestamp
from automotive.bus.diagnostics import OK, WARN, Problem
from automotive.bus.ownership import OwnerTracker
from automotive.bus.properties import PropertyKeys
from automotive.sim.csvdata import cycle_rows, load_platform_rows
from automotive.types.Common import IndicatorStatusEnum
from automotive.types.Platform import PlatformControl, PlatformStatus

# The property keys it reads beyond the runtime's (automotive.bus.app.RUNTIME_KEYS): any other is refused at start.
PROPERTY_KEYS = PropertyKeys.of("config.pubInterval", "dataFile", roles=["PlatformControl", "PlatformStatus"])


def two_deciders(count: int) -> str:
    return (f"{count} command writers drive this vehicle (PlatformControl, shared ownership: every command of each is "
            "executed): run one collision_avoidance, or two in redundant mode (automotive launch --redundant)")


def body(app: Application) -> None:
    interval_s = app.props.get_int("config.pubInterval", 100, minimum=1) / 1000
    rows = load_platform_rows(app.props.get_path("dataFile"), app.log)
    writers_lost: list[bool] = []  # appended by the listener thread when no command writer is alive
    command_writers: list[int] = []  # matched command writers, appended by the listener thread at each change

    def on_status(event: str, topic: str, status: Any) -> None:
        if event == "liveliness_changed" and status.alive_count == 0 and (
                status.not_alive_count_change > 0 or status.alive_count_change < 0):
            writers_lost.append(True)
        elif event == "subscription_matched":
            command_writers.append(status.current_count)

    control_reader = app.reader("PlatformControl", PlatformControl, "PlatformControl", hook=on_status)
    status_writer = app.writer("PlatformStatus", PlatformStatus, "PlatformStatus")
    owner = OwnerTracker(control_reader, app.log, app.stats)
    executed: int | None = None  # sample_id of the last command executed
    deciders = 0  # command writers matched, while the reader is SHARED: more than one drive the vehicle at once

    def health() -> Problem:
        if deciders > 1:
            return Problem(WARN, two_deciders(deciders))
        return Problem(OK, "")

    app.health_check = health
    app.log.info("vehicle platform: %d rows, status every %.0f ms", len(rows), interval_s * 1000)

    steer_angle = 0.0
    blinker = IndicatorStatusEnum.INDICATOR_OFF
    speed_kmh: list[float] = []
    app.status_figure = lambda: (f"{speed_kmh[0]:.1f} km/h, blinker {blinker.name}, steer {steer_angle:.2f}, last "
                                 f"command {executed if executed is not None else 'none'}") if speed_kmh else ""
    topic = control_reader.topic.get_name()
    row_cycle = cycle_rows(rows)
    next_status = time.monotonic()  # the first status at once, then every interval

    def until_status() -> float:
        return next_status - time.monotonic()

    # Woken by each command (executed at once) and by the status period.
    for _ in app.wake_ups(app.waitset(control_reader), timeout_s=until_status):
        while command_writers:
            count = command_writers.pop(0)
            if not owner.enabled and (count > 1) != (deciders > 1):
                if count > 1:
                    app.log.warning(two_deciders(count))
                else:
                    app.log.info("one command writer on %s again", topic)
            deciders = count if not owner.enabled else 0
        while writers_lost:
            writers_lost.pop()
            if owner.enabled and executed is not None:
                app.log.warning("no command writer alive: the next one's numbering is accepted from where it starts")
                executed = None
        taken = control_reader.take(N=1000)
        taken_ns = time.time_ns()
        for command in taken:
            if not isinstance(command, PlatformControl):
                continue
            app.stats.record("take", topic=topic, src=command.sample_info.source_timestamp,  # type: ignore[attr-defined]
                             at=taken_ns, sample_id=command.sample_id)
            owner.follow(command)
            if owner.enabled and executed is not None and command.sample_id <= executed:
                app.log.warning("stale command %d from %s ignored: command %d was executed already",
                                command.sample_id, owner.owner_name, executed)
                app.stats.record("stale_command", sample_id=command.sample_id, executed=executed)
                continue
            executed = command.sample_id
            app.stats.record("command", sample_id=command.sample_id, owner=owner.owner_name)
            app.log.debug("command %d stamped %s: speed %.2f, steer %.2f, blinker %s", command.sample_id,
                          format_timestamp(command.timestamp), command.speed, command.vehicleSteerAngle,
                          IndicatorStatusEnum(command.blinkerStatus).name)
            steer_angle = command.vehicleSteerAngle
            blinker = IndicatorStatusEnum(command.blinkerStatus)
        now = time.monotonic()
        if now < next_status:
            continue
        next_status = max(next_status + interval_s, now)  # after a slow step the schedule restarts, no burst
        row = next(row_cycle)
        iteration = app.tick()
        status_writer.write(PlatformStatus(
            timestamp=now_timestamp(), vehSpd=row.vehSpd, blinkerStatus=blinker, posGasPedal=row.posGasPedal,
            velocity=row.velocity, yawRate=row.yawRate, vehicleSteerAngle=steer_angle))
        app.log.debug("status %d: %.1f km/h, blinker %s, steer %.2f", iteration, row.vehSpd, blinker.name, steer_angle)
        speed_kmh[:] = [row.vehSpd]
        app.stats.record("status", number=iteration)


def main(argv: list[str] | None = None) -> int:
    return run("vehicle_platform", __doc__ or "", body, argv, keys=PROPERTY_KEYS)


if __name__ == "__main__":
    sys.exit(main())
