"""A real RTI Connext peer for interoperability tests, through RTI Connector for Python (rticonnextdds-connector).

The types, topics and QoS live in tests/rti/automotive_rti.xml, declared as the original RTI automotive example
declares them (everything appendable, helpers at the root). This module composes, per peer, one RTI participant in
the test's domain holding only the writers and readers the test asks for, so matching counts mean what they say.

    with RtiPeer(domain_id, writers=["Vision"], readers=["Alerts"]) as peer:
        peer.wait_for_readers("Vision")                 # our Cyclone reader was discovered and matched
        peer.write("Vision", {"id": 1, "timestamp": {"s": 1, "ns": 2}, "objects": []})
        alerts = peer.take_until("Alerts", 1)           # samples as dicts, bounded wait

Endpoint names (see ENDPOINTS): Circle, Lidar, Alerts, Vision, PlatformControl, PlatformStatus, SensorObjects,
Camera, Camera64KiB.
RTI stays on loopback (UDPv4 only, no multicast, initial peer 127.0.0.1): see the Loopback QoS profile. With
``initial_peers`` it uses the interfaces of its network namespace instead and announces itself only to those hosts
(the Unicast profile), as RTI users configure a network without multicast; with ``lan`` it has RTI's own defaults
(multicast discovery on every interface: inside a test's network namespace only).

Run as a script, inside a test's network namespace, it is one such participant in a process of its own: it writes
the given samples every 0.2 s and prints one line per matched endpoint and per distinct sample it reads (on stdout,
each line whole; RTI's own log messages, which RTI writes to stdout a piece at a time, go to stderr instead, so they
never cut into those lines: read the two apart to match whole lines)::

    python tests/rti_peer.py --domain 7 --initial-peers 10.231.0.1 --read Vision,Alerts \\
        --write 'Alerts={"frontCollision": true}'
"""

from __future__ import annotations

import argparse
import itertools
import json
import signal
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, TypeVar
from xml.sax.saxutils import quoteattr

import rticonnextdds_connector as rti

from automotive.bench.rti_reader import own_lines

T = TypeVar("T")

RTI_XML = Path(__file__).resolve().parent / "rti" / "automotive_rti.xml"
QOS_LIBRARY = "RtiPeerQos"


@dataclass(frozen=True)
class Endpoint:
    """One flow of the databus as the RTI peer sees it: topic and the default QoS profiles of its endpoints."""

    topic: str
    writer_profile: str
    reader_profile: str


# The "Writer" profile offers reliable, transient local, a 1 s deadline and a 10 s liveliness lease, which every
# reader profile of ours accepts. Readers follow the original example's flows: best effort where our writers are
# best effort (a reliable reader would not match them), reliable for LiDAR, and the HMI's QoS for alerts. Like a
# real RTI Connext 6 application, every RTI endpoint uses XCDR1 and requests a latency budget of 0.
ENDPOINTS: dict[str, Endpoint] = {
    "Circle": Endpoint("Circle", "Writer", "BestEffortReader"),
    "Lidar": Endpoint("rt/LidarTopic", "Writer", "ReliableReader"),
    "Alerts": Endpoint("AlertTopic", "Alerts", "Alerts"),
    "Vision": Endpoint("VisionTopic", "Writer", "BestEffortReader"),
    "PlatformControl": Endpoint("PlatformControl", "Writer", "BestEffortReader"),
    "PlatformStatus": Endpoint("PlatformStatus", "Writer", "BestEffortReader"),
    "SensorObjects": Endpoint("SensorObjects", "Writer", "BestEffortReader"),
    "Camera": Endpoint("CameraImageData", "Writer", "DefaultReader"),
    "Camera64KiB": Endpoint("CameraImageData_64KiB", "Writer", "ReliableReader"),
}

# Each peer gets its own participant library name: RTI keeps XML definitions per process.
_peer_numbers = itertools.count(1)


