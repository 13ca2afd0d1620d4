"""Foxglove reads every channel, checked with Foxglove's own code: the running system recorded by
automotive.tools.record.record and watched live through automotive.tools.foxglove_bridge.bridge, every channel's schema
parsed and every message decoded by the npm libraries the Foxglove app uses (tests/foxglove/decode.js: @mcap/core with
CRCs checked, @foxglove/omgidl-parser + @foxglove/omgidl-serialization, @foxglove/rosmsg +
@foxglove/rosmsg2-serialization, @foxglove/ws-protocol's client with its default subprotocol), and each decoded message
equal, member by member, to what our own types decode from
the same bytes and to the system's known inputs. The bridge accepts both subprotocol names."""

from __future__ import annotations

import base64
import hashlib
import json
import math
import re
import signal
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
from cyclonedds.idl import IdlEnum, IdlStruct
from foxglove_node import FoxgloveDecoder, install, json_lines
from mcap.reader import make_reader
from test_bridge import advertised, start_bridge
from test_record import ALERT, cloud, matched_writer, start_recorder
from test_system import CAR, TRUCK, scene
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import connect

from automotive.bus.endpoints import Databus
from automotive.sim.lfsr import FramePattern
from automotive.tools.flows import Flow, flows_with_diagnostics
from automotive.tools.foxglove_bridge.wsrelay import (
    LEGACY_SUBPROTOCOL,
    SDK_SUBPROTOCOL,
    rewrite_request,
    rewrite_response,
)
from automotive.types.Alerts import DriverAlerts
from automotive.types.Common import ClassificationEnum
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_

TIMEOUT = 90.0
DECODE_TIMEOUT = 300.0
CAMERA_FRAMES = 6
FRAME_BYTES = 4_196_352  # CameraImage::CameraImageData, the size that MAX_IMAGE_SIZE names
CLOUD_BYTES = 184_320  # 11,520 points of 16 bytes
VISION_ROWS = 40
TALL_ROWS = range(10, 30)  # the truck leads for 2 s (rows every 100 ms): one alert, then one all-clear


@pytest.fixture(scope="session")
def foxglove() -> FoxgloveDecoder:
    return FoxgloveDecoder(install())


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def compare(foxglove: Any, ours: Any, where: str) -> None:
    """Foxglove's decoding (JSON from decode.js) equals ours (a sample of our generated types), member by member.
    ROS 2 names members without the DDS trailing underscore (``header_`` is ``header``)."""
    if isinstance(ours, IdlEnum):
        assert foxglove == ours.name, f"{where}: Foxglove {foxglove!r}, ours {ours.name}"
    elif isinstance(ours, IdlStruct):
        assert isinstance(foxglove, dict), f"{where}: Foxglove {foxglove!r}, ours a {type(ours).__name__}"
        members = {name if name in foxglove else name.rstrip("_"): value for name, value in vars(ours).items()}
        assert set(members) == set(foxglove), f"{where}: Foxglove members {sorted(foxglove)}, ours {sorted(members)}"
        for name, value in members.items():
            compare(foxglove[name], value, f"{where}.{name}")
    elif isinstance(foxglove, dict) and set(foxglove) == {"bytes", "sha256"}:  # an octet array or sequence
        data = bytes(ours)
        assert foxglove == {"bytes": len(data), "sha256": sha256(data)}, f"{where}: Foxglove {foxglove}, ours " \
            f"{len(data)} bytes {sha256(data)}"
    elif isinstance(ours, list):
        assert isinstance(foxglove, list) and len(foxglove) == len(ours), \
            f"{where}: Foxglove {foxglove!r}, ours {ours!r}"
        for index, (theirs, mine) in enumerate(zip(foxglove, ours, strict=True)):
            compare(theirs, mine, f"{where}[{index}]")
    elif isinstance(ours, float) and not math.isfinite(ours):
        assert foxglove == {"nan": "NaN", "inf": "Infinity", "-inf": "-Infinity"}[str(ours)], f"{where}: {foxglove!r}"
    else:
        assert type(foxglove) is type(ours) or (isinstance(ours, float) and isinstance(foxglove, int)), \
            f"{where}: Foxglove {foxglove!r}, ours {ours!r}"
        assert foxglove == ours, f"{where}: Foxglove {foxglove!r}, ours {ours!r}"


