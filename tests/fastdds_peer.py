"""An eProsima Fast DDS peer for interoperability tests: the C++ programs of tests/fastdds, built here, run as
processes.

The programs are built from their sources on first use in a test session (``make`` in tests/fastdds: fastddsgen
generates the type code from tests/fastdds/automotive.idl and shape.idl, then g++ compiles it against Debian's Fast
DDS 2.9) into build/fastdds/, and rebuilt only when a source changed: ``fastdds_peer`` (the system's flows) and
``shape_peer`` (the OMG interoperability suite's shape application: :func:`shape_peer`). Samples of fastdds_peer come
back as JSON lines:

    peer = FastDdsPeer.read(apps, ["VisionTopic", "AlertTopic"], domain_id, count=3)
    samples = peer.wait_samples("VisionTopic", 3)      # dicts, member names as in the IDL
    circle = FastDdsPeer.write_circle(apps, domain_id, "ORANGE", 216, 135, 60)
    hostile = FastDdsPeer.hostile(apps, "PlatformControl", "enum", domain_id)   # valid CDR, nonsense, until stopped

Octet arrays and sequences arrive as {"size", "crc32"} (zlib's CRC-32), with "base64" too when read with data=True.

The peer stays on loopback (UDPv4 on 127.0.0.1, no shared memory, initial peer 127.0.0.1). With ``defaults=True`` it
is Fast DDS's default participant instead (built-in transports: UDPv4 on every interface and shared memory, multicast
discovery), which multicasts on every interface of its host: it must run inside a test's own network namespace, so
``prefix`` (the command that runs it there, e.g. ``lan.host.exec()``; :func:`private_shm` gives it a /dev/shm of the
test's own) is then required:

    FastDdsPeer.read(apps, ["PlatformStatus"], domain_id, defaults=True, prefix=private_shm(lan.host, shm_folder))
"""

from __future__ import annotations

import base64
import fcntl
import json
import re
import shutil
import subprocess
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parent.parent
SOURCES = ROOT / "tests" / "fastdds"
BUILD = ROOT / "build" / "fastdds"
PROGRAM = BUILD / "fastdds_peer"
SHAPE_PROGRAM = BUILD / "shape_peer"
PACKAGES = "libfastrtps-dev libfastcdr-dev fastddsgen g++ make"
BUILD_TIMEOUT = 600.0  # a build from nothing takes about 10 s on an idle 2-core machine; generous under load


