"""The launcher (automotive launch, behind scripts/launch) in background mode: every application reaches its steady
state, Ctrl-C and `automotive launch stop` stop them all, an application that dies is reported with its exit code,
subsets and several vision sensors."""

from __future__ import annotations

import fcntl
import importlib.util
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterable
from pathlib import Path

import pytest
import small_disk
from apprunner import AppRunner, CommandProcess
from dds_helpers import wait_until

from automotive import config
from automotive.bus import stats
from automotive.tools.launch.display import Console
from automotive.tools.launch.supervisor import SECOND_INTERRUPT_AFTER_S
from automotive.tools.support import children

ROOT = Path(__file__).resolve().parent.parent
# The console script automotive launch, as the running interpreter runs it (as scripts/launch does: through
# automotive.start, its import and its signals).
LAUNCH = children.program_command("launch")
APPS = ("vision", "lidar", "sensor_fusion", "vehicle_platform", "collision_avoidance", "hmi", "camera_pub",
        "camera_sub")
# The first line that shows an application doing its work: a sample published or received.
STEADY = {
    "vision": r"published sample 1:",
    "lidar": r"frame \d+: \d+ points",  # a point cloud written (logged every config.logEvery frames)
    "sensor_fusion": r"published list 1:",
    "vehicle_platform": r"command \d+ stamped",  # a PlatformControl received from collision avoidance
    "collision_avoidance": r"command 1:",  # an object list received, a command published
    "hmi": r"DRIVER ALERT",
    "camera_pub": r"published \d+ frames",
    "camera_sub": r"samples=[1-9]",
}
# Light settings: an alert from the first object list (every car is taller than 1 m), small camera frames.
SYSTEM_OVERRIDES = ["-D", "collision_avoidance:config.alertSize=1.0",
                    "-D", "camera_pub:config.imageSize=64KiB", "-D", "camera_sub:config.imageSize=64KiB",
                    "-D", "camera_pub:config.pubInterval=100"]
STOP_TIMEOUT = 10.0
STARTED = re.compile(r"^launch\s+\| started (\S+) \(pid (\d+)\)")


def available(module: str) -> bool:
    return (importlib.util.find_spec(f"automotive.apps.{module}") is not None
            and config.properties_file(module).is_file())


def launch(apps: AppRunner, domain_id: int, log_dir: Path, *args: str,
           env: dict[str, str] | None = None) -> CommandProcess:
    # No display: the HMI shows its console box whatever the test machine has. -v: every line of the applications
    # on the console, the samples that show each one at work included (tests/test_console.py: the default console).
    return apps.start_command("launch", [*LAUNCH, "--mode", "background", "-v",
                                         "--domain", str(domain_id), "--log-dir", str(log_dir),
                                         "--stop-timeout", str(STOP_TIMEOUT), *args],
                              env={"DISPLAY": "", "WAYLAND_DISPLAY": "", **(env or {})})


def started_pids(launcher: CommandProcess) -> dict[str, int]:
    launcher.wait_for(r"application\(s\) running")
    return pids_started(launcher.lines)


def pids_started(lines: Iterable[str]) -> dict[str, int]:
    """Each application's pid from the launcher's "started NAME (pid N)" lines, read up to "application(s) running"
    (which comes once all started): a pipe's lines are read no further."""
    pids: dict[str, int] = {}
    for line in lines:
        if match := STARTED.match(line):
            pids[match.group(1)] = int(match.group(2))
        if "application(s) running" in line:
            break
    return pids


alive = children.alive  # the process exists and is not a zombie


def tail(path: Path, size: int = 6000) -> str:
    return path.read_text(errors="replace")[-size:] if path.is_file() else f"({path} does not exist)"


def app_line(name: str, pattern: str) -> str:
    return rf"^{re.escape(name)}\s+\| .*{pattern}"


