"""One command, ``automotive``: its subcommands reach every tool, benchmark and application; every program answers
``--version``; usage lines and error hints name the command as the user typed it; only ``automotive`` and the eight
applications are console scripts."""

from __future__ import annotations

import importlib.metadata
import subprocess
import sys

import pytest
from apprunner import DEFAULT_SIGINT, signal_state

from automotive import command
from automotive.bus.version import DISTRIBUTION

AUTOMOTIVE = [sys.executable, "-m", "automotive"]
APPLICATION_SCRIPTS = {f"automotive-{name.replace('_', '-')}": f"{module.module}:main"
                       for name, module in command.APPS.items()}
EVERY_COMMAND = ([[name] for name in command.TOOLS] + [["run", name] for name in command.APPS]
                 + [["bench", name] for name in command.BENCHMARKS])


def automotive(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*AUTOMOTIVE, *args], capture_output=True, text=True, timeout=60)


def test_the_console_scripts_are_automotive_and_the_eight_applications() -> None:
    scripts = {entry.name: entry.value for entry in importlib.metadata.distribution(DISTRIBUTION).entry_points
               if entry.group == "console_scripts"}
    assert scripts == {"automotive": "automotive.command:main", **APPLICATION_SCRIPTS}


def test_help_lists_every_command() -> None:
    result = automotive("--help")
    assert result.returncode == 0
    for name in (*command.TOOLS, "run APP", "bench NAME"):
        assert f"\n  {name} " in result.stdout, name
    benchmarks = automotive("bench")
    for name in command.BENCHMARKS:
        assert f"\n  {name} " in benchmarks.stdout, name


@pytest.mark.parametrize("args, message", [
    (["recrod"], "automotive: unknown command 'recrod'; did you mean 'record'? (automotive --help lists them)"),
    (["bench", "soa"], "automotive bench: unknown benchmark 'soa'; did you mean 'soak'?"),
    (["run", "visoin"], "automotive run: unknown application 'visoin'; did you mean 'vision'?"),
    (["run", "xyz"], "automotive run: unknown application 'xyz'; expected one of: vision, lidar,"),
    (["run", "vision", "--bogus"],
     "automotive run vision: unrecognized arguments: --bogus (automotive run vision --help shows the usage)"),
    (["record", "--bogus"],
     "automotive record: the following arguments are required: --output/-o (automotive record --help"),
    (["bench", "soak", "--bogus"], "automotive bench soak: unrecognized arguments: --bogus (automotive bench soak "),
    (["launch", "--bogus"], "automotive launch: unrecognized arguments: --bogus (automotive launch --help shows"),
])
def test_errors_name_the_command_as_typed(args: list[str], message: str) -> None:
    result = automotive(*args)
    assert result.returncode == 2
    assert result.stderr.startswith(message), result.stderr
    assert len(result.stderr.splitlines()) == 1 and "Traceback" not in result.stderr


@pytest.mark.parametrize("args", EVERY_COMMAND, ids=" ".join)
def test_every_command_answers_version_and_names_itself(args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    # in this process: each is the main(argv) of its module, as the command runs it
    with pytest.raises(SystemExit) as ended:
        command.main([*args, "--version"])
    assert ended.value.code == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"automotive {' '.join(args)} {importlib.metadata.version(DISTRIBUTION)} ")
    assert lines[1].startswith(f"Cyclone DDS Python {importlib.metadata.version('cyclonedds')} ")
    assert lines[2] in ("fast paths: on",) or lines[2].startswith("fast paths: off (")


def test_an_application_names_its_own_command() -> None:
    result = subprocess.run([sys.executable, "-m", "automotive.apps.sensor_fusion", "--help"], capture_output=True,
                            text=True, timeout=60)
    assert result.stdout.startswith("usage: automotive-sensor-fusion ")


def test_the_fast_paths_off_are_said_with_why() -> None:
    result = subprocess.run([*AUTOMOTIVE, "--version"], capture_output=True, text=True, timeout=60,
                            env={**__import__("os").environ, "AUTOMOTIVE_FAST_PATHS": "off"})
    assert "fast paths: off (AUTOMOTIVE_FAST_PATHS=off)" in result.stdout


def test_ctrl_c_ends_a_benchmark_without_a_traceback(domain_id: int) -> None:
    import signal

    process = subprocess.Popen([*DEFAULT_SIGINT, *AUTOMOTIVE, "bench", "filter", "--domain", str(domain_id)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert process.stdout is not None
    assert process.stdout.readline()  # it runs
    state = signal_state(process.pid)
    process.send_signal(signal.SIGINT)
    _, errors = process.communicate(timeout=60)
    assert process.returncode == 130 and "Traceback" not in errors, f"{errors} (signals when sent: {state})"
