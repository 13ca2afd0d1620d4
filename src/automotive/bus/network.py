"""Where DDS traffic goes: single host on loopback, a multicast LAN, or unicast peers with multicast off.

The choice produces a Cyclone DDS configuration (XML) for the application's domain. A user's own CYCLONEDDS_URI
is honoured: when it is set and no network option was given explicitly, it is used untouched.

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

import ipaddress
import os
import re
import socket
from dataclasses import dataclass, field
from xml.sax.saxutils import quoteattr

from automotive.bus.errors import ConfigError

LOOPBACK = "loopback"
LAN = "lan"
PEERS = "peers"
MODES = (LOOPBACK, LAN, PEERS)

# Every participant on a host takes a participant index (a port); unicast discovery probes this many per peer.
DEFAULT_MAX_PARTICIPANTS = 120
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
# then climbed again while glibc placed the next buffers in the thread's arena (docs/memory.md). A quarter of that
# makes the climb end within the first minutes and bounds it at a few hundred kB; it still holds two of the largest
# datagrams (64 KiB, the receive chunk of 128 KiB plus one more), so no allocation per datagram is added.
RECEIVE_BUFFER_SIZE = "256KiB"
LOCALHOST = "127.0.0.1"
_HOST_NAME = re.compile(r"^[A-Za-z0-9]([A-Za-z0-9.-]*[A-Za-z0-9])?$")


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
    max_participants: int = DEFAULT_MAX_PARTICIPANTS
    large_data: bool = False
    fragment_size: int = LARGE_DATA_FRAGMENT_SIZE
    socket_buffer: str = LARGE_DATA_SOCKET_BUFFER
    # False for Cyclone's C tools of Debian (ddsperf 0.10.2), which stop on the loopback peer's PruneDelay attribute
    # (unknown before 0.11) where the Python runtime's Cyclone 11 needs it to probe for late joiners forever.
    prune_delay: bool = True
    # Samples kept of a running reliable writer just discovered, until its next heartbeat says where its history
    # starts (Cyclone's Internal/PrimaryReorderMaxSamples and, per reader that joined it, SecondaryReorderMaxSamples:
    # 128 by default; the rest is dropped without a trace). 0: Cyclone's defaults.
    reorder_samples: int = 0

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
        if max_participants < 1:
            raise ConfigError(f"{source}: max participants {max_participants} must be at least 1")
        return cls(mode, interface, tuple(peers), max_participants, large_data)

    def peer_plan(self) -> PeerPlan:
        """The listed peers resolved and classified (peers mode; other modes probe no peer host)."""
        return plan_peers(self.peers) if self.mode == PEERS else PeerPlan()

    def cyclone_xml(self, plan: PeerPlan | None = None) -> str:
        """The Cyclone DDS configuration for this choice (peers mode: from ``plan``, made here if not given)."""
        if self.mode == PEERS:
            return self._peers_xml(plan or self.peer_plan())
        if self.mode == LOOPBACK:
            prune = f' PruneDelay="{PROBE_FOREVER}"' if self.prune_delay else ""
            discovery = (f'<Discovery><Peers><Peer address="{LOCALHOST}"{prune}/></Peers>'
                         f"{self._participant_index_xml()}"
                         f"<SPDPInterval>{LOOPBACK_ANNOUNCE_INTERVAL}</SPDPInterval></Discovery>")
            return self._domain_xml(_interfaces_xml("lo"), False, discovery)
        return self._domain_xml(_interfaces_xml(self.interface), True, "")

    def _peers_xml(self, plan: PeerPlan) -> str:
        interface = self.interface or plan.route_source
        if not interface and not any(not _is_loopback(name) for _, name in socket.if_nameindex()):
            interface = "lo"  # a host without a network
        # Cyclone probes this host's own address (the interface's) by itself; with the prune delay below, as long as
        # it runs, like every listed peer.
        peers = "".join(f"<Peer address={quoteattr(peer)}/>" for peer in (*plan.remote, *plan.own))
        discovery = (f"<Discovery><Peers>{peers}</Peers>{self._participant_index_xml()}"
                     f"<SPDPInterval>{PEERS_ANNOUNCE_INTERVAL}</SPDPInterval>"
                     f"<InitialLocatorPruneDelay>{PROBE_FOREVER}</InitialLocatorPruneDelay></Discovery>")
        # Not asking the kernel on which interface a packet arrived: with that information Cyclone drops participant
        # announcements that arrive on an interface it does not use, such as RTI's answers through 127.0.0.1.
        internal = "<ExtendedPacketInfo>false</ExtendedPacketInfo>"
        return self._domain_xml(_interfaces_xml(interface), False, discovery, internal)

    def _participant_index_xml(self) -> str:
        return (f"<ParticipantIndex>auto</ParticipantIndex>"
                f"<MaxAutoParticipantIndex>{self.max_participants}</MaxAutoParticipantIndex>")

    def _domain_xml(self, interfaces: str, multicast: bool, discovery: str, internal: str = "") -> str:
        general = f"{interfaces}<AllowMulticast>{'true' if multicast else 'false'}</AllowMulticast>"
        if self.reorder_samples:
            internal += (f"<PrimaryReorderMaxSamples>{self.reorder_samples}</PrimaryReorderMaxSamples>"
                         f"<SecondaryReorderMaxSamples>{self.reorder_samples}</SecondaryReorderMaxSamples>")
        if self.large_data:
            general += (f"<MaxMessageSize>{min(65500, self.fragment_size + 1500)}B</MaxMessageSize>"
                        f"<FragmentSize>{self.fragment_size}B</FragmentSize>")
            internal += (f'<SocketReceiveBufferSize min="default" max="{self.socket_buffer}"/>'
                         f'<SocketSendBufferSize min="default" max="{self.socket_buffer}"/>')
        internal = f"<Internal>{internal}</Internal>" if internal else ""
        sizing = f"<Sizing><ReceiveBufferSize>{RECEIVE_BUFFER_SIZE}</ReceiveBufferSize></Sizing>"
        return (f"<CycloneDDS><Domain><General>{general}</General>{discovery}{internal}{sizing}</Domain>"
                f"</CycloneDDS>")

    def describe(self) -> str:
        if self.mode == LOOPBACK:
            return "single host (loopback)"
        if self.mode == LAN:
            return f"LAN multicast on {self.interface or 'the default interface'}"
        return f"unicast peers {', '.join(self.peers)}" + (f" on {self.interface}" if self.interface else "")


def user_uri() -> str | None:
    """The user's own Cyclone configuration, if any."""
    return os.environ.get("CYCLONEDDS_URI") or None


def _is_address(text: str) -> bool:
    try:
        ipaddress.ip_address(text)
    except ValueError:
        return False
    return True


def _valid_host(text: str) -> bool:
    return _is_address(text) or bool(_HOST_NAME.match(text))


def _interfaces_xml(interface: str) -> str:
    """The Interfaces element naming one interface by name or by address; nothing ("" lets Cyclone choose)."""
    if not interface:
        return ""
    attribute = "address" if _is_address(interface) else "name"
    return f"<Interfaces><NetworkInterface {attribute}={quoteattr(interface)}/></Interfaces>"


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
