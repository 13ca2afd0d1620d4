"""Site bridge: carries chosen topics of this site's databus to other sites over Eclipse Zenoh, and theirs back.

Data flow, per topic (automotive.tools.flows; --topics, bridge.allow/deny to choose):

  this site's writers --DDS--> a reader of the flow's profile (raw CDR, never decoded; automotive.wire.rawsample)
    --> a bounded queue with the topic's budget (automotive.bus.budget: max rate, max bandwidth, the newest kept)
    --> Zenoh: key <scope>/<topic>, the CDR bytes as payload, an envelope (kind, source timestamp, sequence,
        site, type name) as attachment; mutual TLS between sites (automotive.wire.zenoh_link)
    --> the other site's bridge: a bounded queue --> a writer of the flow's profile --DDS--> that site's readers

- **No loops.** The bridge's writers carry a mark in their user data and its readers ignore this participant's
  writers; a sample from another bridge's writer (two bridges on one site) is recognised by that mark and not
  forwarded; a sample that comes back over Zenoh from this site's name is not written.
- **QoS across the link.** Reliable flows: Zenoh's blocking congestion control, complete and in order while the
  queues hold (bounded: the oldest dropped and counted). Best-effort flows: Zenoh drops them under congestion.
  Transient-local flows (the alerts): a Zenoh publication cache of the profile's depth, which a bridge starting or
  reconnecting later queries, so a late HMI on the far site shows the current alert.
- **Liveliness.** While a site has live writers of a topic (its own, not a bridge's), its bridge holds a Zenoh
  liveliness token for it. The far site's bridge writes the topic with a writer of MANUAL_BY_TOPIC liveliness
  that it asserts only while such a token exists: when the writers (or their bridge, or the link) go, the far
  readers see the writer's liveliness lost after ``bridge.livelinessLease`` (the HMI: "alert source LOST").
  Asserting needs Cyclone's ``dds_assert_liveliness`` (automotive.cyclone.liveliness, behind the version gate);
  without it the bridge's writers keep the profile's liveliness and one line says that liveliness is not carried.
- **Budgets** per topic: ``bridge.maxFrequency`` (Hz) and ``bridge.maxMbps``; what they drop is
  counted and reported once a second, with the queues' sizes, as a log line and (``--stats FILE``) JSON lines:
  a ``status`` record a second and a ``summary`` at the end (automotive.bus.stats).
- **Bad samples from the link** (no valid envelope, another type) and refused writes are ignored and reported like
  bad samples from the bus: one line, then a count per interval (automotive.bus.badsamples).
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import psutil
import zenoh
import zenoh.ext
from cyclonedds.core import DDSException
from cyclonedds.qos import DataWriterQos, Policy
from cyclonedds.util import duration

from automotive.bus.app import Application, run
from automotive.bus.badsamples import BadSample
from automotive.bus.budget import Budget, SampleQueue
from automotive.bus.errors import ConfigError
from automotive.bus.properties import Properties, PropertyKeys
from automotive.bus.stats import Every
from automotive.cyclone import liveliness
from automotive.tools.flows import Flow, select, system_flows
from automotive.wire.rawsample import RawReader, RawSample, RawWriter, SampleKind, signed_handle
from automotive.wire.zenoh_link import (
    Envelope,
    EnvelopeError,
    LinkSettings,
    ZenohLog,
    data_key,
    parse_writers_key,
    without_source_location,
    writers_key,
    writers_prefix,
    zenoh_config,
)

# The property keys it reads beyond the runtime's (automotive.bus.app.RUNTIME_KEYS): any other is refused at start.
PROPERTY_KEYS = PropertyKeys.of(
    # the link (automotive.wire.zenoh_link.LinkSettings)
    "zenoh.site", "zenoh.scope", "zenoh.mode", "zenoh.listen", "zenoh.connect", "zenoh.tls.ca", "zenoh.tls.certificate",
    "zenoh.tls.key", "zenoh.allowPlainTcp", "zenoh.lease",
    # the topics and their budgets
    "bridge.allow", "bridge.deny", "bridge.maxFrequency", "bridge.maxMbps", "bridge.priority", "bridge.queueDepth",
    "bridge.queueMB", "bridge.readerDepth", "bridge.livelinessLease")

BRIDGE_MARK = b"automotive zenoh-bridge"  # the user data of every writer a bridge creates
TAKE_LIMIT = 64
STATUS_INTERVAL_S = 1.0
PRIORITIES = {"real_time": zenoh.Priority.REAL_TIME, "interactive_high": zenoh.Priority.INTERACTIVE_HIGH,
              "interactive_low": zenoh.Priority.INTERACTIVE_LOW, "data_high": zenoh.Priority.DATA_HIGH,
              "data": zenoh.Priority.DATA, "data_low": zenoh.Priority.DATA_LOW,
              "background": zenoh.Priority.BACKGROUND}
INFINITE_NS = 2**63 - 1
WRITER_CACHE = 1024  # writers per topic whose bridge mark is remembered (forgotten all at once beyond)


def rss_mb() -> float:
    """This process's resident memory in MB."""
    try:
        return float(psutil.Process().memory_info().rss) / 1e6
    except psutil.Error:
        return 0.0


