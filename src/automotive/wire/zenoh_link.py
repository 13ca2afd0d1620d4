"""The Zenoh side of the site bridge (automotive.tools.zenoh.zenoh_bridge): the session's configuration, key
expressions, what travels with each sample, and Zenoh's own log turned into one-line reports.

- **Configuration.** Built from the bridge's properties, never from Zenoh's defaults where they send anything
  anywhere: multicast scouting and gossip off (Zenoh scouts UDP multicast 224.0.0.224:7446 by default in peer and
  router mode), shared memory off (two bridges on one host would otherwise move samples through /dev/shm, past the
  link), listen endpoints always explicit (a router listens on tcp/[::]:7447 by default). Endpoints are ``tls/``
  (mutual TLS: the CA, this site's certificate and key) or, only when ``zenoh.allowPlainTcp=true`` says so, ``tcp/``.
- **Key expressions** follow Zenoh's DDS bridges (zenoh-bridge-dds, zenoh-bridge-ros2dds): the DDS topic name is the
  key, after an optional scope: topic ``rt/LidarTopic`` with scope ``automotive`` is ``automotive/rt/LidarTopic``.
  A site's live writers of a topic are a liveliness token ``<scope>/@dds_writers/<site>/<zenoh id>/<topic>/<type>``
  (the bridge's Zenoh id), with the topic's and type's ``/`` written ``§`` (as zenoh-bridge-ros2dds does in its
  liveliness tokens).
- **Envelope.** Each sample's payload is its CDR bytes unchanged; a Zenoh attachment carries what DDS says about it:
  data, disposal or unregistration, the writer's source timestamp, the sending bridge's sequence number for the
  topic, the site it comes from and the type name.
"""

from __future__ import annotations

import json
import os
import re
import struct
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import zenoh

from automotive.bus.badsamples import RateLimitedLines
from automotive.bus.errors import ConfigError
from automotive.bus.properties import Properties
from automotive.wire.rawsample import SampleKind

MODES = ("router", "peer")
SITE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]*$")
ENDPOINT = re.compile(r"^(tls|tcp)/(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+):(\d{1,5})$")
LIVELINESS_CHUNK = "@dds_writers"
SLASH_ESCAPE = "§"
CERTIFICATE_HINT = "make them with automotive zenoh-certs (docs/zenoh.md)"
# Reconnection: first retry after 250 ms, then at most every second (Zenoh's default backs off to 4 s).
RETRY_FIRST_MS, RETRY_MAX_MS = 250, 1000


