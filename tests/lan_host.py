"""A host on a LAN, made of network namespaces, for tests of who finds the system and what leaves the host.

The host is a namespace whose ``eth0`` is a veth (multicast on, a default route through it, as a real host's LAN
interface); its far end is in a second namespace, the LAN, where a sniffer (``python tests/lan_host.py <device>``,
a raw packet socket) prints one line per frame that leaves the host. IPv6 is off on both ends, so the kernel's own
IPv6 chatter (router solicitations, MLD reports) never shows up among the frames. A participant on another host, when
a test needs one, runs in the LAN namespace itself.

    with LanHost("hd") as lan:
        sniffer = runner.start_command("sniffer", lan.sniffer_command())
        sniffer.wait_for(READY)
        system = runner.start_command("launch", lan.host.exec(*program_command("launch")))
        ...
        assert frames(sniffer) == []
"""

from __future__ import annotations

import itertools
import os
import socket
import struct
import sys
from pathlib import Path
from types import TracebackType

from automotive.tools.support import netlab
from automotive.tools.support.children import Child

HOST_ADDRESS, LAN_ADDRESS = "10.232.0.1", "10.232.0.2"  # a private /24, used only inside the test's namespaces
HOST_DEVICE, LAN_DEVICE = "eth0", "lan0"
SNIFFER = Path(__file__).resolve()
READY = "sniffing"
_names = itertools.count()


class LanHost:
    """The host namespace (``host``) and the LAN namespace (``lan``) with the link between them; deleted on exit."""

    def __init__(self, prefix: str):
        suffix = f"{os.getpid()}-{next(_names)}"
        self.host = netlab.Namespace(f"{prefix}-host-{suffix}")
        try:
            self.lan = netlab.Namespace(f"{prefix}-lan-{suffix}")
            for namespace in (self.host, self.lan):
                netlab.run(*namespace.exec("sysctl", "-qw", "net.ipv6.conf.all.disable_ipv6=1",
                                           "net.ipv6.conf.default.disable_ipv6=1"))
            netlab.veth(self.host, HOST_DEVICE, HOST_ADDRESS, self.lan, LAN_DEVICE, LAN_ADDRESS, multicast=True)
            netlab.run("ip", "-n", self.host.name, "route", "add", "default", "via", LAN_ADDRESS)
        except BaseException:
            self.delete()
            raise

    def __enter__(self) -> LanHost:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.delete()

    def delete(self) -> None:
        self.host.delete()
        if hasattr(self, "lan"):
            self.lan.delete()

    def sniffer_command(self) -> list[str]:
        """The sniffer, run in the LAN namespace on the host's link."""
        return self.lan.exec(sys.executable, str(SNIFFER), LAN_DEVICE)

    def incoming_sniffer_command(self) -> list[str]:
        """A sniffer of the other way, run in the host namespace on its eth0: a line per frame that reaches the host
        from the LAN (a participant on another host, run in the LAN namespace)."""
        return self.host.exec(sys.executable, str(SNIFFER), HOST_DEVICE)


def frames(sniffer: Child) -> list[str]:
    """The frames the sniffer saw so far, a line each (``ip 10.232.0.1:7400 > 239.255.0.1:7400 udp ttl 1``)."""
    return [line for line in sniffer.lines if line.startswith(("ip ", "ethertype "))]


def _summary(frame: bytes) -> str:
    ethertype = struct.unpack("!H", frame[12:14])[0]
    if ethertype != 0x0800:
        return f"ethertype {ethertype:#06x} length {len(frame)}"
    header = (frame[14] & 0x0F) * 4
    protocol, source, destination = frame[23], socket.inet_ntoa(frame[26:30]), socket.inet_ntoa(frame[30:34])
    if protocol in (socket.IPPROTO_UDP, socket.IPPROTO_TCP):
        source_port, destination_port = struct.unpack("!HH", frame[14 + header:18 + header])
        name = "udp" if protocol == socket.IPPROTO_UDP else "tcp"
        return f"ip {source}:{source_port} > {destination}:{destination_port} {name} ttl {frame[22]}"
    return f"ip {source} > {destination} protocol {protocol} ttl {frame[22]}"


def sniff(device: str) -> None:
    """Print a line per frame that arrives on ``device`` (from the other end of the link) until killed."""
    capture = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(0x0003))  # ETH_P_ALL
    capture.bind((device, 0))
    print(READY, flush=True)
    while True:
        frame, address = capture.recvfrom(65535)
        if address[2] != socket.PACKET_OUTGOING:
            print(_summary(frame), flush=True)


if __name__ == "__main__":
    sniff(sys.argv[1])