def topic_values(props: Properties, key: str, topics: list[str], minimum: float) -> dict[str, float]:
    """``topic=number,topic=number`` (as zenoh-bridge-dds' --max-frequency); every topic must be one of ``topics``."""
    values: dict[str, float] = {}
    for item in props.get_list(key, []):
        topic, separator, number = item.rpartition("=")
        if not separator or not topic:
            raise ConfigError(f"{props.where(key)}: {key}: '{item}' is not topic=number")
        if topic not in topics:
            raise ConfigError(f"{props.where(key)}: {key}: unknown topic '{topic}' (known: {', '.join(topics)})")
        try:
            value = float(number)
        except ValueError:
            raise ConfigError(f"{props.where(key)}: {key}: '{number}' (for {topic}) is not a number") from None
        if value < minimum:
            raise ConfigError(f"{props.where(key)}: {key}: {value:g} for {topic} is below {minimum:g}")
        values[topic] = value
    return values


def topic_choices(props: Properties, key: str, topics: list[str], choices: dict[str, Any]) -> dict[str, str]:
    """``topic=name,topic=name``, each name one of ``choices``."""
    values: dict[str, str] = {}
    for item in props.get_list(key, []):
        topic, separator, name = item.rpartition("=")
        if not separator or topic not in topics or name not in choices:
            raise ConfigError(f"{props.where(key)}: {key}: '{item}' is not topic=one of {', '.join(choices)} "
                              f"(topics: {', '.join(topics)})")
        values[topic] = name
    return values


def choose_flows(props: Properties, flows: list[Flow], topics_option: str) -> list[Flow]:
    """The flows to bridge: --topics (or bridge.allow; all when empty) less bridge.deny (automotive.tools.flows'
    selection, as the recorder and the Foxglove bridge choose theirs)."""
    allow, deny = props.get_list("bridge.allow", []), props.get_list("bridge.deny", [])
    if topics_option:
        allowed = select(flows, topics_option)  # the command line wins over the properties
    else:
        allowed = select(flows, ",".join(allow), props.where("bridge.allow") + ": bridge.allow")
    denied = {flow.topic for flow in select(flows, ",".join(deny), props.where("bridge.deny") + ": bridge.deny")
              } if deny else set()
    chosen = [flow for flow in allowed if flow.topic not in denied]
    if not chosen:
        raise ConfigError(f"{props.source}: no topic left to bridge (allow: "
                          f"{', '.join(flow.topic for flow in allowed)}; deny: {', '.join(sorted(denied))})")
    return chosen


@dataclass
class InboundCounts:
    received: int = 0
    written: int = 0
    link_gaps: int = 0  # samples missing in a sending bridge's sequence (best effort: dropped on the way)
    own_site: int = 0  # came back from this site's name: not written (no loops)
    bad: int = 0  # not ours, or of another type: not written
    rejected: int = 0  # DDS refused to write them


