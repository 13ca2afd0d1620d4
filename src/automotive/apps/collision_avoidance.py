"""Collision avoidance: decides on driver alerts and commands the vehicle platform from the fused object list.

Data flow:  Sensor::SensorObjectList on SensorObjects  --+-->  Alerts::DriverAlerts on AlertTopic
            Platform::PlatformStatus on PlatformStatus  --+-->  Platform::PlatformControl on PlatformControl

An object taller than config.alertSize (size[1], metres; 2.0 by default) needs the driver's attention; when none is
left after an alert, an all-clear alert is written. Every object list is answered with a platform command that follows
the first object. The objects are read as a numpy structured array (the generated codecs), not one Python object
each. With ``--stats FILE`` every list taken and every alert and command written is a record linked by DDS source
timestamps (``take``, ``write``), which automotive.bench.alert_latency follows.

Redundant mode (config.redundant=true): two instances run hot; readers follow the stronger live one. Each instance
also reads the other instance's commands and numbers its own after them, so that at a failover the vehicle platform's
sample_ids jump forward, never back; a restarted primary takes over with the next number, without a gap (Commands).
Object lists older than the liveliness lease when taken are not answered: the instance was stalled (StallGuard); a
stalled instance (such lists, or its own time gap past the lease) answers fresh lists only and numbers them after the
other instance's commands at once (Commands.rejoin), so that an outside reader's silence stays near one lease even
when the other instance fails as this one resumes.
"""

from __future__ import annotations

import logging
import sys
import time
from typing import Any

from cyclonedds.core import DDSException
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy

from automotive.bus.app import Application, run
from automotive.bus.checkedreader import CheckedReader
from automotive.bus.clock import now_timestamp, timestamp_of
from automotive.bus.ownership import OwnerTracker, StallGuard
from automotive.bus.properties import PropertyKeys
from automotive.types.Alerts import DriverAlerts
from automotive.types.Common import IndicatorStatusEnum
from automotive.types.Platform import PlatformControl, PlatformStatus
from automotive.types.Sensor import SensorObjectList

# The property keys it reads beyond the runtime's (automotive.bus.app.RUNTIME_KEYS): any other is refused at start.
PROPERTY_KEYS = PropertyKeys.of("config.alertSize",
                                roles=["SensorObjects", "PlatformStatus", "Alerts", "PlatformControl"])

ALL_CLEAR = DriverAlerts(blindSpotDriver=False, blindSpotPassenger=False, frontCollision=False, backCollision=False,
                         parkingCollision=False, driverAttention=False)
# Redundant mode: how long a new instance waits for the owner's commands before it numbers its own from 1.
JOIN_S = 1.0
ALERT_STATES = {None: "not judged yet (no object list)", True: "DRIVER ATTENTION", False: "none"}
ATTENTION = DriverAlerts(blindSpotDriver=False, blindSpotPassenger=False, frontCollision=False, backCollision=False,
                         parkingCollision=False, driverAttention=True)


def needs_attention(objects: SensorObjectList, alert_size: float) -> bool:
    """``objects.objects`` is a numpy structured array (CheckedReader.use_views)."""
    return bool((objects.objects["size"][:, 1] > alert_size).any())  # type: ignore[call-overload]


def command_for(objects: SensorObjectList, sample_id: int, stamp: int | None = None) -> PlatformControl:
    """A platform command that follows the first object of the list (or a neutral one for an empty list); stamped
    ``stamp`` (ns since the epoch) or now."""
    command = PlatformControl(sample_id=sample_id, timestamp=now_timestamp() if stamp is None else timestamp_of(stamp),
                              vehicleSteerAngle=0.0, speed=0.0, blinkerStatus=IndicatorStatusEnum.INDICATOR_OFF)
    if len(objects.objects):
        first: Any = objects.objects[0]
        # the blinker from the classification's number, as the original
        command.blinkerStatus = IndicatorStatusEnum(int(first["classification"]) % 4)
        command.speed = float(first["velocity"][0])
        command.vehicleSteerAngle = float(first["position"][0])
    return command


