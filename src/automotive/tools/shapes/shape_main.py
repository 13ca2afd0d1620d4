"""A shape_main-compatible command: the OMG DDS interoperability suite's shape application, on this project's runtime.

    automotive shape-main -P -t Square -c BLUE -r -k 0 -w          # publish BLUE squares, reliable, keep all
    automotive shape-main -S -t Square --cft "shapesize <= 20"     # subscribe, only the small ones

The OMG suite (github omg-dds/dds-rtps) starts one vendor's shape application as publisher and another's as
subscriber with the QoS of each case on the command line, and classifies the case by what they print. This command
takes the options of the suite's reference application with their meaning and defaults (``-h`` lists them) and
prints the lines the suite's runner waits for: ``Create topic:``, ``Create writer for topic:``, ``Create reader for
topic:``, ``on_publication_matched()``, ``on_subscription_matched()``, ``on_offered_incompatible_qos()``,
``on_requested_incompatible_qos()``, the deadline-missed and liveliness notices, one line per sample
(``%-10s %-10s %03d %03d [%d]``, `` {last payload byte}`` with a payload) and one per instance that ends
(``NOT_ALIVE_DISPOSED_INSTANCE_STATE``, ``NOT_ALIVE_NO_WRITERS_INSTANCE_STATE``).

The type is the suite's (automotive.config's idl/shape.idl: ShapeType with additional_payload_size), registered as
"ShapeType". Both sides default to RELIABLE, VOLATILE, XCDR1 (``-x 2``: XCDR2), Cyclone's KEEP_LAST 1 history
(``-k 0``: KEEP_ALL).

What this command adds to Cyclone DDS, and what it cannot:

- Content filters are ours (automotive.bus.contentfilter): ``--cft EXPR`` and ``-c COLOR`` on a subscriber (the filter
  ``color = %0``) filter on the reader's side; a bad expression prints ``failed to create content filtered topic``
  and the reason (exit code 2).
- The end of a writer: its instances are unregistered (NOT_ALIVE_NO_WRITERS at the readers), as the suite expects,
  unless ``--final-instance-state d`` disposes them; Cyclone's own default would dispose them.
- Presentation: Cyclone sets and matches the policy (an incompatible access scope is reported as incompatible QoS
  PRESENTATION) and presents each instance's samples in order, but it neither writes nor presents coherent sets
  (its begin/end_coherent answer UNSUPPORTED) nor orders samples across instances or topics. So ``--coherent`` on a
  subscriber, ``--coherent-sample-count`` on a publisher, ``--ordered`` with access scope TOPIC or GROUP on a
  subscriber, and GROUP ordered access over several topics on a publisher print "not supported" (the reference's
  words) and end with exit code 2. The rest of the Presentation options work.

Network: loopback by default (``--network``, ``--interface``, ``--peers`` as the other applications). A user's own
CYCLONEDDS_URI is layered over this configuration as the applications layer it (automotive.bus.network): what it
sets wins, except over the network an explicit ``--network``, ``--interface`` or ``--peers`` chooses, and one
``warning: network: ...`` line names what it replaces. SIGINT or SIGTERM stop it cleanly; it then prints ``Done.``.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import random
import signal
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, NoReturn

from cyclonedds.core import DDSException, InstanceState, Listener
from cyclonedds.pub import DataWriter, Publisher
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader, Subscriber
from cyclonedds.topic import Topic

from automotive import config
from automotive.bus.app import DEFAULT_LIBRARY
from automotive.bus.checkedreader import CheckedReader
from automotive.bus.cli import on_signals
from automotive.bus.contentfilter import ContentFilter, FilteredReader, FilterError
from automotive.bus.endpoints import Databus, wait_for_acks
from automotive.bus.errors import ConfigError, refused_as_config_error
from automotive.bus.network import DEFAULT_MAX_PARTICIPANTS, NetworkConfig, read_user_config, user_uri
from automotive.bus.ports import check_domain_id
from automotive.bus.qos import QosProfiles
from automotive.bus.status import policy_name
from automotive.bus.version import add_version_option
from automotive.cyclone import logsink
from automotive.tools.shapes.shapes import MovingShape
from automotive.types.shape import ShapeType

PROG = "automotive shape-main"
TYPE_NAME = "ShapeType"
EXIT_BAD_INPUT = 2
MS = 1_000_000  # nanoseconds
MAX_BLOCKING_NS = 100 * MS  # the DDS default max_blocking_time of a reliable writer
ACK_WAIT_NS = 1000 * MS  # at the end a writer waits at most this long for its readers to acknowledge
TAKE_BATCH = 1000
MAX_TAKES_PER_PERIOD = 10
UNKNOWN_COLOR = "?"  # printed for an instance whose key could not be decoded
# A reader that joins a running Fast DDS writer gets its heartbeat only every 3 s; Cyclone keeps 128 samples until
# then and drops the rest (seen: 100 of 4 instances written every 33 ms lost). 512 covers 4 instances at 30 Hz.
REORDER_SAMPLES = 512
DURABILITY = {"v": "VOLATILE", "l": "TRANSIENT_LOCAL", "t": "TRANSIENT", "p": "PERSISTENT"}
SCOPES = {"i": "INSTANCE_PRESENTATION_QOS", "t": "TOPIC_PRESENTATION_QOS", "g": "GROUP_PRESENTATION_QOS"}

USAGE = f"""usage: {PROG} (-P | -S) -t TOPIC [options]
{PROG}: the OMG DDS interoperability suite's shape application on Cyclone DDS
   --help, -h      : print this menu
   -v [e|d]        : set log message verbosity [e: ERROR, d: DEBUG]
   -P              : publish samples
   -S              : subscribe samples
   -d <int>        : domain id (default: 0)
   -b              : BEST_EFFORT reliability
   -r              : RELIABLE reliability (default)
   -k <depth>      : keep history depth [0: KEEP_ALL]
   -f <interval>   : set a 'deadline' with interval (ms) [0: OFF]
   -s <strength>   : set ownership strength [-1: SHARED]
   -t <topic_name> : set the topic name
   -c <color>      : set color to publish (filter if subscriber)
   -p <partition>  : set a 'partition' string
   -D [v|l|t|p]    : set durability [v: VOLATILE,  l: TRANSIENT_LOCAL,
                                     t: TRANSIENT, p: PERSISTENT]
   -x [1|2]        : set data representation [1: XCDR, 2: XCDR2]
   -w              : print Publisher's samples
   -z <int>        : set shapesize (0: increase the size for every sample)
   -R              : use 'read()' instead of 'take()'
   --write-period <ms>  : waiting period between 'write()' operations in ms (default 33)
   --read-period <ms>   : waiting period between 'read()' or 'take()' operations in ms (default 100)
   --time-filter <ms>   : apply a 'time based filter' with this interval [0: OFF]
   --lifespan <ms>      : the lifespan of a sample
   --num-iterations <n> : iterations of the main loop, then exit (default: until stopped)
   --num-instances <n>  : instances written: BLUE, BLUE1, BLUE2...
   --num-topics <n>     : topics (and a writer or reader each): Square, Square1, Square2...
   --final-instance-state [u|d] : unregister or dispose the instances before the writer is deleted
   --access-scope [i|t|g]       : Presentation access scope INSTANCE, TOPIC or GROUP
   --coherent           : Presentation coherent_access = true
   --ordered            : Presentation ordered_access = true
   --coherent-sample-count <n>  : samples per writer and instance in a coherent set
   --additional-payload-size <bytes> : bytes added to every sample (large data)
   --take-read          : take()/read() instead of take/read of the next instance
   --periodic-announcement <ms> : participant announcement period (accepted, ignored)
   --datafrag-size <bytes>      : data fragment size (Cyclone's FragmentSize; 0: Cyclone's default)
   --cft <expression>   : content filter expression (subscribers; not with -c)
   --size-modulo <n>    : with -z 0, the size goes 1..n and round again
   --network loopback|lan|peers, --interface NAME, --peers HOST,...: where the traffic goes (default loopback)
