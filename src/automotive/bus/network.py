"""Where DDS traffic goes: single host on loopback, a multicast LAN, or unicast peers with multicast off.

The choice produces a Cyclone DDS configuration (XML) for the application's domain.

A user's own CYCLONEDDS_URI (Cyclone users set one to pick an interface, or to trace) is layered on top of it, as
Cyclone layers configuration fragments: Cyclone reads a comma-separated list of files, file:// URIs and XML fragments
in order, a later fragment replacing an earlier one's setting element by element, except lists (network interfaces,
peers), which it adds to. The domain's configuration is the applications' own (:meth:`NetworkConfig.cyclone_xml`),
then the user's (:meth:`NetworkConfig.layered`, from :func:`read_user_config`):

- The network choice (NETWORK_ELEMENTS: interfaces, multicast, peers, participant indexes, the discovery timing that
  goes with them) is one unit, chosen either by the applications or by the user's URI. Without an explicit choice
  (config.network, config.interface or config.peers in the properties, also set by --network, --interface,
  --peers), a URI that sets any of it differently from the applications makes it the URI's: the applications leave
  out all of theirs, so Cyclone's defaults fill what the URI does not say (an interface alone: multicast discovery on
  it, as Cyclone users expect). With an explicit choice, the applications' network wins: those elements are taken
  out of the user's configuration, which is passed on as XML fragments without them.
- Every other element the applications set (TUNING_ELEMENTS: the large-data fragments and socket buffers, the
  receive buffer size, the reorder limits) stays unless the URI sets it too; then the URI's wins.
- An element the URI sets to what the applications set anyway is no override (the tests' CYCLONEDDS_URI is the
  loopback configuration itself). What the URI replaces, or what an explicit choice replaces in it, is said in one
  line at start (:attr:`Layering.notice`); a URI that cannot be read is a ConfigError.

Participant indexes stop at MAX_PARTICIPANT_INDEX (config.maxParticipants at most MAX_PARTICIPANTS), so that no
index's port reaches another domain's (automotive.bus.ports).

Cyclone's default tools on the same host: a Cyclone participant on Cyclone's defaults (the ``cyclonedds`` CLI, ROS 2
with rmw_cyclonedds_cpp, any Cyclone application) uses the host's best LAN interface only: it announces itself by
multicast there (239.255.0.1, the domain's discovery port), listens for unicast on ephemeral ports no index probe
reaches, and drops a participant announcement that arrives on another interface (127.0.0.1 is the loopback
device's). So loopback mode also uses that interface (the one Cyclone would choose, found by
:func:`host_interface`), to receive and to reach the host's own address only:

- Every participant listens on the domain's discovery multicast port without joining the group (no IGMP report
  leaves the host). The kernel hands it the multicast a default tool on this host sends and loops back to its own
  host, because that tool joined the group on that interface; the participant answers it by unicast to the tool's
  own (LAN) address, which the kernel delivers inside the host, on the tool's interface: the tool accepts it. Either
  join order works: a tool started later is heard at its first announcement, a tool started earlier at its next
  (every 8 s on Cyclone's defaults).
- The interface is used for unicast only: the participants never send multicast on it (their multicast goes to the
  loopback device, to the other participants of the host), so nothing goes on the wire for them.
- The domain's sockets are made deaf to every other host (automotive.cyclone.hostonly, a socket filter): another
  host's participant, even one that probes this host's address or whose multicast a default tool here lets in, is
  never heard, so it is never answered. Where that filter cannot be set (not Linux), loopback mode stays on 127.0.0.1
  only, as Cyclone's default tools then cannot find it.
- Cyclone is told not to ask on which interface a datagram arrived (ExtendedPacketInfo), or it would drop the default
  tools' multicast, which arrives on an interface it uses for unicast only.

On a host whose only interface is the loopback (a laptop offline, a container without a network, a CI sandbox),
Cyclone's defaults use lo for everything: SPDP multicast to 239.255.0.1 on lo, the group joined there, unicast on
ephemeral ports (docs/measurements/host-discovery.md). There :func:`host_interface` is lo itself, and loopback mode
announces itself by multicast on lo and joins the group there too (no other interface exists for it to leave by),
besides the probes of 127.0.0.1; the sockets get the same filter. Cyclone reads the interfaces once: when a LAN
interface comes up later, a participant started before goes on with everyone it reaches through lo (the applications,
started before or after, RTI, Fast DDS, Cyclone tools started before), but not a Cyclone tool on its defaults started
after, which uses the new interface only.

Late joiners: a tool of another DDS implementation (RTI Admin Console, rtiddsspy, Shapes Demo, RViz2 on Fast DDS)
started on a host where the system already runs announces itself only to the few participant indexes it probes by
default (RTI 0-4, Fast DDS 0-3), so the participants with higher indexes must find it themselves. In loopback and
peers modes every participant therefore keeps probing every participant index of every peer for as long as it runs
(Cyclone's default stops after 30 s), every LOOPBACK_ANNOUNCE_INTERVAL / PEERS_ANNOUNCE_INTERVAL: a late joiner is
found within about that interval, at the cost measured in docs/deployment.md. In LAN mode the joiner's own
multicast announcement reaches every participant at once.

Unicast peers: each listed host is probed at every participant index (a UDP port) for participant announcements.
The peer list may name only the other hosts (as RTI users write initial peers) or every host: this host is always
probed too (its interface's address, and its own addresses found in the list). Other implementations (RTI Connext)
answer a participant of the same host through 127.0.0.1: Cyclone is told not to drop announcements that arrive on an
interface it does not use. A peer that cannot be used (its name does not resolve, no route leads to it) is left out
and reported once by the caller.
"""