@dataclass(frozen=True)
class LinkSettings:
    """Where and how this site's bridge meets the others."""

    site: str
    scope: str = ""
    mode: str = "peer"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    ca: Path | None = None
    certificate: Path | None = None
    key: Path | None = None
    allow_plain_tcp: bool = False
    lease_s: float = 3.0
    source: str = "zenoh"

    @classmethod
    def from_properties(cls, props: Properties) -> LinkSettings:
        site = props.get_str("zenoh.site")
        if not SITE_NAME.match(site) or len(site) > 64:
            raise ConfigError(f"{props.where('zenoh.site')}: zenoh.site = '{site}' is not a site name "
                              "(up to 64 letters, digits, '_' and '-')")
        scope = props.get_str("zenoh.scope", "").strip("/")
        mode = props.get_choice("zenoh.mode", MODES, "peer")
        listen = tuple(props.get_list("zenoh.listen", []))
        connect = tuple(props.get_list("zenoh.connect", []))
        ca = props.get_path("zenoh.tls.ca") if props.get_str("zenoh.tls.ca", "") else None
        certificate = props.get_path("zenoh.tls.certificate") if props.get_str("zenoh.tls.certificate", "") else None
        key = props.get_path("zenoh.tls.key") if props.get_str("zenoh.tls.key", "") else None
        settings = cls(site, scope, mode, listen, connect, ca, certificate, key,
                       props.get_bool("zenoh.allowPlainTcp", False),
                       props.get_float("zenoh.lease", 3.0, minimum=0.5, maximum=3600), props.source)
        settings.check()
        return settings

    @property
    def uses_tls(self) -> bool:
        return any(endpoint.startswith("tls/") for endpoint in self.listen + self.connect)

    def check(self) -> None:
        """Every endpoint well formed, plain TCP only when allowed, the certificates present for TLS."""
        if not self.listen and not self.connect:
            raise ConfigError(f"{self.source}: neither zenoh.listen nor zenoh.connect names an endpoint "
                              "(e.g. zenoh.listen=tls/10.0.0.2:7447 on one site, zenoh.connect=tls/10.0.0.2:7447 "
                              "on the other)")
        if self.scope:
            _check_key(self.scope, f"{self.source}: zenoh.scope = '{self.scope}'")
        for key, endpoints in (("zenoh.listen", self.listen), ("zenoh.connect", self.connect)):
            for endpoint in endpoints:
                match = ENDPOINT.match(endpoint)
                if match is None or not 0 < int(match.group(3)) <= 65535:
                    raise ConfigError(f"{self.source}: {key}: '{endpoint}' is not an endpoint of the form "
                                      "tls/HOST:PORT (or tcp/HOST:PORT with zenoh.allowPlainTcp=true)")
                if match.group(1) == "tcp" and not self.allow_plain_tcp:
                    raise ConfigError(f"{self.source}: {key}: '{endpoint}' is plain TCP (no authentication, no "
                                      "encryption); use tls/... or set zenoh.allowPlainTcp=true to accept it")
        if self.uses_tls:
            for key, path in (("zenoh.tls.ca", self.ca), ("zenoh.tls.certificate", self.certificate),
                              ("zenoh.tls.key", self.key)):
                if path is None:
                    raise ConfigError(f"{self.source}: {key} is not set, and tls/ endpoints need it "
                                      f"({CERTIFICATE_HINT})")
                if not path.is_file():
                    raise ConfigError(f"{self.source}: {key} = {path}: no such file ({CERTIFICATE_HINT})")

    def describe(self) -> str:
        parts = [f"site {self.site}", f"Zenoh {self.mode}"]
        if self.listen:
            parts.append(f"listening on {', '.join(self.listen)}")
        if self.connect:
            parts.append(f"connecting to {', '.join(self.connect)}")
        parts.append("mutual TLS" if self.uses_tls else "PLAIN TCP (no authentication)")
        parts.append(f"scope '{self.scope}'" if self.scope else "no scope")
        return ", ".join(parts)


def zenoh_config(settings: LinkSettings) -> zenoh.Config:
    """The session's configuration: only what the settings say, nothing found or announced by multicast."""
    values: dict[str, Any] = {
        "mode": settings.mode,
        "listen/endpoints": list(settings.listen),
        "listen/exit_on_failure": True,  # a listen address that cannot be used ends the start with one line
        "connect/endpoints": list(settings.connect),
        "connect/exit_on_failure": False,  # the other site may come later: keep trying
        "connect/timeout_ms": -1,
        "connect/retry": {"period_init_ms": RETRY_FIRST_MS, "period_max_ms": RETRY_MAX_MS,
                          "period_increase_factor": 2},
        "scouting/multicast/enabled": False,
        "scouting/multicast/listen": False,
        "scouting/gossip/enabled": False,
        "transport/shared_memory/enabled": False,
        "transport/link/tx/lease": int(settings.lease_s * 1000),
        "adminspace/enabled": False,
        # Publication caches (the alerts' late-joiner state) order samples by timestamp; a sample stamped ahead of
        # this host's clock (another site's clock) is still accepted.
        "timestamping/enabled": True,
        "timestamping/drop_future_timestamp": False,
    }
    if settings.uses_tls:
        assert settings.ca and settings.certificate and settings.key  # check() made sure
        values["transport/link/tls"] = {
            "root_ca_certificate": str(settings.ca),
            "listen_private_key": str(settings.key), "listen_certificate": str(settings.certificate),
            "connect_private_key": str(settings.key), "connect_certificate": str(settings.certificate),
            "enable_mtls": True, "verify_name_on_connect": True, "close_link_on_expiration": True,
        }
    config = zenoh.Config()
    for key, value in values.items():
        config.insert_json5(key, json.dumps(value))
    return config


# -- key expressions -------------------------------------------------------------------------------------------

def _check_key(key: str, what: str) -> None:
    try:
        zenoh.KeyExpr(key)
    except zenoh.ZError as error:
        raise ConfigError(f"{what} is not a valid Zenoh key expression ({error})") from None


def data_key(scope: str, topic: str) -> str:
    """The key expression of a topic's samples: the topic name, after the scope if there is one."""
    key = f"{scope}/{topic}" if scope else topic
    _check_key(key, f"topic '{topic}' (key '{key}')")
    return key


def _escape(text: str) -> str:
    return text.replace("/", SLASH_ESCAPE)


