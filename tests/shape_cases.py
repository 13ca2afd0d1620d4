"""The OMG DDS interoperability suite's QoS groups as our own test cases, and a runner that classifies what each
shape application prints into the suite's outcome codes (tests/test_shape_main.py).

A case is what the suite's test_suite.py states: the command line of each application (publishers and subscribers,
as the suite writes them; ``-x 2`` is added where no representation is named, as the suite's runner does) and the
outcome code the suite expects of each, plus the check the subscriber's samples must pass. The checks and the
runner are ours: they follow the suite's return codes (OK, INCOMPATIBLE_QOS, READER_NOT_MATCHED, DATA_NOT_RECEIVED,
DEADLINE_MISSED, RECEIVING_FROM_ONE / _BOTH, ...) but read fewer samples than the suite's 500, and where the suite's
check hangs on the machine's timing (history, lifespan, time-based filter) they check the policy's effect with room
for a loaded machine (each such check says how).

Where nothing may flow (another domain, topic or partition), the case names a *witness*: one more subscriber that
does receive from the publisher; once it has, the processes have met on the network, and the case then watches
NEGATIVE_WINDOW_S more seconds for a match that must not come. Processes start one after the other as soon as the
previous one has created its endpoints (no fixed delays), except where a case needs a subscriber to join late.
"""

from __future__ import annotations

import re
import shlex
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from apprunner import AppRunner, CommandProcess

EVENT_TIMEOUT_S = 30.0  # what the suite's runner waits per step (15 s), doubled for a loaded machine
NEGATIVE_WINDOW_S = 3.0  # after the witness received: no match may come in this time
STOP_TIMEOUT_S = 30.0  # the suite's runner waits this long after SIGINT

OK = "OK"
INCOMPATIBLE_QOS = "INCOMPATIBLE_QOS"
READER_NOT_MATCHED = "READER_NOT_MATCHED"
DATA_NOT_RECEIVED = "DATA_NOT_RECEIVED"
DATA_NOT_CORRECT = "DATA_NOT_CORRECT"
DEADLINE_MISSED = "DEADLINE_MISSED"
RECEIVING_FROM_ONE = "RECEIVING_FROM_ONE"
RECEIVING_FROM_BOTH = "RECEIVING_FROM_BOTH"
FILTER_NOT_CREATED = "FILTER_NOT_CREATED"
PUB_UNSUPPORTED_FEATURE = "PUB_UNSUPPORTED_FEATURE"
SUB_UNSUPPORTED_FEATURE = "SUB_UNSUPPORTED_FEATURE"
WRITER_NOT_CREATED = "WRITER_NOT_CREATED"
READER_NOT_CREATED = "READER_NOT_CREATED"

SAMPLE = re.compile(r"^(\S+)\s+(\S+)\s+(-?\d+)\s+(-?\d+)\s+\[(\d+)\](?:\s+\{(\d+)\})?\s*$")
SAMPLE_PATTERN = SAMPLE.pattern
NOT_SUPPORTED = r"(?i:not supported)"
PUBLISHER_EVENTS = {r"on_publication_matched\(\)": OK, r"on_offered_incompatible_qos": INCOMPATIBLE_QOS,
                    NOT_SUPPORTED: PUB_UNSUPPORTED_FEATURE}
SUBSCRIBER_EVENTS = {SAMPLE_PATTERN: OK, r"on_requested_incompatible_qos": INCOMPATIBLE_QOS,
                     r"on_requested_deadline_missed\(\)": DEADLINE_MISSED, NOT_SUPPORTED: SUB_UNSUPPORTED_FEATURE,
                     r"failed to create content filtered topic": FILTER_NOT_CREATED}
NEGATIVE = (READER_NOT_MATCHED, DATA_NOT_RECEIVED)
READY = r"Create writer for topic|Create reader for topic|(?i:not supported)|failed to create content filtered topic"


@dataclass(frozen=True)
class Sample:
    topic: str
    color: str
    x: int
    y: int
    size: int
    payload_last: int | None


