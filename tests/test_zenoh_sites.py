"""Two sites joined only by the Zenoh bridge, over a shaped link between network namespaces
(automotive.tools.zenoh.zenoh_bridge).

Site A (namespace za-*) runs vision, lidar, sensor_fusion and vehicle_platform; site B (zb-*) collision_avoidance and
the HMI. Each site's DDS stays on its namespace's loopback; the only path between them is a veth pair that carries
the bridges' mutual-TLS Zenoh link, shaped to 25 ms delay and 0.5 % loss each way (50 ms round trip, about 1 % of
round trips hit) and 20 Mbit/s: with tc netem where the kernel has it; otherwise (this project's machines: no netem
in the kernel) the rate with tc tbf, the loss with nftables and the delay with a relay in B that holds every byte
25 ms each way (automotive.tools.support.delay_relay; B's bridge connects through it). A third namespace (zc-*, its own
veth pair to A) holds a site whose certificate the CA did not sign. Needs root (ip netns); skipped otherwise. Namespaces
carry the test process's pid and a counter in their names and are always deleted; every process is stopped before.
"""

from __future__ import annotations

import itertools
import os
import re
import signal
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from apprunner import AppRunner, CommandProcess

from automotive.bus import stats
from automotive.tools.support import netlab
from automotive.tools.support.children import program_command

ROOT = Path(__file__).resolve().parent.parent
ADDRESS_A, ADDRESS_B = "10.234.0.1", "10.234.0.2"  # the A-B link: private addresses, only inside the namespaces
ADDRESS_A_FOR_C, ADDRESS_C = "10.234.1.1", "10.234.1.2"  # the A-C link
PORT = 7447
# Each end of the A-B link: 25 ms delay, 0.5 % loss, 20 Mbit/s (so 50 ms round trip, 20 Mbit/s each way).
DELAY_MS, LOSS_PER_MILLE, RATE = 25, 5, "20mbit"
RELAY_PORT = 17447  # the delaying relay in B (kernels without netem), on B's loopback
# A killed bridge, restarted at once, carries the flows again within this many seconds of its restart (README,
# docs/zenoh.md): a Python process starting on a busy machine, the TLS handshake, then DDS discovery.
RECOVERY_BOUND_S = 20.0
START_TIMEOUT = 90.0  # a dozen Python processes starting on a busy 2-core machine
# collision avoidance's line for each command it writes (its status line names the last command too: not that one)
COMMAND_WRITTEN = r"collision_avoidance debug: command \d+: "
_names = itertools.count()


@dataclass
class Site:
    name: str
    namespace_name: str
    certificate: Path
    key: Path
    ca: Path
    namespace: netlab.Namespace | None = None

    @property
    def net(self) -> netlab.Namespace:
        assert self.namespace is not None, f"{self.name}: namespace not made yet"
        return self.namespace