def _unescape(text: str) -> str:
    return text.replace(SLASH_ESCAPE, "/")


def writers_prefix(scope: str) -> str:
    return f"{scope}/{LIVELINESS_CHUNK}" if scope else LIVELINESS_CHUNK


def writers_key(scope: str, site: str, zid: str, topic: str, type_name: str) -> str:
    """The liveliness token of a site's live writers of a topic, held by the bridge with Zenoh id ``zid``."""
    return f"{writers_prefix(scope)}/{site}/{zid}/{_escape(topic)}/{_escape(type_name)}"


@dataclass(frozen=True)
class WritersToken:
    site: str
    zid: str
    topic: str
    type_name: str


def parse_writers_key(scope: str, key: str) -> WritersToken | None:
    prefix = writers_prefix(scope) + "/"
    if not key.startswith(prefix):
        return None
    parts = key[len(prefix):].split("/")
    if len(parts) != 4:
        return None
    return WritersToken(parts[0], parts[1], _unescape(parts[2]), _unescape(parts[3]))


# -- the envelope of a sample --------------------------------------------------------------------------------

_MAGIC = b"AZB1"
_HEAD = struct.Struct("!4sBqQ")  # magic, kind, source timestamp (ns), sequence number
_KINDS = {SampleKind.DATA: 0, SampleKind.DISPOSE: 1, SampleKind.UNREGISTER: 2}
_KIND_OF = {code: kind for kind, code in _KINDS.items()}


class EnvelopeError(ValueError):
    """An attachment that is not one of ours."""


@dataclass(frozen=True)
class Envelope:
    kind: SampleKind
    source_timestamp: int
    sequence: int
    site: str
    type_name: str

    def encode(self) -> bytes:
        site, type_name = self.site.encode(), self.type_name.encode()
        return (_HEAD.pack(_MAGIC, _KINDS[self.kind], self.source_timestamp, self.sequence)
                + bytes([len(site)]) + site + bytes([len(type_name)]) + type_name)

    @classmethod
    def decode(cls, data: bytes) -> Envelope:
        if len(data) < _HEAD.size + 2 or not data.startswith(_MAGIC):
            raise EnvelopeError("not a bridge envelope (wrong size or magic)")
        _, kind, stamp, sequence = _HEAD.unpack_from(data)
        if kind not in _KIND_OF:
            raise EnvelopeError(f"unknown sample kind {kind}")
        offset = _HEAD.size
        texts = []
        for _ in range(2):
            if offset >= len(data):
                raise EnvelopeError("truncated")
            length = data[offset]
            text = data[offset + 1:offset + 1 + length]
            if len(text) != length:
                raise EnvelopeError("truncated")
            try:
                texts.append(text.decode())
            except UnicodeDecodeError:
                raise EnvelopeError("a name is not UTF-8") from None
            offset += 1 + length
        return cls(_KIND_OF[kind], stamp, sequence, texts[0], texts[1])


# -- Zenoh's own log -----------------------------------------------------------------------------------------

# Zenoh (Rust) logs to the process's standard output; these are the lines worth one line of ours. The rest of its
# warnings and errors are passed on as they are, prefixed "zenoh:"; these two are expected with our configuration.
_EXPECTED = ("Gossip is disabled", "Scouting delay elapsed")
_LOG_LINE = re.compile(r"^\S+\s+(?P<level>TRACE|DEBUG|INFO|WARN|ERROR)\s+(?:.*?\s)?(?P<target>[\w:]+): "
                       r"(?P<message>.*)$")
_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_SOURCE_AT = re.compile(r" at /\S+\.rs:\d+\.?")
# The listener's side of a refused handshake: the other side's certificate is not signed by our CA, it sent none,
# or it refused ours.
_REFUSED_HERE = re.compile(r"(invalid peer certificate: \w+|peer sent no certificates|"
                           r"received fatal alert: \w+)")
# The connecting side: "Unable to connect to configured peer tls/10.0.0.2:7447! <reason>. Retry in 1s."
_CANNOT_CONNECT = re.compile(r"Unable to connect to configured peer (?P<endpoint>\S+?)! "
                             r"(?P<reason>.*?)(\. Retry in .*)?$")
# A reliable (blocking) sample that could not go for transport/link/tx/queue/congestion_control/block/
# wait_before_close (5 s): Zenoh closes the transport.
_STALLED = re.compile(r"Unable to push non droppable network message to (?P<zid>\w+)")
LOG_DIRECTIVES = "warn,zenoh::net::runtime::orchestrator=debug"
REPEAT_REPORT_S = 30.0