def samples_of(lines: list[str]) -> list[Sample]:
    found = []
    for line in lines:
        match = SAMPLE.match(line)
        if match:
            topic, color, x, y, size, last = match.groups()
            found.append(Sample(topic, color, int(x), int(y), int(size), None if last is None else int(last)))
    return found


# -- checks of a subscriber's samples: each returns an outcome code ----------------------------------------------------
Check = Callable[[CommandProcess, "Case"], str]


def _wait_samples(process: CommandProcess, count: int) -> list[Sample] | None:
    try:
        process.wait_for(SAMPLE_PATTERN, EVENT_TIMEOUT_S, count=count)
    except AssertionError:
        return None
    return samples_of(process.lines)


def _per_color(samples: list[Sample]) -> dict[str, list[int]]:
    sizes: dict[str, list[int]] = {}
    for sample in samples:
        sizes.setdefault(sample.color, []).append(sample.size)
    return sizes


def check_basic(process: CommandProcess, case: Case) -> str:
    samples = _wait_samples(process, 1)
    if not samples:
        return DATA_NOT_RECEIVED
    return OK if samples[0].size > 0 else DATA_NOT_CORRECT


def check_increasing(process: CommandProcess, case: Case) -> str:
    """Best effort: no sample twice and none out of order (losses allowed), per instance."""
    samples = _wait_samples(process, case.samples)
    if samples is None:
        return DATA_NOT_RECEIVED
    for sizes in _per_color(samples).values():
        if any(later <= earlier for earlier, later in zip(sizes, sizes[1:])):
            return DATA_NOT_CORRECT
    return OK


def check_no_losses(process: CommandProcess, case: Case) -> str:
    """Reliable: after the first sample of an instance, every next one, in order, once."""
    samples = _wait_samples(process, case.samples * case.instances)
    if samples is None:
        return DATA_NOT_RECEIVED
    for sizes in _per_color(samples).values():
        if any(later != earlier + 1 for earlier, later in zip(sizes, sizes[1:])):
            return DATA_NOT_CORRECT
    return OK


def check_volatile(process: CommandProcess, case: Case) -> str:
    """A volatile reader that joined late gets none of the first samples."""
    samples = _wait_samples(process, 1)
    if samples is None:
        return DATA_NOT_RECEIVED
    return OK if samples[0].size >= 5 else DATA_NOT_CORRECT


def check_transient_local(process: CommandProcess, case: Case) -> str:
    """A transient-local reader that joined late gets the writer's history from its first sample on."""
    samples = _wait_samples(process, 1)
    if samples is None:
        return DATA_NOT_RECEIVED
    return OK if samples[0].size == 1 else DATA_NOT_CORRECT


def check_deadline_missed(process: CommandProcess, case: Case) -> str:
    if _wait_samples(process, 1) is None:
        return DATA_NOT_RECEIVED
    try:
        process.wait_for(r"on_requested_deadline_missed\(\)", EVENT_TIMEOUT_S)
    except AssertionError:
        return OK
    return DEADLINE_MISSED


def check_one_in_ten(process: CommandProcess, case: Case) -> str:
    """Time-based filter of 10 write periods: consecutive samples of an instance 5..19 sizes apart (the suite asks
    9..19; a writer the machine delays writes fewer than 10 samples in a second, and an unfiltered reader would get
    every one: 1 apart)."""
    samples = _wait_samples(process, case.samples * case.instances)
    if samples is None:
        return DATA_NOT_RECEIVED
    for sizes in _per_color(samples).values():
        steps = [later - earlier for earlier, later in zip(sizes[1:], sizes[2:])]  # the first step may be short
        if any(not 5 <= step <= 19 for step in steps):
            return DATA_NOT_CORRECT
    return OK