from __future__ import annotations

import copy
import ipaddress
import os
import re
import socket
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from xml.sax.saxutils import quoteattr

import psutil

from automotive.bus.errors import ConfigError
from automotive.bus.ports import MAX_PARTICIPANT_INDEX, MAX_PARTICIPANTS
from automotive.cyclone import hostonly

LOOPBACK = "loopback"
LAN = "lan"
PEERS = "peers"
MODES = (LOOPBACK, LAN, PEERS)

# Every participant on a host takes a participant index (a port): at most this many participants per host, indexes
# 0..118; unicast discovery probes one index more per peer, 0..119, the most whose ports stay inside the domain
# (automotive.bus.ports).
DEFAULT_MAX_PARTICIPANTS = MAX_PARTICIPANTS
# Large samples (camera frames): 62000-byte fragments in datagrams of up to 65500 bytes instead of Cyclone's
# 1344-byte fragments (68 datagrams per 4 MiB frame instead of 3121), and socket buffers as large as the kernel
# allows, so that a burst of fragments is not dropped and repaired. Datagrams above the link MTU are split by IP,
# where one lost piece loses the datagram: meant for one host (loopback's MTU is 64 KiB) or a clean LAN.
LARGE_DATA_FRAGMENT_SIZE = 62000
LARGE_DATA_SOCKET_BUFFER = "4MiB"
# Peers mode: a participant announces itself every second, to the participants it knows and to every probed index
# of every peer (Cyclone's default is every 8 s to the known, and a probe after 0.1 s then every 30 s, for 30 s, to
# the rest). Under 10 % loss a lost announcement is repeated a second later, so two hosts meet within a few seconds
# (docs/deployment.md). Every index of every peer is probed as long as the application runs ("inf"), so that a tool
# started later on any host, which probes only its first few indexes of our host, is found.
PEERS_ANNOUNCE_INTERVAL = "1s"
# Loopback mode: the same probing of every index of this host, every 2 s (measured: about 60 datagrams/s and 1.5 ms
# of CPU/s per participant, never leaving the host; docs/deployment.md).
LOOPBACK_ANNOUNCE_INTERVAL = "2s"
PROBE_FOREVER = "inf"
# Cyclone's receive thread places every datagram it receives in a receive buffer of this size, one after the other
# (a bump allocator that never reuses a buffer's space), and starts a new buffer when one is full. Each page of a
# buffer becomes resident when the first datagram reaches it, so a process's RSS climbs with every byte received
# until the buffer is full and freed: with Cyclone's default of 1 MiB, an application that receives little (a
# sensor that only hears the other participants' discovery, about 2 kB/s) climbed for 8-15 minutes, then dropped,
# then climbed again while glibc placed the next buffers in the thread's arena (docs/measurements/memory.md). A quarter
# of that makes the climb end within the first minutes and bounds it at a few hundred kB; it still holds two of the
# largest datagrams (64 KiB, the receive chunk of 128 KiB plus one more), so no allocation per datagram is added.
RECEIVE_BUFFER_SIZE = "256KiB"
LOCALHOST = "127.0.0.1"
# Cyclone's thread that receives the datagrams and delivers user data to the readers (automotive.bus.realtime).
RECEIVE_THREAD = "recv"
_HOST_NAME = re.compile(r"^[A-Za-z0-9]([A-Za-z0-9.-]*[A-Za-z0-9])?$")

# The elements the applications may set, by their path below CycloneDDS/Domain (how the override line names them).
# The network choice, one unit (see the module's docstring). The last three are Cyclone's deprecated ways of choosing
# interfaces, which it refuses beside General/Interfaces: a URI that uses them chooses the network.
NETWORK_ELEMENTS = ("General/Interfaces", "General/AllowMulticast", "Discovery/Peers", "Discovery/ParticipantIndex",
                    "Discovery/MaxAutoParticipantIndex", "Discovery/SPDPInterval",
                    "Discovery/InitialLocatorPruneDelay", "Internal/ExtendedPacketInfo",
                    "General/NetworkInterfaceAddress", "General/MulticastRecvNetworkInterfaceAddresses",
                    "General/AssumeMulticastCapable")
