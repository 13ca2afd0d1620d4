"""Two hosts made of network namespaces joined by a veth pair: unicast peers with multicast off, a wrong peer list,
a lossy link, and an RTI Connext participant configured as RTI users write initial peers. Needs root (ip netns);
skipped otherwise.

Host A (10.231.0.1, veth-a) and host B (10.231.0.2, veth-b) exist only inside their namespaces, which each test
creates and deletes. Each test's applications are stopped before its namespaces are deleted.
"""

from __future__ import annotations

import itertools
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from apprunner import AppRunner, CommandProcess

from automotive.bus.alerts import ALERT_TEXTS
from automotive.tools.support import netlab
from automotive.tools.support.children import program_command

ROOT = Path(__file__).resolve().parent.parent
SUBNET = "10.231.0"  # a private /24, used only inside the test's namespaces
ADDRESS_A, ADDRESS_B = f"{SUBNET}.1", f"{SUBNET}.2"
PEERS = f"{ADDRESS_A},{ADDRESS_B}"
LOSS_PERCENT = 10
# Peers mode discovers two hosts within this many seconds under LOSS_PERCENT % loss (README, docs/deployment.md).
DISCOVERY_BOUND_S = 5.0
# A line Cyclone DDS logs itself (its errors and warnings: "<time> [<domain>] <thread>: ..."); a normal run has none.
CYCLONE_LOG_LINE = r"^\d+\.\d+ \[\d+\] "
_names = itertools.count()