def check_lifespan(process: CommandProcess, case: Case) -> str:
    """Lifespan of 2.5 write periods, read every 5: each read finds at most 3 consecutive samples, and the samples
    that expired between reads make gaps. (The suite asks for runs of exactly 2 or 3; a writer the machine delays
    leaves only 1 alive now and then, a reader that ignored the lifespan would get 5 at each read, without gaps.)
    Reads until every instance shows 2 whole runs (a read may be half printed when the count is reached)."""
    wanted = case.samples * case.instances
    while True:
        samples = _wait_samples(process, wanted)
        if samples is None:
            return DATA_NOT_RECEIVED
        short = False
        for sizes in _per_color(samples).values():
            runs: list[int] = [1]
            for earlier, later in zip(sizes, sizes[1:]):
                if later <= earlier:
                    return DATA_NOT_CORRECT
                if later == earlier + 1:
                    runs[-1] += 1
                else:
                    runs.append(1)
            complete = runs[1:-1]  # the first and last runs may be cut by the start and the end of the observation
            if any(run > 3 for run in complete):
                print(f"lifespan check: runs of consecutive sizes {runs} in {sizes}")  # shown with a failure
                return DATA_NOT_CORRECT
            short = short or len(complete) < 2
        if not short:
            return OK
        wanted = len(samples) + case.instances


def check_size_at_most_20(process: CommandProcess, case: Case) -> str:
    samples = _wait_samples(process, case.samples)
    if samples is None:
        return DATA_NOT_RECEIVED
    return OK if all(1 <= sample.size <= 20 for sample in samples) else DATA_NOT_CORRECT


def check_payload(process: CommandProcess, case: Case) -> str:
    samples = _wait_samples(process, case.samples)
    if samples is None:
        return DATA_NOT_RECEIVED
    return OK if all(sample.payload_last == 255 for sample in samples) else DATA_NOT_CORRECT


def _final_state(process: CommandProcess, state: str) -> str:
    if _wait_samples(process, 1) is None:
        return DATA_NOT_RECEIVED
    try:  # the writer of the case writes 200 times (6.6 s), then ends every instance
        process.wait_for(rf"\s{state}$", EVENT_TIMEOUT_S)
    except AssertionError:
        return DATA_NOT_CORRECT
    colors = set(_per_color(samples_of(process.lines)))
    deadline = time.monotonic() + EVENT_TIMEOUT_S
    while True:
        ended = {line.split()[1] for line in process.lines if line.endswith(state)}
        if colors <= ended:
            return OK
        if time.monotonic() > deadline:
            return DATA_NOT_CORRECT
        try:
            process.wait_for_more(rf"\s{state}$", 1, timeout=max(deadline - time.monotonic(), 0.1))
        except AssertionError:
            return DATA_NOT_CORRECT


def check_unregistered(process: CommandProcess, case: Case) -> str:
    return _final_state(process, "NOT_ALIVE_NO_WRITERS_INSTANCE_STATE")


def check_disposed(process: CommandProcess, case: Case) -> str:
    return _final_state(process, "NOT_ALIVE_DISPOSED_INSTANCE_STATE")


def _after_all_matched(process: CommandProcess, case: Case) -> list[Sample] | None:
    """The samples received after the subscriber matched every publisher the case expects it to match."""
    writers = sum(1 for app, code in zip(case.apps, case.expected) if app.startswith("-P") and code == OK)
    try:
        process.wait_for(rf"matched writers {writers} ", EVENT_TIMEOUT_S)
    except AssertionError:
        return None
    before = len(samples_of(process.lines))
    samples = _wait_samples(process, before + case.samples)
    return None if samples is None else samples[before:]


def check_one_color(process: CommandProcess, case: Case) -> str:
    samples = _after_all_matched(process, case)
    if samples is None:
        return DATA_NOT_RECEIVED
    return RECEIVING_FROM_ONE if len({sample.color for sample in samples}) == 1 else RECEIVING_FROM_BOTH


def check_sizes(process: CommandProcess, case: Case) -> str:
    """As the suite: one change of size is the switch to the stronger writer; a second is samples of both."""
    samples = _after_all_matched(process, case)
    if samples is None:
        return DATA_NOT_RECEIVED
    changes = sum(1 for earlier, later in zip(samples, samples[1:]) if later.size != earlier.size)
    return RECEIVING_FROM_ONE if changes <= 1 else RECEIVING_FROM_BOTH


