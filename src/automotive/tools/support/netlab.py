"""Private networks for the benchmarks and tests: network namespaces, veth links between them, and link shaping.

Everything made here lives in namespaces that the caller creates and deletes (:class:`Namespace` is a context
manager), so no datagram of a benchmark or test ever reaches the real host's interfaces. A link is shaped with
``tc netem`` where the kernel has it; where it has not (this project's machines), with ``tc tbf`` for the rate and an
nftables ingress rule for the loss, and the caller adds the delay (``python -m automotive.tools.support.delay_relay``
holds every byte of a TCP link for a while): :func:`shape` says which it did. Needs root and iproute2 (+ nftables),
which scripts/setup installs.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import time
from collections.abc import Sequence
from types import TracebackType

COMMAND_TIMEOUT = 30.0


class NetlabError(RuntimeError):
    """A namespace, link or rule that could not be made (the command and its error)."""


def run(*command: str, check: bool = True, stdin: str | None = None) -> subprocess.CompletedProcess[str]:
    """Run a command of iproute2 or nftables; :class:`NetlabError` with its stderr if ``check`` and it failed."""
    result = subprocess.run(list(command), capture_output=True, text=True, input=stdin, timeout=COMMAND_TIMEOUT)
    if check and result.returncode != 0:
        raise NetlabError(f"{' '.join(command)}: {result.stderr.strip()}")
    return result


def unavailable() -> str | None:
    """Why namespaces cannot be made here (for a skip or an error message), or None if they can."""
    if os.geteuid() != 0:
        return "needs root for ip netns"
    if shutil.which("ip") is None:
        return "the ip command (iproute2) is missing"
    probe = f"netlab-probe-{os.getpid()}"
    result = run("ip", "netns", "add", probe, check=False)
    if result.returncode != 0:
        return f"ip netns is not permitted here: {result.stderr.strip()}"
    run("ip", "netns", "del", probe, check=False)
    return None


class Namespace:
    """A network namespace with its loopback up; deleted by :meth:`delete` (or on leaving a ``with`` block)."""

    def __init__(self, name: str):
        self.name = name
        run("ip", "netns", "add", name)
        self.deleted = False
        run("ip", "-n", name, "link", "set", "lo", "up")

    def __enter__(self) -> Namespace:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.delete()

    @property
    def prefix(self) -> list[str]:
        """What runs a command inside: ``ip netns exec <name>``."""
        return ["ip", "netns", "exec", self.name]

    def exec(self, *command: str) -> list[str]:
        return [*self.prefix, *command]

    def pids(self) -> list[int]:
        return [int(pid) for pid in run("ip", "netns", "pids", self.name, check=False).stdout.split()]

    def nft(self, rules: str) -> None:
        """Load an nftables ruleset (``nft -f -``) inside the namespace."""
        run(*self.exec("nft", "-f", "-"), stdin=rules)

    def nft_ingress(self, device: str, table: str, rule: str) -> None:
        """A netdev table ``table`` whose ingress chain on ``device`` applies ``rule`` to every arriving packet."""
        self.nft(f'table netdev {table} {{\n chain ingress {{\n  type filter hook ingress device "{device}" '
                 f"priority 0; policy accept;\n  {rule}\n }}\n}}\n")

    def delete_table(self, family: str, table: str) -> None:
        run(*self.exec("nft", "delete", "table", family, table))

    def link_running(self, device: str) -> bool:
        return "LOWER_UP" in run("ip", "-n", self.name, "link", "show", device, check=False).stdout

    def wait_link_running(self, device: str, timeout: float = 10.0) -> None:
        """Until ``device`` carries packets: no process should start where only loopback is up yet."""
        deadline = time.monotonic() + timeout
        while not self.link_running(device):
            if time.monotonic() > deadline:
                raise NetlabError(f"{device} in {self.name} not running after {timeout:g} s")
            time.sleep(0.05)  # polling the kernel's link state, which nothing announces to us

    def delete(self) -> None:
        if not self.deleted:
            run("ip", "netns", "del", self.name, check=False)
            self.deleted = True


def veth(one: Namespace, one_device: str, one_address: str, other: Namespace, other_device: str,
         other_address: str, prefix_length: int = 24, multicast: bool = False) -> None:
    """A veth pair made straight into two namespaces (nothing of it ever appears on the host), addressed, without
    multicast unless asked, up and running."""
    run("ip", "link", "add", one_device, "netns", one.name, "type", "veth", "peer", "name", other_device, "netns",
        other.name)
    for namespace, device, address in ((one, one_device, one_address), (other, other_device, other_address)):
        run("ip", "-n", namespace.name, "addr", "add", f"{address}/{prefix_length}", "dev", device)
        run("ip", "-n", namespace.name, "link", "set", device, "multicast", "on" if multicast else "off", "up")
    for namespace, device in ((one, one_device), (other, other_device)):
        namespace.wait_link_running(device)


def _qdisc(namespace: Namespace, device: str, *qdisc: str) -> bool:
    return run(*namespace.exec("tc", "qdisc", "replace", "dev", device, "root", *qdisc), check=False).returncode == 0


def shape(ends: Sequence[tuple[Namespace, str]], delay_ms: float, loss_per_mille: int, rate: str) -> bool:
    """Shape every (namespace, device) end: ``rate`` (tc syntax, e.g. ``20mbit``), ``loss_per_mille`` of the arriving
    packets dropped, and ``delay_ms`` each way. True if the kernel's netem did it all; False if it has no netem, so
    that only the rate (tbf) and the loss (nftables) are applied here and the caller must add the delay."""
    netem = ["netem", "delay", f"{delay_ms:g}ms", "loss", f"{loss_per_mille / 10:g}%", "rate", rate]
    if all(_qdisc(namespace, device, *netem) for namespace, device in ends):
        return True
    for namespace, device in ends:
        if not _qdisc(namespace, device, "tbf", "rate", rate, "burst", "64kb", "latency", "400ms"):
            raise NetlabError(f"neither tc netem nor tc tbf works on {device} in {namespace.name}")
        namespace.nft_ingress(device, "netlab_loss", f"numgen random mod 1000 < {loss_per_mille} counter drop")
    return False


def lose(ends: Sequence[tuple[Namespace, str]], percent: int, protocol: str = "udp") -> None:
    """Drop ``percent`` % of the ``protocol`` packets arriving at every end (netem where the kernel has it, else
    nftables); :func:`dropped` counts them."""
    for namespace, device in ends:
        if _qdisc(namespace, device, "netem", "loss", f"{percent}%"):
            continue
        namespace.nft_ingress(device, "netlab_lossy",
                              f"meta l4proto {protocol} numgen random mod 100 < {percent} counter drop")


def dropped(ends: Sequence[tuple[Namespace, str]]) -> int:
    """Packets dropped so far at these ends by :func:`lose` or :func:`shape` (netem statistics, nftables counters)."""
    total = 0
    for namespace, device in ends:
        qdisc = run(*namespace.exec("tc", "-s", "qdisc", "show", "dev", device), check=False).stdout
        if "netem" in qdisc:
            total += sum(int(n) for n in re.findall(r"dropped (\d+)", qdisc))
            continue
        for table in ("netlab_lossy", "netlab_loss"):
            listing = run(*namespace.exec("nft", "list", "table", "netdev", table), check=False).stdout
            total += sum(int(n) for n in re.findall(r"counter packets (\d+)", listing))
    return total


def cut(ends: Sequence[tuple[Namespace, str]]) -> None:
    """The link carries nothing: every packet dropped as it arrives, at every end, until :func:`mend`."""
    for namespace, device in ends:
        namespace.nft_ingress(device, "netlab_cut", "counter drop")


def mend(ends: Sequence[tuple[Namespace, str]]) -> None:
    for namespace, _ in ends:
        namespace.delete_table("netdev", "netlab_cut")

