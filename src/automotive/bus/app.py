"""What every application shares: command line, properties, network, databus, run loop and clean shutdown.

An application is a function that receives an :class:`Application`, reads its properties, creates its endpoints
and runs its loop::

    def vision(app: Application) -> None:
        writer = app.writer("Vision", VisionSensor, default_topic="VisionTopic")
        for _ in app.periodic(app.props.get_int("config.pubInterval", 1000) / 1000):
            writer.write(...)

    def main(argv: list[str] | None = None) -> int:
        return run("vision", "Publishes vision sensor objects.", vision, argv)

Common flags: ``--properties FILE`` (default: the shipped ``properties/<name>.properties`` of
:mod:`automotive.config`), ``-D key=value`` (repeatable), ``--count N`` (stop after N iterations, 0 = run forever),
``--domain``, ``--network``, ``--interface``, ``--peers``, ``--stats FILE`` (status as JSON lines,
:mod:`automotive.bus.stats`), ``--filter TOPIC=EXPR`` (a content filter on the readers of TOPIC, also
``config.filter.<TOPIC>`` in the properties: :mod:`automotive.bus.contentfilter`). Ctrl-C and SIGTERM end the loop;
the entities are deleted and the exit code is 0. Bad input ends with one line on stderr and exit code 2. SIGUSR1
prints every thread's stack on stderr and the application goes on.
"""

from __future__ import annotations

import argparse
import gc
import logging
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import replace
from pathlib import Path
from types import FrameType
from typing import Any, Protocol, TypeVar

from cyclonedds.core import GuardCondition, InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader

from automotive import config, cyclone
from automotive.bus import badsamples, console, cyclonelog, diagnostics, memtune, realtime
from automotive.bus.checkedreader import deferred_bookkeeping
from automotive.bus.cli import (
    EXIT_BAD_INPUT,
    EXIT_INTERRUPTED,
    ArgumentParser,
    add_domain_option,
    add_network_options,
    add_override_option,
    add_stats_option,
    command_name,
    dump_stacks_on_request,
    input_file,
    on_signals,
    stop_dumping_stacks,
)
from automotive.bus.contentfilter import FILTER_PREFIX, TopicFilters
from automotive.bus.endpoints import Databus
from automotive.bus.errors import ConfigError
from automotive.bus.memtrace import start_from_environment as start_memory_probe
from automotive.bus.network import DEFAULT_MAX_PARTICIPANTS, NetworkConfig, read_user_config, user_uri
from automotive.bus.ports import MAX_PARTICIPANTS, check_domain_id
from automotive.bus.properties import Properties, PropertyKeys
from automotive.bus.qos import QosProfiles, profile_name
from automotive.bus.stats import Stats
from automotive.bus.status import EventHook
from automotive.cyclone.bounds import BoundError

T = TypeVar("T")

DEFAULT_LIBRARY = "AutomotiveLibrary"
# Redundant mode: an endpoint whose QoS profile P has a companion P + REDUNDANT_SUFFIX in the library uses it.
REDUNDANT_SUFFIX = "Redundant"
DEFAULT_OWNERSHIP_STRENGTH = 10
# The property keys the runtime reads for every program (Application, its network, content filters; each endpoint
# role adds topic.<Role> and qos.<Role>.Profile): with the program's own (``run``'s ``keys``), all it may be given.
RUNTIME_KEYS = PropertyKeys.of(
    "config.domainId", "qos.File", "qos.Library", "qos.Profile", "config.redundant", "config.instanceName",
    "config.matchReport", "config.mallocTrim", "config.statusInterval", "config.diagnosticsInterval",
    "config.badSampleReport", "config.network",
    "config.interface", "config.peers", "config.maxParticipants", "config.largeData", "config.ownershipStrength",
    realtime.PRIORITY_KEY, realtime.LOCK_MEMORY_KEY, families=[FILTER_PREFIX])

ArgumentAdder = Callable[[argparse.ArgumentParser], None]


def default_properties_path(name: str) -> Path:
    return config.properties_file(name)


def application_command(name: str) -> str:
    """The console script of an application: ``sensor_fusion`` -> ``automotive-sensor-fusion``."""
    return "automotive-" + name.replace("_", "-")


