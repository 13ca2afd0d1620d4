"""How much the launcher's default console prints: what a person reads while the whole system runs.

    automotive bench console                          the whole system, 60 s from its start
    automotive bench console --seconds 120 --vision-sensors 3

The system runs as `automotive launch` starts it in a terminal without a display (background mode, the HMI's console
box), with the console a user gets: no log level chosen, so each application says its state changes, its alerts and
a status line every 5 s, not every sample. From the launcher's "running" line on, for --seconds, every line of its
console is counted: per application and in total, and in the last --steady seconds apart (start-up's matches left
behind). Goal: at most 2 lines a second on average over 60 s of the whole system, start-up included.

The last line is console_lines_per_s=<lines a second over the whole window>.
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import sys
import time

from automotive.bus.cli import ArgumentParser, add_domain_option
from automotive.bus.console import LOG_LEVEL_VARIABLE
from automotive.tools.support.children import Child, Line, program_command, work_folder

PROG = "automotive bench console"
GOAL_LINES_PER_S = 2.0
GOAL_SECONDS = 60.0  # the goal is judged over a minute of the whole system
RUNNING = re.compile(r"^launch\s+\| \d+ application\(s\) running")
LABEL = re.compile(r"^(\S+)\s+\| ")


def count(lines: list[Line], start: float, end: float) -> collections.Counter[str]:
    """Lines of the console that arrived in [start, end), by the label the launcher gives them."""
    counts: collections.Counter[str] = collections.Counter()
    for line in lines:
        if start <= line.time < end:
            match = LABEL.match(line.text)
            counts[match.group(1) if match else "(other)"] += 1
    return counts


def measure(args: argparse.Namespace) -> int:
    env = {**os.environ, LOG_LEVEL_VARIABLE: "", "DISPLAY": "", "WAYLAND_DISPLAY": ""}  # as a user's shell has it
    with work_folder("bench-console-") as folder:
        command = program_command("launch", "--mode", "background", "--log-dir", str(folder / "logs"),
                                  "--vision-sensors", str(args.vision_sensors), *args.launch_args)
        if args.domain is not None:
            command += ["--domain", str(args.domain)]
        launcher = Child("launch", command, env=env)
        try:
            started = launcher.wait_for_line(RUNNING, timeout=60)[0].time
            print(f"{PROG}: the system runs; counting its console lines for {args.seconds:g} s", flush=True)
            time.sleep(max(0.0, started + args.seconds - time.monotonic()))  # the measurement is a span of time
            records = list(launcher.records)
        finally:
            launcher.stop()
    whole = count(records, started, started + args.seconds)
    steady_start = started + max(0.0, args.seconds - args.steady)
    steady = count(records, steady_start, started + args.seconds)
    total, steady_total = sum(whole.values()), sum(steady.values())
    print(f"{'label':<22}{'lines':>7}{'lines/s':>9}{'last ' + format(args.steady, 'g') + ' s':>12}")
    for label, lines in whole.most_common():
        print(f"{label:<22}{lines:>7}{lines / args.seconds:>9.2f}{steady[label]:>12}")
    rate = total / args.seconds
    steady_rate = steady_total / min(args.steady, args.seconds)
    print(f"{'all':<22}{total:>7}{rate:>9.2f}{steady_total:>12}  ({steady_rate:.2f} lines/s in the last "
          f"{min(args.steady, args.seconds):g} s)")
    if args.seconds < GOAL_SECONDS:
        print(f"too short to judge: the goal is over {GOAL_SECONDS:g} s (this run: {args.seconds:g} s)")
    else:
        verdict = "met" if rate <= GOAL_LINES_PER_S else "NOT met"
        print(f"goal {verdict}: at most {GOAL_LINES_PER_S:g} lines a second on average (this run: {rate:.2f})")
    print(f"console_lines_per_s={rate:.2f}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=GOAL_SECONDS, help="how long to count (default 60)")
    parser.add_argument("--steady", type=float, default=30.0,
                        help="also count the last S seconds on their own (default 30)")
    parser.add_argument("--vision-sensors", type=int, default=1, metavar="N", help="as automotive launch (default 1)")
    parser.add_argument("launch_args", nargs="*", metavar="LAUNCH_ARG",
                        help="more arguments for the launcher, after --, e.g. -- --redundant")
    add_domain_option(parser, help="DDS domain id of the system (default: the launcher's, 0)")
    args = parser.parse_args(argv)
    if args.seconds <= 0 or args.steady <= 0:
        parser.error(f"--seconds {args.seconds:g} and --steady {args.steady:g}: expected more than 0")
    return measure(args)


if __name__ == "__main__":
    sys.exit(main())