# -- cases ----------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Case:
    name: str
    apps: tuple[str, ...]  # command lines as the suite writes them, publishers and subscribers
    expected: tuple[str, ...]  # the suite's expected outcome of each
    check: Check = check_basic  # what the subscribers' samples must show
    samples: int = 30  # samples (per instance) a check reads
    witness: str | None = None  # a subscriber that receives where the case's own applications must not
    late_subscriber: int = 0  # start the subscribers after the first publisher printed this many samples (-w)
    ours: tuple[str | None, ...] | None = None  # our outcome where Cyclone cannot do what the suite expects (None:
    # not asserted, the other side of an unsupported one)
    groups: tuple[str, ...] = field(default=(), compare=False)

    @property
    def instances(self) -> int:
        match = re.search(r"--num-instances (\d+)", " ".join(self.apps))
        return int(match.group(1)) if match else 1

    @property
    def outcome(self) -> tuple[str | None, ...]:
        """What this project's command must produce: the suite's expectation, or ours where Cyclone lacks it."""
        return self.ours if self.ours is not None else self.expected


def _case(name: str, apps: list[str], expected: list[str], **options: object) -> Case:
    return Case(name, tuple(apps), tuple(expected), **options)  # type: ignore[arg-type]


P, S = "-P -t Square", "-S -t Square"
BOTH_OK = [OK, OK]
BOTH_INCOMPATIBLE = [INCOMPATIBLE_QOS, INCOMPATIBLE_QOS]
_DURABILITY = "vltp"
_DURABILITY_CASES = [
    _case(f"Durability_{4 * i + j}", [f"{P} -D {w}", f"{S} -D {r}"],
          BOTH_OK if _DURABILITY.index(w) >= _DURABILITY.index(r) else BOTH_INCOMPATIBLE)
    for i, w in enumerate(_DURABILITY) for j, r in enumerate(_DURABILITY)]
_LIFESPAN_CASES = [
    _case(f"Lifespan_{n}", [f"{P} {writer} -z 0 --write-period {write} --lifespan {life}{instances}",
                            f"{S} {reader} --read-period {read}"], BOTH_OK, check=check_lifespan, samples=10)
    for n, (writer, reader, write, life, read, instances) in enumerate(
        (writer, reader, write, life, read, instances)
        for writer, reader in (("-r -k 0", "-r -k 0"), ("-b", "-b -k 0"))
        for write, life, read in ((100, 250, 500), (400, 1000, 2000))
        for instances in ("", " --num-instances 4"))]

