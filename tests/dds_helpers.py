"""In-process DDS endpoints for tests, built with the project's own runtime (profiles, loopback)."""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet

from automotive import config
from automotive.bus.endpoints import Databus
from automotive.bus.network import NetworkConfig
from automotive.bus.qos import QosProfiles

ROOT = Path(__file__).resolve().parent.parent
CYCLONEDDS_CLI = str(Path(sys.executable).parent / "cyclonedds")  # the cyclonedds package's console script


def make_bus(domain_id: int, qos_file: Path | None = None) -> Databus:
    profiles = QosProfiles(qos_file or config.qos_file())
    return Databus(domain_id, profiles, "AutomotiveLibrary", logging.getLogger("test"), NetworkConfig())


def wait_until(condition: Callable[[], bool], timeout: float = 15.0, what: str = "condition") -> None:
    """Poll a condition (a DDS status, a file) until it holds; fail after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.02)


def write_until(process: Any, pattern: str, write: Callable[[], Any], timeout: float = 60.0, after: int = 0) -> None:
    """Write (every 20 ms) until the application ``process`` printed ``pattern`` (more than ``after`` times: lines of
    it from before). A writer that matched a reader may not be known to that reader yet (discovery is not
    symmetric): a best-effort sample written then is lost."""
    def seen() -> bool:
        write()
        return process.count(pattern) > after

    wait_until(seen, timeout, f"/{pattern}/ in the output of {process.name}")


def take_samples(reader: Any, count: int, timeout: float = 15.0) -> list[Any]:
    """Take samples (valid data only) until ``count`` arrived or the timeout passed."""
    waitset = WaitSet(reader.participant)
    waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any))
    received: list[Any] = []
    deadline = time.monotonic() + timeout
    while len(received) < count and time.monotonic() < deadline:
        waitset.wait(int(0.1e9))
        received.extend(s for s in reader.take(N=256) if isinstance(s, reader.topic.data_type))
    return received