TUNING_ELEMENTS = ("General/MaxMessageSize", "General/FragmentSize", "Internal/PrimaryReorderMaxSamples",
                   "Internal/SecondaryReorderMaxSamples", "Internal/SocketReceiveBufferSize",
                   "Internal/SocketSendBufferSize", "Sizing/ReceiveBufferSize", "Threads/Thread")
_GROUPS = ("General", "Discovery", "Internal", "Sizing", "Threads")  # the order of the applications' XML
# Older names Cyclone still reads for the same settings (its "moved" elements and aliases).
_MOVED = {"Internal/MaxMessageSize": "General/MaxMessageSize", "Internal/FragmentSize": "General/FragmentSize",
          "Internal/MinimumSocketReceiveBufferSize": "Internal/SocketReceiveBufferSize",
          "Internal/MinimumSocketSendBufferSize": "Internal/SocketSendBufferSize"}
_GROUP_ALIASES = {"unsupported": "Internal"}
_DOMAIN_ALIASES = ("domain", "ddsi2e", "ddsi2")
_KNOWN_CHILDREN = {group: sorted({path.split("/")[1] for path in (*NETWORK_ELEMENTS, *TUNING_ELEMENTS, *_MOVED)
                                  if path.startswith(group + "/")}) for group in _GROUPS}
URI_VARIABLE = "CYCLONEDDS_URI"


@dataclass(frozen=True)
class PeerPlan:
    """What becomes of each listed peer: another host to probe, this host, or unusable (and why)."""

    remote: tuple[str, ...] = ()  # IPv4 addresses of the other hosts
    own: tuple[str, ...] = ()  # listed addresses that belong to this host
    unusable: tuple[tuple[str, str], ...] = ()  # (peer as listed, reason): left out of the configuration
    route_source: str = ""  # this host's address on the route to the first remote peer


def plan_peers(peers: tuple[str, ...]) -> PeerPlan:
    """Resolve each peer and classify it. Sends nothing: binding and connecting a UDP socket only ask the kernel."""
    remote: list[str] = []
    own: list[str] = []
    unusable: list[tuple[str, str]] = []
    route_source = ""
    for peer in peers:
        try:
            address = str(socket.getaddrinfo(peer, None, socket.AF_INET, socket.SOCK_DGRAM)[0][4][0])
        except (socket.gaierror, UnicodeError) as error:
            reason = getattr(error, "strerror", None) or error
            unusable.append((peer, f"the name does not resolve to an IPv4 address ({reason})"))
            continue
        if _is_own_address(address):
            own.append(address)
            continue
        source = _route_source(address)
        if source is None:
            unusable.append((peer, "no route leads there from this host"))
            continue
        remote.append(address)
        route_source = route_source or source
    return PeerPlan(tuple(dict.fromkeys(remote)), tuple(dict.fromkeys(own)), tuple(unusable), route_source)


