"""Configuration edges of the runtime: which domain ids and participant indexes have ports, a user's CYCLONEDDS_URI
layered over the applications' configuration, and property keys refused before a program starts (the applications'
and those of the tools on the same runtime)."""

from __future__ import annotations

import re
import select
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from apprunner import command_of
from mcap.writer import Writer
from test_bad_input import assert_one_line_error

from automotive import config
from automotive.apps import (
    camera_pub,
    camera_sub,
    collision_avoidance,
    hmi,
    lidar,
    sensor_fusion,
    vehicle_platform,
    vision,
)
from automotive.bus import ports
from automotive.bus.app import RUNTIME_KEYS
from automotive.bus.errors import ConfigError
from automotive.bus.network import NETWORK_ELEMENTS, NetworkConfig, read_user_config
from automotive.bus.properties import Properties, PropertyKeys
from automotive.tools.flows import system_flows
from automotive.tools.foxglove_bridge import bridge
from automotive.tools.lidar_view import lidar_view
from automotive.tools.record import record, replay
from automotive.tools.shapes import shapes
from automotive.tools.support.children import StatsChild, program_command
from automotive.tools.zenoh import zenoh_bridge

TIMEOUT = 60.0
# The tests' own CYCLONEDDS_URI (conftest): the loopback configuration.
TESTS_URI = NetworkConfig().cyclone_xml()
LOOPBACK_AND_PEER = ('<General><Interfaces><NetworkInterface name="lo"/></Interfaces></General>'
                     '<Discovery><Peers><Peer address="127.0.0.1"/></Peers></Discovery>')
APPLICATIONS = {"vision": vision, "lidar": lidar, "sensor_fusion": sensor_fusion,
                "vehicle_platform": vehicle_platform, "collision_avoidance": collision_avoidance, "hmi": hmi,
                "camera_pub": camera_pub, "camera_sub": camera_sub}
# The tools on the applications' runtime (automotive.bus.app.run), which declare their keys the same way.
TOOLS = {"record": record, "replay": replay, "bridge": bridge, "zenoh_bridge": zenoh_bridge, "lidar_view": lidar_view,
         "shapes": shapes}
# Per tool, a close misspelling of one of its keys, and that key.
TOOL_TYPOS = {"record": ("config.chunksize", "config.chunkSize"), "replay": ("qos.Libary", "qos.Library"),
              "bridge": ("config.backlg", "config.backlog"), "zenoh_bridge": ("zenoh.sit", "zenoh.site"),
              "lidar_view": ("config.imageWidht", "config.imageWidth"), "shapes": ("topic.Shape", "topic.Shapes")}


def tracing(path: Path) -> str:
    """A fragment that makes Cyclone write the configuration it uses (each setting with the fragment it came from:
    ``Domain/General/FragmentSize/#text: 62000 B {0}``)."""
    return f"<Tracing><Verbosity>config</Verbosity><OutputFile>{path}</OutputFile></Tracing>"


def effective(trace: Path, setting: str) -> list[str]:
    """The values (with their fragment numbers) Cyclone's trace gives a setting, such as General/FragmentSize."""
    return re.findall(rf"config: Domain/{re.escape(setting)}: (.*)$", trace.read_text(), re.M)


# -- domain ids and participant indexes ---------------------------------------------------------------------------

def test_every_port_of_every_index_stays_inside_its_domain() -> None:
    assert (ports.MAX_PARTICIPANT_INDEX, ports.MAX_PARTICIPANTS, ports.MAX_DOMAIN_ID) == (119, 119, 231)
    for domain in (0, 1, 100, 230):
        assert ports.highest_port(domain) < ports.domain_base(domain + 1)
        # index 120 would be the next domain's discovery multicast port: the one the old default reached
        assert ports.discovery_unicast_port(domain, ports.MAX_PARTICIPANT_INDEX + 1) == ports.domain_base(domain + 1)
    assert ports.highest_port(231) <= 65535 < ports.highest_port(232)
    assert "<MaxAutoParticipantIndex>119</MaxAutoParticipantIndex>" in NetworkConfig().cyclone_xml()
    # Cyclone takes indexes 0..MaxAutoParticipantIndex - 1: 30 participants need 30 (and probe index 30 too)
    assert "<MaxAutoParticipantIndex>30</MaxAutoParticipantIndex>" in NetworkConfig(max_participants=30).cyclone_xml()


