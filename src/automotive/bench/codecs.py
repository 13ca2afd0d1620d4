"""The generated codecs against Cyclone DDS Python's serializer, type by type in the same run; sensor fusion's CPU.

    automotive bench codecs                       every type, then sensor fusion with 50 sensors (8 s, twice)
    automotive bench codecs --no-fusion           the codecs only
    automotive bench codecs --fusion-modes periodic,event --sensors 50 --window 8

Codecs: one sample of every struct type of the IDL (the topic types at the sizes they travel at), serialized and
deserialized through Cyclone's own API (sample.serialize(), Type.deserialize()) once with Cyclone's serializer as the
applications had it (with automotive.cyclone.fastpath) and once with the codecs plugged in
(automotive.cyclone.codec_hook; the octet-block types, which keep the fast path, through their codec directly). Each
figure is the best mean over 5 runs (the least disturbed on a busy machine), in microseconds; x = Cyclone's
(serialize + deserialize) / the codec's, for XCDR1 (what the writers write) and XCDR2. SensorObjectList with 128
objects is also timed into numpy views (serialize from a structured array, deserialize with views=True).

Sensor fusion: sensor_fusion (the real application, default properties, on loopback) fed by this process writing the
shipped vision rows for --sensors sensor ids at 10 Hz each; its CPU (user + system, all threads, psutil) over
--window seconds divided by the vision samples written: with the codecs, and with AUTOMOTIVE_CODECS=off (Cyclone's
serializer) side by side.

Targets: SensorObjectList(128) serialize + deserialize into dataclasses <= 350 us and >= 10x Cyclone's,
into numpy views <= 30 us; every other type >= 5x; sensor fusion <= 50 us of CPU per vision sample. The last line is
codec_speedup_min=<x> sol128_us=<y> sol128_view_us=<z> fusion_us_per_sample=<w>. The fusion target is judged over
at least 2,000 vision samples (--sensors x 10 x --window): CPU time counts in ticks of 10 ms; fewer print the figure
and "too short to judge".
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from automotive import config
from automotive.bench import ddsperf
from automotive.bus.cli import ArgumentParser, add_domain_option
from automotive.bus.clock import now_timestamp
from automotive.bus.endpoints import Databus
from automotive.bus.network import NetworkConfig
from automotive.bus.qos import QosProfiles
from automotive.cyclone import codec_hook, codecgen, fastpath, gate
from automotive.cyclone.bounds import type_name
from automotive.cyclone.codecs import codecs
from automotive.cyclone.matched import matched_subscriptions
from automotive.sim.csvdata import load_vision_rows
from automotive.tools.support.children import Child, program_command, thread_cpu_by_name
from automotive.types.Vision import VisionSensor

PROG = "automotive bench codecs"
# Sequence lengths of the samples timed (others: 8; strings: 12 characters)
LENGTHS = {("SensorObjectList", "objects"): 128, ("VisionSensor", "objects"): 10, ("PCloud", "Location"): 1000,
           ("PointCloud2_", "data_"): 184_320, ("PointCloud2_", "fields_"): 4}
TARGET_SOL128_US, TARGET_SOL128_X, TARGET_VIEW_US, TARGET_OTHER_X, TARGET_FUSION_US = 350, 10, 30, 5, 50
# A process's CPU time counts in clock ticks (10 ms): the fusion target is judged over enough vision samples that a
# tick is at most a tenth of the target per sample (2,000 of them: 50 sensors x 10 Hz x 4 s); fewer say too little.
MIN_FUSION_SAMPLES = math.ceil(1_000_000 / os.sysconf("SC_CLK_TCK") / (TARGET_FUSION_US / 10))


def example(model: codecgen.Model, lengths: dict[tuple[str, str], int]) -> Any:
    """A deterministic sample of a type, with non-trivial values everywhere."""

    def value(node: Any, owner: str, member: str, index: int) -> Any:
        length = lengths.get((owner, member), 8)
        if isinstance(node, codecgen.Prim):
            return {"?": index % 2 == 0, "f": 1.5 + index, "d": 2.25 + index}.get(node.code, index % 100 + 1)
        if isinstance(node, codecgen.EnumNode):
            members: list[Any] = list(node.cls)  # type: ignore[call-overload]
            return members[index % len(members)]
        if isinstance(node, codecgen.Str):
            return "frame_id_map"[: node.bound or 12]
        if isinstance(node, codecgen.OctetArray):
            return bytes(range(256)) * (node.length // 256) + bytes(node.length % 256)
        if isinstance(node, codecgen.OctetSeq):
            return bytes(i % 251 for i in range(min(length, node.bound or length)))
        if isinstance(node, codecgen.PrimArray):
            return [value(node.prim, owner, member, index + i) for i in range(node.length)]
        if isinstance(node, codecgen.PrimSeq):
            return [value(node.prim, owner, member, index + i) for i in range(min(length, node.bound or length))]
        if isinstance(node, codecgen.StructNode):
            return struct(node.model, index)
        if isinstance(node, codecgen.StructArray):
            return [struct(node.model, index + i) for i in range(node.length)]
        if isinstance(node, codecgen.StructSeq):
            return [struct(node.model, index + i) for i in range(min(length, node.bound or length))]
        raise AssertionError(node)

    def struct(inner: codecgen.Model, index: int) -> Any:
        return inner.cls(**{name: value(node, inner.cls.__name__, name, index + i)
                            for i, (name, node) in enumerate(inner.members)})

    return struct(model, 0)


def best_us(action: Callable[[], Any], runs: int = 5) -> float:
    """The best mean time of ``action`` over ``runs`` runs of about 40 ms each, in microseconds."""
    start = time.perf_counter()
    action()
    once = max(time.perf_counter() - start, 1e-7)
    number = max(1, min(5000, int(0.04 / once)))
    best = float("inf")
    for _ in range(runs):
        start = time.perf_counter()
        for _ in range(number):
            action()
        best = min(best, (time.perf_counter() - start) / number)
    return best * 1e6


def time_type(sample: Any, xcdr2: bool) -> tuple[float, float, float, float]:
    """(Cyclone serialize, Cyclone deserialize, codec serialize, codec deserialize) in us."""
    data_type = type(sample)
    codec = codecs()[data_type]
    codec_hook.disable()
    data = sample.serialize(use_version_2=xcdr2)
    cyclone = best_us(lambda: sample.serialize(use_version_2=xcdr2)), best_us(lambda: data_type.deserialize(data))
    codec_hook.enable()
    if codec_hook.installed(data_type):  # what writers and readers get: Cyclone's API, through the hook
        assert sample.serialize(use_version_2=xcdr2) == data
        ours = best_us(lambda: sample.serialize(use_version_2=xcdr2)), best_us(lambda: data_type.deserialize(data))
    else:  # an octet-block type (automotive.fastpath in the applications): the codec itself
        assert codec.encode(sample, xcdr2) == data
        ours = best_us(lambda: codec.encode(sample, xcdr2)), best_us(lambda: codec.decode(data))
    return cyclone[0], cyclone[1], ours[0], ours[1]


def codec_table() -> tuple[float, str, float, float, bool]:
    """Print the table; return (smallest speedup of the other types, which type, SensorObjectList(128) us, its view
    us, every target met)."""
    models = codecgen.Models()
    types = sorted(codecs(), key=lambda cls: (not _is_topic_type(cls), type_name(cls)))
    print(f"{'type':34} {'bytes':>7} | {'Cyclone ser':>11} {'deser':>9} | {'codec ser':>9} {'deser':>8} | "
          f"{'x XCDR1':>7} {'x XCDR2':>7}   (us, best of 5)")
    results: dict[str, tuple[float, float]] = {}
    octet_block_types = {type_name(cls) for cls, codec in codecs().items() if codec.has_octet_blocks}
    sol128 = (0.0, 0.0)
    for data_type in types:
        sample = example(models.model(data_type), LENGTHS)
        name = type_name(data_type)
        v1 = time_type(sample, False)
        v2 = time_type(sample, True)
        x1, x2 = (v1[0] + v1[1]) / (v1[2] + v1[3]), (v2[0] + v2[1]) / (v2[2] + v2[3])
        size = len(sample.serialize(use_version_2=False))
        note = "" if codec_hook.installed(data_type) else "  (octet blocks: fastpath in the applications)"
        print(f"{name:34} {size:>7} | {v1[0]:>11.1f} {v1[1]:>9.1f} | {v1[2]:>9.1f} {v1[3]:>8.1f} | {x1:>7.1f} "
              f"{x2:>7.1f}{note}", flush=True)
        results[name] = (x1, x2)
        if data_type.__name__ == "SensorObjectList":
            sol128 = (v1[2] + v1[3], x1)
    view_us = time_view(models)
    small = example(models.model(next(t for t in types if t.__name__ == "SensorObjectList")),
                    {("SensorObjectList", "objects"): 2})
    s2 = time_type(small, False)
    print(f"{'Sensor::SensorObjectList (2 objects)':34} {len(small.serialize(use_version_2=False)):>7} | "
          f"{s2[0]:>11.1f} {s2[1]:>9.1f} | {s2[2]:>9.1f} {s2[3]:>8.1f} | {(s2[0] + s2[1]) / (s2[2] + s2[3]):>7.1f}")
    print(f"{'Sensor::SensorObjectList (128) numpy':34} {'':>7} | {'':>11} {'':>9} | {view_us[0]:>9.1f} "
          f"{view_us[1]:>8.1f} |   serialize from a structured array, deserialize with views=True")
    # The octet-block types keep automotive.cyclone.fastpath in the applications: shown, not part of the target.
    others = {name: min(x) for name, x in results.items() if name != "Sensor::SensorObjectList"
              and name not in octet_block_types}
    worst = min(others, key=lambda name: others[name])
    met = [sol128[0] <= TARGET_SOL128_US and sol128[1] >= TARGET_SOL128_X, sum(view_us) <= TARGET_VIEW_US,
           others[worst] >= TARGET_OTHER_X]
    print()
    print(f"target SensorObjectList(128) into dataclasses: {sol128[0]:.0f} us (<= {TARGET_SOL128_US}), "
          f"x{sol128[1]:.1f} (>= {TARGET_SOL128_X}): {'met' if met[0] else 'NOT MET'}")
    print(f"target SensorObjectList(128) into numpy views: {sum(view_us):.1f} us (<= {TARGET_VIEW_US}): "
          f"{'met' if met[1] else 'NOT MET'}")
    print(f"target every other type (not the octet-block ones) >= {TARGET_OTHER_X}x: smallest x{others[worst]:.1f} "
          f"({worst}): "
          f"{'met' if met[2] else 'NOT MET'}")
    return others[worst], worst, sol128[0], sum(view_us), all(met)


def _is_topic_type(cls: type) -> bool:
    return cls.__name__ in ("VisionSensor", "SensorObjectList", "PlatformControl", "PlatformStatus", "DriverAlerts",
                            "PointCloud2_", "CameraImageData", "ShapeType")


def time_view(models: codecgen.Models) -> tuple[float, float]:
    sol = next(cls for cls in codecs() if cls.__name__ == "SensorObjectList")
    codec = codecs()[sol]
    sample = example(models.model(sol), LENGTHS)
    data = codec.encode(sample, False)
    viewed = codec.decode(data, views=True)
    array = np.array(viewed.objects)  # a structured array of its own, as a producer would hold it
    as_array = sol(timestamp=sample.timestamp, objects=array)
    assert codec.encode(as_array, False) == data
    return best_us(lambda: codec.encode(as_array, False)), best_us(lambda: codec.decode(data, views=True))


# --- sensor fusion's CPU ---------------------------------------------------------------------------------------------

def vision_rows() -> list[Any]:
    """The shipped vision data, a list of objects per row."""
    return load_vision_rows(config.properties_dir() / "data" / "vision.csv")


@dataclass
class FusionCpu:
    """Sensor fusion's CPU per vision sample (us): in all, and by thread name; the samples written in the window."""

    us_per_sample: float
    samples: int
    threads: dict[str, float]  # per vision sample, us
    python_thread_name: str  # what Linux calls the Python threads of the process (its program's name)

    def python_us(self) -> float:
        return self.threads.get(self.python_thread_name, 0.0)

    def cyclone_us(self) -> float:
        return sum(us for name, us in self.threads.items() if name != self.python_thread_name)


