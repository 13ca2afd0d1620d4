"""What the user sees of a launch: the console (the launcher's and the applications' lines, each prefixed with its
name), and the modes (--mode): a terminal window or a tmux window per application showing its log file, or
background; the choice of mode, and the tmux session that runs the launcher in its window 0.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from automotive.bus.console import DescriptorStream, OutputQueue, flush_stdout, without_debug_record
from automotive.tools.launch import plan
from automotive.tools.launch.logfile import LogFile
from automotive.tools.launch.plan import LaunchError
from automotive.tools.launch.registry import SUMMARY_FILE

if TYPE_CHECKING:  # the supervisor opens a view of each application it runs
    from automotive.tools.launch.supervisor import RunningApp

MODES = ("auto", "window", "tmux", "background")
# The applications' DEBUG lines (every sample: automotive.bus.console), which the console and the windows leave out
# unless -v; the log files keep them. The console cuts a DEBUG record wherever it starts in a line (after another
# writer's open line: console.without_debug_record); a window's grep -E drops the lines that start with one.
DEBUG_LINE_GREP = "^[0-9:.]+ [^ ]+ debug: "
# Lines that must stand out: an alert raised or cleared, a lost alert source.
# Not the HMI's "no alert source" or "no alert state yet": the start of a system is no alert.
ALERT_LINE = re.compile(r"DRIVER ALERT|ALERT:|all clear|All clear|alert source (lost|LOST)")
LAUNCHER_LABEL = "launch"
CONSOLE_QUEUE_LINES = 2000  # lines held for a terminal that is not read, before applications' lines are left out
CONSOLE_CLOSE_WAIT_S = 5.0  # how long the launcher's end waits for a terminal that is not read
# The launcher's line once every application is started: what a program driving the launcher waits for.
RUNNING_LINE = rf"^{LAUNCHER_LABEL}\s+\| \d+ application\(s\) running"
COLOURS = (32, 36, 33, 35, 34, 92, 96, 93, 95, 94, 91, 31)
# Terminal emulators, by the base name of their executable: how to give a window a title and a command to run.
TERMINALS = ("x-terminal-emulator", "xterm", "gnome-terminal", "konsole", "xfce4-terminal", "mate-terminal",
             "lxterminal", "tilix", "alacritty", "kitty", "urxvt", "rxvt")


# -- output: the launcher's terminal and the log files --------------------------------------------------------------
class Console:
    """Lines of the launcher and of the applications, prefixed with their name (coloured on a terminal)."""

    def __init__(self, names: Sequence[str], show_apps: bool, launcher_log: Path | None, verbose: bool = False):
        self.verbose = verbose  # every line of the applications, their DEBUG lines (every sample) too
        self.colour = sys.stdout.isatty() and os.environ.get("NO_COLOR") is None and os.environ.get("TERM") != "dumb"
        self.width = max([len(LAUNCHER_LABEL), *map(len, names)])
        self.colours = {name: COLOURS[index % len(COLOURS)] for index, name in enumerate(names)}
        self.show_apps = show_apps
        # The terminal is written by a thread of its own (an OutputQueue): a terminal paused (Ctrl-S), a pager
        # scrolled back or a stalled ssh session blocks that thread only, never the readers of the applications'
        # output (an application whose output nobody reads blocks at its next line once its pipe is full, and the
        # alert chain with it). Beyond CONSOLE_QUEUE_LINES waiting, the applications' lines are left out (and
        # counted); the launcher's own, few, never are.
        flush_stdout()
        self._lines: OutputQueue[str] = OutputQueue(_write_out, self._left_out, CONSOLE_QUEUE_LINES, "console")
        # its own failures are said here only, not written into it
        self.launcher_log = LogFile(launcher_log, self._launcher_line) if launcher_log else None

    def _prefix(self, name: str) -> str:
        label = name.ljust(self.width)
        if not self.colour:
            return f"{label} | "
        code = "1" if name == LAUNCHER_LABEL else str(self.colours.get(name, 37))
        return f"\033[{code}m{label}\033[0m | "

    def _left_out(self, count: int) -> str:
        return (self._prefix(LAUNCHER_LABEL) + f"{count} line(s) not shown: the console was not read for a while (the "
                "log files have every line)")

    def app_line(self, name: str, text: str) -> None:
        if not self.show_apps:
            return
        if not self.verbose:
            shown = without_debug_record(text)
            if shown != text and not shown.strip():
                return  # a DEBUG line
            text = shown
        if ALERT_LINE.search(text):  # an alert must not scroll by unseen among the status lines
            text = f"\033[1;7m{text}\033[0m" if self.colour else f">>> {text}"
        self._lines.put(self._prefix(name) + text)

    def say(self, text: str) -> None:
        self._launcher_line(text)
        if self.launcher_log is not None:
            self.launcher_log.write(time.strftime("%H:%M:%S ") + text)

    def _launcher_line(self, text: str) -> None:
        self._lines.put(self._prefix(LAUNCHER_LABEL) + text, may_leave_out=False)

    def close(self) -> None:
        """The lines still queued written out, unless the terminal is still not read after CONSOLE_CLOSE_WAIT_S."""
        if self.launcher_log is not None:
            self.launcher_log.close()  # what it says of itself, first
        self._lines.close(CONSOLE_CLOSE_WAIT_S)


def _write_out(line: str) -> None:
    """``line`` and its newline on standard output, written at once. Through its file descriptor when it has one
    (DescriptorStream): a write that blocks holds none of Python's locks then, and an interpreter ending meanwhile (the
    thread is a daemon) does not wait."""
    try:
        try:
            descriptor = sys.stdout.fileno()
        except (OSError, ValueError):  # a stream without one (a test's capture)
            sys.stdout.write(line + "\n")
            sys.stdout.flush()
            return
        DescriptorStream(descriptor).write(line + "\n")
    except (OSError, ValueError):
        pass  # nobody reads our output any more (a closed pipe, a terminal gone): the log files still have it


# -- views: windows or tmux windows that show the log files ---------------------------------------------------------
def tail_command(log_path: Path, verbose: bool = False) -> list[str]:
    """The command a window runs to show a log file: every line with ``verbose``, else without the DEBUG lines."""
    # --pid: the view closes by itself when the launcher is gone, whatever the terminal or multiplexer.
    tail = ["tail", f"--pid={os.getpid()}", "-n", "+1", "-F", str(log_path)]
    if verbose:
        return tail
    return ["sh", "-c", f'{shlex.join(tail)} | grep --line-buffered -v -E "$0"', DEBUG_LINE_GREP]


def find_terminal() -> str | None:
    for candidate in TERMINALS:
        path = shutil.which(candidate)
        if path:
            return path
    return None


def terminal_command(terminal: str, title: str, command: list[str]) -> list[str]:
    kind = Path(os.path.realpath(terminal)).name
    if kind.endswith("xterm") or kind in ("x-terminal-emulator",):
        return [terminal, "-T", title, "-e", *command]
    if kind.startswith("gnome-terminal"):
        return [terminal, "--title", title, "--", *command]
    if kind.startswith("konsole"):
        return [terminal, "-p", f"tabtitle={title}", "-e", *command]
    if kind.startswith(("xfce4-terminal", "mate-terminal")):
        return [terminal, "-T" if kind.startswith("xfce4") else "-t", title, "-x", *command]
    if kind.startswith(("lxterminal", "tilix")):
        return [terminal, "-t", title, "-e", shlex.join(command)]
    if kind.startswith("alacritty"):
        return [terminal, "-t", title, "-e", *command]
    if kind.startswith("kitty"):
        return [terminal, "--title", title, *command]
    if kind.startswith(("urxvt", "rxvt")):
        return [terminal, "-title", title, "-e", *command]
    return [terminal, "-e", *command]


class Views:
    """Nothing to show besides the launcher's own output (background mode)."""

    def open(self, app: RunningApp) -> None:
        pass

    def close(self) -> None:
        pass