class Commands:
    """Numbers the platform commands; in redundant mode after the other instance's.

    Redundant mode: a reader of the commands that ignores this process's own writer (IGNORE_LOCAL), so that its
    exclusive ownership shows the strongest live *other* instance's commands, whoever owns the platform's. An instance
    follows the numbering of a stronger one (the standby the primary's); the strongest keeps its own, and a weaker
    one's numbers matter to it only when it joins. It joins:

    - when it starts: at the first command of another instance, or alone JOIN_S after its first object list;
    - after a stall (frozen or starved past the lease, :meth:`rejoin`): at once if the other instance's last command
      is fresh (written within the lease: its number is the platform's now), or as soon as no other instance's writer
      is alive (nobody numbered since); else at its next command, within JOIN_S at most.

    So a primary that resumes while the standby freezes commands again at once, numbered after the standby's last
    command, instead of waiting for a command that will not come.
    """

    def __init__(self, app: Application, writer: DataWriter[PlatformControl], redundant: bool):
        self.log = app.log
        self.stats = app.stats
        self.others_alive: int | None = None  # live writers of the other instances (None: not told yet)
        self.reader = (app.reader("PlatformControl", PlatformControl, "PlatformControl", hook=self._on_status,
                                  overrides=(Policy.IgnoreLocal.Process,)) if redundant else None)
        self.joined = self.reader is None
        self.join_deadline: float | None = None
        self.rejoining = False  # after a stall: the fast ways to join apply
        self.last_id = 0
        self.lease_ns = writer.get_qos()[Policy.Liveliness].lease_duration if redundant else 0
        self.strength = writer.get_qos()[Policy.OwnershipStrength].strength if redundant else 0
        self.strengths: dict[int, int] = {}  # publication handle -> ownership strength of the other instances

    def _on_status(self, event: str, topic: str, status: Any) -> None:
        if event == "liveliness_changed":  # the listener's thread: one int handed over
            self.others_alive = status.alive_count

    def _strength_of(self, handle: int) -> int:
        if handle not in self.strengths:
            assert self.reader is not None
            try:
                data = self.reader.get_matched_publication_data(handle)
            except DDSException:
                data = None
            qos = data.qos if data is not None else None
            self.strengths[handle] = (qos[Policy.OwnershipStrength].strength
                                      if qos is not None and Policy.OwnershipStrength in qos else 0)
        return self.strengths[handle]

    def follow_others(self) -> None:
        """Take the other instances' latest commands (redundant mode)."""
        if self.reader is None:
            return
        now = time.time_ns()
        seen, fresh, stronger = 0, False, False
        for command in self.reader.take(N=1000):
            if not isinstance(command, PlatformControl):
                continue
            info = command.sample_info  # type: ignore[attr-defined]
            seen = max(seen, command.sample_id)
            fresh = fresh or now - info.source_timestamp <= self.lease_ns
            stronger = stronger or self._strength_of(info.publication_handle) > self.strength
        if not seen:
            return
        if not self.joined and (not self.rejoining or fresh):
            self.last_id = max(self.last_id, seen)
            self._join(f"the other instance's last command is {self.last_id}; ours follow it")
        elif stronger or not self.joined:
            self.last_id = max(self.last_id, seen)

    def rejoin(self) -> None:
        """After a stall: the numbering may be behind the platform's; join again (see the class)."""
        if self.reader is None:
            return
        self.joined, self.rejoining = False, True
        self.join_deadline = time.monotonic() + JOIN_S

    def _join(self, why: str) -> None:
        self.log.info("joined: %s", why)
        self.stats.record("joined", after=self.last_id, rejoined=self.rejoining)
        self.joined, self.rejoining, self.join_deadline = True, False, None

    def next_id(self) -> int | None:
        """The number of the next command, or None while the instance waits to join."""
        if not self.joined:
            if self.rejoining and self.others_alive == 0:
                self._join(f"no other instance alive; ours follow {self.last_id}")
            else:
                self.join_deadline = self.join_deadline or time.monotonic() + JOIN_S
                if time.monotonic() < self.join_deadline:
                    return None
                self._join(f"no other instance's command within {JOIN_S:g} s; ours start at {self.last_id + 1}")
        self.last_id += 1
        return self.last_id


