"""The large flows choose their way per reader, without a property: shared memory on this host, DDS for the others.

The LiDAR and sensor fusion run on their defaults (``config.transport`` unset: auto), each test with a file prefix of
its own. A DDS reader of another locality (here a plain reader in the test process, which announces no shared-memory
key) makes the LiDAR write on DDS only while it is matched; after it leaves, the LiDAR's DDS instance is unregistered,
so that neither the LiDAR's offered deadline nor sensor fusion's requested one is missed while the clouds go on through
shared memory. The camera's and the tools' cases are in tests/test_shm.py, tests/test_lidar_view.py and the tools'
modules; another vendor's late reader of the camera in tests/test_late_joiners.py.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

from dds_helpers import make_bus, wait_until
from lidar_helpers import Clouds
from shm_helpers import files_of

from automotive.bus import stats as records

TIMEOUT = 120.0


def lidar_records(path: Path) -> int:
    """The clouds sensor fusion has taken so far (its --stats records of kind "lidar")."""
    return sum(1 for _ in records.read(path, "lidar")) if path.exists() else 0


def test_a_dds_reader_that_comes_and_goes_is_served_on_dds_only_meanwhile_and_no_deadline_is_missed(  # type: ignore[no-untyped-def]
        apps, domain_id: int, prefix: str, tmp_path: Path) -> None:
    stats = tmp_path / "fusion.jsonl"
    common = ["--domain", str(domain_id), "-D", f"config.shmPrefix={prefix}"]
    fusion = apps.start("sensor_fusion", *common, "--stats", str(stats))
    lidar = apps.start("lidar", *common)
    wait_until(lambda: lidar_records(stats) >= 5, TIMEOUT, "sensor fusion takes clouds through shared memory")

    bus = make_bus(domain_id)  # another locality's reader: the LiDAR writes on DDS for it
    try:
        Clouds(bus).next(lambda cloud: True, "on DDS", count=5, timeout=TIMEOUT)
    finally:
        bus.close()
    left_at = lidar_records(stats)
    # Past both deadlines (writer 1 s, reader 2 s) with the clouds flowing through shared memory only: 3 s of clouds.
    wait_until(lambda: lidar_records(stats) >= left_at + 60, TIMEOUT, "three more seconds of clouds")

    assert lidar.stop(signal.SIGTERM) == 0, lidar.output
    line = lidar.wait_for(r"shared memory: \d+ clouds sent, \d+ written on DDS", timeout=TIMEOUT)
    sent, written = (int(word) for word in line.split() if word.isdigit())
    assert 5 <= written <= sent - 60, line  # on DDS only while the reader was there
    assert fusion.stop(signal.SIGTERM) == 0, fusion.output
    for app in (lidar, fusion):
        assert "deadline missed" not in app.output, app.output
    taken = list(records.read(stats, "lidar"))
    assert len({record["src"] for record in taken}) == len(taken), "a cloud taken twice"
    assert files_of(prefix) == set()


def test_clouds_reach_sensor_fusion_in_order_and_once_with_a_dds_reader_beside(  # type: ignore[no-untyped-def]
        apps, domain_id: int, prefix: str, tmp_path: Path) -> None:
    """While the LiDAR writes on DDS as well (a DDS reader is matched), sensor fusion still takes each cloud once:
    the DDS copies of a writer that reaches it through shared memory are left out."""
    stats = tmp_path / "fusion.jsonl"
    common = ["--domain", str(domain_id), "-D", f"config.shmPrefix={prefix}"]
    bus = make_bus(domain_id)
    try:
        clouds = Clouds(bus)
        fusion = apps.start("sensor_fusion", *common, "--stats", str(stats))
        lidar = apps.start("lidar", *common)
        clouds.next(lambda cloud: True, "on DDS", count=40, timeout=TIMEOUT)
        # Sensor fusion may have started after the LiDAR on a busy machine: 30 clouds taken while the DDS copies flow.
        wait_until(lambda: lidar_records(stats) >= 30, TIMEOUT, "sensor fusion takes 30 clouds")
        assert lidar.stop(signal.SIGTERM) == 0, lidar.output
    finally:
        bus.close()
    assert fusion.stop(signal.SIGTERM) == 0, fusion.output
    taken = list(records.read(stats, "lidar"))
    sources = [record["src"] for record in taken]
    assert len(taken) >= 30 and sources == sorted(set(sources)), sources  # each once, in order
    line = lidar.wait_for(r"shared memory: \d+ clouds sent, \d+ written on DDS", timeout=TIMEOUT)
    sent, written = (int(word) for word in line.split() if word.isdigit())
    assert sent >= len(taken) and written >= 40, line
    assert time.time() - max(sources) / 1e9 < 60  # source timestamps on this host's clock