def test_whole_system_reaches_steady_state_and_ctrl_c_stops_it(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                                tmp_path: Path) -> None:
    stats_dir = tmp_path / "stats"
    stats_dir.mkdir()
    launcher = launch(apps, domain_id, tmp_path, *SYSTEM_OVERRIDES, "--stats-dir", str(stats_dir))
    pids = started_pids(launcher)
    expected = [name for name in APPS if available(name)]
    assert sorted(pids) == sorted(expected)
    for name in APPS:
        if name not in expected:  # not in this version yet: said clearly, and the others run
            launcher.wait_for(rf"{name} is not available in this version")

    for name in expected:
        launcher.wait_for(app_line(name, STEADY[name]), timeout=40)

    start = time.monotonic()
    launcher.process.send_signal(signal.SIGINT)
    assert launcher.wait_exit(timeout=STOP_TIMEOUT + 15) == 0, launcher.output[-3000:]
    assert time.monotonic() - start < STOP_TIMEOUT + 5
    for name, pid in pids.items():
        assert not alive(pid), f"{name} (pid {pid}) is still running"
        launcher.wait_for(rf"^launch\s+\|\s+{name}\s+pid {pid}\s+stopped on SIGTERM, exit code 0", timeout=1)
        log = (tmp_path / f"{name}.log").read_text()
        assert re.search(STEADY[name], log), f"{name}.log lacks its steady-state line"
        assert f"--- {name} stopped on SIGTERM" in log
    assert not (tmp_path / "launch.pid").exists()
    assert "how each application ended" in (tmp_path / "launch-summary.txt").read_text()
    # --stats-dir: each application's status records in <name>.jsonl (what automotive bench soak reads)
    for name in expected:
        assert any(True for _ in stats.read(stats_dir / f"{name}.jsonl", "ready")), f"{name}.jsonl has no ready"
    assert any(record["state"] == "alert" for record in stats.read(stats_dir / "hmi.jsonl", "shown"))
    assert any(True for _ in stats.read(stats_dir / "camera_sub.jsonl", "window"))


def test_an_application_that_dies_is_reported_with_its_exit_code(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                                  tmp_path: Path) -> None:
    # hmi refuses a property value out of range (exit code 2: a key it knows, so the launcher's check of the keys
    # lets it start); vision is killed; sensor fusion goes on until stopped.
    launcher = launch(apps, domain_id, tmp_path, "vision", "sensor_fusion", "hmi", "-D", "hmi:config.mallocTrim=-5")
    pids = started_pids(launcher)
    launcher.wait_for(r"^launch\s+\| hmi ended on its own after [\d.]+ s, exit code 2 \(last error: "
                      r".*config.mallocTrim = -5")
    launcher.wait_for(app_line("sensor_fusion", STEADY["sensor_fusion"]))

    os.kill(pids["vision"], signal.SIGKILL)
    launcher.wait_for(r"^launch\s+\| vision ended on its own after [\d.]+ s, killed by SIGKILL \(signal 9\)",
                      timeout=5)
    assert alive(pids["sensor_fusion"])  # the others go on (until stopped below: "stopped on SIGTERM")

    stop = subprocess.run([*LAUNCH, "stop", "--log-dir", str(tmp_path)], capture_output=True,
                          text=True, timeout=STOP_TIMEOUT + 30)
    # Seen once in a clean-clone run: the launcher did not end. What hung, with the threads' stacks dumped on the way.
    assert stop.returncode == 0, "\n".join([stop.stdout, stop.stderr, "--- launcher:", launcher.output[-6000:],
                                            "--- sensor_fusion.log:", tail(tmp_path / "sensor_fusion.log")])
    assert re.search(r"sensor_fusion\s+pid \d+\s+stopped on SIGTERM, exit code 0", stop.stdout), stop.stdout
    assert re.search(r"hmi\s+pid \d+\s+ended on its own after [\d.]+ s, exit code 2", stop.stdout), stop.stdout
    assert launcher.wait_exit(timeout=5) == 1  # some application failed
    assert not any(alive(pid) for pid in pids.values())


