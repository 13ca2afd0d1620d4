"""How every program of the package starts, so that Ctrl-C or SIGTERM at any moment ends it with one line.

Importing a program (Cyclone DDS, numpy, the generated types) takes a second or more. A signal in that second used to
end it with a traceback of the import (Ctrl-C) or with no word at all (SIGTERM's default action). The console scripts
(``automotive``, ``automotive-vision`` ...) and ``python -m automotive.start MODULE ARGS`` (how the launcher, the
benchmarks and the tests start a program) import the program and run its ``main(argv)`` here, and this module imports
nothing of the package:

- while the program imports, Ctrl-C and SIGTERM end it at once with one line on stderr, exit code 130 (Ctrl-C) or 0
  (SIGTERM, as a program stopped after its start-up ends). At once, not by raising: an exception raised by a signal
  handler inside an import can be swallowed by C code that clears errors of optional imports (seen here: about one
  SIGTERM in three was lost that way), and nothing needs cleaning up before the program has run;
- once it runs, Ctrl-C raises KeyboardInterrupt (Python's own handler) and SIGTERM raises :class:`Stopped` in the
  main thread, so that ``finally`` blocks stop children and remove files; either ends with one line.

A program that installs handlers of its own (automotive.bus.app.run, the launcher) replaces these once it is running.

Every program's stdout is line-buffered from here on: Python buffers a pipe's stdout in blocks (unless
PYTHONUNBUFFERED is set), so a benchmark's progress read through a pipe (``| tee``, a test, the launcher) came all at
once when it ended. A reader of stdout that leaves early (``| head``) ends the program quietly, exit code 0.
"""

from __future__ import annotations

import gc
import importlib
import io
import os
import signal
import sys
from collections.abc import Callable
from types import FrameType, ModuleType
from typing import Any, cast

EXIT_INTERRUPTED = 130  # the shell's code for "ended by SIGINT"


class Stopped(BaseException):
    """SIGTERM arrived while no handler of the program's own was in place (a BaseException: no ``except Exception``
    of the program swallows it)."""


def _raise_stopped(signum: int, frame: FrameType | None) -> None:
    raise Stopped(signum)


def import_program(module: str) -> ModuleType:
    """Import a program with the cyclic garbage collector paused. An import makes tens of thousands of objects that all
    live on (modules, classes, the dataclasses' generated functions: Cyclone's XTypes and QoS classes, the generated
    types), and the collector, triggered every 700 allocations, searched them about 120 times for garbage there is
    none of: 5 % of a program's start-up here."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        return importlib.import_module(module)
    finally:
        if was_enabled:
            gc.enable()


def _say(name: str, signum: int) -> None:
    print(f"{name}: stopped ({'Ctrl-C' if signum == signal.SIGINT else 'SIGTERM'})", file=sys.stderr, flush=True)


def start(module: str, name: str, argv: list[str] | None = None) -> int:
    """Import ``module`` and return its ``main(argv)``; ``name`` is the command the user typed, for the one line."""
    def end_now(signum: int, frame: FrameType | None) -> None:
        _say(name, signum)
        os._exit(EXIT_INTERRUPTED if signum == signal.SIGINT else 0)

    if isinstance(sys.stdout, io.TextIOWrapper):  # not a StringIO of check_settings
        sys.stdout.reconfigure(line_buffering=True)
    # A signal the parent told this process to ignore (SIG_IGN) stays ignored.
    handled = [sig for sig in (signal.SIGINT, signal.SIGTERM) if signal.getsignal(sig) != signal.SIG_IGN]
    previous: dict[int, Any] = {sig: signal.signal(sig, end_now) for sig in handled}
    try:
        main = cast(Callable[[list[str] | None], int], import_program(module).main)
        for sig in handled:  # running: signals unwind the program
            signal.signal(sig, _raise_stopped if sig == signal.SIGTERM else previous[sig])
        return main(argv)
    except KeyboardInterrupt:
        _say(name, signal.SIGINT)
        return EXIT_INTERRUPTED
    except Stopped:
        _say(name, signal.SIGTERM)
        return 0
    except BrokenPipeError:  # stdout's reader left (``| head``): end quietly, as a program that only prints does
        from automotive.bus.console import silence_stdout  # imported by then: the program is running

        silence_stdout()  # or Python's own flush at exit reports the pipe again
        return 0


def _script(module: str, name: str) -> Callable[[], int]:
    def script() -> int:
        return start(module, name)
    script.module = module  # type: ignore[attr-defined]  # the program it starts (tests/test_layers.py)
    return script


# The console scripts (pyproject.toml's [project.scripts]).
automotive = _script("automotive.command", "automotive")
vision = _script("automotive.apps.vision", "automotive-vision")
lidar = _script("automotive.apps.lidar", "automotive-lidar")
sensor_fusion = _script("automotive.apps.sensor_fusion", "automotive-sensor-fusion")
collision_avoidance = _script("automotive.apps.collision_avoidance", "automotive-collision-avoidance")
vehicle_platform = _script("automotive.apps.vehicle_platform", "automotive-vehicle-platform")
hmi = _script("automotive.apps.hmi", "automotive-hmi")
camera_pub = _script("automotive.apps.camera_pub", "automotive-camera-pub")
camera_sub = _script("automotive.apps.camera_sub", "automotive-camera-sub")


def check_settings(programs: list[tuple[str, str, list[str]]]) -> list[tuple[str, int, str]]:
    """Each program's settings read by its own ``main(args + ["--check-config"])`` (properties and keys, no bus), all
    in this one process: (name, exit code, its error line) of each. The launcher's check before it starts anything:
    one process importing the applications once, rather than one per application (a second or more each)."""
    import contextlib
    import io

    results = []
    for name, module, args in programs:
        errors = io.StringIO()
        with contextlib.redirect_stderr(errors), contextlib.redirect_stdout(io.StringIO()):
            try:
                code = start(module, name, [*args, "--check-config"])
            except SystemExit as ended:  # argparse's exit for a bad option
                code = ended.code if isinstance(ended.code, int) else 2
        lines = errors.getvalue().strip().splitlines()
        results.append((name, code, lines[-1] if lines else ""))
    return results


if __name__ == "__main__" and sys.argv[1:2] == ["--check-settings"]:  # the launcher's: JSON in and out
    import json

    checked = check_settings([(name, module, list(args)) for name, module, args in json.load(sys.stdin)])
    print(json.dumps(checked))
elif __name__ == "__main__":  # python -m automotive.start MODULE ARGS...
    if len(sys.argv) < 2:
        print("usage: python -m automotive.start MODULE [ARGS...]", file=sys.stderr)
        sys.exit(2)
    target, program = sys.argv[1], sys.argv[1].rsplit(".", 1)[-1]
    command = (f"automotive-{program.replace('_', '-')}" if target.startswith("automotive.apps.")
               else f"automotive {program.replace('_', '-')}")
    sys.exit(start(target, command, sys.argv[2:]))
