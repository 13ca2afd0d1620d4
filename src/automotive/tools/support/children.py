"""Child processes whose output is collected line by line: start, wait for a line, measure, stop.

The one helper for every program that runs other programs (the launcher, the benchmarks) and for the tests:

- each line of the child's output is kept with the time it arrived (``time.monotonic``) and the stream it came on,
  and handed to an optional callback (the launcher writes log files and its console);
- :meth:`Child.wait_for` waits, bounded, until a line matches (never a fixed sleep);
- :meth:`Child.stop` sends SIGTERM (or another signal), waits, then SIGKILL;
- :meth:`Child.cpu_seconds` and :meth:`Child.memory_bytes` come from psutil (children included if asked);
- :class:`StatsChild` is a child started with ``--stats FILE``: its status records (JSON lines, ``bus.stats``) read
  and awaited, the way every benchmark takes its figures from the programs it runs.

:func:`program_command` is how a program of the project is started: ``python -m <module>`` with the running
interpreter, so the child runs the same installation as the parent (no PATH, no PYTHONPATH needed).

:func:`work_folder` is the folder of a run's files (the children's logs and status records): the user's, kept, or a
temporary one, removed whichever way the run ends (an error, Ctrl-C, SIGTERM).
"""

from __future__ import annotations

import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import IO, Any, Self

import psutil

from automotive.bus import stats

DEFAULT_TIMEOUT = 30.0
STDOUT, STDERR = "stdout", "stderr"

# The programs of the project by the name people use (as the launcher and the tests name them), and their modules.
APPS = ("vision", "lidar", "sensor_fusion", "vehicle_platform", "collision_avoidance", "hmi", "camera_pub",
        "camera_sub")
# The tools' programs by the same names, each in its tool's room (automotive.tools.<room>.<name>).
TOOL_ROOMS = {"record": "record", "replay": "record", "bridge": "foxglove_bridge", "lidar_view": "lidar_view",
              "shapes": "shapes", "launch": "launch", "config_export": "config", "make_scene_data": "support",
              "zenoh_bridge": "zenoh", "zenoh_certs": "zenoh", "delay_relay": "support", "shape_main": "shapes",
              "monitor": "monitor"}
TOOLS = tuple(TOOL_ROOMS)


def program_module(name: str) -> str:
    """The module of a program: ``vision`` -> ``automotive.apps.vision``, ``record`` ->
    ``automotive.tools.record.record``."""
    if name in APPS:
        return f"automotive.apps.{name}"
    if name in TOOLS:
        return f"automotive.tools.{TOOL_ROOMS[name]}.{name}"
    raise ValueError(f"unknown program '{name}' (applications: {', '.join(APPS)}; tools: {', '.join(TOOLS)})")


def program_command(name: str, *args: str, python: Sequence[str] = ()) -> list[str]:
    """``[python, -m, automotive.start, module, args...]`` with the running interpreter (``python``: a prefix such as
    ``chrt``): started through automotive.start, a program stopped while it still imports ends with one line."""
    return [*python, sys.executable, "-m", "automotive.start", program_module(name), *args]


def _exit_as_signalled(signum: int, frame: FrameType | None) -> None:
    raise SystemExit(128 + signum)  # the shell's code for "ended by that signal"


