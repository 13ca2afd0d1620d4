"""What the launcher starts: the applications chosen on its command line, each with its arguments (the -D settings,
the network options, --stats-dir, redundant mode, several vision sensors, the monitor), checked before any starts.

``PROG`` is the name the launcher goes by (``automotive launch``, or ``scripts/launch``: automotive.tools.launch.launch
sets it from --prog); every module of the launcher words its lines with it.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import re
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from automotive import config
from automotive.bus import realtime
from automotive.bus.cli import output_folder_problem
from automotive.bus.ports import check_domain_id
from automotive.tools.support import children

# Every application of the system, in the order they are listed and started.
APPS = children.APPS
PROG = "automotive launch"
# Redundant mode (--redundant): these run twice, as <name> (the primary) and <name>-2 (the standby), with exclusive
# ownership; readers follow the stronger live instance.
REDUNDANT_APPS = ("sensor_fusion", "collision_avoidance")
PRIMARY_STRENGTH, STANDBY_STRENGTH = 20, 10
# The applications of the alert chain (a vision sample to the driver's alert and the platform's command) run with a
# modest real-time priority and their memory locked, where the host permits it (automotive.bus.realtime; an
# application that is not permitted says so in one line and runs without). Not the camera or the LiDAR: their loops
# move megabytes a frame, and at a real-time priority they would take a core from everything else. Given before the
# user's -D settings, which replace them (-D config.realtimePriority=0 turns it off).
REALTIME_APPS = ("vision", "sensor_fusion", "collision_avoidance", "hmi", "vehicle_platform")
REALTIME_PRIORITY = 10
REALTIME_SETTINGS = (f"{realtime.PRIORITY_KEY}={REALTIME_PRIORITY}", f"{realtime.LOCK_MEMORY_KEY}=true")
MONITOR = "monitor"  # --monitor: the tool's name, as a label and as a program (automotive.tools.monitor.monitor)
MONITOR_PORT = 8780  # the monitor's default (automotive.tools.monitor.server.DEFAULT_PORT)
# The -D settings of every application that the monitor takes too (it refuses keys it does not read).
MONITOR_KEYS = ("config.domainId", "config.transport", "config.shmPrefix")  # shared memory: as the apps


class LaunchError(Exception):
    """Bad input or an impossible request: one line on stderr, exit code 2."""


# -- the applications to start ---------------------------------------------------------------------------------------
@dataclass
class AppSpec:
    name: str  # unique label: the module name, or vision-1, vision-2 ... with several vision sensors
    module: str  # automotive.apps.<module>
    args: list[str]

    @property
    def command(self) -> list[str]:
        return children.program_command(self.module, *self.args)


def missing_reason(module: str) -> str | None:
    """Why an application of the list cannot start in this version of the project, or None if it can."""
    if importlib.util.find_spec(children.program_module(module)) is None:
        return f"module {children.program_module(module)} is missing"
    if not config.properties_file(module).is_file():
        return f"the shipped properties/{module}.properties is missing"
    return None


def split_names(values: Sequence[str], what: str) -> list[str]:
    names = [name.strip() for value in values for name in value.split(",") if name.strip()]
    for name in names:
        if name not in APPS:
            raise LaunchError(f"{what}: unknown application '{name}'; expected one of: {', '.join(APPS)}")
    return names


def overrides_for(module: str, name: str, overrides: Sequence[str]) -> list[str]:
    """The -D arguments for one application: KEY=VALUE for all, APP:KEY=VALUE for that application only."""
    args: list[str] = []
    for item in overrides:
        target, _, setting = item.rpartition(":") if re.match(r"^[\w-]+:", item) else ("", "", item)
        if target and target not in (module, name):
            continue
        args += ["-D", setting]
    return args


def check_overrides(overrides: Sequence[str], vision_sensors: int, redundant: bool = False) -> None:
    instance_names = {f"vision-{i}" for i in range(1, vision_sensors + 1)} if vision_sensors > 1 else set()
    if redundant:
        instance_names |= {f"{module}-2" for module in REDUNDANT_APPS}
    for item in overrides:
        match = re.match(r"^([\w-]+):(.*)$", item)
        setting = match.group(2) if match else item
        if match and match.group(1) not in APPS and match.group(1) not in instance_names:
            raise LaunchError(f"-D {item}: unknown application '{match.group(1)}'; expected one of: {', '.join(APPS)}")
        if "=" not in setting or not setting.split("=", 1)[0].strip():
            raise LaunchError(f"-D {item}: expected KEY=VALUE or APP:KEY=VALUE")
        key, _, value = setting.partition("=")
        if key.strip() == "config.domainId":  # said once here, as --domain says it, not by every application
            try:
                check_domain_id(value.strip())
            except ValueError as error:
                raise LaunchError(f"-D {item}: {error}") from None


def plan(args: argparse.Namespace) -> tuple[list[AppSpec], list[tuple[str, str]]]:
    """The applications to start, and the requested ones that this version does not have (name, reason)."""
    chosen = split_names(args.names, "application list") or list(APPS)
    excluded = set(split_names(args.exclude, "--except"))
    if args.vision_sensors < 1:
        raise LaunchError(f"--vision-sensors {args.vision_sensors}: expected 1 or more")
    check_overrides(args.overrides, args.vision_sensors, args.redundant)
    common: list[str] = []
    for flag in ("domain", "network", "interface", "peers"):
        value = getattr(args, flag)
        if value is not None:
            common += [f"--{flag}", str(value)]
    if args.redundant:
        common += ["-D", "config.redundant=true"]
    specs: list[AppSpec] = []
    missing: list[tuple[str, str]] = []
    for module in APPS:  # the system's order, whatever the order on the command line
        if module not in chosen or module in excluded:
            continue
        reason = missing_reason(module)
        if reason is not None:
            missing.append((module, reason))
            continue
        extra = ["--ui", "auto"] if module == "hmi" else []
        own = [*common, *(arg for setting in REALTIME_SETTINGS for arg in ("-D", setting))] \
            if module in REALTIME_APPS else common
        if module == "vision" and args.vision_sensors > 1:
            for sensor in range(1, args.vision_sensors + 1):
                name = f"vision-{sensor}"
                specs.append(AppSpec(name, module, [*own, "-D", f"config.sensorId={sensor}",
                                                    *overrides_for(module, name, args.overrides)]))
        elif module in REDUNDANT_APPS and args.redundant:
            for name, strength in ((module, PRIMARY_STRENGTH), (f"{module}-2", STANDBY_STRENGTH)):
                specs.append(AppSpec(name, module, [*own, "-D", f"config.instanceName={name}",
                                                    "-D", f"config.ownershipStrength={strength}",
                                                    *overrides_for(module, name, args.overrides)]))
        else:
            specs.append(AppSpec(module, module, [*own, *overrides_for(module, module, args.overrides), *extra]))
    if not 0 <= args.monitor_port <= 65535:
        raise LaunchError(f"--monitor-port {args.monitor_port}: expected a port from 0 to 65535")
    if args.monitor and specs:
        settings = [item for item in args.overrides if not re.match(r"^[\w-]+:", item)
                    and item.split("=", 1)[0].strip() in MONITOR_KEYS]
        flags = [arg for flag in ("domain", "network", "interface", "peers") if getattr(args, flag) is not None
                 for arg in (f"--{flag}", str(getattr(args, flag)))]  # the applications' own, less redundant mode
        specs.append(AppSpec(MONITOR, MONITOR, [*flags, "--port", str(args.monitor_port),
                                                 *(arg for item in settings for arg in ("-D", item))]))
    for spec in specs:
        if spec.module == MONITOR:
            continue
        folder = stats_folder(spec.module, spec.name, args.stats_dir)
        if folder is not None:
            spec.args += ["--stats", str(folder / f"{spec.name}.jsonl")]
    return specs, missing


def check_settings(specs: list[AppSpec], overrides: Sequence[str]) -> None:
    """Each application given a -D APP:KEY=VALUE of its own reads its settings once, without joining the bus, before
    any is started: a key it does not know stops the launch with its one line, instead of that application ending
    with exit code 2 while the others run on. (A -D KEY=VALUE for all goes to every application, so a key one of
    them does not know is an error of every launch, seen at once.) One process checks them all (automotive.start:
    each application imported once there, about a second)."""
    targets = {item.split(":", 1)[0] for item in overrides if re.match(r"^[\w-]+:", item)}
    checked = [spec for spec in specs if spec.module in APPS and (spec.module in targets or spec.name in targets)]
    if not checked:
        return
    request = json.dumps([(spec.name, children.program_module(spec.module), spec.args) for spec in checked])
    result = subprocess.run([sys.executable, "-m", "automotive.start", "--check-settings"], input=request,
                            capture_output=True, text=True)
    try:
        answers = json.loads(result.stdout)
    except ValueError:
        raise LaunchError(f"the check of the applications' settings failed: {result.stderr.strip()[-300:]}") from None
    problems = [f"{name}: {line or f'exit code {code}'}" for name, code, line in answers if code != 0]
    if problems:
        raise LaunchError("; ".join(problems) + " (nothing was started)")


def stats_folder(module: str, name: str, stats_dirs: Sequence[str]) -> Path | None:
    """Where one application writes its status records (--stats-dir DIR for all, APP:DIR for that one), or None."""
    folder: Path | None = None
    for item in stats_dirs:
        target, _, path = item.partition(":") if re.match(r"^[\w-]+:", item) else ("", "", item)
        if target and target not in APPS and not target.startswith(tuple(f"{app}-" for app in APPS)):
            raise LaunchError(f"--stats-dir {item}: unknown application '{target}'; expected one of: "
                              f"{', '.join(APPS)}")
        problem = output_folder_problem(Path(path))
        if problem:
            raise LaunchError(f"--stats-dir {item}: {problem}")
        if not target or target in (module, name):
            folder = Path(path).resolve()
    return folder

