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
import ctypes
import importlib.util
import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from automotive import config
from automotive.bus import realtime
from automotive.bus.cli import (
    DUMP_STACKS_SIGNAL,
    EXIT_BAD_INPUT,
    ArgumentParser,
    add_domain_option,
    add_log_dir_option,
    add_network_options,
    add_override_option,
    dump_stacks_on_request,
    on_signals,
    output_folder_problem,
    stop_dumping_stacks,
    user_help,
)
from automotive.bus.console import LOG_LEVEL_VARIABLE, without_debug_record
from automotive.bus.ports import check_domain_id
from automotive.tools.support import children
from automotive.tools.support.children import Child, Line

# Every application of the system, in the order they are listed and started.
APPS = children.APPS
PROG = "automotive launch"
DEFAULT_LOG_DIR = Path("logs")
MODES = ("auto", "window", "tmux", "background")
# Redundant mode (--redundant): these run twice, as <name> (the primary) and <name>-2 (the standby), with exclusive
# ownership; readers follow the stronger live instance.
REDUNDANT_APPS = ("sensor_fusion", "collision_avoidance")
PRIMARY_STRENGTH, STANDBY_STRENGTH = 20, 10
# The applications of the alert chain (a vision sample to the driver's alert and the platform's command) run with a
# modest real-time priority and their memory locked, where the host permits it (automotive.bus.realtime; an
# application that is not permitted says so in one line and runs without). Not the camera or the LiDAR: their loops
# move megabytes a frame, and at a real-time priority they would take a core from everything else. Given before the
# user's -D settings, which replace them (-D config.realtimePriority=0 turns it off).
REALTIME_APPS = ("vision", "sensor_fusion", "collision_avoidance", "hmi", "vehicle_platform")
REALTIME_PRIORITY = 10
REALTIME_SETTINGS = (f"{realtime.PRIORITY_KEY}={REALTIME_PRIORITY}", f"{realtime.LOCK_MEMORY_KEY}=true")
STACK_DUMP_WAIT_S = 1.0  # the time given to a hung process to write its threads' stacks before SIGKILL
SECOND_INTERRUPT_AFTER_S = 0.5  # an interrupt sooner than this after the first is the same one, delivered twice
# What the launcher may still take after its stop timeout, at worst: the stack dump, 5 s for the killed to end, 2 s
# per output stream for their last lines. `launch stop` gives it that, and a margin, before it kills the launcher.
STOP_MARGIN_S = STACK_DUMP_WAIT_S + 5 + 2 * 2 + 5
DEFAULT_STOP_TIMEOUT = 10.0
PID_FILE = "launch.pid"
# The applications' DEBUG lines (every sample: automotive.bus.console), which the console and the windows leave out
# unless -v; the log files keep them. The console cuts a DEBUG record wherever it starts in a line (after another
# writer's open line: console.without_debug_record); a window's grep -E drops the lines that start with one.
DEBUG_LINE_GREP = "^[0-9:.]+ [^ ]+ debug: "
# Lines that must stand out: an alert raised or cleared, a lost alert source.
# Not the HMI's "no alert source" or "no alert state yet": the start of a system is no alert.
ALERT_LINE = re.compile(r"DRIVER ALERT|ALERT:|all clear|All clear|alert source (lost|LOST)")
SUMMARY_FILE = "launch-summary.txt"
MONITOR = "monitor"  # --monitor: the tool's name, as a label and as a program (automotive.tools.monitor.monitor)
MONITOR_PORT = 8780  # the monitor's default (automotive.tools.monitor.server.DEFAULT_PORT)
# The monitor's line that gives its page's URL (automotive.tools.monitor.monitor.URL_LINE): said once by the launcher.
MONITOR_URL_LINE = re.compile(r"^automotive monitor: the page is on (\S+)$")
# The -D settings of every application that the monitor takes too (it refuses keys it does not read).
MONITOR_KEYS = ("config.domainId", "config.transport", "config.shmPrefix")  # shared memory: as the apps
LAUNCHER_LABEL = "launch"
# The launcher's line once every application is started: what a program driving the launcher waits for.
RUNNING_LINE = rf"^{LAUNCHER_LABEL}\s+\| \d+ application\(s\) running"
COLOURS = (32, 36, 33, 35, 34, 92, 96, 93, 95, 94, 91, 31)
PR_SET_PDEATHSIG = 1
# Terminal emulators, by the base name of their executable: how to give a window a title and a command to run.
TERMINALS = ("x-terminal-emulator", "xterm", "gnome-terminal", "konsole", "xfce4-terminal", "mate-terminal",
             "lxterminal", "tilix", "alacritty", "kitty", "urxvt", "rxvt")


