"""Which DDS domain ids and participant indexes have UDP ports: the RTPS port mapping (DDSI-RTPS 2.x, 9.6.1.1).

A participant of domain ``d`` with participant index ``i`` uses, with the mapping's defaults (Cyclone's, RTI's, Fast
DDS's)::

    discovery multicast  PB + DG * d + D0            user multicast  PB + DG * d + D2
    discovery unicast    PB + DG * d + D1 + PG * i   user unicast    PB + DG * d + D3 + PG * i

Each domain owns the DG ports from its base PB + DG * d. An index whose unicast ports pass the next domain's base
sends discovery to another domain's ports (index 120 of domain d is port PB + DG * (d + 1) + 0: domain d + 1's
discovery multicast port), so indexes stop at MAX_PARTICIPANT_INDEX; and a domain is usable only while its highest
port, that of its highest index, fits in 16 bits (Cyclone otherwise fails to send: ``ddsi_udp_conn_write to
udp/127.0.0.1:65536 failed``). Every program takes a domain id through :func:`check_domain_id`, so all say the same.

The standard library only (the command-line plumbing, automotive.bus.cli, imports it).
"""

from __future__ import annotations

PORT_BASE = 7400  # PB
DOMAIN_GAIN = 250  # DG
PARTICIPANT_GAIN = 2  # PG
DISCOVERY_MULTICAST_OFFSET = 0  # d0
DISCOVERY_UNICAST_OFFSET = 10  # d1
USER_MULTICAST_OFFSET = 1  # d2
USER_UNICAST_OFFSET = 11  # d3
HIGHEST_PORT = 65535

# The largest index whose ports all stay below the next domain's base: D3 + PG * index < DG.
MAX_PARTICIPANT_INDEX = (DOMAIN_GAIN - USER_UNICAST_OFFSET - 1) // PARTICIPANT_GAIN  # 119
# Cyclone 11 probes participant indexes 0..MaxAutoParticipantIndex but takes only 0..MaxAutoParticipantIndex - 1
# (its search for a free index stops one past the index it found, and refuses the last one: "Failed to find a free
# participant index"). So a host holds MaxAutoParticipantIndex participants, and MaxAutoParticipantIndex, the
# highest index probed, stops at MAX_PARTICIPANT_INDEX.
MAX_PARTICIPANTS = MAX_PARTICIPANT_INDEX  # 119: indexes 0..118 taken, 0..119 probed
# The largest domain whose highest port (user unicast of index MAX_PARTICIPANT_INDEX) fits in 16 bits.
MAX_DOMAIN_ID = (HIGHEST_PORT - PORT_BASE - USER_UNICAST_OFFSET - PARTICIPANT_GAIN * MAX_PARTICIPANT_INDEX) \
    // DOMAIN_GAIN  # 231


def domain_base(domain_id: int) -> int:
    """The first port of a domain (its discovery multicast port)."""
    return PORT_BASE + DOMAIN_GAIN * domain_id + DISCOVERY_MULTICAST_OFFSET


def discovery_unicast_port(domain_id: int, participant_index: int) -> int:
    return PORT_BASE + DOMAIN_GAIN * domain_id + DISCOVERY_UNICAST_OFFSET + PARTICIPANT_GAIN * participant_index


def highest_port(domain_id: int, max_participant_index: int = MAX_PARTICIPANT_INDEX) -> int:
    """The highest port a participant of ``domain_id`` uses or probes (user unicast of the highest index)."""
    return PORT_BASE + DOMAIN_GAIN * domain_id + USER_UNICAST_OFFSET + PARTICIPANT_GAIN * max_participant_index


def check_domain_id(text: str) -> int:
    """A domain id from its text; a ValueError says the valid range, the same words wherever a domain is given."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= MAX_DOMAIN_ID:
        raise ValueError(f"expected a domain id 0..{MAX_DOMAIN_ID}, not '{text}'")
    return value
