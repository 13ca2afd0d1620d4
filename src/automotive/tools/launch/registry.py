"""How a running launcher is found, from any folder: the pid file in its log folder (its applications' pids), and
its entry in the user's runtime folder; ``automotive launch stop`` and ``automotive launch status``, which use them.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import signal
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from automotive.bus.cli import DUMP_STACKS_SIGNAL, EXIT_BAD_INPUT, ArgumentParser, add_domain_option, add_log_dir_option
from automotive.tools.launch import plan
from automotive.tools.support import children

DEFAULT_LOG_DIR = Path("logs")
STACK_DUMP_WAIT_S = 1.0  # the time given to a hung process to write its threads' stacks before SIGKILL
# What the launcher may still take after its stop timeout, at worst: the stack dump, 5 s for the killed to end, 2 s
# per output stream for their last lines. `launch stop` gives it that, and a margin, before it kills the launcher.
STOP_MARGIN_S = STACK_DUMP_WAIT_S + 5 + 2 * 2 + 5
DEFAULT_STOP_TIMEOUT = 10.0
PID_FILE = "launch.pid"
SUMMARY_FILE = "launch-summary.txt"


# -- the pid file: how `automotive launch stop` finds the launcher and its applications ------------------------------
pid_cmdline = children.command_line
pid_alive = children.alive


def read_pid_file(log_dir: Path) -> dict[str, object] | None:
    try:
        data = json.loads((log_dir / PID_FILE).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def launcher_running(info: dict[str, object]) -> int | None:
    pid = info.get("launcher")
    if isinstance(pid, int) and pid != os.getpid() and pid_alive(pid) and "launch" in pid_cmdline(pid):
        return pid
    return None


# -- the user's running launchers: how `launch stop` and `status` find one from any folder ---------------------------
# Each launcher also leaves a small file in a folder of this user's (one per launcher: its pid, log folder and
# domain), so that `stop` and `status` find it wherever they are typed; the pid file in the log folder stays the
# record of its applications.
def runtime_folder() -> Path:
    """This user's folder of running launchers: $XDG_RUNTIME_DIR/automotive (the session's, private), else
    /tmp/automotive-<uid>."""
    base = os.environ.get("XDG_RUNTIME_DIR", "")
    if base and Path(base).is_dir():
        return Path(base) / "automotive"
    return Path(tempfile.gettempdir()) / f"automotive-{os.getuid()}"


@dataclass
class RegisteredLauncher:
    pid: int
    log_dir: Path
    domain: int
    entry: Path  # its file in the runtime folder

    def describe(self) -> str:
        return f"pid {self.pid}, domain {self.domain}, logs in {self.log_dir}"


def register_launcher(log_dir: Path, domain: int) -> Path | None:
    """Enter this launcher in the user's runtime folder; None (and no entry) when the folder cannot be written: the
    launcher runs all the same, `stop --log-dir` still finds it."""
    folder = runtime_folder()
    entry = folder / f"launcher-{os.getpid()}.json"
    for _ in range(2):  # again if the last launcher to leave removed the folder in between
        try:
            folder.mkdir(mode=0o700, parents=True, exist_ok=True)
            temporary = folder / f".{entry.name}.tmp"
            temporary.write_text(json.dumps({"launcher": os.getpid(), "log_dir": str(log_dir), "domain": domain}))
            temporary.replace(entry)
            return entry
        except OSError:
            continue
    return None


def unregister_launcher(entry: Path) -> None:
    """Remove a launcher's entry, and the user's folder of them once empty (nothing left behind in TMPDIR)."""
    entry.unlink(missing_ok=True)
    try:
        entry.parent.rmdir()
    except OSError:  # another launcher's entry is there (or the folder is gone already)
        pass


def registered_launchers() -> list[RegisteredLauncher]:
    """The user's registered launchers whose log folder's pid file still names them; entries of launchers that are
    gone and left no applications are removed."""
    found: list[RegisteredLauncher] = []
    for entry in sorted(runtime_folder().glob("launcher-*.json")):
        try:
            data = json.loads(entry.read_text())
            launcher = RegisteredLauncher(int(data["launcher"]), Path(data["log_dir"]), int(data["domain"]), entry)
        except (OSError, ValueError, KeyError, TypeError):
            continue
        info = read_pid_file(launcher.log_dir)
        if info is None or info.get("launcher") != launcher.pid or (
                launcher_running(info) is None and not app_pids(info)):
            unregister_launcher(entry)
            continue
        found.append(launcher)
    return found


# -- stop and status ------------------------------------------------------------------------------------------------
def app_pids(info: dict[str, object]) -> dict[str, int]:
    apps = info.get("apps")
    modules = info.get("module")
    if not isinstance(apps, dict) or not isinstance(modules, dict):
        return {}
    # Only processes that still are these applications (a pid may have been reused since).
    return {name: pid for name, pid in apps.items() if isinstance(pid, int) and pid_alive(pid)
            and children.program_module(str(modules.get(name))) in pid_cmdline(pid)}


def stop_hint(log_dir: Path) -> str:
    """The command that stops the launcher of ``log_dir`` from any folder: plain while it is the user's only one."""
    others = [launcher for launcher in registered_launchers() if launcher.pid != os.getpid()]
    return f"{plan.PROG} stop" + (f" --log-dir {shlex.quote(str(log_dir))}" if others else "")


