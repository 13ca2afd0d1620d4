"""Monitor: who talks to whom on the domain, why a writer and a reader do not match, and how the data flows.

    automotive monitor                   serves the page on http://127.0.0.1:8780/, updated every second
    automotive monitor --port 8781 --bind 0.0.0.0 --token T     the page for other hosts: every request needs T
    automotive monitor --once            the domain as text after a discovery window (--wait S), then exit
    automotive monitor --json            the same as one JSON document
    automotive monitor --text            the text again whenever the graph, the matches or a program's health change

It joins the domain read-only, with the common options of every program (--domain, -D config.domainId=..., the
network options), so it sees what the applications see. It reads:

- the built-in discovery topics: every participant (its name, vendor, host and process where discovery tells them),
  every writer and reader with its topic, type and QoS;
- rt/diagnostics, every program's health (automotive.bus.diagnostics): the samples per second of each topic, the age
  of its last sample, deadline misses, liveliness changes and lost samples as the programs report them, and the
  latency each reader measures (p50/p99 over 10 s per topic and per writer: shown per topic, per pair and for the
  alert chain, marked "~" where writer and reader are on different hosts and so do not share a clock);
- the system's flows with its own best-effort raw readers (automotive.tools.monitor.probes): each flow's bytes/s,
  samples/s and last sample's age, and the vehicle (the alert and, in redundant mode, its owner; speed, steer,
  blinker; the fused objects; the LiDAR picture), decoding only what it shows. It never reads the camera's frames
  unless asked (--camera): their rate and latency come from camera_sub's /diagnostics. The LiDAR's clouds and the
  camera's frames of writers on its host come through shared memory, as the recorder reads them (config.transport,
  config.shmPrefix): the monitor makes no writer of its host write them on DDS.

Which writer/reader pairs match is its judgement by the DDS rules (automotive.tools.monitor.rules); for every pair
of the same topic that does not, it gives the reasons in words, offered against requested. It writes no data: only its
own /diagnostics, as every program. Its report goes to stdout, its log to stderr.

The page (automotive.tools.monitor.server, its files in automotive/tools/monitor/page): the graph, the match
analysis, the flows, the programs' health and the vehicle, live over a WebSocket. The snapshot is made at most once a
second and only while a page (or a script reading /snapshot.json) watches; it is serialized once for every page.
Binding to another address than a loopback one needs --token; without it the monitor refuses to start.

Exit codes: 0 done (--once, --json) or stopped (Ctrl-C, SIGTERM); 2 bad input, or the page's port cannot be had (one
line on stderr).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
from typing import TextIO

from automotive.bus.app import Application, build_parser, run
from automotive.bus.cli import EXIT_BAD_INPUT
from automotive.bus.console import LOG_LEVEL_VARIABLE
from automotive.bus.errors import ConfigError
from automotive.bus.properties import PropertyKeys
from automotive.tools.flows import check_transport
from automotive.tools.monitor.discovery import DomainView
from automotive.tools.monitor.model import Snapshot
from automotive.tools.monitor.server import DEFAULT_BIND, DEFAULT_PORT, PageServer, bind_problem, describe
from automotive.tools.monitor.text import render

PROPERTY_KEYS = PropertyKeys.of("config.transport", "config.shmPrefix")
DEFAULT_WAIT_S = 3.0  # discovery on one host takes well under a second; the programs report every second
MAX_WAIT_S = 3600.0
POLL_S = 0.5
UPDATE_S = 1.0  # the page's snapshots: at most one a second
TICK_S = 0.2  # how soon a page that connects gets its first snapshot
URL_LINE = "automotive monitor: the page is on "  # what `automotive launch --monitor` looks for


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
    check_transport(app.props)
    view = DomainView(app.bus, camera=args.camera, props=app.props)
    try:
        watch(app, view, out)
    finally:
        view.close()


def watch(app: Application, view: DomainView, out: TextIO) -> None:
    args = app.args
    app.optional_topics.add(view.diagnostics.topic.get_name())  # no program reporting is no fault of the monitor's
    app.ready()
    once = args.once or args.json
    if once:
        deadline = time.monotonic() + args.wait
        while not app.stop_event.wait(max(0.0, min(POLL_S, deadline - time.monotonic()))):
            view.poll()  # the probes' readers keep a bounded history: taken as it comes
            if time.monotonic() >= deadline:
                break
        snapshot = view.snapshot()
        for problem in view.problems:
            app.log.warning("%s", problem)
        out.write(snapshot.to_json() + "\n" if args.json else render(snapshot))
        out.flush()
        return
    if args.text:
        live_text(app, view, out)
    else:
        serve(app, view, out)


def live_text(app: Application, view: DomainView, out: TextIO) -> None:
    """The text again whenever the graph, the matches or a program's health change."""
    last: tuple[object, ...] | None = None
    app.stop_event.wait(min(app.args.wait, 1.0))
    while app.running:
        snapshot = view.snapshot()
        current = signature(snapshot)
        if current != last:
            out.write(render(snapshot) + "\n")
            out.flush()
            last = current
        if app.stop_event.wait(POLL_S):
            break