def test_an_application_that_does_not_stop_is_killed_after_the_stop_timeout(apps,  # type: ignore[no-untyped-def]
                                                                            domain_id: int, tmp_path: Path) -> None:
    launcher = apps.start_command("launch", [*LAUNCH, "--mode", "background", "-v", "--domain", str(domain_id),
                                             "--log-dir", str(tmp_path), "--stop-timeout", "5", "vision", "hmi"],
                                  env={"DISPLAY": "", "WAYLAND_DISPLAY": ""})
    pids = started_pids(launcher)
    launcher.wait_for(app_line("vision", STEADY["vision"]))
    launcher.wait_for(app_line("hmi", "waiting for alerts"))  # its SIGTERM handler is set: it stops cleanly
    os.kill(pids["vision"], signal.SIGSTOP)  # hung: it neither stops on SIGTERM nor dumps its stacks
    try:
        launcher.process.send_signal(signal.SIGTERM)
        assert launcher.wait_exit(timeout=20) == 1
    finally:
        if alive(pids["vision"]):
            os.kill(pids["vision"], signal.SIGKILL)
    launcher.wait_for(r"^launch\s+\| vision did not stop within 5 s after SIGTERM: killed by SIGKILL \(signal 9\) "
                      rf"\(its threads' stacks are in {re.escape(str(tmp_path / 'vision.log'))}\)$", timeout=1)
    launcher.wait_for(r"^launch\s+\| hmi stopped on SIGTERM, exit code 0", timeout=1)
    assert not any(alive(pid) for pid in pids.values())


def test_one_ctrl_c_delivered_twice_stops_cleanly_and_a_later_second_one_kills(apps,  # type: ignore[no-untyped-def]
                                                                               domain_id: int,
                                                                               tmp_path: Path) -> None:
    # `timeout -s INT 60 scripts/launch` delivers its interrupt to the launcher and to its process group: one stop,
    # not the "second Ctrl-C" that kills without waiting.
    launcher = apps.start_command("launch", [*LAUNCH, "--mode", "background", "-v", "--domain", str(domain_id),
                                             "--log-dir", str(tmp_path), "--stop-timeout", "60", "vision", "hmi"],
                                  env={"DISPLAY": "", "WAYLAND_DISPLAY": ""})
    pids = started_pids(launcher)
    launcher.wait_for(app_line("vision", STEADY["vision"]))
    launcher.wait_for(app_line("hmi", "waiting for alerts"))
    os.kill(pids["vision"], signal.SIGSTOP)  # it cannot stop: only a kill ends it
    try:
        first = time.monotonic()
        launcher.process.send_signal(signal.SIGINT)
        launcher.process.send_signal(signal.SIGINT)
        launcher.wait_for(r"^launch\s+\| hmi stopped on SIGTERM, exit code 0")
        assert alive(pids["vision"])  # waited for, not killed
        # A person's second Ctrl-C comes later: wait until it is past the launcher's window for duplicates.
        time.sleep(max(0.0, first + SECOND_INTERRUPT_AFTER_S + 0.2 - time.monotonic()))
        launcher.process.send_signal(signal.SIGINT)
        assert launcher.wait_exit(timeout=20) == 1  # long before the 60 s stop timeout
    finally:
        if alive(pids["vision"]):
            os.kill(pids["vision"], signal.SIGKILL)
    launcher.wait_for(r"^launch\s+\| vision killed at once on a second Ctrl-C: killed by SIGKILL", timeout=1)


def test_a_full_disk_loses_log_lines_with_a_word_and_never_stops_the_applications(  # type: ignore[no-untyped-def]
        apps, domain_id: int, tmp_path: Path) -> None:
    """An application whose output nobody reads blocks once the pipe is full: a log file that cannot be written must
    not stop the launcher's reading. The failure is said once; the console still shows each sample; once there is
    room again, the file and the console say how many lines are not in it."""
    disk = tmp_path / "disk"
    disk.mkdir()
    launcher = apps.start_command("launch", small_disk.on_small_disk(disk, [
        *LAUNCH, "--mode", "background", "-v", "--domain", str(domain_id), "--log-dir", str(disk), "vision"]),
        env={"DISPLAY": "", "WAYLAND_DISPLAY": ""})  # its log folder a 1 MB tmpfs
    launcher.wait_for(app_line("vision", STEADY["vision"]))
    logs = small_disk.inside(launcher.pid, disk)
    filler = small_disk.fill(logs)
    launcher.wait_for(rf"^launch\s+\| {re.escape(str(disk))}/vision\.log: No space left on device; its lines are not "
                      r"kept until a write succeeds again \(tried every 5 s\)$")
    sample = app_line("vision", r"published sample \d+:")
    launcher.wait_for_more(sample, 3)  # the console still gets every sample: the launcher reads on
    assert launcher.poll() is None

    filler.unlink()
    again = launcher.wait_for(rf"^launch\s+\| {re.escape(str(disk))}/vision\.log: written again; (\d+) line\(s\) "
                              r"from \d\d:\d\d:\d\d to \d\d:\d\d:\d\d \(No space left on device\) are not in it$")
    lost = int(re.search(r"again; (\d+) line", again).group(1))  # type: ignore[union-attr]
    assert lost >= 3, again
    launcher.wait_for_more(sample, 1)
    text = (logs / "vision.log").read_text(errors="replace")
    marker = re.search(rf"^--- not written here: {lost} line\(s\) from .* \(No space left on device\)$", text, re.M)
    assert marker is not None, text[-3000:]
    wait_until(lambda: "published sample" in (logs / "vision.log").read_text(errors="replace")[marker.end():],
               timeout=30, what="a sample's line in vision.log after its note of the lines not in it")

    launcher.process.send_signal(signal.SIGTERM)
    assert launcher.wait_exit(timeout=30) == 0, launcher.output[-3000:]
    assert "Traceback" not in launcher.output, launcher.output[-3000:]


