"""Test set-up: all DDS traffic on loopback, a private domain id per test, and a runner for application processes."""

from __future__ import annotations

import itertools
import os
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from automotive.network import NetworkConfig  # noqa: E402

# In-process participants (and the application processes the tests start, which inherit it) stay on loopback.
os.environ["CYCLONEDDS_URI"] = NetworkConfig().cyclone_xml()

# Domain ids 100..232 belong to tests that ask for the `domain_id` fixture; each test gets its own.
_domain_ids = itertools.cycle(range(100, 233))


@pytest.fixture
def domain_id() -> int:
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
