"""A snapshot as text: what ``automotive monitor --once`` prints (for SSH sessions and scripts).

Sections: the participants with their endpoints, the matched pairs, the mismatches with their reasons, the notices (a
reader with no writer, a topic nobody reads, hints), the flows, the latencies (per topic and reader, per pair, and the
alert chain) and the programs' health. A latency whose writer and reader do not share a clock (other hosts) is marked
``~`` and says so. Names longer than
NAME_WIDTH are cut (``...``): discovery data from another system may carry names of any length.
"""

from __future__ import annotations

import time

from automotive.tools.monitor.model import CLOCK_NOT_SHARED, CLOCK_SHARED, Snapshot, Vehicle
from automotive.tools.monitor.rules import duration_words

NAME_WIDTH = 48
MESSAGE_WIDTH = 300


def cut(text: str | None, width: int = NAME_WIDTH) -> str:
    """``text`` on one line, at most ``width`` characters (``...`` says it was cut); "unknown" for None."""
    if text is None:
        return "unknown"
    line = "".join(character if character.isprintable() else "?" for character in text)
    return line if len(line) <= width else line[:width - 3] + "..."


def render(snapshot: Snapshot) -> str:
    lines: list[str] = []
    add = lines.append
    when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(snapshot.taken_at))
    add(f"domain {snapshot.domain} at {when}: {len(snapshot.participants)} participant(s), "
        f"{len(snapshot.topics)} topic(s), {len(snapshot.matches)} matched pair(s), "
        f"{len(snapshot.mismatches)} mismatch(es)")

    add("")
    add("Participants")
    if not snapshot.participants:
        add("  (none seen)")
    names = {endpoint.key: endpoint for endpoint in snapshot.endpoints}
    for participant in snapshot.participants:
        own = " (this monitor)" if participant.own else ""
        health = f", health {participant.health}" if participant.health else ""
        add(f"  {cut(participant.name)}{own}: {participant.vendor}, host {cut(participant.host)}, "
            f"pid {cut(participant.pid, 12)} ({cut(participant.process)}){health}")
        for hint in participant.hints:
            add(f"    hint: {hint}")
        for kind, keys in (("writes", participant.writers), ("reads", participant.readers)):
            for key in keys:
                endpoint = names.get(key)
                if endpoint is None:
                    continue
                qos = endpoint.qos
                add(f"    {kind} {cut(endpoint.topic)} ({cut(endpoint.type_name)}): {qos.reliability}, "
                    f"{qos.durability}, deadline {duration_words(qos.deadline_ns)}, "
                    f"latency budget {duration_words(qos.latency_budget_ns)}, {qos.ownership}, "
                    f"{'/'.join(qos.representations)}")

    add("")
    add("Matches (by the DDS rules)")
    if not snapshot.matches:
        add("  (none)")
    for match in snapshot.matches:
        add(f"  {cut(match.topic)}: {cut(match.writer_participant)} -> {cut(match.reader_participant)}")
        for hint in match.hints:
            add(f"    hint: {hint}")

    add("")
    add("Mismatches")
    if not snapshot.mismatches:
        add("  (none)")
    for mismatch in snapshot.mismatches:
        writer = snapshot.participant(names[mismatch.writer].participant) if mismatch.writer in names else None
        reader = snapshot.participant(names[mismatch.reader].participant) if mismatch.reader in names else None
        add(f"  {cut(mismatch.topic)}: writer {cut(mismatch.writer_participant)}"
            f"{f' ({writer.vendor})' if writer else ''} -> reader {cut(mismatch.reader_participant)}"
            f"{f' ({reader.vendor})' if reader else ''}")
        for reason in mismatch.reasons:
            add(f"    {cut(reason.words, MESSAGE_WIDTH)}")
        for hint in mismatch.hints:
            add(f"    hint: {hint}")

    add("")
    add("Notices")
    if not snapshot.notices:
        add("  (none)")
    for notice in snapshot.notices:
        add(f"  {cut(notice.words, MESSAGE_WIDTH)}")

    add("")
    add("Flows (from the programs' /diagnostics and the monitor's own readers)")
    if not snapshot.flows:
        add("  (no program reports on rt/diagnostics)")
    for flow in snapshot.flows:
        age = "never seen moving" if flow.last_sample_age_s is None else f"last sample {flow.last_sample_age_s:g} s ago"
        readers = ", ".join(f"{cut(name)} {rate:g}/s" for name, rate in flow.readers.items()) or "none"
        size = "" if flow.bytes_per_s is None else f", {byte_rate(flow.bytes_per_s)}"
        add(f"  {cut(flow.topic)}: {flow.rate:g} samples/s{size}, {age}; read by {readers}; "
            f"deadline missed {flow.deadline_missed}, liveliness changes {flow.liveliness_changes}, "
            f"samples lost {flow.samples_lost}, incompatible QoS {flow.incompatible_qos}")

    add("")
    add("Latency (reception minus the writer's source timestamp, over the last 10 s, as each reader measures it)")
    if not any(flow.latency for flow in snapshot.flows):
        add("  (no program reports a latency)")
    for flow in snapshot.flows:
        for reader_name, figure in flow.latency.items():
            add(f"  {cut(flow.topic)} read by {cut(reader_name)}: "
                f"{latency_words(figure['p50_ms'], figure['p99_ms'], figure['clock'])}, {figure['samples']} samples")
    if snapshot.latencies:
        add("  per pair (writer -> reader):")
    for pair in snapshot.latencies:
        add(f"    {cut(pair.topic)}: {cut(pair.writer)} -> {cut(pair.reader)}: "
            f"{latency_words(pair.p50_ms, pair.p99_ms, pair.clock)}, {pair.samples} samples")
    if snapshot.chain is not None:
        chain = snapshot.chain
        hops = ", ".join(f"{hop.topic} " + ("unknown" if hop.latency is None else
                                            latency_words(hop.latency.p50_ms, hop.latency.p99_ms, hop.latency.clock))
                         for hop in chain.hops)
        total = ("unknown (no hop reports)" if chain.p50_ms is None or chain.p99_ms is None
                 else latency_words(chain.p50_ms, chain.p99_ms, chain.clock))
        if chain.missing and chain.p50_ms is not None:
            total += f", without {', '.join(chain.missing)} (no sample in the last 10 s)"
        add(f"  alert chain vision -> hmi: {total}")
        add(f"    hops: {hops}")
        add(f"    ({chain.basis})")

    add("")
    add("Vehicle")
    lines.extend(f"  {line}" for line in vehicle_lines(snapshot.vehicle))

    add("")
    add("Programs (/diagnostics)")
    if not snapshot.programs:
        add("  (none reports)")
    for program in snapshot.programs:
        add(f"  {cut(program.name)}: {program.level} ({cut(program.host)}, {program.report_age_s:g} s ago): "
            f"{cut(program.message, MESSAGE_WIDTH)}")
    return "\n".join(lines) + "\n"