def recorded_payloads(path: Path) -> dict[tuple[str, str], bytes]:
    """(topic, sha256) -> payload of every message of a recording, read with the official mcap library."""
    with open(path, "rb") as stream:
        return {(channel.topic, sha256(message.data)): message.data
                for _, channel, message in make_reader(stream).iter_messages()}


def alert_states(values: list[dict[str, Any]]) -> list[bool]:
    """driverAttention of each alert, each run of equal alerts counted once (the HMI shows a change of state)."""
    states: list[bool] = []
    for value in values:
        if not states or states[-1] != value["driverAttention"]:
            states.append(value["driverAttention"])
    return states


def check_decoded(lines: list[dict[str, Any]], flows: list[Flow], payloads: dict[tuple[str, str], bytes],
                  source: str) -> Counter[str]:
    """Every channel parsed and every message decoded by Foxglove's libraries, equal to our decoding of the same bytes
    and to the system's inputs; the number of messages per topic."""
    errors = [line for line in lines if "error" in line]
    assert not errors, f"{source}: Foxglove's libraries failed: {errors[:3]}"
    # A flow's channel, and the recorder's channels of its disposals and unregistrations (same type and schema).
    flow_of = {f"{flow.topic}{suffix}": flow for flow in flows for suffix in ("", "/dispose", "/unregister")}
    channels = {line["topic"]: line for line in lines if line["kind"] == "channel"}
    assert {flow.topic for flow in flows} <= set(channels) <= set(flow_of), f"{source}: channels {sorted(channels)}"
    for topic, channel in channels.items():
        assert (channel["schemaName"], channel["schemaEncoding"]) == (flow_of[topic].schema.name,
                                                                      flow_of[topic].schema.encoding)
    by_topic: dict[str, list[dict[str, Any]]] = {topic: [] for topic in channels}
    for number, line in enumerate(line for line in lines if line["kind"] == "message"):
        topic = line["topic"]
        raw = base64.b64decode(line["rawBase64"]) if "rawBase64" in line else payloads[(topic, line["raw"])]
        assert sha256(raw) == line["raw"]
        compare(line["value"], flow_of[topic].data_type.deserialize(raw), f"{source} message {number} on {topic}")
        by_topic[topic].append(line["value"])
    silent = [flow.topic for flow in flows if not by_topic[flow.topic]]
    assert not silent, f"{source}: no message on {silent}"

    # The system's inputs, as Foxglove shows them.
    # collision avoidance's first verdict (all clear), the alert, all clear again
    assert alert_states(by_topic["AlertTopic"]) == [False, True, False], f"{source}: alerts {by_topic['AlertTopic']}"
    assert {name: value for name, value in by_topic["AlertTopic"][1].items() if value} == {"driverAttention": True}
    for scan in by_topic["rt/LidarTopic"]:
        assert (scan["data"]["bytes"], scan["width"] * scan["height"], scan["point_step"],
                scan["header"]["frame_id"], [field["name"] for field in scan["fields"]]) == (
            CLOUD_BYTES, 11_520, 16, "map", ["x", "y", "z", "rgb"])
    car = {"classification": ClassificationEnum(CAR).name, "position": [12.5, -1.5, 0.0],
           "velocity": [3.25, 0.5, -0.25], "size": [4.5, 1.5, 1.75]}
    truck = ClassificationEnum(TRUCK).name
    for topic in ("VisionTopic", "SensorObjects"):
        objects = [obj for value in by_topic[topic] for obj in value["objects"]]
        assert {obj["classification"] for obj in objects} == {car["classification"], truck}, f"{source}: {topic}"
        assert all({key: obj[key] for key in car} == car for obj in objects if obj["classification"] != truck)
    assert all(obj["rangeMode"] == "RANGE_NONE" for value in by_topic["SensorObjects"] for obj in value["objects"])
    # Commands follow the first object: the car (5 % 4: LEFT), the truck while it leads (6 % 4: RIGHT).
    assert {value["blinkerStatus"] for value in by_topic["PlatformControl"]} == {"INDICATOR_LEFT", "INDICATOR_RIGHT"}
    assert {value["blinkerStatus"] for value in by_topic["PlatformStatus"]} <= {
        "INDICATOR_OFF", "INDICATOR_LEFT", "INDICATOR_RIGHT", "INDICATOR_HAZARD"}
    pattern = FramePattern(FRAME_BYTES)
    for frame in by_topic["CameraImageData"]:
        assert frame["id"] == 1 and frame["data"] == {"bytes": FRAME_BYTES,
                                                      "sha256": sha256(bytes(pattern.frame(frame["seqnum"])))}
    assert {value["color"] for value in by_topic["Circle"]} == {"BLUE"}
    return Counter({topic: len(values) for topic, values in by_topic.items()})


