"""A numbered sequence of driver alerts over the databus, for the lossy-link test (run inside a network namespace).

    python tests/alert_sequence.py write --count 20 --readers 2 --peers A,B --interface veth-a --domain 7 [--step]
    python tests/alert_sequence.py read --peers A,B --interface veth-b --domain 7 [--keep-all]

Alert number k (1..63) sets the DriverAlerts flags of k's bits, in the HMI's text order (bit 0: blindSpotDriver ...
bit 5: driverAttention), so that consecutive numbers are different alerts and every printed alert says its number.

The writer uses the HMI profile (reliable, keep last 1, transient local). By default it waits for each alert to be
acknowledged by every matched reader before the next; with --step it then also waits for a line on its standard input
(the test says "next" once the HMI has shown the alert); --interval sets a minimum time between alerts and
--no-wait-acks writes without waiting, as an application would. With keep-last-1 on both sides a newer alert replaces
one that is not yet repaired (writer) or not yet taken (reader): the profile keeps the latest state, not every state.
The reader prints every sample it takes ("alert k"); --keep-all gives it an unbounded history, so that what it prints
is everything the protocol delivered, however slowly this process takes it.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.qos import DataReaderQos, Policy
from cyclonedds.sub import DataReader

from automotive import config
from automotive.bus.console import write_line
from automotive.bus.endpoints import Databus
from automotive.bus.network import NetworkConfig
from automotive.bus.qos import QosProfiles
from automotive.cyclone.matched import matched_subscriptions
from automotive.types.Alerts import DriverAlerts

FLAGS = ("blindSpotDriver", "blindSpotPassenger", "frontCollision", "backCollision", "parkingCollision",
         "driverAttention")
MAX_NUMBER = 2 ** len(FLAGS) - 1
ROOT = Path(__file__).resolve().parent.parent


def alert_for(number: int) -> DriverAlerts:
    return DriverAlerts(**{flag: bool(number >> bit & 1) for bit, flag in enumerate(FLAGS)})


def number_of(alert: DriverAlerts) -> int:
    return sum(1 << bit for bit, flag in enumerate(FLAGS) if getattr(alert, flag))


def make_bus(args: argparse.Namespace) -> Databus:
    network = NetworkConfig.from_settings("", args.interface, args.peers.split(","), source="alert_sequence")
    log = logging.getLogger("alert_sequence")
    log.addHandler(logging.StreamHandler(sys.stdout))
    log.setLevel(logging.INFO)
    return Databus(args.domain, QosProfiles(config.qos_file()), "AutomotiveLibrary", log, network,
                   "alert_sequence")


def write(args: argparse.Namespace) -> int:
    created = time.monotonic()  # discovery starts with the participant
    bus = make_bus(args)
    writer = bus.writer("AlertTopic", DriverAlerts, "HMI")
    deadline = time.monotonic() + args.timeout
    while len(matched_subscriptions(writer)) < args.readers:
        if time.monotonic() > deadline:
            write_line(f"only {len(matched_subscriptions(writer))} of {args.readers} readers matched")
            return 1
        time.sleep(0.05)  # polling a status: the readers are other processes on another host
    write_line(f"matched {args.readers} readers in {time.monotonic() - created:.2f} s")
    start = time.monotonic()
    next_write = start
    for number in range(1, args.count + 1):
        time.sleep(max(0.0, next_write - time.monotonic()))  # pacing (--interval), not synchronisation
        next_write = time.monotonic() + args.interval
        writer.write(alert_for(number))
        if args.wait_acks and not writer.wait_for_acks(int(args.timeout * 1e9)):
            write_line(f"alert {number} not acknowledged within {args.timeout:g} s")
            return 1
        write_line(f"wrote alert {number}")
        if args.step and number < args.count and sys.stdin.readline().strip() != "next":
            write_line("stopped: no 'next' on standard input")
            return 1
    if not writer.wait_for_acks(int(args.timeout * 1e9)):
        write_line(f"the last alerts were not acknowledged within {args.timeout:g} s")
        return 1
    write_line(f"all {args.count} alerts acknowledged in {time.monotonic() - start:.2f} s")
    bus.close()
    return 0


def read(args: argparse.Namespace) -> int:
    bus = make_bus(args)
    if args.keep_all:
        qos = DataReaderQos(Policy.History.KeepAll, base=bus.profiles.reader_qos(bus.library, "HMI"))
        reader: DataReader[DriverAlerts] = DataReader(bus.subscriber, bus.topic("AlertTopic", DriverAlerts), qos=qos)
    else:
        reader = bus.reader("AlertTopic", DriverAlerts, "HMI")
    waitset = WaitSet(bus.participant)
    waitset.attach(ReadCondition(reader, SampleState.NotRead | ViewState.Any | InstanceState.Any))
    write_line("reading alerts")
    try:
        while True:
            waitset.wait(int(1e9))
            for sample in reader.take(N=100):
                if isinstance(sample, DriverAlerts):
                    write_line(f"alert {number_of(sample)}")
    except KeyboardInterrupt:
        pass
    finally:
        bus.close()
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("role", choices=["write", "read"])
    parser.add_argument("--domain", type=int, required=True)
    parser.add_argument("--peers", required=True)
    parser.add_argument("--interface", default="")
    parser.add_argument("--count", type=int, default=20, help=f"alerts to write, 1..{MAX_NUMBER}")
    parser.add_argument("--readers", type=int, default=1, help="write once this many readers matched")
    parser.add_argument("--timeout", type=float, default=20.0, help="seconds for the readers and for each ack")
    parser.add_argument("--interval", type=float, default=0.0, help="minimum seconds between two alerts")
    parser.add_argument("--no-wait-acks", dest="wait_acks", action="store_false",
                        help="do not wait for each alert's acknowledgement")
    parser.add_argument("--step", action="store_true", help="after each alert, wait for 'next' on standard input")
    parser.add_argument("--keep-all", action="store_true", help="reader: keep every sample until taken")
    args = parser.parse_args()
    if not 1 <= args.count <= MAX_NUMBER:
        print(f"--count {args.count}: expected 1..{MAX_NUMBER}", file=sys.stderr)
        return 2
    return write(args) if args.role == "write" else read(args)


if __name__ == "__main__":
    sys.exit(main())