SELF_CASES: list[Case] = [
    _case("Domain_0", [f"{P} -d 0", f"{S} -d 0 -b"], BOTH_OK),
    _case("Domain_1", [f"{P} -d 0", f"{S} -d 1"], [READER_NOT_MATCHED, DATA_NOT_RECEIVED], witness=f"{S} -d 0"),
    _case("Domain_2", [f"{P} -d 1", f"{S} -d 1 -b"], BOTH_OK),
    _case("DataRepresentation_0", [f"{P} -x 1", f"{S} -x 1"], BOTH_OK),
    _case("DataRepresentation_1", [f"{P} -x 1", f"{S} -x 2"], BOTH_INCOMPATIBLE),
    _case("DataRepresentation_2", [f"{P} -x 2", f"{S} -x 1"], BOTH_INCOMPATIBLE),
    _case("DataRepresentation_3", [f"{P} -x 2", f"{S} -x 2 -b"], BOTH_OK),
    _case("Reliability_0", [f"{P} -b -z 0", f"{S} -b"], BOTH_OK, check=check_increasing),
    _case("Reliability_1", [f"{P} -b", f"{S} -r"], BOTH_INCOMPATIBLE),
    _case("Reliability_2", [f"{P} -r", f"{S} -b"], BOTH_OK),
    _case("Reliability_3", [f"{P} -r", f"{S} -r"], BOTH_OK),
    _case("Reliability_4", [f"{P} -r -k 0 -z 0", f"{S} -r -k 0"], BOTH_OK, check=check_no_losses),
    _case("Reliability_5", [f"{P} -r -k 0 -z 0 --num-instances 4", f"{S} -r -k 0"], BOTH_OK,
          check=check_no_losses),
    # The suite reads every 200 ms: a reader that wakes 50 ms late loses a sample of the 5 kept, which a loaded
    # machine does now and then. Reading every 100 ms, still slower than the writer, leaves 150 ms of room.
    _case("History_0", [f"{P} -r -k 5 -z 0 --write-period 50", f"{S} -r -k 5 --read-period 100"], BOTH_OK,
          check=check_no_losses),
    _case("History_1", [f"{P} -r -k 5 -z 0 --write-period 50 --num-instances 4", f"{S} -r -k 5 --read-period 100"],
          BOTH_OK, check=check_no_losses),
    _case("Ownership_0", [f"{P} -s -1", f"{S} -s -1"], BOTH_OK),
    _case("Ownership_1", [f"{P} -s -1", f"{S} -s 1"], BOTH_INCOMPATIBLE),
    _case("Ownership_2", [f"{P} -s 3", f"{S} -s -1"], BOTH_INCOMPATIBLE),
    _case("Ownership_3", [f"{P} -s 3 -r -k 0 -c BLUE -z 20", f"{P} -s 4 -r -k 0 -c BLUE -z 30", f"{S} -s 1 -r -k 0"],
          [OK, OK, RECEIVING_FROM_ONE], check=check_sizes),
    _case("Ownership_4", [f"{P} -s 3 -r -k 0 -c BLUE -z 20", f"{P} -s 4 -r -k 0 -c RED -z 30", f"{S} -s 1 -r -k 0"],
          [OK, OK, RECEIVING_FROM_BOTH], check=check_sizes),
    _case("Ownership_5", [f"{P} -s -1 -r -k 0 -c BLUE -z 20", f"{P} -s -1 -r -k 0 -c BLUE -z 30",
                          f"{S} -s -1 -r -k 0"], [OK, OK, RECEIVING_FROM_BOTH], check=check_sizes),
    _case("Ownership_6", [f"{P} -s -1 -r -k 0 -c BLUE -z 20", f"{P} -s -1 -r -k 0 -c RED -z 30",
                          f"{S} -s -1 -r -k 0"], [OK, OK, RECEIVING_FROM_BOTH], check=check_sizes),
    _case("Deadline_0", [f"{P} -f 3000", f"{S} -f 5000"], BOTH_OK),
    _case("Deadline_1", [f"{P} -f 5000", f"{S} -f 5000"], BOTH_OK),
    _case("Deadline_2", [f"{P} -f 7000", f"{S} -f 5000"], BOTH_INCOMPATIBLE),
    _case("Deadline_3", [f"{P} -f 2000 -w --write-period 3000", f"{S} -f 2000"], [DEADLINE_MISSED, DEADLINE_MISSED],
          check=check_deadline_missed),
    _case("Topic_0", ["-P -t Circle", "-S -t Circle"], BOTH_OK),
    _case("Topic_1", ["-P -t Square", "-S -t Circle"], [READER_NOT_MATCHED, DATA_NOT_RECEIVED], witness=S),
    _case("Cft_0", [f"{P} -r -k 0 -c BLUE", f"{P} -r -k 0 -c RED", f"{S} -r -k 0 -c RED"],
          [OK, OK, RECEIVING_FROM_ONE], check=check_one_color),
    _case("Cft_1", [f"{P} -r -k 0 -z 0 --size-modulo 50", f'{S} -r -k 0 --cft "shapesize <= 20"'], BOTH_OK,
          check=check_size_at_most_20),
    _case("Partition_0", [f'{P} -p "p1"', f'{S} -p "p1"'], BOTH_OK),
    _case("Partition_1", [f'{P} -p "p1"', f'{S} -p "p2"'], [READER_NOT_MATCHED, DATA_NOT_RECEIVED],
          witness=f'{S} -p "p1"'),
    _case("Partition_2", [f'{P} -p "p1" -c BLUE', f'{P} -p "x1" -c RED', f'{S} -p "p*"'],
          [OK, READER_NOT_MATCHED, RECEIVING_FROM_ONE], check=check_one_color),
    *_DURABILITY_CASES,
    _case("Durability_16", [f"{P} -z 0 -r -k 0 -D v -w", f"{S} -r -k 0 -D v"], BOTH_OK, check=check_volatile,
          late_subscriber=8),
    _case("Durability_17", [f"{P} -z 0 -r -k 0 -D l -w", f"{S} -r -k 0 -D l"], BOTH_OK,
          check=check_transient_local, late_subscriber=8),
    _case("TimeBasedFilter_0", [f"{P} -r -k 0 -z 0 --write-period 100", f"{S} -r -k 0 --time-filter 1000"], BOTH_OK,
          check=check_one_in_ten, samples=5),
    _case("TimeBasedFilter_1", [f"{P} -r -k 0 -z 0 --write-period 100 --num-instances 4",
                                f"{S} -r -k 0 --time-filter 1000"], BOTH_OK, check=check_one_in_ten, samples=5),
    _case("FinalInstanceState_0", [f"{P} --num-iterations 200 --num-instances 4 --final-instance-state u", S],
          BOTH_OK, check=check_unregistered),
    _case("FinalInstanceState_1", [f"{P} --num-iterations 200 --num-instances 4 --final-instance-state d", S],
          BOTH_OK, check=check_disposed),
    _case("FinalInstanceState_2", [f"{P} --num-iterations 200 --num-instances 4", S], BOTH_OK,
          check=check_unregistered),
    _case("LargeData_0", [f"{P} -r -k 0 --additional-payload-size 100000", f"{S} -r -k 0"], BOTH_OK,
          check=check_payload),
    *_LIFESPAN_CASES,
    # Presentation: what Cyclone DDS supports works; what it cannot do is said ("not supported"), as the reference
    # application of a vendor without it does.
    _case("OrderedAccess_0", [f"{P} -r -k 0 --ordered --access-scope i", f"{S} -r -k 0 --ordered --access-scope i"],
          BOTH_OK),
    _case("OrderedAccess_3", [f"{P} -r -k 0 --ordered --access-scope t", f"{S} -r -k 0 --ordered --access-scope i"],
          BOTH_OK),
    _case("OrderedAccess_4", [f"{P} -r -k 0 --ordered --access-scope t", f"{S} -r -k 0 --ordered --access-scope t"],
          BOTH_OK, ours=(None, SUB_UNSUPPORTED_FEATURE)),
    _case("CoherentSets_0", [f"{P} -r -k 0 --coherent --access-scope i", f"{S} -r -k 0 --coherent --access-scope i"],
          BOTH_OK, ours=(None, SUB_UNSUPPORTED_FEATURE)),
    _case("CoherentSets_10", [f"{P} -r -k 0 --coherent --access-scope i --num-topics 3 --num-instances 4 "
                              "--coherent-sample-count 3 --write-period 100 -z 0",
                              f"{S} -r -k 0 --coherent --access-scope i --num-topics 3 --take-read --read-period 100"],
          BOTH_OK, ours=(PUB_UNSUPPORTED_FEATURE, SUB_UNSUPPORTED_FEATURE)),
]