class LaunchError(Exception):
    """Bad input or an impossible request: one line on stderr, exit code 2."""


# -- the applications to start ---------------------------------------------------------------------------------------
@dataclass
class AppSpec:
    name: str  # unique label: the module name, or vision-1, vision-2 ... with several vision sensors
    module: str  # automotive.apps.<module>
    args: list[str]

    @property
    def command(self) -> list[str]:
        return children.program_command(self.module, *self.args)


def missing_reason(module: str) -> str | None:
    """Why an application of the list cannot start in this version of the project, or None if it can."""
    if importlib.util.find_spec(children.program_module(module)) is None:
        return f"module {children.program_module(module)} is missing"
    if not config.properties_file(module).is_file():
        return f"the shipped properties/{module}.properties is missing"
    return None


def split_names(values: Sequence[str], what: str) -> list[str]:
    names = [name.strip() for value in values for name in value.split(",") if name.strip()]
    for name in names:
        if name not in APPS:
            raise LaunchError(f"{what}: unknown application '{name}'; expected one of: {', '.join(APPS)}")
    return names


def overrides_for(module: str, name: str, overrides: Sequence[str]) -> list[str]:
    """The -D arguments for one application: KEY=VALUE for all, APP:KEY=VALUE for that application only."""
    args: list[str] = []
    for item in overrides:
        target, _, setting = item.rpartition(":") if re.match(r"^[\w-]+:", item) else ("", "", item)
        if target and target not in (module, name):
            continue
        args += ["-D", setting]
    return args


def check_overrides(overrides: Sequence[str], vision_sensors: int, redundant: bool = False) -> None:
    instance_names = {f"vision-{i}" for i in range(1, vision_sensors + 1)} if vision_sensors > 1 else set()
    if redundant:
        instance_names |= {f"{module}-2" for module in REDUNDANT_APPS}
    for item in overrides:
        match = re.match(r"^([\w-]+):(.*)$", item)
        setting = match.group(2) if match else item
        if match and match.group(1) not in APPS and match.group(1) not in instance_names:
            raise LaunchError(f"-D {item}: unknown application '{match.group(1)}'; expected one of: {', '.join(APPS)}")
        if "=" not in setting or not setting.split("=", 1)[0].strip():
            raise LaunchError(f"-D {item}: expected KEY=VALUE or APP:KEY=VALUE")
        key, _, value = setting.partition("=")
        if key.strip() == "config.domainId":  # said once here, as --domain says it, not by every application
            try:
                check_domain_id(value.strip())
            except ValueError as error:
                raise LaunchError(f"-D {item}: {error}") from None