@contextmanager
def exit_on_sigterm() -> Iterator[None]:
    """Inside the block, SIGTERM raises SystemExit (code 143) in the main thread, as Ctrl-C raises KeyboardInterrupt:
    the program unwinds, its ``finally`` blocks stop its children and remove its folders, instead of dying where it
    stands (SIGTERM's default). The handler only raises, it takes no lock (``automotive.bus.cli.on_signals`` says
    why a handler must not); nothing is there to hand to the signal thread. Outside the main thread, where Python
    sets no handler, nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _exit_as_signalled)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)  # None: not set from Python


@contextmanager
def work_folder(prefix: str, keep: Path | None = None) -> Iterator[Path]:
    """The folder of a run's files: ``keep``, a folder the user named, created if need be and never removed; or else
    a new temporary folder (under ``TMPDIR``, named ``prefix...``) removed on the way out, whichever the way: the
    end, an error, Ctrl-C or SIGTERM (:func:`exit_on_sigterm` holds inside the block). Stop the children that write
    into it inside the block, so that nothing writes there once it is removed."""
    with exit_on_sigterm():
        if keep is not None:
            keep.mkdir(parents=True, exist_ok=True)
            yield keep
            return
        # ignore_cleanup_errors: an error while removing must not hide the one that ended the run
        with tempfile.TemporaryDirectory(prefix=prefix, ignore_cleanup_errors=True) as folder:
            yield Path(folder)


def handles_signal(pid: int, sig: int) -> bool:
    """Whether process ``pid`` has a handler of its own for ``sig`` (the SigCgt mask of /proc/PID/status; False when
    the process is gone or the mask cannot be read)."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("SigCgt:"):
                    return bool(int(line.split()[1], 16) >> (sig - 1) & 1)
    except (OSError, ValueError, IndexError):
        pass
    return False


def wait_until_handled(pid: int, sig: int, timeout: float, ended: Callable[[], bool] = lambda: False) -> bool:
    """Wait up to ``timeout`` seconds until process ``pid`` handles ``sig`` itself; False if it never did in that time
    or ``ended()`` said it is gone (/proc is polled: there is nothing to wait on)."""
    deadline = time.monotonic() + timeout
    while not handles_signal(pid, sig):
        if ended() or time.monotonic() >= deadline:
            return False
        time.sleep(0.001)
    return True


@dataclass(frozen=True)
class Line:
    time: float  # time.monotonic() when it was read
    stream: str  # STDOUT or STDERR (STDOUT for both when stderr is merged)
    text: str


LineCallback = Callable[["Child", Line], None]