# The cases whose options both Cyclone (this command) and Fast DDS 2.9 (tests/fastdds/shape_peer.cpp) support:
# XCDR1 only, no TRANSIENT or PERSISTENT durability, no time-based filter, no Presentation.
FASTDDS_CASES = [case for case in SELF_CASES if case.name in (
    "Domain_0", "Domain_1", "DataRepresentation_0", "Reliability_0", "Reliability_1", "Reliability_4", "Reliability_5",
    "History_0", "History_1",
    "Ownership_2", "Ownership_3", "Ownership_5", "Deadline_2", "Deadline_3", "Topic_1", "Cft_0", "Cft_1",
    "Partition_1", "Partition_2", "Durability_1", "Durability_5", "Durability_17", "FinalInstanceState_0",
    "FinalInstanceState_1", "LargeData_0", "Lifespan_0")]
OURS_TO_FASTDDS, FASTDDS_TO_OURS = "ours-to-fastdds", "fastdds-to-ours"
# Pairings that fail for a reason of the other stack, seen here (docs/shapes-interop.md):
FASTDDS_LIMITS = {
    ("FinalInstanceState_0", OURS_TO_FASTDDS): "a Fast DDS 2.9 reader reports no end of a Cyclone writer's instances",
    ("FinalInstanceState_1", OURS_TO_FASTDDS): "a Fast DDS 2.9 reader reports no end of a Cyclone writer's instances",
    ("FinalInstanceState_1", FASTDDS_TO_OURS): "Fast DDS disposes with an MD5 key hash only, which Cyclone drops",
    ("Lifespan_0", OURS_TO_FASTDDS): "a Fast DDS 2.9 reader does not expire samples by the writer's lifespan",
    # Seen once in a full run on a loaded machine: sizes 20, 30, 20, 30, 30... A Fast DDS 2.9 exclusive reader took
    # one more sample of the weaker writer after one of the stronger, while it was still discovering them.
    ("Ownership_3", OURS_TO_FASTDDS): "a Fast DDS 2.9 exclusive reader may take the weaker writer's sample after the "
                                      "stronger's while discovering them (a race of the other stack)",
    # Seen once in a full run: the Fast DDS writers' samples of both sizes were not interleaved within the window
    # read (the shared-ownership cases depend on when each Fast DDS writer is discovered).
    ("Ownership_5", FASTDDS_TO_OURS): "timing of two Fast DDS 2.9 writers' discovery: not deterministic here",
    ("Ownership_5", OURS_TO_FASTDDS): "timing of the Fast DDS 2.9 reader's discovery: not deterministic here",
}
FASTDDS_PAIRS = [(case, direction) for case in FASTDDS_CASES for direction in (OURS_TO_FASTDDS, FASTDDS_TO_OURS)
                 if (case.name, direction) not in FASTDDS_LIMITS]