"""


class UsageError(Exception):
    """A command line that cannot run: one line on stderr, exit code 2."""


@dataclass
class ShapeOptions:
    publish: bool = False
    subscribe: bool = False
    debug: bool = False
    domain_id: int = 0
    reliable: bool = True
    durability: str = "v"
    xcdr2: bool = False
    history_depth: int = -1  # -1: the default (KEEP_LAST 1), 0: KEEP_ALL
    ownership_strength: int = -1  # -1: SHARED
    topic: str | None = None
    color: str | None = None
    partition: str | None = None
    deadline_ms: int = 0
    time_filter_ms: int = 0
    lifespan_ms: int = 0
    shapesize: int = 20
    print_writer_samples: bool = False
    use_read: bool = False
    write_period_ms: int = 33
    read_period_ms: int = 100
    num_iterations: int = 0
    num_instances: int = 1
    num_topics: int = 1
    unregister: bool = False
    dispose: bool = False
    coherent: bool = False
    ordered: bool = False
    access_scope: str = "i"
    access_scope_set: bool = False
    coherent_sample_count: int = 0
    additional_payload_size: int = 0
    take_next_instance: bool = True
    periodic_announcement_ms: int = 0
    datafrag_size: int = 0
    cft: str | None = None
    size_modulo: int = 0
    network: str | None = None
    interface: str | None = None
    peers: str | None = None
    warnings: list[str] = field(default_factory=list)

    def topic_names(self) -> list[str]:
        assert self.topic is not None
        return [self.topic + (str(index) if index else "") for index in range(self.num_topics)]

    def instance_colors(self) -> list[str]:
        assert self.color is not None
        return [self.color + (str(index) if index else "") for index in range(self.num_instances)]


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        raise UsageError(message)


def _choice(option: str, value: str, allowed: str) -> str:
    if value[:1] not in allowed or not value:
        raise UsageError(f"{option} {value}: expected one of {', '.join(allowed)}")
    return value[0]


def _integer(option: str, value: str, minimum: int | None = None) -> int:
    try:
        number = int(value)
    except ValueError:
        raise UsageError(f"{option} {value}: expected an integer") from None
    if minimum is not None and number < minimum:
        raise UsageError(f"{option} {value}: expected at least {minimum}")
    return number


def parse_options(argv: Sequence[str]) -> ShapeOptions:
    parser = _Parser(prog=PROG, add_help=False, allow_abbrev=False)
    add_version_option(parser)
    for flag in ("-h", "--help", "-P", "-S", "-w", "-R", "--coherent", "--ordered", "--take-read"):
        parser.add_argument(flag, action="store_true", dest=flag.lstrip("-").replace("-", "_"))
    # -b and -r set one value: the last one given wins, as in the reference.
    parser.add_argument("-b", action="store_const", const=False, dest="reliable", default=True)
    parser.add_argument("-r", action="store_const", const=True, dest="reliable")
    for option in ("-v", "-d", "-k", "-f", "-s", "-t", "-c", "-p", "-D", "-x", "-z", "--write-period",
                   "--read-period", "--time-filter", "--lifespan", "--num-iterations", "--num-instances",
                   "--num-topics", "--final-instance-state", "--access-scope", "--coherent-sample-count",
                   "--additional-payload-size", "--periodic-announcement", "--datafrag-size", "--cft",
                   "--size-modulo", "--network", "--interface", "--peers"):
        parser.add_argument(option, dest="opt_" + option.lstrip("-").replace("-", "_"), default=None)
    args = parser.parse_args(list(argv))
    if args.h or args.help:
        print(USAGE, end="")
        sys.exit(0)
    o = ShapeOptions(publish=args.P, subscribe=args.S, print_writer_samples=args.w, use_read=args.R,
                     coherent=args.coherent, ordered=args.ordered, take_next_instance=not args.take_read,
                     reliable=args.reliable)
    value = vars(args)

    def get(option: str) -> str | None:
        return value["opt_" + option.lstrip("-").replace("-", "_")]  # type: ignore[no-any-return]

    if (text := get("-v")) is not None:
        o.debug = _choice("-v", text, "ed") == "d"
    if (text := get("-d")) is not None:
        try:  # the same words as every program's domain option (automotive.bus.ports)
            o.domain_id = check_domain_id(text)
        except ValueError as error:
            raise UsageError(f"-d: {error}") from None
    if (text := get("-k")) is not None:
        o.history_depth = _integer("-k", text, 0)
    if (text := get("-f")) is not None:
        o.deadline_ms = _integer("-f", text, 0)
    if (text := get("-s")) is not None:
        o.ownership_strength = _integer("-s", text, -1)
    o.topic, o.color, o.partition, o.cft = get("-t"), get("-c"), get("-p"), get("--cft")
    if (text := get("-D")) is not None:
        o.durability = _choice("-D", text, "vltp")
    if (text := get("-x")) is not None:
        o.xcdr2 = _choice("-x", text, "12") == "2"
    if (text := get("-z")) is not None:
        o.shapesize = _integer("-z", text, 0)
    for option, attribute, minimum in (("--write-period", "write_period_ms", 0), ("--read-period", "read_period_ms", 0),
                                       ("--time-filter", "time_filter_ms", 0), ("--lifespan", "lifespan_ms", 0),
                                       ("--num-iterations", "num_iterations", 1),
                                       ("--num-instances", "num_instances", 1), ("--num-topics", "num_topics", 1),
                                       ("--coherent-sample-count", "coherent_sample_count", 2),
                                       ("--additional-payload-size", "additional_payload_size", 1),
                                       ("--periodic-announcement", "periodic_announcement_ms", 0),
                                       ("--datafrag-size", "datafrag_size", 0), ("--size-modulo", "size_modulo", 1)):
        if (text := get(option)) is not None:
            setattr(o, attribute, _integer(option, text, minimum))
    if o.datafrag_size > 65535:
        raise UsageError(f"--datafrag-size {o.datafrag_size}: expected at most 65535 bytes")
    if (text := get("--final-instance-state")) is not None:
        state = _choice("--final-instance-state", text, "ud")
        o.unregister, o.dispose = state == "u", state == "d"
    if (text := get("--access-scope")) is not None:
        o.access_scope, o.access_scope_set = _choice("--access-scope", text, "itg"), True
    o.network, o.interface, o.peers = get("--network"), get("--interface"), get("--peers")
    validate(o)
    return o


def validate(o: ShapeOptions) -> None:
    """The reference's checks: errors raise UsageError, what it ignores is listed in ``o.warnings``."""
    if o.topic is None:
        raise UsageError("please specify topic name [-t]")
    if not o.publish and not o.subscribe:
        raise UsageError("please specify publish [-P] or subscribe [-S]")
    if o.publish and o.subscribe:
        raise UsageError("please specify only one of: publish [-P] or subscribe [-S]")
    if o.subscribe and o.color is not None and o.cft is not None:
        raise UsageError("error: cannot specify both --cft and -c for subscriber applications")
    warn = o.warnings.append
    if o.publish and o.color is None:
        o.color = "BLUE"
        warn('warning: color was not specified, defaulting to "BLUE"')
    ignored_on_publisher = ((o.time_filter_ms > 0, "time base filter [--time-filter]"), (o.use_read, "use read [-R]"),
                            (not o.take_next_instance, "--take-read"), (o.cft is not None, "--cft"))
    ignored_on_subscriber = ((o.shapesize != 20, "shapesize [-z]"), (o.lifespan_ms > 0, "--lifespan"),
                             (o.num_instances > 1, "--num-instances"),
                             (o.unregister or o.dispose, "--final-instance-state"),
                             (o.coherent_sample_count > 0, "--coherent-sample-count"),
                             (o.additional_payload_size > 0, "--additional-payload-size"))
    for condition, what in ignored_on_publisher if o.publish else ignored_on_subscriber:
        if condition:
            warn(f"warning: {what} ignored on {'publisher' if o.publish else 'subscriber'} applications")
    if not o.coherent and not o.ordered and o.coherent_sample_count:
        warn("warning: --coherent-sample-count ignored because not coherent, or ordered access enabled")
    if not o.coherent and not o.ordered and o.access_scope_set:
        warn("warning: --access-scope set but not coherent, or ordered access enabled")
    if o.size_modulo > 0 and o.shapesize != 0:
        warn("warning: --size-modulo has no effect unless shapesize (-z) is set to 0")
    if o.periodic_announcement_ms:
        warn("warning: --periodic-announcement ignored (Cyclone DDS announces on its own schedule)")