def describe_threads(threads: dict[str, float], leave_out: str = "") -> str:
    """'recv 40.1, tev 2.0': the threads that used a tenth of a microsecond a sample or more, the busiest first."""
    shown = sorted(((us, name) for name, us in threads.items() if name != leave_out and us >= 0.1), reverse=True)
    return ", ".join(f"{name} {us:.1f}" for us, name in shown)


def fusion_verdict(us_per_sample: float, samples: int) -> str:
    """The fusion target's verdict on a figure taken over ``samples`` vision samples."""
    if samples < MIN_FUSION_SAMPLES:
        return f"too short to judge: the target needs at least {MIN_FUSION_SAMPLES:,} vision samples (this run: " \
               f"{samples:,})"
    return "met" if us_per_sample <= TARGET_FUSION_US else "NOT MET"


def fusion_cpu(mode: str, codecs_on: bool, sensors: int, window: float, domain: int) -> FusionCpu:
    """Sensor fusion's CPU per vision sample, in all and by thread."""
    env = dict(os.environ, CYCLONEDDS_URI=NetworkConfig().cyclone_xml(),
               AUTOMOTIVE_CODECS="on" if codecs_on else "off")
    fusion = Child("sensor_fusion", program_command("sensor_fusion", "--domain", str(domain), "-D",
                                                    f"config.mode={mode}", "-D", "config.matchReport=0"), env=env)
    bus = Databus(domain, QosProfiles(config.qos_file()), "AutomotiveLibrary", logging.getLogger(PROG),
                  NetworkConfig())
    try:
        writer = bus.writer("VisionTopic", VisionSensor, "Vision")
        rows = vision_rows()
        deadline = time.monotonic() + 60
        while not matched_subscriptions(writer):
            if fusion.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"sensor_fusion did not match: {fusion.output[-2000:]}")
            time.sleep(0.05)  # polling the match, bounded
        period = 1.0 / (sensors * 10)
        written, start_cpu, start_written, start_threads = 0, 0.0, 0, {}
        python_thread_name = Path(f"/proc/{fusion.pid}/comm").read_text().strip()
        begin = time.monotonic()
        measuring_since = None
        next_write = begin
        while True:
            now = time.monotonic()
            if measuring_since is None and now - begin >= 2.0:  # 2 s to settle
                measuring_since, start_cpu, start_written = now, fusion.cpu_seconds(), written
                start_threads = thread_cpu_by_name([fusion.pid])
            if measuring_since is not None and now - measuring_since >= window:
                break
            row = rows[(written // sensors) % len(rows)]
            writer.write(VisionSensor(id=1 + written % sensors, timestamp=now_timestamp(), objects=row))
            written += 1
            next_write += period
            delay = next_write - time.monotonic()
            if delay > 0:
                time.sleep(delay)  # pacing the writes, not synchronisation
        used = fusion.cpu_seconds() - start_cpu
        threads = thread_cpu_by_name([fusion.pid])
        count = written - start_written
    finally:
        fusion.stop(timeout=30)
        bus.close()
    per_thread = {name: 1e6 * (seconds - start_threads.get(name, 0.0)) / count for name, seconds in threads.items()}
    return FusionCpu(1e6 * used / count, count, per_thread, python_thread_name)


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--no-fusion", action="store_true", help="time the codecs only")
    parser.add_argument("--fusion-modes", default="periodic", help="sensor fusion modes to measure (default periodic)")
    parser.add_argument("--sensors", type=int, default=50, help="vision sensor ids, 10 Hz each (default 50)")
    parser.add_argument("--window", type=float, default=8.0, help="seconds of fusion CPU measured (default 8)")
    add_domain_option(parser, 89, "DDS domain id")
    args = parser.parse_args(argv)
    modes = [mode for mode in args.fusion_modes.split(",") if mode]
    if any(mode not in ("periodic", "event") for mode in modes) or args.sensors < 1 or args.window <= 0:
        print(f"{PROG}: --fusion-modes takes periodic and/or event; --sensors and --window must be positive",
              file=sys.stderr)
        return 2
    if gate.why_off() is not None:
        print(f"{PROG}: the fast paths are off ({gate.why_off()}): nothing to compare", file=sys.stderr)
        return 1
    fastpath.enable()
    if not codec_hook.enable():
        print(f"{PROG}: the codecs cannot be plugged into this Cyclone DDS (see the warning above)",
              file=sys.stderr)
        return 1
    print(f"codecs against Cyclone DDS Python's serializer, {os.cpu_count()} CPU(s), load average "
          f"{os.getloadavg()[0]:.1f}")
    speedup, worst, sol128, view, met = codec_table()
    fusion_us = float("nan")
    if not args.no_fusion:
        print()
        print(f"sensor fusion, {args.sensors} vision sensors x 10 Hz, CPU per vision sample (all its threads), "
              f"{args.window:g} s")
        profile: FusionCpu | None = None
        for mode in modes:
            results = {}
            for on in (False, True):
                print(f"  {mode}, {'codecs' if on else 'Cyclone serializer'} ...", file=sys.stderr, flush=True)
                results[on] = fusion_cpu(mode, on, args.sensors, args.window, args.domain)
            print(f"  {mode:9} Cyclone's serializer {results[False].us_per_sample:6.1f} us   codecs "
                  f"{results[True].us_per_sample:6.1f} us   ({results[True].samples} samples)")
            codecs_on = results[True]
            cyclone_threads = describe_threads(codecs_on.threads, codecs_on.python_thread_name)
            print(f"  {'':9} with the codecs, by thread: Python {codecs_on.python_us():.1f} us; Cyclone's threads "
                  f"{codecs_on.cyclone_us():.1f} us ({cyclone_threads})")
            if mode == modes[0]:
                profile = codecs_on
        # The floor that is Cyclone's alone: its C subscriber taking the same rate of samples of the same size.
        size = len(VisionSensor(id=1, timestamp=now_timestamp(), objects=vision_rows()[0]).serialize())
        c_sub = ddsperf.subscriber_cpu(size, args.sensors * 10, args.window, args.domain)
        if c_sub is not None:
            print(f"  Cyclone's C subscriber (ddsperf sub, WaitSet) taking {args.sensors * 10} samples/s of {size} "
                  f"bytes: {sum(c_sub.values()):.1f} us a sample ({describe_threads(c_sub)})")
        fusion_us = profile.us_per_sample if profile is not None else float("nan")
        samples = profile.samples if profile is not None else 0
        ok = fusion_us <= TARGET_FUSION_US
        met = met and ok
        print(f"target sensor fusion <= {TARGET_FUSION_US} us of CPU per vision sample ({modes[0]}): "
              f"{fusion_us:.1f} us: {fusion_verdict(fusion_us, samples)}")
        if not ok and samples >= MIN_FUSION_SAMPLES and profile is not None:
            print(f"  why: its Python threads take {profile.python_us():.1f} us of it, Cyclone's own threads "
                  f"{profile.cyclone_us():.1f} us (receiving, acknowledging, storing the samples)"
                  + (f"; Cyclone's C subscriber alone takes {sum(c_sub.values()):.1f} us" if c_sub is not None
                     else ""))
    print(f"codec_speedup_min={speedup:.1f} sol128_us={sol128:.0f} sol128_view_us={view:.1f} "
          f"fusion_us_per_sample={fusion_us:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
