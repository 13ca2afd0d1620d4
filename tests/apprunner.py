"""Run the project's programs as separate processes and wait on what they print (bounded waits, no sleeps).

A thin layer over the project's one child-process helper (automotive.tools.support.children): programs are started by
name (``vision``, ``record``...) as ``python -m automotive.apps.<name>`` or ``automotive.tools.<room>.<name>``
(children.program_module) with the test's interpreter.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

from automotive.tools.support.children import DEFAULT_TIMEOUT, Child, program_command, program_module

__all__ = ["DEFAULT_SIGINT", "DEFAULT_TIMEOUT", "AppProcess", "AppRunner", "CommandProcess", "signal_state"]

CommandProcess = Child
# Every child of a test starts with SIGINT at its default action (coreutils' env resets it, then runs the command in
# its place). A signal ignored in a process stays ignored in the programs it starts, and C libraries in the test
# process may ignore SIGINT for a moment (glibc's system(), which RTI's core calls, ignores it while its command runs):
# a child started then would never see the Ctrl-C a test sends it (seen: a benchmark that ran to its end, exit 0).
DEFAULT_SIGINT = ["env", "--default-signal=INT"]


def signal_state(pid: int) -> str:
    """A process's ignored and blocked signals (for a failure message: why it did not stop)."""
    try:
        lines = Path(f"/proc/{pid}/status").read_text().splitlines()
    except OSError:
        return "gone"
    return ", ".join(line for line in lines if line.startswith(("SigIgn", "SigBlk", "SigCgt")))


class AppProcess(Child):
    """One program, ``python -m automotive.<apps|tools>.<name> <args>``."""

    def __init__(self, name: str, args: list[str], cwd: Path, env: dict[str, str] | None = None):
        super().__init__(name, [*DEFAULT_SIGINT, *program_command(name, *args)], cwd=cwd,
                         env={**os.environ, **(env or {})})


class AppRunner:
    def __init__(self, root: Path):
        self.root = root  # the working directory of the processes
        self.processes: list[Child] = []

    def start(self, name: str, *args: str, env: dict[str, str] | None = None) -> AppProcess:
        process = AppProcess(name, list(args), self.root, env)
        self.processes.append(process)
        return process

    def start_command(self, name: str, command: list[str], env: dict[str, str] | None = None,
                      stdin: bool = False, separate_stderr: bool = False) -> Child:
        """Start any command (stopped at the end like the applications); ``name`` labels its failures;
        ``separate_stderr``: its lines are stdout's only (a program whose library logs to stderr in pieces)."""
        process = Child(name, [*DEFAULT_SIGINT, *command], cwd=self.root, env={**os.environ, **(env or {})},
                        stdin=stdin, separate_stderr=separate_stderr)
        self.processes.append(process)
        return process

    def run(self, name: str, *args: str, timeout: float = DEFAULT_TIMEOUT,
            env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
        """Run a program to completion, capturing stdout and stderr separately."""
        return subprocess.run(program_command(name, *args), cwd=self.root, env={**os.environ, **(env or {})},
                              capture_output=True, text=True, timeout=timeout)

    def stop_all(self) -> None:
        for process in self.processes:
            process.stop()


def command_of(name: str) -> str:
    """How a program names itself in its usage and errors: ``vision`` -> ``automotive-vision``, ``record`` ->
    ``automotive record``, ``bridge`` -> ``automotive foxglove-bridge`` (the command the user types)."""
    from automotive import command

    if name in command.APPS:
        return f"automotive-{name.replace('_', '-')}"
    module = program_module(name)
    return next(f"automotive {word}" for word, entry in command.TOOLS.items() if entry.module == module)