def unsupported_presentation(o: ShapeOptions) -> str | None:
    """The reference's "not supported" line for what Cyclone DDS cannot do of the Presentation options, else None."""
    if o.subscribe and o.coherent:
        return "    Presentation Coherent Access = not supported"  # Cyclone presents no coherent sets
    if o.publish and o.coherent and o.coherent_sample_count:
        return "    Presentation Coherent Access = not supported"  # begin/end_coherent: UNSUPPORTED
    if o.ordered and o.access_scope != "i" and (o.subscribe or (o.access_scope == "g" and o.num_topics > 1)):
        return "    Presentation Access Scope = not supported"  # ordered per instance only
    return None


# -- output --------------------------------------------------------------------------------------------------------
class Console:
    """Whole lines on stdout, flushed at once (the suite's runner reads a pty, our tests a pipe), from any thread."""

    def __init__(self, stop: threading.Event):
        self._lock = threading.Lock()
        self._stop = stop
        self._closed = False

    def line(self, text: str) -> None:
        with self._lock:
            if self._closed:
                return
            try:
                sys.stdout.write(text + "\n")
                sys.stdout.flush()
            except (BrokenPipeError, ValueError):  # nobody reads any more (a closed pipe): stop quietly
                self._closed = True
                self._stop.set()


def sample_line(topic: str, color: str, x: int, y: int, size: int, payload: bytes | Sequence[int]) -> str:
    line = f"{topic:<10} {color:<10} {x:03d} {y:03d} [{size}]"
    return line + (f" {{{payload[-1]}}}" if len(payload) else "")


