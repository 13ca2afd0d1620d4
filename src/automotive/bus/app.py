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
import logging
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from types import FrameType
from typing import Any, TypeVar

from cyclonedds.core import GuardCondition, InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader

from automotive import config, cyclone
from automotive.bus import badsamples, cyclonelog, memtune
from automotive.bus.cli import (
    EXIT_BAD_INPUT,
    MAX_DOMAIN_ID,
    ArgumentParser,
    add_domain_option,
    add_network_options,
    add_override_option,
    add_stats_option,
    dump_stacks_on_request,
    on_signals,
    stop_dumping_stacks,
)
from automotive.bus.contentfilter import TopicFilters
from automotive.bus.endpoints import Databus
from automotive.bus.errors import ConfigError
from automotive.bus.memtrace import start_from_environment as start_memory_probe
from automotive.bus.network import DEFAULT_MAX_PARTICIPANTS, NetworkConfig, user_uri
from automotive.bus.properties import Properties
from automotive.bus.qos import QosProfiles, profile_name
from automotive.bus.stats import Stats
from automotive.bus.status import EventHook
from automotive.cyclone.bounds import BoundError

T = TypeVar("T")

DEFAULT_LIBRARY = "AutomotiveLibrary"
# Redundant mode: an endpoint whose QoS profile P has a companion P + REDUNDANT_SUFFIX in the library uses it.
REDUNDANT_SUFFIX = "Redundant"
DEFAULT_OWNERSHIP_STRENGTH = 10

ArgumentAdder = Callable[[argparse.ArgumentParser], None]


def default_properties_path(name: str) -> Path:
    return config.properties_file(name)


def build_parser(name: str, description: str, add_arguments: ArgumentAdder | None = None) -> argparse.ArgumentParser:
    parser = ArgumentParser(prog=name, description=description)
    parser.add_argument("--properties", type=Path, default=None,
                        help=f"properties file (default: the shipped properties/{name}.properties; "
                             "automotive-config export DIR writes an editable copy)")
    add_override_option(parser)
    parser.add_argument("--count", type=int, default=0, help="stop after N iterations (0: run until stopped)")
    add_domain_option(parser)
    add_network_options(parser)
    add_stats_option(parser)
    parser.add_argument("--filter", dest="filters", action="append", default=[], metavar="TOPIC=EXPR",
                        help="content filter of the readers of TOPIC, e.g. \"Circle=color = 'RED' AND x < 100\" "
                             "(repeatable; config.filter.<TOPIC> in the properties)")
    if add_arguments is not None:
        add_arguments(parser)
    return parser


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
        if args.count < 0:
            raise ConfigError(f"--count {args.count}: expected 0 (forever) or a positive number")
        self.count: int = args.count
        if args.domain is not None:
            props.override([f"config.domainId={args.domain}"], "--domain")
        for flag, key in (("network", "config.network"), ("interface", "config.interface"), ("peers", "config.peers")):
            value = getattr(args, flag)
            if value is not None:
                props.override([f"{key}={value}"], f"--{flag}")
        self.domain_id = props.get_int("config.domainId", 0, minimum=0, maximum=MAX_DOMAIN_ID)
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
        self.stats = Stats(getattr(args, "stats", None), self.instance_name)
        # Bad samples from the bus: one line per topic and kind, then a count every config.badSampleReport seconds.
        self.reporter = badsamples.configure(log, props.get_float("config.badSampleReport",
                                                                  badsamples.DEFAULT_INTERVAL_S, minimum=0.1))
        if not cyclonelog.install(self.reporter):
            log.info("Cyclone's log sink is not reachable: samples Cyclone drops are logged by Cyclone, one line each")
        # Content filters of the readers, per topic (config.filter.<Topic>, --filter TOPIC=EXPR).
        self.filters = TopicFilters(props, getattr(args, "filters", []))
        self.network = self._network_config()
        if self.network is None:
            log.info("network: CYCLONEDDS_URI from the environment")
        else:
            log.info("network: %s", self.network.describe())
        self.bus = Databus(self.domain_id, self.profiles, self.library, log, self.network, self.instance_name,
                           self.stats, self.reporter)
        self.guard = GuardCondition(self.bus.participant)
        self._ready = False
        self.iterations = 0

    def _network_config(self) -> NetworkConfig | None:
        explicit = any(key in self.props for key in ("config.network", "config.interface", "config.peers"))
        network = self.props.get_str("config.network", "")
        interface = self.props.get_str("config.interface", "")
        peers = self.props.get_list("config.peers", [])
        max_participants = self.props.get_int("config.maxParticipants", DEFAULT_MAX_PARTICIPANTS, minimum=1)
        large_data = self.props.get_bool("config.largeData", False)
        if user_uri() is not None and not explicit:
            return None
        return NetworkConfig.from_settings(network, interface, peers, max_participants, large_data, self.props.source)

    # -- endpoints ---------------------------------------------------------------------------------------------
    def topic_name(self, role: str, default: str) -> str:
        return self.props.get_str(f"topic.{role}", default)

    def profile(self, role: str) -> str:
        """``qos.<role>.Profile`` (or ``qos.Profile``, or the role); in redundant mode its Redundant companion."""
        profile = profile_name(self.props, role)
        if self.redundant and self.profiles.has(self.library, profile + REDUNDANT_SUFFIX):
            return profile + REDUNDANT_SUFFIX
        return profile

    def writer(self, role: str, data_type: type[T], default_topic: str, hook: EventHook | None = None) -> DataWriter[T]:
        """A writer of the topic ``topic.<role>`` with the QoS profile ``qos.<role>.Profile`` (or ``qos.Profile``).

        A writer with exclusive ownership gets its strength from ``config.ownershipStrength``.
        """
        profile = self.profile(role)
        strength = None
        if self.profiles.exclusive_writer(self.library, profile):
            strength = self.props.get_int("config.ownershipStrength", DEFAULT_OWNERSHIP_STRENGTH, minimum=0,
                                          maximum=2**31 - 1)
        return self.bus.writer(self.topic_name(role, default_topic), data_type, profile, hook, strength)

    def reader(self, role: str, data_type: type[T], default_topic: str, hook: EventHook | None = None) -> DataReader[T]:
        """A reader of ``topic.<role>`` with the profile ``qos.<role>.Profile``, filtered when the topic has a
        content filter."""
        topic = self.topic_name(role, default_topic)
        return self.bus.reader(topic, data_type, self.profile(role), hook,
                               content_filter=self.filters.predicate(topic, data_type))

    # -- run loop ----------------------------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return not self.stop_event.is_set() and not self.stop_signalled

    def stop(self) -> None:
        self.stop_event.set()
        self.guard.set(True)

    def ready(self) -> None:
        """Called once set-up is done: a property the application never read is a mistake worth stopping for."""
        if self._ready:
            return
        unused = self.props.unused_keys()
        if unused:
            where = ", ".join(f"'{key}' ({self.props.where(key)})" for key in unused)
            raise ConfigError(f"{self.props.source}: unknown key(s) for {self.name}: {where}")
        self.filters.check_all_used(self.name, [endpoint.topic.name for endpoint in self.bus.endpoints
                                                if isinstance(endpoint, DataReader)])
        self._ready = True
        self.stats.record("ready")
        if self.match_report_s > 0:
            threading.Thread(target=self._report_unmatched, name="match-report", daemon=True).start()
        if self.malloc_trim_s > 0:
            memtune.PeriodicTrim(self.stop_event, self.malloc_trim_s).start()

    def _report_unmatched(self) -> None:
        if self.stop_event.wait(self.match_report_s):
            return
        unmatched = self.bus.unmatched()
        for line in unmatched:
            self.log.warning("%s after %g s", line, self.match_report_s)
        if unmatched and len(unmatched) == len(self.bus.endpoints):
            self.log.warning("no peer seen after %g s: nothing matched on any topic (check the peers, the "
                             "interface, the domain id)", self.match_report_s)

    def tick(self) -> int:
        """Count one iteration of the application's work; stop once ``--count`` iterations are done."""
        self.iterations += 1
        if self.count and self.iterations >= self.count:
            self.stop()
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

    def wake_ups(self, waitset: WaitSet, timeout_s: float | Callable[[], float] = 1.0) -> Iterator[None]:
        """Yield after each wake-up of ``waitset`` (data or timeout) until stopped; ``timeout_s`` may be a function
        giving the time to wait before each wait (a periodic deadline).

        The application calls :meth:`tick` for each unit of its work, which ends the loop after ``--count`` of them.
        """
        self.ready()
        while self.running:
            wait_s = timeout_s() if callable(timeout_s) else timeout_s
            waitset.wait(max(int(wait_s * 1e9), 0))
            if self.running:
                yield None

    def close(self) -> None:
        self.bus.close()
        cyclonelog.uninstall()
        self.reporter.close()  # what is still counted is said now
        self.stats.close()


