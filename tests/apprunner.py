"""Run the project's applications as separate processes and wait on what they print (bounded waits, no sleeps)."""

from __future__ import annotations

import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

DEFAULT_TIMEOUT = 30.0


class CommandProcess:
    """Any command (a script, ``ip netns exec ...``), with its output collected line by line for :meth:`wait_for`."""

    def __init__(self, name: str, command: list[str], cwd: Path, env: dict[str, str] | None = None,
                 stdin: bool = False):
        self.name = name
        self.command = command
        full_env = dict(os.environ)
        full_env["PYTHONPATH"] = str(cwd) + os.pathsep + full_env.get("PYTHONPATH", "")
        full_env["PYTHONUNBUFFERED"] = "1"
        if env:
            full_env.update(env)
        self.process = subprocess.Popen(command, cwd=cwd, env=full_env, stdout=subprocess.PIPE,
                                        stderr=subprocess.STDOUT, text=True, bufsize=1,
                                        stdin=subprocess.PIPE if stdin else None)
        self.lines: list[str] = []
        self._new_lines: queue.Queue[str | None] = queue.Queue()
        self._ended = False
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self.lines.append(line.rstrip("\n"))
            self._new_lines.put(line)
        self._new_lines.put(None)

    @property
    def output(self) -> str:
        return "\n".join(self.lines)

    def count(self, pattern: str) -> int:
        regex = re.compile(pattern)
        return sum(1 for line in list(self.lines) if regex.search(line))

    def wait_for(self, pattern: str, timeout: float = DEFAULT_TIMEOUT, count: int = 1) -> str:
        """Wait until ``count`` lines match ``pattern``; return the last match. Fails with the output so far."""
        regex = re.compile(pattern)
        deadline = time.monotonic() + timeout
        while True:
            matches = [line for line in list(self.lines) if regex.search(line)]
            if len(matches) >= count:
                return matches[count - 1]
            if self._ended:
                raise AssertionError(f"{self.name} ended (exit {self.process.wait()}) before {count}x /{pattern}/;"
                                     " output:\n" + self.output[-4000:])
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(f"{self.name}: no {count}x /{pattern}/ within {timeout:.0f} s; output:\n"
                                     + self.output[-4000:])
            try:
                if self._new_lines.get(timeout=min(remaining, 0.5)) is None:
                    self._ended = True
            except queue.Empty:
                pass

    def wait_for_more(self, pattern: str, more: int = 1, timeout: float = DEFAULT_TIMEOUT) -> str:
        """Wait until ``more`` lines beyond those printed so far match ``pattern``; return the last match."""
        return self.wait_for(pattern, timeout, count=self.count(pattern) + more)

    @contextmanager
    def frozen(self) -> Iterator[None]:
        """The process stopped (SIGSTOP: hung, not dead) inside the block, continued (SIGCONT) after it."""
        self.process.send_signal(signal.SIGSTOP)
        try:
            yield
        finally:
            self.process.send_signal(signal.SIGCONT)

    def send(self, line: str) -> None:
        """Write one line to the process's standard input (started with ``stdin=True``)."""
        assert self.process.stdin is not None, f"{self.name} was started without stdin=True"
        self.process.stdin.write(line + "\n")
        self.process.stdin.flush()

    def wait_exit(self, timeout: float = DEFAULT_TIMEOUT) -> int:
        code = self.process.wait(timeout=timeout)
        self._reader.join(timeout=5)
        return code

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 15.0) -> int:
        if self.process.poll() is None:
            self.process.send_signal(sig)
            try:
                self.process.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self._reader.join(timeout=5)
        return self.process.returncode


class AppProcess(CommandProcess):
    """One application, ``python -m apps.<name> <args>``."""

    def __init__(self, name: str, args: list[str], cwd: Path, env: dict[str, str] | None = None):
        super().__init__(name, [sys.executable, "-m", f"apps.{name}", *args], cwd, env)


class AppRunner:
    def __init__(self, root: Path):
        self.root = root
        self.processes: list[CommandProcess] = []

    def start(self, name: str, *args: str, env: dict[str, str] | None = None) -> AppProcess:
        process = AppProcess(name, list(args), self.root, env)
        self.processes.append(process)
        return process

    def start_command(self, name: str, command: list[str], env: dict[str, str] | None = None,
                      stdin: bool = False) -> CommandProcess:
        """Start any command (stopped at the end like the applications); ``name`` labels its failures."""
        process = CommandProcess(name, command, self.root, env, stdin)
        self.processes.append(process)
        return process

    def run(self, name: str, *args: str, timeout: float = DEFAULT_TIMEOUT,
            env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
        """Run an application to completion, capturing stdout and stderr separately."""
        full_env = dict(os.environ)
        full_env["PYTHONPATH"] = str(self.root) + os.pathsep + full_env.get("PYTHONPATH", "")
        if env:
            full_env.update(env)
        return subprocess.run([sys.executable, "-m", f"apps.{name}", *args], cwd=self.root, env=full_env,
                              capture_output=True, text=True, timeout=timeout)

    def stop_all(self) -> None:
        for process in self.processes:
            process.stop()
