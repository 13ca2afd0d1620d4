"""Command-line plumbing shared by every program: the applications, the tools, the launcher and the benchmarks.

- ``ArgumentParser``: bad arguments end with one line on stderr and exit code 2 (argparse's usage block is for
  ``--help``, not for a typo).
- The options several programs share, declared once: ``add_domain_option``, ``add_network_options``,
  ``add_override_option``, ``add_log_dir_option``, ``add_stats_option``.
- ``dump_stacks_on_request``: SIGUSR1 prints every thread's Python stack on stderr, so that a process that does not
  stop when asked shows where it waits (the launcher asks before it kills).

The standard library only.
"""

from __future__ import annotations

import argparse
import faulthandler
import signal
import sys
from pathlib import Path
from typing import Any, NoReturn

EXIT_BAD_INPUT = 2
NETWORK_MODES = ("loopback", "lan", "peers")
DUMP_STACKS_SIGNAL = signal.SIGUSR1


def dump_stacks_on_request() -> None:
    """On SIGUSR1, write every thread's stack to stderr and go on. faulthandler writes from the C signal handler, so
    the dump comes even while the main thread is stuck inside a C call that holds no Python frame to interrupt."""
    faulthandler.register(DUMP_STACKS_SIGNAL, file=sys.stderr, all_threads=True, chain=False)


class ArgumentParser(argparse.ArgumentParser):
    """argparse with a one-line error: ``prog: message (prog --help shows the usage)``, exit code 2."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: {message} ({self.prog} --help shows the usage)", file=sys.stderr)
        sys.exit(EXIT_BAD_INPUT)


def add_domain_option(parser: argparse.ArgumentParser, default: int | None = None,
                      help: str = "DDS domain id (overrides config.domainId)") -> None:
    if default is not None:
        help = f"{help} (default {default})"
    parser.add_argument("--domain", type=int, default=default, help=help)


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