def setup_logging(name: str) -> logging.Logger:
    # Line-buffered output, so that a launcher or a test reading a pipe sees each line at once.
    if hasattr(sys.stdout, "reconfigure"):
        sys.stdout.reconfigure(line_buffering=True)  # type: ignore[union-attr]
    handler = logging.StreamHandler(sys.stdout)
    handler.setFormatter(logging.Formatter("%(asctime)s.%(msecs)03d %(name)s: %(message)s", "%H:%M:%S"))
    log = logging.getLogger(name)
    log.handlers[:] = [handler]
    log.setLevel(logging.INFO)
    log.propagate = False
    return log


def load_properties(name: str, args: argparse.Namespace) -> Properties:
    path = args.properties or default_properties_path(name)
    props = Properties.load(path)
    props.override(args.overrides)
    return props


def run(name: str, description: str, body: Callable[[Application], None], argv: Sequence[str] | None = None,
        add_arguments: ArgumentAdder | None = None) -> int:
    """Parse the command line, build the application, run ``body`` and shut down; return the exit code."""
    args = build_parser(name, description, add_arguments).parse_args(argv)
    log = setup_logging(name)
    dump_stacks_on_request()  # SIGUSR1: where each thread is (the launcher asks before it kills a hung application)
    start_memory_probe(name)  # a diagnostic, only with AUTOMOTIVE_MEMTRACE set (automotive.bus.memtrace)
    app: Application | None = None

    def stop_when_built(signum: int, frame: FrameType | None) -> None:
        # In the main thread, between two bytecodes: lock-free. Before the application exists nothing else stops the
        # set-up; once it exists, the signal thread stops it (stop_app), and the flag covers a signal that thread
        # served just before ``app`` was assigned.
        if app is None:
            raise KeyboardInterrupt
        app.stop_signalled = True

    def stop_app(signum: int) -> None:
        if app is not None:
            app.stop()

    restore_signals = on_signals((signal.SIGINT, signal.SIGTERM), stop_app, stop_when_built)
    try:
        cyclone.start(log)  # the fast paths, once, before any entity; or one line saying why they are off
        app = Application(name, args, load_properties(name, args), log)
        body(app)
        return 0
    except (ConfigError, BoundError) as error:
        print(f"{name}: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return 0
    finally:
        if app is not None:
            app.close()  # with our handlers still in place: a second signal (timeout -s INT sends two) cannot cut it
            log.info("stopped")
        restore_signals()
        stop_dumping_stacks()