def build_parser(name: str, description: str, add_arguments: ArgumentAdder | None = None,
                 command: str | None = None) -> argparse.ArgumentParser:
    """The program's parser; its usage and hints name it as the user typed it (``command``: its own command, by
    default the application's console script)."""
    prog = command_name(command or application_command(name))
    # An application's examples (a tool's own come from its docstring: automotive.bus.cli.user_help).
    examples = None if command is not None else (
        f"examples:\n  {prog:<38} on this host, with the shipped properties\n"
        f"  {prog + ' --domain 7 -v':<38} on domain 7, every sample on the console\n"
        f"  {prog + ' -D config.KEY=VALUE':<38} one property changed (automotive config export DIR: all, to edit)")
    parser = ArgumentParser(prog=prog, description=description, epilog=examples)
    parser.add_argument("--properties", type=input_file, default=None,
                        help=f"properties file (default: the shipped properties/{name}.properties; "
                             "automotive config export DIR writes an editable copy)")
    add_override_option(parser)
    parser.add_argument("--count", type=int, default=0, help="stop after N iterations (0: run until stopped)")
    add_domain_option(parser)
    add_network_options(parser)
    add_stats_option(parser)
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="log every sample too (default: state changes and a status line every "
                             f"{console.STATUS_INTERVAL_S:g} s)")
    parser.add_argument("--filter", dest="filters", action="append", default=[], metavar="TOPIC=EXPR",
                        help="content filter of the readers of TOPIC, e.g. \"Circle=color = 'RED' AND x < 100\" "
                             "(repeatable; config.filter.<TOPIC> in the properties)")
    # The launcher's check before it starts anything: read the properties and overrides, refuse an unknown key, and
    # end without joining the bus (exit 0, or 2 with the one line).
    parser.add_argument("--check-config", action="store_true", help=argparse.SUPPRESS)
    if add_arguments is not None:
        add_arguments(parser)
    return parser


class Waits(Protocol):
    """What :meth:`Application.wake_ups` waits on: a Cyclone WaitSet, or a stand-in with the same call (the shared
    memory's, automotive.wire.shm.SharedFirstWaitSet)."""

    def wait(self, timeout: int, /) -> int: ...