def serve(app: Application, view: DomainView, out: TextIO) -> None:
    """The page: a snapshot a second while someone watches, serialized once for every page."""
    args = app.args
    # The other side's renderer of the LiDAR cloud (automotive.tools.monitor.probes), when the view has one.
    lidar_png = getattr(getattr(view, "probes", None), "lidar_png", None)
    server = PageServer(args.bind, args.port, args.token, app.log, lidar_png if callable(lidar_png) else None)
    try:
        url = server.start()
    except OSError as error:
        raise ConfigError(describe(error, args.bind, args.port)) from None
    try:
        out.write(f"{URL_LINE}{url}\n")
        out.flush()
        said: set[str] = set()
        next_update = 0.0
        last_poll = time.monotonic()
        while app.running:
            now = time.monotonic()
            if server.watched:
                if now >= next_update:
                    next_update = now + UPDATE_S
                    last_poll = now
                    server.publish(view.snapshot().to_json(indent=None))
                    for problem in view.problems:
                        if problem not in said:
                            said.add(problem)
                            app.log.warning("%s", problem)
            elif now - last_poll >= UPDATE_S:  # nobody watches: only keep the reports (and the readers) drained
                last_poll = now
                view.poll()
            if app.stop_event.wait(TICK_S):
                break
    finally:
        server.stop()


def seconds(text: str) -> float:
    """An argparse type: the discovery window, 0..MAX_WAIT_S seconds."""
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0 <= value <= MAX_WAIT_S:  # NaN too
        raise argparse.ArgumentTypeError(f"expected seconds from 0 to {MAX_WAIT_S:g}, not '{text}'")
    return value


def port(text: str) -> int:
    """An argparse type: a TCP port, 0 (the system chooses; the URL printed says which) to 65535."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"expected a port from 0 to 65535, not '{text}'")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--once", action="store_true", help="print the domain as text once, after --wait, and exit")
    parser.add_argument("--json", action="store_true", help="print the domain as one JSON document, and exit")
    parser.add_argument("--text", action="store_true",
                        help="no page: print the text again whenever the graph, the matches or a health change")
    parser.add_argument("--bind", default=DEFAULT_BIND, metavar="ADDRESS",
                        help=f"the page's address (default {DEFAULT_BIND}: this host only; any other needs --token)")
    parser.add_argument("--port", type=port, default=DEFAULT_PORT,
                        help=f"the page's TCP port (default {DEFAULT_PORT}; 0: any free one, the URL printed says)")
    parser.add_argument("--token", default=None, metavar="T",
                        help="a secret every request to the page must carry (?token=T): required to --bind beyond "
                             "this host")
    parser.add_argument("--camera", action="store_true",
                        help="also read the camera's frames (counted, never decoded) for their bytes/s; without it "
                             "the camera's flow is what the programs' /diagnostics say")
    parser.add_argument("--wait", type=seconds, default=DEFAULT_WAIT_S, metavar="S",
                        help=f"the discovery window before the first report (default {DEFAULT_WAIT_S:g} s)")


DESCRIPTION = __doc__ or ""  # --help: its first paragraph and its examples (automotive.bus.cli.user_help)


def main(argv: list[str] | None = None) -> int:
    # --help and --version answer on stdout, a bad option with one line and exit code 2, before anything starts.
    parser = build_parser("monitor", DESCRIPTION, add_arguments, "automotive monitor")
    parsed = parser.parse_args(argv)
    problem = None if parsed.once or parsed.json or parsed.text else bind_problem(parsed.bind, parsed.token)
    if problem:  # before the domain is joined
        print(f"{parser.prog}: {problem}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if (parsed.once or parsed.json) and not parsed.verbose:  # a one-shot answer only: its log (matches, "stopped")
        os.environ.setdefault(LOG_LEVEL_VARIABLE, "warning")  # with -v, or as the user's variable says
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