class WindowViews(Views):
    def __init__(self, terminal: str, console: Console):
        self.terminal = terminal
        self.console = console
        self.windows: list[subprocess.Popen[bytes]] = []

    def open(self, app: RunningApp) -> None:
        command = terminal_command(self.terminal, f"{app.name} (automotive)",
                                   tail_command(app.log_path, self.console.verbose))
        try:
            self.windows.append(subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                                 stderr=subprocess.DEVNULL, start_new_session=True))
        except OSError as error:
            self.console.say(f"cannot open a window for {app.name} ({error}); its output is in {app.log_path}")

    def close(self) -> None:
        for window in self.windows:
            if window.poll() is None:
                window.terminate()
        for window in self.windows:
            try:
                window.wait(timeout=2)
            except subprocess.TimeoutExpired:
                window.kill()


class TmuxViews(Views):
    def __init__(self, session: str, console: Console):
        self.session = session
        self.console = console
        self.window_ids: list[str] = []

    def open(self, app: RunningApp) -> None:
        result = subprocess.run(["tmux", "new-window", "-d", "-P", "-F", "#{window_id}", "-t", f"{self.session}:",
                                 "-n", app.name, shlex.join(tail_command(app.log_path, self.console.verbose))],
                                capture_output=True, text=True)
        if result.returncode == 0:
            self.window_ids.append(result.stdout.strip())
        else:
            self.console.say(f"cannot open a tmux window for {app.name}: {result.stderr.strip()}")

    def close(self) -> None:
        for window_id in self.window_ids:
            subprocess.run(["tmux", "kill-window", "-t", window_id], capture_output=True)