@pytest.mark.parametrize("count", [0, 120, 500])
def test_more_participant_indexes_than_a_domain_has_are_refused(count: int) -> None:
    with pytest.raises(ConfigError, match=rf"^app.properties: config.maxParticipants = {count} is out of range "
                                          r"\(expected 1..119\)$"):
        NetworkConfig.from_settings(max_participants=count, source="app.properties")
    with pytest.raises(ConfigError, match=r"expected 1..119"):
        NetworkConfig(max_participants=count)  # made in code (the benchmarks): refused too


def test_the_highest_domain_probes_its_last_index_and_nothing_beyond(tmp_path: Path) -> None:
    """Cyclone itself, on domain 231 with the applications' loopback configuration: its probes reach index 119's
    port (65398), the highest that fits, and never index 120's (65400: domain 232's first port)."""
    domain = ports.MAX_DOMAIN_ID
    last, beyond = (socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(2))
    try:
        last.bind(("127.0.0.1", ports.discovery_unicast_port(domain, ports.MAX_PARTICIPANT_INDEX)))
        beyond.bind(("127.0.0.1", ports.discovery_unicast_port(domain, ports.MAX_PARTICIPANT_INDEX + 1)))
        participant = subprocess.Popen(
            [sys.executable, "-c", "import sys; from cyclonedds.domain import Domain, DomainParticipant; "
             f"d = Domain({domain}, sys.argv[1]); p = DomainParticipant({domain}); sys.stdin.read()",
             NetworkConfig().cyclone_xml()],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            # Two probe rounds (every LOOPBACK_ANNOUNCE_INTERVAL): the whole range was probed at least once between.
            for _ in range(2):
                ready, _, _ = select.select([last], [], [], 20.0)
                assert ready, "no participant announcement reached index 119's port"
                last.recv(65536)
            ready, _, _ = select.select([beyond], [], [], 0)
            assert not ready, "a participant announcement reached domain 232's first port"
        finally:
            _, errors = participant.communicate("", timeout=30)
        assert participant.returncode == 0 and "failed" not in errors, errors
    finally:
        last.close()
        beyond.close()


def test_every_way_of_giving_a_domain_refuses_232_with_the_same_words(apps) -> None:  # type: ignore[no-untyped-def]
    expected = "expected a domain id 0..231, not '232'"
    for program, args, prefix in [
        ("vision", ["--domain", "232"], "automotive-vision: argument --domain: "),
        ("vision", ["-D", "config.domainId=232"], "automotive-vision: -D: config.domainId: "),
        ("launch", ["-D", "config.domainId=232", "vision"], r"automotive launch: -D config.domainId=232: "),
        ("launch", ["-D", "vision:config.domainId=232", "vision"],
         r"automotive launch: -D vision:config.domainId=232: "),
    ]:
        result = apps.run(program, *args, timeout=TIMEOUT)
        assert_one_line_error(result, "^" + re.escape(prefix + expected))


def test_the_participant_limit_is_one_line_naming_the_key(apps) -> None:  # type: ignore[no-untyped-def]
    result = apps.run("vision", "-D", "config.maxParticipants=120", timeout=TIMEOUT)
    assert_one_line_error(result, r"^automotive-vision: -D: config.maxParticipants = 120 is out of range "
                                  r"\(expected 1..119\)$")


# -- a user's CYCLONEDDS_URI ------------------------------------------------------------------------------------

def test_a_user_uri_is_read_as_cyclone_reads_it(tmp_path: Path) -> None:
    file = tmp_path / "cyclone.xml"
    file.write_text('<?xml version="1.0"?>\n<!-- mine -->\n<CycloneDDS xmlns="https://cdds.io/config">'
                    '<Domain id="7"><General><Interfaces><NetworkInterface name="eth9"/></Interfaces></General>'
                    '</Domain><Domain id="any"><Sizing><ReceiveBufferSize>1MiB</ReceiveBufferSize></Sizing></Domain>'
                    "</CycloneDDS>")
    # XML without CycloneDDS and Domain, abbreviated names in any case, </> and elements left open at the end (so
    # that the rest of the string is inside them: last)
    inline = "<general><Interf><NetworkInterface name='lo'/></></> <Discovery><Peers><Peer address='127.0.0.1'/>"
    settings = read_user_config(f" file://{file},{file}, {inline}", 5).settings()
    assert sorted(settings) == ["Discovery/Peers", "General/Interfaces", "Sizing/ReceiveBufferSize"]
    assert len(settings["Sizing/ReceiveBufferSize"]) == 2  # the file, twice; its domain 7 is not ours
    assert "General/Interfaces" in read_user_config(str(file), 7).settings()
    moved = read_user_config("<Internal><FragmentSize>1000B</FragmentSize></Internal>", 0).settings()
    assert list(moved) == ["General/FragmentSize"]  # Cyclone's older place of the same setting


@pytest.mark.parametrize(("uri", "message"), [
    ("/nonexistent/cyclone.xml", r"^CYCLONEDDS_URI: file '/nonexistent/cyclone.xml' not found \(expected files, "
                                 r"file:// URIs or XML, separated by commas\)$"),
    ("<General><Interfaces></General>", r"^CYCLONEDDS_URI: the XML at character 1 is not well-formed XML "
                                        r"\('</General>' closes 'Interfaces'\)$"),
    ("<Tracing/>,<General attr=unquoted/>", r"^CYCLONEDDS_URI: the XML at character 12 is not well-formed XML"),
    ("<General>a & b</General>", r"^CYCLONEDDS_URI: the XML at character 1 is not well-formed XML \(not "
                                 r"well-formed \(invalid token\): line 1, column 12\)$"),
])
def test_an_unreadable_user_uri_is_named(uri: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        read_user_config(uri, 0)


def test_the_tests_uri_overrides_nothing_and_keeps_the_large_data_settings() -> None:
    layering = NetworkConfig(large_data=True).layered(read_user_config(TESTS_URI, 0))
    assert layering.notice is None
    xml = layering.network.cyclone_xml()
    ours, theirs = xml.split(",", 1)
    assert theirs == TESTS_URI
    assert "<FragmentSize>62000B</FragmentSize>" in ours and '<SocketReceiveBufferSize min="default"' in ours
    assert "<Interfaces>" not in ours and "<Peers>" not in ours  # the URI's, identical: not twice (lists add up)
    assert layering.network.describe() == "single host (loopback), with your CYCLONEDDS_URI"


def test_a_uri_choosing_the_network_keeps_the_tuning_and_is_named() -> None:
    layering = NetworkConfig(large_data=True).layered(
        read_user_config(LOOPBACK_AND_PEER + "<Internal><SocketReceiveBufferSize max='8MiB'/></Internal>", 0))
    assert layering.notice == (
        "network: your CYCLONEDDS_URI sets General/Interfaces, Discovery/Peers, which replace the applications' "
        "network (single host (loopback)); Internal/SocketReceiveBufferSize, which replaces the applications' "
        "setting (min=default max=4MiB)")
    ours = layering.network.cyclone_xml().split(",", 1)[0]
    assert not any(f"<{path.split('/')[1]}>" in ours for path in NETWORK_ELEMENTS)  # all of it is the URI's
    assert "<FragmentSize>62000B</FragmentSize>" in ours and "<SocketReceiveBufferSize" not in ours
    assert layering.network.describe() == "as your CYCLONEDDS_URI chooses"


def test_the_receive_thread_priority_is_cyclones_thread_setting_and_a_uri_setting_threads_replaces_it() -> None:
    # automotive.bus.realtime: Cyclone's receive thread at SCHED_FIFO N, through Cyclone's own configuration.
    assert "<Threads>" not in NetworkConfig().cyclone_xml()
    ours = NetworkConfig(receive_thread_priority=7).cyclone_xml()
    assert ('<Threads><Thread name="recv"><Scheduling><Class>realtime</Class><Priority>7</Priority></Scheduling>'
            "</Thread></Threads>") in ours
    user = '<Threads><Thread name="recv"><Scheduling><Class>timeshare</Class></Scheduling></Thread></Threads>'
    layering = NetworkConfig(receive_thread_priority=7).layered(read_user_config(user, 0))
    assert layering.notice is not None and "Threads/Thread, which replaces the applications' setting" in \
        layering.notice
    ours, theirs = layering.network.cyclone_xml().split(",", 1)
    assert "<Threads>" not in ours and "timeshare" in theirs


def test_an_explicit_network_choice_takes_the_network_out_of_the_uri() -> None:
    uri = LOOPBACK_AND_PEER + "<General><AllowMulticast>false</AllowMulticast></General>" + tracing(Path("/t.log"))
    layering = NetworkConfig.from_settings(interface="lo").layered(read_user_config(uri, 0),
                                                                   "config.interface (--interface)")
    assert layering.notice == ("network: config.interface (--interface) replaces the network your CYCLONEDDS_URI "
                               "sets (General/AllowMulticast, Discovery/Peers)")  # the same interface is no change
    ours, theirs = layering.network.cyclone_xml().split(",", 1)
    assert "<AllowMulticast>true</AllowMulticast>" in ours and '<NetworkInterface name="lo"/>' in ours
    assert "Peer" not in theirs and "AllowMulticast" not in theirs and "Interfaces" not in theirs
    assert "<Tracing><Verbosity>config</Verbosity>" in theirs


def test_a_camera_pair_under_a_uri_picking_lo_and_a_peer_keeps_its_large_fragments(  # type: ignore[no-untyped-def]
        apps, domain_id: int, tmp_path: Path) -> None:
    trace = tmp_path / "cyclone.log"
    frames = 3
    sub = apps.start("camera_sub", "--domain", str(domain_id), "--count", str(frames),
                     env={"CYCLONEDDS_URI": LOOPBACK_AND_PEER})
    sub.wait_for("viewing CameraImageData frames", timeout=TIMEOUT)
    pub = apps.start("camera_pub", "--domain", str(domain_id), "--count", str(frames), "-D", "config.pubInterval=50",
                     env={"CYCLONEDDS_URI": f"{LOOPBACK_AND_PEER},{tracing(trace)}"})
    assert pub.wait_exit(timeout=TIMEOUT) == 0, pub.output
    assert sub.wait_exit(timeout=TIMEOUT) == 0, sub.output
    assert re.search(r"samples=3 size=4196352 .* mismatches=0 .*gaps=0", sub.output), sub.output
    for process in (pub, sub):
        assert process.count(r"WARNING: network: your CYCLONEDDS_URI sets General/Interfaces, Discovery/Peers, "
                             r"which replace the applications' network \(single host \(loopback\)\)$") == 1, \
            process.output
    # What Cyclone used: the camera's fragments and socket buffers (fragment 0: ours), the URI's interface and peer
    assert effective(trace, "General/FragmentSize/#text") == ["62000 B {0}"]
    assert effective(trace, "Internal/SocketReceiveBufferSize[@max]") == ["4 MiB {0}"]
    assert effective(trace, "General/Interfaces/NetworkInterface[@name]") == ["lo {1}"]
    assert effective(trace, "Discovery/Peers/Peer[@Address]") == ["127.0.0.1 {2}"]


def test_the_tests_uri_prints_no_override(apps, domain_id: int, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    trace = tmp_path / "cyclone.log"
    result = apps.run("camera_pub", "--domain", str(domain_id), "--count", "1", "-D", "config.waitSubscribers=0",
                      env={"CYCLONEDDS_URI": f"{TESTS_URI},{tracing(trace)}"}, timeout=TIMEOUT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "CYCLONEDDS_URI sets" not in result.stdout and "replaces" not in result.stdout, result.stdout
    assert "network: single host (loopback), with your CYCLONEDDS_URI" in result.stdout
    assert effective(trace, "General/FragmentSize/#text") == ["62000 B {0}"]
    # each once (lists add up): lo, and the host's LAN interface where it has one (for Cyclone's default tools; on a
    # host with only the loopback, that is lo itself)
    host = NetworkConfig().lan_interface()
    assert effective(trace, "General/Interfaces/NetworkInterface[@name]") == ["lo {1}"] + (
        [f"{host} {{1}}"] if host and host != "lo" else [])


def test_an_explicit_interface_wins_over_the_uris_network(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                          tmp_path: Path) -> None:
    trace = tmp_path / "cyclone.log"
    uri = f"{LOOPBACK_AND_PEER},<General><AllowMulticast>false</AllowMulticast></General>,{tracing(trace)}"
    result = apps.run("vision", "--domain", str(domain_id), "--count", "1", "--interface", "lo",
                      env={"CYCLONEDDS_URI": uri}, timeout=TIMEOUT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert re.search(r"WARNING: network: config.interface \(--interface\) replaces the network your CYCLONEDDS_URI "
                     r"sets \(General/AllowMulticast, Discovery/Peers\)$", result.stdout, re.M), result.stdout
    assert effective(trace, "General/AllowMulticast/#text") == ["true {0}"]
    assert effective(trace, "Discovery/Peers/Peer[@Address]") == []


def test_a_broken_uri_is_one_line_and_exit_2(apps, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    result = apps.run("vision", "--count", "1", env={"CYCLONEDDS_URI": f"{tmp_path}/missing.xml"}, timeout=TIMEOUT)
    assert_one_line_error(result, rf"^automotive-vision: CYCLONEDDS_URI: file '{tmp_path}/missing.xml' not found")
    result = apps.run("vision", "--count", "1", env={"CYCLONEDDS_URI": "<General><Interfaces>\n</General>"},
                      timeout=TIMEOUT)
    assert_one_line_error(result, r"^automotive-vision: CYCLONEDDS_URI: the XML at character 1 is not well-formed")


# -- property keys: known up front -------------------------------------------------------------------------------

def test_an_unknown_key_is_refused_before_anything_starts(apps) -> None:  # type: ignore[no-untyped-def]
    result = apps.run("vision", "-D", "config.nope=1", timeout=TIMEOUT)
    assert_one_line_error(result, r"^automotive-vision: .*vision.properties: unknown key\(s\) for vision: "
                                  r"'config.nope' \(-D\)$")
    # Nothing said, so nothing made: the network line comes before the participant, "publishing" after the writer.
    assert result.stdout == "", result.stdout


def test_an_unknown_key_names_the_nearest_and_its_file(apps, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    properties = tmp_path / "vision.properties"
    shipped = config.properties_file("vision")
    properties.write_text(shipped.read_text().replace("qos.File=../qos/", f"qos.File={shipped.parent.parent}/qos/")
                          .replace("dataFile=data/", f"dataFile={shipped.parent}/data/")
                          + "\nconfig.sensorID=2\n")
    result = apps.run("vision", "--properties", str(properties), "-D", "topic.Vison=X", timeout=TIMEOUT)
    assert_one_line_error(result, r"unknown key\(s\) for vision: 'config.sensorID' \(.*vision.properties; did you "
                                  r"mean 'config.sensorId'\?\), 'topic.Vison' \(-D; did you mean 'topic.Vision'\?\)$")
    assert result.stdout == ""


@pytest.mark.parametrize("name", sorted(TOOLS))
def test_every_tool_refuses_an_unknown_key_before_anything_starts(apps, name: str,  # type: ignore[no-untyped-def]
                                                                  tmp_path: Path) -> None:
    typo, key = TOOL_TYPOS[name]
    needed = {"record": ["-o", str(tmp_path / "out.mcap")], "replay": [str(tmp_path / "in.mcap")],
              "shapes": ["subscribe"]}.get(name, [])  # what the command line needs before the properties count
    result = apps.run(name, *needed, "-D", "config.nope=1", "-D", f"{typo}=1", timeout=TIMEOUT)
    assert_one_line_error(result, rf"^{re.escape(command_of(name))}: .*{name}.properties: unknown key\(s\) for "
                                  rf"{name}: 'config.nope' \(-D\), '{re.escape(typo)}' \(-D; did you mean "
                                  rf"'{re.escape(key)}'\?\)$")
    assert result.stdout == "", result.stdout  # nothing said, so nothing made (no participant, no file)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", sorted(APPLICATIONS) + sorted(TOOLS))
def test_every_key_a_shipped_file_mentions_is_declared(name: str) -> None:
    """The shipped properties of each program, including the commented examples (#   config.peers=...)."""
    declared = RUNTIME_KEYS | {**APPLICATIONS, **TOOLS}[name].PROPERTY_KEYS
    path = config.properties_file(name)
    examples = re.findall(r"^#\s+([A-Za-z][\w.]*)=", path.read_text(), re.M)
    mentioned = Properties.load(path).keys() + examples
    assert examples and "config.domainId" in mentioned
    assert [key for key in mentioned if not declared.covers(key)] == []


def test_every_application_reads_only_declared_keys(domain_id: int, tmp_path: Path) -> None:
    """Each application runs until ready(), whose safety net ends it (exit 2) at a key read but not declared."""
    # (the camera publishes once a second: it has a subscriber here)
    extra = {"hmi": ["--ui", "console"], "camera_pub": ["-D", "config.pubInterval=1000"]}
    run_each_until_ready({name: extra.get(name, []) for name in APPLICATIONS}, domain_id, tmp_path)


def run_each_until_ready(programs: dict[str, list[str]], domain_id: int, tmp_path: Path) -> None:
    """Each program with its arguments until ready(), whose safety net would end it (exit 2) at a key read but not
    declared; then stopped: each ends with 0."""
    running = [StatsChild.start(name, name, [*args, "--domain", str(domain_id), "-D", "config.matchReport=0"],
                                tmp_path / f"{name}.jsonl") for name, args in programs.items()]
    try:
        for child in running:
            child.wait_record("ready", timeout=TIMEOUT)
    finally:
        codes = {child.name: child.stop() for child in running}
    assert codes == dict.fromkeys(programs, 0), [child.child.output for child in running]
    assert not any("does not declare" in child.child.output for child in running)


def empty_recording(path: Path) -> Path:
    """An MCAP file with one channel of the system (the alerts) and no message: enough for the replayer to start."""
    flow = next(flow for flow in system_flows() if flow.topic == "AlertTopic")
    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start(profile="ros2", library="test")
        schema = writer.register_schema(flow.schema.name, flow.schema.encoding, flow.schema.data)
        writer.register_channel(flow.topic, "cdr", schema)
        writer.finish()
    return path


def test_every_tool_reads_only_declared_keys(domain_id: int, tmp_path: Path) -> None:
    """Each tool runs with its shipped properties until ready(), whose safety net ends it (exit 2) at a key read but
    not declared; what a tool needs to get there is given on its command line (zenoh_bridge: certificates, and a link
    to a port nothing listens on, which it keeps trying)."""
    certificates = tmp_path / "certs"
    made = subprocess.run(program_command("zenoh_certs", str(certificates), "site-a=127.0.0.1"), capture_output=True,
                          text=True, timeout=TIMEOUT)
    assert made.returncode == 0, made.stderr
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    needed = {
        "record": ["-o", str(tmp_path / "out.mcap")],
        "replay": [str(empty_recording(tmp_path / "in.mcap"))],  # ready, then done at once: nothing to replay
        "bridge": ["--port", "0"],
        "zenoh_bridge": ["-D", "zenoh.mode=peer", "-D", "zenoh.listen=", "-D", f"zenoh.connect=tls/127.0.0.1:{port}",
                         "-D", f"zenoh.tls.ca={certificates}/ca.pem",
                         "-D", f"zenoh.tls.certificate={certificates}/site-a.pem",
                         "-D", f"zenoh.tls.key={certificates}/site-a.key"],
        "lidar_view": ["--ui", "none"],
        "shapes": ["subscribe"],
    }
    run_each_until_ready({name: needed[name] for name in TOOLS}, domain_id, tmp_path)


SAFETY_NET = """
import sys
from automotive.bus.app import run
from automotive.bus.properties import Properties, PropertyKeys
sys.exit(run("probe", "", lambda app: (app.props.get_str("config.extra", ""), app.ready()), sys.argv[1:],
             keys=PropertyKeys.of()))
"""


def test_a_key_read_but_not_declared_ends_the_program_at_ready(domain_id: int, tmp_path: Path) -> None:
    properties = tmp_path / "probe.properties"
    properties.write_text(f"qos.File={config.qos_file()}\n")
    result = subprocess.run([sys.executable, "-c", SAFETY_NET, "--properties", str(properties), "--domain",
                             str(domain_id)], capture_output=True, text=True, timeout=TIMEOUT)
    assert_one_line_error(result, r"^automotive-probe: probe reads property key\(s\) it does not declare: "
                                  r"config.extra \(a defect of the program")


def test_keys_are_declared_once_per_role() -> None:
    keys = PropertyKeys.of(roles=["Vision"])
    assert keys.exact == {"topic.Vision", "qos.Vision.Profile"}
    assert (RUNTIME_KEYS | keys).covers("config.filter.VisionTopic")
    assert not (RUNTIME_KEYS | keys).covers("config.nope")


@pytest.mark.parametrize(("uri", "said"), [
    ("<CycloneDDS><Domain><General><Interfacez/></General></Domain></CycloneDDS>",
     "CYCLONEDDS_URI: General/Interfacez: unknown element"),
    ("<General><MaxMessageSize>abc</MaxMessageSize></General>", "CYCLONEDDS_URI: General/MaxMessageSize: abc: invalid "
                                                                 "value"),
])
def test_a_uri_cyclone_refuses_is_one_line_naming_the_users_element(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                                     uri: str, said: str) -> None:
    """Issue 38: Cyclone's own complaint (with an offset into the merged XML) and the program's line were three
    lines; now one, in the user's words."""
    result = apps.run("vision", "--domain", str(domain_id), "--count", "1", env={"CYCLONEDDS_URI": uri},
                      timeout=TIMEOUT)
    assert result.returncode == 2, result.stdout + result.stderr
    assert result.stderr == f"automotive-vision: {said}\n", result.stderr
    assert "network:" not in result.stdout and "+" not in result.stderr, result.stdout
