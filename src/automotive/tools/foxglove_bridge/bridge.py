"""Live view: a Foxglove WebSocket server that forwards every flow of the databus, as received, to the Foxglove app.

Data flow:  every topic of the system and rt/diagnostics (automotive.tools.flows; --topics to choose), each read with
the reader side of its writer's QoS profile keeping only the newest sample  -->  serialized samples, never deserialized
(automotive.wire.rawsample)  -->  one Foxglove channel per topic (message encoding ``cdr``, the recorder's schemas)  -->
the Foxglove WebSocket server (foxglove-sdk, on a private loopback port)  -->  a front on ws://HOST:PORT that also
accepts the protocol's older subprotocol name (automotive.tools.foxglove_bridge.wsrelay)

Open it in Foxglove with "Open connection" > "Foxglove WebSocket" > ws://127.0.0.1:8765. The LiDAR cloud shows in
the 3D panel, every other flow in the Raw Messages and Plot panels, and every program's health (rt/diagnostics, ROS 2's
/diagnostics: automotive.bus.diagnostics) in the Diagnostics panels. A viewer must never slow the databus: its readers
keep only the newest sample of each instance (a reliable writer is never held back by the bridge), and each client
gets at most config.backlog messages queued (the oldest dropped first), so a slow or stuck client costs bounded
memory. Disposals and unregistrations are not forwarded (a Foxglove channel carries samples of one type).

The camera's frames and the LiDAR's clouds of writers on this host come through shared memory (automotive.wire.shm;
config.transport=udp: on DDS), the very bytes their DDS samples carry; the DDS copies of those writers' samples are
left out (automotive.tools.flows.FlowInput), so none is forwarded twice. Its shared-memory subscriber keeps the
profile's depth, not only the newest sample, and the bridge forwards every sample it takes there: the camera's
reliable keep-all writer counts each sample it sends through shared memory until the subscriber takes it, and a sample
overwritten unread would never be counted off (measured: with a depth of 1 the camera at full speed stalled for its
max_blocking_time, 10 s, again and again). So, unlike on DDS, a bridge that stops taking samples altogether (a frozen
process) holds the camera back, for at most that max_blocking_time (automotive.wire.shm's flow control).
"""

from __future__ import annotations

import argparse
import sys

import foxglove
from cyclonedds.qos import Policy
from foxglove.websocket import ChannelView, Client, ServerListener

from automotive.bus.app import Application, run
from automotive.bus.errors import ConfigError
from automotive.bus.properties import PropertyKeys
from automotive.bus.stats import Every
from automotive.tools.flows import (
    Flow,
    FlowInput,
    channel_metadata,
    check_transport,
    flows_with_diagnostics,
    open_inputs,
    select,
)
from automotive.tools.foxglove_bridge.wsrelay import LEGACY_SUBPROTOCOL, SDK_SUBPROTOCOL, SubprotocolRelay
from automotive.wire.rawsample import SampleKind

# The property keys it reads beyond the runtime's (automotive.bus.app.RUNTIME_KEYS): any other is refused at start.
PROPERTY_KEYS = PropertyKeys.of("config.backlog", "config.transport", "config.shmPrefix")

TAKE_LIMIT = 16


class SubscriptionLog(ServerListener):
    """Says when a client subscribes to or leaves a topic (called from the server's own threads)."""

    def __init__(self, app: Application):
        self.app = app
        self.subscriptions = 0

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        self.subscriptions += 1
        self.app.log.info("client %d subscribed to %s", client.id, channel.topic)

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
        self.subscriptions -= 1
        self.app.log.info("client %d unsubscribed from %s", client.id, channel.topic)


def foxglove_channel(app: Application, flow: Flow) -> foxglove.Channel:
    schema = flow.schema
    return foxglove.Channel(flow.topic, schema=foxglove.Schema(name=schema.name, encoding=schema.encoding,
                                                               data=schema.data),
                            message_encoding="cdr",
                            metadata=channel_metadata(flow, app.profiles.writer_qos(app.library, flow.profile)))


def body(app: Application) -> None:
    flows = select(flows_with_diagnostics(app.props.folder), app.args.topics)
    backlog = app.props.get_int("config.backlog", 16, minimum=1)
    check_transport(app.props)
    port: int = app.args.port
    if not 0 <= port <= 65535:
        raise ConfigError(f"--port {port}: expected 0..65535")
    # Readers first: the channels appear to clients at once, the data as soon as writers match.
    inputs = open_inputs(app, flows, (Policy.History.KeepLast(1),), shared_overrides=())
    try:
        serve(app, inputs, backlog, port)
    finally:
        for flow_input in inputs:
            flow_input.close()


def serve(app: Application, inputs: list[FlowInput], backlog: int, port: int) -> None:
    """Forward every flow's samples to the Foxglove clients until stopped."""
    listener = SubscriptionLog(app)
    readers = [(flow_input, foxglove_channel(app, flow_input.flow)) for flow_input in inputs]
    # The SDK's server on a private loopback port, behind a front on --host/--port that also accepts the older
    # subprotocol name (automotive.tools.foxglove_bridge.wsrelay).
    try:
        server = foxglove.start_server(name="automotive databus", host="127.0.0.1", port=0,
                                       message_backlog_size=backlog, server_listener=listener)
    except Exception as error:  # foxglove-sdk raises its own error types
        raise ConfigError(f"cannot start the Foxglove WebSocket server ({error})") from None
    try:
        front = SubprotocolRelay(app.args.host, port, server.port, app.log)
    except OSError as error:  # the port is taken, the address is not this host's, ...
        server.stop()
        raise ConfigError(f"--host {app.args.host} --port {port}: cannot start the WebSocket server ({error})") \
            from None
    app.log.info("Foxglove WebSocket server on ws://%s:%d (%d topics, at most %d messages queued per client; "
                 "subprotocol %s or %s)", app.args.host, front.port, len(readers), backlog, SDK_SUBPROTOCOL,
                 LEGACY_SUBPROTOCOL)
    forwarded = {flow_input.flow.topic: 0 for flow_input in inputs}
    every_second = Every()
    waitset = app.waitset(*(flow_input.reader for flow_input in inputs))
    for flow_input in inputs:
        flow_input.attach(waitset)
    try:
        for _ in app.wake_ups(waitset, timeout_s=0.5):
            for flow_input, channel in readers:
                for sample, receive_ns in flow_input.drain(TAKE_LIMIT):
                    if sample.kind is SampleKind.DATA:
                        channel.log(bytes(sample.data), log_time=receive_ns)
                        forwarded[flow_input.flow.topic] += 1
                        app.tick()
                flow_input.check_deadline()
            if every_second.due():
                app.log.info("forwarded %s; %d subscription(s)", status(forwarded), listener.subscriptions)
    finally:
        front.stop()
        server.stop()
    app.log.info("forwarded in total %s", status(forwarded))
    for flow_input in inputs:
        if flow_input.shared_counts():
            app.log.info("%s: %s", flow_input.flow.topic, flow_input.shared_counts())


def status(forwarded: dict[str, int]) -> str:
    return " ".join(f"{topic}={count}" for topic, count in forwarded.items() if count) or "nothing yet"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8765, help="TCP port (default 8765; 0: any free port)")
    parser.add_argument("--topics", default="", help="comma-separated topics to forward (default: every topic)")


def main(argv: list[str] | None = None) -> int:
    return run("bridge", __doc__ or "", body, argv, add_arguments, command="automotive foxglove-bridge",
               keys=PROPERTY_KEYS)


if __name__ == "__main__":
    sys.exit(main())
