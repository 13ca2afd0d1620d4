"""Whether a writer and a reader of one topic match, by the DDS rules, and why not, in words.

DDS matches a writer and a reader of the same topic name when their types agree, they share a partition, their data
representations meet and, for each request-offered (RxO) policy, what the writer *offers* is at least what the reader
*requests* (DDS 1.4, 2.2.3 "Supported QoS", the RxO column; XTypes 1.3, 7.6.3.1.1 for the data representation).
:data:`RULES` is that table: one :class:`Rule` per policy, its check a small function that returns the reason in
words (offered against requested) or None when the pair passes it. :func:`mismatch_reasons` runs the table;
:func:`hints` adds what this project learned about other vendors, which no rule of the standard says.

Everything here is plain data: no DDS entity is needed, so every rule is unit-tested alone (tests/test_monitor.py).
"""

from __future__ import annotations

import fnmatch
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

INFINITE_NS = 2**63 - 1  # DDS_INFINITY as Cyclone gives durations (nanoseconds)

# The orders of the RxO policies whose kinds are ranked: an offered kind at least the requested one matches.
RELIABILITY = ("BEST_EFFORT", "RELIABLE")
DURABILITY = ("VOLATILE", "TRANSIENT_LOCAL", "TRANSIENT", "PERSISTENT")
LIVELINESS = ("AUTOMATIC", "MANUAL_BY_PARTICIPANT", "MANUAL_BY_TOPIC")
PRESENTATION = ("INSTANCE", "TOPIC", "GROUP")
DESTINATION_ORDER = ("BY_RECEPTION_TIMESTAMP", "BY_SOURCE_TIMESTAMP")
OWNERSHIP = ("SHARED", "EXCLUSIVE")
XCDR1, XCDR2 = "XCDR1", "XCDR2"

VENDOR_RTI = "RTI Connext DDS"
VENDOR_FASTDDS = "eProsima Fast DDS"
VENDOR_CYCLONE = "Eclipse Cyclone DDS"
RTI_PROBED_INDEXES = 5  # RTI's default initial peers probe participant indexes 0..4 of a host


@dataclass(frozen=True)
class EndpointQos:
    """What matching looks at of one endpoint (a writer's offer or a reader's request). The defaults are the DDS
    specification's defaults, which also stand for a policy the discovery data does not carry."""

    type_name: str = ""
    type_information: bool = False  # the endpoint sent XTypes type information
    reliability: str = "RELIABLE"  # a writer's default; a reader's is BEST_EFFORT (reader_defaults)
    durability: str = "VOLATILE"
    deadline_ns: int = INFINITE_NS
    latency_budget_ns: int = 0
    liveliness: str = "AUTOMATIC"
    lease_ns: int = INFINITE_NS
    ownership: str = "SHARED"
    partitions: tuple[str, ...] = ()
    presentation: str = "INSTANCE"
    coherent_access: bool = False
    ordered_access: bool = False
    destination_order: str = "BY_RECEPTION_TIMESTAMP"
    representations: tuple[str, ...] = (XCDR1,)  # a writer writes the first; a reader accepts any
    # Shown, never matched on:
    history: str = "KEEP_LAST 1"
    ownership_strength: int = 0
    lifespan_ns: int = INFINITE_NS
    time_based_filter_ns: int = 0

    def to_dict(self) -> dict[str, object]:
        return {"type_name": self.type_name, "type_information": self.type_information,
                "reliability": self.reliability, "durability": self.durability,
                "deadline": duration_words(self.deadline_ns), "latency_budget": duration_words(self.latency_budget_ns),
                "liveliness": self.liveliness, "lease_duration": duration_words(self.lease_ns),
                "ownership": self.ownership, "ownership_strength": self.ownership_strength,
                "partitions": list(self.partitions), "presentation": self.presentation,
                "coherent_access": self.coherent_access, "ordered_access": self.ordered_access,
                "destination_order": self.destination_order, "data_representation": list(self.representations),
                "history": self.history, "lifespan": duration_words(self.lifespan_ns),
                "time_based_filter": duration_words(self.time_based_filter_ns)}


def reader_defaults(**policies: Any) -> EndpointQos:
    """A reader's request with the specification's reader defaults (BEST_EFFORT) and the given policies."""
    return replace(EndpointQos(reliability="BEST_EFFORT"), **policies)