class Child:
    """One child process with its output collected (stderr merged into stdout unless ``separate_stderr``).

    ``read=False`` defers the reader threads to :meth:`start_reading` (the launcher starts every child before any
    thread exists: its ``preexec_fn`` runs between fork and exec, safe only in a single-threaded parent).

    ``keep=False`` hands each line to ``on_line`` only and keeps none (no :attr:`records`, nothing for
    :meth:`wait_for`): a child that runs for hours (the launcher's applications) would otherwise cost its parent
    memory for every line it ever printed (the launcher grew 1.4 MB a minute with the whole system when it did).
    """

    def __init__(self, name: str, command: Sequence[str], *, cwd: Path | None = None,
                 env: dict[str, str] | None = None, stdin: bool = False, separate_stderr: bool = False,
                 on_line: LineCallback | None = None, on_end: Callable[[Child, str], None] | None = None,
                 new_session: bool = False,
                 preexec_fn: Callable[[], None] | None = None, read: bool = True, keep: bool = True):
        self.name = name
        self.command = list(command)
        full_env = dict(os.environ if env is None else env)
        full_env["PYTHONUNBUFFERED"] = "1"
        self.on_line = on_line
        self.on_end = on_end
        self.keep = keep
        self.process = subprocess.Popen(
            self.command, cwd=cwd, env=full_env, stdout=subprocess.PIPE,
            stderr=subprocess.PIPE if separate_stderr else subprocess.STDOUT,
            stdin=subprocess.PIPE if stdin else subprocess.DEVNULL, start_new_session=new_session,
            preexec_fn=preexec_fn)
        self.records: list[Line] = []  # every line with its arrival time and stream
        self._new_lines: queue.Queue[Line | None] = queue.Queue()
        self._open_streams = 0
        self._ended = False
        self._readers: list[threading.Thread] = []
        if read:
            self.start_reading()

    @property
    def pid(self) -> int:
        return self.process.pid

    def start_reading(self) -> None:
        streams = [(self.process.stdout, STDOUT)]
        if self.process.stderr is not None:
            streams.append((self.process.stderr, STDERR))
        self._open_streams = len(streams)
        for stream, label in streams:
            reader = threading.Thread(target=self._read, args=(stream, label), daemon=True,
                                      name=f"{self.name}-{label}")
            self._readers.append(reader)
            reader.start()

    def _read(self, stream: IO[bytes] | None, label: str) -> None:
        assert stream is not None
        for raw in iter(stream.readline, b""):
            line = Line(time.monotonic(), label, raw.decode("utf-8", errors="replace").rstrip("\r\n"))
            if self.keep:
                self.records.append(line)
            if self.on_line is not None:
                self.on_line(self, line)
            if self.keep:
                self._new_lines.put(line)
        self._new_lines.put(None)  # this stream ended
        if self.on_end is not None:
            self.on_end(self, label)

    # -- what it printed ---------------------------------------------------------------------------------------
    @property
    def lines(self) -> list[str]:
        """The text of every line so far."""
        return [line.text for line in list(self.records)]

    @property
    def output(self) -> str:
        return "\n".join(self.lines)

    def count(self, pattern: str) -> int:
        regex = re.compile(pattern)
        return sum(1 for line in list(self.records) if regex.search(line.text))

    def matches(self, pattern: str | re.Pattern[str], since: int = 0) -> Iterator[tuple[Line, re.Match[str]]]:
        """(line, match) of each line from line ``since`` on that matches ``pattern``."""
        regex = re.compile(pattern) if isinstance(pattern, str) else pattern
        for line in list(self.records)[since:]:
            match = regex.search(line.text)
            if match:
                yield line, match

    def wait_for_line(self, pattern: str | re.Pattern[str], timeout: float = DEFAULT_TIMEOUT, count: int = 1,
                      since: int = 0) -> tuple[Line, re.Match[str]]:
        """Wait until ``count`` lines from line ``since`` on match ``pattern``; the last of them and its match.

        Raises AssertionError with the output so far when the child ends first or the time is up.
        """
        deadline = time.monotonic() + timeout
        regex = re.compile(pattern) if isinstance(pattern, str) else pattern
        label = regex.pattern
        # Each line is searched once: a chatty child (a line per sample) would otherwise cost the waiting process
        # a search of every earlier line at each new one.
        scanned, found = since, 0
        while True:
            records, end = self.records, len(self.records)  # the reading thread may append meanwhile: up to end
            for index in range(scanned, end):
                match = regex.search(records[index].text)
                if match:
                    found += 1
                    if found >= count:
                        return records[index], match
            scanned = max(scanned, end)
            if self._ended:
                raise AssertionError(f"{self.name} ended (exit {self.process.wait()}) before {count}x /{label}/;"
                                     " output:\n" + self.output[-4000:])
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(f"{self.name}: no {count}x /{label}/ within {timeout:.0f} s; output:\n"
                                     + self.output[-4000:])
            try:
                new = self._new_lines.get(timeout=min(remaining, 0.5))
                while True:  # every line queued by now: searched together
                    if new is None:
                        self._open_streams -= 1
                        self._ended = self._open_streams <= 0
                    new = self._new_lines.get_nowait()
            except queue.Empty:
                if not self._readers and self.process.poll() is not None:
                    self._ended = True

    def wait_for(self, pattern: str, timeout: float = DEFAULT_TIMEOUT, count: int = 1) -> str:
        """Wait until ``count`` lines match ``pattern``; return the last match's line."""
        return self.wait_for_line(pattern, timeout, count)[0].text

    def wait_for_more(self, pattern: str, more: int = 1, timeout: float = DEFAULT_TIMEOUT) -> str:
        """Wait until ``more`` lines beyond those printed so far match ``pattern``; return the last match."""
        return self.wait_for(pattern, timeout, count=self.count(pattern) + more)

    # -- control -----------------------------------------------------------------------------------------------
    def send(self, line: str) -> None:
        """Write one line to the child's standard input (started with ``stdin=True``)."""
        assert self.process.stdin is not None, f"{self.name} was started without stdin=True"
        self.process.stdin.write((line + "\n").encode())
        self.process.stdin.flush()

    def send_signal(self, sig: int, group: bool = False) -> None:
        """Send ``sig`` to the child (``group``: to its process group, its own children too); gone is fine."""
        try:
            if group:
                os.killpg(self.process.pid, sig)
                return
        except (ProcessLookupError, PermissionError):
            pass
        try:
            self.process.send_signal(sig)
        except ProcessLookupError:
            pass

    def wait_until_handled(self, sig: int, timeout: float, give_up: Callable[[], bool] = lambda: False) -> bool:
        """Wait up to ``timeout`` seconds until the child handles ``sig`` itself; False if it never did, ended, or
        ``give_up()`` said to wait no more.

        A program of the package handles SIGTERM from the first line of automotive.start on; before that, in the tens
        of milliseconds (more on a loaded machine) in which the interpreter starts, SIGTERM's default action would end
        it without a word, "killed by SIGTERM", instead of the clean stop it asks for."""
        return wait_until_handled(self.process.pid, sig, timeout, lambda: give_up() or self.process.poll() is not None)

    @contextmanager
    def frozen(self) -> Iterator[None]:
        """The process stopped (SIGSTOP: hung, not dead) inside the block, continued (SIGCONT) after it."""
        self.send_signal(signal.SIGSTOP)
        try:
            yield
        finally:
            self.send_signal(signal.SIGCONT)

    def poll(self) -> int | None:
        return self.process.poll()

    def join_output(self, timeout: float = 5.0) -> None:
        """Wait for the reader threads (the last lines) after the process ended."""
        for reader in self._readers:
            reader.join(timeout=timeout)

    def wait_exit(self, timeout: float = DEFAULT_TIMEOUT) -> int:
        code = self.process.wait(timeout=timeout)
        self.join_output()
        return code

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 15.0, group: bool = False) -> int:
        """Send ``sig``, wait up to ``timeout`` seconds, then SIGKILL; the exit code (negative: the signal)."""
        if self.process.poll() is None:
            self.send_signal(sig, group)
            try:
                self.process.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.send_signal(signal.SIGKILL, group)
                self.process.wait()
        self.join_output()
        return self.process.returncode

    # -- figures -----------------------------------------------------------------------------------------------
    def _psutil(self) -> psutil.Process | None:
        try:
            return psutil.Process(self.process.pid)
        except psutil.Error:
            return None

    def cpu_seconds(self, children: bool = False) -> float:
        """User + system CPU time so far (1 s per second = one core busy); NaN once the process is gone."""
        process = self._psutil()
        try:
            if process is None:
                return float("nan")
            times = process.cpu_times()
            total = times.user + times.system
            if children:
                total += sum(child.cpu_times().user + child.cpu_times().system
                             for child in process.children(recursive=True))
            return float(total)
        except psutil.Error:
            return float("nan")

    def memory_bytes(self) -> int:
        """Resident memory (RSS) now; 0 once the process is gone."""
        process = self._psutil()
        try:
            return int(process.memory_info().rss) if process is not None else 0
        except psutil.Error:
            return 0