class ShapeListener(Listener):
    """Prints every status event of one endpoint as the reference application does."""

    def __init__(self, console: Console, topic: str):
        super().__init__()
        self.console = console
        self.where = f"topic: '{topic}'  type: '{TYPE_NAME}'"

    def on_publication_matched(self, writer: Any, status: Any) -> None:
        self.console.line(f"on_publication_matched() {self.where} : matched readers {status.current_count} "
                          f"(change = {status.current_count_change})")

    def on_subscription_matched(self, reader: Any, status: Any) -> None:
        self.console.line(f"on_subscription_matched() {self.where} : matched writers {status.current_count} "
                          f"(change = {status.current_count_change})")

    def on_offered_incompatible_qos(self, writer: Any, status: Any) -> None:
        self.console.line(f"on_offered_incompatible_qos() {self.where} : {status.last_policy_id} "
                          f"({policy_name(status.last_policy_id)})")

    def on_requested_incompatible_qos(self, reader: Any, status: Any) -> None:
        self.console.line(f"on_requested_incompatible_qos() {self.where} : {status.last_policy_id} "
                          f"({policy_name(status.last_policy_id)})")

    def on_offered_deadline_missed(self, writer: Any, status: Any) -> None:
        self.console.line(f"on_offered_deadline_missed() {self.where} : (total = {status.total_count}, "
                          f"change = {status.total_count_change})")

    def on_requested_deadline_missed(self, reader: Any, status: Any) -> None:
        self.console.line(f"on_requested_deadline_missed() {self.where} : (total = {status.total_count}, "
                          f"change = {status.total_count_change})")

    def on_liveliness_lost(self, writer: Any, status: Any) -> None:
        self.console.line(f"on_liveliness_lost() {self.where} : (total = {status.total_count}, "
                          f"change = {status.total_count_change})")

    def on_liveliness_changed(self, reader: Any, status: Any) -> None:
        self.console.line(f"on_liveliness_changed() {self.where} : (alive = {status.alive_count}, "
                          f"not_alive = {status.not_alive_count})")