# -- modes ----------------------------------------------------------------------------------------------------------
def interactive() -> bool:
    return sys.stdin.isatty() and sys.stdout.isatty() and not os.environ.get("CI")


def choose_mode(requested: str) -> str:
    if requested == "window":
        if not os.environ.get("DISPLAY"):
            raise LaunchError("--mode window: DISPLAY is not set (no graphical display)")
        if find_terminal() is None:
            raise LaunchError(f"--mode window: no terminal emulator found (looked for {', '.join(TERMINALS)})")
        return "window"
    if requested == "tmux":
        if shutil.which("tmux") is None:
            raise LaunchError("--mode tmux: tmux is not installed")
        return "tmux"
    if requested == "background":
        return "background"
    if not interactive():
        return "background"
    if os.environ.get("DISPLAY") and find_terminal() is not None:
        return "window"
    if shutil.which("tmux") is not None:
        return "tmux"
    return "background"


def tmux_session_name(args: argparse.Namespace) -> str:
    return "automotive" + (f"-domain{args.domain}" if args.domain is not None else "")


def run_in_tmux(args: argparse.Namespace, argv: list[str]) -> int:
    """Start a tmux session whose window 0 runs this launcher (background mode, plus one tmux window per app)."""
    session = tmux_session_name(args)
    if subprocess.run(["tmux", "has-session", "-t", f"={session}"], capture_output=True).returncode == 0:
        raise LaunchError(f"tmux session '{session}' already exists: `tmux attach -t {session}` to see it, "
                          f"`{plan.PROG} stop` to stop it")
    inner = [sys.executable, "-m", "automotive.start", "automotive.tools.launch.launch", "--prog", plan.PROG, *argv,
             "--mode", "background", "--log-dir", str(args.log_dir), "--tmux-session", session]
    # A running tmux server starts new sessions with its own environment: hand over what the applications need.
    passed = {key: os.environ[key] for key in ("CYCLONEDDS_URI", "DISPLAY", "WAYLAND_DISPLAY", "XAUTHORITY",
                                               "PYTHONPATH", "PATH", "NO_COLOR") if key in os.environ}
    # The session ends with the launcher; its summary stays in logs/launch-summary.txt (printed by us or by stop).
    shell = shlex.join(["env", *(f"{key}={value}" for key, value in passed.items()), *inner])
    result = subprocess.run(["tmux", "new-session", "-d", "-s", session, "-n", LAUNCHER_LABEL, "-c", os.getcwd(),
                             "-x", "200", "-y", "50", shell], capture_output=True, text=True)
    if result.returncode != 0:
        raise LaunchError(f"tmux could not start session '{session}': {result.stderr.strip()}")
    log_dir: Path = args.log_dir
    if os.environ.get("TMUX"):
        switched = subprocess.run(["tmux", "switch-client", "-t", session], capture_output=True, text=True)
        if switched.returncode == 0:
            print(f"launch: switched to tmux session '{session}'; `{plan.PROG} stop` stops it")
        else:  # the system runs all the same: say how to see it
            print(f"launch: running in tmux session '{session}', but could not switch to it "
                  f"({switched.stderr.strip() or 'tmux switch-client failed'}): `tmux attach -t {session}` to "
                  f"watch, `{plan.PROG} stop` to stop")
        return 0
    if not interactive():
        print(f"launch: running in tmux session '{session}': `tmux attach -t {session}` to watch, "
              f"`{plan.PROG} stop` to stop")
        return 0
    subprocess.run(["tmux", "attach-session", "-t", session])
    if subprocess.run(["tmux", "has-session", "-t", f"={session}"], capture_output=True).returncode == 0:
        print(f"launch: detached; the system runs on in tmux session '{session}': `tmux attach -t {session}` to "
              f"watch, `{plan.PROG} stop` to stop")
        return 0
    summary = log_dir / SUMMARY_FILE
    if summary.is_file():
        print(summary.read_text(), end="")
    return 0


