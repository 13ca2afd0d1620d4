"""The shipped configuration, as package data: one properties file per program, the QoS profiles, the IDL and the
CSV data of the vision sensor and the vehicle platform.

Layout (the same in the package and in a copy made with ``automotive config export DIR``)::

    properties/<program>.properties     qos.File=../qos/automotive_qos.xml, dataFile=data/<name>.csv
    properties/data/{vision,platform}.csv
    qos/automotive_qos.xml
    idl/automotive.idl

Relative paths in a properties file resolve against that file's folder, so the shipped files find each other inside
the installed package and an exported copy finds its own files. Read with ``importlib.resources``; the standard
library only, so that every layer may ask for it.
"""

from __future__ import annotations

import atexit
import contextlib
import shutil
from importlib.resources import as_file, files
from pathlib import Path

_stack = contextlib.ExitStack()
atexit.register(_stack.close)
_root: Path | None = None

FOLDERS = ("properties", "qos", "idl")


def shipped_dir() -> Path:
    """The folder of the shipped configuration as a real path (extracted once if the package is not on disk)."""
    global _root
    if _root is None:
        _root = _stack.enter_context(as_file(files(__name__)))
    return _root


def properties_dir() -> Path:
    return shipped_dir() / "properties"


def properties_file(program: str) -> Path:
    """The shipped properties file of a program (``vision``, ``record``...)."""
    return properties_dir() / f"{program}.properties"


def qos_file() -> Path:
    return shipped_dir() / "qos" / "automotive_qos.xml"


def idl_file() -> Path:
    return shipped_dir() / "idl" / "automotive.idl"


def export(destination: Path, overwrite: bool = False) -> list[Path]:
    """Copy the shipped configuration into ``destination`` (properties/, qos/, idl/); return the files written.

    Refuses (FileExistsError naming the first one) to replace an existing file unless ``overwrite``.
    """
    source = shipped_dir()
    planned = [(path, destination / path.relative_to(source)) for folder in FOLDERS
               for path in sorted((source / folder).rglob("*")) if path.is_file() and "__pycache__" not in path.parts]
    if not overwrite:
        for _, target in planned:
            if target.exists():
                raise FileExistsError(str(target))
    written = []
    for path, target in planned:
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, target)
        written.append(target)
    return written
