"""Cyclone DDS's own log lines, rate-limited: a sample Cyclone drops is one report line, not one line per sample.

Cyclone checks every received sample against the reader's type in C (enum values, string and sequence bounds,
truncation) and drops one that fails, with a warning on stderr for EACH sample (measured, Cyclone 11.0.1 and a Fast
DDS 2.9 writer of enum value 99: 29 samples, 29 lines):

    1795463914.888568 [151]       recv: data(application, vendor 1.15): 10f7f01:c848d0dd:0:103 #2: deserialization
        PlatformControl/Platform::PlatformControl failed (for reasons unknown)

A hostile writer would fill the log without end. :func:`install` gives Cyclone a log sink (``dds_set_log_sink``) that
turns these warnings into reports of the process's bad-sample reporter (automotive.bus.badsamples: one line per
topic and interval, naming the writer's GUID and vendor) and passes every other line through to stderr, also
rate-limited per kind of line (numbers and GUIDs left out), so that a flood of any other warning is summarised too.

How the sink gets into Cyclone is automotive.cyclone.logsink's business (Cyclone internals, behind the version gate);
when it cannot, :func:`install` returns False and Cyclone logs as it always did (one line per dropped sample).

The sink is called from Cyclone's own threads (the receive thread), holding Cyclone's log lock and possibly a proxy
writer's lock; it takes the GIL, formats and logs, and never calls into DDS (no participant name lookup there, which
is why these reports name the writer by GUID and vendor only).
"""

from __future__ import annotations

import re
import sys
import threading
from typing import Any

from automotive.bus.badsamples import BadSample, BadSampleReporter, RateLimitedLines
from automotive.cyclone import logsink
from automotive.cyclone.logsink import LC_ERROR, LC_FATAL, LC_WARNING  # noqa: F401  (Cyclone's log categories)

# DDSI vendor ids (the OMG's list) of the stacks this system meets.
VENDORS = {
    (1, 1): "RTI Connext DDS",
    (1, 2): "OpenSplice",
    (1, 3): "OpenDDS",
    (1, 15): "eProsima Fast DDS",
    (1, 16): "Eclipse Cyclone DDS",
}

_DROPPED = re.compile(r"data\(application, vendor (\d+)\.(\d+)\): ([0-9a-fA-F:]+) #\d+: "
                      r"deserialization (.*)/([^/]*) failed \((.*)\)$")
_NUMBERS = re.compile(r"[0-9A-Fa-f:.]*\d[0-9A-Fa-f:.]*")


# Cyclone's complaint about its configuration: ``config: //CycloneDDS/Domain/General: Interfacez: unknown element
# (CYCLONEDDS_URI+671 line 1)``; the offset is into the merged XML (ours, then the user's), which the user never saw.
_CONFIG = re.compile(r"^config: //CycloneDDS(?:/Domain)?/?(?P<path>[^:]*): (?P<what>.*?)"
                     r"(?: \((?P<source>[^()]*)\))?$")


def config_problem(message: str) -> str | None:
    """Cyclone's line about its configuration in the user's words: the element's path as the user writes it (without
    CycloneDDS/Domain, which a fragment may leave out), what is wrong, and the source when it is a file of theirs."""
    found = _CONFIG.match(message.strip())
    if found is None:
        return None
    path = "/".join(part for part in found["path"].split("/") if part and part != "#text")
    what = found["what"]
    element = re.match(r"^([\w:-]+): (unknown element|unknown attribute)", what)  # "Interfacez: unknown element"
    if element is not None:
        path, what = "/".join(filter(None, (path, element[1]))), what[len(element[1]) + 2:]
    source = found["source"] or ""
    where = f" ({source})" if source and not source.startswith("CYCLONEDDS_URI+") else ""
    return f"{path + ': ' if path else ''}{what}{where}"


class _Sink:
    def __init__(self, reporter: BadSampleReporter, setter: Any = None):
        self.reporter = reporter
        self.others = RateLimitedLines(self._to_stderr, reporter.interval_s)
        self.config_problems: list[str] = []  # kept for the one line of a configuration Cyclone refuses

    @staticmethod
    def _to_stderr(line: str) -> None:
        sys.stderr.write(line + "\n")
        sys.stderr.flush()

    def handle(self, priority: int, header: str, message: str) -> None:
        dropped = _DROPPED.search(message)
        if dropped is not None:
            vendor = (int(dropped[1]), int(dropped[2]))
            name = VENDORS.get(vendor, "")
            writer = f"writer {dropped[3]} (vendor {vendor[0]}.{vendor[1]}{' ' + name if name else ''})"
            problem = BadSample("", f"not deserializable ({dropped[6]})",
                                f"a valid {dropped[5]}: enum values in the enum, strings and sequences within their "
                                "bounds, nothing truncated")
            self.reporter.report(dropped[4], problem, writer, action="dropped by Cyclone DDS")
            return
        refused = config_problem(message)
        if refused is not None:  # said by the program, in one line with its own, when the domain cannot be made
            self.config_problems.append(refused)
            return
        line = f"{header}{message}"
        if priority & LC_FATAL:  # Cyclone aborts right after: said as is
            self._to_stderr(line)
            return
        shape = _NUMBERS.sub("#", message)
        self.others.add(shape, line, line, f"Cyclone DDS: {shape}", "cyclonedds: ")


_lock = threading.Lock()
_installed: _Sink | None = None


def install(reporter: BadSampleReporter) -> bool:
    """Route Cyclone's log lines through the rate limits (once per process); False if Cyclone's sink setter cannot be
    reached (Cyclone keeps logging every line to stderr)."""
    global _installed
    with _lock:
        if _installed is not None:
            _installed.reporter = reporter
            return True
        sink = _Sink(reporter)
        if not logsink.install(sink.handle):
            return False
        _installed = sink
    return True


def uninstall() -> None:
    """Give Cyclone back its default sink (stderr) and emit what the rate limits still count."""
    global _installed
    with _lock:
        sink, _installed = _installed, None
    if sink is None:
        return
    logsink.uninstall()
    sink.others.close()


def installed() -> bool:
    return _installed is not None


def take_config_problems() -> list[str]:
    """What Cyclone said of its configuration since the last call (nothing when the sink is not installed: Cyclone
    then said it on stderr itself)."""
    sink = _installed
    if sink is None:
        return []
    problems, sink.config_problems = sink.config_problems, []
    return problems