def stop_all(children: Sequence[Child], sig: int = signal.SIGTERM, timeout: float = 15.0) -> None:
    """Signal every child at once, then wait for each (SIGKILL after ``timeout`` seconds in all)."""
    for child in children:
        if child.poll() is None:
            child.send_signal(sig)
    deadline = time.monotonic() + timeout
    for child in children:
        try:
            child.process.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            child.send_signal(signal.SIGKILL)
            child.process.wait()
        child.join_output()


def keep_outputs(children: Sequence[Child], folder: Path, log_folder: Path | None = None) -> None:
    """Each child's output as ``folder/<name>.log``, and ``log_folder`` (a launcher's log folder) copied into
    ``folder/logs``: what a benchmark's --log-dir keeps of a run."""
    folder.mkdir(parents=True, exist_ok=True)
    for child in children:
        (folder / f"{child.name}.log").write_text(child.output)
    if log_folder is not None and log_folder.is_dir():
        shutil.copytree(log_folder, folder / "logs", dirs_exist_ok=True)


Record = dict[str, Any]


def any_record(record: Record) -> bool:
    return True


class RunFailed(RuntimeError):
    """A child did not do what was awaited: it ended first."""


class RecordTimeout(RunFailed, TimeoutError):
    """A record that was awaited did not come in time."""