def _participant_xml(library: str, domain_id: int, writers: Mapping[str, str], readers: Mapping[str, str],
                     initial_peers: Sequence[str] = (), lan: bool = False) -> str:
    def endpoint(tag: str, qos_tag: str, name: str, profile: str) -> str:
        topic = ENDPOINTS[name].topic
        return (f"<{tag} name={quoteattr(name)} topic_ref={quoteattr(topic)}>"
                f"<{qos_tag} base_name={quoteattr(f'{QOS_LIBRARY}::{profile}')}/></{tag}>")

    publisher = "".join(endpoint("data_writer", "datawriter_qos", n, p) for n, p in writers.items())
    subscriber = "".join(endpoint("data_reader", "datareader_qos", n, p) for n, p in readers.items())
    return (f"<dds><domain_participant_library name={quoteattr(library)}>"
            f"<domain_participant name=\"Peer\" domain_ref=\"RtiPeerDomains::Automotive\" domain_id=\"{domain_id}\">"
            f"{_participant_qos(initial_peers, lan)}"
            f"<publisher name=\"Pub\">{publisher}</publisher>"
            f"<subscriber name=\"Sub\">{subscriber}</subscriber>"
            f"</domain_participant></domain_participant_library></dds>")


def _participant_qos(initial_peers: Sequence[str], lan: bool = False) -> str:
    if lan:
        return f"<domain_participant_qos base_name=\"{QOS_LIBRARY}::Lan\"/>"
    if not initial_peers:
        return f"<domain_participant_qos base_name=\"{QOS_LIBRARY}::Loopback\"/>"
    peers = "".join(f"<element>udpv4://{peer}</element>" for peer in initial_peers)
    return (f"<domain_participant_qos base_name=\"{QOS_LIBRARY}::Unicast\">"
            f"<discovery><initial_peers>{peers}</initial_peers></discovery></domain_participant_qos>")


def _profiles(names: Iterable[str] | Mapping[str, str], default: Callable[[Endpoint], str]) -> dict[str, str]:
    """Endpoint name -> QoS profile; a mapping picks profiles explicitly, a plain list takes the defaults."""
    chosen = dict(names) if isinstance(names, Mapping) else {name: "" for name in names}
    for name in chosen:
        if name not in ENDPOINTS:
            raise ValueError(f"unknown RTI peer endpoint '{name}' (known: {', '.join(ENDPOINTS)})")
    return {name: profile or default(ENDPOINTS[name]) for name, profile in chosen.items()}


