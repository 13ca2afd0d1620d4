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

from domain_ids import claim_domain_ids, worker_domain_ids  # noqa: E402
from leftovers import adopt_orphans, descendants, stop_leftovers  # noqa: E402

from automotive import cyclone  # noqa: E402
from automotive.bus.network import NetworkConfig  # noqa: E402

# In-process participants (and the application processes the tests start, which inherit it) stay on loopback.
os.environ["CYCLONEDDS_URI"] = NetworkConfig().cyclone_xml()
# The programs the tests start log every sample (DEBUG), which many tests wait for; the tests of the default console
# (INFO: state changes and a status line) take the variable out of the child's environment.
os.environ["AUTOMOTIVE_LOG_LEVEL"] = "debug"
# The programs see the streams a plain shell gives them, whatever the developer's environment: a program that needs
# PYTHONUNBUFFERED to say its lines through a pipe as they come is a defect (a benchmark once did).
os.environ.pop("PYTHONUNBUFFERED", None)
# The fast paths of the test process's own endpoints, as every program switches them on when it starts.
cyclone.start()
# Every process a test starts stays in this process's tree, orphans too (tests/leftovers.py).
adopt_orphans()


# Tests that ask for the `domain_id` fixture each get a domain id of their own (a worker's ids are used again, in turn,
# once it has run that many such tests; each test's processes are gone by then), except the ids a module's running
# system holds (module_domain_id) until the module ends. A worker claims its ids on this host at its first test
# (tests/domain_ids.py): xdist's controller, which runs none, claims none.
_worker_ids: list[int] = []
_domain_ids: Iterator[int] = iter(())
_held_domain_ids: set[int] = set()


def _next_domain_id() -> int:
    global _domain_ids
    if not _worker_ids:
        _worker_ids.extend(claim_domain_ids(worker_domain_ids(os.environ.get("PYTEST_XDIST_WORKER", "gw0"),
                                                              int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))))
        _domain_ids = itertools.cycle(_worker_ids)
    for _ in _worker_ids:
        candidate = next(_domain_ids)
        if candidate not in _held_domain_ids:
            return candidate
    raise RuntimeError(f"every domain id of this worker is held by a module: {sorted(_held_domain_ids)}")


# -- the fast tier (scripts/test --fast): tests that start no process -------------------------------------------------
# Whole modules whose tests start no process and answer quickly (less those marked not_fast); a test elsewhere joins
# with @pytest.mark.fast.
FAST_MODULES = {"test_badsamples", "test_codecs", "test_csvdata", "test_layers", "test_methodcache", "test_pointcloud",
                "test_properties", "test_qos", "test_rawsample", "test_soak", "test_types", "test_wsrelay"}


# -- workers (scripts/test runs pytest-xdist with --dist loadgroup) ----------------------------------------------------
# A module runs whole on one worker (its module fixtures, a system started once, process-wide switches such as the
# fast paths stay with its tests), except these, whose tests are independent of each other and of the process (each
# in a network namespace of its own) and together take longer than any other module: they are shared out test by test.
SPREAD_MODULES = {"test_shape_main"}


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        module = item.module.__name__ if item.module is not None else ""
        if module in FAST_MODULES and item.get_closest_marker("not_fast") is None:
            item.add_marker(pytest.mark.fast)
        if module not in SPREAD_MODULES:
            item.add_marker(pytest.mark.xdist_group(module))


@pytest.fixture(autouse=True)
def _no_process_outlives_its_test() -> Iterator[None]:
    """A process a test started and left running fails the test (after a grace), and is killed: it would meet the
    worker's later tests on the domain id it had (tests/leftovers.py)."""
    before = descendants()
    yield
    leftovers = stop_leftovers(before)
    if leftovers:
        pytest.fail(f"process(es) outlived the test (killed now): {'; '.join(leftovers)}", pytrace=False)


class ProcessStarted(RuntimeError):
    pass


@pytest.fixture(autouse=True)
def _fast_tests_start_no_process(request: pytest.FixtureRequest) -> Iterator[None]:
    """A test of the fast tier that starts a process fails: the tier's promise is checked on every run."""
    if request.node.get_closest_marker("fast") is None:
        yield
        return
    original = subprocess.Popen._execute_child  # type: ignore[attr-defined]

    def refuse(self: subprocess.Popen[bytes], args: object, *rest: object, **kwargs: object) -> None:
        raise ProcessStarted(f"a test of the fast tier started a process ({args!r}): take it out of FAST_MODULES or "
                             "its @pytest.mark.fast (tests/conftest.py)")

    subprocess.Popen._execute_child = refuse  # type: ignore[attr-defined]
    try:
        yield
    finally:
        subprocess.Popen._execute_child = original  # type: ignore[attr-defined]


@pytest.fixture
def domain_id() -> int:
    return _next_domain_id()


@pytest.fixture
def other_domain_id(domain_id: int) -> int:
    """A second domain id of the test's own, for a test that runs two systems apart."""
    return _next_domain_id()


@pytest.fixture(scope="module")
def module_domain_id() -> Iterator[int]:
    """A domain id of its own for a module whose tests share one running system: no other test gets it meanwhile."""
    domain = _next_domain_id()
    _held_domain_ids.add(domain)
    try:
        yield domain
    finally:
        _held_domain_ids.discard(domain)


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


_shm_prefixes = itertools.count(1)


@pytest.fixture
def prefix() -> Iterator[str]:
    """A shared-memory file prefix (``config.shmPrefix``) for this test only; whatever remains of it is removed
    afterwards (tests/shm_helpers.py). Name it first among a test's fixtures: its clean-up then runs after the
    programs the test started have stopped."""
    from shm_helpers import remove_files

    name = f"autotest{os.getpid()}x{next(_shm_prefixes)}_"
    yield name
    remove_files(name)
