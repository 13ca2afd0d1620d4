"""The methods ``dataclasses`` writes for each class, compiled once per machine instead of at every start.

``@dataclass`` writes the source of each class's ``__init__``, ``__repr__``, ``__eq__``... and compiles it while the
class is made. A program here makes about 200 dataclasses as it loads (Cyclone DDS Python's XTypes and QoS classes,
the generated types, the package's own), so about 750 such functions: 70-90 ms of CPU at every start, about a sixth
of it (docs/measurements/suite-time.md). Python keeps the compiled modules (``__pycache__``) but not these.

While a program imports (:func:`automotive.start.import_program`), ``dataclasses`` compiles through
:class:`CompiledMethods`: code objects kept by their source text in one file of the user's cache directory
(``$XDG_CACHE_HOME/automotive`` or ``~/.cache/automotive``, one file per Python build). A source compiles to the same
code every time, so the source is the whole key. A file that cannot be read, or was written by another Python, counts
as empty; one that cannot be written leaves the program as fast as before, no slower. The file is loaded as code, as
``__pycache__`` is, so it lives where only the user writes. ``AUTOMOTIVE_METHOD_CACHE=off`` turns it off.

This module imports nothing of the package (automotive.start imports it before anything else).
"""

from __future__ import annotations

import builtins
import dataclasses
import marshal
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from types import CodeType
from typing import Any

ENVIRONMENT = "AUTOMOTIVE_METHOD_CACHE"  # "off": compile at every start, as Python does
FILENAME = f"dataclass-methods.{sys.implementation.cache_tag}.marshal"
# Written first in the file: code objects and marshal's format belong to one interpreter build.
BUILD = (sys.version, sys.hexversion, marshal.version)
# The file keeps every program's methods (about 900 for all the programs here, 0.9 MB) and grows only as class
# definitions change, by upgrades and edits. Past this many, a process that writes it keeps only what it used.
MAX_METHODS = 4000


def cache_directory() -> str | None:
    """``$XDG_CACHE_HOME/automotive``, else ``~/.cache/automotive``; None where neither is an absolute path (no home
    directory), rather than a folder named "~" in the current one."""
    for base in (os.environ.get("XDG_CACHE_HOME", ""), os.path.join(os.path.expanduser("~"), ".cache")):
        if os.path.isabs(base):  # the XDG specification: a relative XDG_CACHE_HOME is to be ignored
            return os.path.join(base, "automotive")
    return None


class CompiledMethods:
    """Code objects by source text, read from ``path`` (empty when missing, unreadable or another build's); ``exec``
    stands in for the builtin while ``dataclasses`` makes classes."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.codes: dict[str, CodeType] = self._read()
        self.used: dict[str, CodeType] = {}  # what this process took or compiled
        self.compiled = 0  # sources not in the file, compiled by this process

    def _read(self) -> dict[str, CodeType]:
        try:
            with open(self.path, "rb") as stream:
                build, codes = marshal.loads(stream.read())
        except (OSError, EOFError, ValueError, TypeError):  # missing, cut short, not ours
            return {}
        if build != BUILD or not isinstance(codes, dict):
            return {}
        return codes

    def exec(self, source: Any, globals: dict[str, Any] | None = None, locals: Any = None) -> None:
        if isinstance(source, str):
            code = self.codes.get(source)
            if not isinstance(code, CodeType):  # not in the file (or not code there: compiled afresh all the same)
                code = self.codes[source] = compile(source, "<string>", "exec")  # as exec(source) compiles it
                self.compiled += 1
            self.used[source] = code
            source = code
        builtins.exec(source, globals, locals)

    def save(self) -> None:
        """Write the file again if this process compiled anything new: whole, under a temporary name first, so that
        a program starting at the same moment reads the old file or the new one, never half of one. Two programs
        that add at once: the last one's file wins, and the other's sources are added at its next start."""
        if not self.compiled:
            return
        kept = self.codes if len(self.codes) <= MAX_METHODS else self.used
        # A name of this process's own (the pid alone repeats across PID namespaces), created, never opened shared.
        temporary = f"{self.path}.{os.getpid()}-{os.urandom(4).hex()}"
        try:
            os.makedirs(os.path.dirname(self.path), exist_ok=True)
            with open(temporary, "xb") as stream:
                stream.write(marshal.dumps((BUILD, kept)))
            os.replace(temporary, self.path)
        except OSError:  # a read-only home, a full disk: the next start compiles again
            try:
                os.unlink(temporary)
            except OSError:
                pass


@contextmanager
def compiled_once(directory: str | None = None) -> Iterator[CompiledMethods | None]:
    """Within the block, ``dataclasses`` takes compiled methods from the cache in ``directory`` (the user's cache
    directory by default) and adds the ones it lacks; the file is written at the end if anything was added."""
    directory = directory or cache_directory()
    # Off, no cache directory, or inside a block of its own already: dataclasses compiles as usual.
    if os.environ.get(ENVIRONMENT) == "off" or directory is None or "exec" in vars(dataclasses):
        yield None
        return
    methods = CompiledMethods(os.path.join(directory, FILENAME))
    # dataclasses calls exec() by its global name: a module attribute of that name is found before the builtin.
    dataclasses.exec = methods.exec  # type: ignore[attr-defined]
    try:
        yield methods
    finally:
        del dataclasses.exec  # type: ignore[attr-defined]
        methods.save()