def build() -> Path:
    """Build (or bring up to date) the peers; fail the test with what is missing when Fast DDS is not installed.
    Returns the path of fastdds_peer."""
    missing = [tool for tool in ("fastddsgen", "make", "g++") if shutil.which(tool) is None]
    if missing:
        pytest.fail(f"the Fast DDS test peer cannot be built: {', '.join(missing)} not found; "
                    f"scripts/setup installs the Debian packages {PACKAGES}", pytrace=False)
    started = time.monotonic()
    BUILD.mkdir(parents=True, exist_ok=True)
    with open(BUILD / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # the test workers of one run (pytest-xdist) build once, one after the other
        result = subprocess.run(["make", "-s", "-j2", "-C", str(SOURCES), f"OUT={BUILD}"], capture_output=True,
                                text=True, timeout=BUILD_TIMEOUT)
    if result.returncode != 0:
        hint = "" if Path("/usr/include/fastdds").is_dir() else \
            f" (no Fast DDS headers: scripts/setup installs the Debian packages {PACKAGES})"
        pytest.fail(f"building the Fast DDS test peer failed{hint}:\n{result.stdout}{result.stderr[-4000:]}",
                    pytrace=False)
    elapsed = time.monotonic() - started
    if elapsed > 1:
        print(f"built the Fast DDS peers in {BUILD.relative_to(ROOT)} in {elapsed:.1f} s")
    return PROGRAM


def shape_peer() -> Path:
    """The Fast DDS shape application (tests/fastdds/shape_peer.cpp), built if needed."""
    build()
    return SHAPE_PROGRAM


class FastDdsPeer:
    """One running fastdds_peer process (started through the tests' ``apps`` runner, stopped with the test)."""

    def __init__(self, process: Any):
        self.process = process

    @classmethod
    def read(cls, apps: Any, topics: list[str], domain_id: int, count: int = 0, qos: str = "default",
             data: bool = False, name: str = "fastdds-reader", participants: int | None = None,
             defaults: bool = False, prefix: Sequence[str] = ()) -> FastDdsPeer:
        """A reader per topic; ``participants``: participant indexes probed on 127.0.0.1 (None: Fast DDS's
        default, four); ``defaults``: Fast DDS's default participant, run through ``prefix`` (see the module)."""
        command = [str(build()), "read", *topics, "--domain", str(domain_id), "--count", str(count), "--qos", qos]
        command += (["--data"] if data else []) + _range(participants)
        return cls(apps.start_command(name, _transports(command, participants, defaults, prefix)))

    @classmethod
    def write_circle(cls, apps: Any, domain_id: int, color: str, x: int, y: int, size: int,
                     participants: int | None = None, defaults: bool = False, prefix: Sequence[str] = (),
                     name: str = "fastdds-writer") -> FastDdsPeer:
        """A Shapes Demo circle written every 100 ms; ``participants``, ``defaults`` and ``prefix`` as for
        :meth:`read`."""
        command = [str(build()), "write", "Circle", "--domain", str(domain_id), "--color", color,
                   "--x", str(x), "--y", str(y), "--size", str(size)] + _range(participants)
        return cls(apps.start_command(name, _transports(command, participants, defaults, prefix)))

    @classmethod
    def hostile(cls, apps: Any, topic: str, kind: str, domain_id: int, count: int = 0, period_ms: int = 20
                ) -> FastDdsPeer:
        """Once a reader matched, samples of one hostile kind on ``topic`` every ``period_ms`` (``count`` of them; 0:
        until stopped), see fastdds_peer.cpp: enum, nan, inf, bad-ns, many, empty, huge, zero, negative, far,
        mismatch, noxyz, short, long. A reader that matched may not know the writer yet (discovery is not symmetric):
        wait for what the application reports, not for the peer's writes."""
        command = [str(build()), "hostile", topic, "--kind", kind, "--domain", str(domain_id), "--count", str(count),
                   "--period-ms", str(period_ms)]
        return cls(apps.start_command(f"fastdds-hostile-{kind}", command))

    def wait_written(self, timeout: float = 60.0) -> None:
        """Wait until a hostile writer wrote all its samples."""
        self.process.wait_for(r"^hostile: \d+ written$", timeout)

    def wait_matched(self, topic: str, what: str = "writer", timeout: float = 60.0) -> None:
        self.process.wait_for(rf"^matched: [1-9]\d* {what}\(s\) on {re.escape(topic)}$", timeout)

    def samples(self, topic: str) -> list[dict[str, Any]]:
        """Every sample of ``topic`` printed so far, in arrival order."""
        lines = [json.loads(line) for line in list(self.process.lines) if line.startswith("{")]
        return [line["sample"] for line in lines if line["topic"] == topic]

    def wait_samples(self, topic: str, count: int, timeout: float = 60.0) -> list[dict[str, Any]]:
        self.process.wait_for(rf'^\{{"topic": "{re.escape(topic)}"', timeout, count)
        return self.samples(topic)[:count]

    @property
    def output(self) -> str:
        return str(self.process.output)

    def stop(self) -> int:
        return int(self.process.stop())


def _range(participants: int | None) -> list[str]:
    return [] if participants is None else ["--participants", str(participants)]


def _transports(command: list[str], participants: int | None, defaults: bool, prefix: Sequence[str]) -> list[str]:
    """The command line run through ``prefix``: on loopback, or with ``--defaults`` (only with a prefix: Fast DDS's
    defaults multicast on every interface, which must be a test namespace's)."""
    if not defaults:
        return [*prefix, *command]
    if not prefix:
        raise ValueError("a Fast DDS peer on Fast DDS's defaults multicasts on every interface: run it inside a "
                         "test's network namespace (give prefix)")
    if participants is not None:
        raise ValueError("participants: the Fast DDS peer on its defaults probes Fast DDS's default range")
    return [*prefix, *command, "--defaults"]


def private_shm(namespace: Any, folder: Path) -> list[str]:
    """The prefix that runs a command inside ``namespace`` (an automotive.tools.support.netlab.Namespace) with
    ``folder`` as its /dev/shm: Fast DDS's shared memory transport (on by default) then meets only the peers given the
    same folder, never a Fast DDS participant of another test or of the host, and leaves nothing in the host's /dev/shm.
    (``ip netns exec`` runs each command in a mount namespace of its own: the bind mount is that command's alone.)"""
    folder.mkdir(parents=True, exist_ok=True)
    return namespace.exec("sh", "-c", 'mount --bind "$0" /dev/shm && exec "$@"', str(folder))


def octets(value: dict[str, Any]) -> bytes:
    """The bytes of an octet array or sequence read with data=True."""
    data = base64.b64decode(value["base64"])
    assert len(data) == value["size"]
    return data