class RtiPeer:
    """One RTI Connext participant with the requested writers and readers, in ``domain_id``, on loopback (or,
    given ``initial_peers``, unicast to those hosts on the interfaces of its network namespace).

    ``writers``/``readers`` are endpoint names (keys of ENDPOINTS), or mappings from endpoint name to a QoS
    profile of the RtiPeerQos library: "Writer", "WriterXcdr2" (writes XCDR2), "ReliableReader",
    "BestEffortReader", "ReliableReaderXcdr2"/"BestEffortReaderXcdr2" (also accept XCDR2), "Alerts",
    "DefaultReader" (RTI's defaults: what an application that names no profile gets), "ExclusiveReader" (the
    defaults with EXCLUSIVE ownership and a 300 ms liveliness lease, keeping 100 samples).
    Samples are dicts as RTI Connector gives them: nested dicts for structs, lists for sequences, arrays and octet
    sequences (a list of ints), ints for enums.
    """

    def __init__(self, domain_id: int, writers: Iterable[str] | Mapping[str, str] = (),
                 readers: Iterable[str] | Mapping[str, str] = (), xml: Path = RTI_XML,
                 initial_peers: Sequence[str] = (), lan: bool = False):
        self.domain_id = domain_id
        self.writers = _profiles(writers, lambda e: e.writer_profile)
        self.readers = _profiles(readers, lambda e: e.reader_profile)
        library = f"RtiPeer{next(_peer_numbers)}"
        participant = _participant_xml(library, domain_id, self.writers, self.readers, initial_peers, lan)
        self.connector: rti.Connector | None = rti.Connector(f"{library}::Peer", f'{xml};str://"{participant}"')
        self._outputs = {name: self.connector.get_output(f"Pub::{name}") for name in self.writers}
        self._inputs = {name: self.connector.get_input(f"Sub::{name}") for name in self.readers}

    def __enter__(self) -> RtiPeer:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:
        """Delete the participant and all its endpoints (safe to call twice)."""
        if self.connector is not None:
            self.connector.close()
            self.connector = None
            self._outputs.clear()
            self._inputs.clear()

    def output(self, name: str) -> rti.Output:
        """The Connector Output of writer ``name``, for anything this helper does not wrap."""
        return self._outputs[name]

    def input(self, name: str) -> rti.Input:
        """The Connector Input of reader ``name``."""
        return self._inputs[name]

    def matched_readers(self, name: str) -> int:
        """How many DDS readers (ours included) writer ``name`` currently matches."""
        return len(self._outputs[name].matched_subscriptions)

    def matched_writers(self, name: str) -> int:
        """How many DDS writers reader ``name`` currently matches."""
        return len(self._inputs[name].matched_publications)

    def wait_for_readers(self, name: str, count: int = 1, timeout: float = 15.0) -> None:
        """Wait until writer ``name`` matches at least ``count`` readers; AssertionError after ``timeout`` s."""
        _wait(lambda: self.matched_readers(name) >= count, timeout, f"RTI writer {name} to match {count} reader(s)")

    def wait_for_writers(self, name: str, count: int = 1, timeout: float = 15.0) -> None:
        """Wait until reader ``name`` matches at least ``count`` writers; AssertionError after ``timeout`` s."""
        _wait(lambda: self.matched_writers(name) >= count, timeout, f"RTI reader {name} to match {count} writer(s)")

    def write(self, name: str, sample: Mapping[str, Any]) -> None:
        """Write one sample given as a dict (nested dicts for structs, lists for sequences and arrays, ints for
        enums). Members not given take their defaults (0, "", empty)."""
        output = self._outputs[name]
        output.clear_members()
        output.instance.set_dictionary(dict(sample))
        output.write()

    def wait_for_acknowledgments(self, name: str, timeout: float = 15.0) -> None:
        """Wait until every reliable reader matched by writer ``name`` acknowledged all its samples."""
        try:
            self._outputs[name].wait(int(timeout * 1000))
        except rti.TimeoutError:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for acknowledgments on RTI writer "
                                 f"{name}") from None

    def _take(self, name: str, each: Callable[[Any], T]) -> list[T]:
        """Take what reader ``name`` holds now: ``each(sample)`` of its valid samples, before they go back."""
        reader = self._inputs[name]
        reader.take()
        try:
            return [each(sample) for sample in reader.samples.valid_data_iter]
        finally:
            reader.return_samples()

    def take(self, name: str) -> list[dict[str, Any]]:
        """Take what reader ``name`` holds now: the valid samples, as dicts."""
        return self._take(name, lambda sample: sample.get_dictionary())

    def take_count(self, name: str) -> int:
        """Take what reader ``name`` holds now; how many valid samples. Nothing is converted: a camera frame made
        into a dict (4 Mi numbers) takes seconds of the peer's only thread."""
        return len(self._take(name, lambda sample: None))

    def take_until(self, name: str, count: int = 1, timeout: float = 15.0,
                   accept: Callable[[dict[str, Any]], bool] | None = None) -> list[dict[str, Any]]:
        """Take samples from reader ``name`` until ``count`` accepted ones arrived or ``timeout`` s passed;
        returns the accepted samples (possibly fewer than ``count``: the caller asserts)."""
        return self._until(name, count, timeout,
                           lambda: [s for s in self.take(name) if accept is None or accept(s)])

    def count_until(self, name: str, count: int = 1, timeout: float = 15.0) -> int:
        """Take samples from reader ``name`` until ``count`` arrived or ``timeout`` s passed; how many. Nothing is
        converted (see take_count): for a test that asks whether a flow arrives, not what it holds."""
        return len(self._until(name, count, timeout, lambda: self._take(name, lambda sample: None)))

    def _until(self, name: str, count: int, timeout: float, take: Callable[[], list[T]]) -> list[T]:
        reader = self._inputs[name]
        received: list[T] = []
        deadline = time.monotonic() + timeout
        while len(received) < count:
            received.extend(take())
            remaining = deadline - time.monotonic()
            if len(received) >= count or remaining <= 0:
                break
            try:
                reader.wait(max(1, int(min(remaining, 0.2) * 1000)))
            except rti.TimeoutError:
                pass  # poll again: data may have come between the take and the wait
        return received


