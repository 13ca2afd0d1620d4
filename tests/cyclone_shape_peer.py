"""A stand-in for Cyclone DDS's own shape application (the OMG interoperability suite's shape_main on Cyclone's C API,
not available here) on Cyclone's defaults, for tests/test_shape_main.py:

    python tests/cyclone_shape_peer.py -P -t Square [-x 1|2] [-d DOMAIN]     # BLUE squares, size 20, every 33 ms
    python tests/cyclone_shape_peer.py -S -t Square [-x 1|2] [-d DOMAIN]     # prints what it reads every 100 ms

A plain Cyclone DDS participant with no configuration of its own: started without CYCLONEDDS_URI it is on Cyclone's
defaults (the first multicast-capable interface, SPDP multicast to 239.255.0.1, no participant index), as Cyclone's
shape_main is when the suite's runner starts it. Its QoS is the reference application's default: RELIABLE, VOLATILE,
KEEP_LAST 1, SHARED ownership, the representation of ``-x`` (XCDR1 unless ``-x 2``). It prints the lines of the
reference that the suite's runner (and tests/shape_cases.py) reads: ``Create writer for topic:``, ``Create reader for
topic:``, ``on_publication_matched()``, ``on_subscription_matched()`` and one line per sample read
(``%-10s %-10s %03d %03d [%d]``). SIGINT or SIGTERM end it with exit code 0.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from typing import Any

from cyclonedds.core import Listener
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from automotive.types.shape import ShapeType

WRITE_PERIOD_S = 0.033  # the reference's defaults
READ_PERIOD_S = 0.1
_printing = threading.Lock()


def say(line: str) -> None:
    with _printing:  # the listener's thread prints too
        print(line, flush=True)


class Events(Listener):
    """Prints the matches as the reference does."""

    def __init__(self, topic: str):
        super().__init__()
        self.where = f"topic: '{topic}'  type: 'ShapeType'"

    def on_publication_matched(self, writer: Any, status: Any) -> None:
        say(f"on_publication_matched() {self.where} : matched readers {status.current_count}")

    def on_subscription_matched(self, reader: Any, status: Any) -> None:
        say(f"on_subscription_matched() {self.where} : matched writers {status.current_count}")


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="cyclone_shape_peer", description=__doc__.split("\n\n")[0])
    role = parser.add_mutually_exclusive_group(required=True)
    role.add_argument("-P", dest="publish", action="store_true", help="publish")
    role.add_argument("-S", dest="subscribe", action="store_true", help="subscribe")
    parser.add_argument("-t", dest="topic", required=True, help="topic name")
    parser.add_argument("-x", dest="representation", choices=("1", "2"), default="1", help="XCDR1 or XCDR2")
    parser.add_argument("-d", dest="domain", type=int, default=0, help="domain id")
    args = parser.parse_args(argv)
    stop = threading.Event()
    for number in (signal.SIGINT, signal.SIGTERM):
        signal.signal(number, lambda *_: stop.set())
    representation = Policy.DataRepresentation(use_xcdrv2_representation=True) if args.representation == "2" \
        else Policy.DataRepresentation(use_cdrv0_representation=True)
    qos = Qos(Policy.Reliability.Reliable(max_blocking_time=100_000_000), Policy.Durability.Volatile,
              Policy.History.KeepLast(1), Policy.Ownership.Shared, representation)
    participant = DomainParticipant(args.domain)
    topic = Topic(participant, args.topic, ShapeType)
    listener = Events(args.topic)
    endpoint: DataWriter[ShapeType] | DataReader[ShapeType]
    if args.publish:
        say(f"Create writer for topic: {args.topic} color: BLUE")
        endpoint = writer = DataWriter(participant, topic, qos=qos, listener=listener)
        step = 0
        while not stop.wait(WRITE_PERIOD_S):
            step += 1
            writer.write(ShapeType(color="BLUE", x=step % 200, y=(3 * step) % 200, shapesize=20,
                                   additional_payload_size=b""))
    else:
        say(f"Create reader for topic: {args.topic}")
        endpoint = reader = DataReader(participant, topic, qos=qos, listener=listener)
        while not stop.wait(READ_PERIOD_S):
            for sample in reader.take(N=100):
                if sample.sample_info.valid_data:
                    say(f"{args.topic:<10} {sample.color:<10} {sample.x:03d} {sample.y:03d} [{sample.shapesize}]")
    endpoint.set_listener(None)  # no callback while the participant goes
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
