"""Participant, topics, publisher/subscriber, writers and readers created from (library, profile) QoS pairs.

This is what the original applications do with create_..._with_profile; every endpoint gets the shared status
listener, so its DDS events are reported with its topic name. Every reader is a CheckedReader: its take hands the
application only samples that decode and pass their type's checks, and reports the others
(automotive.bus.checkedreader).
"""

from __future__ import annotations

import logging
import socket
from dataclasses import replace
from typing import Any, TypeVar

import psutil
from cyclonedds.core import DDSException
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter, Publisher
from cyclonedds.qos import DataReaderQos, DataWriterQos, Policy, Qos
from cyclonedds.sub import DataReader, Subscriber
from cyclonedds.topic import Topic

from automotive.bus import badsamples, console, cyclonelog, memtune
from automotive.bus.badsamples import BadSampleReporter
from automotive.bus.checkedreader import CheckedReader
from automotive.bus.contentfilter import FilteredReader, Predicate
from automotive.bus.errors import ConfigError, refused_as_config_error
from automotive.bus.network import URI_VARIABLE, NetworkConfig, PeerPlan, user_uri
from automotive.bus.ports import domain_base, highest_port
from automotive.bus.qos import QosProfiles
from automotive.bus.stats import Stats
from automotive.bus.status import EventCounts, EventHook, StatusListener
from automotive.cyclone import bounds, codec_hook, hostonly, typeinfo
from automotive.cyclone.matched import matched_publications, matched_subscriptions

T = TypeVar("T")


class NamedTopic(Topic[T]):  # type: ignore[type-var]  # generated types: unchecked
    """A Topic that keeps its name: Cyclone DDS Python's ``name`` and ``get_name()`` ask the C library into a fresh
    256-byte buffer at each call, and the readers and writers name their topic for every sample they count."""

    def __init__(self, participant: DomainParticipant, name: str, data_type: type[T], **kwargs: Any):
        super().__init__(participant, name, data_type, **kwargs)
        self._name = name

    def get_name(self, max_size: int = 256) -> str:
        return self._name

    name = property(get_name, doc="the topic's name")  # type: ignore[assignment]


class CheckedWriter(DataWriter[T]):
    """A DataWriter that refuses, with a clear BoundError, a sample over its IDL bounds before serializing it."""

    def write(self, sample: T, timestamp: int | None = None) -> None:
        if not codec_hook.installed(type(sample)):  # a type's codec checks the bounds as it encodes
            bounds.check(sample)
        # numpy arrays of fixed-size structs are written by the generated codecs; made dataclasses for Cyclone's
        # serializer when the codecs are not plugged in (the version gate is closed)
        super().write(codec_hook.writable(sample), timestamp)
        console.traffic.count_out(self.topic.name)


def wait_for_acks(writer: DataWriter[Any], timeout_ns: int) -> bool:
    """True when every matched reliable reader acknowledged what ``writer`` wrote, False when ``timeout_ns`` ran out
    first. DataWriter.wait_for_acks of Cyclone DDS Python 11.0.1 raises AttributeError instead of returning False (it
    compares with ``Exception.DDS_RETCODE_TIMEOUT``, Python's builtin Exception): seen as a traceback of shape-main
    on a busy machine."""
    try:
        return writer.wait_for_acks(timeout_ns)
    except AttributeError as error:
        if "DDS_RETCODE_TIMEOUT" not in str(error):
            raise
        return False