# -- QoS -----------------------------------------------------------------------------------------------------------
def _presentation(o: ShapeOptions) -> Any:
    scope = {"i": Policy.PresentationAccessScope.Instance, "t": Policy.PresentationAccessScope.Topic,
             "g": Policy.PresentationAccessScope.Group}[o.access_scope]
    return scope(coherent_access=o.coherent, ordered_access=o.ordered)


def group_qos(o: ShapeOptions) -> Qos:
    """The publisher's or subscriber's QoS: partition and presentation."""
    policies: list[Any] = [Policy.Partition([o.partition])] if o.partition is not None else []
    if o.coherent or o.ordered:
        policies.append(_presentation(o))
    return Qos(*policies)


def endpoint_policies(o: ShapeOptions) -> list[Any]:
    """What writers and readers share: reliability, durability, representation, ownership, deadline, history."""
    policies: list[Any] = [
        Policy.Reliability.Reliable(max_blocking_time=MAX_BLOCKING_NS) if o.reliable else Policy.Reliability.BestEffort,
        {"v": Policy.Durability.Volatile, "l": Policy.Durability.TransientLocal, "t": Policy.Durability.Transient,
         "p": Policy.Durability.Persistent}[o.durability],
        Policy.DataRepresentation(use_xcdrv2_representation=True) if o.xcdr2
        else Policy.DataRepresentation(use_cdrv0_representation=True),
        Policy.Ownership.Exclusive if o.ownership_strength != -1 else Policy.Ownership.Shared,
    ]
    if o.deadline_ms > 0:
        policies.append(Policy.Deadline(o.deadline_ms * MS))
    if o.history_depth > 0:
        policies.append(Policy.History.KeepLast(o.history_depth))
    elif o.history_depth == 0:
        policies.append(Policy.History.KeepAll)
    return policies