@dataclass
class Sites:
    a: Site
    b: Site
    c: Site
    runner: AppRunner
    domain_id: int
    folder: Path
    bridges: int = 0
    stats: dict[str, Path] = field(default_factory=dict)
    b_connects_to: str = f"{ADDRESS_A}:{PORT}"  # A's router, or the delaying relay in front of it

    def start(self, site: Site, label: str, command: list[str]) -> CommandProcess:
        # The shipped single-host default inside the site's namespace (not the tests' CYCLONEDDS_URI, made for the
        # machine's own interfaces): DDS never crosses the veth, so the bridges are the only way between the sites.
        return self.runner.start_command(f"{label}@{site.name}", site.net.exec("env", "-u", "CYCLONEDDS_URI", *command))

    def app(self, site: Site, name: str, *args: str) -> CommandProcess:
        """An application on a site's databus (the single-host default inside the namespace)."""
        return self.start(site, name, program_command(name, "--domain", str(self.domain_id), *args))

    def bridge(self, site: Site, *args: str) -> CommandProcess:
        if site is self.a:
            link = ["-D", "zenoh.mode=router", "-D",
                    f"zenoh.listen=tls/{ADDRESS_A}:{PORT},tls/{ADDRESS_A_FOR_C}:{PORT}", "-D", "zenoh.connect="]
        else:
            target = self.b_connects_to if site is self.b else f"{ADDRESS_A_FOR_C}:{PORT}"
            link = ["-D", "zenoh.mode=peer", "-D", "zenoh.listen=", "-D", f"zenoh.connect=tls/{target}"]
        self.bridges += 1
        stats_file = self.folder / f"stats-{site.name}-{self.bridges}.jsonl"
        self.stats[site.name] = stats_file
        return self.app(site, "zenoh_bridge", "-D", f"zenoh.site={site.name}", *link,
                        "-D", f"zenoh.tls.ca={site.ca}", "-D", f"zenoh.tls.certificate={site.certificate}",
                        "-D", f"zenoh.tls.key={site.key}", "--stats", str(stats_file), *args)

    def last_stats(self, site: Site) -> dict[str, Any]:
        return last_json_line(self.stats[site.name])

    def shape(self) -> None:
        """25 ms and 0.5 % loss each way, 20 Mbit/s, on the A-B link (netem, or tbf + nftables + a relay)."""
        if netlab.shape(self.ab_ends, DELAY_MS, LOSS_PER_MILLE, RATE):
            return
        relay = self.start(self.b, "delay_relay", program_command("delay_relay", "--listen", f"127.0.0.1:{RELAY_PORT}",
                                                                  "--target", f"{ADDRESS_A}:{PORT}",
                                                                  "--delay-ms", str(DELAY_MS)))
        relay.wait_for(r"^relay ready$")
        self.b_connects_to = f"127.0.0.1:{RELAY_PORT}"

    def cut(self) -> None:
        """The A-B link carries nothing (every packet dropped as it arrives, both ways)."""
        netlab.cut(self.ab_ends)

    def mend(self) -> None:
        netlab.mend(self.ab_ends)

    @property
    def ab_ends(self) -> list[tuple[netlab.Namespace, str]]:
        return [(self.a.net, "veth-ab"), (self.b.net, "veth-ba")]


def last_json_line(path: Path) -> dict[str, Any]:
    """The last complete status record of a bridge's --stats file (the bridge may be writing the next one)."""
    records = list(stats.read(path, "status"))
    assert records, f"{path}: no status record yet"
    return records[-1]


def make_certificates(folder: Path) -> None:
    for args in ([str(folder / "ca"), f"site-a={ADDRESS_A},{ADDRESS_A_FOR_C},127.0.0.1", f"site-b={ADDRESS_B}"],
                 [str(folder / "rogue"), f"site-c={ADDRESS_C}"]):
        result = subprocess.run(program_command("zenoh_certs", *args), capture_output=True, text=True, timeout=60)
        assert result.returncode == 0, result.stderr


@pytest.fixture
def sites(domain_id: int, tmp_path: Path) -> Iterator[Sites]:
    reason = netlab.unavailable()
    if reason is not None:
        pytest.skip(reason)
    make_certificates(tmp_path)
    suffix = f"{os.getpid()}-{next(_names)}"
    trusted, rogue = tmp_path / "ca", tmp_path / "rogue"
    a = Site("site-a", f"za-{suffix}", trusted / "site-a.pem", trusted / "site-a.key", trusted / "ca.pem")
    b = Site("site-b", f"zb-{suffix}", trusted / "site-b.pem", trusted / "site-b.key", trusted / "ca.pem")
    # Site C trusts the real CA (its certificate is public), but its own certificate is signed by another CA.
    c = Site("site-c", f"zc-{suffix}", rogue / "site-c.pem", rogue / "site-c.key", trusted / "ca.pem")
    runner = AppRunner(ROOT)
    try:
        for site in (a, b, c):
            site.namespace = netlab.Namespace(site.namespace_name)
        # Created straight into the namespaces: nothing of the links ever appears on the real host.
        netlab.veth(a.net, "veth-ab", ADDRESS_A, b.net, "veth-ba", ADDRESS_B)
        netlab.veth(a.net, "veth-ac", ADDRESS_A_FOR_C, c.net, "veth-ca", ADDRESS_C)
        yield Sites(a, b, c, runner, domain_id, tmp_path)
    finally:
        runner.stop_all()
        for site in (a, b, c):
            if site.namespace is not None:
                site.namespace.delete()