def body(app: Application) -> None:
    alert_size = app.props.get_float("config.alertSize", 2.0)
    objects_reader = app.reader("SensorObjects", SensorObjectList, "SensorObjects")
    if isinstance(objects_reader, CheckedReader):
        objects_reader.use_views()
    status_reader = app.reader("PlatformStatus", PlatformStatus, "PlatformStatus")
    alert_writer = app.writer("Alerts", DriverAlerts, "AlertTopic")
    control_writer = app.writer("PlatformControl", PlatformControl, "PlatformControl")
    topics = {"objects": objects_reader.topic.get_name(), "alerts": alert_writer.topic.get_name(),
              "commands": control_writer.topic.get_name()}
    objects_owner = OwnerTracker(objects_reader, app.log, app.stats)
    commands = Commands(app, control_writer, app.redundant)
    stall_guard = StallGuard(control_writer, app.log)  # redundant mode: no answers to lists missed while stalled

    # None until the first object list is judged: that verdict is said whatever it is (an HMI then shows "all clear"
    # because a live collision avoidance said so, never on silence); then each change, and an alert while it lasts.
    alert_active: bool | None = None
    status_count = 0
    last_command: list[str] = []
    app.status_figure = lambda: (f"alert: {ALERT_STATES[alert_active]}"
                                 + (f"; {last_command[0]}" if last_command else "; no command yet"))
    # Redundant mode: woken at least twice a lease, so that a gap longer than the lease between two wake-ups is this
    # process's own stall (frozen, starved), even when nothing was queued meanwhile.
    lease_s = stall_guard.max_age_ns / 1e9
    last_wake = stall_noticed = time.monotonic()
    for _ in app.wake_ups(app.waitset(objects_reader, status_reader), timeout_s=lease_s / 2 if lease_s else 1.0):
        now = time.monotonic()
        own_gap_s, last_wake = now - last_wake, now
        taken = [objects for objects in objects_reader.take(N=100) if isinstance(objects, SensorObjectList)]
        taken_ns = time.time_ns()
        lists = stall_guard.fresh(taken, "object list(s)", objects_reader)
        # (The backlog of one stall comes in several takes: the late lists of the later ones are the same stall.)
        if (lease_s and (own_gap_s > lease_s or (stall_guard.stalled and now - stall_noticed > lease_s))
                and (commands.joined or commands.rejoining)):
            stall_noticed = now
            # What this instance knew is stale: the other one answered meanwhile, and may have changed the alert.
            # Rebuilt from fresh inputs: the numbering from the other's commands, the alert from the next verdict.
            app.log.warning("stalled %.0f ms (past the %.0f ms lease): answering fresh object lists only, numbered "
                            "after the other instance's commands", own_gap_s * 1000, lease_s * 1000)
            app.stats.record("stalled", gap_ms=round(own_gap_s * 1000))
            commands.rejoin()
            alert_active = None
        commands.follow_others()
        for objects in lists:
            objects_owner.follow(objects)
            source = objects.sample_info.source_timestamp  # type: ignore[attr-defined]
            app.stats.record("take", topic=topics["objects"], src=source, at=taken_ns, objects=len(objects.objects))
            # Checked again with each output's own stamp: frozen since the take, the list is no longer fresh (the
            # next wake-up sees the gap). So no output of a list older than the lease is ever written.
            stamp = time.time_ns()
            if stall_guard.outdated(source, stamp):
                continue
            if needs_attention(objects, alert_size):
                alert_writer.write(ATTENTION, timestamp=stamp)
                app.stats.record("write", topic=topics["alerts"], src=stamp, inputs=[source], attention=True)
                if alert_active is not True:
                    app.log.info("ALERT: driver attention needed (an object taller than %.1f m)", alert_size)
                    app.stats.record("alert", state="alert")
                alert_active = True
            elif alert_active is not False:
                alert_writer.write(ALL_CLEAR, timestamp=stamp)
                app.stats.record("write", topic=topics["alerts"], src=stamp, inputs=[source], attention=False)
                # the first verdict, when it is all clear, clears nothing: the HMI's box shows it, -v this line
                app.log.log(logging.INFO if alert_active else logging.DEBUG, "all clear: no object taller than %.1f m",
                            alert_size)
                app.stats.record("alert", state="clear")
                alert_active = False
            sample_id = commands.next_id()
            if sample_id is None:
                continue
            stamp = time.time_ns()
            if stall_guard.outdated(source, stamp):
                continue
            command = command_for(objects, sample_id, stamp)
            control_writer.write(command, timestamp=stamp)
            app.stats.record("write", topic=topics["commands"], src=stamp, inputs=[source], sample_id=sample_id)
            app.log.debug("command %d: speed %.2f, steer %.2f, blinker %s (%d objects, %d status samples read)",
                          sample_id, command.speed, command.vehicleSteerAngle, command.blinkerStatus.name,
                          len(objects.objects), status_count)
            last_command[:] = [f"command {sample_id}: speed {command.speed:.2f}, steer {command.vehicleSteerAngle:.2f}"]
            app.stats.record("command", sample_id=sample_id)
            app.tick()
        # Read, and otherwise ignored, as in the original; after the outputs, which the alert chain waits for
        status_count += len(status_reader.take(N=1000))


def main(argv: list[str] | None = None) -> int:
    return run("collision_avoidance", __doc__ or "", body, argv, keys=PROPERTY_KEYS)


if __name__ == "__main__":
    sys.exit(main())