@dataclass(frozen=True)
class Reason:
    """Why a pair does not match, by one rule: the policy, what the writer offers, what the reader requests, and
    what the rule says."""

    policy: str
    offered: str
    requested: str
    rule: str

    @property
    def words(self) -> str:
        return f"{self.policy}: offered {self.offered}, requested {self.requested} ({self.rule})"

    def to_dict(self) -> dict[str, str]:
        return {"policy": self.policy, "offered": self.offered, "requested": self.requested, "rule": self.rule,
                "words": self.words}


Check = Callable[[EndpointQos, EndpointQos], Reason | None]


@dataclass(frozen=True)
class Rule:
    policy: str
    check: Check = field(repr=False)
    summary: str  # the rule in one line, for the documentation and the page's legend


def duration_words(ns: int) -> str:
    """``infinite``, ``0``, ``100 ms``, ``1.5 s``, ``250 us``: a duration as people write it (a negative one raw)."""
    if ns >= INFINITE_NS:
        return "infinite"
    if ns <= 0:
        return "0" if ns == 0 else f"{ns} ns"
    for unit, size in (("s", 1_000_000_000), ("ms", 1_000_000), ("us", 1_000)):
        if ns >= size:
            return f"{ns / size:.6g} {unit}"
    return f"{ns} ns"


def _rank(order: tuple[str, ...], kind: str) -> int:
    """The kind's rank; an unknown kind ranks below every known one (shown raw, judged as the weakest)."""
    return order.index(kind) if kind in order else -1


def _ranked(policy: str, order: tuple[str, ...], offered: str, requested: str, rule: str) -> Reason | None:
    if _rank(order, offered) >= _rank(order, requested) and offered in order:
        return None
    if offered == requested:
        return None  # two unknown kinds alike: nothing to say
    return Reason(policy, offered, requested, rule)


def check_type_name(offered: EndpointQos, requested: EndpointQos) -> Reason | None:
    if offered.type_name == requested.type_name:
        return None
    both = offered.type_information and requested.type_information
    rule = ("the type names differ; with type information on both sides, XTypes may still match assignable types, "
            "which this monitor does not judge" if both else
            "the type names must be equal (one side sent no type information)")
    return Reason("type", offered.type_name or "unknown", requested.type_name or "unknown", rule)


def check_data_representation(offered: EndpointQos, requested: EndpointQos) -> Reason | None:
    written = offered.representations[0] if offered.representations else XCDR1
    accepted = requested.representations or (XCDR1,)
    if written in accepted:
        return None
    return Reason("data representation", written, " or ".join(accepted),
                  "the reader must accept the representation the writer writes")


def check_reliability(offered: EndpointQos, requested: EndpointQos) -> Reason | None:
    return _ranked("reliability", RELIABILITY, offered.reliability, requested.reliability,
                   "a RELIABLE reader matches only RELIABLE writers")


def check_durability(offered: EndpointQos, requested: EndpointQos) -> Reason | None:
    return _ranked("durability", DURABILITY, offered.durability, requested.durability,
                   "the writer must keep its data at least as long as the reader asks: "
                   "VOLATILE < TRANSIENT_LOCAL < TRANSIENT < PERSISTENT")


def check_deadline(offered: EndpointQos, requested: EndpointQos) -> Reason | None:
    if offered.deadline_ns <= requested.deadline_ns:
        return None
    return Reason("deadline", duration_words(offered.deadline_ns), duration_words(requested.deadline_ns),
                  "the writer must promise a period no longer than the reader's deadline")


def check_latency_budget(offered: EndpointQos, requested: EndpointQos) -> Reason | None:
    if offered.latency_budget_ns <= requested.latency_budget_ns:
        return None
    return Reason("latency budget", duration_words(offered.latency_budget_ns),
                  duration_words(requested.latency_budget_ns),
                  "the writer's budget must be at most the reader's; an asynchronous writer (budget above 0) is "
                  "not matched by readers that keep the default budget 0")


def check_liveliness_kind(offered: EndpointQos, requested: EndpointQos) -> Reason | None:
    return _ranked("liveliness kind", LIVELINESS, offered.liveliness, requested.liveliness,
                   "AUTOMATIC < MANUAL_BY_PARTICIPANT < MANUAL_BY_TOPIC")


