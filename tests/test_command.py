"""One command, ``automotive``: its subcommands reach every tool, benchmark and application; every program answers
``--version``; usage lines and error hints name the command as the user typed it; only ``automotive`` and the eight
applications are console scripts."""

from __future__ import annotations

import importlib
import importlib.metadata
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from apprunner import DEFAULT_SIGINT, signal_state
from test_launcher import pids_started

from automotive import command, config
from automotive.bus.version import DISTRIBUTION
from automotive.tools.support.children import Child, handles_signal, wait_until_handled

AUTOMOTIVE = [sys.executable, "-m", "automotive"]
APPLICATION_SCRIPTS = {f"automotive-{name.replace('_', '-')}": f"automotive.start:{name}" for name in command.APPS}
EVERY_COMMAND = ([[name] for name in command.TOOLS] + [["run", name] for name in command.APPS]
                 + [["bench", name] for name in command.BENCHMARKS])


def automotive(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*AUTOMOTIVE, *args], capture_output=True, text=True, timeout=60)


def test_the_console_scripts_are_automotive_and_the_eight_applications() -> None:
    scripts = {entry.name: entry.value for entry in importlib.metadata.distribution(DISTRIBUTION).entry_points
               if entry.group == "console_scripts"}
    assert scripts == {"automotive": "automotive.start:automotive", **APPLICATION_SCRIPTS}
    for name, value in scripts.items():  # each names a program that exists
        module, function = value.split(":")
        assert callable(getattr(importlib.import_module(module), function)), name


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
                            env={**os.environ, "AUTOMOTIVE_FAST_PATHS": "off"})
    assert "fast paths: off (AUTOMOTIVE_FAST_PATHS=off)" in result.stdout


