"""What discovery costs the running system, and how soon a tool that joins it late finds every application.

    automotive bench discovery                          the whole system (automotive launch), 10 late joins
    automotive bench discovery --vision-sensors 50 --except camera_pub,camera_sub --joins 5

The system runs as `automotive launch` starts it, with its shipped network defaults (loopback), inside a network
namespace this program creates and deletes (its loopback is private, so the counts are the system's alone; needs
root). Once the system is older than Cyclone's default prune delay for unanswered peers (--age, 35 s):

- cost, over --window seconds: the discovery datagrams per second (every datagram sent to a participant's
  metatraffic port: participant announcements and probes, endpoint discovery, heartbeats of the built-in endpoints;
  counted by an nftables rule in the namespace) and the CPU time per second of Cyclone's discovery threads (tev:
  timed events, which send the announcements; dq.builtins: handling what discovery receives), summed over the
  applications; the reception threads' time is printed beside it (it holds the application data too);
- late joins: --joins times, a participant that probes only participant indexes 0-4 of 127.0.0.1, as RTI Connext
  does with its default initial peer (Fast DDS probes 0-3), creates one reader per flow of the system; the time
  until every reader matched its writer is one late join.

The last line is late_join_p99_s=<p99 of the late joins>.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

from automotive.bus.cli import ArgumentParser, add_domain_option, add_log_dir_option
from automotive.bus.latency import percentile
from automotive.tools.launch.display import RUNNING_LINE
from automotive.tools.support import netlab
from automotive.tools.support.children import Child, program_command, thread_cpu_by_name, work_folder

PROG = "automotive bench discovery"
DISCOVERY_THREADS = ("tev", "dq.builtins")
RECEPTION_THREADS = ("recv", "recvUC", "recvMC")
JOINER_INDEXES = range(5)  # RTI Connext's default probe of an initial peer without an index range: 0-4


def run(*command: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    result = subprocess.run(command, capture_output=True, text=True)
    if check and result.returncode != 0:
        raise SystemExit(f"{PROG}: {' '.join(command)} failed: {result.stderr.strip()}")
    return result


class Namespace(netlab.Namespace):
    """A network namespace of this run, with nftables counters of the datagrams sent to metatraffic ports."""

    def __init__(self, domain: int):
        super().__init__(f"bench-discovery-{os.getpid()}")
        # Well-known ports of the domain: 7400 + 250 x domain + 10 + 2 x index (metatraffic), + 1 (user data).
        base = 7400 + 250 * domain
        self.nft(f"table inet bench {{\n chain out {{\n  type filter hook output priority 0; policy accept;\n"
                 f"  udp dport {base + 10}-{base + 249} udp dport & 1 == 0 counter\n }}\n}}\n")

    def datagrams(self) -> int:
        listing = run(*self.exec("nft", "list", "table", "inet", "bench")).stdout
        return sum(int(n) for n in re.findall(r"counter packets (\d+)", listing))


def thread_cpu_s(pids: list[int], names: tuple[str, ...]) -> float:
    """CPU seconds (user + system) of the threads of these processes that have one of these names."""
    return sum(seconds for name, seconds in thread_cpu_by_name(pids).items() if name in names)


JOINER = r'''
import json, sys, time
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from automotive import config as shipped
from automotive.tools.flows import system_flows
from automotive.bus.qos import QosProfiles
from automotive.bus.app import DEFAULT_LIBRARY
from automotive.cyclone.matched import matched_publications
domain, ports, timeout = int(sys.argv[1]), sys.argv[2].split(","), float(sys.argv[3])
# Only these ports: without multicast, Cyclone would probe every index of localhost itself (AddLocalhost), which
# the tools this stands for do not do.
peers = "".join(f'<Peer address="127.0.0.1:{port}"/>' for port in ports)
config = ('<CycloneDDS><Domain><General><Interfaces><NetworkInterface name="lo"/></Interfaces>'
          '<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>'
          f'<MaxAutoParticipantIndex>120</MaxAutoParticipantIndex><Peers AddLocalhost="false">{peers}</Peers>'
          '</Discovery></Domain></CycloneDDS>')
profiles = QosProfiles(shipped.qos_file())
flows = [flow for flow in system_flows() if flow.topic != "Circle"]
started = time.monotonic()
dds_domain = Domain(domain, config)
participant = DomainParticipant(domain)
readers = [DataReader(participant, Topic(participant, flow.topic, flow.data_type),
                      qos=profiles.reader_qos(DEFAULT_LIBRARY, flow.profile)) for flow in flows]
matched = {}
while len(matched) < len(readers) and time.monotonic() - started < timeout:
    for flow, reader in zip(flows, readers):
        if flow.topic not in matched and matched_publications(reader):
            matched[flow.topic] = time.monotonic() - started
    time.sleep(0.01)
print(json.dumps({"matched": matched, "flows": [flow.topic for flow in flows]}), flush=True)
'''


def late_join(namespace: Namespace, domain: int, timeout: float) -> dict[str, float]:
    ports = ",".join(str(7400 + 250 * domain + 10 + 2 * index) for index in JOINER_INDEXES)
    env = {key: value for key, value in os.environ.items() if key != "CYCLONEDDS_URI"}
    result = subprocess.run(namespace.exec(sys.executable, "-c", JOINER, str(domain), ports, str(timeout)),
                            capture_output=True, text=True, env=env, timeout=timeout + 60)
    if result.returncode != 0 or not result.stdout.strip():
        raise SystemExit(f"{PROG}: the late joiner failed: {result.stderr.strip()[-2000:]}")
    report = json.loads(result.stdout.strip().splitlines()[-1])
    missing = [topic for topic in report["flows"] if topic not in report["matched"]]
    if missing:
        print(f"  late join: NOT matched within {timeout:g} s: {', '.join(missing)} (counted as {timeout:g} s)")
    return {topic: report["matched"].get(topic, timeout) for topic in report["flows"]}


def bench(args: argparse.Namespace) -> int:
    if os.geteuid() != 0:
        print(f"{PROG}: needs root (it runs the system in a network namespace of its own)",
              file=sys.stderr)
        return 2
    # The launcher's logs: --log-dir, kept, or a temporary folder removed at the end (also on an error, Ctrl-C or
    # SIGTERM, which ends the run as Ctrl-C does: the system stopped, the namespace gone).
    with work_folder("bench-discovery-", args.log_dir) as log_dir:
        return measure(args, log_dir)


def measure(args: argparse.Namespace, log_dir: Path) -> int:
    domain = args.domain
    try:
        namespace = Namespace(domain)
    except netlab.NetlabError as error:
        raise SystemExit(f"{PROG}: {error}") from None
    env = {key: value for key, value in os.environ.items() if key != "CYCLONEDDS_URI"}
    env.update(DISPLAY="", WAYLAND_DISPLAY="")
    launch_args = ["--mode", "background", "--domain", str(domain), "--log-dir", str(log_dir),
                   *(["--vision-sensors", str(args.vision_sensors)] if args.vision_sensors > 1 else []),
                   *(["--except", args.exclude] if args.exclude else [])]
    launcher = Child("launch", program_command("launch", *launch_args, python=namespace.prefix), env=env)
    try:
        try:
            line = launcher.wait_for(RUNNING_LINE, timeout=120)
        except AssertionError:
            raise SystemExit(f"{PROG}: the launcher ended before the system ran") from None
        print(line.split("| ", 1)[1].strip())
        started = time.monotonic()
        while time.monotonic() - started < args.age:
            time.sleep(min(5.0, args.age - (time.monotonic() - started)))
            print(f"  system age {time.monotonic() - started:.0f} s of {args.age:g}", flush=True)
        pids = namespace.pids()
        datagrams, window_start = namespace.datagrams(), time.monotonic()
        cpu = [thread_cpu_s(pids, DISCOVERY_THREADS), thread_cpu_s(pids, RECEPTION_THREADS)]
        time.sleep(args.window)
        elapsed = time.monotonic() - window_start
        rate = (namespace.datagrams() - datagrams) / elapsed
        cpu_ms, reception_ms = ((thread_cpu_s(pids, names) - before) / elapsed * 1000
                                for names, before in zip((DISCOVERY_THREADS, RECEPTION_THREADS), cpu, strict=True))
        processes = len(pids) - 1  # the launcher
        print(f"cost over {elapsed:.0f} s, {processes} application processes: {rate:.0f} discovery datagrams/s "
              f"({rate / processes:.0f} per process); Cyclone's discovery threads {cpu_ms:.1f} ms CPU/s "
              f"({cpu_ms / processes:.2f} per process); reception threads, data included, {reception_ms:.1f} ms/s")
        joins = []
        for number in range(1, args.joins + 1):
            times = late_join(namespace, domain, args.timeout)
            joins.append(max(times.values()))
            slowest = max(times, key=lambda topic: times[topic])
            if joins[-1] < args.timeout:
                print(f"  late join {number}: every flow matched after {joins[-1]:.2f} s (last: {slowest})",
                      flush=True)
        print(f"late joins: min {min(joins):.2f} s, median {statistics.median(joins):.2f} s, "
              f"p99 {percentile(joins, 0.99):.2f} s, max {max(joins):.2f} s")
        print(f"discovery_datagrams_per_s={rate:.0f} cyclone_cpu_ms_per_s={cpu_ms:.1f}")
        print(f"late_join_p99_s={percentile(joins, 0.99):.2f}")
        return 0
    finally:
        subprocess.run(program_command("launch", "stop", "--log-dir", str(log_dir), python=namespace.prefix),
                       capture_output=True)
        launcher.stop(timeout=30)
        namespace.delete()


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_domain_option(parser, 86, "DDS domain id")
    parser.add_argument("--vision-sensors", type=int, default=1, help="vision sensors the launcher starts (1)")
    parser.add_argument("--except", dest="exclude", default="", metavar="A,B", help="applications not started")
    parser.add_argument("--age", type=float, default=35.0, help="system age before measuring, seconds (35)")
    parser.add_argument("--window", type=float, default=30.0, help="cost measurement window, seconds (30)")
    parser.add_argument("--joins", type=int, default=10, help="late joins to time (10)")
    parser.add_argument("--timeout", type=float, default=30.0, help="give up a late join after this long (30 s)")
    add_log_dir_option(parser, help="keep the applications' logs there (default: a temporary folder, removed at the "
                                    "end)")
    args = parser.parse_args(argv)
    if args.joins < 1 or args.window <= 0 or args.age < 0:
        parser.error("--joins must be >= 1, --window > 0, --age >= 0")
    return bench(args)


if __name__ == "__main__":
    sys.exit(main())
