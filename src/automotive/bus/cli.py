"""Command-line plumbing shared by every program: the applications, the tools, the launcher and the benchmarks.

- ``ArgumentParser``: bad arguments end with one line on stderr and exit code 2 (argparse's usage block is for
  ``--help``, not for a typo).
- The options several programs share, declared once: ``add_domain_option``, ``add_network_options``,
  ``add_override_option``, ``add_log_dir_option``, ``add_stats_option``.
- ``dump_stacks_on_request``: SIGUSR1 prints every thread's Python stack on stderr, so that a process that does not
  stop when asked shows where it waits (the launcher asks before it kills); ``stop_dumping_stacks`` once it ends.
- ``on_signals``: what a stop signal does (set an Event, wake a WaitSet) runs in a thread of its own, never in the
  Python signal handler, where it can deadlock.

The standard library only (``--version`` asks automotive.bus.version, on demand).
"""

from __future__ import annotations

import argparse
import errno
import faulthandler
import os
import re
import signal
import socket
import stat
import sys
import tempfile
import textwrap
import threading
from collections.abc import Callable, Iterable
from pathlib import Path
from types import FrameType
from typing import Any, NoReturn

from automotive.bus import ports

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130  # Ctrl-C before the program was running: the shell's code for "ended by SIGINT"
NETWORK_MODES = ("loopback", "lan", "peers")
MAX_DOMAIN_ID = ports.MAX_DOMAIN_ID  # 231: the highest whose RTPS ports fit in 16 bits (automotive.bus.ports)
DUMP_STACKS_SIGNAL = signal.SIGUSR1
_signal_thread: threading.Thread | None = None
_signal_callbacks: dict[int, list[Callable[[int], None]]] = {}
_signal_callbacks_lock = threading.Lock()

SignalHandler = Callable[[int, FrameType | None], Any]


def dump_stacks_on_request() -> None:
    """On SIGUSR1, write every thread's stack to stderr and go on (call it from the main thread).

    The dump is not made in the signal handler: a Python handler runs only when the main thread is back in Python,
    never while it is stuck in a C call (the case worth diagnosing), and faulthandler's own signal-time dump of all
    threads reads their frames without the GIL and was seen to crash the process (SIGSEGV). The signal thread
    (:func:`on_signals`) makes the dump holding the GIL, so every frame it reads stays valid.
    """
    signal.signal(DUMP_STACKS_SIGNAL, _ignore_in_main_thread)  # a Python handler, so that the byte is written
    _start_signal_thread()
    _register([DUMP_STACKS_SIGNAL], _dump_stacks, once=True)  # however many programs' main run in this process


def _dump_stacks(signum: int) -> None:
    faulthandler.dump_traceback(file=sys.stderr, all_threads=True)


def on_signals(signals: Iterable[signal.Signals], callback: Callable[[int], None],
               main_thread_handler: SignalHandler | None = None) -> Callable[[], None]:
    """Call ``callback(signum)`` from the signal thread each time one of ``signals`` arrives (call it from the main
    thread); returns the function that unregisters it and gives the signals their previous handlers back.

    Why not in the handler: Python runs a signal handler in the main thread between two bytecodes, possibly while
    that thread holds the plain (not re-entrant) lock inside the very ``threading.Event`` the handler would set, in
    ``Event.wait`` or ``Event.clear``: the handler then waits for itself, for ever. Python's C-level handler writes
    the signal's number to the wake-up fd at once, whatever the main thread does; the signal thread reads it and
    calls ``callback`` as an ordinary thread, where taking such a lock only waits until the main thread lets go.
    ``main_thread_handler`` (default: nothing) still runs in the main thread, for what only it can do (raise
    KeyboardInterrupt before there is anything to stop); it must take no lock.
    """
    chosen = list(signals)
    handler = main_thread_handler or _ignore_in_main_thread
    previous = {sig: signal.signal(sig, handler) for sig in chosen}  # a Python handler: the byte is written
    _start_signal_thread()
    _register(chosen, callback)

    def restore() -> None:
        with _signal_callbacks_lock:
            for sig in chosen:
                callbacks = _signal_callbacks.get(int(sig), [])
                if callback in callbacks:
                    callbacks.remove(callback)
        for sig, old in previous.items():
            signal.signal(sig, old)

    return restore


def _register(signals: Iterable[signal.Signals], callback: Callable[[int], None], once: bool = False) -> None:
    """Have the signal thread call ``callback`` for each of ``signals`` (``once``: unless it already does)."""
    with _signal_callbacks_lock:
        for sig in signals:
            callbacks = _signal_callbacks.setdefault(int(sig), [])
            if not (once and callback in callbacks):
                callbacks.append(callback)


def _ignore_in_main_thread(signum: int, frame: FrameType | None) -> None:
    """The Python handler of a signal whose work the signal thread does."""


def _start_signal_thread() -> None:
    global _signal_thread
    if _signal_thread is not None:  # once a process (a test may run several programs' main in one)
        return
    reader, writer = socket.socketpair()
    writer.setblocking(False)  # set_wakeup_fd needs it: the C handler must never block
    signal.set_wakeup_fd(writer.fileno(), warn_on_full_buffer=False)
    _signal_thread = threading.Thread(target=_serve_signals, args=(reader, writer), name="signals", daemon=True)
    _signal_thread.start()