def open_domain(domain_id: int, network: NetworkConfig, plan: PeerPlan, log: logging.Logger) -> Domain:
    """The Cyclone domain with the applications' network configuration. In loopback mode with the interface
    Cyclone's default tools use on this host (its LAN interface; lo on a host with only the loopback), its sockets are
    made deaf to other hosts (automotive.cyclone.hostonly) before any participant joins it;
    if that cannot be done, or the domain's discovery multicast port is another program's, the domain is opened on
    127.0.0.1 only, with a warning: the application runs, unseen by Cyclone's default tools."""
    lan_interface = "" if network.network_from_user else network.lan_interface()
    if not lan_interface:
        return _domain(domain_id, network, plan)
    network = replace(network, host_interface=lan_interface)
    # A fixed port, unlike the participant index ports (Cyclone takes the next free index): domains from 102 up lie
    # in the kernel's range of ephemeral ports, where any program's socket may hold it for a while. Looked at first,
    # so that Cyclone does not print its own error; and again if Cyclone fails (taken meanwhile).
    port_taken = f"the domain's discovery multicast port {domain_base(domain_id)} is taken by another program"
    if _port_taken(domain_base(domain_id)):
        return _loopback_only(domain_id, network, plan, log, port_taken)
    before = hostonly.open_sockets()
    try:
        domain = _domain(domain_id, network, plan)
    except ConfigError as error:
        if not _port_taken(domain_base(domain_id)):
            raise
        log.debug("network: %s", error)
        return _loopback_only(domain_id, network, plan, log, port_taken)
    addresses = tuple(address.address for address in psutil.net_if_addrs().get(lan_interface, [])
                      if address.family == socket.AF_INET) + ("127.0.0.1",)
    try:
        filtered = hostonly.restrict(before, addresses, range(domain_base(domain_id), highest_port(domain_id) + 1))
        if not filtered.covers(domain_base(domain_id)):
            raise hostonly.FilterError(0, "its discovery sockets were not found")
    except OSError as error:
        del domain
        return _loopback_only(domain_id, network, plan, log, str(error.strerror or error))
    return domain


def _loopback_only(domain_id: int, network: NetworkConfig, plan: PeerPlan, log: logging.Logger, why: str) -> Domain:
    log.warning("network: Cyclone DDS tools on their defaults will not see this application: %s; staying on "
                "127.0.0.1 only", why)
    return _domain(domain_id, replace(network, host_interface=""), plan)


