"""Command-line plumbing shared by the applications, the launcher and the benchmark scripts.

- ``ArgumentParser``: bad arguments end with one line on stderr and exit code 2 (argparse's usage block is for
  ``--help``, not for a typo).
- ``run_in_project_venv``: a script started with any Python (``scripts/bench-lidar`` runs the system's python3 through
  its shebang) installs the project once (scripts/setup) and restarts itself with the project's ``.venv`` Python,
  where Cyclone DDS and the other pinned dependencies are.

This module imports nothing beyond the standard library: it runs before the project's dependencies can be imported.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path
from typing import Any, NoReturn

ROOT = Path(__file__).resolve().parent.parent
VENV = ROOT / ".venv"
EXIT_BAD_INPUT = 2


class ArgumentParser(argparse.ArgumentParser):
    """argparse with a one-line error: ``prog: message (prog --help shows the usage)``, exit code 2.

    A script of scripts/ is named as the README prints it (``scripts/bench-lidar``).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        script = Path(sys.argv[0]).resolve()
        if "prog" not in kwargs and script.parent == ROOT / "scripts":
            kwargs["prog"] = f"scripts/{script.name}"
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: {message} ({self.prog} --help shows the usage)", file=sys.stderr)
        sys.exit(EXIT_BAD_INPUT)


def in_project_venv() -> bool:
    return Path(sys.prefix).resolve() == VENV.resolve()


def run_in_project_venv(script: str | Path, argv: list[str]) -> None:
    """Return at once inside the project's .venv; else run scripts/setup and re-execute ``script`` there.

    Ends the process with one line and exit code 2 if the set-up fails.
    """
    if in_project_venv():
        return
    result = subprocess.run(["bash", str(ROOT / "scripts" / "setup")], stdout=sys.stderr)
    python = VENV / "bin" / "python"
    if result.returncode != 0 or not python.is_file():
        print(f"{Path(script).name}: scripts/setup failed (exit code {result.returncode}); fix what it reports",
              file=sys.stderr)
        sys.exit(EXIT_BAD_INPUT)
    os.execv(str(python), [str(python), str(Path(script).resolve()), *argv])
