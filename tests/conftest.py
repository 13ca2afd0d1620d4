"""Test set-up: all DDS traffic on loopback, a private domain id per test, and a runner for application processes."""

from __future__ import annotations

import itertools
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))  # the tests' helper modules

from automotive import cyclone  # noqa: E402
from automotive.bus.network import NetworkConfig  # noqa: E402

# In-process participants (and the application processes the tests start, which inherit it) stay on loopback.
os.environ["CYCLONEDDS_URI"] = NetworkConfig().cyclone_xml()
# The programs the tests start log every sample (DEBUG), which many tests wait for; the tests of the default console
# (INFO: state changes and a status line) take the variable out of the child's environment.
os.environ["AUTOMOTIVE_LOG_LEVEL"] = "debug"
# The fast paths of the test process's own endpoints, as every program switches them on when it starts.
cyclone.start()



def worker_domain_ids(worker: str, workers: int, first: int = 100, last: int = 230) -> range:
    """The domain ids of one pytest-xdist worker (``gw0``, ``gw1``...; one worker without xdist): ``first..last``
    shared out, so that tests on two workers never meet on a domain. Ids below 100 are left to the few tests that
    name one of their own; 231 is the highest id whose ports fit with 120 participant indexes."""
    index = int(worker[2:]) if worker.startswith("gw") and worker[2:].isdigit() else 0
    size = (last - first + 1) // max(workers, 1)
    return range(first + index * size, first + (index + 1) * size)


# Tests that ask for the `domain_id` fixture each get a domain id of their own (a worker's ids are used again, in turn,
# once it has run that many such tests; each test's processes are gone by then).
_domain_ids = itertools.cycle(worker_domain_ids(os.environ.get("PYTEST_XDIST_WORKER", "gw0"),
                                                int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))))


@pytest.fixture
def domain_id() -> int:
    return next(_domain_ids)


@pytest.fixture(scope="module")
def module_domain_id() -> int:
    """A domain id of its own for a module whose tests share one running system."""
    return next(_domain_ids)


@pytest.fixture
def apps() -> Iterator[object]:
    """Start application processes; every one still running at the end of the test is stopped."""
    from apprunner import AppRunner

    runner = AppRunner(ROOT)
    try:
        yield runner
    finally:
        runner.stop_all()


@pytest.fixture
def bus(domain_id: int) -> Iterator[object]:
    """A databus of the test process on the test's domain (loopback, the project's QoS profiles)."""
    from dds_helpers import make_bus

    databus = make_bus(domain_id)
    try:
        yield databus
    finally:
        databus.close()


@pytest.fixture
def virtual_display() -> Iterator[str]:
    """A private X display (Xvfb) for window tests."""
    xvfb = shutil.which("Xvfb")
    if xvfb is None:
        pytest.fail("Xvfb is not installed (scripts/setup installs it)")
    read_fd, write_fd = os.pipe()
    # -displayfd: Xvfb picks a free display number and writes it to the pipe once it accepts connections.
    process = subprocess.Popen([xvfb, "-displayfd", str(write_fd), "-screen", "0", "800x600x24", "-nolisten", "tcp"],
                               pass_fds=(write_fd,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write_fd)
    with os.fdopen(read_fd) as pipe:
        number = pipe.readline().strip()
    try:
        assert number, "Xvfb did not start"
        yield f":{number}"
    finally:
        process.terminate()
        process.wait(timeout=10)