class StatsChild:
    """A program of the project started with ``--stats FILE``: the child and the status records it appends."""

    def __init__(self, child: Child, stats_path: Path):
        self.child = child
        self.stats = stats_path
        self._records = stats.Follower(stats_path)

    @classmethod
    def start(cls, name: str, program: str, args: Sequence[str], stats_path: Path, *,
              env: dict[str, str] | None = None, prefix: Sequence[str] = (),
              python: Sequence[str] = ()) -> Self:
        """Start ``program`` (a name for :func:`program_command`) as ``name`` with ``--stats stats_path``;
        ``prefix`` goes before the whole command (``ip netns exec ...``), ``python`` before the interpreter."""
        command = program_command(program, *args, "--stats", str(stats_path), python=python)
        return cls(Child(name, [*prefix, *command], env=env), stats_path)

    @property
    def name(self) -> str:
        return self.child.name

    def records(self, kind: str, since: float = 0.0, until: float = float("inf"),
                match: Callable[[Record], bool] = any_record) -> list[Record]:
        """The records of ``kind`` written from ``since`` to before ``until`` (time.time) that ``match`` accepts."""
        return [record for record in self._records.records(kind) if since <= record["t"] < until and match(record)]

    def first(self, kind: str, match: Callable[[Record], bool] = any_record) -> float | None:
        """The time of the first record of ``kind`` that ``match`` accepts (None: none yet)."""
        return next((float(record["t"]) for record in self.records(kind, match=match)), None)

    def wait_record(self, kind: str, timeout: float = DEFAULT_TIMEOUT, *, since: float = 0.0, count: int = 1,
                    match: Callable[[Record], bool] = any_record, what: str | None = None) -> Record:
        """The ``count``-th record of ``kind`` from ``since`` on that ``match`` accepts, once the child wrote it;
        :class:`RunFailed` if the child ends first, :class:`RecordTimeout` after ``timeout`` seconds."""
        what = what or f"a '{kind}' record"
        deadline = time.monotonic() + timeout
        while True:
            found = self.records(kind, since, match=match)
            if len(found) >= count:
                return found[count - 1]
            if self.child.poll() is not None:
                raise RunFailed(f"{self.name} ended (exit {self.child.poll()}) before {what}; last output: "
                                + " | ".join(self.child.lines[-5:]))
            if time.monotonic() > deadline:
                raise RecordTimeout(f"{self.name}: no {what} within {timeout:g} s")
            time.sleep(0.05)  # polling a file another process appends to

    def stop(self, sig: int = signal.SIGINT, timeout: float = 30.0) -> int:
        return self.child.stop(sig, timeout=timeout)


def alive(pid: int) -> bool:
    """True if the process exists and is not a zombie (a zombie has ended; only its exit status is left)."""
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.Error:
        return False


def command_line(pid: int) -> str:
    """A process's command line, words joined by spaces ("" if it is gone)."""
    try:
        return " ".join(psutil.Process(pid).cmdline())
    except psutil.Error:
        return ""


def thread_cpu_by_name(pids: Sequence[int]) -> dict[str, float]:
    """CPU seconds (user + system) so far of the threads of these processes, summed by thread name (Cyclone names
    its threads: recv, tev, dq.builtins...; Python's are named after the program). Processes that are gone count 0.

    Read from /proc by hand: psutil gives each thread's times but not its name.
    """
    totals: dict[str, float] = {}
    ticks = os.sysconf("SC_CLK_TCK")
    for pid in pids:
        try:
            threads = os.listdir(f"/proc/{pid}/task")
        except OSError:
            continue
        for tid in threads:
            try:
                stat = Path(f"/proc/{pid}/task/{tid}/stat").read_text()
            except OSError:
                continue
            name = stat[stat.index("(") + 1:stat.rindex(")")]
            fields = stat[stat.rindex(")") + 2:].split()
            totals[name] = totals.get(name, 0.0) + (int(fields[11]) + int(fields[12])) / ticks
    return totals
