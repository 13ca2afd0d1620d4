"""The site bridge's parts without a network: its Zenoh configuration (nothing scouted, TLS or plainly allowed TCP),
key expressions, the envelope of a sample, budgets and bounded queues, Zenoh's log turned into our lines, and its
bad input (automotive.wire.zenoh_link, automotive.bus.budget, automotive.tools.zenoh.zenoh_certs and zenoh_bridge). The
bridge between namespaces is in test_zenoh_sites.py."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import pytest
from test_bad_input import assert_one_line_error

from automotive.bus.budget import Budget, SampleQueue
from automotive.bus.errors import ConfigError
from automotive.bus.properties import Properties
from automotive.tools.support.children import program_command
from automotive.wire.rawsample import SampleKind
from automotive.wire.zenoh_link import (
    Envelope,
    EnvelopeError,
    LinkSettings,
    ZenohLog,
    data_key,
    parse_writers_key,
    without_source_location,
    writers_key,
    zenoh_config,
)


@pytest.fixture(scope="module")
def certificates(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("certs")
    result = subprocess.run(program_command("zenoh_certs", str(folder), "site-a=127.0.0.1", "site-b=127.0.0.1"),
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    return folder


def settings_props(certificates: Path, **values: str) -> Properties:
    base = {"zenoh.site": "site-a", "zenoh.listen": "tls/127.0.0.1:7447", "zenoh.tls.ca": str(certificates / "ca.pem"),
            "zenoh.tls.certificate": str(certificates / "site-a.pem"),
            "zenoh.tls.key": str(certificates / "site-a.key")}
    base.update({key.replace("_", "."): value for key, value in values.items()})
    return Properties(base, "test.properties")


def test_certificates_are_v3_with_the_key_usages_rustls_wants(certificates: Path) -> None:
    text = subprocess.run(["openssl", "x509", "-in", str(certificates / "site-a.pem"), "-noout", "-text"],
                          capture_output=True, text=True, check=True).stdout
    assert "Version: 3 (0x2)" in text
    assert "TLS Web Server Authentication, TLS Web Client Authentication" in text
    assert "IP Address:127.0.0.1" in text and "DNS:site-a" in text
    ca = subprocess.run(["openssl", "x509", "-in", str(certificates / "ca.pem"), "-noout", "-text"],
                        capture_output=True, text=True, check=True).stdout
    assert "CA:TRUE" in ca and "Certificate Sign" in ca
    verify = subprocess.run(["openssl", "verify", "-CAfile", str(certificates / "ca.pem"),
                             str(certificates / "site-b.pem")], capture_output=True, text=True)
    assert verify.returncode == 0, verify.stdout + verify.stderr


def test_certificate_script_refuses_a_bad_site_name_in_one_line(tmp_path: Path) -> None:
    result = subprocess.run(program_command("zenoh_certs", str(tmp_path), "site a"),
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "automotive zenoh-certs: site name 'site a': expected letters, digits, '.' and '-'"]


def test_configuration_scouts_nothing_and_uses_mutual_tls(certificates: Path) -> None:
    settings = LinkSettings.from_properties(settings_props(certificates, zenoh_mode="router"))
    config = zenoh_config(settings)

    def value(key: str) -> object:
        return json.loads(config.get_json(key))

    assert value("mode") == "router"
    assert value("scouting/multicast/enabled") is False
    assert value("scouting/gossip/enabled") is False
    assert value("transport/shared_memory/enabled") is False
    assert value("listen/endpoints") == ["tls/127.0.0.1:7447"]  # never the router's default tcp/[::]:7447
    assert value("connect/endpoints") == []
    tls = value("transport/link/tls")
    assert isinstance(tls, dict)
    assert tls["enable_mtls"] is True and tls["verify_name_on_connect"] is True
    assert tls["root_ca_certificate"] == str(certificates / "ca.pem")
    assert tls["connect_certificate"] == tls["listen_certificate"] == str(certificates / "site-a.pem")


def test_plain_tcp_only_when_the_properties_say_so(certificates: Path) -> None:
    with pytest.raises(ConfigError, match=r"zenoh.connect: 'tcp/10.0.0.2:7447' is plain TCP .*"
                                          r"zenoh.allowPlainTcp=true"):
        LinkSettings.from_properties(settings_props(certificates, zenoh_listen="", zenoh_connect="tcp/10.0.0.2:7447"))
    settings = LinkSettings.from_properties(Properties({"zenoh.site": "b", "zenoh.connect": "tcp/10.0.0.2:7447",
                                                        "zenoh.allowPlainTcp": "true"}))
    assert not settings.uses_tls and "PLAIN TCP" in settings.describe()
    assert json.loads(zenoh_config(settings).get_json("transport/link/tls"))["root_ca_certificate"] is None


@pytest.mark.parametrize("values,pattern", [
    ({"zenoh_listen": "udp/127.0.0.1:7447"}, r"'udp/127.0.0.1:7447' is not an endpoint of the form tls/HOST:PORT"),
    ({"zenoh_listen": "tls/127.0.0.1:99999"}, r"not an endpoint"),
    ({"zenoh_listen": ""}, r"neither zenoh.listen nor zenoh.connect"),
    ({"zenoh_site": "site/a"}, r"zenoh.site = 'site/a' is not a site name"),
    ({"zenoh_tls_key": "/nonexistent/site-a.key"}, r"zenoh.tls.key = /nonexistent/site-a.key: no such file "
                                                   r"\(make them with automotive zenoh-certs"),
    ({"zenoh_mode": "client"}, r"zenoh.mode = 'client' is not one of router, peer"),
])
def test_bad_link_settings(certificates: Path, values: dict[str, str], pattern: str) -> None:
    with pytest.raises(ConfigError, match=pattern):
        LinkSettings.from_properties(settings_props(certificates, **values))


def test_key_expressions_follow_zenohs_dds_bridges() -> None:
    assert data_key("", "rt/LidarTopic") == "rt/LidarTopic"
    assert data_key("automotive", "rt/LidarTopic") == "automotive/rt/LidarTopic"
    key = writers_key("automotive", "site-b", "abc123", "rt/LidarTopic", "sensor_msgs::msg::dds_::PointCloud2_")
    assert key == "automotive/@dds_writers/site-b/abc123/rt§LidarTopic/sensor_msgs::msg::dds_::PointCloud2_"
    token = parse_writers_key("automotive", key)
    assert token is not None
    assert (token.site, token.zid, token.topic, token.type_name) == \
        ("site-b", "abc123", "rt/LidarTopic", "sensor_msgs::msg::dds_::PointCloud2_")
    assert parse_writers_key("other", key) is None
    with pytest.raises(ConfigError, match="not a valid Zenoh key expression"):
        data_key("", "bad*topic")


def test_envelope_round_trip_and_garbage() -> None:
    envelope = Envelope(SampleKind.DISPOSE, 1_795_000_000_123_456_789, 42, "site-b", "Vision::VisionSensor")
    assert Envelope.decode(envelope.encode()) == envelope
    for garbage in (b"", b"AZB1", b"XXXX" + envelope.encode()[4:], envelope.encode()[:-3]):
        with pytest.raises(EnvelopeError):
            Envelope.decode(garbage)


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_rate_budget_sends_the_newest_sample_and_counts_the_rest() -> None:
    clock = FakeClock()
    queue: SampleQueue[int] = SampleQueue(64, 10**9, Budget(max_rate=2, clock=clock))
    sent = []
    for number in range(16):  # two seconds of an 8 Hz flow through a 2 Hz budget (steps exact in binary)
        queue.offer(number, 100)
        item = queue.next(0)
        if item is not None:
            sent.append(item)
        clock.now += 0.125
    assert sent == [0, 4, 8, 12]  # one every 0.5 s, each the newest at its turn
    assert queue.counts.dropped_budget == 11 and len(queue) == 1  # 15 is waiting for its turn
    queue.offer(99, 10, state_change=True)  # a disposal is never replaced by the budget
    queue.offer(100, 100)
    assert queue.counts.dropped_budget == 12
    assert queue.next(0) == 99


def test_bandwidth_budget_lets_a_large_sample_through_then_waits_for_the_debt() -> None:
    clock = FakeClock()
    budget = Budget(max_bytes_per_s=1_000_000, clock=clock)
    queue: SampleQueue[str] = SampleQueue(8, 10**9, budget)
    queue.offer("frame 1", 4_000_000)
    assert queue.next(0) == "frame 1"
    queue.offer("frame 2", 4_000_000)
    assert queue.next(0) is None
    assert budget.wait_s() == pytest.approx(3.0)  # 1 MB allowed at once, 3 MB of debt left
    clock.now += 3.0
    assert queue.next(0) == "frame 2"


def test_queue_stays_within_its_bounds_and_counts_what_it_drops() -> None:
    queue: SampleQueue[int] = SampleQueue(max_length=4, max_bytes=1000)
    for number in range(10):
        queue.offer(number, 300)
    assert len(queue) == 3 and queue.bytes == 900  # three fit in 1000 bytes
    assert queue.counts.dropped_full == 7 and queue.counts.max_bytes <= 1000
    assert [queue.next(0) for _ in range(4)] == [7, 8, 9, None]
    for number in range(10):
        queue.offer(number, 1)
    assert len(queue) == 4 and queue.counts.max_length == 4
    big = SampleQueue[int](max_length=4, max_bytes=1000)
    big.offer(1, 5000)  # a sample larger than the bound still passes, alone
    assert len(big) == 1


def zenoh_line(level: str, target: str, message: str) -> str:
    return (f"\x1b[2m2026-11-23T19:56:30.595849Z\x1b[0m \x1b[33m {level}\x1b[0m acc-0 ThreadId(05) "
            f"\x1b[2m{target}\x1b[0m\x1b[2m:\x1b[0m {message}\n")


def test_zenoh_log_lines_become_one_line_reports() -> None:
    said: list[str] = []
    log = ZenohLog(said.append)
    for _ in range(5):  # a refused site retries every second: said once, the repeats counted
        log.handle(zenoh_line("WARN", "zenoh_link_tls::unicast", "invalid peer certificate: BadSignature. "
                                                                   "Hint: increase the system open file limit."))
    log.handle(zenoh_line("DEBUG", "zenoh::net::runtime::orchestrator", "Unable to connect to configured peer "
                          "tls/10.0.0.2:7447! Can not create a new TLS link bound to 10.0.0.2: received fatal "
                          "alert: DecryptError at /root/x/unicast.rs:378.. Retry in 1s."))
    log.handle(zenoh_line("WARN", "zenoh::net::routing::hat::peer", "Gossip is disabled: cannot de-duplicate"))
    log.handle(zenoh_line("ERROR", "zenoh::net::runtime", "something else went wrong"))
    log.handle(zenoh_line("DEBUG", "zenoh::net::runtime::orchestrator", "Try to connect: tls/10.0.0.2:7447"))
    assert said == [
        "link: refused a TLS handshake: the other side's certificate is not signed by this site's CA (BadSignature)",
        "link: cannot connect to tls/10.0.0.2:7447: the other side refused this site's certificate (received fatal "
        "alert: DecryptError); retrying",
        "zenoh: error: something else went wrong",
    ]
    assert log.refused == 5


def test_zenoh_errors_lose_their_rust_source_locations() -> None:
    """How Zenoh 1.9 words a listener it cannot open: the locations go, the reason stays."""
    assert without_source_location(
        "Cannot create a new TLS listener on 127.0.0.1:7447. Missing TLS private key. at /root/.cargo/git/checkouts/"
        "zenoh-9c599d5ef3e0480e/cc83980/io/zenoh-links/zenoh-link-tls/src/utils.rs:532. at /root/.cargo/git/"
        "checkouts/zenoh-9c599d5ef3e0480e/cc83980/io/zenoh-links/zenoh-link-tls/src/unicast.rs:426."
    ) == "Cannot create a new TLS listener on 127.0.0.1:7447. Missing TLS private key."


@pytest.mark.parametrize("args,pattern", [
    (["--topics", "NoSuchTopic"], r"--topics: unknown topic\(s\) NoSuchTopic \(known: VisionTopic, "),
    (["-D", "bridge.maxFrequency=rt/LidarTopic=fast"], r"bridge.maxFrequency: 'fast' \(for rt/LidarTopic\) is not "
                                                       r"a number"),
    (["-D", "bridge.maxMbps=Lidar=3"], r"bridge.maxMbps: unknown topic 'Lidar'"),
    (["-D", "bridge.priority=AlertTopic=urgent"], r"bridge.priority: 'AlertTopic=urgent' is not topic=one of "),
    (["-D", "bridge.deny=VisionTopic", "--topics", "VisionTopic"], r"no topic left to bridge"),
    (["-D", "zenoh.connect=tcp/127.0.0.1:7447", "-D", "zenoh.listen="], r"is plain TCP"),
])
def test_bad_bridge_input(apps, certificates: Path, args: list[str], pattern: str) -> None:  # type: ignore[no-untyped-def]
    tls = ["-D", f"zenoh.tls.ca={certificates}/ca.pem", "-D", f"zenoh.tls.certificate={certificates}/site-a.pem",
           "-D", f"zenoh.tls.key={certificates}/site-a.key"]
    assert_one_line_error(apps.run("zenoh_bridge", *tls, *args), rf"^automotive zenoh-bridge: .*{pattern}")


def test_missing_certificates_are_one_line_with_the_remedy(apps) -> None:  # type: ignore[no-untyped-def]
    result = apps.run("zenoh_bridge", "-D", "zenoh.tls.ca=/nonexistent/ca.pem")
    assert_one_line_error(result, r"^automotive zenoh-bridge: .*zenoh.tls.ca = /nonexistent/ca.pem: no such file "
                                  r"\(make them "
                                  r"with automotive zenoh-certs")


def test_listen_address_in_use_is_one_line(apps, domain_id: int, certificates: Path) -> None:  # type: ignore[no-untyped-def]
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = apps.run("zenoh_bridge", "--domain", str(domain_id), "-D", f"zenoh.listen=tls/127.0.0.1:{port}",
                          "-D", f"zenoh.tls.ca={certificates}/ca.pem",
                          "-D", f"zenoh.tls.certificate={certificates}/site-a.pem",
                          "-D", f"zenoh.tls.key={certificates}/site-a.key")
    assert_one_line_error(result,
                          rf"^automotive zenoh-bridge: .*cannot open the Zenoh link \(.*tls/127.0.0.1:{port}.*\): ")
    assert re.search(r"[Aa]ddress (already )?in use|[Cc]an not create", result.stderr), result.stderr


def test_without_the_fast_paths_the_bridge_runs_and_says_liveliness_is_not_carried(  # type: ignore[no-untyped-def]
        apps, domain_id: int, certificates: Path) -> None:
    """Asserting liveliness needs Cyclone's C call (automotive.cyclone.liveliness, behind the version gate): with the
    gate closed the bridge still carries the flows, and says once what it cannot carry."""
    import socket

    with socket.socket() as probe:  # a port nothing listens on: the bridge keeps retrying, as when a site is down
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    bridge = apps.start("zenoh_bridge", "--domain", str(domain_id), "--topics", "AlertTopic", "-D", "zenoh.mode=peer",
                        "-D", "zenoh.listen=", "-D", f"zenoh.connect=tls/127.0.0.1:{port}",
                        "-D", f"zenoh.tls.ca={certificates}/ca.pem",
                        "-D", f"zenoh.tls.certificate={certificates}/site-a.pem",
                        "-D", f"zenoh.tls.key={certificates}/site-a.key", env={"AUTOMOTIVE_FAST_PATHS": "off"})
    bridge.wait_for(r"bridge of site site-a ready: 1 topic\(s\): AlertTopic", timeout=60)
    assert bridge.count(r"liveliness is not carried across the link: .*AUTOMOTIVE_FAST_PATHS=off") == 1, bridge.output
    assert bridge.stop() == 0, bridge.output
    assert "Traceback" not in bridge.output


@pytest.mark.parametrize("program,args,pattern", [
    ("zenoh_certs", ["certs"], r"^automotive zenoh-certs: the following arguments are required: SITE"),
    ("zenoh_certs", ["certs", "site-a", "--days", "0"], r"^automotive zenoh-certs: --days 0: expected a positive"),
    ("zenoh_certs", ["certs", "site-a=10.0.0.2,bad host"], r"^automotive zenoh-certs: site site-a: 'bad host' is not "
                                                            r"an IP address or host name$"),
    ("delay_relay", ["--listen", "nowhere", "--target", "127.0.0.1:1"],
     r"^python -m automotive.tools.support.delay_relay: argument --listen: 'nowhere' is not HOST:PORT"),
])
def test_the_link_tools_refuse_bad_arguments_in_one_line(tmp_path: Path, program: str, args: list[str],
                                                         pattern: str) -> None:
    result = subprocess.run(program_command(program, *args), cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert_one_line_error(result, pattern)
    assert not (tmp_path / "certs").exists()  # nothing written before every argument was checked
