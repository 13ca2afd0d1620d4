"""The launcher's work once it knows what to start: the supervisor starts every application (its output to its log
file and the console), watches them, reports each one's end, and on a stop sends SIGTERM, then SIGKILL to any left;
its pid file and registry entry say it runs meanwhile.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import re
import shlex
import signal
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from automotive.bus.cli import DUMP_STACKS_SIGNAL, dump_stacks_on_request, on_signals, stop_dumping_stacks
from automotive.bus.console import LOG_LEVEL_VARIABLE
from automotive.tools.launch import plan
from automotive.tools.launch.display import Console, TmuxViews, Views, WindowViews, find_terminal
from automotive.tools.launch.logfile import LogFile
from automotive.tools.launch.plan import MONITOR, AppSpec, LaunchError
from automotive.tools.launch.registry import (
    PID_FILE,
    STACK_DUMP_WAIT_S,
    SUMMARY_FILE,
    launcher_running,
    read_pid_file,
    register_launcher,
    stop_hint,
    unregister_launcher,
)
from automotive.tools.support import children
from automotive.tools.support.children import Child, Line

HANDLER_WAIT_S = 2.0  # the longest a stop waits for starting applications to handle SIGTERM (it takes milliseconds)
SECOND_INTERRUPT_AFTER_S = 0.5  # an interrupt sooner than this after the first is the same one, delivered twice
# The monitor's line that gives its page's URL (automotive.tools.monitor.monitor.URL_LINE): said once by the launcher.
MONITOR_URL_LINE = re.compile(r"^automotive monitor: the page is on (\S+)$")
PR_SET_PDEATHSIG = 1


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
    log: LogFile
    child: Child
    started: float = field(default_factory=time.monotonic)
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
    def log_path(self) -> Path:
        return self.log.path

    @property
    def process(self) -> subprocess.Popen[bytes]:
        return self.child.process


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

    def on_suspend(self, signum: int) -> None:
        """Ctrl-Z: a suspended launcher would read no more of its applications' output, and each would stop at its
        next lines once its pipe is full: the system stalled behind a shell prompt. It goes on, and says why."""
        self.console.say("Ctrl-Z: the launcher does not suspend (its applications would stop at their next lines with "
                         "nobody to read them); Ctrl-C stops the system")

    def write_pid_file(self) -> None:
        info = {"launcher": os.getpid(), "mode": self.mode, "stop_timeout": self.stop_timeout,
                "apps": {app.name: app.process.pid for app in self.apps}, "module": {
                    app.name: app.spec.module for app in self.apps}}
        temporary = self.log_dir / f".{PID_FILE}.{os.getpid()}"
        try:
            temporary.write_text(json.dumps(info))
            temporary.replace(self.log_dir / PID_FILE)
        except OSError as error:  # a full disk: the applications run all the same
            temporary.unlink(missing_ok=True)
            self.console.say(f"cannot write {self.log_dir / PID_FILE}: {error.strerror or error}; "
                             f"`{plan.PROG} stop` and `status` will not find this launcher (pid {os.getpid()}): "
                             "Ctrl-C or SIGTERM stops it")
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
            log = LogFile(self.log_dir / f"{spec.name}.log", self.console.say)
            log.write(f"--- {time.strftime('%Y-%m-%d %H:%M:%S')} {shlex.join(spec.command)}")
            try:
                child = Child(spec.name, spec.command, env=env, separate_stderr=True,
                              new_session=True,  # Ctrl-C reaches the launcher only
                              preexec_fn=set_parent_death_signal, read=False, on_line=self._on_line,
                              keep=False,  # every line goes to the log file and the console, none stays in memory
                              on_end=lambda child, stream: self.wake.set())  # ending: look at it now
            except OSError as error:
                self.console.say(f"cannot start {spec.name}: {error}")
                log.close()
                continue
            self.apps.append(RunningApp(spec, log, child))
            self.console.say(f"started {spec.name} (pid {child.pid}): python -m {children.program_module(spec.module)} "
                             f"{shlex.join(spec.args)}".rstrip())
        self.write_pid_file()
        for app in self.apps:
            app.child.start_reading()
            self.views.open(app)

    def _on_line(self, child: Child, line: Line) -> None:
        app = next(app for app in self.apps if app.child is child)
        app.log.write(line.text)
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
        app.log.close(f"--- {app.name} {app.how}")

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
        # An application still starting its interpreter is let to install its handler first: then it ends with exit
        # code 0, as a stop asks, not killed by the signal's default action (tens of milliseconds at most). They start
        # together, so one deadline serves them all; a second Ctrl-C waits no more.
        handlers_deadline = time.monotonic() + HANDLER_WAIT_S
        for app in running:
            app.child.wait_until_handled(signal.SIGTERM, max(0.0, handlers_deadline - time.monotonic()),
                                         give_up=lambda: self.kill_now)
            app.term_sent = time.monotonic()
            self._signal(app, signal.SIGTERM)
        now = time.monotonic()
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
                          f"stop it with `{plan.PROG} stop`, or use another --log-dir")
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
    on_signals((signal.SIGTSTP,), supervisor.on_suspend)
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
        try:
            (log_dir / SUMMARY_FILE).write_text("\n".join(summary) + "\n")
        except OSError as error:  # a full disk: the console has it
            console.say(f"cannot write {log_dir / SUMMARY_FILE}: {error.strerror or error}")
        supervisor.remove_pid_file()
        console.close()
        stop_dumping_stacks()
    return supervisor.exit_code()


