"""Foxglove's own npm libraries for the tests: tests/foxglove/package-lock.json installed with `npm ci` into a cache
folder (one per lock file, kept between runs), and tests/foxglove/decode.js run with Node.js over it.

Node.js and npm come from the Debian package `nodejs` (scripts/setup installs it, and `npm` where a distribution ships
it apart). The cache is ``$AUTOMOTIVE_NODE_HOME``, else ``$XDG_CACHE_HOME/automotive-node`` (``~/.cache``), one folder
per lock file's hash: a changed lock file installs afresh, an unchanged one costs nothing. Test runs that start at the
same time install once (a file lock), and a half-done install is never used (installed into a temporary folder, then
renamed).
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

PACKAGE_DIR = Path(__file__).resolve().parent / "foxglove"
DECODER = PACKAGE_DIR / "decode.js"
MIN_NODE_MAJOR = 20  # the "engines" of @foxglove/rosmsg2-serialization 3.1.0
INSTALL_TIMEOUT_S = 600.0  # from the npm registry on a loaded machine; seconds from npm's own cache


def cache_root() -> Path:
    if os.environ.get("AUTOMOTIVE_NODE_HOME"):
        return Path(os.environ["AUTOMOTIVE_NODE_HOME"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "automotive-node"


def install() -> Path:
    """The node_modules folder of tests/foxglove/package-lock.json, installed if need be; the test fails with one
    line when Node.js or npm is missing or the install fails."""
    missing = [tool for tool in ("node", "npm") if shutil.which(tool) is None]
    if missing:
        pytest.fail(f"{' and '.join(missing)} not found: install the Debian package nodejs (scripts/setup does)",
                    pytrace=False)
    version = subprocess.run(["node", "--version"], capture_output=True, text=True, timeout=60).stdout.strip()
    if int(version.lstrip("v").split(".")[0] or 0) < MIN_NODE_MAJOR:
        pytest.fail(f"node {version} found: Foxglove's @foxglove/rosmsg2-serialization needs Node.js "
                    f"{MIN_NODE_MAJOR} or newer (the nodejs package of Debian 13, or NodeSource's)", pytrace=False)
    lock = (PACKAGE_DIR / "package-lock.json").read_bytes()
    root = cache_root()
    target = root / hashlib.sha256(lock).hexdigest()[:16]
    if (target / "node_modules").is_dir():
        return target / "node_modules"
    root.mkdir(parents=True, exist_ok=True)
    with open(root / ".lock", "w") as lock_file:
        fcntl.flock(lock_file, fcntl.LOCK_EX)  # another test run may be installing the same lock file
        if not (target / "node_modules").is_dir():
            staging = root / f"{target.name}.installing-{os.getpid()}"
            shutil.rmtree(staging, ignore_errors=True)
            staging.mkdir()
            for name in ("package.json", "package-lock.json"):
                shutil.copy(PACKAGE_DIR / name, staging / name)
            result = subprocess.run(["npm", "ci", "--prefer-offline", "--no-audit", "--no-fund", "--loglevel=error"],
                                    cwd=staging, capture_output=True, text=True, timeout=INSTALL_TIMEOUT_S)
            if result.returncode != 0:
                shutil.rmtree(staging, ignore_errors=True)
                errors = [line for line in result.stderr.splitlines()
                          if line.startswith("npm error") and "complete log" not in line]
                pytest.fail(f"npm ci of {PACKAGE_DIR / 'package-lock.json'} failed: "
                            f"{(errors or result.stderr.strip().splitlines() or ['no output'])[-1]}", pytrace=False)
            shutil.rmtree(target, ignore_errors=True)
            staging.rename(target)
    return target / "node_modules"


class FoxgloveDecoder:
    """tests/foxglove/decode.js with the installed libraries."""

    def __init__(self, node_modules: Path):
        self.env = {"NODE_PATH": str(node_modules)}

    def command(self, *args: str) -> list[str]:
        return ["node", str(DECODER), *args]

    def run(self, *args: str, timeout: float) -> list[dict[str, Any]]:
        """Run to the end; its JSON lines (fails the test on a non-zero exit)."""
        result = subprocess.run(self.command(*args), env={**os.environ, **self.env}, capture_output=True,
                                text=True, timeout=timeout)
        assert result.returncode == 0, f"decode.js {' '.join(args)} exited {result.returncode}:\n" \
            f"{result.stdout[-3000:]}{result.stderr[-3000:]}"
        return json_lines(result.stdout.splitlines())


def json_lines(lines: list[str]) -> list[dict[str, Any]]:
    return [json.loads(line) for line in lines if line.startswith("{")]
