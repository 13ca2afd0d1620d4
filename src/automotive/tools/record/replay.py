"""Replayer: writes the samples of an MCAP recording back onto the databus, as recorded.

Data flow:  FILE (automotive.tools.record.record, or rosbag2 MCAP with the same topics)  -->  each channel's topic and
schema matched to a flow of the system (automotive.tools.flows)  -->  the recorded CDR bytes written unchanged
(automotive.wire.rawsample) with the flow's writer QoS, at the recorded pace scaled by --rate (0: as fast as flow
control allows); disposals and unregistrations replayed as such.

A channel whose topic or schema is not one of the system's is skipped (said once). The replayed samples carry the
time of their replay as source timestamp, as a live writer's would (their own data timestamps are left as
recorded). A message Cyclone refuses to write (its bytes are not a valid sample of the type: a file from elsewhere,
or damaged) is reported once per topic and interval, like a bad sample from the bus, and the replay goes on. At the
end, reliable readers get up to 10 s to acknowledge the last samples.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cyclonedds.core import DDSException
from mcap.exceptions import McapError
from mcap.reader import SeekingReader

from automotive.bus.app import Application, run
from automotive.bus.badsamples import BadSample
from automotive.bus.diagnostics import DIAGNOSTICS_TOPIC
from automotive.bus.endpoints import wait_for_acks
from automotive.bus.errors import ConfigError
from automotive.bus.properties import PropertyKeys
from automotive.bus.stats import Every
from automotive.cyclone.matched import matched_subscriptions
from automotive.tools.flows import Flow, select, system_flows
from automotive.wire.rawsample import RawSample, RawWriter, SampleKind

# The property keys it reads beyond the runtime's (automotive.bus.app.RUNTIME_KEYS): any other is refused at start.
PROPERTY_KEYS = PropertyKeys.of()

MCAP_MAGIC = b"\x89MCAP0\r\n"
ACK_TIMEOUT_S = 10.0


@dataclass
class Track:
    """A channel of the file that is replayed: the flow it feeds and what its messages are."""

    flow: Flow
    kind: SampleKind
    writer: RawWriter
    written: int = 0
    refused: int = 0


def open_recording(path: Path) -> tuple[Any, SeekingReader]:
    """The file and its reader, once it is known to be a finished MCAP file (else a ConfigError)."""
    try:
        stream = open(path, "rb")  # closed by the caller
    except OSError as error:
        raise ConfigError(f"{path}: cannot read ({error.strerror})") from None
    head = stream.read(len(MCAP_MAGIC))
    if head != MCAP_MAGIC:
        stream.close()
        raise ConfigError(f"{path}: not an MCAP file (it does not begin with the MCAP magic bytes)")
    stream.seek(-len(MCAP_MAGIC), 2)
    if stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
        stream.close()
        raise ConfigError(f"{path}: truncated MCAP file (no summary at its end: was the recorder killed?)")
    stream.seek(0)
    reader = SeekingReader(stream)
    try:
        reader.get_summary()
    except (McapError, ValueError, EOFError) as error:
        stream.close()
        raise ConfigError(f"{path}: unreadable MCAP summary ({error})") from None
    return stream, reader


def flow_of(channel: Any, flows: dict[str, Flow]) -> tuple[Flow | None, SampleKind]:
    """The flow a channel feeds: by its DDS topic (automotive.tools.record.record's metadata) or its name, a ROS 2 name
    such as /LidarTopic standing for the DDS topic rt/LidarTopic."""
    metadata = channel.metadata or {}
    kind = {kind.value: kind for kind in SampleKind}.get(metadata.get("dds_sample_kind", ""), SampleKind.DATA)
    topic = metadata.get("dds_topic", channel.topic)
    if topic not in flows and f"rt{topic}" in flows:
        topic = f"rt{topic}"
    return flows.get(topic), kind


def body(app: Application) -> None:
    path: Path = app.args.file
    rate: float = app.args.rate
    if rate < 0:
        raise ConfigError(f"--rate {rate:g}: expected 0 (as fast as possible) or a positive factor")
    start_s, end_s = app.args.start, app.args.end
    if start_s is not None and end_s is not None and end_s < start_s:
        raise ConfigError(f"--end {end_s:g} is before --start {start_s:g}")
    all_flows = system_flows(app.props.folder)
    chosen = select(all_flows, app.args.topics)
    flows = {flow.topic: flow for flow in chosen}
    known = {flow.topic: flow for flow in all_flows}
    stream, reader = open_recording(path)
    try:
        summary = reader.get_summary()
        assert summary is not None  # open_recording checked it
        tracks: dict[int, Track] = {}
        writers: dict[str, RawWriter] = {}
        for channel_id, channel in sorted(summary.channels.items()):
            flow, kind = flow_of(channel, known)
            schema = summary.schemas.get(channel.schema_id)
            if flow is None:
                if channel.topic == DIAGNOSTICS_TOPIC:  # the health of the recorded programs, not theirs to replay
                    app.log.info("channel %s: the recorded programs' health (/diagnostics), not replayed",
                                 channel.topic)
                else:
                    app.log.info("channel %s: not a topic of the system, skipped", channel.topic)
                continue
            if schema is None or schema.name != flow.schema.name or channel.message_encoding != "cdr":
                app.log.info("channel %s: schema %s (%s) is not %s's (%s), skipped", channel.topic,
                             schema.name if schema else "none", channel.message_encoding, flow.topic, flow.schema.name)
                continue
            if flow.topic not in flows:
                continue  # not asked for with --topics
            if flow.topic not in writers:
                writers[flow.topic] = RawWriter(app.bus.writer(flow.topic, flow.data_type, flow.profile))
            tracks[channel_id] = Track(flow, kind, writers[flow.topic])
        if not tracks:
            raise ConfigError(f"{path}: no channel of the chosen topics ({', '.join(flows)}) to replay")
        app.ready()
        if not wait_for_readers(app, list(writers.values()), app.args.wait_readers):
            return
        first = summary.statistics.message_start_time if summary.statistics else 0
        app.log.info("replaying %s: %d channel(s) on %s, rate %s%s", path, len(tracks),
                     ", ".join(writers), f"{rate:g}x" if rate else "as fast as possible",
                     ", looping" if app.args.loop else "")
        while app.running:
            replay_once(app, reader, tracks, first, rate, start_s, end_s)
            if not app.args.loop:
                break
        for topic, writer in writers.items():
            if not wait_for_acks(writer.writer, int(ACK_TIMEOUT_S * 1e9)):
                app.log.warning("[%s] not every sample acknowledged within %g s", topic, ACK_TIMEOUT_S)
        app.log.info("replayed %d samples: %s", sum(t.written for t in tracks.values()), counts(tracks))
        refused = sum(t.refused for t in tracks.values())
        if refused:
            app.log.warning("%d message(s) not replayed: Cyclone refused them as samples of their type", refused)
    finally:
        stream.close()


def counts(tracks: dict[int, Track]) -> str:
    totals: dict[str, int] = {}
    for track in tracks.values():
        name = track.flow.topic if track.kind is SampleKind.DATA else f"{track.flow.topic}/{track.kind.value}"
        totals[name] = totals.get(name, 0) + track.written
    return " ".join(f"{name}={count}" for name, count in totals.items())


def wait_for_readers(app: Application, writers: list[RawWriter], minimum: int) -> bool:
    """Wait until every writer matched ``minimum`` readers (or the application is stopped); True if they did."""
    if minimum <= 0:
        return True
    app.log.info("waiting for %d reader(s) on every topic", minimum)
    while app.running:
        if all(len(matched_subscriptions(writer.writer)) >= minimum for writer in writers):
            return True
        app.stop_event.wait(0.05)  # polling a status of remote readers
    return False


def replay_once(app: Application, reader: SeekingReader, tracks: dict[int, Track], first: int, rate: float,
                start_s: float | None, end_s: float | None) -> None:
    """One pass over the file, each message written at its recorded time (relative to --start) divided by rate."""
    begin = first + int((start_s or 0) * 1e9)
    end = first + int(end_s * 1e9) + 1 if end_s is not None else None
    topics = sorted({channel.topic for channel in
                     (reader.get_summary().channels[channel_id] for channel_id in tracks)})  # type: ignore[union-attr]
    started = time.monotonic()
    every_second = Every()
    for _, channel, message in reader.iter_messages(topics=topics, start_time=begin, end_time=end,
                                                    log_time_order=True):
        track = tracks.get(channel.id)
        if track is None:
            continue
        if rate > 0:
            delay = (message.log_time - begin) / 1e9 / rate - (time.monotonic() - started)
            if delay > 0 and app.stop_event.wait(delay):
                return
        if not app.running:
            return
        try:
            track.writer.put(RawSample(message.data, track.kind, 0, 0, 0, 0))
        except DDSException as error:  # not a valid sample of the type: said once per interval, then the next one
            track.refused += 1
            code = DDSException.error_message_mapping.get(error.code, (str(error.code),))[0]
            app.reporter.report(track.flow.topic, BadSample("", f"refused by Cyclone's writer ({code})",
                                                            f"a valid {track.flow.type_name}"),
                                f"message {message.sequence} of channel {channel.topic}", action="not replayed")
            continue
        track.written += 1
        app.tick()
        if every_second.due():
            app.log.info("replayed %d samples: %s", sum(t.written for t in tracks.values()), counts(tracks))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="the MCAP recording")
    parser.add_argument("--rate", type=float, default=1.0,
                        help="speed factor of the recorded timing (default 1; 0: as fast as flow control allows)")
    parser.add_argument("--loop", action="store_true", help="replay again from the start until stopped")
    parser.add_argument("--topics", default="", help="comma-separated topics to replay (default: every topic)")
    parser.add_argument("--start", type=float, default=None, help="seconds into the recording to start at")
    parser.add_argument("--end", type=float, default=None, help="seconds into the recording to end at")
    parser.add_argument("--wait-readers", type=int, default=0, metavar="N",
                        help="start once every replayed topic has N matched readers (default 0: at once)")


def main(argv: list[str] | None = None) -> int:
    return run("replay", __doc__ or "", body, argv, add_arguments, command="automotive replay",
               keys=PROPERTY_KEYS)


if __name__ == "__main__":
    sys.exit(main())