# Ours and Cyclone's application (tests/cyclone_shape_peer.py), both on their defaults in one host, as the suite's
# runner starts them: no option beyond the case's, the reference's default QoS (RELIABLE, VOLATILE, XCDR1). What is
# tested is that they meet whichever starts first. One that starts after a participant on Cyclone's defaults hears
# it at its next periodic announcement: every 8 s (Cyclone's default lease of 10 s less 2 s), well within
# EVENT_TIMEOUT_S and the suite's own 15 s.
CYCLONE_DEFAULTS_CASES = [
    _case("Defaults_PublisherFirst", [P, S], BOTH_OK),
    _case("Defaults_SubscriberFirst", [S, P], BOTH_OK),
]
OURS_TO_CYCLONE, CYCLONE_TO_OURS = "ours-to-cyclone", "cyclone-to-ours"
CYCLONE_DEFAULTS_PAIRS = [(case, direction) for case in CYCLONE_DEFAULTS_CASES
                          for direction in (OURS_TO_CYCLONE, CYCLONE_TO_OURS)]


# -- the runner -----------------------------------------------------------------------------------------------------
@dataclass
class Implementation:
    """How to start one side's shape application: ours, the Fast DDS peer, or the stand-in for Cyclone's."""

    name: str
    command: list[str]


def with_representation(args: str, representation: str) -> str:
    return args if re.search(r"(^|\s)-x\s", args) else f"{args} -x {representation}"