def test_ctrl_c_ends_a_benchmark_without_a_traceback(domain_id: int) -> None:
    # Without PYTHONUNBUFFERED (conftest takes it out): the program's own stdout says each line as it comes.
    process = subprocess.Popen([*DEFAULT_SIGINT, *AUTOMOTIVE, "bench", "filter", "--domain", str(domain_id)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert process.stdout is not None
    assert process.stdout.readline()  # it runs (its first line, while it still runs)
    state = signal_state(process.pid)
    process.send_signal(signal.SIGINT)
    _, errors = process.communicate(timeout=60)
    assert process.returncode == 130 and "Traceback" not in errors, f"{errors} (signals when sent: {state})"


def test_a_benchmark_whose_reader_leaves_ends_quietly(domain_id: int) -> None:
    """``automotive bench filter | head -1``: its next line meets a closed pipe; no traceback, exit code 0."""
    process = subprocess.Popen([*AUTOMOTIVE, "bench", "filter", "--domain", str(domain_id)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert process.stdout is not None and process.stderr is not None
    assert process.stdout.readline()
    process.stdout.close()  # the reader leaves while the benchmark has lines to print
    errors = process.stderr.read()
    assert process.wait(timeout=60) == 0 and errors == "", errors


SCRIPTS = Path(sys.executable).parent  # the console scripts of this installation


def wait_until_caught(process: subprocess.Popen[str], sig: int = signal.SIGTERM) -> None:
    """Until the program's entry (automotive.start) handles SIGTERM: from then on it is still importing for a second
    or more, and no signal may end it with a traceback or without a word."""
    if not wait_until_handled(process.pid, sig, 30, lambda: process.poll() is not None):
        assert process.poll() is None, f"it ended first: {process.communicate()}"
        raise AssertionError("the entry never handled SIGTERM")


@pytest.mark.parametrize(("command_line", "name"), [
    (["automotive-vision"], "automotive-vision"),
    (["automotive", "record", "-o", "{tmp}/drive.mcap"], "automotive"),
    (["automotive", "launch", "--log-dir", "{tmp}/logs"], "automotive"),
], ids=["vision", "record", "launch"])
@pytest.mark.parametrize(("sig", "code", "said"), [(signal.SIGINT, 130, "Ctrl-C"), (signal.SIGTERM, 0, "SIGTERM")],
                         ids=["SIGINT", "SIGTERM"])
def test_a_signal_while_a_program_starts_ends_it_with_one_line(command_line: list[str], name: str, sig: int, code: int,
                                                               said: str, tmp_path: Path, domain_id: int) -> None:
    """Issue 38: Ctrl-C or SIGTERM while the program still imports: one line, exit code 130 or 0, no traceback."""
    args = [str(SCRIPTS / command_line[0]), *(item.format(tmp=tmp_path) for item in command_line[1:])]
    process = subprocess.Popen([*DEFAULT_SIGINT, *args, "--domain", str(domain_id)], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    wait_until_caught(process)
    process.send_signal(sig)
    out, errors = process.communicate(timeout=60)
    assert process.returncode == code, f"{process.returncode}: {out} {errors}"
    assert errors == f"{name}: stopped ({said})\n", errors
    assert "Traceback" not in out


def test_a_launcher_stopped_while_its_applications_start_ends_cleanly(tmp_path: Path, domain_id: int) -> None:
    """Issue 38: SIGTERM to a launcher whose applications are still importing: each ends on SIGTERM with exit code 0
    (not "killed by SIGTERM"), and so does the launcher."""
    process = subprocess.Popen([*DEFAULT_SIGINT, sys.executable, "-m", "automotive.start",
                                "automotive.tools.launch.launch", "--mode", "background", "--domain", str(domain_id),
                                "--log-dir", str(tmp_path), "vision", "hmi"],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                               env={**os.environ, "DISPLAY": "", "WAYLAND_DISPLAY": ""})
    assert process.stdout is not None
    pids = pids_started(process.stdout)
    assert sorted(pids) == ["hmi", "vision"], pids
    for pid in pids.values():  # each application's entry handles SIGTERM (it is importing, or already running)
        assert wait_until_handled(pid, signal.SIGTERM, 30), f"pid {pid} never handled SIGTERM"
    process.send_signal(signal.SIGTERM)
    out, _ = process.communicate(timeout=60)
    assert process.returncode == 0, out
    summary = out.split("how each application ended:")[1]
    assert summary.count("stopped on SIGTERM, exit code 0") == 2, out
    assert "Traceback" not in out and "killed" not in out, out


def test_a_launcher_stopped_before_its_applications_handle_sigterm_lets_them_end_cleanly(tmp_path: Path,
                                                                                         domain_id: int) -> None:
    """Before a program's entry (automotive.start) runs, its interpreter is starting: SIGTERM's default action would
    end it "killed by SIGTERM". The launcher's stop waits until each application handles the signal, then sends it.
    Here the window is made long: the application's interpreter sleeps 1.5 s in a sitecustomize before the entry."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(
        "import sys, time\nif any(arg.startswith('automotive.apps.') for arg in sys.argv):\n    time.sleep(1.5)\n")
    path = os.pathsep.join(part for part in (str(site), os.environ.get("PYTHONPATH", "")) if part)
    process = subprocess.Popen([*DEFAULT_SIGINT, sys.executable, "-m", "automotive.start",
                                "automotive.tools.launch.launch", "--mode", "background", "--domain", str(domain_id),
                                "--log-dir", str(tmp_path / "logs"), "vision"],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                               env={**os.environ, "PYTHONPATH": path, "DISPLAY": "", "WAYLAND_DISPLAY": ""})
    assert process.stdout is not None
    pid = pids_started(process.stdout)["vision"]
    assert not handles_signal(pid, signal.SIGTERM)  # still in its sitecustomize
    process.send_signal(signal.SIGTERM)
    out, _ = process.communicate(timeout=60)
    assert process.returncode == 0, out
    summary = out.split("how each application ended:")[1]
    assert "vision  pid" in summary and "stopped on SIGTERM, exit code 0" in summary, out
    assert "killed" not in out and "Traceback" not in out, out


def test_a_second_ctrl_c_ends_the_wait_for_a_starting_application() -> None:
    """The launcher's stop waits until starting applications handle SIGTERM; a second Ctrl-C (``give_up``) ends that
    wait at once. Here the child never handles it: without ``give_up`` the call would take its whole 60 s."""
    child = Child("sleeper", [sys.executable, "-c", "import time; time.sleep(120)"])
    try:
        begun = time.monotonic()
        assert not child.wait_until_handled(signal.SIGTERM, 60, give_up=lambda: True)
        assert time.monotonic() - begun < 30
        assert child.poll() is None  # it was only given up on, not ended
    finally:
        child.stop(signal.SIGKILL, timeout=10)


@pytest.mark.parametrize("args", EVERY_COMMAND, ids=" ".join)
def test_help_says_what_a_user_does(args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 38: --help is a short summary, the options and examples as typed, not the module's design notes."""
    with pytest.raises(SystemExit) as ended:
        command.main([*args, "--help"])
    assert ended.value.code == 0
    text = capsys.readouterr().out
    for internal in ("``", ":class:", ":mod:", "python -m", "automotive.tools.", "automotive.wire.", "automotive.bus.",
                     "automotive.apps."):
        assert internal not in text, f"{internal!r} in:\n{text}"
    if args[0] == "shape-main":  # the OMG suite's own menu, as every vendor's shape application prints it
        return
    description = text.split("\n\n")[1]  # after the usage
    assert len(description.splitlines()) <= 8, description
    if args[0] in ("run", "record", "launch", "lidar-view", "shapes-demo", "monitor"):
        examples = text.split("examples:\n", 1)[1]
        assert examples.startswith(f"  automotive {' '.join(args)}"), text


LATE_STOP = """
import sys
from automotive.bus.app import run
from automotive.bus.properties import PropertyKeys
built = []
code = run("probe", "", lambda app: (built.append(app), app.ready()), sys.argv[1:], keys=PropertyKeys.of())
built[0].stop()  # as the signal thread does when it serves a SIGTERM after the main thread, stopped by it, closed all
sys.exit(code)
"""


def test_a_stop_that_comes_after_the_application_closed_does_nothing(domain_id: int, tmp_path: Path) -> None:
    """A SIGTERM stops a program twice: its main thread notices it and closes the application, and the signal thread
    asks the application to stop. On a busy machine the second came after the first had closed everything, and the
    program said "signal 15: [DDS_RETCODE_BAD_PARAMETER] ... calling set on GuardCondition" on stderr."""
    properties = tmp_path / "probe.properties"
    properties.write_text(f"qos.File={config.qos_file()}\n")
    result = subprocess.run([sys.executable, "-c", LATE_STOP, "--properties", str(properties), "--domain",
                             str(domain_id)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0 and result.stderr == "", result.stderr