class Application:
    """The running application: its arguments, properties, databus and stop signal."""

    def __init__(self, name: str, args: argparse.Namespace, props: Properties, log: logging.Logger):
        self.name = name
        self.args = args
        self.props = props
        self.log = log
        self.stop_event = threading.Event()
        # Set by the main thread's signal handler, which must take no lock (automotive.bus.cli.on_signals).
        self.stop_signalled = False
        self.stop_requested = False  # stop() was called (by the signal thread, or the application itself)
        if args.count < 0:
            raise ConfigError(f"--count {args.count}: expected 0 (forever) or a positive number")
        self.count: int = args.count
        if args.domain is not None:
            props.override([f"config.domainId={args.domain}"], "--domain")
        for flag, key in (("network", "config.network"), ("interface", "config.interface"), ("peers", "config.peers")):
            value = getattr(args, flag)
            if value is not None:
                props.override([f"{key}={value}"], f"--{flag}")
        try:  # the same words as --domain's (automotive.bus.ports)
            self.domain_id = check_domain_id(str(props.get_int("config.domainId", 0)))
        except ValueError as error:
            raise ConfigError(f"{props.where('config.domainId')}: config.domainId: {error}") from None
        self.library = props.get_str("qos.Library", DEFAULT_LIBRARY)
        self.profiles = QosProfiles(props.get_path("qos.File", str(config.qos_file())))
        # Redundant mode (hot-standby sensor_fusion and collision_avoidance, exclusive ownership): opt-in, because
        # exclusive endpoints do not match the shared ones of the default system and of other vendors' defaults.
        self.redundant = props.get_bool("config.redundant", False)
        # The name of this instance (two of an application run in redundant mode), given to the participant and to
        # exclusive writers: readers name the owner they follow with it.
        self.instance_name = props.get_str("config.instanceName", name)
        # After this many seconds, endpoints that matched nothing are reported: the sign of a wrong peer list,
        # domain id or QoS (0 turns the report off).
        self.match_report_s = props.get_float("config.matchReport", 10.0, minimum=0)
        # Every this many seconds the process looks whether its resident memory grew and then gives its free malloc
        # memory back to the kernel, so that a burst does not stay resident (automotive.bus.memtune.PeriodicTrim; 0
        # turns it off).
        self.malloc_trim_s = props.get_float("config.mallocTrim", memtune.TRIM_INTERVAL_S, minimum=0)
        # Every this many seconds one status line: samples in and out per topic, and the application's key figure
        # (``status_figure``); 0 turns it off.
        self.status_interval_s = props.get_float("config.statusInterval", console.STATUS_INTERVAL_S, minimum=0)
        self.status_figure: Callable[[], str] | None = None
        # Every this many seconds the program's health on ROS 2's /diagnostics (automotive.bus.diagnostics; 0: off).
        self.diagnostics_interval_s = props.get_float("config.diagnosticsInterval", diagnostics.DEFAULT_INTERVAL_S,
                                                      minimum=0)
        # The program's own verdict on its health, for /diagnostics (the HMI's alert source): a level and one line.
        self.health_check: diagnostics.HealthCheck | None = None
        self.diagnostics: diagnostics.Diagnostics | None = None
        self.optional_topics: set[str] = set()  # inputs the application does without (reader(..., optional=True))
        self.stats = Stats(getattr(args, "stats", None), self.instance_name)
        # Bad samples from the bus: one line per topic and kind, then a count every config.badSampleReport seconds.
        self.reporter = badsamples.configure(log, props.get_float("config.badSampleReport",
                                                                  badsamples.DEFAULT_INTERVAL_S, minimum=0.1))
        if not cyclonelog.install(self.reporter):
            log.info("Cyclone's log sink is not reachable: samples Cyclone drops are logged by Cyclone, one line each")
        # Content filters of the readers, per topic (config.filter.<Topic>, --filter TOPIC=EXPR).
        self.filters = TopicFilters(props, getattr(args, "filters", []))
        self.network, notice = self._network_config()
        # Real-time settings (automotive.bus.realtime): checked now, so that Cyclone's receive thread is created at the
        # priority; the taking thread (this one) takes it when the set-up is done (ready). Not permitted: one line.
        self.realtime = realtime.read_settings(props)
        if self.realtime.priority:
            problem = realtime.priority_problem(self.realtime.priority)
            if problem is None:
                self.network = replace(self.network, receive_thread_priority=self.realtime.priority)
            else:
                log.warning("%s", problem)
                self.realtime = replace(self.realtime, priority=0)
        if self.realtime.lock_memory and (problem := realtime.lock_memory()) is not None:
            log.warning("%s", problem)
        # The shipped default (one host, no configuration of the user's) is what everyone expects: said at DEBUG;
        # anything else is worth a line.
        shipped_default = (self.network.mode == "loopback" and not self.network.user_config
                           and not self.network.network_from_user)
        if notice is not None:
            log.warning("%s", notice)
        self.bus = Databus(self.domain_id, self.profiles, self.library, log, self.network, self.instance_name,
                           self.stats, self.reporter)
        # Said once Cyclone took the configuration: one it refuses is one line, naming the user's element.
        log.log(logging.DEBUG if shipped_default else logging.INFO, "network: %s", self.network.describe())
        self.guard = GuardCondition(self.bus.participant)
        # A stop served by the signal thread after the main thread, stopped by the same signal, closed the application
        # sets nothing: the guard went with the participant (Cyclone: BAD_PARAMETER, seen on a busy machine).
        self._guard_lock = threading.Lock()
        self._closed = False
        self._ready = False
        self.iterations = 0

    def _network_config(self) -> tuple[NetworkConfig, str | None]:
        """The network configuration, under the user's CYCLONEDDS_URI when one is set, and the line saying what that
        URI replaces (automotive.bus.network). An explicit network choice (config.network, config.interface or
        config.peers, from the properties or --network, --interface, --peers) wins over the URI's network."""
        explicit = next((f"{key} ({self.props.where(key)})" for key in ("config.network", "config.interface",
                                                                         "config.peers") if key in self.props), "")
        network = self.props.get_str("config.network", "")
        interface = self.props.get_str("config.interface", "")
        peers = self.props.get_list("config.peers", [])
        max_participants = self.props.get_int("config.maxParticipants", DEFAULT_MAX_PARTICIPANTS, minimum=1,
                                              maximum=MAX_PARTICIPANTS)
        large_data = self.props.get_bool("config.largeData", False)
        own = NetworkConfig.from_settings(network, interface, peers, max_participants, large_data, self.props.source)
        uri = user_uri()
        if uri is None:
            return own, None
        layering = own.layered(read_user_config(uri, self.domain_id), explicit)
        return layering.network, layering.notice

    # -- endpoints ---------------------------------------------------------------------------------------------
    def topic_name(self, role: str, default: str) -> str:
        return self.props.get_str(f"topic.{role}", default)

    def profile(self, role: str) -> str:
        """``qos.<role>.Profile`` (or ``qos.Profile``, or the role); in redundant mode its Redundant companion."""
        profile = profile_name(self.props, role)
        if self.redundant and self.profiles.has(self.library, profile + REDUNDANT_SUFFIX):
            return profile + REDUNDANT_SUFFIX
        return profile

    def writer(self, role: str, data_type: type[T], default_topic: str, hook: EventHook | None = None,
               overrides: tuple[Any, ...] = ()) -> DataWriter[T]:
        """A writer of the topic ``topic.<role>`` with the QoS profile ``qos.<role>.Profile`` (or ``qos.Profile``);
        ``overrides`` replace the profile's policies (a shared-memory writer's USER_DATA).

        A writer with exclusive ownership gets its strength from ``config.ownershipStrength``.
        """
        profile = self.profile(role)
        strength = None
        if self.profiles.exclusive_writer(self.library, profile):
            strength = self.props.get_int("config.ownershipStrength", DEFAULT_OWNERSHIP_STRENGTH, minimum=0,
                                          maximum=2**31 - 1)
        return self.bus.writer(self.topic_name(role, default_topic), data_type, profile, hook, strength, overrides)

    def reader(self, role: str, data_type: type[T], default_topic: str, hook: EventHook | None = None,
               optional: bool = False, overrides: tuple[Any, ...] = ()) -> DataReader[T]:
        """A reader of ``topic.<role>`` with the profile ``qos.<role>.Profile``, filtered when the topic has a
        content filter; ``optional``: an input the application does without (no warning while nobody writes it);
        ``overrides`` replace the profile's policies (a shared-memory reader's USER_DATA)."""
        topic = self.topic_name(role, default_topic)
        if optional:
            self.optional_topics.add(topic)
        return self.bus.reader(topic, data_type, self.profile(role), hook, overrides,
                               content_filter=self.filters.predicate(topic, data_type))

    # -- run loop ----------------------------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return not self.stop_event.is_set() and not self.stop_signalled

    @property
    def interrupted(self) -> bool:
        """Stopped before its work is done (a signal, an error): a write that flow control holds back gives up. The
        stop of ``--count``'s last iteration is not one: that iteration's sample is still to be written."""
        return self.stop_requested or self.stop_signalled

    def stop(self) -> None:
        self.stop_requested = True
        self._end_loops()

    def _end_loops(self) -> None:
        self.stop_event.set()
        with self._guard_lock:
            if not self._closed:
                self.guard.set(True)

    def ready(self) -> None:
        """Called once set-up is done: a property the application never read is a mistake worth stopping for."""
        if self._ready:
            return
        # The declaration's safety net: every key read must be declared, or a user could not set it (an unknown key
        # is refused before the program starts: run).
        undeclared = self.props.undeclared_reads()
        if undeclared:
            raise ConfigError(f"{self.name} reads property key(s) it does not declare: {', '.join(undeclared)} (a "
                              "defect of the program: its declaration must name every key it reads)")
        # A known key that this configuration never reads (config.ownershipStrength without an exclusive writer).
        unused = self.props.unused_keys()
        if unused:
            where = ", ".join(f"'{key}' ({self.props.where(key)})" for key in unused)
            raise ConfigError(f"{self.props.source}: unknown key(s) for {self.name}: {where}")
        self.filters.check_all_used(self.name, [endpoint.topic.name for endpoint in self.bus.endpoints
                                                if isinstance(endpoint, DataReader)])
        self._ready = True
        # The objects of the set-up (modules, types, QoS, endpoints) live as long as the process: out of the cyclic
        # collector's way, so that the collections the samples' objects trigger stay short. Before, a third of a
        # chain application's CPU was the collector walking them, inside the hops (docs/measurements/alert-latency.md).
        gc.freeze()
        self.stats.record("ready")
        if self.match_report_s > 0:
            threading.Thread(target=self._report_unmatched, name="match-report", daemon=True).start()
        if self.status_interval_s > 0:
            threading.Thread(target=self._report_status, name="status-line", daemon=True).start()
        if self.malloc_trim_s > 0:
            memtune.PeriodicTrim(self.stop_event, self.malloc_trim_s).start()
        if self.diagnostics_interval_s > 0:
            self.diagnostics = diagnostics.Diagnostics(self, self.diagnostics_interval_s, self.log)
            self.diagnostics.start()
        if self.realtime.priority:  # last: the threads above stay at the default policy
            realtime.raise_this_thread(self.realtime.priority)

    def _report_unmatched(self) -> None:
        if self.stop_event.wait(self.match_report_s):
            return
        unmatched = self.bus.unmatched()
        # Topics where an endpoint was seen but its QoS does not match: that, not the network, is what kept them apart
        # (its line, with the policy, was said when it was seen).
        mismatched = {topic: line.split("incompatible QoS ", 1)[-1].split(" ", 1)[0]
                      for topic, _, line in self.bus.events.recent_events(float("inf"), "requested_incompatible_qos",
                                                                           "offered_incompatible_qos")}
        for line in unmatched:
            topic = line[1:line.index("]")]
            if topic in mismatched:
                self.log.warning("%s after %g s: one was seen, its QoS does not match (%s)", line,
                                 self.match_report_s, mismatched[topic])
                continue
            # An optional input (the LiDAR's Shapes Demo circles) is often absent by design: its status line's 0/s
            # says so; a warning would cry wolf in every default run.
            optional = any(line.startswith(f"[{topic}] reader") for topic in self.optional_topics)
            self.log.log(logging.DEBUG if optional else logging.WARNING, "%s after %g s%s", line, self.match_report_s,
                         " (an optional input)" if optional else "")
        if unmatched and len(unmatched) == len(self.bus.endpoints) and not mismatched:
            self.log.warning("no peer seen after %g s: nothing matched on any topic (check the peers, the "
                             "interface, the domain id)", self.match_report_s)

    def _report_status(self) -> None:
        console.traffic.take_counts()  # what moved during set-up is not part of the first period
        topics_in = [endpoint.topic.get_name() for endpoint in self.bus.endpoints if isinstance(endpoint, DataReader)]
        topics_out = [endpoint.topic.get_name() for endpoint in self.bus.endpoints
                      if isinstance(endpoint, DataWriter)]
        last = time.monotonic()
        while not self.stop_event.wait(self.status_interval_s):
            now = time.monotonic()
            parts = [console.traffic.rates(now - last, topics_in, topics_out)]
            last = now
            if self.status_figure is not None:
                try:
                    parts.append(self.status_figure())
                except Exception as error:  # noqa: BLE001  (a figure that fails must not end the status line)
                    parts.append(f"(figure failed: {error})")
            self.log.info("status: %s", "; ".join(part for part in parts if part) or "idle")

    def tick(self) -> int:
        """Count one iteration of the application's work; stop once ``--count`` iterations are done."""
        self.iterations += 1
        if self.count and self.iterations >= self.count:
            self._end_loops()  # after this iteration, whose work is still to be done (not interrupted)
        return self.iterations

    def periodic(self, interval_s: float) -> Iterator[int]:
        """Yield iteration numbers 1, 2, ... every ``interval_s`` seconds until stopped or ``--count`` is reached."""
        self.ready()
        next_time = time.monotonic()
        while self.running:
            yield self.tick()
            next_time += interval_s
            delay = next_time - time.monotonic()
            if delay < 0:  # fell behind (a slow step): restart the schedule rather than burst
                next_time = time.monotonic()
            elif self.stop_event.wait(delay):
                break

    def waitset(self, *readers: DataReader[Any]) -> WaitSet:
        """A WaitSet woken by new samples on any of ``readers`` and by the stop signal."""
        waitset = WaitSet(self.bus.participant)
        for reader in readers:
            waitset.attach(ReadCondition(reader, SampleState.NotRead | ViewState.Any | InstanceState.Any))
        waitset.attach(self.guard)
        return waitset

    def wake_ups(self, waitset: Waits, timeout_s: float | Callable[[], float] = 1.0) -> Iterator[None]:
        """Yield after each wake-up of ``waitset`` (data or timeout) until stopped; ``timeout_s`` may be a function
        giving the time to wait before each wait (a periodic deadline).

        The application calls :meth:`tick` for each unit of its work, which ends the loop after ``--count`` of them.
        """
        self.ready()
        with deferred_bookkeeping() as book_takes, self.stats.deferred(self.log) as write_records:
            while self.running:
                book_takes()  # the counts and latencies of the last wake-up's takes, after its outputs
                write_records()  # and its --stats records
                wait_s = timeout_s() if callable(timeout_s) else timeout_s
                waitset.wait(max(int(wait_s * 1e9), 0))
                if self.running:
                    yield None

    def close(self) -> None:
        with self._guard_lock:
            self._closed = True
        if self.diagnostics is not None:
            self.diagnostics.stop()  # its writer goes with the participant
        self.bus.close()
        cyclonelog.uninstall()
        self.reporter.close()  # what is still counted is said now
        self.stats.close()