def start_system(sites: Sites) -> dict[str, CommandProcess]:
    a, b = sites.a, sites.b
    processes = {
        "bridge_a": sites.bridge(a),
        "bridge_b": sites.bridge(b),
        "platform": sites.app(a, "vehicle_platform"),
        "fusion": sites.app(a, "sensor_fusion"),
        "vision": sites.app(a, "vision"),
        "lidar": sites.app(a, "lidar"),
        # every car is taller than 1 m: collision avoidance keeps the driver-attention alert up
        "avoidance": sites.app(b, "collision_avoidance", "-D", "config.alertSize=1.0"),
        "hmi_b": sites.app(b, "hmi", "--ui", "console"),
    }
    processes["hmi_b"].wait_for(r"DRIVER ALERT: Driver attention required", timeout=START_TIMEOUT)
    processes["platform"].wait_for(r"command \d+ stamped", timeout=START_TIMEOUT)  # B's command executed on A
    return processes


def test_two_sites_over_a_shaped_link(sites: Sites) -> None:
    a, b, c = sites.a, sites.b, sites.c
    sites.shape()
    processes = start_system(sites)
    bridge_a, bridge_b, platform = processes["bridge_a"], processes["bridge_b"], processes["platform"]
    # The object lists crossed to B, the alert came out of B's HMI, the command came back to A; A's platform status
    # reached B too.
    processes["avoidance"].wait_for(r"command \d+: .*\(\d+ objects, [1-9]\d* status samples read\)", timeout=60)
    bridge_a.wait_for(r"\[AlertTopic\] writers alive on site site-b")
    # Late HMIs: on B, the alert's own site, and on A, across the link (the bridge's writer keeps the state).
    sites.app(b, "hmi", "--ui", "console").wait_for(r"DRIVER ALERT: Driver attention required", timeout=60)
    hmi_a = sites.app(a, "hmi", "--ui", "console")
    hmi_a.wait_for(r"DRIVER ALERT: Driver attention required", timeout=60)

    # A site whose certificate the CA did not sign: refused, in one line, and it gets nothing.
    bridge_c = sites.bridge(c)
    hmi_c = sites.app(c, "hmi", "--ui", "console")
    refused = bridge_a.wait_for(r"link: refused a TLS handshake", timeout=60)
    assert "the other side's certificate is not signed by this site's CA" in refused, refused
    bridge_c.wait_for(r"link: cannot connect to tls/10\.234\.1\.1:7447: the other side refused this site's "
                      r"certificate", timeout=60)
    hmi_c.wait_for(r"waiting for alerts", timeout=60)
    platform.wait_for_more(r"command \d+ stamped", more=30, timeout=60)  # 3 s of commands while C keeps trying
    assert hmi_c.count(r"DRIVER ALERT") == 0, hmi_c.output[-2000:]
    assert bridge_c.count(r"link: connected") == 0 and bridge_c.count(r"from link: \S") == 0, bridge_c.output[-2000:]
    # one line, whatever the number of attempts (repeats are counted in a line at most every 30 s)
    assert bridge_a.count(r"link: refused a TLS handshake(?!.*\(again)") == 1, bridge_a.output[-3000:]
    assert sites.last_stats(a)["refused_handshakes"] >= 1

    # The budget: the LiDAR's 20 Hz reach the link at 2 Hz, the rest counted as dropped.
    lidar = sites.last_stats(a)["topics"]["rt/LidarTopic"]["to_link"]
    assert lidar["sent"] >= 2 and lidar["dropped_budget"] >= 5 * lidar["sent"], lidar
    bridge_a.wait_for(r"to link: .*rt/LidarTopic=\d \(\d+ dropped by the budget\)")
    # No loop: neither bridge took a sample of a bridge's writer, nothing came back to its own site.
    for site in (a, b):
        for topic, counts in sites.last_stats(site)["topics"].items():
            assert counts["to_link"]["from_bridges"] == 0 and counts["from_link"]["own_site"] == 0, (topic, counts)

    # Liveliness across the link: B's alert writer killed, A's HMI reports the source lost; restarted, back.
    processes["avoidance"].stop(signal.SIGKILL)
    bridge_b.wait_for(r"\[AlertTopic\] no live writer on this site any more", timeout=60)
    hmi_a.wait_for(r"alert source LOST", timeout=30)
    sites.app(b, "collision_avoidance", "-D", "config.alertSize=1.0")
    hmi_a.wait_for(r"alert source back", timeout=START_TIMEOUT)
    for process in (bridge_a, bridge_b, bridge_c):
        assert "Traceback" not in process.output, process.output[-3000:]


