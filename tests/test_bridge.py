"""automotive.tools.foxglove_bridge.bridge: a real WebSocket client speaking the Foxglove SDK protocol (subprotocol
foxglove.sdk.v1) sees every topic advertised with the recorder's schemas and receives the DDS sample bytes unchanged; a
client that stops reading
costs the bridge bounded memory and does not hold back a reliable writer."""

from __future__ import annotations

import json
import re
import socket
import struct
import time
from pathlib import Path
from typing import Any

from cyclonedds.core import DDSException
from dds_helpers import wait_until
from test_record import VISION, cloud, wire
from websockets.sync.client import ClientConnection, connect

from automotive.bus.endpoints import Databus
from automotive.cyclone.matched import matched_subscriptions
from automotive.sim.lfsr import FramePattern
from automotive.tools.flows import flows_with_diagnostics
from automotive.types.CameraImage import CameraImageData
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.types.Vision import VisionSensor
from automotive.wire.camera import FrameWriter

TIMEOUT = 60.0
SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01  # binary opcode: subscription id (uint32), log time (uint64), payload


def start_bridge(apps: Any, domain_id: int, *args: str) -> tuple[Any, int]:
    bridge = apps.start("bridge", "--domain", str(domain_id), "--port", "0", *args)
    line = bridge.wait_for(r"Foxglove WebSocket server on ws://127\.0\.0\.1:\d+", timeout=TIMEOUT)
    return bridge, int(re.search(r":(\d+) ", line).group(1))  # type: ignore[union-attr]


def advertised(client: ClientConnection) -> dict[str, dict[str, Any]]:
    """Read the server's text messages until the channel advertisement; topic -> channel."""
    deadline = time.monotonic() + TIMEOUT
    while time.monotonic() < deadline:
        message = client.recv(timeout=TIMEOUT)
        if isinstance(message, str) and json.loads(message)["op"] == "advertise":
            return {channel["topic"]: channel for channel in json.loads(message)["channels"]}
    raise AssertionError("no advertise message")


def subscribe(client: ClientConnection, channels: dict[str, dict[str, Any]], topics: list[str]) -> dict[int, str]:
    """Subscribe to ``topics``; subscription id -> topic."""
    ids = {number: topic for number, topic in enumerate(topics, start=1)}
    client.send(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": number, "channelId": channels[topic]["id"]} for number, topic in ids.items()]}))
    return ids


def test_channels_and_payloads_over_the_foxglove_protocol(apps, bus: Databus, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    bridge, port = start_bridge(apps, domain_id)
    with connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], max_size=None) as client:
        assert client.subprotocol == SUBPROTOCOL
        channels = advertised(client)
        flows = flows_with_diagnostics()  # the system's and every program's /diagnostics
        assert set(channels) == {flow.topic for flow in flows}
        for flow in flows:
            channel = channels[flow.topic]
            assert (channel["encoding"], channel["schemaName"], channel["schemaEncoding"]) == (
                "cdr", flow.schema.name, flow.schema.encoding)
            assert channel["schema"] == flow.schema.data.decode()
        subscriptions = subscribe(client, channels, ["VisionTopic", "rt/LidarTopic"])
        bridge.wait_for(r"client \d+ subscribed to rt/LidarTopic", timeout=TIMEOUT)
        vision = bus.writer("VisionTopic", VisionSensor, "Vision")
        lidar = bus.writer("rt/LidarTopic", PointCloud2_, "Lidar")
        for topic in ("VisionTopic", "rt/LidarTopic"):
            bridge.wait_for(rf"\[{re.escape(topic)}\] reader matched a writer", timeout=TIMEOUT)
        wait_until(lambda: bool(matched_subscriptions(vision) and matched_subscriptions(lidar)), TIMEOUT,
                   "the bridge's readers")
        before = time.time_ns()
        lidar.write(cloud())
        received: dict[str, tuple[int, bytes]] = {}
        deadline = time.monotonic() + TIMEOUT
        while len(received) < 2:
            # Best effort: a sample written just after matching may miss the reader; the vision sample is written
            # again until it arrives.
            assert time.monotonic() < deadline, f"received only {list(received)}; the bridge said:\n{bridge.output}"
            if "VisionTopic" not in received:
                vision.write(VISION)
            try:
                message = client.recv(timeout=1.0)
            except TimeoutError:
                continue
            if isinstance(message, bytes) and message[0] == MESSAGE_DATA:
                subscription, log_time = struct.unpack_from("<IQ", message, 1)
                received[subscriptions[subscription]] = (log_time, message[13:])
    assert received["VisionTopic"][1] == wire(VISION)
    assert received["rt/LidarTopic"][1] == wire(cloud())
    assert all(before <= log_time <= time.time_ns() for log_time, _ in received.values())


def peak_memory_mb(pid: int) -> float:
    """The process's peak resident memory (VmHWM), in MB."""
    text = Path(f"/proc/{pid}/status").read_text()
    return int(re.search(r"VmHWM:\s+(\d+) kB", text).group(1)) / 1024  # type: ignore[union-attr]


def test_a_stuck_client_costs_bounded_memory(apps, bus: Databus, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    frames = 120  # 4 MiB each: 500 MB through the bridge, most of it to a client that reads nothing
    backlog = 8
    bridge, port = start_bridge(apps, domain_id, "--topics", "CameraImageData", "-D", f"config.backlog={backlog}")
    writer = FrameWriter(bus.writer("CameraImageData", CameraImageData, "Camera"), FramePattern(4196352))
    bridge.wait_for(r"\[CameraImageData\] reader matched a writer", timeout=TIMEOUT)
    wait_until(lambda: bool(matched_subscriptions(writer.writer)), TIMEOUT, "the bridge's camera reader")
    # max_queue=1: the client library stops reading the socket once it holds one unread message, as a stuck
    # Foxglove would; the kernel's socket buffers fill, then the bridge's per-client backlog.
    with connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], max_size=None, max_queue=1) as client:
        subscribe(client, advertised(client), ["CameraImageData"])
        bridge.wait_for(r"client \d+ subscribed to CameraImageData", timeout=TIMEOUT)
        baseline = peak_memory_mb(bridge.process.pid)
        for seqnum in range(1, frames + 1):
            try:
                writer.write_pattern(1, seqnum)  # reliable: blocks (then fails) if the bridge held the writer back
            except DDSException as error:
                raise AssertionError(f"frame {seqnum}: the bridge held back the writer ({error})") from None
        assert writer.writer.wait_for_acks(int(TIMEOUT * 1e9)), "the bridge did not acknowledge every frame"
        bridge.wait_for(r"forwarded CameraImageData=\d+", timeout=TIMEOUT)
        growth = peak_memory_mb(bridge.process.pid) - baseline
    # Unbounded, the bridge would hold most of the 500 MB for the stuck client; bounded, the backlog's 8 frames
    # (34 MB) and what the library keeps in flight.
    assert growth < 200, f"the bridge grew by {growth:.0f} MB for a stuck client"


def test_bad_input_is_one_line(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        for args, message in ((["--port", str(port)], rf"--port {port}: cannot start the WebSocket server"),
                              (["--topics", "VisionTopic,Nope"], r"--topics: unknown topic\(s\) Nope \(known: "),
                              (["--port", "70000"], r"--port 70000: expected 0\.\.65535")):
            result = apps.run("bridge", "--domain", str(domain_id), *args, timeout=TIMEOUT)
            assert result.returncode == 2, result.stdout + result.stderr
            assert len(result.stderr.strip().splitlines()) == 1, result.stderr
            assert re.search(rf"^automotive foxglove-bridge: .*{message}", result.stderr), result.stderr
