"""How every program of the package starts, so that Ctrl-C or SIGTERM at any moment ends it with one line.

Importing a program (Cyclone DDS, numpy, the generated types) takes a second or more. A signal in that second used to
end it with a traceback of the import (Ctrl-C) or with no word at all (SIGTERM's default action). The console scripts
(``automotive``, ``automotive-vision`` ...) and ``python -m automotive.start MODULE ARGS`` (how the launcher, the
benchmarks and the tests start a program) import the program and run its ``main(argv)`` here, and this module imports
nothing of the package but automotive.methodcache (which imports nothing of it either):

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
from typing import TYPE_CHECKING, Any, cast

from automotive.methodcache import compiled_once

if TYPE_CHECKING:
    from importlib.machinery import ModuleSpec

EXIT_INTERRUPTED = 130  # the shell's code for "ended by SIGINT"


class Stopped(BaseException):
    """SIGTERM arrived while no handler of the program's own was in place (a BaseException: no ``except Exception``
    of the program swallows it)."""


def _raise_stopped(signum: int, frame: FrameType | None) -> None:
    raise Stopped(signum)


# Modules of the standard library that a dependency imports as it loads but uses only in functions no program here calls
# at its start. While that dependency loads, the module is a stand-in (:class:`_StandIn`) that imports the real one on
# first use; about 50-60 ms of CPU less at every program's start here (asyncio pulls in ssl; urllib.request pulls in
# http.client, email and ssl). Each entry is a fact about the dependency's pinned version, checked by
# tests/test_startup_imports.py: the dependency's import leaves the module unloaded, and its use still works.
DEFERRED: dict[str, tuple[str, ...]] = {
    "cyclonedds": ("asyncio",),  # only the async read and wait methods use it (cyclonedds/core.py, sub.py)
    # only xml.sax.saxutils's prepare_input_source uses it, which javaproperties' XML functions do not call
    "javaproperties": ("urllib.request",),
}


class _StandIn(ModuleType):
    """Where a dependency imported a deferred module: the first attribute asked for imports the real module (its
    attributes are kept here once asked for). Bound only by the dependency's own modules: once the dependency has
    loaded, ``import`` gives everyone else the real module (a submodule's stand-in stays its package's attribute,
    which the dependency reads, until the real submodule is imported)."""

    def __getattr__(self, attribute: str) -> Any:
        if attribute.startswith("__"):  # __path__, __file__...: no import machinery treats this as the real module
            raise AttributeError(attribute)
        name = self.__name__
        if sys.modules.get(name) is self:
            sys.modules.pop(name, None)
        value = getattr(importlib.import_module(name), attribute)
        setattr(self, attribute, value)
        return value


def _load_deferring(deferred: tuple[str, ...], load: Callable[[ModuleType], None], module: ModuleType) -> None:
    """Load the dependency ``module`` (its loader's exec_module, ``load``) with stand-ins for ``deferred`` in
    sys.modules (and as attributes of their packages, as an import sets them); stand-ins nobody used are taken out
    of sys.modules afterwards."""
    placed: list[_StandIn] = []
    for deferred_name in deferred:
        if deferred_name in sys.modules:
            continue
        package, _, child = deferred_name.rpartition(".")
        stand_in = _StandIn(deferred_name)
        if package:
            setattr(importlib.import_module(package), child, stand_in)
        sys.modules[deferred_name] = stand_in
        placed.append(stand_in)
    try:
        load(module)
    finally:
        for stand_in in placed:
            if sys.modules.get(stand_in.__name__) is stand_in:
                del sys.modules[stand_in.__name__]


class _DeferringFinder:
    """Finds the dependencies of DEFERRED through the rest of sys.meta_path and loads them with stand-ins (a meta path
    finder; not importlib.abc's subclass, whose import costs more than this saves)."""

    def find_spec(self, name: str, path: Any = None, target: ModuleType | None = None) -> ModuleSpec | None:
        deferred = DEFERRED.get(name)
        if deferred is None:
            return None
        for finder in sys.meta_path[sys.meta_path.index(self) + 1:]:
            spec = finder.find_spec(name, path, target) if hasattr(finder, "find_spec") else None
            if spec is not None:
                break
        else:
            return None
        loader = spec.loader
        if loader is None or not hasattr(loader, "exec_module"):
            return spec
        load = loader.exec_module

        def exec_module(module: ModuleType) -> None:
            del loader.exec_module  # type: ignore[attr-defined]  # the loader's own method again
            _load_deferring(deferred, load, module)

        loader.exec_module = exec_module  # type: ignore[method-assign]  # this loader instance, this one load
        return spec


def import_program(module: str) -> ModuleType:
    """Import a program with the cyclic garbage collector paused, the modules of DEFERRED deferred and the
    dataclasses' methods compiled once per machine (automotive.methodcache). An import makes tens of thousands of
    objects that all live on (modules, classes, the dataclasses' generated functions: Cyclone's XTypes and QoS classes,
    the generated types), and the collector, triggered every 700 allocations, searched them about 120 times for
    garbage there is none of: 5 % of a program's start-up here."""
    was_enabled = gc.isenabled()
    gc.disable()
    finder = None
    if not any(isinstance(installed, _DeferringFinder) for installed in sys.meta_path):
        finder = _DeferringFinder()
        sys.meta_path.insert(0, finder)
    try:
        with compiled_once():
            return importlib.import_module(module)
    finally:
        if finder is not None:
            sys.meta_path.remove(finder)
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