def test_killed_bridges_recover_and_a_restarted_bridge_gets_the_alert_state(sites: Sites) -> None:
    a, b = sites.a, sites.b
    sites.shape()
    processes = start_system(sites)
    platform = processes["platform"]
    recoveries = {}
    for site, name in ((a, "bridge_a"), (b, "bridge_b")):
        processes[name].stop(signal.SIGKILL)
        restarted = time.time()
        processes[name] = sites.bridge(site)
        # A command written after the restart can only have come through the new bridge.
        stamp = wait_for_command_written_after(platform, restarted, RECOVERY_BOUND_S)
        recoveries[site.name] = round(time.time() - restarted, 2)
        print(f"bridge of {site.name} restarted: a command written {stamp - restarted:.2f} s later reached A "
              f"{recoveries[site.name]:.2f} s after the restart")

    # No new alert is written while fusion is frozen (collision avoidance answers object lists). A bridge of A
    # killed and restarted now can only learn the current alert from B's publication cache: a late HMI on A shows it.
    avoidance = processes["avoidance"]
    with processes["fusion"].frozen():
        answered = avoidance.count(COMMAND_WRITTEN)
        processes["bridge_a"].stop(signal.SIGKILL)
        processes["bridge_a"] = sites.bridge(a)
        hmi_a = sites.app(a, "hmi", "--ui", "console")
        hmi_a.wait_for(r"DRIVER ALERT: Driver attention required", timeout=START_TIMEOUT)
        # nothing new was written (an object list already on its way when fusion froze may still be answered)
        assert avoidance.count(COMMAND_WRITTEN) <= answered + 2, avoidance.output[-2000:]
    wait_for_command_written_after(platform, time.time(), RECOVERY_BOUND_S)


def wait_for_command_written_after(platform: CommandProcess, wall_time: float, timeout: float) -> float:
    """Wait until the vehicle platform executes a command whose source timestamp (collision avoidance's write, same
    host clock) is later than ``wall_time``; return that timestamp."""
    deadline = time.monotonic() + timeout
    seen = 0
    while True:
        lines = list(platform.lines)
        stamps = [float(match.group(1)) for line in lines[seen:]
                  if (match := re.search(r"command \d+ stamped (\d+\.\d+)", line))]
        seen = len(lines)
        later = [stamp for stamp in stamps if stamp > wall_time]
        if later:
            return later[0]
        platform.wait_for_more(r"command \d+ stamped", timeout=max(0.1, deadline - time.monotonic()))


def test_memory_stays_bounded_while_the_link_is_down(sites: Sites) -> None:
    """Camera frames (4 MiB, 10 a second, no budget) keep coming on A while the link carries nothing."""
    a, b = sites.a, sites.b
    queue_mb = 16
    bridge_a = sites.bridge(a, "--topics", "CameraImageData,PlatformControl", "-D", "bridge.maxFrequency=",
                            "-D", f"bridge.queueMB={queue_mb}")
    bridge_b = sites.bridge(b, "--topics", "CameraImageData,PlatformControl")
    camera = sites.app(a, "camera_pub", "-D", "config.pubInterval=100")
    camera.wait_for(r"published \d+ frames", timeout=START_TIMEOUT)
    bridge_b.wait_for(r"from link: CameraImageData=[1-9]", timeout=START_TIMEOUT)
    camera.wait_for_more(r"published \d+ frames", more=3)
    baseline_mb = sites.last_stats(a)["rss_MB"]

    sites.cut()  # the link carries nothing: Zenoh's lease (3 s) ends the session
    bridge_a.wait_for(r"link: peer \S+ disconnected", timeout=30)
    camera.wait_for_more(r"published \d+ frames", more=5)  # 50 frames (200 MB) offered to a link that is down
    bridge_a.wait_for_more(r"to link: .*CameraImageData=0 \(\d+ dropped, queue full\)", timeout=30)
    camera_out = sites.last_stats(a)["topics"]["CameraImageData"]["to_link"]
    frame = 1366 * 768 * 4 + 100
    assert camera_out["subscribed"] is False
    assert camera_out["max_queued_bytes"] <= queue_mb * 1e6, camera_out  # the bound, never more
    assert camera_out["queued_bytes"] >= queue_mb * 1e6 - 2 * frame, camera_out  # ... and it was reached
    assert camera_out["dropped_full"] > 0, camera_out
    rss_mb = sites.last_stats(a)["rss_MB"]
    assert rss_mb < baseline_mb + 150, (baseline_mb, rss_mb)  # generous: the queue holds 16 MB
    print(f"link down: queue {camera_out['queued_bytes'] / 1e6:.1f} MB (bound {queue_mb} MB), "
          f"{camera_out['dropped_full']} frames dropped, RSS {baseline_mb:.0f} -> {rss_mb:.0f} MB")

    # B, which dials, comes back with a new Zenoh id: a transport that A may still be closing (its socket lingers
    # while its 4 MiB frames are unacknowledged) ends by deleting A's transport of B's old id, never the new one.
    renewal = r"a new Zenoh session, id (\S+) \(was (\S+)\)"
    renewed = re.search(renewal, bridge_b.wait_for(renewal, timeout=30))
    assert renewed is not None
    new_id, old_id = renewed.groups()
    assert new_id != old_id
    sites.mend()  # the link is back: B reconnects, frames flow again
    bridge_a.wait_for(rf"link: connected to peer {new_id}", timeout=30)
    try:
        bridge_b.wait_for_more(r"from link: CameraImageData=[1-9]", timeout=60)
    except AssertionError as error:  # the sending side's account too (less its once-a-second lines)
        said = "\n".join(line for line in bridge_a.output.splitlines() if not re.search(r"to link: |status: ", line))
        raise AssertionError(f"{error}\n{bridge_a.name}:\n{said[-6000:]}") from None


