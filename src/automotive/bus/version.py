"""What ``--version`` prints on every command: this package's version, Cyclone DDS Python's, and whether the fast
paths (automotive.cyclone) are on in a process started the same way, and if not, why."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

DISTRIBUTION = "automotive-databus"


def package_version() -> str:
    import importlib.metadata  # on demand: most programs that offer --version never print it

    try:
        return importlib.metadata.version(DISTRIBUTION)
    except importlib.metadata.PackageNotFoundError:  # run from a source tree that was never installed
        return "unknown (not installed)"


def version_text(prog: str) -> str:
    from automotive.cyclone import gate  # imported on demand: --version is the only user here

    off = gate.why_off()
    fast_paths = "on" if off is None else f"off ({off})"
    return (f"{prog} {package_version()} ({DISTRIBUTION})\n"
            f"Cyclone DDS Python {gate.cyclone_version()} (fast paths tested on {gate.TESTED_VERSION})\n"
            f"fast paths: {fast_paths}")


class VersionAction(argparse.Action):
    """``--version``: print :func:`version_text` and exit 0 (argparse's own takes a fixed string, made up front)."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS,
                 default: Any = argparse.SUPPRESS, help: str | None = None) -> None:
        super().__init__(option_strings, dest=dest, default=default, nargs=0,
                         help=help or "print the package's, Cyclone DDS's version and the fast paths' state, and exit")

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        print(version_text(parser.prog))
        parser.exit(0)


def add_version_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--version", action=VersionAction)
