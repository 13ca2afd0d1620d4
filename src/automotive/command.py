"""``automotive``: one command for every tool and benchmark of the databus, as ``ros2``, ``cyclonedds`` and ``git`` are.

    automotive launch                     the whole system on this host (automotive launch --help)
    automotive record -o drive.mcap       record the bus to MCAP
    automotive monitor --once             who talks to whom, and why a writer and a reader do not match
    automotive run vision                 one application (the same as automotive-vision)
    automotive bench soak --minutes 30    a benchmark (automotive bench lists them)
    automotive --version                  this package's, Cyclone DDS's version, and whether the fast paths are on

Each command is the ``main(argv)`` of its own module, given the rest of the command line untouched: the dispatcher only
picks the program, so every program keeps its own parser, usage and exit codes. That is why this is a small table and
not argparse's subparsers, which would parse (and could reject) the programs' options before the programs see them.
Modules are imported only when chosen, so ``automotive --help`` starts no DDS.

The eight applications also have their own commands (``automotive-vision`` ...): the per-application command line is
part of the design. Internal helpers (``python -m automotive.tools.support.make_scene_data``, ``...delay_relay``) are
not here.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from typing import NamedTuple, cast

from automotive.bus.cli import EXIT_BAD_INPUT, ArgumentParser, set_command_name
from automotive.start import import_program

PROG = "automotive"


class Command(NamedTuple):
    module: str
    summary: str


TOOLS: dict[str, Command] = {
    "launch": Command("automotive.tools.launch.launch", "start the applications together, watch them, stop them"),
    "record": Command("automotive.tools.record.record", "record topics of the bus to an MCAP file"),
    "replay": Command("automotive.tools.record.replay", "publish a recording again, at its own pace"),
    "foxglove-bridge": Command("automotive.tools.foxglove_bridge.bridge", "serve the live bus to Foxglove (WebSocket)"),
    "zenoh-bridge": Command("automotive.tools.zenoh.zenoh_bridge",
                            "carry chosen topics to another site over Eclipse Zenoh"),
    "zenoh-certs": Command("automotive.tools.zenoh.zenoh_certs",
                           "make the certificates of two Zenoh sites (mutual TLS)"),
    "shapes-demo": Command("automotive.tools.shapes.shapes", "a small Shapes Demo: publish a circle, or print circles"),
    "shape-main": Command("automotive.tools.shapes.shape_main", "the OMG interoperability suite's shape application"),
    "lidar-view": Command("automotive.tools.lidar_view.lidar_view", "show the LiDAR point cloud (a window or a PNG)"),
    "config": Command("automotive.tools.config.config_export", "export the shipped configuration to edit it"),
    "monitor": Command("automotive.tools.monitor.monitor",
                       "who talks to whom on the domain, and why a pair does not match"),
}
APPS: dict[str, Command] = {
    "vision": Command("automotive.apps.vision", "publishes the objects a vision sensor sees"),
    "lidar": Command("automotive.apps.lidar", "publishes the LiDAR point cloud, Shapes Demo circles as spheres"),
    "sensor_fusion": Command("automotive.apps.sensor_fusion", "aggregates vision and LiDAR into object lists"),
    "collision_avoidance": Command("automotive.apps.collision_avoidance",
                                   "decides: alerts the driver, commands the vehicle"),
    "vehicle_platform": Command("automotive.apps.vehicle_platform", "the CAN-bus vehicle: status out, commands in"),
    "hmi": Command("automotive.apps.hmi", "pops up driver alerts"),
    "camera_pub": Command("automotive.apps.camera_pub", "the rear-view camera: 4 MiB frames"),
    "camera_sub": Command("automotive.apps.camera_sub", "receives the camera's frames and checks them"),
}
BENCHMARKS: dict[str, Command] = {
    "lidar": Command("automotive.bench.lidar", "the LiDAR's rendering and writing rate"),
    "fastpath": Command("automotive.bench.fastpath", "the fast paths against Cyclone's public API"),
    "large-data": Command("automotive.bench.large_data", "camera frames against Cyclone's C ddsperf"),
    "scale": Command("automotive.bench.scale", "many vision sensors into one sensor fusion"),
    "failover": Command("automotive.bench.failover", "time to fail over to a hot standby"),
    "record": Command("automotive.bench.record", "the recorder's throughput"),
    "discovery": Command("automotive.bench.discovery", "how fast late joiners are found"),
    "zenoh": Command("automotive.bench.zenoh_bridge", "the Zenoh bridge between two sites"),
    "soak": Command("automotive.bench.soak", "every application's memory over hours"),
    "filter": Command("automotive.bench.filter", "content filters' cost"),
    "codecs": Command("automotive.bench.codecs", "the generated codecs and sensor fusion's CPU"),
    "alert-latency": Command("automotive.bench.alert_latency", "vision to driver alert, end to end"),
    "console": Command("automotive.bench.console", "how many lines a second the launcher's console shows"),
    "monitor": Command("automotive.bench.monitor", "the monitor's CPU while the whole system runs"),
    "monitor-page": Command("automotive.bench.monitor_page", "how soon the monitor's page shows what runs"),
    "system": Command("automotive.bench.system", "the whole system's CPU, camera latency and LiDAR hop"),
}
GROUPS = {"run": (APPS, "application"), "bench": (BENCHMARKS, "benchmark")}


def _table(commands: dict[str, Command], indent: str = "  ") -> str:
    width = max(map(len, commands))
    return "\n".join(f"{indent}{name.ljust(width)}  {command.summary}" for name, command in commands.items())


def _parser(prog: str, description: str, epilog: str, choices: str) -> ArgumentParser:
    import argparse

    parser = ArgumentParser(prog=prog, description=description, epilog=epilog,
                            formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("command", metavar=choices, nargs="?", help=argparse.SUPPRESS)
    parser.add_argument("args", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    return parser


def _unknown(prog: str, kind: str, name: str, commands: dict[str, Command]) -> int:
    import difflib  # only for a misspelt name: not part of every start

    close = difflib.get_close_matches(name, list(commands), n=1)
    hint = f"; did you mean '{close[0]}'?" if close else f"; expected one of: {', '.join(commands)}"
    print(f"{prog}: unknown {kind} '{name}'{hint} ({prog} --help lists them)", file=sys.stderr)
    return EXIT_BAD_INPUT


def _call(command: Command, argv: list[str], name: str) -> int:
    set_command_name(name)
    main = cast(Callable[[list[str]], int], import_program(command.module).main)
    try:
        return main(argv)
    except KeyboardInterrupt:  # Ctrl-C in a program that does not catch it (a benchmark): an end, not a traceback
        return 130


def _group(group: str, argv: list[str]) -> int:
    commands, kind = GROUPS[group]
    prog = f"{PROG} {group}"
    parser = _parser(prog, f"Run one {kind} of the databus.", f"{kind}s:\n{_table(commands)}", kind.upper())
    if not argv or argv[0] in ("-h", "--help") or argv[0] == "--version":
        parser.parse_args(argv or ["--help"])
        return 0
    name = argv[0].replace("-", "_") if group == "run" else argv[0]
    if name not in commands:
        return _unknown(prog, kind, argv[0], commands)
    return _call(commands[name], argv[1:], f"{prog} {argv[0]}")


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    epilog = (f"commands:\n{_table(TOOLS)}\n"
              f"  run APP          one of the applications (`{PROG} run` lists them; also automotive-<app>)\n"
              f"  bench NAME       one of the benchmarks (`{PROG} bench` lists them)\n\n"
              f"`{PROG} COMMAND --help` shows a command's options.")
    parser = _parser(PROG, "The automotive databus on Eclipse Cyclone DDS: its tools and benchmarks.", epilog,
                     "COMMAND")
    if not args or args[0].startswith("-"):
        parser.parse_args(args or ["--help"])  # --help, --version or a bad option: argparse answers and exits
        return 0
    if args[0] in GROUPS:
        return _group(args[0], args[1:])
    if args[0] not in TOOLS:
        return _unknown(PROG, "command", args[0], {**TOOLS, "run": Command("", ""), "bench": Command("", "")})
    return _call(TOOLS[args[0]], args[1:], f"{PROG} {args[0]}")