def test_foxglove_decodes_every_channel_of_a_recording_and_of_the_bridge(  # type: ignore[no-untyped-def]
        apps, domain_id: int, tmp_path: Path, foxglove: FoxgloveDecoder) -> None:
    domain = ["--domain", str(domain_id)]
    flows = flows_with_diagnostics()  # the system's and every program's health (/diagnostics)
    recording = tmp_path / "drive.mcap"
    recorder = apps.start("record", *domain, "--output", str(recording))
    recorder.wait_for(r"recording \d+ topic", timeout=TIMEOUT)
    # A backlog that holds what arrives while the client decodes a 4 MiB frame: the alerts must all get through.
    bridge, port = start_bridge(apps, domain_id, "-D", "config.backlog=256")
    client = apps.start_command("decode.js ws", foxglove.command("ws", f"ws://127.0.0.1:{port}"), env=foxglove.env)
    client.wait_for(r'"kind":"open"', timeout=TIMEOUT)
    bridge.wait_for(r"client \d+ subscribed to", count=len(flows), timeout=TIMEOUT)

    # The system, as scripts/launch starts it (the HMI only reads), with a scene that raises one alert, a slower
    # LiDAR and a few full-size camera frames (sent once the recorder and the bridge both read them).
    apps.start("shapes", "publish", "--color", "BLUE", *domain)
    apps.start("lidar", *domain, "-D", "config.pubInterval=500")
    apps.start("vehicle_platform", *domain)
    avoidance = apps.start("collision_avoidance", *domain)
    apps.start("sensor_fusion", *domain)
    camera = apps.start("camera_pub", *domain, "-D", "config.pubInterval=200", "-D", "config.waitSubscribers=2",
                        "--count", str(CAMERA_FRAMES))
    avoidance.wait_for(r"\[SensorObjects\] reader matched a writer", timeout=TIMEOUT)
    for tool in (recorder, bridge):
        for topic in ("AlertTopic", "PlatformStatus", "rt/LidarTopic", "Circle"):
            tool.wait_for(rf"\[{re.escape(topic)}\] reader matched a writer", timeout=TIMEOUT)
    vision = apps.start("vision", *domain, "-D", f"dataFile={scene(tmp_path / 'scene.csv', VISION_ROWS, TALL_ROWS)}",
                        "--count", str(VISION_ROWS))
    avoidance.wait_for(r"all clear", count=2, timeout=TIMEOUT)  # its first verdict, then the alert's end
    assert vision.wait_exit(timeout=TIMEOUT) == 0, vision.output
    assert camera.wait_exit(timeout=TIMEOUT) == 0, camera.output
    recorder.wait_for(rf" CameraImageData={CAMERA_FRAMES}/", timeout=TIMEOUT)
    client.wait_for(r'"topic":"AlertTopic".*"driverAttention":false', timeout=TIMEOUT)
    for flow in flows:
        client.wait_for(rf'"kind":"message","topic":"{re.escape(flow.topic)}"', timeout=TIMEOUT)
    assert client.stop(signal.SIGTERM) == 0, client.output[-3000:]
    recorder.wait_for_more(r"record: recorded=", 1, timeout=TIMEOUT)  # the last samples are on their way
    assert recorder.stop(signal.SIGINT) == 0, recorder.output[-3000:]

    live = json_lines(client.lines)
    assert live[0] == {"kind": "open", "protocol": LEGACY_SUBPROTOCOL}  # the ws-protocol client's default name
    assert live[-1]["kind"] == "close"
    decoded = foxglove.run("mcap", str(recording), timeout=DECODE_TIMEOUT)
    [summary] = [line for line in decoded if line["kind"] == "mcap"]
    assert summary["profile"] == "ros2" and summary["chunks"] == summary["chunksWithCrc"] > 0, summary
    payloads = recorded_payloads(recording)
    recorded = check_decoded(decoded, flows, payloads, "the recording")
    assert recorded["CameraImageData"] == CAMERA_FRAMES
    assert sum(recorded.values()) == summary["messages"]
    check_decoded([line for line in live if line["kind"] in ("channel", "message")], flows, payloads, "the bridge")


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_foxglove_decodes_compressed_recordings(apps, bus: Databus, domain_id: int, tmp_path: Path,  # type: ignore[no-untyped-def]
                                                foxglove: FoxgloveDecoder, compression: str) -> None:
    recording = tmp_path / f"{compression}.mcap"
    recorder = start_recorder(apps, domain_id, recording, "--topics", "AlertTopic,rt/LidarTopic",
                              "-D", f"config.compression={compression}")
    matched_writer(bus, recorder, "AlertTopic", DriverAlerts, "HMI").write(ALERT)
    matched_writer(bus, recorder, "rt/LidarTopic", PointCloud2_, "Lidar").write(cloud())
    recorder.wait_for(r"recorded=2 ", timeout=TIMEOUT)
    assert recorder.stop(signal.SIGINT) == 0, recorder.output[-3000:]
    lines = foxglove.run("mcap", str(recording), timeout=DECODE_TIMEOUT)
    errors = [line for line in lines if "error" in line]
    assert not errors, errors
    [summary] = [line for line in lines if line["kind"] == "mcap"]
    assert (summary["compressions"], summary["messages"], summary["chunksWithCrc"] > 0) == ([compression], 2, True)
    payloads = recorded_payloads(recording)
    for line in (line for line in lines if line["kind"] == "message"):
        compare(line["value"], type(ALERT if line["topic"] == "AlertTopic" else cloud()).deserialize(
            payloads[(line["topic"], line["raw"])]), line["topic"])