@dataclass
class Route:
    """One topic, both ways: this site's writers to the link, the link to this site's readers."""

    flow: Flow
    key: str
    writer_qos: DataWriterQos
    outbound: SampleQueue[RawSample]
    inbound: SampleQueue[tuple[Envelope, bytes]]
    priority: str  # a key of PRIORITIES
    reader: RawReader | None = None
    publisher: Any = None
    subscriber: Any = None
    proxy: RawWriter | None = None
    sequence: int = 0
    taken: int = 0
    sent: int = 0
    sent_bytes: int = 0
    from_bridges: int = 0  # samples of another bridge's writers: not forwarded
    publish_errors: int = 0
    dropped_no_route: int = 0  # best effort, while no other site subscribes: dropped (reliable flows wait)
    matched: threading.Event = field(default_factory=threading.Event)  # another site subscribes to the key
    inbound_counts: InboundCounts = field(default_factory=InboundCounts)
    # This site's writers of the topic: their handles, alive or not, and which are other bridges' writers.
    alive_writers: set[int] = field(default_factory=set)
    writer_is_bridge: dict[int, bool] = field(default_factory=dict)
    token: Any = None
    # The other sites whose tokens say they have live writers of the topic: token key -> site.
    remote_writers: dict[str, str] = field(default_factory=dict)
    last_sequence: dict[str, int] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)
    # Held around each put: a new session's publisher replaces the old one only between puts.
    send_lock: threading.Lock = field(default_factory=threading.Lock)
    # Transient-local flows: what the publication cache holds (payload, attachment), put again into a new session's.
    recent: deque[tuple[bytes, bytes]] | None = None

    @property
    def topic(self) -> str:
        return self.flow.topic

    @property
    def reliable(self) -> bool:
        return Policy.Reliability.BestEffort not in self.writer_qos

    @property
    def transient_local(self) -> bool:
        return Policy.Durability.TransientLocal in self.writer_qos or \
            Policy.Durability.Transient in self.writer_qos or Policy.Durability.Persistent in self.writer_qos

    @property
    def depth(self) -> int:
        for policy in self.writer_qos:
            if isinstance(policy, Policy.History.KeepLast):
                return int(policy.depth)
        return 1


