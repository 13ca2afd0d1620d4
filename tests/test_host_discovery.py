"""Who finds the system on its shipped defaults (the single-host network mode), and what of it leaves the host.

The system (`automotive launch`: eight applications, no configuration, no CYCLONEDDS_URI) runs in a host made of
network namespaces (tests/lan_host.py): its eth0 is a multicast-capable link to a LAN namespace, where a sniffer prints
every frame that leaves the host. Every other participant here runs on Cyclone DDS's own defaults, as a user's tool
would: no CYCLONEDDS_URI, so it announces itself by multicast on eth0 and listens on ports nobody can guess.

- Everyone on the host finds the system: `cyclonedds ps` lists the eight applications (joining after the system, and
  long after every discovery timeout); `cyclonedds subscribe` started before the system receives its samples; a
  plain Cyclone participant reads every flow from the application that writes it and is matched by every application
  that reads one, in either join order; a ROS 2-style reader gets LiDAR clouds that an independent ROS 2
  implementation (rosbags) decodes.
- Nobody off the host does: no frame leaves the host while the system runs alone, and a participant on another host
  (the LAN namespace) never matches an application, even while a default tool on the host has joined the multicast
  group there, so that the kernel hands the other host's announcements to the applications' sockets too.

The plain participant is this module run as a script (the tests start it inside a namespace):

    python tests/test_host_discovery.py participant --domain N --name NAME [--read TOPIC]... [--write TOPIC]...
    python tests/test_host_discovery.py ros2-lidar --domain N --save DIR --count K

One system is started after the tools (the first test) and one before them, shared by the other tests (the module's
fixture `system`). The participants they add write nothing the applications read, except the other host's circles,
which must never reach them. Needs root (ip netns); skipped otherwise.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from apprunner import AppRunner, CommandProcess
from dds_helpers import CYCLONEDDS_CLI, wait_until
from lan_host import HOST_ADDRESS, LAN_ADDRESS, READY, LanHost, frames

from automotive.bus.ports import domain_base
from automotive.cyclone.matched import matched_publications, matched_subscriptions
from automotive.tools.support import netlab
from automotive.tools.support.children import program_command

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = Path(__file__).resolve()
URI_VARIABLE = "CYCLONEDDS_URI"
LIBRARY = "AutomotiveLibrary"
APPS = ("vision", "lidar", "sensor_fusion", "vehicle_platform", "collision_avoidance", "hmi", "camera_pub",
        "camera_sub")
# Who writes and who reads each flow of the shipped system (src/automotive/apps) and the flow's QoS profile
# (src/automotive/config/properties). A profile's reader requests what its writer offers: the plain participant takes
# the profiles' QoS to match the applications' endpoints.
WRITERS = {"VisionTopic": "vision", "rt/LidarTopic": "lidar", "SensorObjects": "sensor_fusion",
           "PlatformStatus": "vehicle_platform", "PlatformControl": "collision_avoidance",
           "AlertTopic": "collision_avoidance", "CameraImageData": "camera_pub"}
READERS = {"VisionTopic": "sensor_fusion", "rt/LidarTopic": "sensor_fusion", "SensorObjects": "collision_avoidance",
           "PlatformStatus": "collision_avoidance", "PlatformControl": "vehicle_platform", "AlertTopic": "hmi",
           "CameraImageData": "camera_sub", "Circle": "lidar"}
PROFILES = {"VisionTopic": "Vision", "rt/LidarTopic": "Lidar", "SensorObjects": "SensorFusion",
            "PlatformStatus": "Platform", "PlatformControl": "CollisionAvoidance", "AlertTopic": "HMI",
            "CameraImageData": "Camera", "Circle": "Shapes"}
# Every application prints a status line every 5 s (config.statusInterval): the tests count time in them.
STATUS_INTERVAL_S = 5
# A participant on Cyclone's defaults announces itself by multicast every 8 s (measured here with Cyclone 11.0.1: the
# cyclonedds CLI and a plain participant alike). The applications hear a tool started before them at its next
# announcement after they joined.
DEFAULT_ANNOUNCE_INTERVAL_S = 8
# The applications take up to a few seconds to join on a loaded 2-core host; a tool started before them is heard
# within an announcement interval after that. Allowed for that order, from the launch:
TOOL_FIRST_TIMEOUT_S = 40
# `cyclonedds subscribe` first scans this long for the topic's writers and their type (XTypes), then subscribes with a
# participant of its own: started before the system, its scan must hear the applications (within the bound above).
SUBSCRIBE_SCAN_S = 30
# A plain participant (this file's script) starting: Python and Cyclone's imports on a busy 2-core machine (a clean
# clone's busy run saw one print nothing in 20 s).
PARTICIPANT_START_TIMEOUT_S = 90
# `cyclonedds ps` scans this long; a tool that joins after the system is answered at its first announcement.
PS_SCAN_S = 6
# Late: past Cyclone's initial probing (30 s) and several announcement intervals of the applications and the tools.
LATE_S = 35


# -- helpers ----------------------------------------------------------------------------------------------------------

def on_defaults(namespace: netlab.Namespace, *command: str) -> list[str]:
    """A command run in the namespace on Cyclone's defaults: the tests' CYCLONEDDS_URI (tests/conftest.py) taken out
    of its environment, as in a user's shell; everything else (AUTOMOTIVE_LOG_LEVEL too) kept."""
    return namespace.exec("env", "-u", URI_VARIABLE, *command)