def load_properties(name: str, args: argparse.Namespace) -> Properties:
    path = args.properties or default_properties_path(name)
    props = Properties.load(path)
    props.override(args.overrides)
    return props


def run(name: str, description: str, body: Callable[[Application], None], argv: Sequence[str] | None = None,
        add_arguments: ArgumentAdder | None = None, command: str | None = None,
        keys: PropertyKeys | None = None) -> int:
    """Parse the command line, build the application, run ``body`` and shut down; return the exit code.

    ``command``: how a tool run through ``automotive`` is named (``automotive record``); an application's is its
    console script (``automotive-vision``). ``keys``: the property keys the program reads beyond RUNTIME_KEYS; with
    them, a key of the properties or of -D that it does not know is refused before anything starts."""
    parser = build_parser(name, description, add_arguments, command)
    args = parser.parse_args(argv)
    app: Application | None = None
    stdout_gone = False

    def stop_reader_gone() -> None:  # stdout's reader left (``| head``): end as if asked to
        nonlocal stdout_gone
        stdout_gone = True
        if app is not None:
            app.stop()

    log = console.setup_logging(name, args.verbose, stop_reader_gone)
    dump_stacks_on_request()  # SIGUSR1: where each thread is (the launcher asks before it kills a hung application)
    start_memory_probe(name)  # a diagnostic, only with AUTOMOTIVE_MEMTRACE set (automotive.bus.memtrace)

    stopped_while_starting: list[int] = []  # the signal that ended the set-up

    def stop_when_built(signum: int, frame: FrameType | None) -> None:
        # In the main thread, between two bytecodes: lock-free. Before the application exists nothing else stops the
        # set-up; once it exists, the signal thread stops it (stop_app), and the flag covers a signal that thread
        # served just before ``app`` was assigned.
        if app is None:
            stopped_while_starting.append(signum)
            raise KeyboardInterrupt
        app.stop_signalled = True

    def stop_app(signum: int) -> None:
        if app is not None:
            app.stop()

    restore_signals = on_signals((signal.SIGINT, signal.SIGTERM), stop_app, stop_when_built)
    try:
        props = load_properties(name, args)
        if keys is not None:  # an unknown key ends the program here, before it says or creates anything
            props.declare(RUNTIME_KEYS | keys, name)
        if getattr(args, "check_config", False):
            return 0
        cyclone.start(log)  # the fast paths, once, before any entity; or one line saying why they are off
        app = Application(name, args, props, log)
        if stdout_gone:
            app.stop()
        body(app)
        return 0
    except BrokenPipeError:  # a print to a closed stdout (the HMI's console box, a tool's table): end quietly
        console.silence_stdout()
        return 0
    except (ConfigError, BoundError) as error:
        print(f"{parser.prog}: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        if app is None:  # stopped while starting: one line; Ctrl-C says so in the exit code, SIGTERM ends cleanly
            log.info("stopped while starting")
            return EXIT_INTERRUPTED if stopped_while_starting[:1] != [signal.SIGTERM] else 0
        return 0
    finally:
        if app is not None:
            app.close()  # with our handlers still in place: a second signal (timeout -s INT sends two) cannot cut it
            log.info("stopped")
        restore_signals()
        stop_dumping_stacks()
