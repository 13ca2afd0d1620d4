"""The real-time settings of an application (config.realtimePriority, config.lockMemory: automotive.bus.realtime):
applied where the process is permitted (the tests run as root), one line each where it is not (the same application
with CAP_SYS_NICE and CAP_IPC_LOCK dropped), and the application runs either way. The launcher gives them to the
alert chain's applications only.
"""

from __future__ import annotations

import os
import re
import shutil
import time
from pathlib import Path

import pytest
from apprunner import AppProcess

from automotive.bus.realtime import LOCK_MEMORY_KEY, PRIORITY_KEY
from automotive.tools.launch.launch import build_parser
from automotive.tools.launch.plan import REALTIME_APPS, plan
from automotive.tools.support.children import DEFAULT_TIMEOUT

PRIORITY = 7
SETTINGS = ["-D", f"{PRIORITY_KEY}={PRIORITY}", "-D", f"{LOCK_MEMORY_KEY}=true"]
ROOT = os.geteuid() == 0
SETPRIV = shutil.which("setpriv")


def threads(pid: int) -> dict[int, tuple[str, int, int]]:
    """Each thread of ``pid``: its name, scheduling policy (without SCHED_RESET_ON_FORK) and priority."""
    found = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        tid = int(task.name)
        try:
            name = (task / "comm").read_text().strip()
            policy = os.sched_getscheduler(tid) & ~os.SCHED_RESET_ON_FORK
            found[tid] = (name, policy, os.sched_getparam(tid).sched_priority)
        except (OSError, ProcessLookupError):
            continue  # a thread that ended meanwhile
    return found


def locked_kib(pid: int) -> int:
    status = Path(f"/proc/{pid}/status").read_text()
    match = re.search(r"^VmLck:\s+(\d+) kB", status, re.MULTILINE)
    assert match is not None, status
    return int(match.group(1))


def wait_until_fifo(pid: int, process: AppProcess) -> dict[int, tuple[str, int, int]]:
    """The threads once the application's own thread runs at SCHED_FIFO (at the end of its set-up)."""
    deadline = time.monotonic() + DEFAULT_TIMEOUT
    while True:
        found = threads(pid)
        if found.get(pid, ("", 0, 0))[1] == os.SCHED_FIFO:
            return found
        assert process.poll() is None, process.output
        assert time.monotonic() < deadline, f"the application's thread never ran at SCHED_FIFO: {found}"
        time.sleep(0.05)  # polling /proc: nothing to wait on


@pytest.mark.skipif(not ROOT, reason="needs root (or CAP_SYS_NICE and CAP_IPC_LOCK)")
def test_permitted_the_taking_and_receive_threads_run_at_the_priority_and_memory_is_locked(
        apps: object, domain_id: int) -> None:
    platform = apps.start("vehicle_platform", "--domain", str(domain_id), "-D", "config.statusInterval=1",  # type: ignore[attr-defined]
                          *SETTINGS)
    pid = platform.process.pid
    found = wait_until_fifo(pid, platform)
    assert found[pid] == (found[pid][0], os.SCHED_FIFO, PRIORITY)
    receive = [info for tid, info in found.items() if info[0] == "recv"]
    assert receive == [("recv", os.SCHED_FIFO, PRIORITY)], found
    # Only those two: Cyclone's housekeeping and the application's other threads stay at the default policy.
    others = {tid: info for tid, info in found.items() if tid != pid and info[0] != "recv"}
    assert others and all(info[1] == os.SCHED_OTHER for info in others.values()), found
    assert locked_kib(pid) > 0
    platform.wait_for("status:")  # it runs: a status line a second
    assert "not applied" not in platform.output


@pytest.mark.skipif(not ROOT or SETPRIV is None, reason="needs root and setpriv to drop the capabilities")
def test_not_permitted_one_line_each_and_the_application_runs(apps: object, domain_id: int) -> None:
    # Root without CAP_SYS_NICE and CAP_IPC_LOCK: no real-time priority (RLIMIT_RTPRIO 0) and a finite
    # RLIMIT_MEMLOCK, as for an ordinary user.
    command = [SETPRIV, "--bounding-set=-sys_nice,-ipc_lock", "--inh-caps=-sys_nice,-ipc_lock", "--"]
    from automotive.tools.support.children import program_command

    platform = apps.start_command("vehicle_platform", [  # type: ignore[attr-defined]
        *command, *program_command("vehicle_platform", "--domain", str(domain_id), "-D", "config.statusInterval=1",
                                   *SETTINGS)])
    platform.wait_for("status:")  # it runs
    lines = platform.lines
    priority_lines = [line for line in lines if f"{PRIORITY_KEY}={PRIORITY} not applied" in line]
    lock_lines = [line for line in lines if f"{LOCK_MEMORY_KEY}=true not applied" in line]
    assert len(priority_lines) == 1 and "not permitted" in priority_lines[0], lines
    assert len(lock_lines) == 1 and "not permitted" in lock_lines[0], lines
    assert "Traceback" not in platform.output
    pid = platform.process.pid
    assert all(info[1] == os.SCHED_OTHER for info in threads(pid).values())
    assert locked_kib(pid) == 0


@pytest.mark.parametrize("value", ["50", "-1", "high"])
def test_a_bad_priority_is_refused_in_one_line(apps: object, domain_id: int, value: str) -> None:
    result = apps.run("vehicle_platform", "--domain", str(domain_id), "-D",  # type: ignore[attr-defined]
                      f"{PRIORITY_KEY}={value}")
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and PRIORITY_KEY in result.stderr, result.stderr
    assert "Traceback" not in result.stderr


def test_the_launcher_gives_the_settings_to_the_chain_only() -> None:
    specs, _ = plan(build_parser().parse_args([]))
    for spec in specs:
        given = " ".join(spec.args)
        expected = spec.module in REALTIME_APPS
        assert (f"{PRIORITY_KEY}=" in given) == expected, (spec.name, given)
        assert (f"{LOCK_MEMORY_KEY}=true" in given) == expected, (spec.name, given)
    assert {spec.module for spec in specs} >= {"camera_pub", "lidar"} | set(REALTIME_APPS)
    # The user's -D comes after the launcher's and wins.
    specs, _ = plan(build_parser().parse_args(["-D", f"{PRIORITY_KEY}=0"]))
    fusion = next(spec for spec in specs if spec.module == "sensor_fusion")
    assert fusion.args.index(f"{PRIORITY_KEY}=0") > fusion.args.index(f"{PRIORITY_KEY}=10")