def _wait(condition: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.02)


# --- as a process of its own (tests/test_multihost.py runs it inside a network namespace) ----------------------------

# The endpoints whose samples the printed lines tell apart (_sample_label); of the others, a line says that samples
# arrive, and they are only counted.
LABELLED = ("Vision", "PlatformControl", "Alerts", "Circle")


def _sample_label(name: str, sample: Mapping[str, Any], written: Mapping[str, Mapping[str, Any]]) -> tuple[str, str]:
    """What tells one writer's samples from another's in the printed lines: (kind, text); one line per kind."""
    if name == "Vision":
        return f"id={sample['id']}", f"id={sample['id']}"
    if name == "PlatformControl":
        own = sample["sample_id"] == written.get(name, {}).get("sample_id")
        return ("own" if own else "other"), f"sample_id={sample['sample_id']}"
    if name == "Alerts":
        flags = ",".join(flag for flag, value in sample.items() if value) or "none"
        return flags, flags
    return sample["color"], f"color={sample['color']}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="One RTI Connext participant in a process of its own.")
    parser.add_argument("--domain", type=int, required=True)
    parser.add_argument("--initial-peers", default="", help="comma-separated hosts (default: loopback only)")
    parser.add_argument("--lan", action="store_true", help="RTI's default discovery (multicast), every interface")
    parser.add_argument("--read", default="", metavar="NAME[:PROFILE],...",
                        help="endpoints to read, each with its default reader profile or the one named")
    parser.add_argument("--write", action="append", default=[], metavar="NAME=JSON",
                        help="an endpoint to write and its sample as JSON, written every 0.2 s (repeatable)")
    args = parser.parse_args(argv)
    readers = dict(item.partition(":")[::2] for item in args.read.split(",") if item)
    samples: dict[str, dict[str, Any]] = {}
    for item in args.write:
        name, _, sample = item.partition("=")
        try:
            samples[name] = json.loads(sample or "{}")
        except json.JSONDecodeError as error:
            print(f"--write {item}: the sample is not JSON ({error})", file=sys.stderr)
            return 2
    say = own_lines()
    try:
        peer = RtiPeer(args.domain, writers=list(samples), readers=readers,
                       initial_peers=[host for host in args.initial_peers.split(",") if host], lan=args.lan)
    except ValueError as error:
        print(error, file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # close the participant on the way out
    seen: set[tuple[str, str]] = set()
    matched: dict[str, int] = {}
    say("rti peer running")
    try:
        while True:
            for name, sample in samples.items():
                peer.write(name, sample)
                count = peer.matched_readers(name)
                if count > matched.get(f"writer {name}", 0):
                    say(f"writer {name} matched {count} reader(s)")
                matched[f"writer {name}"] = count
            # Every match is said before any sample is taken, so that a match is said within one round.
            for name in readers:
                count = peer.matched_writers(name)
                if count > matched.get(f"reader {name}", 0):
                    say(f"reader {name} matched {count} writer(s)")
                matched[f"reader {name}"] = count
            for name in readers:
                if name not in LABELLED:
                    if peer.take_count(name) and (name, "any") not in seen:
                        seen.add((name, "any"))
                        say(f"received {name} any")
                    continue
                for sample in peer.take(name):
                    kind, text = _sample_label(name, sample, samples)
                    if (name, kind) not in seen:
                        seen.add((name, kind))
                        say(f"received {name} {text}")
            time.sleep(0.2)
    finally:
        peer.close()


if __name__ == "__main__":
    sys.exit(main())
