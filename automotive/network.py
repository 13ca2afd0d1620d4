"""Where DDS traffic goes: single host on loopback, a multicast LAN, or unicast peers with multicast off.

The choice produces a Cyclone DDS configuration (XML) for the application's domain. A user's own CYCLONEDDS_URI
is honoured: when it is set and no network option was given explicitly, it is used untouched.
"""

from __future__ import annotations

import ipaddress
import os
import re
from dataclasses import dataclass, field
from xml.sax.saxutils import quoteattr

from automotive.errors import ConfigError

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
_HOST_NAME = re.compile(r"^[A-Za-z0-9]([A-Za-z0-9.-]*[A-Za-z0-9])?$")


@dataclass(frozen=True)
class NetworkConfig:
    mode: str = LOOPBACK
    interface: str = ""  # "" lets Cyclone choose (LAN and peers modes)
    peers: tuple[str, ...] = field(default_factory=tuple)
    max_participants: int = DEFAULT_MAX_PARTICIPANTS
    large_data: bool = False
    fragment_size: int = LARGE_DATA_FRAGMENT_SIZE
    socket_buffer: str = LARGE_DATA_SOCKET_BUFFER

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

    def cyclone_xml(self) -> str:
        """The Cyclone DDS configuration for this choice."""
        if self.mode == LOOPBACK:
            interface, multicast, peers = "lo", False, ("127.0.0.1",)
        elif self.mode == LAN:
            interface, multicast, peers = self.interface, True, ()
        else:
            interface, multicast, peers = self.interface, False, self.peers
        general = f"<AllowMulticast>{'true' if multicast else 'false'}</AllowMulticast>"
        if interface:
            attribute = "address" if _is_address(interface) else "name"
            general = f"<Interfaces><NetworkInterface {attribute}={quoteattr(interface)}/></Interfaces>" + general
        internal = ""
        if self.large_data:
            general += (f"<MaxMessageSize>{min(65500, self.fragment_size + 1500)}B</MaxMessageSize>"
                        f"<FragmentSize>{self.fragment_size}B</FragmentSize>")
            internal = (f'<Internal><SocketReceiveBufferSize min="default" max="{self.socket_buffer}"/>'
                        f'<SocketSendBufferSize min="default" max="{self.socket_buffer}"/></Internal>')
        discovery = ""
        if peers:
            peer_xml = "".join(f"<Peer address={quoteattr(peer)}/>" for peer in peers)
            discovery = (f"<Discovery><Peers>{peer_xml}</Peers><ParticipantIndex>auto</ParticipantIndex>"
                         f"<MaxAutoParticipantIndex>{self.max_participants}</MaxAutoParticipantIndex></Discovery>")
        return f"<CycloneDDS><Domain><General>{general}</General>{discovery}{internal}</Domain></CycloneDDS>"

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
