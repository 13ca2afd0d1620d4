"""The site bridge (automotive zenoh-bridge) against direct DDS: throughput and latency of every flow, and of 4 MiB
frames.

    automotive bench zenoh [--seconds 20] [--scenarios direct,loopback,shaped] [--domain 90] [--log-dir DIR]

Three set-ups, one after the other, each in two phases:

- ``direct``: every application on one DDS domain (loopback), no bridge;
- ``loopback``: site A (vision, lidar, sensor_fusion, vehicle_platform) on one DDS domain, site B
  (collision_avoidance, hmi) on another, on this host, joined only by two bridges over mutual TLS on 127.0.0.1;
- ``shaped``: the same two sites in network namespaces joined by a veth pair shaped to 25 ms delay, 0.5 % loss and
  20 Mbit/s each way (tc netem, or where the kernel has none tc tbf, nftables and a delaying relay,
  python -m automotive.tools.support.delay_relay); needs root, skipped otherwise.

Phase 1, the system's flows at their own rates: a probe on each site reads every flow for --seconds and records,
for the flows written on the other site (every flow, in ``direct``), samples/s, MB/s and the latency (reception time
minus the writer's source timestamp, which the bridge carries; one host, one clock). Phase 2, 4 MiB camera frames
as fast as flow control allows from camera_pub on A to camera_sub on B (which verifies every byte): frames/s, MB/s,
latency p50/p99, frames missing, from camera_sub's ``totals`` record. Every figure comes from the programs' --stats
JSON lines (automotive.bus.stats), never from their log text. The bridges run without budgets
(``bridge.maxFrequency=``), so that the figures are the link's and the bridge's, not a budget's; on the shaped link,
which cannot carry the LiDAR's 29.5 Mbit/s, they keep the shipped LiDAR budget of 2 Hz. Every process stays on
loopback or inside the benchmark's namespaces (named with this process's pid, deleted at the end); Zenoh scouts
nothing.

Prints a table; the last line is ``zenoh_ratio_4MiB=<bridge over loopback / direct, MB/s of 4 MiB frames>``.
Figures taken on a machine shared with other work are provisional.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from automotive.bus import stats
from automotive.bus.cli import ArgumentParser, add_domain_option, add_log_dir_option, output_folder_problem
from automotive.bus.latency import percentile
from automotive.bus.network import NetworkConfig
from automotive.tools.support import netlab
from automotive.tools.support.children import Child, RunFailed, StatsChild, program_command, work_folder
from automotive.tools.zenoh.zenoh_certs import CertificateError
from automotive.tools.zenoh.zenoh_certs import make as make_certificates

PROG = "automotive bench zenoh"
MODULE = "automotive.bench.zenoh_bridge"
START_TIMEOUT = 120.0
SCENARIOS = ("direct", "loopback", "shaped")
SITE_A_APPS = ("vehicle_platform", "sensor_fusion", "vision", "lidar")
SITE_B_APPS = ("collision_avoidance", "hmi")
WRITTEN_ON_A = ("VisionTopic", "rt/LidarTopic", "SensorObjects", "PlatformStatus")
WRITTEN_ON_B = ("AlertTopic", "PlatformControl")
PORT = 7447
ADDRESS_A, ADDRESS_B = "10.235.0.1", "10.235.0.2"  # the shaped link, only inside the benchmark's namespaces
DELAY_MS, LOSS_PER_MILLE, RATE = 25, 5, "20mbit"
RELAY_PORT = 17447
# The shaped link carries 20 Mbit/s; the LiDAR alone writes 29.5 Mbit/s (20 clouds of 184 KB a second), so there the
# bridges keep the shipped LiDAR budget (2 Hz): without it the link is over-subscribed and every flow from A waits
# in the link's queue (about 0.6 s measured).
SHAPED_BUDGET = "rt/LidarTopic=2"


@dataclass
class Row:
    scenario: str
    flow: str
    samples_per_s: float = float("nan")
    mb_per_s: float = float("nan")
    p50_ms: float | None = None
    p99_ms: float | None = None
    lost: str = ""
    note: str = ""


@dataclass
class Setup:
    """Where each site runs: a command prefix (ip netns exec ...), a DDS domain, and how B's bridge reaches A's."""

    scenario: str
    prefix_a: list[str]
    prefix_b: list[str]
    domain_a: int
    domain_b: int
    listen_a: str = ""
    connect_b: str = ""
    processes: list[StatsChild] = field(default_factory=list)

    def start(self, site: str, name: str, command: Sequence[str], env: dict[str, str], log_dir: Path) -> StatsChild:
        """A child on a site (``command`` without the site's prefix) writing its records to ``--stats``."""
        label = f"{self.scenario}-{name}"
        records = log_dir / f"{label}.jsonl"
        prefix = self.prefix_a if site == "a" else self.prefix_b
        process = StatsChild(Child(label, [*prefix, *command, "--stats", str(records)], env=env), records)
        self.processes.append(process)
        return process

    def stop_all(self, log_dir: Path) -> None:
        for process in reversed(self.processes):
            process.child.stop(signal.SIGINT, timeout=30)
            (log_dir / f"{process.child.name}.log").write_text("".join(f"{line.text}\n"
                                                                       for line in process.child.records))
        self.processes.clear()


# -- the probe (a child process): every flow of one site, counted and timed ---------------------------------------

def probe(domain: int, seconds: float, records: Path) -> int:
    """Read every flow but the camera for ``seconds``; record per topic count, bytes and latencies (``flows``)."""
    import logging

    from cyclonedds.qos import Policy

    from automotive import config
    from automotive.bus.app import DEFAULT_LIBRARY
    from automotive.bus.endpoints import Databus
    from automotive.bus.qos import QosProfiles
    from automotive.tools.flows import system_flows
    from automotive.wire.rawsample import RawReader, SampleKind

    log = logging.getLogger("probe")
    figures = stats.Stats(records, "probe")
    bus = Databus(domain, QosProfiles(config.qos_file()), DEFAULT_LIBRARY, log, None, "probe", figures)
    flows = [flow for flow in system_flows() if flow.topic not in ("CameraImageData", "Circle")]
    readers = [(flow.topic, RawReader(bus.reader(flow.topic, flow.data_type, flow.profile,
                                                 overrides=(Policy.History.KeepLast(64),)), zero_copy=False))
               for flow in flows]
    results: dict[str, dict[str, Any]] = {flow.topic: {"count": 0, "bytes": 0, "latencies_ms": []} for flow in flows}
    figures.record("ready")
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        for topic, reader in readers:
            for sample, receive_ns in reader.drain(64):
                if sample.kind is not SampleKind.DATA:
                    continue
                entry = results[topic]
                entry["count"] += 1
                entry["bytes"] += len(sample.data)
                entry["latencies_ms"].append((receive_ns - sample.source_timestamp) / 1e6)
        time.sleep(0.002)  # polling keeps the probe simple; 2 ms is far below every flow's period
    figures.record("flows", seconds=seconds, topics=results)
    bus.close()
    figures.close()
    return 0


def probe_command(domain: int, seconds: float) -> list[str]:
    return [sys.executable, "-m", MODULE, "--probe", str(domain), "--seconds", str(seconds)]


# -- set-ups ----------------------------------------------------------------------------------------------------

class ShapedLink:
    """Sites A and B in two namespaces joined by a shaped veth pair (made by open(), deleted by close())."""

    def __init__(self, env: dict[str, str]) -> None:
        self.env = env
        self.namespaces: list[netlab.Namespace] = []
        self.relay: Child | None = None
        self.connect_b = f"{ADDRESS_A}:{PORT}"
        self.how = ""

    def open(self) -> tuple[netlab.Namespace, netlab.Namespace]:
        suffix = os.getpid()
        a = netlab.Namespace(f"zbench-a-{suffix}")
        self.namespaces.append(a)
        b = netlab.Namespace(f"zbench-b-{suffix}")
        self.namespaces.append(b)
        netlab.veth(a, "veth-ab", ADDRESS_A, b, "veth-ba", ADDRESS_B)
        if netlab.shape([(a, "veth-ab"), (b, "veth-ba")], DELAY_MS, LOSS_PER_MILLE, RATE):
            self.how = "tc netem"
            return a, b
        self.relay = Child("delay_relay", program_command("delay_relay", "--listen", f"127.0.0.1:{RELAY_PORT}",
                                                          "--target", f"{ADDRESS_A}:{PORT}", "--delay-ms",
                                                          str(DELAY_MS), python=b.prefix), env=self.env)
        try:
            self.relay.wait_for(r"^relay ready$", timeout=60)
        except AssertionError as error:
            raise RunFailed(f"the delaying relay did not start: {str(error).splitlines()[0]}") from None
        self.connect_b = f"127.0.0.1:{RELAY_PORT}"
        self.how = "tc tbf (rate), nftables (loss), a delaying relay (python -m automotive.tools.support.delay_relay)"
        return a, b

    def close(self) -> None:
        if self.relay is not None:
            self.relay.stop()
        for namespace in self.namespaces:
            namespace.delete()


def bridge_command(site: str, domain: int, certs: Path, listen: str, connect: str, budget: str = "") -> list[str]:
    link = (["-D", "zenoh.mode=router", "-D", f"zenoh.listen=tls/{listen}", "-D", "zenoh.connect="] if listen else
            ["-D", "zenoh.mode=peer", "-D", "zenoh.listen=", "-D", f"zenoh.connect=tls/{connect}"])
    return program_command("zenoh_bridge", "--domain", str(domain), "-D", f"zenoh.site={site}", *link,
                           "-D", f"zenoh.tls.ca={certs}/ca.pem", "-D", f"zenoh.tls.certificate={certs}/{site}.pem",
                           "-D", f"zenoh.tls.key={certs}/{site}.key", "-D", f"bridge.maxFrequency={budget}")


def run_setup(setup: Setup, seconds: float, certs: Path, env: dict[str, str], log_dir: Path) -> list[Row]:
    rows: list[Row] = []
    bridged = setup.scenario != "direct"
    try:
        if bridged:
            budget = SHAPED_BUDGET if setup.scenario == "shaped" else ""
            setup.start("a", "bridge-a", bridge_command("site-a", setup.domain_a, certs, setup.listen_a, "", budget),
                        env, log_dir)
            setup.start("b", "bridge-b", bridge_command("site-b", setup.domain_b, certs, "", setup.connect_b, budget),
                        env, log_dir)
        system: dict[str, StatsChild] = {}
        for site, names in (("a", SITE_A_APPS), ("b", SITE_B_APPS)):
            domain = setup.domain_a if site == "a" else setup.domain_b
            for name in names:
                extra = ["-D", "config.alertSize=1.0"] if name == "collision_avoidance" else \
                    ["--ui", "console"] if name == "hmi" else []
                system[name] = setup.start(site, name, program_command(name, "--domain", str(domain), *extra),
                                           env, log_dir)
        # the loop runs: A's objects to B, B's commands to A
        system["vehicle_platform"].wait_record("command", START_TIMEOUT)
        probes = {site: setup.start(site, f"probe-{site}",
                                    probe_command(setup.domain_a if site == "a" else setup.domain_b, seconds),
                                    env, log_dir)
                  for site in (("a",) if not bridged else ("a", "b"))}
        results = {site: process.wait_record("flows", seconds + START_TIMEOUT) for site, process in probes.items()}
        for process in system.values():
            process.child.stop(signal.SIGINT, timeout=30)
        for topic in (*WRITTEN_ON_A, *WRITTEN_ON_B):
            site = "a" if not bridged else ("b" if topic in WRITTEN_ON_A else "a")
            entry = results[site]["topics"][topic]
            latencies = entry["latencies_ms"]
            rows.append(Row(setup.scenario, topic, entry["count"] / seconds, entry["bytes"] / seconds / 1e6,
                            percentile(latencies, 0.5), percentile(latencies, 0.99)))
        rows.append(run_camera(setup, seconds, env, log_dir))
    except RunFailed as error:
        rows.append(Row(setup.scenario, "-", note=str(error).splitlines()[0]))
    finally:
        setup.stop_all(log_dir)
    return rows


def run_camera(setup: Setup, seconds: float, env: dict[str, str], log_dir: Path) -> Row:
    common = ["-D", "config.imageSize=full"]  # the system's camera flow (the bridges bridge that type)
    sub = setup.start("b", "camera_sub", program_command("camera_sub", "--domain", str(setup.domain_b), *common,
                                                         "--exit-with-publisher"), env, log_dir)
    sub.wait_record("ready", START_TIMEOUT)
    pub = setup.start("a", "camera_pub", program_command("camera_pub", "--domain", str(setup.domain_a), *common,
                                                         "-D", "config.pubInterval=0"), env, log_dir)
    sub.wait_record("window", START_TIMEOUT)  # frames arrive
    time.sleep(seconds)  # the measured window
    pub.child.stop(signal.SIGINT, timeout=30)
    # camera_sub records its totals as it stops (across a bridge, the bridge's writer does not leave): its rate is
    # frames received over the time from the first to the last (it reports a second only when frames came in it,
    # so an average of its once-a-second records would overstate a slow link)
    sub.child.stop(signal.SIGINT, timeout=30)
    totals = next(iter(sub.records("totals")), None)
    if totals is None:
        raise RunFailed("camera_sub wrote no totals")
    latency = totals["latency_ms"]
    return Row(setup.scenario, "CameraImageData 4 MiB, as fast as possible", float(totals["samples_per_s"]),
               float(totals["mb_per_s"]), latency["p50"], latency["p99"], f"{totals['gaps']} missing")


def fmt(value: float | None, digits: int = 1) -> str:
    return "-" if value is None or value != value else f"{value:.{digits}f}"


def measure(args: argparse.Namespace, scenarios: list[str], log_dir: Path, certs: Path) -> int:
    # Loopback only, with the large-data settings the camera pair and the bridge use (62 KB fragments, large socket
    # buffers): the same for direct DDS and for each site's DDS.
    env = dict(os.environ, CYCLONEDDS_URI=NetworkConfig(large_data=True).cyclone_xml())
    rows: list[Row] = []
    notes: list[str] = []
    for scenario in scenarios:
        print(f"{PROG}: {scenario} ...", file=sys.stderr, flush=True)
        if scenario == "direct":
            rows += run_setup(Setup("direct", [], [], args.domain, args.domain), args.seconds, certs, env, log_dir)
        elif scenario == "loopback":
            rows += run_setup(Setup("loopback", [], [], args.domain, args.domain + 1, f"127.0.0.1:{PORT + 10000}",
                                    f"127.0.0.1:{PORT + 10000}"), args.seconds, certs, env, log_dir)
        else:
            reason = netlab.unavailable()
            if reason is not None:
                notes.append(f"shaped: skipped ({reason})")
                continue
            link = ShapedLink(env)
            try:
                site_a, site_b = link.open()
                notes.append(f"shaped link: {DELAY_MS} ms, {LOSS_PER_MILLE / 10} % loss each way, {RATE}/s, "
                             f"by {link.how}")
                rows += run_setup(Setup("shaped", site_a.prefix, site_b.prefix, args.domain, args.domain,
                                        f"{ADDRESS_A}:{PORT}", link.connect_b), args.seconds, certs, env, log_dir)
            except (RunFailed, netlab.NetlabError) as error:
                notes.append(f"shaped: {error}")
            finally:
                link.close()
    print(f"{'set-up':<9} {'flow':<44} {'samples/s':>9} {'MB/s':>8} {'p50 ms':>8} {'p99 ms':>8}  notes")
    for row in rows:
        print(f"{row.scenario:<9} {row.flow:<44} {fmt(row.samples_per_s):>9} {fmt(row.mb_per_s, 3):>8} "
              f"{fmt(row.p50_ms, 2):>8} {fmt(row.p99_ms, 2):>8}  {row.lost} {row.note}".rstrip())
    for note in notes:
        print(note)
    if args.log_dir is not None:
        print(f"logs and every process's JSON lines (--stats): {log_dir}")
    camera = {row.scenario: row.mb_per_s for row in rows if row.flow.startswith("CameraImageData")}
    direct, bridged = camera.get("direct"), camera.get("loopback")
    ratio = bridged / direct if direct and bridged is not None and direct == direct and bridged == bridged else None
    print(f"zenoh_ratio_4MiB={fmt(ratio, 3) if ratio is not None else 'nan'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=20.0, help="measured window of each phase (default 20)")
    parser.add_argument("--scenarios", default=",".join(SCENARIOS),
                        help="comma-separated, of: direct, loopback, shaped (default: all)")
    add_domain_option(parser, 90, "first DDS domain id (uses two)")
    add_log_dir_option(parser, help="keep every process's output and JSON lines there (default: a temporary "
                                    "folder, removed at the end)")
    parser.add_argument("--probe", type=int, default=None, help=argparse.SUPPRESS)  # the probe child: its domain
    parser.add_argument("--stats", type=Path, default=None, help=argparse.SUPPRESS)  # the probe child's records
    args = parser.parse_args(argv)
    if args.log_dir is not None and (problem := output_folder_problem(args.log_dir, create=True)):
        parser.error(f"--log-dir {args.log_dir}: {problem}")  # before the run, not after it
    if args.seconds <= 0:
        parser.error(f"--seconds {args.seconds:g}: expected a positive number")
    if args.probe is not None:
        if args.stats is None:
            parser.error("--probe needs --stats FILE")
        return probe(args.probe, args.seconds, args.stats)
    scenarios = [name for name in args.scenarios.split(",") if name]
    unknown = [name for name in scenarios if name not in SCENARIOS]
    if unknown or not scenarios:
        parser.error(f"--scenarios: expected some of {', '.join(SCENARIOS)}, got {args.scenarios!r}")
    if not 0 <= args.domain <= 231:
        parser.error(f"--domain {args.domain}: expected 0..231")
    # The logs: --log-dir, kept, or a temporary folder; the certificates (private keys) always in a temporary folder of
    # their own. The temporary ones are removed at the end, also on an error, Ctrl-C or SIGTERM (which ends the run as
    # Ctrl-C does, every process stopped first).
    with work_folder("bench-zenoh-", args.log_dir) as log_dir, work_folder("bench-zenoh-certs-") as certs:
        try:
            make_certificates(certs, [f"site-a=127.0.0.1,{ADDRESS_A}", f"site-b=127.0.0.1,{ADDRESS_B}"])
        except CertificateError as error:
            print(f"{PROG}: {error}", file=sys.stderr)
            return 2
        return measure(args, scenarios, log_dir, certs)


if __name__ == "__main__":
    sys.exit(main())