def _serve_signals(reader: socket.socket, writer: socket.socket) -> None:
    # ``writer`` is an argument only to stay open (and registered) as long as this thread runs.
    while data := reader.recv(64):
        for signum in data:
            with _signal_callbacks_lock:
                callbacks = list(_signal_callbacks.get(signum, ()))
            for callback in callbacks:
                try:
                    callback(signum)
                except Exception as error:  # noqa: BLE001  (this thread serves every later signal too)
                    print(f"signal {signum}: {error!r}", file=sys.stderr)


def stop_dumping_stacks() -> None:
    """Ignore SIGUSR1 from here on: called once the process is ending, so that a process asked for its stacks while
    it exits still ends with its own exit code (SIGUSR1's default action terminates)."""
    signal.signal(DUMP_STACKS_SIGNAL, signal.SIG_IGN)


_command_name: str | None = None


def set_command_name(name: str) -> None:
    """The dispatcher (``automotive run vision``) says how the user named the program it runs."""
    global _command_name
    _command_name = name


def command_name(default: str) -> str:
    """The name a program's usage line and hints give it: what the user typed, else its own command's name."""
    return _command_name or default


class ArgumentParser(argparse.ArgumentParser):
    """argparse with a one-line error: ``prog: message (prog --help shows the usage)``, exit code 2; and
    ``--version`` (:mod:`automotive.bus.version`) on every program that has ``--help``."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        description = kwargs.get("description")
        if isinstance(description, str) and "\n\n" in description.strip():  # a module's docstring: its user part
            kwargs["description"], examples = user_help(description, kwargs.get("prog") or "")
            epilog = "\n\n".join(part for part in (examples, kwargs.get("epilog") or "") if part)
            kwargs["epilog"] = epilog or None
            kwargs["formatter_class"] = argparse.RawDescriptionHelpFormatter
        super().__init__(*args, **kwargs)
        if self.add_help:
            from automotive.bus.version import add_version_option

            add_version_option(self)

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: {message} ({self.prog} --help shows the usage)", file=sys.stderr)
        sys.exit(EXIT_BAD_INPUT)


# What a docstring holds for its maintainers, not for a user's --help: RST roles and literals, module paths.
_ROLE = re.compile(r":(?:mod|class|func|meth|attr|data):`~?([^`]+)`")
_LITERAL = re.compile(r"``([^`]+)``")
_MODULE_NOTE = re.compile(r"\s*\((?:see |in |by )?automotive\.[\w.]+(?:[;,][^()]*)?\)|\bautomotive\.(?:\w+\.)+\w+")
_COMMAND_LINE = re.compile(r"^\s{2,}(automotive\b|scripts/|python -m automotive)")
HELP_WIDTH = 100


def user_help(docstring: str, prog: str) -> tuple[str, str]:
    """A program's module docstring as its --help says it: the first paragraph (what the program does), its
    "Exit codes" paragraph, and its example command lines (as the user types them: ``python -m automotive.tools.X``
    becomes the program's own name ``prog``); the design notes stay in the code."""
    paragraphs = [part.strip("\n") for part in re.split(r"\n\s*\n", textwrap.dedent(docstring).strip())]

    def plain(text: str) -> str:
        text = _ROLE.sub(lambda match: match[1].rsplit(".", 1)[-1], text)
        text = _LITERAL.sub(r"\1", text)
        return re.sub(r"\s+", " ", _MODULE_NOTE.sub("", text)).strip()

    def filled(text: str) -> str:
        return textwrap.fill(plain(text), HELP_WIDTH)

    prose = [part for part in paragraphs if not _COMMAND_LINE.match(part)]
    summary = [filled(prose[0])] if prose else []
    summary += [filled(part) for part in prose[1:] if part.startswith("Exit codes")]
    examples = []
    for part in paragraphs:
        for line in part.splitlines():
            if _COMMAND_LINE.match(line):
                line = re.sub(r"python -m automotive\.[\w.]+", prog, line.strip()) if prog else line.strip()
                examples.append("  " + _MODULE_NOTE.sub("", _LITERAL.sub(r"\1", line)).rstrip())
    return "\n\n".join(summary), ("examples:\n" + "\n".join(examples)) if examples else ""


def domain_id(text: str) -> int:
    """An argparse type: a DDS domain id, 0..MAX_DOMAIN_ID (automotive.bus.ports.check_domain_id: every program and
    property that takes a domain says the same)."""
    try:
        return ports.check_domain_id(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def add_domain_option(parser: argparse.ArgumentParser, default: int | None = None,
                      help: str = "DDS domain id (overrides config.domainId)") -> None:
    if default is not None:
        help = f"{help} (default {default})"
    parser.add_argument("--domain", type=domain_id, default=default, help=help)


def add_network_options(parser: argparse.ArgumentParser, for_every: str = "") -> None:
    """``--network``, ``--interface``, ``--peers`` (config.network, config.interface, config.peers)."""
    parser.add_argument("--network", choices=NETWORK_MODES, default=None,
                        help=f"{for_every}single host on loopback (default), multicast LAN, or unicast peers")
    parser.add_argument("--interface", default=None,
                        help=f"{for_every}network interface name or address (config.interface)")
    parser.add_argument("--peers", default=None, metavar="H1,H2",
                        help=f"{for_every}comma-separated unicast peers, multicast off (config.peers)")


def add_override_option(parser: argparse.ArgumentParser, metavar: str = "KEY=VALUE",
                        help: str = "override a property (repeatable)") -> None:
    parser.add_argument("-D", dest="overrides", action="append", default=[], metavar=metavar, help=help)


def add_log_dir_option(parser: argparse.ArgumentParser, default: Path | None = None,
                       help: str = "write every process's output there") -> None:
    parser.add_argument("--log-dir", type=Path, default=default, help=help)


def add_stats_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--stats", type=Path, default=None, metavar="FILE",
                        help="append the periodic status as JSON lines to FILE (one object a line)")


# -- output paths: checked before a program starts --------------------------------------------------------------------
# A file or folder a program writes (a recording, a plot, a log or stats folder) is checked when the command line is
# read, before any participant exists: a missing or read-only folder then ends the program at once with one line, not
# after a run of minutes (a plot written on exit) or with a traceback at the first write. The problems are phrased to
# follow "OPTION PATH: ". Whether a folder takes new files is tried, not guessed from permission bits: root writes
# through them, a read-only mount refuses even root, and network or FUSE file systems have rules of their own.


def output_file_problem(path: Path) -> str | None:
    """Why a program could not create, replace or append to the file ``path``; None when it can."""
    kind, error = _path_kind(path)
    if kind == "folder":
        return "is a folder, not a file"
    if kind == "other":  # an existing file (or a device such as /dev/null): written in place, its folder not needed
        return None if os.access(path, os.W_OK) else f"cannot write to it ({_denial(path)})"
    if error:
        return error
    folder = path.parent
    kind, error = _path_kind(folder)
    if kind == "missing":
        return error or f"folder {folder} does not exist"
    if kind == "other":
        return f"{folder} is not a folder"
    problem = _cannot_create_in(folder)
    return f"cannot create files in folder {folder} ({problem})" if problem else None


def output_folder_problem(path: Path, create: bool = False) -> str | None:
    """Why a program could not write new files into the folder ``path``; None when it can. ``create``: the program
    creates the folder and its missing parents (mkdir -p), so a missing one is fine if its nearest existing parent
    takes new folders."""
    kind, error = _path_kind(path)
    if kind == "other":
        return "is not a folder"
    if kind == "folder":
        problem = _cannot_create_in(path)
        return f"cannot create files in it ({problem})" if problem else None
    if error:
        return error
    if not create:
        return "no such folder"
    parent = path.parent
    while True:
        kind, error = _path_kind(parent)
        if kind != "missing" or error or parent == parent.parent:
            break
        parent = parent.parent
    if error:
        return error
    if kind != "folder":
        return f"cannot create it: {parent} is not a folder"
    problem = _cannot_create_in(parent)
    return f"cannot create it in folder {parent} ({problem})" if problem else None


def input_file(text: str) -> Path:
    """An argparse type: a file the program reads; an empty path or a folder is refused as it is parsed (reading
    them would name the current folder, '.', instead of what the user typed)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("the path is empty: give a file")
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: is a folder, not a file")
    return path


def output_file(text: str) -> Path:
    """An argparse type: a file the program writes (:func:`output_file_problem`), checked as it is parsed."""
    path = Path(text)
    problem = output_file_problem(path)
    if problem:
        raise argparse.ArgumentTypeError(f"{text}: {problem}")
    return path


def output_folder(text: str) -> Path:
    """An argparse type: a folder the program writes into, created with its parents when missing
    (:func:`output_folder_problem` with ``create``), checked as it is parsed."""
    path = Path(text)
    problem = output_folder_problem(path, create=True)
    if problem:
        raise argparse.ArgumentTypeError(f"{text}: {problem}")
    return path


def _path_kind(path: Path) -> tuple[str, str]:
    """("missing" | "folder" | "other", why it cannot be looked at, or "")."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return "missing", ""
    except NotADirectoryError:
        return "missing", f"{path.parent} is not a folder"
    except OSError as error:  # a parent that cannot be searched (EACCES), a symbolic link loop...
        return "missing", f"cannot look at it ({error.strerror})"
    return ("folder" if stat.S_ISDIR(mode) else "other"), ""


def _cannot_create_in(folder: Path) -> str:
    """Why no file can be created in ``folder`` (its strerror), or "": an unnamed temporary file, nothing left."""
    try:
        with tempfile.TemporaryFile(dir=folder):
            return ""
    except OSError as error:
        return error.strerror or str(error)


def _denial(path: Path) -> str:
    """Why an existing file cannot be written: its file system is read-only, else its permissions."""
    try:
        read_only = bool(os.statvfs(path).f_flag & os.ST_RDONLY)
    except OSError:
        read_only = False
    return os.strerror(errno.EROFS if read_only else errno.EACCES)