class CaseRun:
    """Runs one case's applications in one network namespace and classifies what each printed."""

    def __init__(self, case: Case, runner: AppRunner, namespace: str, publisher: Implementation,
                 subscriber: Implementation, representation: str = "2"):
        self.case = case
        self.runner = runner
        self.namespace = namespace
        self.publisher = publisher
        self.subscriber = subscriber
        self.representation = representation
        self.processes: list[CommandProcess] = []
        self.witness: CommandProcess | None = None
        self.before_witness: dict[int, int] = {}  # lines each process had printed when the witness started

    def start(self, args: str, label: str, implementation: Implementation) -> CommandProcess:
        argv = shlex.split(with_representation(args, self.representation))
        # In a namespace of its own the command's own network setting (loopback) applies, not the tests' URI.
        return self.runner.start_command(f"{label} ({implementation.name}: {args})",
                                         ["ip", "netns", "exec", self.namespace, *implementation.command, *argv],
                                         env={"CYCLONEDDS_URI": ""})

    def run(self) -> list[str | None]:
        """Start the applications, then classify each: first those expected to see something, then, after the
        witness received and NEGATIVE_WINDOW_S passed, those that must see nothing (classified without waiting)."""
        case = self.case
        first_publisher: CommandProcess | None = None
        for index, args in enumerate(case.apps):
            publishing = args.startswith("-P")
            if not publishing and case.late_subscriber and first_publisher is not None:
                first_publisher.wait_for(SAMPLE_PATTERN, EVENT_TIMEOUT_S, count=case.late_subscriber)
            process = self.start(args, f"{case.name} app {index + 1}",
                                 self.publisher if publishing else self.subscriber)
            process.wait_for(READY, EVENT_TIMEOUT_S)
            self.processes.append(process)
            if publishing and first_publisher is None:
                first_publisher = process
        outcomes: list[str | None] = [None] * len(case.apps)
        negative = [code in NEGATIVE for code in case.outcome]
        for index, (process, args, expected) in enumerate(zip(self.processes, case.apps, case.outcome)):
            if expected is not None and not negative[index]:
                outcomes[index] = self.classify(process, args, wait=True)
        if any(negative):
            self.before_witness = {id(process): len(process.lines) for process in self.processes}
            if case.witness is not None:
                self.witness = self.start(case.witness, f"{case.name} witness", self.subscriber)
                self.witness.wait_for(SAMPLE_PATTERN, EVENT_TIMEOUT_S)
            # An observation window, not a wait for a condition: what must not happen has had this long to happen.
            threading.Event().wait(NEGATIVE_WINDOW_S)
            for index, (process, args) in enumerate(zip(self.processes, case.apps)):
                if negative[index]:
                    outcomes[index] = self.classify(process, args, wait=False)
        return outcomes

    def classify(self, process: CommandProcess, args: str, wait: bool) -> str:
        publishing = args.startswith("-P")
        events = PUBLISHER_EVENTS if publishing else SUBSCRIBER_EVENTS
        outcome = _first_event(process, events, wait)
        if publishing and not wait and outcome == OK and self.witness is not None:
            # The witness is a reader of this publisher: only a match before it started, or a second one, counts.
            before = process.lines[:self.before_witness.get(id(process), 0)]
            if not any("on_publication_matched()" in line for line in before) and \
                    not any(re.search(r"matched readers [2-9]", line) for line in process.lines):
                outcome = None
        if outcome is None:
            return READER_NOT_MATCHED if publishing else DATA_NOT_RECEIVED
        if publishing:
            if outcome == OK and " -w" in f" {args}" and DEADLINE_MISSED in self.case.expected:
                try:
                    process.wait_for(r"on_offered_deadline_missed\(\)", EVENT_TIMEOUT_S)
                except AssertionError:
                    return OK
                return DEADLINE_MISSED
            return outcome
        if outcome != OK:
            return outcome
        return self.case.check(process, self.case)

    def stop(self) -> list[tuple[CommandProcess, int]]:
        """SIGINT to every application, as the suite's runner stops them; their exit codes."""
        everything = [*self.processes, *([self.witness] if self.witness else [])]
        return [(process, process.stop(signal.SIGINT, timeout=STOP_TIMEOUT_S)) for process in everything]


def _first_event(process: CommandProcess, events: dict[str, str], wait: bool) -> str | None:
    """The outcome of the first line matching one of ``events``, in the order printed; None if none came (waiting up
    to EVENT_TIMEOUT_S when ``wait``)."""
    combined = "|".join(f"(?:{pattern})" for pattern in events)
    if wait:
        try:
            process.wait_for(combined, EVENT_TIMEOUT_S)
        except AssertionError:
            return None
    for line in list(process.lines):
        for pattern, outcome in events.items():
            if re.search(pattern, line):
                return outcome
    return None


def describe(run: CaseRun, outcomes: list[str | None]) -> str:
    lines = [f"{run.case.name}: expected {list(run.case.outcome)}, got {outcomes}"]
    for process in [*run.processes, *([run.witness] if run.witness else [])]:
        lines.append(f"--- {process.name}:\n" + "\n".join(process.lines[-40:]))
    return "\n".join(lines)


def repo_root() -> Path:
    return Path(__file__).resolve().parent.parent