def launch_command(domain: int, log_dir: Path) -> list[str]:
    """The launcher on the shipped defaults: only the domain, the log folder and background mode (as without a
    display: the HMI shows its console box)."""
    return program_command("launch", "--domain", str(domain), "--log-dir", str(log_dir), "--mode", "background")


def participant_command(domain: int, name: str, *args: str) -> list[str]:
    return [sys.executable, str(SCRIPT), "participant", "--domain", str(domain), "--name", name, *args]


def every_flow() -> list[str]:
    """The plain participant's endpoints: a reader of every flow an application writes, a writer of every flow an
    application reads."""
    return [*(arg for topic in WRITERS for arg in ("--read", topic)),
            *(arg for topic in READERS for arg in ("--write", topic))]


def status_line(app: str) -> str:
    """The launcher's console line of an application's periodic status."""
    return rf"^{app}\s+\| \S+ {app}: status: "


def assert_reads_every_flow_and_every_application_finds_it(plain: CommandProcess, timeout: float) -> None:
    """Samples of every flow from the application that writes it (so every writing application found the plain
    participant, to send them), and each of its writers matched by the application that reads the flow."""
    for topic, app in WRITERS.items():
        plain.wait_for(rf"^sample {re.escape(topic)} from {app}$", timeout=timeout)
    for topic, app in READERS.items():
        plain.wait_for(rf"^reader {re.escape(topic)} of {app} matched$", timeout=timeout)


def run_ps(namespace: netlab.Namespace, domain: int) -> set[str]:
    """The participant names `cyclonedds ps` (Cyclone's defaults) lists in the namespace."""
    result = subprocess.run(on_defaults(namespace, CYCLONEDDS_CLI, "ps", "--id", str(domain), "--runtime",
                                        f"{PS_SCAN_S}s", "--suppress-progress-bar", "--color", "none"),
                            capture_output=True, text=True, timeout=PS_SCAN_S + 30, cwd=ROOT,
                            env={**os.environ, "COLUMNS": "250"})  # a table row per participant, nothing cut
    assert result.returncode == 0, result.stdout + result.stderr
    names = set(re.findall(r"│ (\w+) \([0-9a-f-]{36}\)", result.stdout))  # │ vision (0110d4ce-...) │
    assert names, result.stdout + result.stderr
    return names


def announcers(sniffer: CommandProcess, domain: int) -> set[str]:
    """The sources (address:port) of the multicast participant announcements of the domain the sniffer saw."""
    return {match.group(1) for line in frames(sniffer)
            if (match := re.match(rf"ip (\S+) > 239\.255\.0\.1:{domain_base(domain)} udp", line))}


@dataclass(frozen=True)
class UdpSocket:
    address: str
    port: int
    pids: frozenset[int]
    dropped: int  # datagrams the kernel dropped for it, those its socket filter refused included