def add_choice_options(parser: argparse.ArgumentParser) -> None:
    add_log_dir_option(parser, None, "the launcher whose logs are in this folder (its --log-dir)")
    add_domain_option(parser, help="the launcher running on this domain")


def chosen_launchers(args: argparse.Namespace) -> list[tuple[Path, dict[str, object]]]:
    """The launchers (log folder, pid file) that ``--log-dir`` or ``--domain`` name, or all of this user's."""
    if args.log_dir is not None:
        info = read_pid_file(args.log_dir)
        return [] if info is None else [(args.log_dir, info)]
    chosen = []
    for launcher in registered_launchers():
        info = read_pid_file(launcher.log_dir)
        if info is not None and (args.domain is None or launcher.domain == args.domain):
            chosen.append((launcher.log_dir, {**info, "domain": launcher.domain}))
    if not chosen and args.domain is None:  # a launcher of a version that did not register: the current folder's
        info = read_pid_file(DEFAULT_LOG_DIR)
        if info is not None:
            chosen.append((DEFAULT_LOG_DIR.resolve(), info))
    return chosen


def describe_launcher(log_dir: Path, info: dict[str, object]) -> str:
    domain = info.get("domain")
    return f"pid {info.get('launcher')}" + (f", domain {domain}" if domain is not None else "") + f", logs in {log_dir}"


def no_launcher(args: argparse.Namespace) -> str:
    if args.log_dir is not None:
        return f"no launcher is running with its logs in {args.log_dir} (no {args.log_dir / PID_FILE})"
    if args.domain is not None:
        return f"no launcher of yours is running on domain {args.domain}"
    return "no launcher of yours is running"


def stop_command(argv: list[str]) -> int:
    parser = ArgumentParser(prog=f"{plan.PROG} stop", description="Stop the running launcher (found from any folder; "
                                                             "--log-dir or --domain choose one of several).")
    add_choice_options(parser)
    parser.add_argument("--timeout", type=float, default=None,
                        help=f"how long to wait for the launcher (default: its stop timeout + {STOP_MARGIN_S:g} s)")
    args = parser.parse_args(argv)
    chosen = chosen_launchers(args)
    if not chosen:
        print(f"{plan.PROG} stop: {no_launcher(args)}", file=sys.stderr)
        return 1
    if len(chosen) > 1:
        listed = "; ".join(describe_launcher(log_dir, info) for log_dir, info in chosen)
        print(f"{plan.PROG} stop: {len(chosen)} launchers are running ({listed}): choose one with --domain N or "
              "--log-dir DIR", file=sys.stderr)
        return EXIT_BAD_INPUT
    log_dir, info = chosen[0]
    launcher = launcher_running(info)
    if launcher is None:  # the launcher died without cleaning up: end what it left behind
        leftovers = app_pids(info)
        for name, pid in leftovers.items():
            os.kill(pid, signal.SIGKILL)
            print(f"launch stop: the launcher had died; killed its leftover {name} (pid {pid})")
        if not leftovers:
            print("launch stop: no launcher is running (stale pid file removed)")
        (log_dir / PID_FILE).unlink(missing_ok=True)
        registered_launchers()  # drops the dead launcher's entry
        return 0
    stop_timeout = info.get("stop_timeout")
    timeout = args.timeout if args.timeout is not None else (
        float(stop_timeout) if isinstance(stop_timeout, (int, float)) else DEFAULT_STOP_TIMEOUT) + STOP_MARGIN_S
    print(f"launch stop: stopping the launcher ({describe_launcher(log_dir, info)})")
    os.kill(launcher, signal.SIGTERM)
    deadline = time.monotonic() + timeout
    while pid_alive(launcher) and time.monotonic() < deadline:
        time.sleep(0.1)  # not our child: polling /proc is the only way to see it end
    if pid_alive(launcher):
        os.kill(launcher, DUMP_STACKS_SIGNAL)  # where the launcher hangs, on its stderr, before it is killed
        print(f"launch stop: the launcher did not end within {timeout:g} s: asked for its threads' stacks (on its "
              "stderr)")
        time.sleep(STACK_DUMP_WAIT_S)  # not our child: nothing to wait on but the time faulthandler needs
        for name, pid in app_pids(info).items():
            os.kill(pid, signal.SIGKILL)
            print(f"launch stop: killed {name} (pid {pid})")
        os.kill(launcher, signal.SIGKILL)
        print("launch stop: killed the launcher")
        (log_dir / PID_FILE).unlink(missing_ok=True)
        registered_launchers()
        return 1
    summary = log_dir / SUMMARY_FILE
    if summary.is_file():
        print(summary.read_text(), end="")
    return 0


def status_command(argv: list[str]) -> int:
    parser = ArgumentParser(prog=f"{plan.PROG} status", description="What the running launchers run (found from any "
                                                               "folder; --log-dir or --domain choose one).")
    add_choice_options(parser)
    args = parser.parse_args(argv)
    running = [(log_dir, info) for log_dir, info in chosen_launchers(args) if launcher_running(info) is not None]
    if not running:
        print(f"launch status: {no_launcher(args)}")
        return 1
    for log_dir, info in running:
        print(f"launcher {describe_launcher(log_dir, info)}, {info.get('mode')} mode")
        alive = app_pids(info)
        apps = info.get("apps")
        for name, pid in (apps.items() if isinstance(apps, dict) else []):
            print(f"  {name:<20} pid {pid:<7} {'running' if name in alive else 'ended'}")
    return 0

