"""The tests' DDS domain ids: the few that tests name themselves, and the rest, shared out among pytest-xdist's
workers (tests/conftest.py hands them out; tests/test_layers.py checks that no test names another).

A worker claims its ids for as long as it runs, with a lock file each in :data:`CLAIMS`, so that another test run on
the same host (another clone's, a CI job beside a developer's) takes others: two runs on one domain hear each other's
samples (seen: a sensor fusion that got another run's vision samples on a topic its own test did not write)."""

from __future__ import annotations

import fcntl
import os
import re
import tempfile
import time
from pathlib import Path

# Domain ids that tests name themselves, none with traffic on the host's loopback: bad input that ends before any
# participant (test_properties, test_bench_edges, test_camera, test_shm, the documented examples); the OMG suite's 0
# and 1 run in network namespaces of their own.
NAMED_DOMAIN_IDS = {0, 1, 5, 7, 73, 81}
# Up to 100: the ports of domains from 101 up reach into the kernel's range of ephemeral ports (32768-60999), where
# another process's socket may hold a domain's fixed discovery multicast port for a while (tests run many of them).
TEST_DOMAIN_IDS = [domain for domain in range(2, 101) if domain not in NAMED_DOMAIN_IDS]


# Where the workers of every test run on this host claim their domain ids; how many a worker claims at most (a
# second run on the host finds the rest) and at least (one a module's system holds, the others in turn); how long it
# waits for that many.
CLAIMS = Path(tempfile.gettempdir()) / "automotive-test-domains"
MOST_CLAIMED = 12
LEAST_CLAIMED = 4
CLAIM_WAIT_S = 600.0
_claimed: dict[int, int] = {}  # domain id -> the descriptor whose lock claims it (held until the process ends)


def worker_domain_ids(worker: str, workers: int) -> list[int]:
    """The domain ids one pytest-xdist worker (``gw0``, ``gw1``...; one worker without xdist) looks at first:
    TEST_DOMAIN_IDS shared out, so that tests on two workers never meet on a domain."""
    index = int(worker[2:]) if worker.startswith("gw") and worker[2:].isdigit() else 0
    size = len(TEST_DOMAIN_IDS) // max(workers, 1)
    return TEST_DOMAIN_IDS[index * size:(index + 1) * size]


def claim_domain_ids(preferred: list[int]) -> list[int]:
    """Domain ids of this process's own on this host, at most MOST_CLAIMED: first those of ``preferred`` that no
    other process claimed, then any other test id. Waits (up to CLAIM_WAIT_S) while other runs hold all but fewer
    than LEAST_CLAIMED. A claim ends with the process, however it ends (the lock goes with its descriptor)."""
    CLAIMS.mkdir(exist_ok=True)
    try:
        CLAIMS.chmod(0o1777)  # every user's test runs claim here (made by the first, the umask aside)
    except PermissionError:  # another user's folder, already open to all
        pass
    candidates = [*preferred, *(domain for domain in TEST_DOMAIN_IDS if domain not in preferred)]
    deadline = time.monotonic() + CLAIM_WAIT_S
    while True:
        for domain in candidates:
            if len(_claimed) >= MOST_CLAIMED:
                break
            if domain not in _claimed:
                _try_claim(domain)
        if len(_claimed) >= LEAST_CLAIMED:
            return sorted(_claimed, key=candidates.index)
        if time.monotonic() > deadline:
            raise RuntimeError(f"only {len(_claimed)} test domain id(s) are free on this host after "
                               f"{CLAIM_WAIT_S:g} s: other test runs hold the rest (their lock files are in {CLAIMS})")
        time.sleep(1.0)


def _try_claim(domain: int) -> None:
    descriptor = os.open(CLAIMS / str(domain), os.O_RDONLY | os.O_CREAT | os.O_CLOEXEC, 0o644)  # a lock needs no more
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:  # another run's
        os.close(descriptor)
        return
    _claimed[domain] = descriptor


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