def test_a_link_mended_while_the_old_one_still_closes_carries_data_again(sites: Sites) -> None:
    """The link comes back as soon as A has given it up, while A still closes its side of the old one: A's socket
    lingers (up to 10 s) with 4 MiB frames unacknowledged, and Zenoh's close then deletes whatever transport A holds
    for B's Zenoh id. B dials with a new id each time, so the frames flow again, three times over."""
    a, b = sites.a, sites.b
    bridge_a = sites.bridge(a, "--topics", "CameraImageData", "-D", "bridge.maxFrequency=")
    bridge_b = sites.bridge(b, "--topics", "CameraImageData")
    sites.app(a, "camera_pub", "-D", "config.pubInterval=100")
    bridge_b.wait_for(r"from link: CameraImageData=[1-9]", timeout=START_TIMEOUT)
    for _ in range(3):
        b_id = re.findall(r"(?:; Zenoh id|a new Zenoh session, id) (\w+)", bridge_b.output)[-1]
        sites.cut()
        bridge_a.wait_for(rf"link: peer {b_id} disconnected", timeout=30)
        sites.mend()
        # frames in 4 more seconds: a new link that the old one's late close cuts carries them for a second at most
        bridge_b.wait_for_more(r"from link: CameraImageData=[1-9]", more=4, timeout=30)
        renewal = bridge_b.wait_for(rf"a new Zenoh session, id \w+ \(was {b_id}\)", timeout=5)
        new_id = renewal.split("a new Zenoh session, id ")[1].split()[0]
        bridge_a.wait_for(rf"link: connected to peer {new_id}", timeout=5)


def test_two_bridges_on_one_site_make_no_loop(sites: Sites) -> None:
    """Two bridges on site A (to different sites): each writes what it receives onto A's databus, and neither
    sends the other's writes back over the link."""
    a, b = sites.a, sites.b
    bridge_a = sites.bridge(a, "--topics", "VisionTopic")
    stats_a = sites.stats[a.name]
    # A second bridge on A's databus, under another site name, connected to the same router: what A's bridge
    # sends, it receives and writes onto A's databus again.
    second = sites.app(a, "zenoh_bridge", "--topics", "VisionTopic", "-D", "zenoh.site=site-a2", "-D",
                       "zenoh.mode=peer", "-D", "zenoh.listen=", "-D", f"zenoh.connect=tls/{ADDRESS_A}:{PORT}",
                       "-D", f"zenoh.tls.ca={a.ca}", "-D", f"zenoh.tls.certificate={b.certificate}",
                       "-D", f"zenoh.tls.key={b.key}")
    vision = sites.app(a, "vision")
    second.wait_for(r"from link: VisionTopic=[1-9]", timeout=START_TIMEOUT)
    vision.wait_for_more(r"published sample", more=30)
    counts = last_json_line(stats_a)["topics"]["VisionTopic"]["to_link"]
    published = vision.count(r"published sample")
    assert counts["from_bridges"] > 0, counts  # it saw the second bridge's writes ...
    assert counts["sent"] <= published, (counts, published)  # ... and sent only vision's samples
    assert bridge_a.count(r"Traceback") == 0 and second.count(r"Traceback") == 0
