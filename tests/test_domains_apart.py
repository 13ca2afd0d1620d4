"""Domains apart: the system on domain N never sends to a port of another domain, and participants of other stacks on
their own defaults on the neighbouring domains N-1 and N+1 neither hear it nor are heard by it.

A domain owns the 250 ports from 7400 + 250 x domain (automotive.bus.ports); a participant index whose ports passed
the next domain's base (index 120 was domain N+1's discovery multicast port) sent discovery to another domain. Here,
for the launcher's shipped defaults and for its largest setup (``--vision-sensors``, ``--redundant``):

1. A raw UDP listener (this file run as a script: ``python tests/test_domains_apart.py listen``) holds every port of
   domains N-1 and N+1 (the discovery and user multicast ports joined to 239.255.0.1 on lo and eth0, every unicast
   port bound to 0.0.0.0) from before the system starts until every participant of the system has probed the
   participant indexes several times: nothing arrives there. Its own datagrams, sent through each interface at start,
   prove it hears what would arrive; a port of domain N that it holds as well (participant index 119 for the shipped
   setup) counts the system's probes, so the window is measured in the system's own announcements. For the largest
   setup it holds domain N's low indexes (as other participants of the host would) so that the system's participants
   take the highest ones a Cyclone participant can take (up to 118: see HIGHEST_USABLE_INDEX), where an index's
   ports come next to the next domain's. The listener's own control: a Cyclone participant configured as the
   applications were before the fix (indexes up to 120) is caught within a second.
2. RTI Connector and Fast DDS participants on their defaults on N-1 and N+1 (as measured here: Fast DDS announces
   itself by multicast on lo and eth0 and probes no unicast port; RTI by multicast on eth0 only, and by unicast to
   127.0.0.1 indexes 0-4) read the system's flows and write flows the applications read: they find each other on
   their domain (the positive control), and nothing of the system: no match and no sample either way (the
   applications' status records, --stats-dir, say what they matched and took; the LiDAR names each circle).
3. The same peers on domain N do match and exchange data with the system: the observations of 2 can see a match.

Everything runs in a LanHost (tests/lan_host.py: a host namespace with lo and a multicast-capable eth0), as peers on
their defaults must: they multicast on every interface. RTI's shared memory gets an IPC namespace of its own, Fast
DDS's a /dev/shm of the test's (tests/fastdds_peer.py private_shm), so nothing meets a process outside the test. The
host namespace reserves the ports of N-1..N+1 (no process gets one as its ephemeral port), so that each participant
takes the index the test expects.

The domain: ``module_domain_id`` (tests/domain_ids.py: TEST_DOMAIN_IDS shared out among the workers), with N-1 and
N+1 used as well. They may be another test's ids: it does not matter, as no datagram of this module leaves its own
namespaces (nor any shared memory), and no other test's reaches them; the ids only need their ports (N+1 <= 231,
MAX_DOMAIN_ID). Needs root (network namespaces); skipped otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import select
import signal
import socket
import struct
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from apprunner import AppRunner
from fastdds_peer import FastDdsPeer, private_shm
from lan_host import HOST_ADDRESS, HOST_DEVICE, LanHost

from automotive.bus.ports import (
    DOMAIN_GAIN,
    MAX_DOMAIN_ID,
    MAX_PARTICIPANT_INDEX,
    discovery_unicast_port,
    domain_base,
)
from automotive.tools.launch.display import RUNNING_LINE
from automotive.tools.support import netlab
from automotive.tools.support.children import STDOUT, Child, program_command

ROOT = Path(__file__).resolve().parent.parent

MULTICAST_GROUP = "239.255.0.1"
LISTENING = "listening"
IP_PKTINFO = 8  # linux/in.h (not in Python's socket module): the destination address of each datagram
# The rounds of discovery announcements each participant of the system sends while the listener holds the ports
# (the shipped loopback mode probes every index every 2 s).
ROUNDS = 3


# -- the raw UDP listener (run inside the host namespace) -------------------------------------------------------------

def _port_name(port: int) -> str:
    """``domain 7 discovery multicast``, ``domain 7 index 3 user unicast``... (the port mapping's names)."""
    domain, offset = divmod(port - domain_base(0), DOMAIN_GAIN)
    if offset in (0, 1):
        return f"domain {domain} {('discovery', 'user')[offset]} multicast"
    if offset >= 10:
        index, user = divmod(offset - 10, 2)
        return f"domain {domain} index {index} {('discovery', 'user')[user]} unicast"
    return f"domain {domain} port +{offset}"


def _membership(group: str, interface: str) -> bytes:
    """struct ip_mreqn: a group on one interface, by index."""
    return socket.inet_aton(group) + socket.inet_aton("0.0.0.0") + struct.pack("i", socket.if_nametoindex(interface))


def _describe(data: bytes) -> str:
    """An RTPS datagram's vendor and GUID prefix (who sent it), or the first bytes of anything else."""
    if data[:4] == b"RTPS" and len(data) >= 20:
        return f"RTPS vendor {data[6]:02x}.{data[7]:02x} guid prefix {data[8:20].hex()}"
    return f"not RTPS: {data[:16]!r}"


def listen(watched: list[int], held_domain: int, held: range, address: str, interfaces: list[str]) -> int:
    """Hold every port of the ``watched`` domains and print a line per datagram that arrives there; hold the
    discovery ports of ``held_domain``'s indexes ``held`` too, printing the GUID prefix of each announcement that
    arrives at the highest one (the system's probes)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, min(hard, 4096)), hard))
    sockets: dict[int, tuple[socket.socket, int, bool]] = {}  # fd -> (socket, port, watched)

    def bind(port: int, watch: bool, groups: bool = False) -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.IPPROTO_IP, IP_PKTINFO, 1)
        sock.bind(("0.0.0.0", port))
        for interface in interfaces if groups else []:
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, _membership(MULTICAST_GROUP, interface))
        sockets[sock.fileno()] = (sock, port, watch)

    for domain in watched:
        for port in range(domain_base(domain), domain_base(domain) + DOMAIN_GAIN):
            bind(port, True, groups=port - domain_base(domain) in (0, 1))
    for index in held:
        bind(discovery_unicast_port(held_domain, index), False)
    witness = discovery_unicast_port(held_domain, held[-1]) if held else None

    # Self-test: what this host sends to the watched ports, by multicast through each interface and by unicast to
    # each address, arrives (not RTPS: never taken for the system's).
    expected: set[tuple[str, str, int]] = set()
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for domain in watched:
        for interface in interfaces:
            sender.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, _membership("0.0.0.0", interface))
            expected.add((interface, MULTICAST_GROUP, domain_base(domain)))
            sender.sendto(f"self-test {interface}".encode(), (MULTICAST_GROUP, domain_base(domain)))
        for destination, index in (("127.0.0.1", MAX_PARTICIPANT_INDEX), (address, 0)):
            port = discovery_unicast_port(domain, index)
            expected.add(("unicast", destination, port))
            sender.sendto(b"self-test unicast", (destination, port))
    sender.close()
    deadline = time.monotonic() + 10
    while expected and time.monotonic() < deadline:
        for fd in select.select(list(sockets), [], [], 0.2)[0]:
            sock, port, _ = sockets[fd]
            data, ancillary, _, source = sock.recvmsg(65535, socket.CMSG_SPACE(12))
            destination = _destination(ancillary)
            if data.startswith(b"self-test "):
                expected.discard((data[10:].decode(), destination, port))
    if expected:
        print(f"self-test failed: nothing arrived for {sorted(expected)}", flush=True)
        return 1
    print(f"{LISTENING} on {sum(watch for _, _, watch in sockets.values())} ports of domain(s) "
          f"{', '.join(map(str, watched))}; holding {len(held)} discovery port(s) of domain {held_domain}", flush=True)
    while True:
        for fd in select.select(list(sockets), [], [])[0]:
            sock, port, watch = sockets[fd]
            data, ancillary, _, source = sock.recvmsg(65535, socket.CMSG_SPACE(12))
            if watch and data.startswith(b"self-test "):
                continue  # a late copy of the self-test's
            if watch:
                print(f"datagram {source[0]}:{source[1]} > {_destination(ancillary)}:{port} ({_port_name(port)}), "
                      f"{len(data)} bytes, {_describe(data)}", flush=True)
            elif port == witness and data[:4] == b"RTPS":
                print(f"probe {data[8:20].hex()}", flush=True)


def _destination(ancillary: list[tuple[int, int, bytes]]) -> str:
    for level, kind, data in ancillary:
        if level == socket.IPPROTO_IP and kind == IP_PKTINFO:
            return socket.inet_ntoa(data[8:12])  # struct in_pktinfo: ifindex, spec_dst, addr (the header's)
    return "?"


def _main() -> int:
    parser = argparse.ArgumentParser(description="Hold UDP ports of DDS domains and print what arrives there.")
    parser.add_argument("command", choices=["listen"])
    parser.add_argument("--watch", required=True, help="comma-separated domain ids: every port of each is held")
    parser.add_argument("--hold", required=True, metavar="DOMAIN:FIRST-LAST",
                        help="a domain's participant indexes whose discovery ports are held (the last one counts "
                             "the announcements it receives)")
    parser.add_argument("--address", required=True, help="this host's LAN address (for the self-test)")
    parser.add_argument("--interfaces", default="lo,eth0")
    args = parser.parse_args()
    domain, _, indexes = args.hold.partition(":")
    first, _, last = indexes.partition("-")
    return listen([int(d) for d in args.watch.split(",")], int(domain), range(int(first), int(last) + 1),
                  args.address, args.interfaces.split(","))


# -- the tests ----------------------------------------------------------------------------------------------------

# The launcher's largest setup: `automotive launch --help` sets no maximum to --vision-sensors (1 or more); ten
# sensors and the redundant pairs make 19 applications. The listener holds domain N's indexes below them, as other
# participants of the host would, so that they take the highest indexes, next to domain N+1's ports.
LARGEST_VISION_SENSORS = 10
# The highest index a Cyclone participant can take: Cyclone DDS 11's automatic index search fails ("Failed to find a
# free participant index") when the free index it found is MaxAutoParticipantIndex itself (its loop counts one past
# it), so MAX_PARTICIPANT_INDEX (119) is never taken: the applications' 120 indexes are 119 in fact.
HIGHEST_USABLE_INDEX = MAX_PARTICIPANT_INDEX - 1
SETUPS: dict[str, list[str]] = {
    "shipped": [],
    "largest": ["--vision-sensors", str(LARGEST_VISION_SENSORS), "--redundant"],
}
# The flows the peers read (the system writes them) and write (Circle: the LiDAR; PlatformControl: the vehicle
# platform). In redundant mode SensorObjects, AlertTopic and PlatformControl are EXCLUSIVE (the standbys): RTI then
# reads them with its ExclusiveReader profile; the Fast DDS reader (SHARED) and RTI's command writer cannot match
# them, so the control on domain N expects those only from the shipped setup.
RTI_READS = ("Vision", "SensorObjects", "PlatformStatus", "Alerts", "Circle")
FASTDDS_READS = ("VisionTopic", "SensorObjects", "PlatformStatus", "AlertTopic", "rt/LidarTopic", "Circle")
SHARED_FLOWS_FASTDDS = ("VisionTopic", "PlatformStatus", "rt/LidarTopic")
EXCLUSIVE_FLOWS_RTI = ("SensorObjects", "Alerts")
EXCLUSIVE_FLOWS_FASTDDS = ("SensorObjects", "AlertTopic")
# What a peer of domain d writes: its circles' colours and the RTI command's sample id tell them apart.
COMMAND_IDS = {-1: 4241, 0: 4242, 1: 4243}  # by offset from N
STARTUP_TIMEOUT = 120.0  # the system and RTI's Python process on a loaded 2-core machine
WAIT = 60.0


@dataclass
class System:
    """The system of one setup, started in a LanHost, and what the listener saw while it started."""

    setup: str
    domain: int
    lan: LanHost
    launcher: Child
    stats: Path
    shm: Path
    applications: int
    listener_lines: list[str]
    indexes: list[int]  # the participant indexes of domain N bound by the system

    @property
    def redundant(self) -> bool:
        return "--redundant" in SETUPS[self.setup]

    def records(self, kind: str, since: float = 0.0) -> list[dict[str, Any]]:
        """The applications' status records of ``kind`` (``t`` >= ``since``), all programs."""
        found = []
        for path in sorted(self.stats.glob("*.jsonl")):
            for line in path.read_text().splitlines():
                try:
                    record = json.loads(line)
                except json.JSONDecodeError:  # a line being written
                    continue
                if record.get("kind") == kind and record.get("t", 0) >= since:
                    found.append(record)
        return found

    def match_counts(self, until: float = float("inf"), since: float = 0.0) -> dict[tuple[str, str, str], int]:
        """Per (program, topic, endpoint): the highest match count recorded between ``since`` and ``until``,
        or, with ``since`` 0, the last one before ``until``."""
        counts: dict[tuple[str, str, str], int] = {}
        for record in sorted(self.records("matched", since), key=lambda r: r["t"]):
            if record["t"] > until:
                break
            key = (record["program"], record["topic"], record["endpoint"])
            counts[key] = max(counts.get(key, 0), record["count"]) if since else record["count"]
        return counts


def _bound_discovery_ports(lan: LanHost, domain: int) -> set[int]:
    """The participant indexes of ``domain`` whose discovery unicast port is bound in the host namespace."""
    out = subprocess.run(lan.host.exec("ss", "-ulnH"), capture_output=True, text=True, timeout=20).stdout
    ports = {int(match) for match in re.findall(r"\S+:(\d+)\s", out)}
    return {index for index in range(MAX_PARTICIPANT_INDEX + 1) if discovery_unicast_port(domain, index) in ports}


def _wait_for_probes(listener: Child, participants: int, rounds: int, timeout: float) -> Counter[str]:
    """Until ``participants`` distinct GUID prefixes each probed the listener's witness port ``rounds`` times."""
    deadline = time.monotonic() + timeout
    while True:
        probes = Counter(line.split()[1] for line in listener.lines if line.startswith("probe "))
        if sum(1 for count in probes.values() if count >= rounds) >= participants:
            return probes
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise AssertionError(f"the witness port heard only {dict(probes)} within {timeout:.0f} s "
                                 f"(expected {participants} participants x {rounds} announcements)")
        listener.wait_for_more(r"^probe ", timeout=remaining)


@pytest.fixture(scope="module", params=list(SETUPS))
def system(request: pytest.FixtureRequest, module_domain_id: int,
           tmp_path_factory: pytest.TempPathFactory) -> Iterator[System]:
    reason = netlab.unavailable()
    if reason is not None:
        pytest.skip(reason)
    setup: str = request.param
    domain = module_domain_id
    assert 1 <= domain < MAX_DOMAIN_ID, f"domain {domain}: N-1 and N+1 must be domain ids too"
    folder = tmp_path_factory.mktemp(f"domains-{setup}")
    for name in ("logs", "stats", "shm"):
        (folder / name).mkdir()
    runner = AppRunner(ROOT)
    expected = 8 if setup == "shipped" else 7 + LARGEST_VISION_SENSORS + 2
    # Held indexes of domain N: the highest as a witness of the probes (shipped), or all below the system's (largest).
    held = range(MAX_PARTICIPANT_INDEX, MAX_PARTICIPANT_INDEX + 1) if setup == "shipped" else \
        range(0, HIGHEST_USABLE_INDEX + 1 - expected)
    with LanHost("dom") as lan:
        try:
            # The kernel gives no process of the host a port of N-1, N or N+1 as its own (ephemeral) port: Cyclone's
            # transmit sockets and the peers' take one each, and one that fell on a participant index's port (up to a
            # few runs in 100 for the largest setup) would push a participant to another index (DDS ports lie within
            # the ephemeral range for every domain from 102 on).
            netlab.run(*lan.host.exec("sysctl", "-qw", "net.ipv4.ip_local_reserved_ports="
                                      f"{domain_base(domain - 1)}-{domain_base(domain + 2) - 1}"))
            started = time.monotonic()
            listener = runner.start_command("listener", lan.host.exec(
                sys.executable, str(Path(__file__).resolve()), "listen", "--watch", f"{domain - 1},{domain + 1}",
                "--hold", f"{domain}:{held[0]}-{held[-1]}", "--address", HOST_ADDRESS,
                "--interfaces", f"lo,{HOST_DEVICE}"))
            listener.wait_for(rf"^{LISTENING} ", timeout=WAIT)
            # The system on its shipped network defaults: no CYCLONEDDS_URI (conftest's loopback configuration), the
            # shipped console (INFO).
            launcher = runner.start_command("launch", lan.host.exec(
                "env", "-u", "CYCLONEDDS_URI", "-u", "AUTOMOTIVE_LOG_LEVEL", *program_command(
                    "launch", "--domain", str(domain), "--mode", "background", "--log-dir", str(folder / "logs"),
                    "--stats-dir", str(folder / "stats"), *SETUPS[setup])))
            running = launcher.wait_for(RUNNING_LINE, timeout=STARTUP_TIMEOUT)
            applications = int(re.search(r"(\d+) application\(s\) running", running).group(1))  # type: ignore[union-attr]
            assert applications == expected, running
            # Every application at work (its first status line: its endpoints exist, so the system's own matches
            # are made before the peers come), and every participant's announcements sent several times.
            for name in re.findall(r"^launch\s+\| started (\S+) \(pid", launcher.output, re.MULTILINE):
                launcher.wait_for(rf"^{re.escape(name)}\s+\| .*status: ", timeout=STARTUP_TIMEOUT)
            probes = _wait_for_probes(listener, applications, ROUNDS, STARTUP_TIMEOUT)
            indexes = sorted(_bound_discovery_ports(lan, domain) - set(held))
            listener.stop()
            print(f"[{setup}] listener phase {time.monotonic() - started:.1f} s; {len(probes)} participant(s) "
                  f"probed; the system's indexes of domain {domain}: {indexes}")
            yield System(setup, domain, lan, launcher, folder / "stats", folder / "shm", applications,
                         listener.lines, indexes)
        finally:
            runner.stop_all()
            for pid in lan.host.pids():  # none expected: every process of the namespace is ours
                os.kill(pid, signal.SIGKILL)


def test_the_listener_hears_a_participant_whose_indexes_reach_the_next_domain(module_domain_id: int,
                                                                              apps: AppRunner) -> None:
    """The listener's own control, for the bug this module guards against: a Cyclone participant configured as the
    applications were before indexes stopped at 119 (peer 127.0.0.1, MaxAutoParticipantIndex 120) probes index 120,
    whose discovery port is domain N+1's discovery multicast port: the listener reports its announcements there."""
    reason = netlab.unavailable()
    if reason is not None:
        pytest.skip(reason)
    domain = module_domain_id
    old = ('<CycloneDDS><Domain><General><AllowMulticast>false</AllowMulticast><Interfaces>'
           '<NetworkInterface name="lo"/></Interfaces></General><Discovery><Peers><Peer address="127.0.0.1"/></Peers>'
           '<ParticipantIndex>auto</ParticipantIndex>'
           f'<MaxAutoParticipantIndex>{MAX_PARTICIPANT_INDEX + 1}</MaxAutoParticipantIndex></Discovery></Domain>'
           '</CycloneDDS>')
    with LanHost("dom") as lan:
        try:
            listener = apps.start_command("listener", lan.host.exec(
                sys.executable, str(Path(__file__).resolve()), "listen", "--watch", f"{domain - 1},{domain + 1}",
                "--hold", f"{domain}:{MAX_PARTICIPANT_INDEX}-{MAX_PARTICIPANT_INDEX}", "--address", HOST_ADDRESS,
                "--interfaces", f"lo,{HOST_DEVICE}"))
            listener.wait_for(rf"^{LISTENING} ", timeout=WAIT)
            apps.start_command("participant", lan.host.exec("env", f"CYCLONEDDS_URI={old}", sys.executable, "-c", (
                "import signal; from cyclonedds.domain import DomainParticipant; "
                f"participant = DomainParticipant({domain}); signal.pause()")))
            listener.wait_for(rf"^datagram 127\.0\.0\.1:\d+ > 127\.0\.0\.1:{domain_base(domain + 1)} \(domain "
                              rf"{domain + 1} discovery multicast\), \d+ bytes, RTPS vendor 01\.10 ", timeout=WAIT)
        finally:
            apps.stop_all()


def test_the_system_sends_nothing_to_the_neighbouring_domains_ports(system: System) -> None:
    """Phase A: not one datagram of the system (RTPS or not) on any port of N-1 or N+1, while every participant
    announced itself several times to every index; the system sat where asked (largest: up to index 118, the highest
    a Cyclone participant takes)."""
    lines = system.listener_lines
    arrived = [line for line in lines if line.startswith("datagram ")]  # RTPS or not: nothing else runs there
    assert arrived == [], "the system sent to the neighbouring domains' ports:\n" + "\n".join(arrived[:20])
    assert len(system.indexes) == system.applications, system.indexes
    if system.setup == "largest":
        expected = list(range(HIGHEST_USABLE_INDEX + 1 - system.applications, HIGHEST_USABLE_INDEX + 1))
        assert system.indexes == expected, "the system's participants did not take the highest indexes"
    else:
        assert system.indexes == list(range(system.applications)), system.indexes


def _colour(stack: str, domain: int) -> str:
    return f"{stack}{domain}"


@dataclass
class Peers:
    """An RTI participant and a Fast DDS reader and writer, on their defaults, on one domain."""

    domain: int
    rti: Child
    reader: FastDdsPeer
    writer: FastDdsPeer
    command_id: int

    @property
    def colours(self) -> tuple[str, str]:
        return _colour("RTI", self.domain), _colour("FASTDDS", self.domain)


def _start_peers(apps: AppRunner, system: System, offset: int) -> Peers:
    domain = system.domain + offset
    rti_colour, fast_colour = _colour("RTI", domain), _colour("FASTDDS", domain)
    command_id = COMMAND_IDS[offset]
    # RTI's defaults (the Lan profile: nothing but the participant's name), its shared memory in an IPC namespace of
    # its own; its stderr apart (RTI's log messages go there: Fast DDS's shared memory locators, which it cannot use).
    rti = Child(f"rti@{domain}", system.lan.host.exec(
        "unshare", "--ipc", sys.executable, str(ROOT / "tests" / "rti_peer.py"), "--domain", str(domain), "--lan",
        "--read", ",".join(f"{name}:ExclusiveReader" if system.redundant and name in EXCLUSIVE_FLOWS_RTI else name
                           for name in RTI_READS),
        "--write", "Circle=" + json.dumps({"color": rti_colour, "x": 60, "y": 60, "shapesize": 20}),
        "--write", f'PlatformControl={{"sample_id": {command_id}}}'), cwd=ROOT, separate_stderr=True)
    apps.processes.append(rti)  # stopped with the test's other processes
    prefix = private_shm(system.lan.host, system.shm)
    reader = FastDdsPeer.read(apps, list(FASTDDS_READS), domain, name=f"fastdds-reader@{domain}", defaults=True,
                              prefix=prefix)
    writer = FastDdsPeer.write_circle(apps, domain, fast_colour, 180, 180, 20, defaults=True, prefix=prefix,
                                      name=f"fastdds-writer@{domain}")
    return Peers(domain, rti, reader, writer, command_id)


def _wait_found_each_other(peers: Peers) -> None:
    """The positive control on the peers' domain: RTI and Fast DDS on their defaults find each other and their
    circles cross, both ways (two writers and two readers of Circle each)."""
    rti_colour, fast_colour = peers.colours
    peers.rti.wait_for(r"^rti peer running$", timeout=STARTUP_TIMEOUT)
    peers.rti.wait_for(r"^reader Circle matched [2-9] writer\(s\)$", timeout=WAIT)  # more: see the checks
    peers.rti.wait_for(rf"^received Circle color={fast_colour}$", timeout=WAIT)
    peers.reader.wait_matched("Circle", timeout=WAIT)
    peers.reader.process.wait_for(r"^matched: [2-9] writer\(s\) on Circle$", timeout=WAIT)
    peers.reader.process.wait_for(rf'^\{{"topic": "Circle", "sample": \{{"color": "{rti_colour}"', timeout=WAIT)
    peers.writer.process.wait_for(r"^matched: [2-9] reader\(s\) on Circle$", timeout=WAIT)


def _peer_saw_the_system(peers: Peers) -> list[str]:
    """What a peer on a neighbouring domain printed that only the system could have caused."""
    own = set(peers.colours)
    rti = [record.text for record in list(peers.rti.records) if record.stream == STDOUT]
    found = [line for line in rti
             if re.search(r"(reader (?!Circle )\S+ matched|writer (?!Circle )\S+ matched|received (?!Circle ))", line)
             or re.search(r"(reader|writer) Circle matched ([3-9]|\d\d)", line)
             or any(colour not in own for colour in re.findall(r"received Circle color=(\S+)", line))]
    for process in (peers.reader.process, peers.writer.process):  # unanchored: a line may follow a log message
        for line in process.lines:
            if re.search(r"matched: [1-9]\d* \S+ on (?!Circle\b)", line) or \
                    re.search(r"matched: ([3-9]|\d\d) \S+ on Circle", line) or "incompatible QoS" in line:
                found.append(f"{process.name}: {line}")
    for sample in peers.reader.samples("Circle"):
        if sample["color"] not in own:
            found.append(f"fastdds reader: a circle {sample['color']}")
    for topic in FASTDDS_READS:
        if topic != "Circle" and peers.reader.samples(topic):
            found.append(f"fastdds reader: {len(peers.reader.samples(topic))} sample(s) of {topic}")
    return found


def test_peers_on_their_defaults_on_the_neighbouring_domains_neither_match_nor_hear_the_system(
        system: System, apps: AppRunner) -> None:
    """Phase B: RTI and Fast DDS on their defaults on N-1 and N+1, reading the system's flows and writing Circle and
    PlatformControl, find each other on their domain and nothing of the system, nor the system anything of them,
    over several of the system's status periods after they found each other."""
    pytest.importorskip("rticonnextdds_connector")
    started = time.time()
    before = system.match_counts(until=started)
    neighbours = [_start_peers(apps, system, offset) for offset in (-1, 1)]
    for peers in neighbours:
        _wait_found_each_other(peers)
    # The window, counted in the system's own work once the peers announced themselves and found each other: three
    # status lines of the vehicle platform (5 s apart: 10 s at least), over which every participant of the system
    # probes every index at least five times and the peers announce themselves again (Fast DDS every 3 s).
    system.launcher.wait_for_more(r"^vehicle_platform\s+\| .*status: ", more=3, timeout=WAIT)
    window_s = time.time() - started
    heard = {f"{peers.domain}": _peer_saw_the_system(peers) for peers in neighbours}
    assert heard == {f"{peers.domain}": [] for peers in neighbours}, f"peers heard the system: {heard}"
    after = system.match_counts(since=started)
    new = {key: count for key, count in after.items() if count > before.get(key, 0)}
    assert new == {}, f"the system matched endpoints of the neighbouring domains' peers: {new}"
    commands = {record["sample_id"] for record in system.records("take", since=started) if "sample_id" in record}
    assert commands.isdisjoint(COMMAND_IDS[o] for o in (-1, 1)), commands
    colours = [_colour(stack, system.domain + offset) for stack in ("RTI", "FASTDDS") for offset in (-1, 1)]
    shapes = [line for line in system.launcher.lines if re.search(rf"shape ({'|'.join(colours)}) appeared", line)]
    assert shapes == [], "the LiDAR drew the neighbouring domains' circles"
    print(f"[{system.setup}] peers on {system.domain - 1} and {system.domain + 1}: found each other, nothing of "
          f"the system over {window_s:.1f} s")


def test_the_same_peers_on_the_systems_domain_match_and_exchange_data(system: System, apps: AppRunner) -> None:
    """Phase C, the control: the same peers on domain N itself are found by the system, read its flows and are
    read by it (the observations of the neighbours' test can see a match)."""
    pytest.importorskip("rticonnextdds_connector")
    started = time.time()
    before = system.match_counts(until=started)
    peers = _start_peers(apps, system, 0)
    rti_colour, fast_colour = peers.colours
    peers.rti.wait_for(r"^rti peer running$", timeout=STARTUP_TIMEOUT)
    running = time.time()
    for colour in (rti_colour, fast_colour):
        system.launcher.wait_for(rf"^lidar\s+\| .*shape {colour} appeared", timeout=WAIT)
    for name in RTI_READS:
        peers.rti.wait_for(rf"^received {name} ", timeout=WAIT)
    for topic in SHARED_FLOWS_FASTDDS + (() if system.redundant else EXCLUSIVE_FLOWS_FASTDDS):
        peers.reader.wait_samples(topic, 1, timeout=WAIT)
    if not system.redundant:  # vehicle_platform's command reader is EXCLUSIVE in redundant mode
        _wait_until(lambda: peers.command_id in {r.get("sample_id") for r in system.records("take", since=started)},
                    f"vehicle_platform to take command {peers.command_id}")
    after = system.match_counts(since=started)
    new = {key for key, count in after.items() if count > before.get(key, 0)}
    for program, topic, endpoint in (("lidar", "Circle", "reader"), ("vehicle_platform", "PlatformStatus", "writer"),
                                     ("lidar", "rt/LidarTopic", "writer")):
        assert (program, topic, endpoint) in new, f"{program} {topic} {endpoint} matched no peer: {sorted(new)}"
    print(f"[{system.setup}] peers on {system.domain}: {len(new)} endpoint(s) of the system matched them; every "
          f"flow crossed {time.time() - running:.1f} s after RTI's participant was up")


def _wait_until(condition: Callable[[], bool], what: str, timeout: float = WAIT) -> None:
    """Poll ``condition`` (a file the applications append to: nothing to block on) until true or ``timeout``."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.1)

if __name__ == "__main__":
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    sys.exit(_main())