def plan(args: argparse.Namespace) -> tuple[list[AppSpec], list[tuple[str, str]]]:
    """The applications to start, and the requested ones that this version does not have (name, reason)."""
    chosen = split_names(args.names, "application list") or list(APPS)
    excluded = set(split_names(args.exclude, "--except"))
    if args.vision_sensors < 1:
        raise LaunchError(f"--vision-sensors {args.vision_sensors}: expected 1 or more")
    check_overrides(args.overrides, args.vision_sensors, args.redundant)
    common: list[str] = []
    for flag in ("domain", "network", "interface", "peers"):
        value = getattr(args, flag)
        if value is not None:
            common += [f"--{flag}", str(value)]
    if args.redundant:
        common += ["-D", "config.redundant=true"]
    specs: list[AppSpec] = []
    missing: list[tuple[str, str]] = []
    for module in APPS:  # the system's order, whatever the order on the command line
        if module not in chosen or module in excluded:
            continue
        reason = missing_reason(module)
        if reason is not None:
            missing.append((module, reason))
            continue
        extra = ["--ui", "auto"] if module == "hmi" else []
        own = [*common, *(arg for setting in REALTIME_SETTINGS for arg in ("-D", setting))] \
            if module in REALTIME_APPS else common
        if module == "vision" and args.vision_sensors > 1:
            for sensor in range(1, args.vision_sensors + 1):
                name = f"vision-{sensor}"
                specs.append(AppSpec(name, module, [*own, "-D", f"config.sensorId={sensor}",
                                                    *overrides_for(module, name, args.overrides)]))
        elif module in REDUNDANT_APPS and args.redundant:
            for name, strength in ((module, PRIMARY_STRENGTH), (f"{module}-2", STANDBY_STRENGTH)):
                specs.append(AppSpec(name, module, [*own, "-D", f"config.instanceName={name}",
                                                    "-D", f"config.ownershipStrength={strength}",
                                                    *overrides_for(module, name, args.overrides)]))
        else:
            specs.append(AppSpec(module, module, [*own, *overrides_for(module, module, args.overrides), *extra]))
    if not 0 <= args.monitor_port <= 65535:
        raise LaunchError(f"--monitor-port {args.monitor_port}: expected a port from 0 to 65535")
    if args.monitor and specs:
        settings = [item for item in args.overrides if not re.match(r"^[\w-]+:", item)
                    and item.split("=", 1)[0].strip() in MONITOR_KEYS]
        flags = [arg for flag in ("domain", "network", "interface", "peers") if getattr(args, flag) is not None
                 for arg in (f"--{flag}", str(getattr(args, flag)))]  # the applications' own, less redundant mode
        specs.append(AppSpec(MONITOR, MONITOR, [*flags, "--port", str(args.monitor_port),
                                                 *(arg for item in settings for arg in ("-D", item))]))
    for spec in specs:
        if spec.module == MONITOR:
            continue
        folder = stats_folder(spec.module, spec.name, args.stats_dir)
        if folder is not None:
            spec.args += ["--stats", str(folder / f"{spec.name}.jsonl")]
    return specs, missing


def check_settings(specs: list[AppSpec], overrides: Sequence[str]) -> None:
    """Each application given a -D APP:KEY=VALUE of its own reads its settings once, without joining the bus, before
    any is started: a key it does not know stops the launch with its one line, instead of that application ending
    with exit code 2 while the others run on. (A -D KEY=VALUE for all goes to every application, so a key one of
    them does not know is an error of every launch, seen at once.) One process checks them all (automotive.start:
    each application imported once there, about a second)."""
    targets = {item.split(":", 1)[0] for item in overrides if re.match(r"^[\w-]+:", item)}
    checked = [spec for spec in specs if spec.module in APPS and (spec.module in targets or spec.name in targets)]
    if not checked:
        return
    request = json.dumps([(spec.name, children.program_module(spec.module), spec.args) for spec in checked])
    result = subprocess.run([sys.executable, "-m", "automotive.start", "--check-settings"], input=request,
                            capture_output=True, text=True)
    try:
        answers = json.loads(result.stdout)
    except ValueError:
        raise LaunchError(f"the check of the applications' settings failed: {result.stderr.strip()[-300:]}") from None
    problems = [f"{name}: {line or f'exit code {code}'}" for name, code, line in answers if code != 0]
    if problems:
        raise LaunchError("; ".join(problems) + " (nothing was started)")


def stats_folder(module: str, name: str, stats_dirs: Sequence[str]) -> Path | None:
    """Where one application writes its status records (--stats-dir DIR for all, APP:DIR for that one), or None."""
    folder: Path | None = None
    for item in stats_dirs:
        target, _, path = item.partition(":") if re.match(r"^[\w-]+:", item) else ("", "", item)
        if target and target not in APPS and not target.startswith(tuple(f"{app}-" for app in APPS)):
            raise LaunchError(f"--stats-dir {item}: unknown application '{target}'; expected one of: "
                              f"{', '.join(APPS)}")
        problem = output_folder_problem(Path(path))
        if problem:
            raise LaunchError(f"--stats-dir {item}: {problem}")
        if not target or target in (module, name):
            folder = Path(path).resolve()
    return folder