def udp_sockets(namespace: netlab.Namespace) -> list[UdpSocket]:
    """The UDP sockets of the namespace, with their processes and drop counts (ss)."""
    output = netlab.run(*namespace.exec("ss", "-uanpmH")).stdout
    return [UdpSocket(match.group(1), int(match.group(2)), frozenset(int(pid) for pid in
                                                                     re.findall(r"pid=(\d+)", match.group(3))),
                      int(match.group(4)))
            for match in re.finditer(r"(\S+):(\d+)\s+\S+:\*\s+users:\((.*?)\)\s+skmem:\([^)]*\bd(\d+)\)", output)]


@dataclass
class System:
    """The system launched in the host of a LanHost, the sniffer on the host's link, and the runner of both."""

    lan: LanHost
    runner: AppRunner
    sniffer: CommandProcess
    launcher: CommandProcess
    domain: int
    alone: list[str]  # the frames the sniffer saw while the system ran alone

    def pids(self) -> dict[str, int]:
        return {match.group(1): int(match.group(2)) for line in self.launcher.lines
                if (match := re.match(r"^launch\s+\| started (\S+) \(pid (\d+)\)", line))}

    def start(self, name: str, namespace: netlab.Namespace, *command: str) -> CommandProcess:
        return self.runner.start_command(name, on_defaults(namespace, *command))


def needs_namespaces() -> None:
    reason = netlab.unavailable()
    if reason is not None:
        pytest.skip(reason)


# -- tools first, then the system (its own system; first in the module, before the shared one starts) -----------------

def test_tools_started_before_the_system_find_every_application(apps: AppRunner, domain_id: int,
                                                                tmp_path: Path) -> None:
    """`cyclonedds subscribe PlatformStatus` and the plain participant, both on Cyclone's defaults, are up and have
    announced themselves before the system starts: the applications hear them at their next announcement."""
    needs_namespaces()
    with LanHost("hd") as lan:
        try:
            sniffer = apps.start_command("sniffer", lan.sniffer_command())
            sniffer.wait_for(READY)
            subscribe = apps.start_command("subscribe", on_defaults(
                lan.host, CYCLONEDDS_CLI, "subscribe", "PlatformStatus", "--id", str(domain_id), "--runtime",
                f"{SUBSCRIBE_SCAN_S}s", "--suppress-progress-bar", "--color", "none"))
            plain = apps.start_command("plain", on_defaults(lan.host, *participant_command(domain_id, "plain",
                                                                                           *every_flow())))
            plain.wait_for(r"^ready$", timeout=PARTICIPANT_START_TIMEOUT_S)
            # Both tools have announced themselves on eth0 (the sniffer sees a tool's announcements: they leave the
            # host), so both exist before the first application does.
            wait_until(lambda: len(announcers(sniffer, domain_id)) >= 2, timeout=30,
                       what="the first announcements of both tools")
            launcher = apps.start_command("launch", on_defaults(lan.host, *launch_command(domain_id, tmp_path)))
            assert_reads_every_flow_and_every_application_finds_it(plain, timeout=TOOL_FIRST_TIMEOUT_S)
            plain.stop()  # done with: the camera's frames would cost it and the camera CPU for the rest of the scan
            # Its scan found the writer and its type (else it says so and ends), then its subscriber printed samples.
            subscribe.wait_for(r"^PlatformStatus\($", timeout=SUBSCRIBE_SCAN_S + 30)
            subscribe.wait_for(r"^\s+vehSpd=-?[\d.]+,$", timeout=10)
            assert "Traceback" not in launcher.output
        finally:
            apps.stop_all()  # the cyclonedds subscribe keeps printing until killed


# -- the system first, the tools after it (one system for these tests) ------------------------------------------------