def test_the_launchers_own_log_that_cannot_be_written_is_said_on_the_console_only(
        capsys: pytest.CaptureFixture[str]) -> None:
    """/dev/full fails every write with ENOSPC: the launcher's lines still reach the console, and so does one line
    about its log, once (a failure of the launcher's log is not written into the launcher's log)."""
    console = Console(["vision"], show_apps=True, launcher_log=Path("/dev/full"))
    for number in range(3):
        console.say(f"line {number}")
    console.close()
    lines = capsys.readouterr().out.splitlines()
    assert lines == ["launch | line 0",
                     "launch | /dev/full: No space left on device; its lines are not kept until a write succeeds "
                     "again (tried every 5 s)",
                     "launch | line 1", "launch | line 2",
                     "launch | /dev/full: 3 line(s) from " + lines[-1].split(" from ")[1]], lines
    assert re.fullmatch(r"launch \| /dev/full: 3 line\(s\) from \d\d:\d\d:\d\d on are not in it \(No space left on "
                        r"device\)", lines[-1]), lines


def test_a_console_nobody_reads_never_stops_the_applications(domain_id: int, tmp_path: Path) -> None:
    """A terminal paused with Ctrl-S, a pager scrolled back, a stalled ssh session: the launcher's output is not read.
    The applications go on (their log files grow), the console holds what it can and says how many lines it left
    out once it is read again, and the launcher still stops cleanly."""
    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, fcntl.F_SETPIPE_SZ, 4096)  # full after some 60 lines
    launcher = subprocess.Popen([*LAUNCH, "--mode", "background", "-v", "--domain", str(domain_id), "--log-dir",
                                 str(tmp_path), "-D", "vision:config.pubInterval=2", "vision"],  # 500 lines a second
                                stdout=write_end, stderr=subprocess.STDOUT,
                                env={**os.environ, "DISPLAY": "", "WAYLAND_DISPLAY": ""})
    os.close(write_end)
    console = os.fdopen(read_end, "r", errors="replace")
    lines: list[str] = []

    def read() -> None:
        for line in console:
            lines.append(line)

    reader = threading.Thread(target=read, daemon=True)  # started when the test reads the console at last
    left_out = re.compile(r"^launch\s+\| (\d+) line\(s\) not shown: the console was not read for a while \(the log "
                          r"files have every line\)$")
    try:
        # Far more lines than the pipe and the console's queue hold (2,000): some are left out, none waits.
        wait_until(lambda: small_disk.last_published_sample(tmp_path / "vision.log") > 3000, timeout=120,
                   what="vision's 3,000th sample in its log file")
        assert launcher.poll() is None
        reader.start()  # read at last: the console says what it left out
        wait_until(lambda: any(left_out.match(line) for line in list(lines)), timeout=60,
                   what="the console's line of the lines it left out")
        launcher.send_signal(signal.SIGTERM)
        assert launcher.wait(timeout=60) == 0, "".join(lines[-50:])
    finally:
        if launcher.poll() is None:
            launcher.kill()
        if reader.ident is not None:  # started: it ends at the launcher's end of output
            reader.join(timeout=30)
        console.close()
    out = "".join(lines)
    counts = [int(match[1]) for line in lines if (match := left_out.match(line))]
    assert sum(counts) > 500, out[-3000:]
    assert "vision  pid" in out.split("how each application ended:")[1], out[-3000:]
    assert "Traceback" not in out