@dataclass(frozen=True)
class NetworkConfig:
    mode: str = LOOPBACK
    interface: str = ""  # "" lets Cyclone choose (LAN and peers modes)
    peers: tuple[str, ...] = field(default_factory=tuple)
    # Participants per host: indexes 0..max_participants - 1 taken, 0..max_participants probed (Cyclone's
    # MaxAutoParticipantIndex; automotive.bus.ports says why one more).
    max_participants: int = DEFAULT_MAX_PARTICIPANTS
    large_data: bool = False
    fragment_size: int = LARGE_DATA_FRAGMENT_SIZE
    socket_buffer: str = LARGE_DATA_SOCKET_BUFFER
    # True for Cyclone's C tools of Debian (ddsperf 0.10.2), which stop on what Cyclone 0.10 does not know: the
    # loopback peer's PruneDelay attribute (the Python runtime's Cyclone 11 needs it to probe for late joiners
    # forever) and ExtendedPacketInfo; so no LAN interface either (see host_interface).
    cyclone_0_10: bool = False
    # Loopback mode: the LAN interface whose own address the participants also use, so that Cyclone's default tools
    # on this host find them (see the module's docstring); None: this host's (host_interface()), "": none.
    host_interface: str | None = None
    # Samples kept of a running reliable writer just discovered, until its next heartbeat says where its history
    # starts (Cyclone's Internal/PrimaryReorderMaxSamples and, per reader that joined it, SecondaryReorderMaxSamples:
    # 128 by default; the rest is dropped without a trace). 0: Cyclone's defaults.
    reorder_samples: int = 0
    # Cyclone's receive thread at this SCHED_FIFO priority (0: Cyclone's default, the process's policy);
    # automotive.bus.realtime says when and why.
    receive_thread_priority: int = 0
    # Layered under a user's CYCLONEDDS_URI (made by ``layered``): the user's configuration, given to Cyclone after
    # ours; the elements of ours it replaces, left out; and whether the network choice is the user's.
    user_config: str = ""
    omitted: frozenset[str] = frozenset()
    network_from_user: bool = False

    def __post_init__(self) -> None:
        # Also for configurations made in code (the benchmarks): an index past the last would probe another domain.
        if not 1 <= self.max_participants <= MAX_PARTICIPANTS:
            raise ConfigError(f"max participants {self.max_participants}: expected 1..{MAX_PARTICIPANTS} (participant "
                              f"indexes probed up to {MAX_PARTICIPANT_INDEX} keep every port inside the domain)")

    @classmethod
    def from_settings(cls, network: str = "", interface: str = "", peers: list[str] | None = None,
                      max_participants: int = DEFAULT_MAX_PARTICIPANTS, large_data: bool = False,
                      source: str = "network") -> NetworkConfig:
        """Peers imply unicast mode, an interface implies LAN mode, nothing implies loopback."""
        peers = peers or []
        for peer in peers:
            if not _valid_host(peer):
                raise ConfigError(f"{source}: peer '{peer}' is not a host name or IP address")
        if interface and not re.fullmatch(r"[\w.:-]+", interface):
            raise ConfigError(f"{source}: interface '{interface}' is not an interface name or address")
        mode = network or (PEERS if peers else LAN if interface else LOOPBACK)
        if mode not in MODES:
            raise ConfigError(f"{source}: network '{mode}' is not one of {', '.join(MODES)}")
        if mode == PEERS and not peers:
            raise ConfigError(f"{source}: network 'peers' needs a list of peers (config.peers=host1,host2)")
        if not 1 <= max_participants <= MAX_PARTICIPANTS:
            raise ConfigError(f"{source}: config.maxParticipants = {max_participants} is out of range (expected "
                              f"1..{MAX_PARTICIPANTS})")
        return cls(mode, interface, tuple(peers), max_participants, large_data)

    def peer_plan(self) -> PeerPlan:
        """The listed peers resolved and classified (peers mode; other modes probe no peer host)."""
        return plan_peers(self.peers) if self.mode == PEERS and not self.network_from_user else PeerPlan()

    def cyclone_xml(self, plan: PeerPlan | None = None) -> str:
        """The Cyclone DDS configuration of the domain (peers mode: from ``plan``, made here if not given): this
        choice's XML, followed, when layered under a user's CYCLONEDDS_URI, by the user's configuration (a
        comma-separated list, as Cyclone reads it)."""
        kept = [(path, xml) for path, xml in self.elements(plan) if path not in self.omitted
                and not (self.network_from_user and path in NETWORK_ELEMENTS)]
        groups = {group: "".join(xml for path, xml in kept if path.split("/")[0] == group) for group in _GROUPS}
        domain = "".join(f"<{group}>{content}</{group}>" for group, content in groups.items() if content)
        own = f"<CycloneDDS><Domain>{domain}</Domain></CycloneDDS>"
        return f"{own},{self.user_config}" if self.user_config else own

    def elements(self, plan: PeerPlan | None = None) -> list[tuple[str, str]]:
        """What this choice sets, element by element: (path below CycloneDDS/Domain, its XML), in the XML's order."""
        elements: list[tuple[str, str]] = []
        if self.mode == PEERS:
            plan = plan or self.peer_plan()
            interface = self.interface or plan.route_source
            if not interface and not any(not _is_loopback(name) for _, name in socket.if_nameindex()):
                interface = "lo"  # a host without a network
            # Cyclone probes this host's own address (the interface's) by itself; with the prune delay below, as long
            # as it runs, like every listed peer.
            peers = "".join(f"<Peer address={quoteattr(peer)}/>" for peer in (*plan.remote, *plan.own))
            elements += [*_interfaces_element(interface), ("General/AllowMulticast", _text("AllowMulticast", "false")),
                         ("Discovery/Peers", f"<Peers>{peers}</Peers>"), *self._participant_index_elements(),
                         ("Discovery/SPDPInterval", _text("SPDPInterval", PEERS_ANNOUNCE_INTERVAL)),
                         ("Discovery/InitialLocatorPruneDelay", _text("InitialLocatorPruneDelay", PROBE_FOREVER)),
                         # Not asking the kernel on which interface a packet arrived: with that information Cyclone
                         # drops participant announcements that arrive on an interface it does not use, such as
                         # RTI's answers through 127.0.0.1.
                         ("Internal/ExtendedPacketInfo", _text("ExtendedPacketInfo", "false"))]
        elif self.mode == LOOPBACK:
            prune = "" if self.cyclone_0_10 else f' PruneDelay="{PROBE_FOREVER}"'
            host = self.lan_interface()
            only_loopback = _is_loopback(host)
            # With a LAN interface: multicast discovery on the loopback device only (its socket also hears the
            # default tools' looped-back multicast), unicast only on the LAN interface, no multicast group joined.
            # On a host whose only interface is the loopback (where Cyclone's default tools multicast on lo and join
            # the group there): multicast discovery on lo, the group joined on lo.
            if only_loopback:
                interfaces = [("General/Interfaces", '<Interfaces><NetworkInterface name="lo" multicast="true" '
                               'allow_multicast="spdp"/></Interfaces>')]
            elif host:
                interfaces = [("General/Interfaces", '<Interfaces><NetworkInterface name="lo" multicast="true" '
                               f'allow_multicast="spdp"/><NetworkInterface name={quoteattr(host)} '
                               'allow_multicast="false"/></Interfaces>')]
            else:
                interfaces = _interfaces_element("lo")
            elements += [*interfaces, ("General/AllowMulticast", _text("AllowMulticast", "false"))]
            if host and not only_loopback:
                elements.append(("General/MulticastRecvNetworkInterfaceAddresses",
                                 _text("MulticastRecvNetworkInterfaceAddresses", "none")))
            elements += [("Discovery/Peers", f'<Peers><Peer address="{LOCALHOST}"{prune}/></Peers>'),
                         *self._participant_index_elements(),
                         ("Discovery/SPDPInterval", _text("SPDPInterval", LOOPBACK_ANNOUNCE_INTERVAL))]
            if host:
                elements.append(("Internal/ExtendedPacketInfo", _text("ExtendedPacketInfo", "false")))
        else:
            elements += [*_interfaces_element(self.interface),
                         ("General/AllowMulticast", _text("AllowMulticast", "true"))]
        if self.large_data:
            message_size = min(65500, self.fragment_size + 1500)
            elements += [("General/MaxMessageSize", _text("MaxMessageSize", f"{message_size}B")),
                         ("General/FragmentSize", _text("FragmentSize", f"{self.fragment_size}B"))]
        if self.reorder_samples:
            elements += [("Internal/PrimaryReorderMaxSamples", _text("PrimaryReorderMaxSamples", self.reorder_samples)),
                         ("Internal/SecondaryReorderMaxSamples",
                          _text("SecondaryReorderMaxSamples", self.reorder_samples))]
        if self.large_data:
            elements += [("Internal/SocketReceiveBufferSize",
                          f'<SocketReceiveBufferSize min="default" max="{self.socket_buffer}"/>'),
                         ("Internal/SocketSendBufferSize",
                          f'<SocketSendBufferSize min="default" max="{self.socket_buffer}"/>')]
        elements.append(("Sizing/ReceiveBufferSize", _text("ReceiveBufferSize", RECEIVE_BUFFER_SIZE)))
        if self.receive_thread_priority:
            elements.append(("Threads/Thread", f'<Thread name="{RECEIVE_THREAD}"><Scheduling><Class>realtime</Class>'
                             f"<Priority>{self.receive_thread_priority}</Priority></Scheduling></Thread>"))
        return elements

    def lan_interface(self) -> str:
        """Loopback mode: the interface Cyclone's default tools use on this host, which the participants also use: a LAN
        interface (for unicast), or lo on a host with only the loopback (multicast discovery there); "" for none."""
        if self.mode != LOOPBACK or self.cyclone_0_10:
            return ""
        if self.host_interface is not None:
            return self.host_interface
        return host_interface() if hostonly.available() else ""

    def _participant_index_elements(self) -> list[tuple[str, str]]:
        return [("Discovery/ParticipantIndex", _text("ParticipantIndex", "auto")),
                ("Discovery/MaxAutoParticipantIndex", _text("MaxAutoParticipantIndex", self.max_participants))]

    def describe(self) -> str:
        if self.network_from_user:
            return f"as your {URI_VARIABLE} chooses"
        if self.mode == LOOPBACK:
            text = "single host (loopback)"
        elif self.mode == LAN:
            text = f"LAN multicast on {self.interface or 'the default interface'}"
        else:
            text = f"unicast peers {', '.join(self.peers)}" + (f" on {self.interface}" if self.interface else "")
        return text + (f", with your {URI_VARIABLE}" if self.user_config else "")

    def layered(self, user: UserConfig, explicit: str = "") -> Layering:
        """This configuration under the user's (see the module's docstring); ``explicit`` names the explicit network
        choice (``config.peers (--peers)``), "" if there is none."""
        # Peers mode is always explicit; its peers are not resolved for a comparison (no name look-up twice).
        ours = dict(self.elements(PeerPlan() if self.mode == PEERS else None))
        theirs = user.settings()

        def differs(path: str) -> bool:
            return path in theirs and (path not in ours or not _same(theirs[path], ours[path]))

        replaced_tuning = [path for path in ours if path not in NETWORK_ELEMENTS and differs(path)]
        their_network = [path for path in NETWORK_ELEMENTS if path in theirs]
        notice: list[str] = []
        sets: list[str] = []  # what the URI sets in place of the applications' settings
        if explicit:
            # The user's network elements are taken out of the user's configuration (Cyclone would add the URI's
            # interfaces and peers to ours).
            user_config = user.without(their_network) if their_network else user.uri
            overridden = [path for path in their_network if differs(path)]
            if overridden:
                notice.append(f"{explicit} replaces the network your {URI_VARIABLE} sets ({', '.join(overridden)})")
            network_from_user = False
        else:
            user_config = user.uri
            network_from_user = any(differs(path) for path in their_network)
            if network_from_user:
                verb = "replaces" if len(their_network) == 1 else "replace"
                sets.append(f"{', '.join(their_network)}, which {verb} the applications' network ({self.describe()})")
        sets += [f"{path}, which replaces the applications' setting ({_summary(ours[path])})"
                 for path in replaced_tuning]
        if sets:
            notice.append(f"your {URI_VARIABLE} sets {'; '.join(sets)}")
        # What the user's configuration sets is left out of ours, also when equal: Cyclone adds lists up.
        omitted = frozenset(path for path in theirs if path in ours and (path not in NETWORK_ELEMENTS or not explicit))
        layered = replace(self, user_config=user_config, omitted=omitted, network_from_user=network_from_user)
        return Layering(layered, "network: " + "; ".join(notice) if notice else None)


