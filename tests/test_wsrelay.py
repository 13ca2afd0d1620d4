"""automotive.tools.foxglove_bridge.wsrelay on its own, in front of a plain TCP server: the handshake of a client
offering only the old subprotocol name is rewritten both ways, every byte after it passes unchanged in both directions,
an oversized or unfinished request head is dropped, and stop() ends every connection."""

from __future__ import annotations

import contextlib
import hashlib
import logging
import socket
import threading
from collections.abc import Iterator

import pytest

from automotive.tools.foxglove_bridge import wsrelay
from automotive.tools.foxglove_bridge.wsrelay import LEGACY_SUBPROTOCOL, SDK_SUBPROTOCOL, SubprotocolRelay

TIMEOUT = 30.0
PAYLOAD = bytes(range(256)) * (8 * 4096)  # 8 MiB each way: many times the relay's pipes and socket buffers


def send_quietly(sock: socket.socket, data: bytes) -> None:
    """Send, ignoring a connection that the other side ended (what test_stop_ends_open_connections does)."""
    with contextlib.suppress(OSError):
        sock.sendall(data)


class Backend:
    """A stand-in for the SDK server: answers a request head with a 101 naming foxglove.sdk.v1 (plus the first bytes
    of its stream in the same write, as a real server may), then streams PAYLOAD and records what it receives."""

    def __init__(self) -> None:
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.heads: list[bytes] = []
        self.received: list[bytes] = []
        self.thread = threading.Thread(target=self.serve, daemon=True)
        self.thread.start()

    def serve(self) -> None:
        connection, _ = self.listener.accept()
        with connection:
            data = bytearray()
            while b"\r\n\r\n" not in data:
                data += connection.recv(4096)
            head, rest = bytes(data).split(b"\r\n\r\n", 1)
            self.heads.append(head)
            answer = (b"HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: " + SDK_SUBPROTOCOL.encode()
                      + b"\r\n\r\n" + PAYLOAD)
            sender = threading.Thread(target=send_quietly, args=(connection, answer))
            sender.start()
            received = bytearray(rest)
            while chunk := connection.recv(1 << 16):
                received += chunk
            self.received.append(bytes(received))
            sender.join()


@pytest.fixture
def backend() -> Iterator[Backend]:
    server = Backend()
    yield server
    server.listener.close()


@pytest.fixture
def relay(backend: Backend) -> Iterator[SubprotocolRelay]:
    front = SubprotocolRelay("127.0.0.1", 0, backend.port, logging.getLogger("test"))
    yield front
    front.stop()


def receive_all(sock: socket.socket) -> bytes:
    data = bytearray()
    while chunk := sock.recv(1 << 16):
        data += chunk
    return bytes(data)


def test_bytes_pass_unchanged_after_a_rewritten_handshake(backend: Backend, relay: SubprotocolRelay) -> None:
    with socket.create_connection(("127.0.0.1", relay.port), timeout=TIMEOUT) as client:
        request = (b"GET / HTTP/1.1\r\nHost: x\r\nSec-WebSocket-Protocol: " + LEGACY_SUBPROTOCOL.encode()
                   + b"\r\n\r\n")
        sender = threading.Thread(target=lambda: (client.sendall(request + PAYLOAD), client.shutdown(socket.SHUT_WR)))
        sender.start()
        answer = receive_all(client)
        sender.join()
    backend.thread.join(TIMEOUT)
    head, stream = answer.split(b"\r\n\r\n", 1)
    assert head == b"HTTP/1.1 101 Switching Protocols\r\nSec-WebSocket-Protocol: " + LEGACY_SUBPROTOCOL.encode()
    assert hashlib.sha256(stream).digest() == hashlib.sha256(PAYLOAD).digest() and len(stream) == len(PAYLOAD)
    assert backend.heads == [b"GET / HTTP/1.1\r\nSec-WebSocket-Protocol: " + SDK_SUBPROTOCOL.encode() + b"\r\nHost: x"]
    assert [len(data) for data in backend.received] == [len(PAYLOAD)] and backend.received[0] == PAYLOAD


def test_an_oversized_request_head_is_dropped(relay: SubprotocolRelay) -> None:
    with socket.create_connection(("127.0.0.1", relay.port), timeout=TIMEOUT) as client:
        try:
            client.sendall(b"GET / HTTP/1.1\r\n" + b"X: " + b"y" * (wsrelay.MAX_HEAD_BYTES + 1024) + b"\r\n")
        except OSError:
            pass  # the relay may close before it has taken everything
        assert receive_all(client) == b""  # closed without an answer


def test_stop_ends_open_connections(backend: Backend, relay: SubprotocolRelay) -> None:
    with socket.create_connection(("127.0.0.1", relay.port), timeout=TIMEOUT) as client:
        client.sendall(b"GET / HTTP/1.1\r\nSec-WebSocket-Protocol: " + SDK_SUBPROTOCOL.encode() + b"\r\n\r\n")
        assert client.recv(16)  # the backend's answer: the connection is established and streaming
        # The client reads no further: the backend's 8 MiB fill the socket buffers and the relay's pipe.
        stopper = threading.Thread(target=relay.stop)
        stopper.start()
        stopper.join(TIMEOUT)
        assert not stopper.is_alive(), "stop() hung on a connection whose client does not read"
        assert not relay.threads
        with pytest.raises(OSError):
            socket.create_connection(("127.0.0.1", relay.port), timeout=TIMEOUT).close()


def test_a_silent_client_is_dropped_after_the_handshake_timeout(relay: SubprotocolRelay,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(wsrelay, "HANDSHAKE_TIMEOUT_S", 0.2)
    with socket.create_connection(("127.0.0.1", relay.port), timeout=TIMEOUT) as client:
        assert receive_all(client) == b""  # closed by the relay, not by this test's timeout (which would raise)


def test_connections_beyond_the_limit_are_refused(backend: Backend, relay: SubprotocolRelay,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(wsrelay, "MAX_CONNECTIONS", 1)
    with socket.create_connection(("127.0.0.1", relay.port), timeout=TIMEOUT) as first:
        first.sendall(b"GET / HTTP/1.1\r\nSec-WebSocket-Protocol: " + SDK_SUBPROTOCOL.encode() + b"\r\n\r\n")
        assert first.recv(16)  # established
        with socket.create_connection(("127.0.0.1", relay.port), timeout=TIMEOUT) as second:
            assert receive_all(second).startswith(b"HTTP/1.1 503 ")