def test_a_console_nobody_reads_leaves_out_application_lines_only_and_counts_them(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The console's own queue, with standard output a pipe nobody reads for a while, full before the console writes
    (so that its writer waits from its first line, however the threads are scheduled): of 3,000 application lines
    some are left out, the count says exactly how many, and the launcher's line (a stop, the summary) is never one of
    them."""
    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, fcntl.F_SETPIPE_SZ, 4096)
    os.set_blocking(write_end, False)
    try:
        while True:
            os.write(write_end, b"\n" * 512)  # empty lines, left out below
    except BlockingIOError:
        pass
    os.set_blocking(write_end, True)
    stdout = os.fdopen(write_end, "w")
    monkeypatch.setattr(sys, "stdout", stdout)
    console = Console(["vision"], show_apps=True, launcher_log=None)
    for number in range(3000):
        console.app_line("vision", f"sample {number}")
    console.say("how each application ended:")
    with os.fdopen(read_end, "r") as pipe:
        lines: list[str] = []
        reader = threading.Thread(target=lambda: lines.extend(text for line in pipe if (text := line.rstrip("\n"))),
                                  daemon=True)
        reader.start()  # read at last
        console.close()
        stdout.close()  # the end of the pipe's output: the reader ends
        reader.join(timeout=30)
    shown = [int(line.split("sample ")[1]) for line in lines if line.startswith("vision | sample ")]
    assert shown == sorted(shown) and len(shown) < 3000, len(shown)
    notice = (r"launch \| (\d+) line\(s\) not shown: the console was not read for a while "
              r"\(the log files have every line\)")
    counts = [int(match[1]) for line in lines if (match := re.fullmatch(notice, line))]
    assert len(shown) + sum(counts) == 3000, (len(shown), counts)
    assert re.fullmatch(notice, lines[-2]) and lines[-1] == "launch | how each application ended:", lines[-3:]


def test_ctrl_z_does_not_suspend_the_launcher(apps, domain_id: int, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """A suspended launcher reads no more output: its applications would stop once their pipes are full."""
    launcher = launch(apps, domain_id, tmp_path, "vision")
    sample = app_line("vision", STEADY["vision"].replace("1:", r"\d+:"))
    launcher.wait_for(sample)
    launcher.process.send_signal(signal.SIGTSTP)
    launcher.wait_for(r"^launch\s+\| Ctrl-Z: the launcher does not suspend \(its applications would stop at their next "
                      r"lines with nobody to read them\); Ctrl-C stops the system$")
    launcher.wait_for_more(sample, 3)
    state = Path(f"/proc/{launcher.pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    assert state != "T", state  # not stopped
    launcher.process.send_signal(signal.SIGINT)
    assert launcher.wait_exit(timeout=STOP_TIMEOUT + 15) == 0, launcher.output[-3000:]


def test_subset_with_three_vision_sensors_stopped_by_launch_stop(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                                  tmp_path: Path) -> None:
    others = [name for name in APPS if name not in ("vision", "sensor_fusion")]
    launcher = launch(apps, domain_id, tmp_path, "--vision-sensors", "3", "--except", ",".join(others))
    pids = started_pids(launcher)
    assert sorted(pids) == ["sensor_fusion", "vision-1", "vision-2", "vision-3"]
    launcher.wait_for(app_line("sensor_fusion", r"of sensor\(s\) 1,2,3$"), timeout=30)
    assert "config.sensorId=2" in (tmp_path / "vision-2.log").read_text().splitlines()[0]

    status = subprocess.run([*LAUNCH, "status", "--log-dir", str(tmp_path)], capture_output=True,
                            text=True, timeout=10)
    assert status.returncode == 0 and status.stdout.count("running") == 4, status.stdout
    stop = subprocess.run([*LAUNCH, "stop", "--log-dir", str(tmp_path)], capture_output=True,
                          text=True, timeout=STOP_TIMEOUT + 30)
    assert stop.returncode == 0, stop.stderr
    assert stop.stdout.count("stopped on SIGTERM, exit code 0") == 4, stop.stdout
    assert launcher.wait_exit(timeout=5) == 0
    assert not any(alive(pid) for pid in pids.values())


@pytest.mark.parametrize(("args", "message"), [
    (["no_such_app"], "unknown application 'no_such_app'"),
    (["--except", "visio"], "--except: unknown application 'visio'"),
    (["--vision-sensors", "0"], "--vision-sensors 0: expected 1 or more"),
    (["-D", "nokey"], "-D nokey: expected KEY=VALUE"),
    (["-D", "radar:config.x=1"], "-D radar:config.x=1: unknown application 'radar'"),
    (["--stats-dir", "no/such/folder"], "--stats-dir no/such/folder: no such folder"),
    (["--stats-dir", "radar:."], "--stats-dir radar:.: unknown application 'radar'"),
])
def test_bad_input_is_one_line_and_exit_code_2(args: list[str], message: str, tmp_path: Path) -> None:
    result = subprocess.run([*LAUNCH, "--log-dir", str(tmp_path), *args],
                            capture_output=True, text=True, timeout=20)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and message in result.stderr, result.stderr
    assert "Traceback" not in result.stderr


def test_an_unknown_key_of_one_application_starts_none(domain_id: int, tmp_path: Path) -> None:
    """Issue 38: the launcher checks the settings of each application given its own -D before it starts any."""
    result = subprocess.run([*LAUNCH, "--mode", "background", "--log-dir", str(tmp_path), "--domain", str(domain_id),
                             "-D", "collision_avoidance:config.alertSiz=1.0"], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 2, result.stdout + result.stderr
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr, result.stderr
    assert "collision_avoidance: automotive-collision-avoidance: " in result.stderr
    assert "unknown key(s) for collision_avoidance: 'config.alertSiz' (-D; did you mean 'config.alertSize'?)" in \
        result.stderr
    assert "nothing was started" in result.stderr and not list(tmp_path.glob("*.log")), result.stdout


def test_list_names_all_eight_applications() -> None:
    result = subprocess.run([*LAUNCH, "--list"], capture_output=True, text=True, timeout=20)
    assert result.returncode == 0
    assert [line.split()[0] for line in result.stdout.splitlines()] == list(APPS)



def test_list_into_a_pipe_nobody_reads_ends_quietly() -> None:
    """``automotive launch --list | head -1``: the reader is gone before the list is written (its end closed first,
    so the write fails every time): exit code 0, no traceback."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        result = subprocess.run([*LAUNCH, "--list"], stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=20)
    finally:
        os.close(write_end)
    assert result.returncode == 0 and result.stderr == "", result.stderr


def test_stop_and_status_find_the_launchers_from_any_folder(apps: AppRunner, domain_id: int, other_domain_id: int,
                                                           tmp_path: Path) -> None:
    """Issue 38: `launch stop` and `status` typed in another folder, without --log-dir, find the user's running
    launchers (a per-user runtime folder); two running: status lists both, stop asks which, --domain chooses."""
    env = {"XDG_RUNTIME_DIR": str(tmp_path / "runtime")}
    (tmp_path / "runtime").mkdir()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()

    def command(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([*LAUNCH, *args], capture_output=True, text=True, cwd=elsewhere,
                              env={**os.environ, **env}, timeout=STOP_TIMEOUT + 30)

    first = launch(apps, domain_id, tmp_path / "one", "vision", env=env)
    started_pids(first)
    first.wait_for(r"`automotive launch stop` stops them")  # the only launcher: the plain command
    status = command("status")
    assert status.returncode == 0, status.stdout + status.stderr
    assert f"domain {domain_id}, logs in {tmp_path / 'one'}" in status.stdout and "vision" in status.stdout

    second = launch(apps, other_domain_id, tmp_path / "two", "vision", env=env)
    started_pids(second)
    second.wait_for(rf"`automotive launch stop --log-dir {re.escape(str(tmp_path / 'two'))}` stops them")
    status = command("status")
    assert status.stdout.count("launcher pid") == 2, status.stdout
    ambiguous = command("stop")
    assert ambiguous.returncode == 2 and ambiguous.stderr.count("\n") == 1, ambiguous.stderr
    assert "2 launchers are running" in ambiguous.stderr and "--domain" in ambiguous.stderr

    stopped = command("stop", "--domain", str(other_domain_id))
    assert stopped.returncode == 0, stopped.stdout + stopped.stderr
    assert f"domain {other_domain_id}, logs in {tmp_path / 'two'}" in stopped.stdout.splitlines()[0]
    assert second.wait_exit(timeout=10) == 0
    assert first.poll() is None
    stopped = command("stop")  # one left: no choice needed
    assert stopped.returncode == 0 and f"domain {domain_id}" in stopped.stdout, stopped.stdout + stopped.stderr
    assert first.wait_exit(timeout=10) == 0
    gone = command("status")
    assert gone.returncode == 1 and "no launcher of yours is running" in gone.stdout
    assert not list((tmp_path / "runtime").rglob("launcher-*.json"))


def test_stop_without_a_launcher_says_so(tmp_path: Path) -> None:
    result = subprocess.run([*LAUNCH, "stop", "--log-dir", str(tmp_path)], capture_output=True,
                            text=True, timeout=20)
    assert result.returncode == 1 and "no launcher is running" in result.stderr


def test_a_child_that_keeps_no_lines_hands_each_to_its_callback() -> None:
    """The launcher's children (keep=False): every line reaches the callback, none stays in the parent's memory
    (a system that runs for hours prints millions of lines)."""
    seen: list[str] = []
    child = children.Child("printer", [sys.executable, "-c", "for n in range(2000): print(f'line {n}')"],
                           on_line=lambda child, line: seen.append(line.text), keep=False)
    assert child.wait_exit(timeout=30) == 0
    assert seen == [f"line {n}" for n in range(2000)]
    assert child.records == [] and child._new_lines.qsize() <= 1  # at most the end-of-stream mark


def test_only_alerts_stand_out_on_the_console() -> None:
    from automotive.tools.launch.display import ALERT_LINE

    assert ALERT_LINE.search("hmi: DRIVER ALERT: Front collision warning")
    assert ALERT_LINE.search("collision_avoidance: ALERT: driver attention needed")
    assert ALERT_LINE.search("hmi WARNING: alert source LOST: the alert writer's liveliness was lost")
    assert not ALERT_LINE.search("hmi: HMI: console alert box, waiting for alerts; no alert source")
    assert not ALERT_LINE.search("+==== no alert state yet ====+ Collision avoidance live, has said nothing yet")


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")
def test_tmux_mode_says_its_mode_and_a_failed_switch(domain_id: int, tmp_path: Path) -> None:
    """Issue 38: in tmux mode the launcher says "tmux mode" (not "background"), and a switch to its session that
    tmux refuses is said as such, with how to watch it."""
    # A tmux server of the test's own, with no client attached: the launcher, as if run inside it ($TMUX), starts
    # its session there, and tmux refuses to switch a client that does not exist.
    socket = tmp_path / "tmux.sock"
    subprocess.run(["tmux", "-S", str(socket), "new-session", "-d", "-s", "other"], check=True, timeout=20)
    env = {**os.environ, "TMUX": f"{socket},1,0", "DISPLAY": "", "XDG_RUNTIME_DIR": str(tmp_path)}
    logs = tmp_path / "logs"
    try:
        started = subprocess.run([*LAUNCH, "--mode", "tmux", "--domain", str(domain_id), "--log-dir", str(logs),
                                  "vision"], capture_output=True, text=True, env=env, timeout=60)
        assert started.returncode == 0, started.stdout + started.stderr
        assert "could not switch to it (no current client)" in started.stdout, started.stdout
        assert f"`tmux attach -t automotive-domain{domain_id}` to watch" in started.stdout, started.stdout
        launch_log = logs / "launch.log"
        wait_until(lambda: launch_log.is_file() and "application(s) running" in launch_log.read_text(), 60,
                   "the launcher in tmux running its application")
        assert "(tmux mode)" in launch_log.read_text(), launch_log.read_text()
        stopped = subprocess.run([*LAUNCH, "stop", "--log-dir", str(logs)], capture_output=True, text=True, env=env,
                                 timeout=STOP_TIMEOUT + 30)
        assert stopped.returncode == 0, stopped.stdout + stopped.stderr
    finally:
        subprocess.run(["tmux", "-S", str(socket), "kill-server"], capture_output=True, timeout=20)