class SiteBridge:
    """The bridge of one site: its Zenoh session, the routes, and the threads that move samples."""

    def __init__(self, app: Application, settings: LinkSettings, flows: list[Flow], topics: list[str]):
        self.app = app
        self.log = app.log
        self.settings = settings
        props = app.props
        frequencies = topic_values(props, "bridge.maxFrequency", topics, 0.001)
        bandwidths = topic_values(props, "bridge.maxMbps", topics, 0.001)
        priorities = topic_choices(props, "bridge.priority", topics, PRIORITIES)
        depth = props.get_int("bridge.queueDepth", 64, minimum=1)
        queue_bytes = int(props.get_float("bridge.queueMB", 16, minimum=0.001) * 1e6)
        self.reader_depth = props.get_int("bridge.readerDepth", 16, minimum=1)
        self.lease_s = props.get_float("bridge.livelinessLease", 2.0, minimum=0.1)
        self.reporter = app.reporter  # bad samples from the link, refused writes: one line, then counts
        self.routes: dict[str, Route] = {}
        for flow in flows:
            budget = Budget(frequencies.get(flow.topic),
                            bandwidths[flow.topic] * 1e6 / 8 if flow.topic in bandwidths else None)
            self.routes[flow.topic] = Route(
                flow, data_key(settings.scope, flow.topic), app.profiles.writer_qos(app.library, flow.profile),
                SampleQueue(depth, queue_bytes, budget), SampleQueue(depth, queue_bytes),
                priorities.get(flow.topic, "data"))
        self.assert_liveliness = liveliness.asserter()
        if self.assert_liveliness is None:
            self.log.warning("liveliness is not carried across the link: Cyclone's dds_assert_liveliness is not "
                             "usable here (%s); this site's readers see the other sites' writers as always alive",
                             self._why_no_liveliness())
        self.zenoh_log = ZenohLog(lambda text: self.log.warning("%s", text))
        self.session: zenoh.Session | None = None
        self.zid = ""
        self.peers: dict[str, str] = {}  # zid -> router/peer, of the open transports
        self.threads: list[threading.Thread] = []
        self._entities: list[Any] = []  # Zenoh subscribers and listeners of the session, kept alive until it closes
        # The session is replaced whole (see _renew_session); callbacks of an older one are ignored by generation.
        self._session_lock = threading.Lock()
        self._generation = 0
        self._renewal = threading.Event()
        self._stop = threading.Event()
        self.renewals = 0
        self._sites_seen: dict[str, set[str]] = {}  # topic -> other bridges' token keys of this site's name

    @staticmethod
    def _why_no_liveliness() -> str:
        from automotive.cyclone import why_off

        return why_off() or "libddsc lacks the call"

    # -- set-up ----------------------------------------------------------------------------------------------
    def open(self) -> None:
        self.zenoh_log.start([handler for handler in self.log.handlers if hasattr(handler, "setStream")])
        for route in self.routes.values():
            self._open_route(route)
        try:
            self._start_session()
        except zenoh.ZError as error:
            raise ConfigError(f"{self.settings.source}: cannot open the Zenoh link ({self.settings.describe()}): "
                              f"{without_source_location(str(error))}") from None
        for route in self.routes.values():
            self._start_threads(route)
        if self.settings.connect:
            thread = threading.Thread(target=self._renew_loop, name="zenoh-renewal", daemon=True)
            thread.start()
            self.threads.append(thread)

    def _start_session(self) -> None:
        """Open a Zenoh session and declare on it what the bridge needs: its transport events, every route's
        publisher and subscriber, the other sites' liveliness tokens."""
        session = zenoh.open(zenoh_config(self.settings))
        self._generation += 1
        generation = self._generation
        self.session, self.zid, self.peers = session, str(session.zid()), {}
        if generation == 1:
            self.log.info("link: %s; Zenoh id %s", self.settings.describe(), self.zid)
        try:
            self._entities = [session.info.declare_transport_events_listener(
                lambda event: self._on_transport(event, generation), history=True)]
            for route in self.routes.values():
                self._declare_route(session, route, generation)
            self._entities.append(session.liveliness().declare_subscriber(
                f"{writers_prefix(self.settings.scope)}/**", lambda sample: self._on_token(sample, generation),
                history=True))
        except zenoh.ZError:
            _close_session(session)  # not left open beside the next attempt
            raise

    def _open_route(self, route: Route) -> None:
        """The DDS side of a route: its reader of this site's writers."""
        flow = route.flow

        def on_event(event: str, topic: str, status: Any) -> None:
            self._on_reader_event(route, event, status)

        # This site's writers, never this participant's own (IgnoreLocal); enough history that a burst waits
        # for the main loop instead of being replaced, and never a reader that holds a writer back (keep last, no
        # resource limits of the profile's).
        reader = self.app.bus.reader(flow.topic, flow.data_type, flow.profile, on_event,
                                     overrides=(Policy.History.KeepLast(self.reader_depth),
                                                Policy.ResourceLimits(-1, -1, -1), Policy.IgnoreLocal.Participant))
        route.reader = RawReader(reader, zero_copy=False)
        if route.transient_local:
            route.recent = deque(maxlen=route.depth)

    def _declare_route(self, session: zenoh.Session, route: Route, generation: int) -> None:
        """The Zenoh side of a route, on one session."""
        congestion = zenoh.CongestionControl.BLOCK if route.reliable else zenoh.CongestionControl.DROP
        reliability = zenoh.Reliability.RELIABLE if route.reliable else zenoh.Reliability.BEST_EFFORT
        if route.transient_local:
            route.publisher = zenoh.ext.declare_advanced_publisher(
                session, route.key, congestion_control=congestion, priority=PRIORITIES[route.priority],
                reliability=reliability, allowed_destination=zenoh.Locality.REMOTE,
                cache=zenoh.ext.CacheConfig(route.depth), publisher_detection=True)
            route.subscriber = zenoh.ext.declare_advanced_subscriber(
                session, route.key, lambda sample: self._on_sample(route, sample),
                allowed_origin=zenoh.Locality.REMOTE,
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=route.depth))
            route.matched.set()  # what it publishes while no site listens waits in its cache
            for payload, attachment in route.recent or ():  # a new session's cache holds what the old one held
                route.publisher.put(payload, attachment=attachment)
        else:
            # Other sites only: this session's own subscriber of the key must not count as a listener.
            route.publisher = session.declare_publisher(route.key, congestion_control=congestion,
                                                        priority=PRIORITIES[route.priority],
                                                        reliability=reliability,
                                                        allowed_destination=zenoh.Locality.REMOTE)
            route.subscriber = session.declare_subscriber(route.key, lambda sample: self._on_sample(route, sample),
                                                          allowed_origin=zenoh.Locality.REMOTE)

            def on_matching(status: Any) -> None:
                if generation != self._generation:
                    return  # an older session's publisher, closing
                if status.matching:
                    route.matched.set()
                else:
                    route.matched.clear()

            self._entities.append(route.publisher.declare_matching_listener(on_matching))
            if route.publisher.matching_status:
                route.matched.set()

    def _start_threads(self, route: Route) -> None:
        flow = route.flow
        for target, name in ((self._send_loop, "to-link"), (self._write_loop, "from-link")):
            thread = threading.Thread(target=target, args=(route,), name=f"{name} {flow.topic}", daemon=True)
            thread.start()
            self.threads.append(thread)
        budget = route.outbound.budget
        self.log.info("[%s] route: key %s, %s%s, priority %s, budget %s", flow.topic, route.key,
                      "reliable (blocking)" if route.reliable else "best effort (dropping)",
                      f", publication cache of {route.depth}" if route.transient_local else "",
                      route.priority, budget.describe())

    # -- Zenoh callbacks (Zenoh's threads) --------------------------------------------------------------------
    def _on_transport(self, event: Any, generation: int) -> None:
        if generation != self._generation:
            return  # an older session's transports, closing with it
        transport = event.transport
        zid, kind = str(transport.zid), str(transport.whatami).split(".")[-1].lower()
        if event.kind == zenoh.SampleKind.PUT:
            self.peers[zid] = kind
            self.log.info("link: connected to %s %s (%d open)", kind, zid, len(self.peers))
        else:
            if self.peers.pop(zid, None) is None:
                return  # the end of a transport that closed before (its socket lingered): nothing changes
            self.log.warning("link: %s %s disconnected (%d open)", kind, zid, len(self.peers))
            if not self.peers and self.settings.connect:
                self._renewal.set()

    # -- a new session once every link is down ---------------------------------------------------------------
    # A transport that Zenoh is still closing (its socket lingers up to 10 s while data it sent is unacknowledged)
    # ends by deleting whatever transport the manager holds for that peer's Zenoh id: if this site has reconnected
    # meanwhile, the other site's new transport to it is cut and carries nothing more, while both sides stay
    # connected (eclipse-zenoh/zenoh#1886; docs/measurements/zenoh.md). A site that dials its links therefore comes
    # back with a new Zenoh id, which no closing transport can match: a new session, declared again as before.
    def _renew_loop(self) -> None:
        while True:
            self._renewal.wait()
            if self._stop.is_set():
                return
            self._renewal.clear()
            self._renew_session()

    def _renew_session(self) -> None:
        with self._session_lock:
            for route in self.routes.values():
                route.send_lock.acquire()
            try:
                old, old_zid = self.session, self.zid
                for route in self.routes.values():
                    route.token = None  # undeclared with the old session
                    if not route.transient_local:
                        route.matched.clear()
                self._generation += 1  # nothing of the old session counts any more
                if old is not None and self.settings.listen:
                    _close_session(old)  # its listening sockets first: the new session listens on the same
                    old = None
                failures = 0
                while not self._stop.is_set():
                    try:
                        self._start_session()
                        break
                    except zenoh.ZError as error:
                        if failures == 0:
                            self.log.warning("link: cannot open a new Zenoh session: %s; retrying every second",
                                             without_source_location(str(error)))
                        failures += 1
                        self._stop.wait(1.0)
                self.renewals += 1
            finally:
                for route in self.routes.values():
                    route.send_lock.release()
        if old is not None:  # its transports may linger: closed aside, the new session dials meanwhile
            threading.Thread(target=_close_session, args=(old,), name="zenoh-close", daemon=True).start()
        if self._stop.is_set():
            return
        self.log.info("link: every link was down: a new Zenoh session, id %s (was %s), so that a link the other "
                      "site still closes cannot cut the next one", self.zid, old_zid)

    def _on_token(self, sample: zenoh.Sample, generation: int) -> None:
        if generation != self._generation:
            return
        key = str(sample.key_expr)
        token = parse_writers_key(self.settings.scope, key)
        if token is None or token.topic not in self.routes:
            return
        route = self.routes[token.topic]
        alive = sample.kind == zenoh.SampleKind.PUT
        if token.zid == self.zid:
            return  # this bridge's own token
        if token.site == self.settings.site:
            if alive:
                self.reporter.repeated_event(token.topic, "same_site_bridge",
                                             f"another bridge also routes this topic for site {token.site}: the "
                                             "other sites get its samples twice (give each bridge its own topics, "
                                             "or its own zenoh.scope)")
            return
        if token.type_name != route.flow.type_name:
            self.reporter.repeated_event(token.topic, "remote_type",
                                         f"site {token.site} has writers of type {token.type_name}, this site "
                                         f"{route.flow.type_name}: not bridged")
            return
        with route.lock:
            before = bool(route.remote_writers)
            if alive:
                route.remote_writers[key] = token.site
            else:
                route.remote_writers.pop(key, None)
            after = bool(route.remote_writers)
        if after and not before:
            self.log.info("[%s] writers alive on site %s: this site gets a writer of the topic", token.topic,
                          token.site)
        elif before and not after:
            self.log.warning("[%s] no writer alive on the other sites any more (site %s's went): this site's "
                             "readers see the writer's liveliness lost within %g s", token.topic, token.site,
                             self.proxy_lease_s(route))

    def _on_sample(self, route: Route, sample: zenoh.Sample) -> None:
        counts = route.inbound_counts
        counts.received += 1
        attachment = sample.attachment
        try:
            if attachment is None:
                raise EnvelopeError("no attachment")
            envelope = Envelope.decode(attachment.to_bytes())
        except EnvelopeError as error:
            counts.bad += 1
            self.reporter.report(route.topic, BadSample("attachment", str(error), "a site bridge's envelope"),
                                 "the Zenoh link")
            return
        if envelope.site == self.settings.site:
            counts.own_site += 1  # another bridge of this site sent it: it is on this site's databus already
            return
        if envelope.type_name != route.flow.type_name:
            counts.bad += 1
            self.reporter.report(route.topic, BadSample("type", envelope.type_name, route.flow.type_name),
                                 f"the bridge of site {envelope.site}")
            return
        with route.lock:
            last = route.last_sequence.get(envelope.site)
            if last is not None and envelope.sequence > last + 1:
                counts.link_gaps += envelope.sequence - last - 1
            if last is None or envelope.sequence > last:
                route.last_sequence[envelope.site] = envelope.sequence
        data = sample.payload.to_bytes()
        route.inbound.offer((envelope, data), len(data), envelope.kind is not SampleKind.DATA)

    # -- DDS side --------------------------------------------------------------------------------------------
    def _on_reader_event(self, route: Route, event: str, status: Any) -> None:
        """Which of this site's writers are alive (Cyclone's listener thread)."""
        handle = signed_handle(getattr(status, "last_publication_handle", 0))
        with route.lock:
            if event == "liveliness_changed":
                if status.alive_count_change > 0:
                    route.alive_writers.add(handle)
                elif status.alive_count_change < 0:
                    route.alive_writers.discard(handle)
            elif event == "subscription_matched" and status.current_count_change < 0:
                route.alive_writers.discard(handle)

    def is_bridge_writer(self, route: Route, handle: int) -> bool:
        known = route.writer_is_bridge.get(handle)
        if known is None:
            assert route.reader is not None
            try:
                data = route.reader.reader.get_matched_publication_data(handle)
            except DDSException:
                data = None
            known = data is not None and any(isinstance(policy, Policy.Userdata) and policy.data == BRIDGE_MARK
                                             for policy in data.qos)
            if data is not None:
                if len(route.writer_is_bridge) >= WRITER_CACHE:  # writers come and go: the memory stays bounded
                    route.writer_is_bridge.clear()
                route.writer_is_bridge[handle] = known
        return known

    def take(self, route: Route) -> None:
        assert route.reader is not None
        for sample in route.reader.take(TAKE_LIMIT):
            if self.is_bridge_writer(route, sample.writer):
                route.from_bridges += 1
                continue
            route.taken += 1
            route.outbound.offer(sample, len(sample.data), sample.kind is not SampleKind.DATA)
            self.app.tick()

    def update_token(self, route: Route) -> None:
        """Hold the topic's liveliness token while this site has a live writer of it (a bridge's not counted)."""
        with route.lock:
            alive = [handle for handle in route.alive_writers]
        live = any(not self.is_bridge_writer(route, handle) for handle in alive)
        if not self._session_lock.acquire(blocking=False):
            return  # a new session is being opened: the next call declares on it
        try:
            if live and route.token is None and self.session is not None:
                route.token = self.session.liveliness().declare_token(
                    writers_key(self.settings.scope, self.settings.site, self.zid, route.topic,
                                route.flow.type_name))
                self.log.info("[%s] this site has a live writer: announced to the other sites", route.topic)
            elif not live and route.token is not None:
                route.token.undeclare()
                route.token = None
                self.log.info("[%s] no live writer on this site any more: withdrawn from the other sites",
                              route.topic)
        finally:
            self._session_lock.release()

    def proxy_lease_s(self, route: Route) -> float:
        """The liveliness lease of the bridge's writer of a topic: the bridge's, or the profile's if shorter."""
        lease_ns = INFINITE_NS
        for policy in route.writer_qos:
            if isinstance(policy, (Policy.Liveliness.Automatic, Policy.Liveliness.ManualByParticipant,
                                   Policy.Liveliness.ManualByTopic)):
                lease_ns = policy.lease_duration
        return min(self.lease_s, lease_ns / 1e9)

    def proxy(self, route: Route) -> RawWriter:
        """The writer of a topic on this site for the other sites' samples, created when first needed."""
        with route.lock:
            if route.proxy is None:
                flow = route.flow
                overrides: tuple[Any, ...] = (Policy.Userdata(BRIDGE_MARK),)
                if self.assert_liveliness is not None:  # asserted while the other site's writers are alive
                    overrides += (Policy.Liveliness.ManualByTopic(duration(seconds=self.proxy_lease_s(route))),)
                writer = self.app.bus.writer(flow.topic, flow.data_type, flow.profile, overrides=overrides)
                route.proxy = RawWriter(writer)
            return route.proxy

    def assert_remote_liveliness(self) -> None:
        if self.assert_liveliness is None:
            return
        for route in self.routes.values():
            with route.lock:
                alive = bool(route.remote_writers)
            if alive:
                self.assert_liveliness(self.proxy(route).writer)

    # -- the threads that move samples -----------------------------------------------------------------------
    def _send_loop(self, route: Route) -> None:
        """This site's samples of one topic to the link (may block: reliable flows wait for the link)."""
        while self.app.running:
            if not route.matched.is_set() and route.reliable:
                route.matched.wait(0.5)  # no other site listens (the link is down): the bounded queue keeps the newest
                continue
            sample = route.outbound.next(0.5)
            if sample is None:
                continue
            if not route.matched.is_set():
                route.dropped_no_route += 1  # best effort: no other site listens, nothing to keep it for
                continue
            route.sequence += 1
            envelope = Envelope(sample.kind, sample.source_timestamp, route.sequence, self.settings.site,
                                route.flow.type_name)
            payload, attachment = bytes(sample.data), envelope.encode()
            try:
                with route.send_lock:
                    route.publisher.put(payload, attachment=attachment)
                    if route.recent is not None:
                        route.recent.append((payload, attachment))
                route.sent += 1
                route.sent_bytes += len(sample.data)
            except zenoh.ZError as error:
                route.publish_errors += 1
                if self.app.running:
                    self.reporter.repeated_event(route.topic, "publish_refused", f"Zenoh refused a sample: {error}")

    def _write_loop(self, route: Route) -> None:
        """The other sites' samples of one topic onto this site's databus."""
        while self.app.running:
            item = route.inbound.next(0.5)
            if item is None:
                continue
            envelope, data = item
            try:
                self.proxy(route).put(RawSample(data, envelope.kind, envelope.source_timestamp, 0, 0, 0),
                                      timestamp=envelope.source_timestamp or None)
                route.inbound_counts.written += 1
            except DDSException as error:
                route.inbound_counts.rejected += 1
                self.reporter.repeated_event(route.topic, "write_refused",
                                             f"a sample from site {envelope.site} was not written: {error}")

    # -- status ----------------------------------------------------------------------------------------------
    def snapshot(self) -> dict[str, Any]:
        topics: dict[str, Any] = {}
        for route in self.routes.values():
            out_counts, in_counts = route.outbound.counts, route.inbound.counts
            topics[route.topic] = {
                "to_link": {"taken": route.taken, "sent": route.sent, "sent_bytes": route.sent_bytes,
                            "dropped_budget": out_counts.dropped_budget, "dropped_full": out_counts.dropped_full,
                            "queued": len(route.outbound), "queued_bytes": route.outbound.bytes,
                            "max_queued": out_counts.max_length, "max_queued_bytes": out_counts.max_bytes,
                            "dropped_no_route": route.dropped_no_route, "from_bridges": route.from_bridges,
                            "errors": route.publish_errors, "subscribed": route.matched.is_set(),
                            "announced": route.token is not None},
                "from_link": {**route.inbound_counts.__dict__, "dropped_full": in_counts.dropped_full,
                              "queued": len(route.inbound), "queued_bytes": route.inbound.bytes,
                              "max_queued": in_counts.max_length, "max_queued_bytes": in_counts.max_bytes,
                              "remote_writers": sorted(set(route.remote_writers.values()))},
            }
        return {"site": self.settings.site, "peers": len(self.peers), "renewals": self.renewals,
                "refused_handshakes": self.zenoh_log.refused, "rss_MB": round(rss_mb(), 1), "topics": topics}

    def status_line(self, previous: dict[str, Any], current: dict[str, Any]) -> str | None:
        """What moved in the last second, and what was dropped; None when nothing did."""
        out_parts, in_parts = [], []
        for topic, now in current["topics"].items():
            before = previous.get("topics", {}).get(topic)
            sent, budget, full, no_route = (_delta(now, before, "to_link", name) for name in
                                            ("sent", "dropped_budget", "dropped_full", "dropped_no_route"))
            if sent or budget or full or no_route:
                out_parts.append(f"{topic}={sent}" + _drops((budget, "dropped by the budget"),
                                                            (full, "dropped, queue full"),
                                                            (no_route, "dropped, no site listening")))
            written, gaps, inbound_full = (_delta(now, before, "from_link", name) for name in
                                           ("written", "link_gaps", "dropped_full"))
            if written or gaps or inbound_full:
                in_parts.append(f"{topic}={written}" + _drops((gaps, "lost on the link"),
                                                              (inbound_full, "dropped, queue full")))
        if not out_parts and not in_parts:
            return None
        return (f"to link: {' '.join(out_parts) or '-'} | from link: {' '.join(in_parts) or '-'} | "
                f"{current['peers']} peer(s)")

    def close(self) -> None:
        self._stop.set()
        self._renewal.set()
        for route in self.routes.values():
            route.outbound.close()
            route.inbound.close()
        with self._session_lock:
            if self.session is not None:
                for route in self.routes.values():
                    if route.token is not None:
                        route.token.undeclare()
                        route.token = None
                _close_session(self.session)
        deadline = time.monotonic() + 3.0  # a thread blocked on a stalled link is a daemon: it is not waited for
        for thread in self.threads:
            thread.join(timeout=max(0.0, deadline - time.monotonic()))
        self.zenoh_log.stop()


