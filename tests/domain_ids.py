"""The tests' DDS domain ids: the few that tests name themselves, and the rest, shared out among pytest-xdist's
workers (tests/conftest.py hands them out; tests/test_layers.py checks that no test names another)."""

from __future__ import annotations

import re
from pathlib import Path

# Domain ids that tests name themselves (tests/test_camera.py, test_shm.py, the documented examples); the OMG suite's
# 0 and 1 run in namespaces of their own.
NAMED_DOMAIN_IDS = {0, 1, 5, 7, 70, 71, 72, 73, 76, 77, 81}
# Up to 100: the ports of domains from 101 up reach into the kernel's range of ephemeral ports (32768-60999), where
# another process's socket may hold a domain's fixed discovery multicast port for a while (tests run many of them).
TEST_DOMAIN_IDS = [domain for domain in range(2, 101) if domain not in NAMED_DOMAIN_IDS]


def worker_domain_ids(worker: str, workers: int) -> list[int]:
    """The domain ids of one pytest-xdist worker (``gw0``, ``gw1``...; one worker without xdist): TEST_DOMAIN_IDS
    shared out, so that tests on two workers never meet on a domain."""
    index = int(worker[2:]) if worker.startswith("gw") and worker[2:].isdigit() else 0
    size = len(TEST_DOMAIN_IDS) // max(workers, 1)
    return TEST_DOMAIN_IDS[index * size:(index + 1) * size]


# A domain id written into a test: a command's --domain, a config.domainId, a participant's or bus's argument, a
# keyword, a module constant named *DOMAIN*.
_NAMED_DOMAIN = re.compile(r'"--domain",\s*"(\d+)"|--domain[ =](\d+)\b|config\.domainId\s*=\s*(\d+)'
                           r"|\b[A-Z_]*DOMAIN[A-Z_]*\s*=\s*(\d+)\b|\bdomain(?:_id)?\s*=\s*(\d+)\b"
                           r"|\b(?:DomainParticipant|make_bus|Databus)\((\d+)")


def foreign_domain_ids(path: Path) -> list[str]:
    """Lines of ``path`` that name a domain id that conftest hands out to the tests that ask: a test naming one meets
    whichever test on another worker, or later on its own, was given it (seen: a replay's recorded alerts in another
    test's recording)."""
    found = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        for match in _NAMED_DOMAIN.finditer(line):
            domain = int(next(group for group in match.groups() if group is not None))
            if domain in TEST_DOMAIN_IDS:
                found.append(f"{path}:{number}: domain {domain}")
    return found