@pytest.fixture(scope="module")
def system(module_domain_id: int, tmp_path_factory: pytest.TempPathFactory) -> Iterator[System]:
    """The system, started alone in its host and left running for the module's tests that join it later."""
    needs_namespaces()
    runner = AppRunner(ROOT)
    with LanHost("hd") as lan:
        try:
            sniffer = runner.start_command("sniffer", lan.sniffer_command())
            sniffer.wait_for(READY)
            launcher = runner.start_command("launch", on_defaults(lan.host, *launch_command(
                module_domain_id, tmp_path_factory.mktemp("system"))))
            # A while alone: until every application is at work (its first status line), and one status round more.
            for app in APPS:
                launcher.wait_for(status_line(app), timeout=60)
            for app in APPS:
                launcher.wait_for(status_line(app), count=2, timeout=2 * STATUS_INTERVAL_S + 10)
            yield System(lan, runner, sniffer, launcher, module_domain_id, frames(sniffer))
        finally:
            runner.stop_all()


def test_no_frame_leaves_the_host_while_the_system_runs_alone(system: System) -> None:
    assert system.alone == [], "frames left the host:\n" + "\n".join(system.alone[:20])


def test_cyclonedds_ps_started_after_the_system_lists_every_application(system: System) -> None:
    assert run_ps(system.lan.host, system.domain) >= set(APPS)


def test_plain_participant_joining_the_system_reads_every_flow_and_every_application_finds_it(
        system: System) -> None:
    plain = system.start("plain", system.lan.host, *participant_command(system.domain, "plain", *every_flow()))
    try:
        plain.wait_for(r"^ready$", timeout=PARTICIPANT_START_TIMEOUT_S)
        assert_reads_every_flow_and_every_application_finds_it(plain, timeout=20)
    finally:
        plain.stop()


def test_ros2_reader_on_defaults_gets_lidar_clouds_that_rosbags_decodes(system: System, tmp_path: Path) -> None:
    from rosbags.typesys import Stores, get_typestore

    reader = system.start("ros2-lidar", system.lan.host, sys.executable, str(SCRIPT), "ros2-lidar", "--domain",
                          str(system.domain), "--save", str(tmp_path), "--count", "2")
    try:
        reader.wait_for(r"^saved 2 clouds from lidar$", timeout=PARTICIPANT_START_TIMEOUT_S)  # its start included
    finally:
        reader.stop()
    store = get_typestore(Stores.ROS2_HUMBLE)
    clouds: list[Any] = [store.deserialize_cdr(path.read_bytes(), "sensor_msgs/msg/PointCloud2")
              for path in sorted(tmp_path.glob("cloud-*.cdr"))]
    assert len(clouds) == 2
    for cloud in clouds:
        assert cloud.header.frame_id == "map"
        assert (cloud.height, cloud.width, cloud.point_step, cloud.row_step, cloud.is_bigendian, cloud.is_dense) == \
            (64, 180, 16, 180 * 16, False, True)
        assert [(field.name, field.offset, field.datatype, field.count) for field in cloud.fields] == \
            [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("rgb", 12, 7, 1)]
        assert len(cloud.data) == cloud.row_step * cloud.height


