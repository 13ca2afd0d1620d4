"""The suite's guard against processes that outlive their test (tests/leftovers.py, used by conftest for every test)."""

from __future__ import annotations

import subprocess

import psutil
from leftovers import descendants, stop_leftovers


def test_an_orphan_is_adopted_named_and_killed() -> None:
    before = descendants()
    # The shell ends at once; its background sleep is orphaned and, adopted by this process, stays in its tree.
    subprocess.run(["sh", "-c", "exec sleep 300 </dev/null >/dev/null 2>&1 & echo $!"], check=True, timeout=30,
                   capture_output=True, text=True)
    [orphan] = [psutil.Process(pid) for pid in descendants() - before]
    assert orphan.ppid() == psutil.Process().pid and orphan.name() == "sleep"
    named = stop_leftovers(before, grace_s=1.0)
    assert len(named) == 1 and named[0].startswith(f"{orphan.pid} sleep 300"), named
    assert not psutil.pid_exists(orphan.pid)  # killed and reaped


def test_a_process_that_ends_within_the_grace_is_no_leftover() -> None:
    before = descendants()
    subprocess.run(["sh", "-c", "sleep 0.5 </dev/null >/dev/null 2>&1 &"], check=True, timeout=30)
    assert stop_leftovers(before) == []  # waited for, within the grace
    assert descendants() == before  # and reaped