@dataclass(frozen=True)
class Layering:
    """A configuration layered under a user's CYCLONEDDS_URI, and the one line saying what the URI replaces."""

    network: NetworkConfig
    notice: str | None


@dataclass(frozen=True)
class UserConfig:
    """A user's Cyclone configuration (CYCLONEDDS_URI), read as Cyclone reads it, for one domain."""

    uri: str
    fragments: tuple[ET.Element, ...]  # each file's or inline fragment's root element, well-formed, no namespaces
    abbreviated: tuple[bool, ...]  # per fragment: names may be abbreviated to a unique prefix (inline XML)
    domain_id: int

    def settings(self) -> dict[str, list[ET.Element]]:
        """The elements this configuration sets for the domain, by path below CycloneDDS/Domain (the applications'
        names: General/Interfaces...), each with every occurrence in order."""
        found: dict[str, list[ET.Element]] = {}
        for fragment, abbreviated in zip(self.fragments, self.abbreviated):
            for _, element, path in _settings(fragment, abbreviated, self.domain_id):
                found.setdefault(path, []).append(element)
        return found

    def without(self, paths: Iterable[str]) -> str:
        """This configuration with the elements at ``paths`` taken out (of every domain), as XML fragments."""
        removed = set(paths)
        texts = []
        for fragment, abbreviated in zip(self.fragments, self.abbreviated):
            fragment = copy.deepcopy(fragment)
            for parent, element, path in list(_settings(fragment, abbreviated, None)):
                if path in removed:
                    parent.remove(element)
            texts.append(ET.tostring(fragment, encoding="unicode"))
        return ",".join(texts)