def run(*command: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(list(command), capture_output=True, text=True, timeout=20)


def must(*command: str) -> None:
    result = run(*command)
    if result.returncode != 0:
        raise AssertionError(f"{' '.join(command)}: {result.stderr.strip()}")


@dataclass
class Host:
    namespace: str
    device: str
    address: str
    net: netlab.Namespace | None = None

    @property
    def end(self) -> tuple[netlab.Namespace, str]:
        assert self.net is not None, f"{self.namespace} not made yet"
        return self.net, self.device


@dataclass
class TwoHosts:
    a: Host
    b: Host
    runner: AppRunner
    domain_id: int
    processes: list[CommandProcess] = field(default_factory=list)

    def start(self, host: Host, name: str, command: list[str], stdin: bool = False,
              separate_stderr: bool = False, env: dict[str, str] | None = None) -> CommandProcess:
        return self.runner.start_command(f"{name}@{host.namespace}", ["ip", "netns", "exec", host.namespace, *command],
                                         env=env, stdin=stdin, separate_stderr=separate_stderr)

    def app(self, host: Host, name: str, *args: str, peers: str = PEERS) -> CommandProcess:
        return self.start(host, name, program_command(name, "--domain", str(self.domain_id), "--peers", peers,
                                                      "--interface", host.device, *args))

    def assert_no_cyclone_lines(self) -> None:
        for process in self.runner.processes:
            lines = [line for line in process.lines if re.match(CYCLONE_LOG_LINE, line)]
            assert not lines, f"{process.name} printed Cyclone DDS log lines:\n" + "\n".join(lines[:10])

    def add_loss(self, percent: int) -> None:
        """Drop ``percent`` % of the UDP packets arriving on each end of the link (both directions)."""
        netlab.lose([self.a.end, self.b.end], percent)

    def dropped(self) -> int:
        """Packets dropped on the link so far."""
        return netlab.dropped([self.a.end, self.b.end])


@pytest.fixture
def hosts(domain_id: int) -> Iterator[TwoHosts]:
    reason = netlab.unavailable()
    if reason is not None:
        pytest.skip(reason)
    suffix = f"{os.getpid()}-{next(_names)}"
    a = Host(f"auto-a-{suffix}", "veth-a", ADDRESS_A)
    b = Host(f"auto-b-{suffix}", "veth-b", ADDRESS_B)
    runner = AppRunner(ROOT)
    try:
        for host in (a, b):
            host.net = netlab.Namespace(host.namespace)
        # Created straight into the namespaces: nothing of the link ever appears on the real host.
        netlab.veth(*a.end, a.address, *b.end, b.address)
        yield TwoHosts(a, b, runner, domain_id)
    finally:
        runner.stop_all()
        for host in (a, b):
            if host.net is not None:
                host.net.delete()


def test_alert_reaches_the_other_host_and_the_command_flows_back(hosts: TwoHosts) -> None:
    a, b = hosts.a, hosts.b
    unroutable = "10.232.0.1"  # no route leads there from the namespaces: left out, reported once, never sent to
    hmi = hosts.app(b, "hmi", "--ui", "console", peers=f"{PEERS},{unroutable}")
    avoidance = hosts.app(b, "collision_avoidance", "-D", "config.alertSize=1.0")  # every car is taller than 1 m
    platform = hosts.app(a, "vehicle_platform")
    fusion = hosts.app(a, "sensor_fusion")
    hosts.app(a, "vision")

    start = time.monotonic()
    avoidance.wait_for(r"\[SensorObjects\] reader matched a writer")  # A's sensor fusion, seen from B
    fusion.wait_for(r"\[SensorObjects\] writer matched a reader")
    hmi.wait_for(r"DRIVER ALERT: Driver attention required")  # B's HMI: the alert made on B from A's objects
    platform.wait_for(r"\[PlatformControl\] reader matched a writer")
    platform.wait_for(r"command \d+ stamped")  # B's command executed on A
    avoidance.wait_for(r"\[PlatformStatus\] reader matched a writer")  # A's status, seen from B
    print(f"cross-host flow established in {time.monotonic() - start:.1f} s")
    for process in (hmi, avoidance, platform, fusion):
        assert process.count(r"network: unicast peers") == 1, process.output[-2000:]
    assert hmi.count(rf"network: peer {unroutable} left out: no route leads there from this host") == 1
    hosts.assert_no_cyclone_lines()


def test_wrong_peer_list_nothing_flows(hosts: TwoHosts) -> None:
    a, b = hosts.a, hosts.b
    # Each host lists itself and an address where no host is: neither ever contacts the other.
    wrong_a, wrong_b = f"{ADDRESS_A},{SUBNET}.3", f"{ADDRESS_B},{SUBNET}.4"
    hmi = hosts.app(b, "hmi", "--ui", "console", peers=wrong_b)
    report = ["-D", "config.matchReport=2"]  # endpoints that matched nothing are reported after 2 s
    avoidance = hosts.app(b, "collision_avoidance", "-D", "config.alertSize=1.0", *report, peers=wrong_b)
    platform = hosts.app(a, "vehicle_platform", *report, peers=wrong_a)
    fusion = hosts.app(a, "sensor_fusion", peers=wrong_a)
    hosts.app(a, "vision", peers=wrong_a)

    # Each host on its own works: the applications of one host find each other.
    fusion.wait_for(r"\[VisionTopic\] reader matched a writer")
    hmi.wait_for(r"\[AlertTopic\] reader matched a writer")
    fusion.wait_for(r"published list 1:")
    # An observation window counted in A's own work: 50 object lists (5 s). With the right peers the first
    # cross-host match comes well within 1 s of both hosts being up.
    fusion.wait_for(r"published list 50:", timeout=30)
    assert fusion.count(r"\[SensorObjects\] writer matched") == 0, fusion.output[-2000:]
    assert avoidance.count(r"\[SensorObjects\] reader matched") == 0, avoidance.output[-2000:]
    assert avoidance.count(r"\[PlatformStatus\] reader matched") == 0, avoidance.output[-2000:]
    assert avoidance.count(r"\[PlatformControl\] writer matched") == 0, avoidance.output[-2000:]
    assert platform.count(r"\[PlatformControl\] reader matched") == 0, platform.output[-2000:]
    assert platform.count(r"\[PlatformStatus\] writer matched") == 0, platform.output[-2000:]
    assert hmi.count(r"DRIVER ALERT: ") == 0
    assert platform.count(r"command \d+ stamped") == 0
    # ... and the applications say so
    avoidance.wait_for(r"\[SensorObjects\] reader: no writer matched after 2 s")
    avoidance.wait_for(r"\[PlatformStatus\] reader: no writer matched after 2 s")
    platform.wait_for(r"\[PlatformControl\] reader: no writer matched after 2 s")


def decode_hmi_alert(line: str) -> int:
    """The alert number of an HMI 'DRIVER ALERT: text; text' line (bit i: the i-th text of the HMI)."""
    texts = line.split("DRIVER ALERT: ", 1)[1].split("; ")
    order = list(ALERT_TEXTS.values())
    return sum(1 << order.index(text) for text in texts)


def test_every_alert_arrives_in_order_over_a_lossy_link(hosts: TwoHosts) -> None:
    """Numbered alerts from A reach B's HMI and a keep-all reader through a link that drops 10 % each way.

    The HMI profile keeps the latest alert (keep last 1 on both sides): an alert replaced before it was repaired or
    taken is, by design, not shown. So the writer sends each alert once the previous one was acknowledged by both
    readers and shown by the HMI (a step driven by this test); each alert still has to cross the lossy link on its
    own, and any loss on the way has to be repaired by the reliable protocol.
    """
    a, b = hosts.a, hosts.b
    count = 30
    hosts.add_loss(LOSS_PERCENT)
    script = str(ROOT / "tests" / "alert_sequence.py")
    common = ["--domain", str(hosts.domain_id), "--peers", PEERS]
    hmi = hosts.app(b, "hmi", "--ui", "console")
    reader = hosts.start(b, "alert_reader", [sys.executable, script, "read", "--keep-all", *common,
                                             "--interface", b.device])
    # The writer starts once both readers exist, so that the time it takes to match them is discovery's alone.
    hmi.wait_for(r"waiting for alerts")
    reader.wait_for(r"^reading alerts$")
    writer = hosts.start(a, "alert_writer", [sys.executable, script, "write", *common, "--interface", a.device,
                                             "--count", str(count), "--readers", "2", "--step", "--timeout", "20"],
                         stdin=True)
    matched = writer.wait_for(r"matched 2 readers in [\d.]+ s", timeout=30)
    discovery_s = float(matched.split()[-2])
    assert discovery_s <= DISCOVERY_BOUND_S, matched
    for number in range(1, count + 1):
        writer.wait_for(rf"^wrote alert {number}$", timeout=20)  # acknowledged by both readers
        reader.wait_for(rf"^alert {number}$", timeout=5)
        hmi.wait_for(r"DRIVER ALERT: ", count=number, timeout=5)
        if number < count:
            writer.send("next")
    summary = writer.wait_for(rf"all {count} alerts acknowledged")
    assert writer.wait_exit(timeout=10) == 0

    received = [int(line.split()[1]) for line in reader.lines if re.fullmatch(r"alert \d+", line)]
    assert received == list(range(1, count + 1)), received  # in order, none missing, none twice
    shown = [decode_hmi_alert(line) for line in hmi.lines if "DRIVER ALERT: " in line]
    assert shown == list(range(1, count + 1)), shown
    dropped = hosts.dropped()
    print(f"{matched}; {summary}; {dropped} packets dropped on the link")
    assert dropped > 0  # the loss was real
    hosts.assert_no_cyclone_lines()


def test_rti_participant_whose_initial_peers_name_only_the_other_host(hosts: TwoHosts) -> None:
    """An RTI Connext participant on B whose initial peers name only A, as RTI users write them; our applications
    on A (peers: every host) and on B (peers: only A). Every flow reaches every reader, both ways: the RTI readers
    get what A and B write, and our readers on A (another host) and on B (the same host) get what RTI writes."""
    a, b = hosts.a, hosts.b
    # RTI's default transports include shared memory: an IPC namespace of its own keeps it from other RTI processes
    rti = hosts.start(b, "rti_peer", [
        "unshare", "--ipc", sys.executable, str(ROOT / "tests" / "rti_peer.py"), "--domain", str(hosts.domain_id),
        # The participant also reads what it writes: its alert reader keeps 16 samples (not the HMI profile's
        # latest one), so that its own alert, written every 0.2 s, does not replace ours before it is taken.
        "--initial-peers", ADDRESS_A,
        "--read", "Vision,SensorObjects,PlatformStatus,PlatformControl,Alerts:ReliableReader",
        "--write", 'Vision={"id": 42}', "--write", 'PlatformControl={"sample_id": 4242}',
        "--write", 'Alerts={"frontCollision": true}'], separate_stderr=True)  # RTI logs to stderr in pieces
    hosts.app(a, "vision")
    fusion = hosts.app(a, "sensor_fusion")
    platform = hosts.app(a, "vehicle_platform")
    avoidance = hosts.app(b, "collision_avoidance", "-D", "config.alertSize=1.0", peers=ADDRESS_A)
    hmi = hosts.app(b, "hmi", "--ui", "console", peers=ADDRESS_A)

    # RTI on B reads our flows from A ...
    rti.wait_for(r"^received Vision id=(?!42$)\d+$")  # vision's own sensor id, not RTI's 42
    rti.wait_for(r"^received SensorObjects ")
    rti.wait_for(r"^received PlatformStatus ")
    # ... and from B (the RTI participant's own writers are told apart by their values)
    rti.wait_for(r"^received PlatformControl sample_id=(?!4242$)\d+$")
    rti.wait_for(r"^received Alerts driverAttention$")
    # Our readers on A get RTI's samples from B, and so does our HMI on B
    fusion.wait_for(r"published list \d+: .* of sensor\(s\) (\d+,)*42\b")
    platform.wait_for(r"command 4242 stamped")
    hmi.wait_for(r"DRIVER ALERT: Front collision warning$")
    # ... and our applications found each other across the hosts too
    avoidance.wait_for(r"\[SensorObjects\] reader matched a writer")
    platform.wait_for(r"command (?!4242 )\d+ stamped")  # collision avoidance on B commands A
    hosts.assert_no_cyclone_lines()


def test_lan_multicast_with_the_launcher_on_each_host(hosts: TwoHosts, tmp_path: Path) -> None:
    """The README's LAN example: scripts/launch with a subset and --interface on each host, multicast discovery."""
    a, b = hosts.a, hosts.b
    for host in (a, b):
        must("ip", "-n", host.namespace, "link", "set", host.device, "multicast", "on")
    launch = [str(ROOT / "scripts" / "launch"), "--no-setup", "--mode", "background", "-v",
              "--domain", str(hosts.domain_id)]
    on_a = hosts.start(a, "launch", [*launch, "--interface", a.device, "--log-dir", str(tmp_path / "a"),
                                     "vision", "sensor_fusion", "vehicle_platform"])
    on_b = hosts.start(b, "launch", [*launch, "--interface", b.device, "--log-dir", str(tmp_path / "b"),
                                     "--except", "vision,lidar,sensor_fusion,vehicle_platform,camera_pub,camera_sub",
                                     "-D", "collision_avoidance:config.alertSize=1.0"])
    on_b.wait_for(r"^hmi\s+\| .*network: LAN multicast on veth-b")
    on_b.wait_for(r"^hmi\s+\| .*DRIVER ALERT: Driver attention required")
    on_a.wait_for(r"^vehicle_platform\s+\| .*command \d+ stamped")
    for launcher in (on_a, on_b):
        launcher.process.send_signal(signal.SIGINT)
        assert launcher.wait_exit(timeout=20) == 0, launcher.output[-2000:]


# A system older than Cyclone's default prune delay for unanswered peers (30 s), and what the README promises a
# participant of any stack that joins it later (tests/test_late_joiners.py has the single-host cases).
SYSTEM_AGE_S = 35.0
LATE_JOIN_BOUND_S = 10.0
LATE_READS = ("Vision", "SensorObjects", "PlatformStatus", "PlatformControl", "Alerts", "Lidar", "Camera")
# The system on A writes Cyclone's discovery trace (about 3 MB), so that a late join that fails says what each
# application saw of the RTI participant: how a failure in CI was found to be the peer's own (docs/development.md).
TRACE_FILE = "cyclone-${CYCLONEDDS_PID}.log"


def launch_on_a(hosts: TwoHosts, log_dir: Path, *args: str) -> CommandProcess:
    """``scripts/launch`` on A (background, verbose) with Cyclone's discovery trace in ``log_dir``."""
    tracing = f"<Tracing><Category>discovery</Category><OutputFile>{log_dir}/{TRACE_FILE}</OutputFile></Tracing>"
    uri = os.environ["CYCLONEDDS_URI"].replace("</Domain>", tracing + "</Domain>", 1)
    return hosts.start(hosts.a, "launch", [
        str(ROOT / "scripts" / "launch"), "--no-setup", "--mode", "background", "-v", "--domain", str(hosts.domain_id),
        "--log-dir", str(log_dir), *args], env={"CYCLONEDDS_URI": uri})


def discovery_digest(log_dir: Path, since: float) -> str:
    """What each application on A saw of the participants of B after ``since`` (wall clock), from its trace: when it
    found each, and which of their endpoints it learnt of and matched."""
    lines = []
    traces = {trace: trace.read_text(errors="replace")
              for trace in sorted(log_dir.glob(TRACE_FILE.replace("${CYCLONEDDS_PID}", "*")))}
    # Each participant's discovery port on A (its participant index), as the others found it.
    ports = {guid: port for text in traces.values() for guid, port in re.findall(
        r"SPDP ST0 (\S+) .*?meta udp/" + re.escape(ADDRESS_A) + r":(\d+)", text)}
    for trace, text in traces.items():
        own = re.search(r'PARTICIPANT (\S+) QOS=\{.*?entity_name="(\w+)"', text)
        found = re.findall(r"^(\d+\.\d+) .*SPDP ST0 (\w+:\w+:\w+):1c1 .*?NEW .*?\(data udp/" + re.escape(ADDRESS_B),
                           text, re.M)
        name = f"{own.group(2)} (port {ports.get(own.group(1), '?')})" if own else trace.name
        finds = ", ".join(f"found {prefix} at {float(when) - since:+.2f} s" for when, prefix in found)
        lines.append(f"  {name}: {finds or 'found no participant of B'}")
        for _when, prefix in found:
            quoted = re.escape(prefix)
            known = dict(re.findall(rf"SEDP ST0 {quoted}:(\w+) .*? (?:reader|writer) (\w+):", text))
            matched = {known[entity] for pair in re.findall(
                rf"ddsi_proxy_reader_add_connection\(wr \S+ prd {quoted}:(\w+)\)|"
                rf"ddsi_proxy_writer_add_connection\(pwr {quoted}:(\w+) ", text) for entity in pair if entity in known}
            lines.append(f"    its endpoints seen: {', '.join(sorted(known.values())) or 'none'}; matched here: "
                         f"{', '.join(sorted(matched)) or 'none'}")
    return "discovery on A, from Cyclone's traces:\n" + ("\n".join(lines) or "  no traces")


def late_rti_participant(hosts: TwoHosts, launcher: CommandProcess, log_dir: Path, *rti_args: str) -> None:
    """Start an RTI participant on B once the system launched on A has run SYSTEM_AGE_S: it must match every flow
    within LATE_JOIN_BOUND_S, receive the small ones, and its circle must reach the LiDAR on A."""
    launcher.wait_for(r"application\(s\) running")
    started = time.monotonic()
    launcher.wait_for(r"^lidar\s+\| .*frame \d+:")
    time.sleep(max(0.0, started + SYSTEM_AGE_S - time.monotonic()))  # the point of the test: join late
    assert launcher.process.poll() is None, launcher.output[-4000:]
    joined = time.monotonic()
    rti = hosts.start(hosts.b, "rti_peer", [
        "unshare", "--ipc", sys.executable, str(ROOT / "tests" / "rti_peer.py"), "--domain", str(hosts.domain_id),
        *rti_args, "--read", ",".join(f"{name}:DefaultReader" for name in LATE_READS),
        "--write", 'Circle={"color": "ORANGE", "x": 100, "y": 100, "shapesize": 30}'], separate_stderr=True)
    # The bound counts from the RTI participant's creation, not from the start of a Python process that imports
    # RTI's Connector (several seconds on a loaded 2-core machine: not what this test is about).
    rti.wait_for(r"^rti peer running$", timeout=120)
    joined, joined_wall = time.monotonic(), time.time()
    try:
        for name in LATE_READS:
            rti.wait_for(rf"^reader {name} matched [1-9]", timeout=LATE_JOIN_BOUND_S + joined - time.monotonic())
        rti.wait_for(r"^writer Circle matched [1-9]", timeout=LATE_JOIN_BOUND_S + joined - time.monotonic())
    except AssertionError as failure:
        raise AssertionError(f"{failure}\n{discovery_digest(log_dir, joined_wall)}") from None
    print(f"late RTI participant on B matched every flow after {time.monotonic() - joined:.2f} s")
    for name in ("Vision", "SensorObjects", "PlatformStatus", "PlatformControl", "Lidar"):
        rti.wait_for(rf"^received {name} ")
    launcher.wait_for(r"^lidar\s+\| .*shape ORANGE appeared")


def test_a_late_rti_participant_on_another_host_finds_every_application_with_unicast_peers(
        hosts: TwoHosts, tmp_path: Path) -> None:
    """The whole system on A in peers mode, an RTI participant on B (initial peers: A) joining it late."""
    launcher = launch_on_a(hosts, tmp_path / "a", "--peers", PEERS)
    late_rti_participant(hosts, launcher, tmp_path / "a", "--initial-peers", ADDRESS_A)
    hosts.assert_no_cyclone_lines()


def test_a_late_rti_participant_on_another_host_finds_every_application_on_a_multicast_lan(
        hosts: TwoHosts, tmp_path: Path) -> None:
    """The whole system on A in LAN mode, an RTI participant on B with RTI's own defaults joining it late."""
    for host in (hosts.a, hosts.b):
        must("ip", "-n", host.namespace, "link", "set", host.device, "multicast", "on")
    launcher = launch_on_a(hosts, tmp_path / "a", "--interface", hosts.a.device)
    late_rti_participant(hosts, launcher, tmp_path / "a", "--lan")


def test_camera_frames_go_through_shared_memory_on_their_host_and_over_udp_to_the_other_at_once(
        prefix: str, hosts: TwoHosts) -> None:
    """The shipped transport (auto) on both hosts, with the same shared-memory prefix and one /dev/shm (the two
    "hosts" share this machine): the viewer beside the publisher gets the frames through shared memory, the one on
    the other host over UDP, each frame once; the publisher writes every frame on DDS for the remote one only."""
    frames = 40
    common = ["-D", f"config.shmPrefix={prefix}", "-D", "config.imageSize=64KiB", "--count", str(frames)]
    local = hosts.app(hosts.a, "camera_sub", *common)
    remote = hosts.app(hosts.b, "camera_sub", *common)
    for viewer in (local, remote):
        viewer.wait_for("viewing CameraImageData_64KiB frames")
    publisher = hosts.app(hosts.a, "camera_pub", *common, "-D", "config.pubInterval=20",
                          "-D", "config.waitSubscribers=2")
    for viewer in (local, remote):
        assert viewer.wait_exit(timeout=120) == 0, viewer.output[-3000:]
        assert re.search(rf"totals: samples={frames} size=65536 .* mismatches=0 .* gaps=0", viewer.output), \
            viewer.output[-3000:]
    assert publisher.wait_exit(timeout=120) == 0, publisher.output[-3000:]
    assert f"shared memory: {frames} frames sent, {frames} written on DDS" in publisher.output, publisher.output
    assert "shared memory with publishers on this host" in local.output
    assert "goes over DDS only" not in local.output + remote.output + publisher.output
    hosts.assert_no_cyclone_lines()


def own_host_name(name: str, command: list[str]) -> list[str]:
    """``command`` run under host name ``name`` (a UTS namespace of its own): the test's network namespaces share
    this machine's host name, and host names are what discovery and /diagnostics tell hosts apart by."""
    return ["unshare", "--uts", "sh", "-c", 'hostname "$0" && exec "$@"', name, *command]


def test_the_monitor_marks_a_latency_between_two_hosts_as_of_clocks_not_shared(hosts: TwoHosts) -> None:
    """vision on host A (this machine's host name), sensor_fusion and the monitor on host B (a host name of its
    own): sensor_fusion's latency of VisionTopic is of A's clock against B's, shown marked, never as if exact."""
    a, b = hosts.a, hosts.b
    b_name = f"automotive-b-{os.getpid()}"
    network = ("--domain", str(hosts.domain_id), "--peers", PEERS, "--interface", b.device)
    fusion = hosts.start(b, "sensor_fusion", own_host_name(b_name, program_command("sensor_fusion", *network)))
    hosts.app(a, "vision")
    fusion.wait_for(r"\[VisionTopic\] reader matched a writer")

    def monitor(*args: str) -> str:
        result = subprocess.run(["ip", "netns", "exec", b.namespace, *own_host_name(
            b_name, program_command("monitor", *network, "--wait", "3", *args))],
            capture_output=True, text=True, timeout=120)
        assert result.returncode == 0, result.stderr[-3000:]
        return result.stdout

    deadline = time.monotonic() + 90
    while True:
        document = json.loads(monitor("--json"))
        pair = next((pair for pair in document["latencies"] if (pair["topic"], pair["writer"], pair["reader"])
                     == ("VisionTopic", "vision", "sensor_fusion")), None)
        if pair is not None and pair["writer_host"] is not None:
            break
        assert time.monotonic() < deadline, json.dumps(document, indent=1)[:6000]
    assert (pair["clock"], pair["writer_host"], pair["reader_host"]) == ("not shared", socket.gethostname(), b_name)
    assert pair["samples"] > 0, pair
    flow = next(flow for flow in document["flows"] if flow["topic"] == "VisionTopic")
    assert flow["latency"]["sensor_fusion"]["clock"] == "not shared", flow
    assert document["chain"]["clock"] != "shared", document["chain"]
    text = monitor("--once")
    section = text.split("\nLatency ", 1)[1].split("\n\n", 1)[0]
    assert re.search(r"^    VisionTopic: vision -> sensor_fusion: p50 ~-?[\d.e+-]+ ms, p99 ~-?[\d.e+-]+ ms "
                     r"\(clock not shared: another host\)", section, re.M), section
    assert re.search(r"^  VisionTopic read by sensor_fusion: p50 ~", section, re.M), section
    hosts.assert_no_cyclone_lines()