def writer_qos(o: ShapeOptions) -> Qos:
    policies = endpoint_policies(o)
    if o.ownership_strength != -1:
        policies.append(Policy.OwnershipStrength(o.ownership_strength))
    if o.lifespan_ms > 0:
        policies.append(Policy.Lifespan(o.lifespan_ms * MS))
    if o.durability != "v":
        # Cyclone keeps for late-joining readers what the durability service's history says (KEEP_LAST 1 by
        # default), not the writer's history: make them the same, as the other vendors do.
        history = Policy.History.KeepAll if o.history_depth == 0 else Policy.History.KeepLast(max(o.history_depth, 1))
        policies.append(Policy.DurabilityService(cleanup_delay=0, history=history, max_samples=-1, max_instances=-1,
                                                 max_samples_per_instance=-1))
    # Unregistering (explicitly at the end, or by deleting the writer) must not dispose: the suite expects
    # NOT_ALIVE_NO_WRITERS unless --final-instance-state d, which disposes explicitly.
    policies.append(Policy.WriterDataLifecycle(autodispose=False))
    return Qos(*policies)


def reader_qos(o: ShapeOptions) -> Qos:
    policies = endpoint_policies(o)
    if o.time_filter_ms > 0:
        policies.append(Policy.TimeBasedFilter(o.time_filter_ms * MS))
    return Qos(*policies)