def host_interface() -> str:
    """The interface a Cyclone participant on its defaults uses on this host: as Cyclone chooses, the first one that
    is up and has an IPv4 address, preferring one that can multicast, then one that is not point-to-point; the
    loopback device ("lo") only where it is the only one (a host offline, a container without a network); "" where
    not even that is up."""
    stats = psutil.net_if_stats()
    best, best_quality = "", 0
    for name, addresses in psutil.net_if_addrs().items():
        status = stats.get(name)
        if status is None or not status.isup or not any(address.family == socket.AF_INET for address in addresses):
            continue
        flags = set(status.flags.split(","))
        if "loopback" in flags:
            if name == "lo" and not best:  # automotive.cyclone.hostonly filters on the device named lo
                best = name
            continue
        quality = 3 if "multicast" in flags else 1 if "pointopoint" in flags else 2
        if quality > best_quality:
            best, best_quality = name, quality
    return best


def user_uri() -> str | None:
    """The user's own Cyclone configuration, if any."""
    return os.environ.get(URI_VARIABLE) or None


def read_user_config(uri: str, domain_id: int) -> UserConfig:
    """The user's configuration, split and read as Cyclone does (files, file:// URIs, XML fragments, which may leave
    out CycloneDDS and Domain, close an element with ``</>`` and leave elements open at the end); a ConfigError names
    the part that cannot be read."""
    fragments: list[ET.Element] = []
    abbreviated: list[bool] = []
    position = _skip_separators(uri, 0)
    while position < len(uri):
        if uri[position] == "<":
            what = f"the XML at character {position + 1}"
            text, position = _fragment(uri, position, what)
            inline = True
        else:
            end = uri.find(",", position)
            end = len(uri) if end < 0 else end
            name = uri[position:end]
            what = f"file '{name}'"
            text = _read_file(name, what)
            start = text.find("<")
            if start < 0:
                raise ConfigError(f"{URI_VARIABLE}: {what} holds no XML")
            text, _ = _fragment(text, start, what)
            position, inline = end, False
        fragments.append(_parse(text, what))
        abbreviated.append(inline)
        position = _skip_separators(uri, position)
    return UserConfig(uri, tuple(fragments), tuple(abbreviated), domain_id)


