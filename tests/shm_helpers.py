"""The iceoryx2 files of a test's own shared-memory prefix (``config.shmPrefix``): what a test looks at and removes.

Every test that runs a shared-memory flow names its files with a prefix of its own (the ``prefix`` fixture of
tests/conftest.py) and looks only at those: other processes on this machine may use iceoryx2 at the same time.
"""

from __future__ import annotations

import contextlib
import re
from pathlib import Path

SHM_ROOT = Path("/dev/shm")
ICEORYX_ROOT = Path("/tmp/iceoryx2")  # iceoryx2's folder of node and service records
GLOBAL_FILE = re.compile(r"node\.[\d_]+\.global_mgmt$")  # iceoryx2's one shared file per prefix, not a service's


def files_of(prefix: str, include_global: bool = False) -> set[Path]:
    """This prefix's files in /dev/shm and under iceoryx2's folder /tmp/iceoryx2 (files and event sockets)."""
    found = set(SHM_ROOT.glob(f"{prefix}*"))
    if ICEORYX_ROOT.is_dir():
        found |= {path for path in ICEORYX_ROOT.rglob(f"{prefix}*") if not path.is_dir()}
    return found if include_global else {path for path in found if not GLOBAL_FILE.search(path.name)}


def remove_files(prefix: str) -> None:
    """Remove whatever remains of this prefix, and the node folders that leaves empty."""
    for path in files_of(prefix, include_global=True):
        path.unlink(missing_ok=True)
        if path.parent.parent == ICEORYX_ROOT / "nodes":  # a node's own folder (named by its id), left empty
            with contextlib.suppress(OSError):
                path.parent.rmdir()
