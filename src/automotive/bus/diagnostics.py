"""Every program's health on ROS 2's /diagnostics: once a second one ``diagnostic_msgs/msg/DiagnosticArray``.

The DDS topic is ``rt/diagnostics`` (ROS 2's ``/diagnostics``), its type ROS 2's own (``diagnostic_msgs::msg::dds_::
DiagnosticArray_``, XCDR1, the IDL's ``diagnostic_msgs`` module) and its QoS ROS 2's default (reliable, volatile, keep
last 10: automotive.bus.qos.ROS2_DEFAULT_PROFILE), so rqt_robot_monitor, Foxglove's Diagnostics panel, rosbags and
``cyclonedds subscribe rt/diagnostics`` read it as they read any ROS 2 robot's diagnostics.

Each array holds one DiagnosticStatus, the program's:

- ``name``: the instance name (``vision``, ``collision_avoidance_b``); ``hardware_id``: the host name;
- ``level``: ERROR or WARN when a flow the program needs is missing, else OK (STALE is what a monitor shows on its own
  for a program that stopped reporting; a running program never says it of itself):

  - ERROR: what the program itself judges an error (``health_check``: the HMI's alert source lost);
  - WARN: a reader that is not optional with no writer matched, once the match report's grace (``config.matchReport``)
    has passed; a writer whose liveliness is lost as the reader sees it now; a deadline missed, an incompatible QoS or
    a bad sample in the last RECENT_S seconds;
- ``message``: the problems, worst first, in the console's words (``[AlertTopic] reader: no writer matched``); when
  all is well, what the console's status line says (``out VisionTopic 10/s; sample 50: 5 object(s)``);
- ``values``: samples in and out per second per topic, the matched peers of each endpoint, the status events counted
  per topic (deadline missed, liveliness changes, samples lost, incompatible QoS), bad samples, RSS and CPU; and per
  topic read, the latency of its samples over the last 10 s (automotive.bus.latency.recent: reception minus the
  writer's source timestamp, as each reader measures it): ``VisionTopic latency p50 ms (last 10 s)``, ``... p99 ms
  ...``, ``... samples ...`` for all its writers together, and the same keys with ``from <writer participant>`` after
  the topic for each writer (``VisionTopic from vision latency p50 ms (last 10 s)``). A writer on another host stamps
  with its own clock: the monitor marks such figures as such.

Its writer is none of the program's endpoints: it is in no status line, no match report and no traffic count, and it
adds no console line. ``config.diagnosticsInterval`` sets the period (1 s; 0 turns it off).
"""

from __future__ import annotations

import logging
import os
import resource
import socket
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Protocol

from cyclonedds.core import DDSException
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader

from automotive.bus import console, latency, memtune
from automotive.bus.badsamples import BadSampleReporter
from automotive.bus.endpoints import Databus
from automotive.bus.qos import ROS2_DEFAULT_PROFILE, QosProfiles
from automotive.cyclone.matched import matched_publications, matched_subscriptions
from automotive.types.builtin_interfaces.msg.dds_ import Time_
from automotive.types.diagnostic_msgs.msg.dds_ import DiagnosticArray_, DiagnosticStatus_, KeyValue_
from automotive.types.diagnostic_msgs.msg.dds_.DiagnosticStatus_Constants import ERROR, OK, STALE, WARN
from automotive.types.std_msgs.msg.dds_ import Header_

DIAGNOSTICS_TOPIC = "rt/diagnostics"
ROS2_TYPE = "diagnostic_msgs/msg/DiagnosticArray"
DEFAULT_INTERVAL_S = 1.0
RECENT_S = 5.0  # a deadline missed, an incompatible QoS or a bad sample warns for this long (at least 3 periods)
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}
# Status events that make a WARN while recent.
RECENT_WARNINGS = ("requested_deadline_missed", "offered_deadline_missed", "liveliness_lost",
                   "requested_incompatible_qos", "offered_incompatible_qos")

__all__ = ["DEFAULT_INTERVAL_S", "DIAGNOSTICS_TOPIC", "ERROR", "OK", "ROS2_TYPE", "STALE", "WARN", "Diagnostics",
           "Problem", "assess"]


@dataclass(frozen=True)
class Problem:
    """A level and one line: what a program says of its health (``health_check``), or what is wrong."""

    level: int
    message: str


HealthCheck = Callable[[], Problem | None]


class Monitored(Protocol):
    """What the report reads of a running program (automotive.bus.app.Application)."""

    bus: Databus
    instance_name: str
    domain_id: int
    match_report_s: float
    optional_topics: set[str]
    status_figure: Callable[[], str] | None
    health_check: HealthCheck | None
    reporter: BadSampleReporter
    profiles: QosProfiles
    library: str


@dataclass(frozen=True)
class EndpointState:
    topic: str
    reader: bool
    matched: int