# -- the application -------------------------------------------------------------------------------------------------
class ShapeApplication:
    """One participant with its topics and writers or readers, built from the options."""

    def __init__(self, o: ShapeOptions, console: Console, stop: threading.Event):
        self.o = o
        self.console = console
        self.stop = stop
        self.listeners: list[ShapeListener] = []
        self.writers: list[DataWriter[ShapeType]] = []
        self.readers: list[DataReader[ShapeType]] = []
        self.writes_not_done = 0
        self.write_warned_at = -float("inf")
        log = logging.getLogger(PROG)
        log.addHandler(logging.StreamHandler(sys.stderr))
        network, notice = self._network()
        if notice is not None:
            console.line(f"warning: {notice}")
        self.bus = Databus(o.domain_id, QosProfiles(config.qos_file()), DEFAULT_LIBRARY, log, network, "shape_main")
        self.topics: list[Topic[ShapeType]] = []
        for name in o.topic_names():
            console.line(f"Create topic: {name}")
            self.topics.append(self.bus.topic(name, ShapeType))

    def _network(self) -> tuple[NetworkConfig, str | None]:
        """The network configuration, under the user's CYCLONEDDS_URI when one is set (as automotive.bus.app layers
        it for the applications), and the line saying what that URI replaces; --network, --interface or --peers is
        an explicit choice that wins over the URI's network."""
        o = self.o
        peers = [peer.strip() for peer in (o.peers or "").split(",") if peer.strip()]
        own = NetworkConfig.from_settings(o.network or "", o.interface or "", peers, DEFAULT_MAX_PARTICIPANTS,
                                          False, "command line")
        own = dataclasses.replace(own, reorder_samples=REORDER_SAMPLES)
        if o.datafrag_size:
            own = dataclasses.replace(own, large_data=True, fragment_size=o.datafrag_size)
        uri = user_uri()
        if uri is None:
            return own, None
        explicit = next((option for option, value in (("--network", o.network), ("--interface", o.interface),
                                                      ("--peers", o.peers)) if value is not None), "")
        layering = own.layered(read_user_config(uri, o.domain_id), explicit)
        return layering.network, layering.notice

    def _listener(self, topic: str) -> ShapeListener:
        listener = ShapeListener(self.console, topic)
        self.listeners.append(listener)  # Cyclone keeps only a C reference
        return listener

    # -- publisher
    def run_publisher(self) -> None:
        o = self.o
        with refused_as_config_error("the publisher (-p)"):
            publisher = Publisher(self.bus.participant, qos=group_qos(o))
        qos = writer_qos(o)
        for topic in self.topics:
            self.console.line(f"Create writer for topic: {topic.name} color: {o.color}")
            with refused_as_config_error(f"the writer of {topic.name} with these QoS options"):
                self.writers.append(DataWriter(publisher, topic, qos=qos, listener=self._listener(topic.name)))
        rng = random.Random()
        assert o.color is not None
        shape = MovingShape(o.color, max(o.shapesize, 1), rng.randint(1, 5), rng)
        shape.size = o.shapesize
        payload = b"\xff" * o.additional_payload_size
        colors = o.instance_colors()
        iteration = 0
        next_write = time.monotonic()
        while not self.stop.is_set():
            shape.step()
            if o.shapesize == 0:
                shape.size = shape.size % o.size_modulo + 1 if o.size_modulo > 0 else shape.size + 1
            for writer in self.writers:
                for color in colors:
                    try:
                        writer.write(ShapeType(color=color, x=shape.x, y=shape.y, shapesize=shape.size,
                                               additional_payload_size=payload))
                    except DDSException as error:
                        self.write_not_done(writer.topic.name, color, error)
                        continue
                    if o.print_writer_samples:
                        self.console.line(sample_line(writer.topic.name, color, shape.x, shape.y, shape.size,
                                                      payload))
            iteration += 1
            if o.num_iterations and iteration >= o.num_iterations:
                break
            next_write = _wait_until(next_write + o.write_period_ms / 1000, self.stop)
        self.finish_instances(colors)

    def write_not_done(self, topic: str, color: str, error: DDSException) -> None:
        """A write Cyclone did not do: as the reference (which ignores write's result), the sample is not sent and
        the next one is tried. The usual case is a timeout: a KEEP_ALL reliable writer whose readers acknowledge
        slower than it writes blocks for max_blocking_time (100 ms) and gives up. Said on stderr, at most once a
        second, without digits in brackets (the suite's runner reads '[n]' as a sample's size)."""
        self.writes_not_done += 1
        now = time.monotonic()
        if now - self.write_warned_at >= 1.0:
            self.write_warned_at = now
            reason = str(error).split("]", 1)[0].lstrip("[")
            print(f"{PROG}: write of {color} on {topic} not done ({reason}), {self.writes_not_done} so far; "
                  "the next sample is tried", file=sys.stderr, flush=True)

    def finish_instances(self, colors: list[str]) -> None:
        """Unregister (the default) or dispose every instance, then give readers a second to acknowledge."""
        for writer in self.writers:
            for color in colors:
                key = ShapeType(color=color, x=0, y=0, shapesize=0, additional_payload_size=b"")
                try:
                    if self.o.dispose:
                        writer.dispose(key)
                    else:
                        writer.unregister_instance(key)
                except DDSException:
                    pass  # an instance never written (stopped before the first write): nothing to end
        for writer in self.writers:
            try:
                wait_for_acks(writer, ACK_WAIT_NS)
            except DDSException:
                pass  # not acknowledged in time: nothing more to do before the writer goes

    # -- subscriber
    def run_subscriber(self) -> None:
        o = self.o
        with refused_as_config_error("the subscriber (-p)"):
            subscriber = Subscriber(self.bus.participant, qos=group_qos(o))
        qos = reader_qos(o)
        content_filter = None
        if o.cft is not None or o.color is not None:
            try:
                color = o.color or ""
                expression = ContentFilter.parse(o.cft) if o.cft is not None else \
                    ContentFilter.parse("color = %0", [color if "'" in color else f"'{color}'"])
                content_filter = expression.bind(ShapeType)
            except FilterError as error:
                self.console.line("failed to create content filtered topic")
                raise ConfigError(f"--cft {o.cft!r}: {error}") from None
        for topic in self.topics:
            name = topic.name + ("_filtered" if content_filter is not None else "")
            self.console.line(f"Create reader for topic: {name}")
            listener = self._listener(topic.name)
            # Checked readers: a sample that does not decode or fails its checks is reported and left out (the
            # filter sees only the others).
            with refused_as_config_error(f"the reader of {name} with these QoS options"):
                if content_filter is not None:
                    self.readers.append(FilteredReader(subscriber, topic, qos=qos, listener=listener,
                                                       content_filter=content_filter))
                else:
                    self.readers.append(CheckedReader(subscriber, topic, qos=qos, listener=listener))
        iteration = 0
        while not self.stop.is_set():
            if o.ordered:
                self.console.line(f"Reading with ordered access, iteration {iteration}")
            for reader in self.readers:
                self.print_samples(reader)
            iteration += 1
            if o.num_iterations and iteration >= o.num_iterations:
                break
            # The waiting period between two reads, as the option says and as the interoperability suite's own
            # shape_main waits: a read that a loaded machine woke late is not followed by one that comes early (with
            # a lifespan, two reads too close together see one run of samples where the suite expects two).
            self.stop.wait(o.read_period_ms / 1000)

    def print_samples(self, reader: DataReader[ShapeType]) -> None:
        get = reader.read if self.o.use_read else reader.take
        samples: list[Any] = []
        for _ in range(MAX_TAKES_PER_PERIOD):  # bounded: a writer faster than this loop never keeps it here
            batch = get(N=TAKE_BATCH)
            samples.extend(batch)
            if len(batch) < TAKE_BATCH or self.o.use_read or self.stop.is_set():
                break
        if self.o.take_next_instance:  # take/read_next_instance: instance by instance, in handle order
            samples.sort(key=lambda sample: _unsigned(sample.sample_info.instance_handle))
        topic = reader.topic.name
        for sample in samples:
            info = sample.sample_info
            if info.valid_data:
                self.console.line(sample_line(topic, sample.color, sample.x, sample.y, sample.shapesize,
                                              sample.additional_payload_size))
            if info.instance_state == InstanceState.Alive:
                continue
            key = sample if info.valid_data else sample.key_sample
            # The key of an instance whose last sample was bad may not decode either (a colour that is not UTF-8).
            color = getattr(key, "color", None) or UNKNOWN_COLOR
            state = "NOT_ALIVE_DISPOSED_INSTANCE_STATE" if info.instance_state == InstanceState.NotAliveDisposed \
                else "NOT_ALIVE_NO_WRITERS_INSTANCE_STATE"
            self.console.line(f"{topic:<10} {color:<10} {state}")

    def close(self) -> None:
        for endpoint in [*self.writers, *self.readers]:
            endpoint.set_listener(None)  # waits for a callback in progress; none starts after this
        self.writers.clear()
        self.readers.clear()
        self.bus.close()