# -- output: the launcher's terminal and the log files --------------------------------------------------------------
class Console:
    """Lines of the launcher and of the applications, prefixed with their name (coloured on a terminal)."""

    def __init__(self, names: Sequence[str], show_apps: bool, launcher_log: Path | None, verbose: bool = False):
        self.verbose = verbose  # every line of the applications, their DEBUG lines (every sample) too
        self.colour = sys.stdout.isatty() and os.environ.get("NO_COLOR") is None and os.environ.get("TERM") != "dumb"
        self.width = max([len(LAUNCHER_LABEL), *map(len, names)])
        self.colours = {name: COLOURS[index % len(COLOURS)] for index, name in enumerate(names)}
        self.show_apps = show_apps
        self.lock = threading.Lock()
        self.launcher_log: IO[str] | None = open(launcher_log, "w", encoding="utf-8") if launcher_log else None

    def _prefix(self, name: str) -> str:
        label = name.ljust(self.width)
        if not self.colour:
            return f"{label} | "
        code = "1" if name == LAUNCHER_LABEL else str(self.colours.get(name, 37))
        return f"\033[{code}m{label}\033[0m | "

    def _emit(self, line: str) -> None:
        try:
            sys.stdout.write(line + "\n")
            sys.stdout.flush()
        except (BrokenPipeError, ValueError):
            pass  # nobody reads our output any more: the log files still have it

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
        with self.lock:
            self._emit(self._prefix(name) + text)

    def say(self, text: str) -> None:
        with self.lock:
            self._emit(self._prefix(LAUNCHER_LABEL) + text)
            if self.launcher_log is not None:
                self.launcher_log.write(time.strftime("%H:%M:%S ") + text + "\n")
                self.launcher_log.flush()

    def close(self) -> None:
        if self.launcher_log is not None:
            self.launcher_log.close()


def describe_code(code: int) -> str:
    if code >= 0:
        return f"exit code {code}"
    try:
        return f"killed by {signal.Signals(-code).name} (signal {-code})"
    except ValueError:
        return f"killed by signal {-code}"


def set_parent_death_signal() -> None:
    """In the child before exec: die with SIGTERM if the launcher dies (even by SIGKILL), leaving no orphan."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    except (OSError, AttributeError):
        pass  # not Linux: `automotive launch stop` still finds the applications through the pid file


@dataclass
class RunningApp:
    spec: AppSpec
    log_path: Path
    child: Child
    started: float = field(default_factory=time.monotonic)
    log: IO[str] | None = None
    log_lock: threading.Lock = field(default_factory=threading.Lock)
    last_error: str = ""  # its last line on stderr: usually why it ended
    term_sent: float | None = None
    killed: bool = False
    code: int | None = None
    ended: float | None = None
    how: str = ""

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def process(self) -> subprocess.Popen[bytes]:
        return self.child.process


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


def launch_domain(args: argparse.Namespace) -> int:
    """The domain the launcher's applications run on: --domain, else a -D config.domainId for every application,
    else the shipped properties' 0."""
    if args.domain is not None:
        return int(args.domain)
    for item in reversed(args.overrides):
        match = re.fullmatch(r"config\.domainId=(\d+)", item.strip())
        if match:
            return int(match.group(1))
    return 0