def check_liveliness_lease(offered: EndpointQos, requested: EndpointQos) -> Reason | None:
    if offered.lease_ns <= requested.lease_ns:
        return None
    return Reason("liveliness lease", duration_words(offered.lease_ns), duration_words(requested.lease_ns),
                  "the writer's lease must be at most the lease the reader requests")


def check_ownership(offered: EndpointQos, requested: EndpointQos) -> Reason | None:
    if offered.ownership == requested.ownership:
        return None
    return Reason("ownership", offered.ownership, requested.ownership, "both sides must be SHARED, or both EXCLUSIVE")


def check_presentation(offered: EndpointQos, requested: EndpointQos) -> Reason | None:
    scope = _ranked("presentation", PRESENTATION, offered.presentation, requested.presentation,
                    "the access scope offered must be at least the one requested: INSTANCE < TOPIC < GROUP")
    if scope is not None:
        return scope
    for name, wants, has in (("coherent access", requested.coherent_access, offered.coherent_access),
                             ("ordered access", requested.ordered_access, offered.ordered_access)):
        if wants and not has:
            return Reason("presentation", f"{name} off", f"{name} on",
                          f"a reader that requests {name} matches only writers that offer it")
    return None


def check_destination_order(offered: EndpointQos, requested: EndpointQos) -> Reason | None:
    return _ranked("destination order", DESTINATION_ORDER, offered.destination_order, requested.destination_order,
                   "BY_RECEPTION_TIMESTAMP < BY_SOURCE_TIMESTAMP")


def _wildcard(name: str) -> bool:
    return any(character in name for character in "*?[")


def partitions_meet(offered: tuple[str, ...], requested: tuple[str, ...]) -> bool:
    """Whether two partition lists share a partition: no partition is the default partition ""; a name with
    wildcards (fnmatch) matches the other side's plain names, never another name with wildcards."""
    for a in offered or ("",):
        for b in requested or ("",):
            if _wildcard(a) and _wildcard(b):
                continue
            if a == b or (_wildcard(a) and fnmatch.fnmatchcase(b, a)) or (_wildcard(b) and fnmatch.fnmatchcase(a, b)):
                return True
    return False


def check_partition(offered: EndpointQos, requested: EndpointQos) -> Reason | None:
    if partitions_meet(offered.partitions, requested.partitions):
        return None

    def listed(partitions: tuple[str, ...]) -> str:
        return ", ".join(f"'{name}'" for name in partitions) if partitions else "the default partition ''"

    return Reason("partition", listed(offered.partitions), listed(requested.partitions),
                  "the writer's publisher and the reader's subscriber must share a partition")


# The table: the type and the representation first (no QoS can mend them), then the RxO policies in the order of the
# DDS specification's QoS table, then the partition.
RULES: tuple[Rule, ...] = (
    Rule("type", check_type_name, "same type name (or XTypes-assignable types, with type information on both sides)"),
    Rule("data representation", check_data_representation,
         "the reader accepts the representation the writer writes (XCDR1 or XCDR2)"),
    Rule("reliability", check_reliability, "offered >= requested: BEST_EFFORT < RELIABLE"),
    Rule("durability", check_durability,
         "offered >= requested: VOLATILE < TRANSIENT_LOCAL < TRANSIENT < PERSISTENT"),
    Rule("deadline", check_deadline, "offered period <= requested period"),
    Rule("latency budget", check_latency_budget, "offered budget <= requested budget"),
    Rule("liveliness kind", check_liveliness_kind,
         "offered >= requested: AUTOMATIC < MANUAL_BY_PARTICIPANT < MANUAL_BY_TOPIC"),
    Rule("liveliness lease", check_liveliness_lease, "offered lease <= requested lease"),
    Rule("ownership", check_ownership, "the same kind on both sides"),
    Rule("presentation", check_presentation,
         "offered scope >= requested (INSTANCE < TOPIC < GROUP); coherent and ordered access offered if requested"),
    Rule("destination order", check_destination_order,
         "offered >= requested: BY_RECEPTION_TIMESTAMP < BY_SOURCE_TIMESTAMP"),
    Rule("partition", check_partition, "a partition in common (wildcards on one side only)"),
)