# The markup Cyclone's parser reads: comments, processing instructions, CDATA, and tags (</> closes the innermost).
_MARKUP = re.compile(r"<!--.*?-->|<\?.*?\?>|<!\[CDATA\[.*?\]\]>|<!DOCTYPE[^>]*>"
                     r"|<(?P<close>/)?(?P<name>[^\s/>!?]*)(?P<attributes>(?:\s+[^\s=/>]+\s*=\s*(?:\"[^\"]*\"|'[^']*'))*)"
                     r"\s*(?P<empty>/)?>", re.S)


def _skip_separators(text: str, position: int) -> int:
    while position < len(text) and (text[position].isspace() or text[position] == ","):
        position += 1
    return position


def _read_file(name: str, what: str) -> str:
    # As Cyclone: the name as a path, else after a file:// prefix.
    candidates = [name] + ([name[len("file://"):]] if name.startswith("file://") else [])
    for candidate in candidates:
        try:
            return Path(candidate).read_text(encoding="utf-8")
        except FileNotFoundError:
            continue
        except (OSError, UnicodeDecodeError) as error:
            reason = error.strerror if isinstance(error, OSError) else error
            raise ConfigError(f"{URI_VARIABLE}: cannot read {what} ({reason})") from None
    raise ConfigError(f"{URI_VARIABLE}: {what} not found (expected files, file:// URIs or XML, separated by commas)")


def _fragment(text: str, start: int, what: str) -> tuple[str, int]:
    """The element that starts at ``text[start]``, well-formed as Cyclone reads it (a ``</>`` closes the innermost
    element, elements still open at the end are closed there), and the position after it."""
    out: list[str] = []
    open_names: list[str] = []
    position = start
    while True:
        tag = text.find("<", position)
        if tag < 0:
            out.append(text[position:])
            position = len(text)
            break
        out.append(text[position:tag])
        match = _MARKUP.match(text, tag)
        if match is None:
            raise ConfigError(f"{URI_VARIABLE}: {what} is not well-formed XML (a '<' at character {tag + 1 - start} "
                              "starts no tag)")
        position = match.end()
        name = match.group("name")
        if name is None:  # a comment, a processing instruction...
            out.append(match.group(0))
        elif match.group("close"):
            if not open_names or (name and name.lower() != open_names[-1].lower()):
                raise ConfigError(f"{URI_VARIABLE}: {what} is not well-formed XML ('{match.group(0)}' closes "
                                  f"{'nothing' if not open_names else repr(open_names[-1])})")
            out.append(f"</{open_names.pop()}>")
            if not open_names:
                break
        elif not name:
            raise ConfigError(f"{URI_VARIABLE}: {what} is not well-formed XML (a tag without a name)")
        elif match.group("empty"):
            out.append(match.group(0))
            if not open_names:
                break
        else:
            out.append(match.group(0))
            open_names.append(name)
    out += [f"</{name}>" for name in reversed(open_names)]
    return "".join(out), position


def _parse(text: str, what: str) -> ET.Element:
    try:
        root = ET.fromstring(text)
    except ET.ParseError as error:
        raise ConfigError(f"{URI_VARIABLE}: {what} is not well-formed XML ({error})") from None
    for element in root.iter():
        element.tag = str(element.tag).rpartition("}")[2]  # Cyclone's files name a namespace; it plays no part
        for key in [key for key in element.attrib if key.startswith("{")]:
            del element.attrib[key]  # xsi:schemaLocation
    return root


def _name_matches(written: str, name: str, abbreviated: bool) -> bool:
    written = written.lower()
    return written == name.lower() or (abbreviated and bool(written) and name.lower().startswith(written))


