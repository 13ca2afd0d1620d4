"""Monitor: who talks to whom on the domain, why a writer and a reader do not match, and how the data flows.

    automotive monitor --once            the domain as text after a discovery window (--wait S), then exit
    automotive monitor --json            the same as one JSON document
    automotive monitor                   the text again whenever the graph, the matches or a program's health change

It joins the domain read-only, with the common options of every program (--domain, -D config.domainId=..., the
network options), so it sees what the applications see. It reads:

- the built-in discovery topics: every participant (its name, vendor, host and process where discovery tells them),
  every writer and reader with its topic, type and QoS;
- rt/diagnostics, every program's health (automotive.bus.diagnostics): the samples per second of each topic, the age
  of its last sample, deadline misses, liveliness changes and lost samples as the programs report them. It never
  subscribes to the data itself (the camera's frames included).

Which writer/reader pairs match is its judgement by the DDS rules (automotive.tools.monitoring.rules); for every pair
of the same topic that does not, it gives the reasons in words, offered against requested. It writes no data: only its
own /diagnostics, as every program. Its report goes to stdout, its log to stderr. The web page is not built yet.

Exit codes: 0 done (--once, --json) or stopped (Ctrl-C, SIGTERM); 2 bad input (one line on stderr).
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from typing import TextIO

from automotive.bus.app import Application, build_parser, run
from automotive.bus.properties import PropertyKeys
from automotive.tools.monitoring.discovery import DomainView
from automotive.tools.monitoring.model import Snapshot
from automotive.tools.monitoring.text import render

PROPERTY_KEYS = PropertyKeys.of()
DEFAULT_WAIT_S = 3.0  # discovery on one host takes well under a second; the programs report every second
MAX_WAIT_S = 3600.0
POLL_S = 0.5


def signature(snapshot: Snapshot) -> tuple[object, ...]:
    """What makes the live form print again: the graph, the matches, the mismatches, the health levels (not the
    rates, which change every second)."""
    return (tuple((p.key, p.name, p.health) for p in snapshot.participants),
            tuple(e.key for e in snapshot.endpoints),
            tuple((m.writer, m.reader) for m in snapshot.matches),
            tuple((m.writer, m.reader, tuple(r.words for r in m.reasons)) for m in snapshot.mismatches),
            tuple((p.name, p.level) for p in snapshot.programs))


def body(app: Application, out: TextIO) -> None:
    args = app.args
    view = DomainView(app.bus)
    app.optional_topics.add(view.diagnostics.topic.get_name())  # no program reporting is no fault of the monitor's
    app.ready()
    once = args.once or args.json
    if once:
        app.stop_event.wait(args.wait)
        snapshot = view.snapshot()
        for problem in view.problems:
            app.log.warning("%s", problem)
        out.write(snapshot.to_json() + "\n" if args.json else render(snapshot))
        out.flush()
        return
    last: tuple[object, ...] | None = None
    app.stop_event.wait(min(args.wait, 1.0))
    while app.running:
        snapshot = view.snapshot()
        current = signature(snapshot)
        if current != last:
            out.write(render(snapshot) + "\n")
            out.flush()
            last = current
        if app.stop_event.wait(POLL_S):
            break


def seconds(text: str) -> float:
    """An argparse type: the discovery window, 0..MAX_WAIT_S seconds."""
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0 <= value <= MAX_WAIT_S:  # NaN too
        raise argparse.ArgumentTypeError(f"expected seconds from 0 to {MAX_WAIT_S:g}, not '{text}'")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--once", action="store_true", help="print the domain as text once, after --wait, and exit")
    parser.add_argument("--json", action="store_true", help="print the domain as one JSON document, and exit")
    parser.add_argument("--wait", type=seconds, default=DEFAULT_WAIT_S, metavar="S",
                        help=f"the discovery window before the first report (default {DEFAULT_WAIT_S:g} s)")


DESCRIPTION = ("Who talks to whom on the domain and why a writer and a reader do not match. --once prints it as text "
               "and exits, --json as one JSON document; without them it prints the text again whenever the graph, "
               "the matches or a program's health change (the web page is not built yet). Reads discovery and "
               "rt/diagnostics only: it writes no data.")


def main(argv: list[str] | None = None) -> int:
    # --help and --version answer on stdout, a bad option with one line and exit code 2, before anything starts.
    build_parser("monitor", DESCRIPTION, add_arguments, "automotive monitor").parse_args(argv)
    out = sys.stdout
    # The report is stdout's; the program's log (and any stray print) goes to stderr, so that --json's stdout is one
    # JSON document whatever the log level.
    with contextlib.redirect_stdout(sys.stderr):
        try:
            return run("monitor", DESCRIPTION, lambda app: body(app, out), argv, add_arguments,
                       command="automotive monitor", keys=PROPERTY_KEYS)
        except BrokenPipeError:  # the report's reader left (``| head``)
            return 0


if __name__ == "__main__":
    sys.exit(main())