def test_the_bridge_accepts_both_subprotocol_names(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    bridge, port = start_bridge(apps, domain_id)
    for offered, chosen in (([SDK_SUBPROTOCOL], SDK_SUBPROTOCOL), ([LEGACY_SUBPROTOCOL], LEGACY_SUBPROTOCOL),
                            ([LEGACY_SUBPROTOCOL, SDK_SUBPROTOCOL], SDK_SUBPROTOCOL)):
        with connect(f"ws://127.0.0.1:{port}", subprotocols=offered, max_size=None) as client:
            assert client.subprotocol == chosen
            assert {flow.topic for flow in flows_with_diagnostics()} == set(advertised(client))
    with pytest.raises(InvalidStatus, match="HTTP 400"):  # the SDK's own answer to a client of another protocol
        connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.websocket.v2"])
    with connect(f"ws://127.0.0.1:{port}", subprotocols=[LEGACY_SUBPROTOCOL]) as client:
        advertised(client)
        assert bridge.stop(signal.SIGTERM) == 0, bridge.output  # a connected client does not hold the bridge up
        with pytest.raises(ConnectionClosed):
            while True:
                client.recv(timeout=TIMEOUT)
    assert "Traceback" not in bridge.output


def test_the_handshake_rewrite() -> None:
    legacy = (b"GET / HTTP/1.1\r\nHost: h\r\nUpgrade: websocket\r\nSec-WebSocket-Key: k\r\n"
              b"sec-websocket-protocol: " + LEGACY_SUBPROTOCOL.encode())
    rewritten, is_legacy = rewrite_request(legacy)
    assert is_legacy
    assert rewritten == (b"GET / HTTP/1.1\r\nSec-WebSocket-Protocol: foxglove.sdk.v1\r\nHost: h\r\n"
                         b"Upgrade: websocket\r\nSec-WebSocket-Key: k")
    both = legacy + b", " + SDK_SUBPROTOCOL.encode()
    assert rewrite_request(both) == (both, False)
    other = b"GET / HTTP/1.1\r\nSec-WebSocket-Protocol: foxglove.websocket.v2"
    assert rewrite_request(other) == (other, False)
    assert rewrite_request(b"GET / HTTP/1.1\r\nHost: h") == (b"GET / HTTP/1.1\r\nHost: h", False)
    malformed = b"GET / HTTP/1.1\r\nSec-WebSocket-Protocol\r\nHost: h"  # passed on: the SDK answers it
    assert rewrite_request(malformed) == (malformed, False)
    answer = b"HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: foxglove.sdk.v1\r\nsec-websocket-accept: a"
    assert rewrite_response(answer) == (b"HTTP/1.1 101 Switching Protocols\r\nSec-WebSocket-Protocol: "
                                        b"foxglove.websocket.v1\r\nsec-websocket-accept: a")
    refused = b"HTTP/1.1 400 Bad Request\r\ncontent-length: 3"
    assert rewrite_response(refused) == refused


def test_the_types_no_flow_uses_decode_in_foxglove_too(tmp_path: Path, foxglove: FoxgloveDecoder) -> None:
    """The IDL's other types, as omgidl channels: the other camera frame sizes, the original's lane and LiDAR types,
    and PointCloud2_ itself (the flows above cover the rest)."""
    from mcap.writer import CompressionType, Writer

    from automotive import config
    from automotive.tools.flows import type_name
    from automotive.types.CameraImage import CameraImageData_1MiB, CameraImageData_4MiB, CameraImageData_64KiB
    from automotive.types.Common import POSIXTimestamp
    from automotive.types.Lane import ConfidenceEnum, LaneBoundaryEnum, LaneObject, LaneSensor
    from automotive.types.Lidar import LidarSensor, PCloud, Point

    frames = [frame_type(id=7, sec_=-2, nanosec_=3, seqnum=9, data=bytes(FramePattern(size).frame(9)))
              for frame_type, size in ((CameraImageData_64KiB, 65_536), (CameraImageData_1MiB, 1_048_576),
                                       (CameraImageData_4MiB, 4_194_304))]
    lane = LaneObject(isValid=True, confidence=ConfidenceEnum.CONFIDENCE_HIGH,
                      boundaryType=LaneBoundaryEnum.BOUNDRY_DOUBLEMARKER, offset=1.5, headingAngle=-0.25,
                      curvature=0.125)
    lidar = LidarSensor(timestamp=POSIXTimestamp(s=5, ns=6), ptCloud=PCloud(
        Location=[Point(point=[1.0, -2.0, 3.5]), Point(point=[0.0, 0.5, -1.0])], color=200, normal=0.5,
        intensity=0.75, count=2, xLimits=[-1.0, 1.0], yLimits=[-2.0, 2.0], zLimits=[-3.0, 3.0]))
    samples = [*frames, LaneSensor(left=lane, right=lane), lidar, cloud()]
    path = tmp_path / "types.mcap"
    with open(path, "wb") as stream:
        writer = Writer(stream, compression=CompressionType.NONE)
        writer.start(profile="ros2")
        for sample in samples:
            schema = writer.register_schema(type_name(type(sample)), "omgidl", config.idl_file().read_bytes())
            channel = writer.register_channel(type_name(type(sample)), "cdr", schema)
            writer.add_message(channel, log_time=1, publish_time=1, data=sample.serialize(use_version_2=False))
        writer.finish()
    lines = foxglove.run("mcap", str(path), timeout=DECODE_TIMEOUT)
    errors = [line for line in lines if "error" in line]
    assert not errors, errors
    decoded = {line["topic"]: line["value"] for line in lines if line["kind"] == "message"}
    assert sorted(decoded) == sorted(type_name(type(sample)) for sample in samples)
    for sample in samples:
        compare(decoded[type_name(type(sample))], sample, type_name(type(sample)))
    assert decoded["Lane::LaneSensor"]["left"]["boundaryType"] == "BOUNDRY_DOUBLEMARKER"


def test_decode_js_reports_a_schema_foxglove_cannot_parse(tmp_path: Path, foxglove: FoxgloveDecoder) -> None:
    """The check itself: the IDL as it was before the fix (a constant expression) fails in Foxglove's parser."""
    from mcap.writer import CompressionType, Writer

    from automotive import config

    broken = config.idl_file().read_text().replace("MAX_IMAGE_SIZE = 4196352", "MAX_IMAGE_SIZE = 1366 * 768 * 4")
    assert broken != config.idl_file().read_text()
    path = tmp_path / "broken.mcap"
    with open(path, "wb") as stream:
        writer = Writer(stream, compression=CompressionType.NONE)  # as the recorder writes by default
        writer.start(profile="ros2")
        schema = writer.register_schema("Alerts::DriverAlerts", "omgidl", broken.encode())
        channel = writer.register_channel("AlertTopic", "cdr", schema)
        writer.add_message(channel, log_time=1, publish_time=1, data=bytes(12))
        writer.finish()
    lines = foxglove.run("mcap", str(path), timeout=DECODE_TIMEOUT)
    [channel_line] = [line for line in lines if line["kind"] == "channel"]
    assert "invalid syntax" in channel_line["error"], json.dumps(channel_line)