def _close_session(session: zenoh.Session) -> None:
    try:
        session.close()
    except zenoh.ZError:
        pass  # closed already: nothing of it is used any more


def _delta(now: dict[str, Any], before: dict[str, Any] | None, direction: str, name: str) -> int:
    value = int(now[direction][name])
    return value - int(before[direction][name]) if before else value


def _drops(*counts: tuple[int, str]) -> str:
    parts = [f"{count} {what}" for count, what in counts if count]
    return f" ({'; '.join(parts)})" if parts else ""


def body(app: Application) -> None:
    settings = LinkSettings.from_properties(app.props)
    known = system_flows(app.props.folder)
    flows = choose_flows(app.props, known, app.args.topics)
    bridge = SiteBridge(app, settings, flows, [flow.topic for flow in known])
    try:
        bridge.open()
        readers = [route.reader.reader for route in bridge.routes.values() if route.reader is not None]
        app.log.info("bridge of site %s ready: %d topic(s): %s", settings.site, len(bridge.routes),
                     ", ".join(bridge.routes))
        lease_check = min(bridge.proxy_lease_s(route) for route in bridge.routes.values()) / 4
        next_assert = time.monotonic()
        every_second = Every(STATUS_INTERVAL_S)
        previous: dict[str, Any] = {}
        for _ in app.wake_ups(app.waitset(*readers), timeout_s=min(0.2, lease_check)):
            for route in bridge.routes.values():
                bridge.take(route)
            now = time.monotonic()
            if now >= next_assert:
                for route in bridge.routes.values():
                    bridge.update_token(route)
                bridge.assert_remote_liveliness()
                next_assert = now + lease_check
            if every_second.due() is not None:
                current = bridge.snapshot()
                line = bridge.status_line(previous, current)
                if line:
                    app.log.info("%s", line)
                app.stats.record("status", **current)
                previous = current
    finally:
        bridge.close()
        app.stats.record("summary", **bridge.snapshot())


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--topics", default="",
                        help="comma-separated topics to bridge (default: bridge.allow, or every topic)")


def main(argv: list[str] | None = None) -> int:
    return run("zenoh_bridge", __doc__ or "", body, argv, add_arguments, command="automotive zenoh-bridge",
               keys=PROPERTY_KEYS)


if __name__ == "__main__":
    sys.exit(main())