def _known(written: str, names: Iterable[str], abbreviated: bool) -> str | None:
    """Which of ``names`` a written element name means, as Cyclone matches: any case, or a unique prefix."""
    names = list(names)
    exact = [name for name in names if name.lower() == written.lower()]
    if exact:
        return exact[0]
    prefixed = [name for name in names if _name_matches(written, name, abbreviated)]
    return prefixed[0] if len(prefixed) == 1 else None


def _domain_applies(domain: ET.Element, domain_id: int | None) -> bool:
    """Whether a Domain element configures ``domain_id`` (its id attribute or legacy Id element: absent, "any" or that
    number); None: any domain."""
    ids = [value for key, value in domain.attrib.items() if key.lower() == "id"]
    ids += [child.text or "" for child in domain if child.tag.lower() == "id"]
    return domain_id is None or all(value.strip().lower() in ("any", str(domain_id)) for value in ids)


def _settings(fragment: ET.Element, abbreviated: bool,
              domain_id: int | None) -> Iterator[tuple[ET.Element, ET.Element, str]]:
    """(parent, element, path below Domain) of the setting elements of a fragment that apply to ``domain_id``: a
    fragment is CycloneDDS, a Domain, or (inline) anything below Domain."""
    if _name_matches(fragment.tag, "CycloneDDS", abbreviated):
        containers = [child for child in fragment if child.tag.lower() in _DOMAIN_ALIASES]
        containers.append(fragment)  # General, Discovery... right below CycloneDDS: Cyclone's older layout
    elif fragment.tag.lower() in _DOMAIN_ALIASES:
        containers = [fragment]
    else:
        containers = []
        yield from _group_settings(fragment, abbreviated)
    for container in containers:
        if container is fragment or _domain_applies(container, domain_id):
            for group in container:
                yield from _group_settings(group, abbreviated)


def _group_settings(group: ET.Element, abbreviated: bool) -> Iterator[tuple[ET.Element, ET.Element, str]]:
    name = _GROUP_ALIASES.get(group.tag.lower()) or _known(group.tag, _GROUPS, abbreviated)
    if name is None:
        return
    for element in group:
        child = _known(element.tag, _KNOWN_CHILDREN[name], abbreviated) or element.tag
        path = f"{name}/{child}"
        yield group, element, _MOVED.get(path, path)


def _shape(element: ET.Element) -> tuple[object, ...]:
    """An element's content for comparison: names and values in any case and without blanks ("62000 B" = 62000B)."""
    def plain(text: str | None) -> str:
        return "".join((text or "").split()).casefold()
    attributes = tuple(sorted((key.lower(), plain(value)) for key, value in element.attrib.items()))
    return element.tag.lower(), attributes, plain(element.text), tuple(_shape(child) for child in element)


def _same(theirs: list[ET.Element], ours: str) -> bool:
    """Whether the user's occurrences of an element amount to ours (one occurrence, the same content)."""
    return len(theirs) == 1 and _shape(theirs[0]) == _shape(ET.fromstring(ours))


def _summary(xml: str) -> str:
    """An element's value in a few words: its text, the names or addresses it lists, its other attributes."""
    def words(element: ET.Element) -> list[str]:
        found = [value for key, value in element.attrib.items() if key in ("name", "address")]
        found += [f"{key}={value}" for key, value in element.attrib.items() if key not in ("name", "address")]
        found += [element.text.strip()] if element.text and element.text.strip() else []
        return found + [word for child in element for word in words(child)]
    return " ".join(words(ET.fromstring(xml))) or "set"


def _text(name: str, value: object) -> str:
    return f"<{name}>{value}</{name}>"


def _interfaces_element(interface: str) -> list[tuple[str, str]]:
    """The Interfaces element naming one interface by name or by address; none ("" lets Cyclone choose)."""
    if not interface:
        return []
    attribute = "address" if _is_address(interface) else "name"
    return [("General/Interfaces", f"<Interfaces><NetworkInterface {attribute}={quoteattr(interface)}/></Interfaces>")]


def _is_address(text: str) -> bool:
    try:
        ipaddress.ip_address(text)
    except ValueError:
        return False
    return True


def _valid_host(text: str) -> bool:
    return _is_address(text) or bool(_HOST_NAME.match(text))


def _is_loopback(interface: str) -> bool:
    return interface in ("lo", "lo0") or (_is_address(interface) and ipaddress.ip_address(interface).is_loopback)


def _is_own_address(address: str) -> bool:
    """True when ``address`` belongs to this host (the kernel lets a socket bind to it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.bind((address, 0))
        except OSError:
            return False
    return True


def _route_source(address: str) -> str | None:
    """This host's address on the route to ``address``, or None without a route (connecting a UDP socket sends
    nothing)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.connect((address, 7400))
        except OSError:
            return None
        return str(probe.getsockname()[0])