def test_another_hosts_participant_never_matches_an_application(system: System) -> None:
    """A participant on Cyclone's defaults on another host (the LAN namespace) reads PlatformStatus and writes circles
    on Circle (the LiDAR's input), while a default tool on the host has joined the discovery multicast group on eth0,
    so that the kernel hands the other host's announcements to every socket of the host on the discovery port, the
    applications' too. The tool hears the other host and the applications; the applications drop what the other
    host sends (their sockets' filter keeps datagrams made on this host only), so they never answer it."""
    frames_before = len(frames(system.sniffer))
    lines_before = len(system.launcher.lines)
    incoming = system.runner.start_command("incoming", system.lan.incoming_sniffer_command())
    incoming.wait_for(READY)
    tool = system.start("host_tool", system.lan.host, *participant_command(
        system.domain, "host_tool", "--read", "PlatformStatus", "--read", "Circle"))
    other: CommandProcess | None = None
    try:
        # The 20 s bounds below are discovery's, counted once a participant is up: its start is the machine's.
        tool.wait_for(r"^ready$", timeout=PARTICIPANT_START_TIMEOUT_S)
        tool.wait_for(r"^sample PlatformStatus from vehicle_platform$", timeout=20)
        other = system.start("other_host", system.lan.lan, *participant_command(
            system.domain, "other_host", "--read", "PlatformStatus", "--write", "Circle", "--circles"))
        other.wait_for(r"^ready$", timeout=PARTICIPANT_START_TIMEOUT_S)
        # The other host's announcement reached the tool, and its circles did.
        tool.wait_for(r"^participant other_host$", timeout=20)
        tool.wait_for(r"^sample Circle from other_host$", timeout=20)
        other.wait_for(r"^participant host_tool$", timeout=20)
        # The applications answer an announcement they hear at once. The window: until the host has received two of
        # the other host's announcements (its first and its next periodic one, 8 s later), and the LiDAR has printed
        # a status line after that (its circle rate over the last 5 s).
        other_announcements = rf"^ip {re.escape(LAN_ADDRESS)}:\d+ > 239\.255\.0\.1:{domain_base(system.domain)} udp"
        incoming.wait_for(other_announcements, count=2, timeout=2 * DEFAULT_ANNOUNCE_INTERVAL_S + 10)
        announced = incoming.count(other_announcements)
        sockets = udp_sockets(system.lan.host)
        system.launcher.wait_for_more(status_line("lidar"), timeout=STATUS_INTERVAL_S + 10)
    finally:
        for process in (tool, other, incoming):
            if process is not None:
                process.stop()

    # The other host saw the tool only, and matched nothing of the applications.
    assert other is not None
    assert [line for line in other.lines if re.search(rf"\b({'|'.join(APPS)})\b", line)] == [], other.output
    # The applications' discovery sockets were handed every announcement of the other host, and dropped each.
    app_pids = set(system.pids().values())
    assert len(app_pids) == len(APPS)
    discovery = [socket for socket in sockets if socket.port == domain_base(system.domain) and socket.pids & app_pids]
    assert len(discovery) == len(APPS), sockets
    assert all(socket.dropped >= announced for socket in discovery), (announced, discovery)
    # The LiDAR took no circle.
    lidar = [line for line in system.launcher.lines[lines_before:] if re.match(status_line("lidar"), line)]
    assert lidar and all(" in Circle 0/s;" in line for line in lidar), lidar
    # No frame left the host from a socket of an application. Which frames are the system's: every participant of
    # the domain binds the domain's two multicast ports (the tool too: those say nothing of the sender), but Cyclone
    # sends from its transmit sockets only, one per participant and interface, bound to the interface's address on a
    # port of its own (ss lists them: 10.232.0.1:<port> of each application). An application that answered the other
    # host, or sent anything on eth0, would send from such a port of its own. So: no frame's source is a port only an
    # application holds; and the tool's frames, which it sends to the other host, were seen (the sniffer watches the
    # right link). The rest are the kernel's, for the tool: IGMP reports of its group membership and ARP for its
    # unicast to the other host (while the system ran alone, no frame at all: the test above).
    shared = {socket.port for socket in sockets if socket.pids - app_pids}
    app_ports = {socket.port for socket in sockets if socket.pids & app_pids} - shared
    tool_ports = {socket.port for socket in sockets if tool.pid in socket.pids}
    seen = frames(system.sniffer)[frames_before:]
    sources = {line: (match.group(1), int(match.group(2))) for line in seen
               if (match := re.match(r"ip (\S+):(\d+) > ", line))}
    assert [line for line, (_, port) in sources.items() if port in app_ports] == [], seen
    assert {address for address, _ in sources.values()} == {HOST_ADDRESS}, seen
    assert any(port in tool_ports for _, port in sources.values()), seen


