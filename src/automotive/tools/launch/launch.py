"""Start the automotive applications together, watch them, and stop them together.

    automotive launch                                   all applications, single host (loopback)
    automotive launch vision sensor_fusion              a subset, by name
    automotive launch --except camera_pub,camera_sub    all but these
    automotive launch --vision-sensors 3                three vision sensors, config.sensorId 1, 2, 3
    automotive launch --redundant                       hot standbys: two sensor_fusion, two collision_avoidance
    automotive launch --peers 10.0.0.1,10.0.0.2 --interface eth0 vision sensor_fusion
    automotive launch -D collision_avoidance:config.alertSize=1.0 -D config.domainId=7
    automotive launch --stats-dir figures               each application's --stats records in figures/<name>.jsonl
    automotive launch --stats-dir hmi:figures           only the HMI's
    automotive launch --monitor                         and `automotive monitor`: its page on http://127.0.0.1:8780/
    automotive launch stop                              stop the running launcher (from another terminal)
    automotive launch status                            what the running launcher runs
    automotive launch --list                            the applications this version has

(``scripts/launch`` in a clone of the repository: the same, after installing what is needed.)

Modes (--mode): `window` opens one terminal window per application (a graphical terminal emulator exists and DISPLAY
is set); `tmux` opens a tmux session with the launcher in window 0 and one window per application; `background`
multiplexes every application's output into this terminal, each line prefixed with the application's name (in its
own colour on a terminal). Every mode also writes one log file per application (logs/<name>.log in the current
directory, or --log-dir). Without --mode: window
if possible, else tmux in a terminal, else background; with no terminal (a pipe, CI) always background.

The launcher owns the application processes in every mode (the windows only show their log files), so stopping works
the same everywhere: Ctrl-C, SIGTERM or `automotive launch stop` sends SIGTERM to each application, waits --stop-timeout
seconds, sends SIGKILL to any left, and prints how each one ended. An application that ends on its own is reported at
once with its exit code; the others go on. A second Ctrl-C kills at once. Before it kills an application that did not
stop, the launcher asks it for its threads' stacks (SIGUSR1), which go to its log: where it hung. The launcher
answers SIGUSR1 the same way, and `automotive launch stop` asks it before it kills a launcher that does not end.

Each application is started as ``python -m automotive.apps.<name>`` with the launcher's own interpreter, so it runs
the same installation. With --monitor the launcher also starts the monitor (``python -m
automotive.tools.monitor.monitor``, on the same domain and network options; it is a tool, not one of the applications)
beside them, watched and stopped like them, and says the page's URL once on the console.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from automotive.bus import console
from automotive.bus.cli import (
    EXIT_BAD_INPUT,
    ArgumentParser,
    add_domain_option,
    add_log_dir_option,
    add_network_options,
    add_override_option,
    output_folder_problem,
    user_help,
)
from automotive.tools.launch import plan
from automotive.tools.launch.display import MODES, choose_mode, run_in_tmux
from automotive.tools.launch.plan import (
    APPS,
    MONITOR_PORT,
    PRIMARY_STRENGTH,
    REDUNDANT_APPS,
    STANDBY_STRENGTH,
    LaunchError,
    check_settings,
    missing_reason,
)
from automotive.tools.launch.registry import DEFAULT_LOG_DIR, DEFAULT_STOP_TIMEOUT, status_command, stop_command
from automotive.tools.launch.supervisor import run_supervisor


def list_command() -> int:
    for module in APPS:
        reason = missing_reason(module)
        print(f"{module:<20} {'available' if reason is None else 'not in this version: ' + reason}")
    return 0


def printing(command: Callable[[], int]) -> int:
    """Run a command that only prints; a reader that leaves early (``--list | head -1``) ends it quietly. Only for
    such commands: the launcher itself must go on stopping its applications whatever happens to its output."""
    try:
        code = command()
        sys.stdout.flush()
        return code
    except BrokenPipeError:
        console.silence_stdout()  # Python would report the pipe again when it flushes stdout at exit
        return 0


# -- entry ----------------------------------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(
        prog=plan.PROG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Start the automotive applications together and stop them together "
                    f"(`{plan.PROG} stop` stops a running launcher, `{plan.PROG} status` shows it).",
        epilog=user_help(__doc__ or "", plan.PROG)[1] + f"\n\napplications: {', '.join(APPS)}")
    parser.add_argument("names", nargs="*", metavar="APP", help="applications to start (default: all)")
    parser.add_argument("--except", dest="exclude", action="append", default=[], metavar="A,B",
                        help="applications not to start (comma-separated, repeatable)")
    parser.add_argument("--vision-sensors", type=int, default=1, metavar="N",
                        help="start N vision sensors, config.sensorId 1..N (default 1)")
    parser.add_argument("--redundant", action="store_true",
                        help="redundant mode: a primary and a standby of " + " and ".join(REDUNDANT_APPS) +
                             f" (ownership strengths {PRIMARY_STRENGTH} and {STANDBY_STRENGTH}), exclusive ownership")
    parser.add_argument("--monitor", action="store_true",
                        help="also start `automotive monitor`: the domain live on a web page (its URL is said once)")
    parser.add_argument("--monitor-port", type=int, default=MONITOR_PORT, metavar="PORT",
                        help=f"the monitor's page port (default {MONITOR_PORT}; 0: any free one)")
    parser.add_argument("--mode", choices=MODES, default="auto",
                        help="window, tmux or background (default auto: window if a display and a terminal "
                             "emulator exist, tmux in a terminal, background otherwise)")
    add_domain_option(parser, help="DDS domain id for every application")
    add_network_options(parser, for_every="for every application: ")
    add_override_option(parser, "[APP:]KEY=VALUE",
                        "property override for every application, or for APP only (repeatable)")
    add_log_dir_option(parser, DEFAULT_LOG_DIR, "log files, pid file and summary (default: logs/ in the current "
                                                "directory)")
    parser.add_argument("--stats-dir", action="append", default=[], metavar="[APP:]DIR",
                        help="every application (or APP only) appends its status records (--stats) to "
                             "DIR/<name>.jsonl (repeatable)")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="show every line of the applications, every sample too (default: their starts and ends, "
                             "state changes, alerts and a status line every 5 s; the log files keep every line)")
    parser.add_argument("--quiet", action="store_true",
                        help="background mode: only the launcher's own lines on the console (the applications' "
                             "lines are in their log files)")
    parser.add_argument("--stop-timeout", type=float, default=DEFAULT_STOP_TIMEOUT, metavar="S",
                        help=f"seconds between SIGTERM and SIGKILL when stopping (default {DEFAULT_STOP_TIMEOUT:g})")
    parser.add_argument("--no-setup", action="store_true",
                        help="scripts/launch: do not run scripts/setup first (the launcher itself ignores it)")
    parser.add_argument("--list", action="store_true", help="list the applications and whether this version has them")
    parser.add_argument("--tmux-session", default=None, help=argparse.SUPPRESS)  # window 0 of a tmux session
    parser.add_argument("--prog", default=None, help=argparse.SUPPRESS)  # the name the launcher was started by
    return parser


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """The launcher; ``prog`` is the name it says it was started by (scripts/launch passes its own)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["--prog"] and len(argv) > 1:  # the tmux session's inner launcher
        prog, argv = argv[1], argv[2:]
    plan.PROG = prog or plan.PROG
    try:
        return _main(argv)
    except LaunchError as error:
        print(f"{plan.PROG}: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT


def _main(argv: list[str]) -> int:
    if argv[:1] == ["stop"]:
        return stop_command(argv[1:])
    if argv[:1] == ["status"]:
        return printing(lambda: status_command(argv[1:]))
    args = build_parser().parse_intermixed_args(argv)
    if args.list:
        return printing(list_command)
    problem = output_folder_problem(args.log_dir, create=True)  # before anything starts: a read-only folder too
    if problem:
        raise LaunchError(f"--log-dir {args.log_dir}: {problem}")
    specs, missing = plan.plan(args)
    check_settings(specs, args.overrides)
    if not specs:
        reasons = "; ".join(f"{name}: {reason}" for name, reason in missing)
        raise LaunchError(f"nothing to start ({reasons})" if reasons else "nothing to start")
    mode = choose_mode(args.mode)
    args.log_dir = args.log_dir.resolve()
    if mode == "tmux" and not args.tmux_session:
        return run_in_tmux(args, argv)
    return run_supervisor(args, specs, missing, mode)


if __name__ == "__main__":
    sys.exit(main())