def _port_taken(port: int) -> bool:
    """Whether another program holds a UDP port so that Cyclone cannot share it (bound without address reuse)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(("0.0.0.0", port))
        except OSError:
            return True
    return False


def _domain(domain_id: int, network: NetworkConfig, plan: PeerPlan) -> Domain:
    cyclonelog.take_config_problems()  # only what this domain's configuration gets said
    try:
        return Domain(domain_id, network.cyclone_xml(plan))
    except DDSException as error:
        problems = cyclonelog.take_config_problems()
        if problems and network.user_config:  # Cyclone named the element: the user's, in the user's words
            raise ConfigError(f"{URI_VARIABLE}: " + "; ".join(dict.fromkeys(problems))) from None
        if problems:
            raise ConfigError(f"network {network.describe()}: Cyclone refused the configuration: "
                              + "; ".join(dict.fromkeys(problems))) from None
        raise ConfigError(f"network {network.describe()}: Cyclone refused the configuration ({error})") from None


class Databus:
    """One participant of one application, with its endpoints."""

    def __init__(self, domain_id: int, profiles: QosProfiles, library: str, log: logging.Logger,
                 network: NetworkConfig | None = None, name: str = "automotive", stats: Stats | None = None,
                 reporter: BadSampleReporter | None = None):
        memtune.settle_malloc()  # before the first receive buffer: resident memory settles (automotive.bus.memtune)
        typeinfo.enable()  # the types' XTypes information from the build-time table (the version gate decides)
        self.name = name
        self.stats = stats or Stats(None, name)
        self.reporter = reporter  # of bad samples; None: the process's (automotive.bus.badsamples)
        self.domain_id = domain_id
        self.profiles = profiles
        self.library = library
        self.log = log
        # A Domain object carries our network configuration; with the user's own CYCLONEDDS_URI we leave it alone.
        self.domain: Domain | None = None
        if network is not None:
            plan = network.peer_plan()
            for peer, reason in plan.unusable:
                log.warning("network: peer %s left out: %s", peer, reason)
            self.domain = open_domain(domain_id, network, plan, log)
        try:
            self.participant = DomainParticipant(domain_id, qos=Qos(Policy.EntityName(name)))
        except DDSException as error:
            hint = f"CYCLONEDDS_URI={user_uri()}" if network is None else network.describe()
            raise ConfigError(f"cannot join DDS domain {domain_id} ({hint}): {error}") from None
        self.publisher = Publisher(self.participant)
        self.subscriber = Subscriber(self.participant)
        self._topics: dict[str, Topic[Any]] = {}
        self._listeners: list[StatusListener] = []
        self.events = EventCounts()  # the status events of every endpoint, by topic and kind (/diagnostics)
        # Strong references until close(): Cyclone Python deletes an entity when its last Python reference goes,
        # and if that happens inside the entity's own listener callback (a reader's "unmatched" as a writer
        # leaves), the process hangs. Holding them here makes close() the one place they are let go.
        self._endpoints: list[DataWriter[Any] | DataReader[Any]] = []

    def topic(self, name: str, data_type: type[T]) -> Topic[T]:  # type: ignore[type-var]
        topic = self._topics.get(name)
        if topic is None:
            with refused_as_config_error(f"topic '{name}'"):
                topic = NamedTopic(self.participant, name, data_type)
            self._topics[name] = topic
        elif topic.data_type is not data_type:
            raise ConfigError(f"topic '{name}' is used with two types: {topic.data_type.__name__} "
                              f"and {data_type.__name__}")
        return topic

    def _listener(self, topic_name: str, hook: EventHook | None, exclusive: bool = False) -> StatusListener:
        listener = StatusListener(topic_name, self.log, hook, exclusive, self.stats,
                                  self.reporter or badsamples.reporter(), self.events)
        self._listeners.append(listener)  # Cyclone keeps only a C reference: keep the Python object alive
        return listener

    def writer(self, topic_name: str, data_type: type[T], profile: str,
               hook: EventHook | None = None, strength: int | None = None,
               overrides: tuple[Any, ...] = ()) -> DataWriter[T]:
        """A writer; ``strength`` is its ownership strength (EXCLUSIVE profiles), sent with the instance's name;
        ``overrides`` are policies that replace the profile's (the site bridge's writers: liveliness, user data)."""
        qos = self.profiles.writer_qos(self.library, profile)
        if overrides:
            qos = DataWriterQos(*overrides, base=qos)
        if strength is not None:
            # The entity name travels with the writer's discovery data: readers name the owner they follow.
            qos = DataWriterQos(Policy.OwnershipStrength(strength), Policy.EntityName(self.name), base=qos)
        topic = self.topic(topic_name, data_type)
        with refused_as_config_error(f"the writer of topic '{topic_name}' with QoS profile '{profile}'"):
            writer = CheckedWriter(self.publisher, topic, qos=qos, listener=self._listener(topic_name, hook))
        self._endpoints.append(writer)
        return writer

    def reader(self, topic_name: str, data_type: type[T], profile: str, hook: EventHook | None = None,
               overrides: tuple[Any, ...] = (), content_filter: Predicate | None = None) -> DataReader[T]:
        """A reader with the profile's reader QoS; ``overrides`` are policies that replace the profile's (a
        recorder keeps every sample: History.KeepAll); with ``content_filter``, a reader that returns only the
        checked samples it accepts (automotive.bus.contentfilter)."""
        qos = self.profiles.reader_qos(self.library, profile)
        if overrides:
            qos = DataReaderQos(*overrides, base=qos)
        topic = self.topic(topic_name, data_type)
        exclusive = Policy.Ownership.Exclusive in qos
        listener = self._listener(topic_name, hook, exclusive)
        reader: DataReader[T]
        with refused_as_config_error(f"the reader of topic '{topic_name}' with QoS profile '{profile}'"):
            if content_filter is None:
                reader = CheckedReader(self.subscriber, topic, qos=qos, listener=listener, reporter=self.reporter)
            else:
                reader = FilteredReader(self.subscriber, topic, qos=qos, listener=listener, reporter=self.reporter,
                                        content_filter=content_filter)
        self._endpoints.append(reader)
        return reader

    @property
    def endpoints(self) -> list[DataWriter[Any] | DataReader[Any]]:
        return list(self._endpoints)

    def unmatched(self) -> list[str]:
        """A description of each endpoint that has matched nothing so far (no remote reader or writer)."""
        lines = []
        for endpoint in self._endpoints:
            topic = endpoint.topic.get_name()
            if isinstance(endpoint, DataWriter) and not matched_subscriptions(endpoint):
                lines.append(f"[{topic}] writer: no reader matched")
            elif isinstance(endpoint, DataReader) and not matched_publications(endpoint):
                lines.append(f"[{topic}] reader: no writer matched")
        return lines

    def close(self) -> None:
        """Delete the participant and everything in it (Cyclone deletes children with their parent)."""
        for endpoint in self._endpoints:
            endpoint.set_listener(None)  # waits for a callback in progress; none starts after this
        self.participant.__del__()
        self._endpoints.clear()
        self._topics.clear()
        self._listeners.clear()
        if self.domain is not None:
            self.domain.__del__()
