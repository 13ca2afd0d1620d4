"""The installed package, as a user gets it: the wheel built from this tree, installed (not editable) into a fresh
virtual environment, run from an empty folder far from the source tree.

No network: the wheel is built and installed from .venv/wheelhouse (scripts/setup puts the pinned dependencies' and
the build requirements' wheels there).
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from apprunner import AppRunner

ROOT = Path(__file__).resolve().parent.parent
WHEELHOUSE = ROOT / ".venv" / "wheelhouse"
# The console scripts pyproject.toml declares, as the development install (scripts/setup) registered them.
SCRIPTS = sorted(entry.name for entry in importlib.metadata.distribution("automotive-databus").entry_points
                 if entry.group == "console_scripts")
NOT_COPIED = shutil.ignore_patterns(".venv", ".git", "build", "logs", "out", "__pycache__", "*.egg-info", ".*_cache")


class Installation:
    def __init__(self, venv: Path, wheel: Path, home: Path):
        self.venv = venv
        self.bin = venv / "bin"
        self.wheel = wheel
        self.home = home  # an empty folder: the working directory of every command
        # As a user's Python: the first import of a module writes its bytecode (the install skips byte-compiling; a
        # PYTHONDONTWRITEBYTECODE of the tests' environment would make every command compile every module again).
        self.env = {key: value for key, value in os.environ.items()
                    if key not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONDONTWRITEBYTECODE")}
        self.env["PATH"] = os.pathsep.join([str(self.bin), *(part for part in self.env.get("PATH", "").split(
            os.pathsep) if Path(part).resolve() != (ROOT / ".venv" / "bin").resolve())])

    def run(self, *command: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
        return subprocess.run([str(self.bin / command[0]), *command[1:]], cwd=self.home, env=self.env,
                              capture_output=True, text=True, timeout=timeout)


def must(command: list[str], timeout: float = 600) -> str:
    result = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, f"{' '.join(command)}:\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    return result.stdout


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Installation:
    if not (WHEELHOUSE / ".complete").is_file():
        pytest.fail(f"{WHEELHOUSE} is not complete: scripts/setup makes it")
    work = tmp_path_factory.mktemp("package")
    source = work / "source"
    shutil.copytree(ROOT, source, ignore=NOT_COPIED)
    dist = work / "dist"
    must([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-index", "--find-links", str(WHEELHOUSE),
          "-w", str(dist), str(source)])
    [wheel] = dist.glob("automotive_databus-*.whl")
    venv = work / "venv"
    must([sys.executable, "-m", "venv", str(venv)])
    # --no-compile: byte-compiling every dependency took half of the install (12 of 22 s quiet); what the tests run
    # is compiled on its first import instead (Installation.env)
    must([str(venv / "bin" / "python"), "-m", "pip", "install", "-q", "--no-compile", "--no-index", "--find-links",
          str(WHEELHOUSE), str(wheel)])
    home = work / "empty"
    home.mkdir()
    return Installation(venv, wheel, home)


def test_the_wheel_holds_one_package_with_its_configuration(installed: Installation) -> None:
    names = zipfile.ZipFile(installed.wheel).namelist()
    top = {name.split("/")[0] for name in names if not name.startswith("automotive_databus-")}
    assert top == {"automotive"}
    for shipped in ("automotive/config/properties/vision.properties", "automotive/config/properties/data/vision.csv",
                    "automotive/config/properties/data/platform.csv", "automotive/config/qos/automotive_qos.xml",
                    "automotive/config/idl/automotive.idl", "automotive/types/.idlpy_manifest",
                    # automotive monitor's page, served from package data
                    "automotive/tools/monitor/page/index.html", "automotive/tools/monitor/page/app.js",
                    "automotive/tools/monitor/page/style.css",
                    "automotive/tools/monitor/page/vendor/cytoscape.min.js",
                    "automotive/tools/monitor/page/vendor/cytoscape.LICENSE"):
        assert shipped in names, shipped
    where = installed.run("python", "-c", "import automotive; print(automotive.__file__)")
    assert where.stdout.startswith(str(installed.venv)), where.stdout + where.stderr  # not the source tree


@pytest.mark.parametrize("script", SCRIPTS)
def test_every_console_script_answers_help_and_version(installed: Installation, script: str) -> None:
    result = installed.run(script, "--help")
    assert result.returncode == 0 and "usage:" in result.stdout, result.stdout + result.stderr
    version = installed.run(script, "--version")
    assert version.returncode == 0 and "Cyclone DDS Python" in version.stdout, version.stdout + version.stderr


def test_the_command_reaches_a_benchmark_and_an_application(installed: Installation) -> None:
    bench = installed.run("automotive", "bench", "soak", "--help")
    assert bench.returncode == 0 and bench.stdout.startswith("usage: automotive bench soak"), bench.stdout
    app = installed.run("automotive", "run", "lidar", "--help")
    assert app.returncode == 0 and app.stdout.startswith("usage: automotive run lidar"), app.stdout


def test_the_configuration_export_is_a_usable_copy(installed: Installation, domain_id: int) -> None:
    folder = installed.home / "my-config"
    export = installed.run("automotive", "config", "export", str(folder))
    assert export.returncode == 0, export.stderr
    for name in ("properties/vision.properties", "properties/data/vision.csv", "qos/automotive_qos.xml",
                 "idl/automotive.idl"):
        assert (folder / name).is_file(), name
    again = installed.run("automotive", "config", "export", str(folder))
    assert again.returncode == 2 and again.stderr.count("\n") == 1 and "--overwrite" in again.stderr
    # The copy is the one used: its own sensor id and its own (relative) QoS and data files.
    properties = folder / "properties" / "vision.properties"
    properties.write_text(properties.read_text().replace("config.sensorId=1", "config.sensorId=9"))
    vision = installed.run("automotive-vision", "--properties", str(properties), "--domain", str(domain_id),
                           "--count", "2", "-D", "config.pubInterval=10", "-v")
    assert vision.returncode == 0, vision.stdout + vision.stderr
    assert "vision sensor 9:" in vision.stdout and vision.stdout.count("published sample") == 2, vision.stdout


def test_the_launcher_runs_the_system_from_an_empty_folder(installed: Installation, domain_id: int) -> None:
    runner = AppRunner(installed.home)
    launcher = runner.start_command("automotive launch", [
        str(installed.bin / "automotive"), "launch", "--mode", "background", "--domain", str(domain_id),
        "vision", "sensor_fusion", "collision_avoidance", "hmi", "-D", "collision_avoidance:config.alertSize=1.0"],
        env={**installed.env, "DISPLAY": "", "WAYLAND_DISPLAY": ""})
    try:
        launcher.wait_for(r"4 application\(s\) running", timeout=60)
        launcher.wait_for(r"^hmi\s+\| .*!!! DRIVER ALERT !!!", timeout=60)  # the HMI's console box
        launcher.process.send_signal(signal.SIGINT)
        assert launcher.wait_exit(timeout=30) == 0, launcher.output[-3000:]
        summary = (installed.home / "logs" / "launch-summary.txt").read_text()
        assert len(re.findall(r"stopped on SIGTERM, exit code 0", summary)) == 4, summary
        assert "python -m automotive.apps.hmi" in launcher.output
    finally:
        runner.stop_all()


def test_the_monitor_answers_once_and_in_json_from_an_empty_folder(installed: Installation, domain_id: int) -> None:
    runner = AppRunner(installed.home)
    vision = runner.start_command("automotive-vision", [str(installed.bin / "automotive-vision"), "--domain",
                                                        str(domain_id)], env=installed.env)
    try:
        vision.wait_for(r"vision: status: ", timeout=60)  # publishing, with its /diagnostics
        before = sorted(installed.home.iterdir())
        text = installed.run("automotive", "monitor", "--once", "--domain", str(domain_id), "--wait", "3")
        assert text.returncode == 0, text.stdout + text.stderr
        assert re.search(r"^\s*vision\b", text.stdout, re.M) and "VisionTopic" in text.stdout, text.stdout
        document = installed.run("automotive", "monitor", "--json", "--domain", str(domain_id), "--wait", "3")
        assert document.returncode == 0, document.stderr
        names = {participant.get("name") for participant in json.loads(document.stdout)["participants"]}
        assert "vision" in names, names
        assert sorted(installed.home.iterdir()) == before  # it writes no file
    finally:
        runner.stop_all()