def latency_words(p50_ms: float, p99_ms: float, clock: str) -> str:
    """``p50 1.23 ms, p99 4.56 ms``; marked ``~`` with why when writer and reader do not share a clock."""
    if clock == CLOCK_SHARED:
        return f"p50 {p50_ms:.3g} ms, p99 {p99_ms:.3g} ms"
    why = "clock not shared: another host" if clock == CLOCK_NOT_SHARED else "a host not known: clock may not be shared"
    return f"p50 ~{p50_ms:.3g} ms, p99 ~{p99_ms:.3g} ms ({why})"


def byte_rate(per_s: float) -> str:
    for unit, size in (("MB/s", 1e6), ("kB/s", 1e3)):
        if per_s >= size:
            return f"{per_s / size:.3g} {unit}"
    return f"{per_s:.3g} B/s"


def _number(value: float | None, unit: str = "", digits: str = ".1f") -> str:
    return "unknown" if value is None else f"{value:{digits}}{unit}"


def vehicle_lines(vehicle: Vehicle) -> list[str]:
    """The vehicle in a few lines: the alert (and its owner), the platform, the fused objects and LiDAR, the camera."""
    if vehicle.alert is None:
        alert = "alert: unknown (no alert state taken)"
    elif vehicle.alert_texts:
        alert = "alert: DRIVER ALERT: " + "; ".join(cut(text) for text in vehicle.alert_texts)
    else:
        alert = "alert: all clear"
    if vehicle.redundant:
        strength = "" if vehicle.alert_owner_strength is None else f", strength {vehicle.alert_owner_strength}"
        alert += f" (redundant mode: owner {cut(vehicle.alert_owner)}{strength})"
    platform = (f"speed {_number(vehicle.speed_kmh, ' km/h')}, steer {_number(vehicle.steer_angle, '', '.2f')}, "
                f"blinker {vehicle.blinker or 'unknown'}")
    if vehicle.command_age_s is not None:
        platform += (f"; command: speed {_number(vehicle.command_speed)}, steer "
                     f"{_number(vehicle.command_steer_angle, '', '.2f')}, "
                     f"blinker {vehicle.command_blinker or 'unknown'}")
    objects = (f"fused objects: {'unknown' if vehicle.fused_objects is None else vehicle.fused_objects}; LiDAR: "
               + ("no cloud taken" if vehicle.lidar_age_s is None else
                  f"{'unknown' if vehicle.lidar_points is None else vehicle.lidar_points} points, "
                  f"{vehicle.lidar_age_s:g} s ago"))
    camera = ("camera: unknown (no camera_sub reports)" if vehicle.camera_program is None else
              f"camera: {_number(vehicle.camera_rate, ' frames/s')}, latency p50 "
              f"{_number(vehicle.camera_latency_ms, ' ms')} ({cut(vehicle.camera_program)})")
    return [alert, platform, objects, camera]