def test_cyclonedds_ps_joining_long_after_the_start_lists_every_application(system: System) -> None:
    for app in APPS:  # the system has run for LATE_S: LATE_S / 5 status lines of each application
        system.launcher.wait_for(status_line(app), count=LATE_S // STATUS_INTERVAL_S, timeout=LATE_S + 30)
    assert run_ps(system.lan.host, system.domain) >= set(APPS)



def test_an_application_whose_discovery_multicast_port_is_taken_runs_on_loopback_and_says_so(
        apps: AppRunner, domain_id: int) -> None:
    """Unlike the index ports, the domain's discovery multicast port is fixed: another program may hold it (an
    ephemeral port, for domains from 102 up). The application then runs on 127.0.0.1 only, with one line saying that
    Cyclone's default tools will not see it, and no line of Cyclone's own."""
    needs_namespaces()
    port = domain_base(domain_id)
    holder = ("import socket, sys; s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); "
              f"s.bind(('0.0.0.0', {port})); print('holding', flush=True); sys.stdin.read()")
    with LanHost("hd") as lan:
        held = apps.start_command("holder", lan.host.exec(sys.executable, "-c", holder), stdin=True)
        held.wait_for(r"^holding$")
        vision = apps.start_command("vision", on_defaults(lan.host, *program_command(
            "vision", "--domain", str(domain_id), "--count", "3")))
        assert vision.wait_exit() == 0, vision.output
        warnings = [line for line in vision.lines if "WARNING" in line]
        assert len(warnings) == 1 and warnings[0].endswith(
            f"WARNING: network: Cyclone DDS tools on their defaults will not see this application: the domain's "
            f"discovery multicast port {port} is taken by another program; staying on 127.0.0.1 only"), vision.output
        assert not re.search(r"^\d+\.\d+ \[\d+\] ", vision.output, re.M), vision.output  # no Cyclone line
        held.stop()

# -- the plain participant (this module as a script) ------------------------------------------------------------------

def flow_type(topic: str) -> type[Any]:
    from automotive.types.Alerts import DriverAlerts
    from automotive.types.automotive import ShapeType
    from automotive.types.CameraImage import CameraImageData
    from automotive.types.Platform import PlatformControl, PlatformStatus
    from automotive.types.Sensor import SensorObjectList
    from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
    from automotive.types.Vision import VisionSensor

    types: dict[str, type[Any]] = {
        "VisionTopic": VisionSensor, "rt/LidarTopic": PointCloud2_, "SensorObjects": SensorObjectList,
        "PlatformStatus": PlatformStatus, "PlatformControl": PlatformControl, "AlertTopic": DriverAlerts,
        "CameraImageData": CameraImageData, "Circle": ShapeType}
    return types[topic]


class Names:
    """The names (EntityName) of the participants discovered so far, by participant key."""

    def __init__(self, participant: Any):
        from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsParticipant

        self.reader = BuiltinDataReader(participant, BuiltinTopicDcpsParticipant)
        self.names: dict[Any, str] = {}

    def update(self) -> None:
        """Take what discovery brought."""
        from cyclonedds.qos import Policy

        for sample in self.reader.take(N=256):
            if sample.sample_info.valid_data and sample.key not in self.names:
                self.names[sample.key] = (sample.qos[Policy.EntityName].name if Policy.EntityName in sample.qos
                                          else str(sample.key))

    def of(self, endpoint: Any) -> str | None:
        """The name of a matched endpoint's participant (None: no longer matched). A participant is discovered before
        its endpoints, so its name is known once they are."""
        if endpoint is None:
            return None
        if endpoint.participant_key not in self.names:
            self.update()
        return self.names.get(endpoint.participant_key, str(endpoint.participant_key))


def participate(args: argparse.Namespace) -> None:
    """A Cyclone participant on its defaults (no Domain configuration), named ``args.name``, with a reader of each
    ``--read`` topic and a writer of each ``--write`` topic (the flow's QoS profile). Prints, once each: ``ready``,
    ``participant NAME`` (discovered), ``writer TOPIC of NAME matched`` and ``sample TOPIC from NAME`` (a reader's),
    ``reader TOPIC of NAME matched`` (a writer's). Writes nothing, except circles with ``--circles``. Until SIGTERM."""
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from automotive import config
    from automotive.bus.qos import QosProfiles
    from automotive.cyclone.serdata import take
    from automotive.types.automotive import ShapeType

    stopping: list[int] = []
    signal.signal(signal.SIGTERM, lambda signum, frame: stopping.append(signum))
    profiles = QosProfiles(config.qos_file())
    participant = DomainParticipant(args.domain, qos=Qos(Policy.EntityName(args.name)))
    topics = {topic: Topic(participant, topic, flow_type(topic)) for topic in {*args.read, *args.write}}
    # Reliable where the flow is: a best-effort reader of the 4 MiB camera frames, on Cyclone's default socket buffers,
    # on a loaded host, lost a fragment of every frame for 20 s once. The reader takes the frames as they come (CDR
    # bytes, nothing decoded), so that the camera's flow control (8 frames unacknowledged at most) never waits on it.
    readers = {topic: DataReader(participant, topics[topic], qos=profiles.reader_qos(LIBRARY, PROFILES[topic]))
               for topic in args.read}
    writers = {topic: DataWriter(participant, topics[topic], qos=profiles.writer_qos(LIBRARY, PROFILES[topic]))
               for topic in args.write}
    names = Names(participant)
    said: set[str] = set()

    def say(line: str) -> None:
        if line not in said:
            said.add(line)
            print(line, flush=True)

    say("ready")
    circle = 0
    while not stopping:
        names.update()
        for name in list(names.names.values()):
            if name != args.name:
                say(f"participant {name}")
        for topic, reader in readers.items():
            for handle in matched_publications(reader):
                if (who := names.of(reader.get_matched_publication_data(handle))) is not None:
                    say(f"writer {topic} of {who} matched")
            for taken in take(reader, 64):  # CDR bytes: no time spent decoding 4 MiB camera frames
                if taken.info.valid_data and (who := names.of(
                        reader.get_matched_publication_data(taken.info.publication_handle))) is not None:
                    say(f"sample {topic} from {who}")
        for topic, writer in writers.items():
            for handle in matched_subscriptions(writer):
                if (who := names.of(writer.get_matched_subscription_data(handle))) is not None:
                    say(f"reader {topic} of {who} matched")
        if args.circles:
            circle += 1
            writers["Circle"].write(ShapeType(color="ORANGE", x=circle % 200, y=100, shapesize=30))
        time.sleep(0.05)  # a poll of discovery and samples, 20 times a second
    participant.__del__()  # announce the participant's end


def ros2_lidar(args: argparse.Namespace) -> None:
    """The LiDAR's cloud as RViz2 reads it (tests/test_lidar_ros2.py), on Cyclone's defaults: saves ``args.count``
    serialized samples as DIR/cloud-<n>.cdr and says from whom (``saved K clouds from NAME``)."""
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from test_lidar_ros2 import RVIZ2_READER

    from automotive.cyclone.serdata import take
    from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_

    participant = DomainParticipant(args.domain, qos=Qos(Policy.EntityName("ros2_lidar")))
    reader = DataReader(participant, Topic(participant, "rt/LidarTopic", PointCloud2_), qos=RVIZ2_READER)
    names = Names(participant)
    saved: list[str] = []
    while len(saved) < args.count:
        for taken in take(reader, args.count - len(saved)):
            if taken.info.valid_data:
                (args.save / f"cloud-{len(saved)}.cdr").write_bytes(bytes(taken.data))
                saved.append(names.of(reader.get_matched_publication_data(taken.info.publication_handle)) or "?")
        time.sleep(0.05)  # a poll, 20 times a second
    print(f"saved {len(saved)} clouds from {', '.join(sorted(set(saved)))}", flush=True)
    participant.__del__()


def main() -> None:
    parser = argparse.ArgumentParser(description="A Cyclone DDS participant on its defaults (tests of discovery).")
    commands = parser.add_subparsers(dest="command", required=True)
    plain = commands.add_parser("participant")
    plain.add_argument("--domain", type=int, required=True)
    plain.add_argument("--name", required=True)
    plain.add_argument("--read", action="append", default=[], choices=PROFILES)
    plain.add_argument("--write", action="append", default=[], choices=PROFILES)
    plain.add_argument("--circles", action="store_true", help="write a circle on Circle 20 times a second")
    lidar = commands.add_parser("ros2-lidar")
    lidar.add_argument("--domain", type=int, required=True)
    lidar.add_argument("--save", type=Path, required=True)
    lidar.add_argument("--count", type=int, default=2)
    args = parser.parse_args()
    if args.command == "participant":
        if args.circles and "Circle" not in args.write:
            parser.error("--circles needs --write Circle")
        participate(args)
    else:
        ros2_lidar(args)


if __name__ == "__main__":
    main()
