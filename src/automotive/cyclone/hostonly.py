"""Cyclone DDS's sockets of a domain made deaf to every other host: a classic BPF socket filter on each.

The single-host network mode (automotive.bus.network) lets Cyclone use the host's own LAN address beside 127.0.0.1, so
that Cyclone participants on their defaults on this host (the ``cyclonedds`` CLI, ROS 2 with rmw_cyclonedds_cpp) find
the applications. That address could also reach other hosts; this filter keeps them out. Every UDP socket Cyclone
opens for the domain gets a socket filter that lets a datagram in only when it was made on this host:

- it came through the loopback device (unicast to 127.0.0.1 and to any of the host's own addresses), or
- it is a multicast datagram this host sent and looped back to itself (packet type PACKET_LOOPBACK).

Datagrams from other hosts are dropped by the kernel before Cyclone reads them, so Cyclone never learns of a
participant on another host, and so never sends to one: no packet of the domain leaves the host (its only configured
peer is 127.0.0.1, and it sends multicast on the loopback device only). No Cyclone API opens a domain's sockets to
its user, so they are found as the sockets that appear while the domain is created (:func:`open_sockets` before,
:func:`restrict` after); Cyclone opens all of them then (one unicast pair, one multicast pair, a transmit socket per
interface) and none later. Written by hand: no library sets a socket filter on another library's sockets.

Linux only (SO_ATTACH_FILTER); :func:`available` says whether this host has it.
"""

from __future__ import annotations

import ctypes
import os
import socket
import struct
from dataclasses import dataclass

SO_ATTACH_FILTER = 26  # Linux's value (asm-generic/socket.h); not in Python's socket module
PACKET_LOOPBACK = 5  # linux/if_packet.h: a multicast datagram looped back to its sender's host
# Classic BPF (linux/filter.h): the packet type and the receiving device are "ancillary data" loads.
_SKF_AD_OFF = 0xFFFFF000  # -0x1000 as an unsigned 32-bit offset
_SKF_AD_PKTTYPE = 4
_SKF_AD_IFINDEX = 8
_LOAD_WORD_ABSOLUTE = 0x20  # BPF_LD | BPF_W | BPF_ABS
_JUMP_IF_EQUAL = 0x15  # BPF_JMP | BPF_JEQ | BPF_K
_RETURN = 0x06  # BPF_RET | BPF_K
_KEEP_ALL = 0xFFFFFFFF
_DROP = 0


class FilterError(OSError):
    """A socket of the domain that could not be filtered (the domain must then not use the host's LAN address)."""


def program(loopback_index: int) -> list[tuple[int, int, int, int]]:
    """The filter: keep a datagram that arrived on the loopback device or was looped back by this host, drop the rest
    (instructions as (code, jump if true, jump if false, constant))."""
    return [
        (_LOAD_WORD_ABSOLUTE, 0, 0, _SKF_AD_OFF + _SKF_AD_PKTTYPE),
        (_JUMP_IF_EQUAL, 2, 0, PACKET_LOOPBACK),  # looped-back multicast: keep
        (_LOAD_WORD_ABSOLUTE, 0, 0, _SKF_AD_OFF + _SKF_AD_IFINDEX),
        (_JUMP_IF_EQUAL, 0, 1, loopback_index),  # through the loopback device: keep
        (_RETURN, 0, 0, _KEEP_ALL),
        (_RETURN, 0, 0, _DROP),
    ]


def attach(sock: socket.socket) -> None:
    """Set the host-only filter on one socket (FilterError if the kernel refuses it)."""
    instructions = program(socket.if_nametoindex("lo"))
    code = b"".join(struct.pack("HBBI", *instruction) for instruction in instructions)
    buffer = ctypes.create_string_buffer(code, len(code))
    # struct sock_fprog { unsigned short len; struct sock_filter *filter; }: the kernel copies the program.
    fprog = struct.pack("HP", len(instructions), ctypes.addressof(buffer))
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_ATTACH_FILTER, fprog)
    except OSError as error:
        raise FilterError(error.errno, f"cannot filter a DDS socket ({error.strerror})") from None


def available() -> bool:
    """Whether this host can filter sockets (Linux with socket filters, and a loopback device named lo)."""
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            attach(probe)
    except OSError:
        return False
    return True


def open_sockets() -> dict[int, str]:
    """The process's open sockets: file descriptor -> its inode ("socket:[1234]")."""
    found: dict[int, str] = {}
    for name in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{name}")
        except OSError:  # closed meanwhile, or the listing's own descriptor
            continue
        if target.startswith("socket:"):
            found[int(name)] = target
    return found


@dataclass(frozen=True)
class Filtered:
    """The domain's sockets that were filtered, by their bound (address, port)."""

    sockets: tuple[tuple[str, int], ...]

    def covers(self, port: int) -> bool:
        return any(bound_port == port for _, bound_port in self.sockets)


def restrict(before: dict[int, str], addresses: tuple[str, ...], ports: range) -> Filtered:
    """Filter the UDP sockets opened since ``before`` (:func:`open_sockets`) that are Cyclone's: bound to any address
    on a port of the domain (``ports``), or to one of the interface ``addresses`` Cyclone transmits from.
    FilterError when one cannot be filtered."""
    filtered: list[tuple[str, int]] = []
    for descriptor, target in open_sockets().items():
        if before.get(descriptor) == target:
            continue
        try:
            sock = socket.socket(fileno=os.dup(descriptor))
        except OSError:  # closed meanwhile
            continue
        with sock:
            if sock.family != socket.AF_INET or sock.type != socket.SOCK_DGRAM:
                continue
            address, port = sock.getsockname()
            if (address == "0.0.0.0" and port in ports) or address in addresses:
                attach(sock)
                filtered.append((address, port))
    return Filtered(tuple(filtered))