def mismatch_reasons(offered: EndpointQos, requested: EndpointQos) -> list[Reason]:
    """Every reason why the writer's offer and the reader's request do not match; empty: they match."""
    return [reason for rule in RULES if (reason := rule.check(offered, requested)) is not None]


# What to change, per policy that fails: the reason says which rule; this says which side can give way. The latency
# budget and the data representation have their own, vendor-aware hints below.
REMEDIES: dict[str, Callable[[EndpointQos, EndpointQos], str]] = {
    "reliability": lambda offered, requested: (
        "the writer sends best effort: make the writer RELIABLE, or let the reader request BEST_EFFORT (it then "
        "takes what arrives, with no resend)"),
    "durability": lambda offered, requested: (
        f"the reader asks for {requested.durability} data the writer does not keep: give the writer durability "
        f"{requested.durability}, or let the reader request {offered.durability} (a late joiner then misses what "
        "was written before it)"),
    "ownership": lambda offered, requested: (
        "an EXCLUSIVE reader matches only EXCLUSIVE writers and a SHARED one only SHARED writers: redundant mode's "
        "profiles are EXCLUSIVE (config.redundant=true on both sides), the defaults SHARED"
        if offered.ownership in OWNERSHIP and requested.ownership in OWNERSHIP else
        "both sides must name the same ownership kind"),
    "deadline": lambda offered, requested: (
        f"the writer promises a sample every {duration_words(offered.deadline_ns)}, the reader wants one every "
        f"{duration_words(requested.deadline_ns)}: shorten the writer's deadline or lengthen the reader's"),
    "liveliness kind": lambda offered, requested: (
        f"give the writer liveliness {requested.liveliness}, or let the reader request {offered.liveliness}"),
    "liveliness lease": lambda offered, requested: (
        f"the writer's lease ({duration_words(offered.lease_ns)}) is longer than the reader allows "
        f"({duration_words(requested.lease_ns)}): shorten the writer's lease or lengthen the reader's"),
    "partition": lambda offered, requested: (
        "put the writer's publisher and the reader's subscriber in one partition (the same name, or a wildcard on "
        "one side)"),
    "type": lambda offered, requested: (
        "both sides must use the same type name, modules included: build both from one IDL"),
}


def hints(offered: EndpointQos, requested: EndpointQos, writer_vendor: str, reader_vendor: str,
          reasons: list[Reason]) -> list[str]:
    """What to change for one writer/reader pair that does not match (REMEDIES, per failing policy), and what this
    project learned about other vendors, for a pair matched or not."""
    said: list[str] = []
    policies = {reason.policy for reason in reasons}
    said.extend(REMEDIES[policy](offered, requested) for policy in sorted(policies) if policy in REMEDIES)
    if "latency budget" in policies:
        said.append("an asynchronous writer hides its data from every default reader: give the reader a latency "
                    f"budget of at least {duration_words(offered.latency_budget_ns)}, or the writer a budget of 0")
    if "data representation" in policies and VENDOR_FASTDDS in (writer_vendor, reader_vendor):
        said.append("Fast DDS 2.9 speaks XCDR1 only: the other side must write (or accept) XCDR1")
    elif "data representation" in policies and VENDOR_RTI == reader_vendor:
        said.append("RTI Connext 6 readers accept XCDR1 only by default: write XCDR1, or set the reader's "
                    "data_representation to accept XCDR2")
    if (not reasons and reader_vendor == VENDOR_RTI and requested.lease_ns > offered.lease_ns
            and offered.lease_ns < INFINITE_NS):
        said.append(f"RTI readers judge a writer lost by the lease they request ({duration_words(requested.lease_ns)}),"
                    f" not by the writer's ({duration_words(offered.lease_ns)}): request the lease you need, or a "
                    "failover waits that long")
    return said


def participant_hint(vendor: str, others_on_host: int) -> str | None:
    """RTI's default discovery probes indexes 0..4 of a host: with more participants there, some are never probed."""
    if vendor == VENDOR_RTI and others_on_host >= RTI_PROBED_INDEXES:
        return (f"RTI probes participant indexes 0-{RTI_PROBED_INDEXES - 1} only by default, and {others_on_host} "
                "other participants share its host: one it does not see may hold a higher index, and is found only "
                "if it announces itself to RTI (ours do)")
    return None