def explain_refusal(reason: str) -> str:
    if "invalid peer certificate" in reason:
        detail = reason.split(":", 1)[1].strip()
        return f"the other side's certificate is not signed by this site's CA ({detail})"
    if "no certificates" in reason:
        return "the other side presented no certificate"
    return f"the other side refused this site's certificate ({reason})"


def without_source_location(text: str) -> str:
    """Zenoh's message without the Rust source locations it appends (" at /root/.cargo/.../unicast.rs:426.")."""
    return _SOURCE_AT.sub("", text).strip()


@dataclass
class ZenohLog:
    """Zenoh's log, read from the standard output it writes to, turned into our lines.

    Zenoh writes its log (Rust's tracing) to file descriptor 1. The bridge's own output moves to a copy of the real
    standard output; descriptor 1 becomes a pipe that a thread reads: a refused TLS handshake becomes one line,
    a failing connection one line per endpoint and reason; repeats are counted and said at most every 30 s
    (automotive.bus.badsamples.RateLimitedLines, as the runtime does with Cyclone's repeated lines).
    """

    report: Callable[[str], None]
    refused: int = 0
    _once: RateLimitedLines = field(init=False)
    _saved_fd: int = -1
    _thread: threading.Thread | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def __post_init__(self) -> None:
        self._once = RateLimitedLines(self.report, REPEAT_REPORT_S)

    def start(self, streams: list[Any]) -> IO[str]:
        """Redirect descriptor 1 to the reader; returns the stream that now reaches the real standard output, which
        ``streams`` (logging handlers) are switched to."""
        sys.stdout.flush()
        self._saved_fd = os.dup(1)
        read_fd, write_fd = os.pipe()
        os.dup2(write_fd, 1)
        os.close(write_fd)
        real = os.fdopen(os.dup(self._saved_fd), "w", buffering=1, encoding="utf-8")
        sys.stdout = real
        for handler in streams:
            handler.setStream(real)
        self._thread = threading.Thread(target=self._read, args=(read_fd,), name="zenoh-log", daemon=True)
        self._thread.start()
        zenoh.init_log_from_env_or(LOG_DIRECTIVES)
        return real

    def stop(self) -> None:
        if self._saved_fd >= 0:
            os.dup2(self._saved_fd, 1)  # the pipe's last writer closes: the thread reads to its end
            os.close(self._saved_fd)
            self._saved_fd = -1
        if self._thread is not None:
            self._thread.join(timeout=2)
        self._once.close()  # what is still counted is said now

    def _read(self, read_fd: int) -> None:
        with os.fdopen(read_fd, "r", encoding="utf-8", errors="replace") as pipe:
            for line in pipe:
                self.handle(line)

    def handle(self, raw: str) -> None:
        """One line of Zenoh's log."""
        line = _ANSI.sub("", raw).strip()
        match = _LOG_LINE.match(line)
        if match is None:
            if line:
                self.report(f"zenoh: {line}")
            return
        level, message = match["level"], without_source_location(match["message"])
        message = message.replace(" Hint: increase the system open file limit.", "")
        connect = _CANNOT_CONNECT.search(message)
        if connect is not None:
            reason = connect["reason"].strip().rstrip(".")
            certificate = re.search(r"invalid peer certificate: \w+|received fatal alert: \w+", reason)
            if certificate is not None:
                reason = explain_refusal(certificate.group(0))
            self._once.add(("connect", connect["endpoint"], reason),
                           f"link: cannot connect to {connect['endpoint']}: {reason}; retrying",
                           reason, f"cannot connect to {connect['endpoint']}", "link: ")
            return
        refused = _REFUSED_HERE.search(message) if "tls" in match["target"] else None
        if refused is not None:
            with self._lock:
                self.refused += 1
            explained = explain_refusal(refused.group(0))
            self._once.add(("refused", refused.group(0)), f"link: refused a TLS handshake: {explained}", explained,
                           "TLS handshakes refused", "link: ")
            return
        stalled = _STALLED.search(message)
        if stalled is not None:
            self.report(f"link: the link to {stalled['zid']} stalled (a reliable sample waited too long to go): "
                        "Zenoh closes it")
            return
        if level in ("WARN", "ERROR") and not any(text in message for text in _EXPECTED):
            self.report(f"zenoh: {level.lower()}: {message}")