# -- the supervisor -------------------------------------------------------------------------------------------------
class Supervisor:
    def __init__(self, specs: list[AppSpec], log_dir: Path, stop_timeout: float, console: Console, views: Views,
                 mode: str, domain: int = 0):
        self.specs = specs
        self.log_dir = log_dir
        self.domain = domain
        self.registry_entry: Path | None = None  # this launcher's file in the user's runtime folder
        self.stop_timeout = stop_timeout
        self.console = console
        self.views = views
        self.mode = mode
        self.apps: list[RunningApp] = []
        self.wake = threading.Event()
        self.stop_requested = False
        self.kill_now = False
        self.first_interrupt: float | None = None
        self.missing: list[tuple[str, str]] = []

    # Signals (served by the signal thread, automotive.bus.cli.on_signals) only set flags; the main loop does the work.
    def on_signal(self, signum: int) -> None:
        now = time.monotonic()
        if signum == signal.SIGINT:
            # A second Ctrl-C: no more waiting. One interrupt delivered twice (a wrapper such as `timeout` sends it
            # to the launcher and to its process group) comes within milliseconds; a person's second press does not.
            if self.first_interrupt is not None and now - self.first_interrupt >= SECOND_INTERRUPT_AFTER_S:
                self.kill_now = True
            if self.first_interrupt is None:
                self.first_interrupt = now
        self.stop_requested = True
        self.wake.set()

    def write_pid_file(self) -> None:
        info = {"launcher": os.getpid(), "mode": self.mode, "stop_timeout": self.stop_timeout,
                "apps": {app.name: app.process.pid for app in self.apps}, "module": {
                    app.name: app.spec.module for app in self.apps}}
        temporary = self.log_dir / f".{PID_FILE}.{os.getpid()}"
        temporary.write_text(json.dumps(info))
        temporary.replace(self.log_dir / PID_FILE)
        if self.registry_entry is None:
            self.registry_entry = register_launcher(self.log_dir, self.domain)

    def remove_pid_file(self) -> None:
        info = read_pid_file(self.log_dir)
        if info is not None and info.get("launcher") == os.getpid():
            (self.log_dir / PID_FILE).unlink(missing_ok=True)
        if self.registry_entry is not None:
            unregister_launcher(self.registry_entry)
            self.registry_entry = None

    def start_all(self) -> None:
        # Every line, every sample included, goes to the log files; the console leaves the DEBUG lines out unless -v.
        env = {**os.environ, LOG_LEVEL_VARIABLE: "debug"}
        # All processes are started before any reader thread exists: the child set-up (parent-death signal) runs
        # between fork and exec, which is only safe while no other thread may hold a lock (the signal thread waits
        # in recv, holding none).
        for spec in self.specs:
            if self.stop_requested:
                break
            log_path = self.log_dir / f"{spec.name}.log"
            log_path.write_text(f"--- {time.strftime('%Y-%m-%d %H:%M:%S')} {shlex.join(spec.command)}\n")
            try:
                child = Child(spec.name, spec.command, env=env, separate_stderr=True,
                              new_session=True,  # Ctrl-C reaches the launcher only
                              preexec_fn=set_parent_death_signal, read=False, on_line=self._on_line,
                              keep=False,  # every line goes to the log file and the console, none stays in memory
                              on_end=lambda child, stream: self.wake.set())  # ending: look at it now
            except OSError as error:
                self.console.say(f"cannot start {spec.name}: {error}")
                continue
            self.apps.append(RunningApp(spec, log_path, child))
            self.console.say(f"started {spec.name} (pid {child.pid}): python -m {children.program_module(spec.module)} "
                             f"{shlex.join(spec.args)}".rstrip())
        self.write_pid_file()
        for app in self.apps:
            app.log = open(app.log_path, "a", encoding="utf-8")
            app.child.start_reading()
            self.views.open(app)

    def _on_line(self, child: Child, line: Line) -> None:
        app = next(app for app in self.apps if app.child is child)
        assert app.log is not None
        with app.log_lock:
            app.log.write(line.text + "\n")
            app.log.flush()
        if line.stream == children.STDERR:
            app.last_error = line.text
        page = MONITOR_URL_LINE.match(line.text) if app.spec.module == MONITOR else None
        if page is not None:  # said once by the launcher, in every mode, --quiet too
            self.console.say(f"the monitor's page: {page.group(1)}")
            return
        self.console.app_line(app.name, line.text)

    def running(self) -> list[RunningApp]:
        return [app for app in self.apps if app.code is None]

    def _collect(self, app: RunningApp, code: int) -> None:
        """Record how an application ended, report it, and append it to its log file."""
        app.code = code
        app.ended = time.monotonic()
        app.child.join_output(timeout=2)  # its last lines first
        seconds = app.ended - app.started
        if app.killed and self.kill_now:
            app.how = f"killed at once on a second Ctrl-C: {describe_code(code)}"
        elif app.killed:
            app.how = (f"did not stop within {self.stop_timeout:g} s after SIGTERM: {describe_code(code)} "
                       f"(its threads' stacks are in {app.log_path})")
        elif app.term_sent is not None:
            app.how = f"stopped on SIGTERM, {describe_code(code)} ({app.ended - app.term_sent:.1f} s)"
        else:
            app.how = f"ended on its own after {seconds:.1f} s, {describe_code(code)}"
        if app.term_sent is None:
            last = f" (last error: {app.last_error})" if app.last_error and code != 0 else ""
            self.console.say(f"{app.name} {app.how}{last}")
        else:
            self.console.say(f"{app.name} {app.how}")
        if app.log is not None:
            with app.log_lock:
                app.log.write(f"--- {app.name} {app.how}\n")
                app.log.close()

    def poll(self) -> None:
        for app in self.running():
            code = app.process.poll()
            if code is not None:
                self._collect(app, code)

    def watch(self) -> None:
        """Until a stop is requested or every application has ended."""
        while not self.stop_requested and self.running():
            self.poll()
            self.wake.wait(0.1)  # a reader thread or a signal wakes us early
            self.wake.clear()
        if not self.stop_requested:
            self.console.say("every application has ended")

    def _signal(self, app: RunningApp, sig: signal.Signals) -> None:
        app.child.send_signal(sig, group=True)  # its process group: an application's own children too

    def stop_all(self) -> None:
        self.poll()
        running = self.running()
        if not running:
            return
        self.console.say(f"stopping {len(running)} application(s): SIGTERM, then SIGKILL after {self.stop_timeout:g} s")
        now = time.monotonic()
        for app in running:
            app.term_sent = now
            self._signal(app, signal.SIGTERM)
        deadline = now + self.stop_timeout
        while self.running() and time.monotonic() < deadline and not self.kill_now:
            self.poll()
            self.wake.wait(0.05)
            self.wake.clear()
        hung = [app for app in self.running() if app.process.poll() is None]
        for app in hung:
            app.killed = True  # it did not stop in time, whatever ends it now
        if hung and not self.kill_now:
            # Where each one waits, in its log, before it is killed: a hang is a defect worth finding.
            for app in hung:
                app.child.send_signal(DUMP_STACKS_SIGNAL)
            time.sleep(STACK_DUMP_WAIT_S)
        for app in hung:
            if app.process.poll() is None:
                self._signal(app, signal.SIGKILL)
        for app in self.running():
            try:
                code = app.process.wait(timeout=5)
            except subprocess.TimeoutExpired:  # not even SIGKILL ended it (uninterruptible): report what we know
                code = -int(signal.SIGKILL)
            self._collect(app, code)

    def summary(self) -> list[str]:
        width = max([len(app.name) for app in self.apps] + [len(name) for name, _ in self.missing] + [4])
        lines = ["how each application ended:"]
        for app in self.apps:
            lines.append(f"  {app.name.ljust(width)}  pid {app.process.pid:<7} {app.how}")
        for name, reason in self.missing:
            lines.append(f"  {name.ljust(width)}  not started: {reason}")
        return lines

    def exit_code(self) -> int:
        failed = [app for app in self.apps if app.killed or (app.code is not None and app.code != 0)]
        return 1 if failed else 0