def endpoint_states(endpoints: Iterable[DataWriter[Any] | DataReader[Any]]) -> list[EndpointState]:
    states = []
    for endpoint in endpoints:
        reader = isinstance(endpoint, DataReader)
        try:
            matched = len(matched_publications(endpoint) if isinstance(endpoint, DataReader)
                          else matched_subscriptions(endpoint))
        except DDSException:
            continue  # deleted while the program ends
        states.append(EndpointState(endpoint.topic.get_name(), reader, matched))
    return states


def assess(endpoints: list[EndpointState], optional: set[str], grace_over: bool,
           recent: list[tuple[str, str, str]], not_alive: list[str], bad_samples: int,
           own: Problem | None) -> list[Problem]:
    """What is wrong, worst first: the program's own verdict, a needed reader with no writer (after the grace; with
    the QoS that kept a writer out, if one was offered), writers whose liveliness is lost now, recent events
    (``recent``: (topic, event, line)) and bad samples."""
    problems: list[Problem] = []
    if own is not None and own.level != OK:
        problems.append(own)
    incompatible = {topic: line.split("] ", 1)[-1] for topic, event, line in recent
                    if event == "requested_incompatible_qos"}
    said = set()
    if grace_over:
        for endpoint in endpoints:
            if endpoint.reader and not endpoint.matched and endpoint.topic not in optional:
                why = incompatible.get(endpoint.topic)
                if why:
                    said.add(endpoint.topic)
                problems.append(Problem(WARN, f"[{endpoint.topic}] reader: " + (why or "no writer matched")))
    problems.extend(Problem(WARN, line) for line in not_alive)
    problems.extend(Problem(WARN, line) for topic, event, line in recent
                    if event in RECENT_WARNINGS and not (event == "requested_incompatible_qos" and topic in said))
    if bad_samples:
        problems.append(Problem(WARN, f"{bad_samples} bad sample(s) ignored in the last {RECENT_S:g} s"))
    return sorted(problems, key=lambda problem: -problem.level)  # stable: in the order above within a level


def rates_line(rates_in: dict[str, float], rates_out: dict[str, float]) -> str:
    """The console's words (automotive.bus.console.Traffic.rates): ``in VisionTopic 10/s; out SensorObjects 10/s``."""
    def listed(direction: str, rates: dict[str, float]) -> str:
        return f"{direction} " + ", ".join(f"{topic} {rate:.3g}/s" for topic, rate in rates.items()) if rates else ""

    return "; ".join(part for part in (listed("in", rates_in), listed("out", rates_out)) if part)


class ProcessUsage:
    """This process's CPU since the last look, read the cheap way (``getrusage``; its resident memory:
    :func:`automotive.bus.memtune.resident_bytes`). psutil's ``Process.memory_info`` and ``cpu_percent`` took about
    0.2 ms of the 0.4 ms that a report cost, once a second in every program
    (docs/measurements/shared-memory-default.md)."""

    def __init__(self) -> None:
        self._last = self._times()

    @staticmethod
    def _times() -> tuple[float, float]:
        """(monotonic seconds, CPU seconds of every thread of the process)."""
        usage = resource.getrusage(resource.RUSAGE_SELF)
        return time.monotonic(), usage.ru_utime + usage.ru_stime

    def cpu_percent(self) -> float:
        """Percent of one core since the last call (the first: since this object was made)."""
        (wall, cpu), (last_wall, last_cpu) = self._times(), self._last
        self._last = (wall, cpu)
        return 100.0 * (cpu - last_cpu) / max(wall - last_wall, 1e-9)