def _unsigned(handle: int) -> int:
    return handle & 0xFFFFFFFFFFFFFFFF


def _wait_until(deadline: float, stop: threading.Event) -> float:
    """Sleep until ``deadline`` (monotonic) or the stop signal; a step that ran late restarts the schedule."""
    delay = deadline - time.monotonic()
    if delay < 0:
        return time.monotonic()
    stop.wait(delay)
    return deadline


def print_debug(o: ShapeOptions, console: Console) -> None:
    shown = {name: value for name, value in dataclasses.asdict(o).items() if name != "warnings"}
    console.line("Shape Options: " + ", ".join(f"{name}={value}" for name, value in shown.items()))
    console.line(f"    DurabilityKind = {DURABILITY[o.durability]}, Access Scope = {SCOPES[o.access_scope]}")


def quiet_cyclone_warnings() -> None:
    """Cyclone's warnings go to stderr, which the suite's runner reads with stdout; one it prints for every disposal
    by a Fast DDS or RTI writer ("<time> [0] recv: ... deserialization ... failed (keyhash is MD5 ...)") carries a
    "[0]" that the runner takes for a sample's size. Errors still show (with the gate closed, the warnings too)."""
    logsink.set_log_mask(logsink.LC_FATAL | logsink.LC_ERROR)


def main(argv: Sequence[str] | None = None) -> int:
    quiet_cyclone_warnings()
    if hasattr(sys.stdout, "reconfigure"):
        sys.stdout.reconfigure(line_buffering=True)  # type: ignore[union-attr]
    stop = threading.Event()
    console = Console(stop)
    try:
        options = parse_options(sys.argv[1:] if argv is None else argv)
    except UsageError as error:
        print(f"{PROG}: {error} ({PROG} -h shows the options)", file=sys.stderr)
        return EXIT_BAD_INPUT
    for warning in options.warnings:
        console.line(warning)
    if options.debug:
        print_debug(options, console)

    # stop.set() runs in the signal thread, never in the handler, where it can deadlock (automotive.bus.cli).
    restore_signals = on_signals((signal.SIGINT, signal.SIGTERM), lambda signum: stop.set())
    application: ShapeApplication | None = None
    try:
        application = ShapeApplication(options, console, stop)
        unsupported = unsupported_presentation(options)
        if unsupported is not None:
            console.line(unsupported)
            return EXIT_BAD_INPUT
        if options.publish:
            application.run_publisher()
        else:
            application.run_subscriber()
    except ConfigError as error:
        print(f"{PROG}: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    finally:
        if application is not None:
            application.close()
        restore_signals()
        ignore_stop_signals()
    console.line("Done.")
    return 0


def ignore_stop_signals() -> None:
    """Once the command's work is done, SIGINT and SIGTERM have nothing left to stop. The suite's runner (and the
    tests) send SIGINT whenever they are done, also while the command is already ending (a "not supported" exit);
    Python gives a handler of its own back to the default at interpreter shutdown, and the signal would then end the
    process by the signal (exit -2) instead of with its exit code. An ignored signal stays ignored."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)


if __name__ == "__main__":
    sys.exit(main())