def run_supervisor(args: argparse.Namespace, specs: list[AppSpec], missing: list[tuple[str, str]], mode: str) -> int:
    log_dir: Path = args.log_dir
    log_dir.mkdir(parents=True, exist_ok=True)
    info = read_pid_file(log_dir)
    if info is not None and launcher_running(info) is not None:
        raise LaunchError(f"a launcher (pid {info['launcher']}) already runs with its logs in {log_dir}: "
                          f"stop it with `{PROG} stop`, or use another --log-dir")
    (log_dir / SUMMARY_FILE).unlink(missing_ok=True)
    names = [spec.name for spec in specs]
    console = Console(names, show_apps=mode != "window" and not args.quiet, launcher_log=log_dir / "launch.log",
                      verbose=args.verbose)
    views: Views = Views()
    if mode == "window":
        terminal = find_terminal()
        assert terminal is not None
        views = WindowViews(terminal, console)
    elif args.tmux_session:
        views = TmuxViews(args.tmux_session, console)
    supervisor = Supervisor(specs, log_dir, args.stop_timeout, console, views,
                            "tmux" if args.tmux_session else mode, launch_domain(args))
    supervisor.missing = missing
    dump_stacks_on_request()
    on_signals((signal.SIGINT, signal.SIGTERM, signal.SIGHUP), supervisor.on_signal)
    for name, reason in missing:
        console.say(f"{name} is not available in this version ({reason}): not started")
    try:
        supervisor.start_all()
        if supervisor.apps:
            console.say(f"{len(supervisor.apps)} application(s) running ({supervisor.mode} mode), logs in {log_dir}; "
                        f"Ctrl-C or `{stop_hint(log_dir)}` stops them")
            supervisor.watch()
    finally:
        supervisor.stop_all()
        views.close()
        summary = supervisor.summary()
        for line in summary:
            console.say(line)
        (log_dir / SUMMARY_FILE).write_text("\n".join(summary) + "\n")
        supervisor.remove_pid_file()
        console.close()
        stop_dumping_stacks()
    return supervisor.exit_code()


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
                          f"`{PROG} stop` to stop it")
    inner = [sys.executable, "-m", "automotive.start", "automotive.tools.launch.launch", "--prog", PROG, *argv,
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
            print(f"launch: switched to tmux session '{session}'; `{PROG} stop` stops it")
        else:  # the system runs all the same: say how to see it
            print(f"launch: running in tmux session '{session}', but could not switch to it "
                  f"({switched.stderr.strip() or 'tmux switch-client failed'}): `tmux attach -t {session}` to "
                  f"watch, `{PROG} stop` to stop")
        return 0
    if not interactive():
        print(f"launch: running in tmux session '{session}': `tmux attach -t {session}` to watch, "
              f"`{PROG} stop` to stop")
        return 0
    subprocess.run(["tmux", "attach-session", "-t", session])
    if subprocess.run(["tmux", "has-session", "-t", f"={session}"], capture_output=True).returncode == 0:
        print(f"launch: detached; the system runs on in tmux session '{session}': `tmux attach -t {session}` to "
              f"watch, `{PROG} stop` to stop")
        return 0
    summary = log_dir / SUMMARY_FILE
    if summary.is_file():
        print(summary.read_text(), end="")
    return 0


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
    return f"{PROG} stop" + (f" --log-dir {shlex.quote(str(log_dir))}" if others else "")


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
    parser = ArgumentParser(prog=f"{PROG} stop", description="Stop the running launcher (found from any folder; "
                                                             "--log-dir or --domain choose one of several).")
    add_choice_options(parser)
    parser.add_argument("--timeout", type=float, default=None,
                        help=f"how long to wait for the launcher (default: its stop timeout + {STOP_MARGIN_S:g} s)")
    args = parser.parse_args(argv)
    chosen = chosen_launchers(args)
    if not chosen:
        print(f"{PROG} stop: {no_launcher(args)}", file=sys.stderr)
        return 1
    if len(chosen) > 1:
        listed = "; ".join(describe_launcher(log_dir, info) for log_dir, info in chosen)
        print(f"{PROG} stop: {len(chosen)} launchers are running ({listed}): choose one with --domain N or "
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
    parser = ArgumentParser(prog=f"{PROG} status", description="What the running launchers run (found from any "
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
        # Python would report the pipe again when it flushes stdout at exit: point stdout at /dev/null first.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


# -- entry ----------------------------------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(
        prog=PROG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Start the automotive applications together and stop them together "
                    f"(`{PROG} stop` stops a running launcher, `{PROG} status` shows it).",
        epilog=user_help(__doc__ or "", PROG)[1] + f"\n\napplications: {', '.join(APPS)}")
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
    global PROG
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["--prog"] and len(argv) > 1:  # the tmux session's inner launcher
        prog, argv = argv[1], argv[2:]
    PROG = prog or PROG
    try:
        return _main(argv)
    except LaunchError as error:
        print(f"{PROG}: {error}", file=sys.stderr)
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
    specs, missing = plan(args)
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