class Diagnostics:
    """The report's writer and its thread: :meth:`start` once the program is set up, :meth:`stop` before its
    participant goes."""

    def __init__(self, program: Monitored, interval_s: float = DEFAULT_INTERVAL_S,
                 log: logging.Logger | None = None):
        self.program = program
        self.interval_s = interval_s
        self.log = log or logging.getLogger("automotive")
        self.hostname = socket.gethostname()
        self.usage = ProcessUsage()  # its CPU share is measured from now
        bus = program.bus
        qos = program.profiles.writer_qos(program.library, ROS2_DEFAULT_PROFILE)
        # Not one of the bus's endpoints: in no status line, match report or traffic count.
        self.writer: DataWriter[DiagnosticArray_] | None = DataWriter(
            bus.publisher, bus.topic(DIAGNOSTICS_TOPIC, DiagnosticArray_), qos=qos)
        self.started = time.monotonic()
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, name="diagnostics", daemon=True)
        self._totals = console.traffic.totals()
        self._bad_samples: list[tuple[float, int]] = [(self.started, program.reporter.reported)]
        self.written = 0

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._done.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)
        self.writer = None  # deleted with the participant

    def _run(self) -> None:
        next_time = time.monotonic() + self.interval_s
        last = time.monotonic()
        while not self._done.wait(max(next_time - time.monotonic(), 0)):
            now = time.monotonic()
            next_time = max(next_time + self.interval_s, now)
            try:
                status = self.status(now - last)
                last = now
                writer = self.writer
                if writer is None:
                    return
                writer.write(DiagnosticArray_(header_=header(), status_=[status]))
                self.written += 1
            except Exception as error:  # noqa: BLE001  (the report must never end the program, nor flood its console)
                self.log.debug("diagnostics: %s", error)

    def status(self, seconds: float) -> DiagnosticStatus_:
        """The program's status now; ``seconds`` since the last one (the rates' period)."""
        program = self.program
        per_s = max(seconds, 1e-9)
        totals_in, totals_out = console.traffic.totals()
        before_in, before_out = self._totals
        self._totals = (totals_in, totals_out)
        endpoints = endpoint_states(program.bus.endpoints)
        topics_in = [endpoint.topic for endpoint in endpoints if endpoint.reader]
        topics_out = [endpoint.topic for endpoint in endpoints if not endpoint.reader]
        rates_in = {topic: (totals_in.get(topic, 0) - before_in.get(topic, 0)) / per_s
                    for topic in dict.fromkeys([*topics_in, *totals_in])}
        rates_out = {topic: (totals_out.get(topic, 0) - before_out.get(topic, 0)) / per_s
                     for topic in dict.fromkeys([*topics_out, *totals_out])}

        events = program.bus.events
        now = time.monotonic()
        reported = program.reporter.reported
        self._bad_samples = [(at, count) for at, count in self._bad_samples if at >= now - RECENT_S]
        self._bad_samples.append((now, reported))
        own = program.health_check() if program.health_check is not None else None
        problems = assess(endpoints, program.optional_topics, now - self.started >= program.match_report_s,
                          events.recent_events(RECENT_S, *RECENT_WARNINGS),
                          events.not_alive(), reported - self._bad_samples[0][1], own)

        figure = ""
        if program.status_figure is not None:
            try:
                figure = program.status_figure()
            except Exception as error:  # noqa: BLE001  (as the status line: a figure that fails is said, not fatal)
                figure = f"(figure failed: {error})"
        if problems:
            level, message = problems[0].level, "; ".join(problem.message for problem in problems)
        else:
            parts = [rates_line(rates_in, rates_out), figure, own.message if own is not None else ""]
            level, message = OK, "; ".join(part for part in parts if part) or "idle"

        values: list[tuple[str, str]] = []
        if figure:
            values.append(("figure", figure))
        values += [(f"{topic} in/s", f"{rate:.3g}") for topic, rate in rates_in.items()]
        values += [(f"{topic} out/s", f"{rate:.3g}") for topic, rate in rates_out.items()]
        for endpoint in endpoints:
            side = "reader matched writers" if endpoint.reader else "writer matched readers"
            values.append((f"{endpoint.topic} {side}", str(endpoint.matched)))
        for topic in dict.fromkeys(endpoint.topic for endpoint in endpoints):
            values += [
                (f"{topic} deadline missed", str(events.count(topic, "requested_deadline_missed",
                                                               "offered_deadline_missed"))),
                (f"{topic} liveliness changes", str(events.count(topic, "liveliness_changed", "liveliness_lost"))),
                (f"{topic} samples lost", str(events.count(topic, "sample_lost", "sample_rejected"))),
                (f"{topic} incompatible QoS", str(events.count(topic, "requested_incompatible_qos",
                                                               "offered_incompatible_qos"))),
            ]
        values += latency_values(latency.recent.summaries())
        rss_mb = memtune.resident_bytes() / 1e6
        cpu = self.usage.cpu_percent()
        values += [("bad samples", str(reported)), ("RSS MB", f"{rss_mb:.1f}"), ("CPU %", f"{cpu:.1f}"),
                   ("pid", str(os.getpid())), ("domain", str(program.domain_id)),
                   ("uptime s", f"{now - self.started:.0f}")]
        return DiagnosticStatus_(level_=level, name_=program.instance_name, message_=message,
                                 hardware_id_=self.hostname,
                                 values_=[KeyValue_(key_=key, value_=value) for key, value in values])


# The keys of the latency values: "<topic> latency p50 ms (last 10 s)", "<topic> from <writer> latency p50 ms ...".
LATENCY_FROM = " from "
LATENCY_P50 = f" latency p50 ms (last {latency.WINDOW_S} s)"
LATENCY_P99 = f" latency p99 ms (last {latency.WINDOW_S} s)"
LATENCY_SAMPLES = f" latency samples (last {latency.WINDOW_S} s)"


def latency_values(summaries: list[latency.LatencySummary]) -> list[tuple[str, str]]:
    """The latency keys and values of each topic read, and of each of its writers (participants)."""
    values: list[tuple[str, str]] = []
    for summary in summaries:
        subject = summary.topic if summary.writer is None else f"{summary.topic}{LATENCY_FROM}{summary.writer}"
        values += [(subject + LATENCY_P50, f"{summary.p50_ms:.3f}"), (subject + LATENCY_P99, f"{summary.p99_ms:.3f}"),
                   (subject + LATENCY_SAMPLES, str(summary.count))]
    return values


def header() -> Header_:
    sec, nanosec = divmod(time.time_ns(), 1_000_000_000)
    return Header_(stamp_=Time_(sec_=sec, nanosec_=nanosec), frame_id_="")
