"""A TCP front for the Foxglove WebSocket server that also accepts the protocol's older subprotocol name.

foxglove-sdk's server (0.30.3, the newest on PyPI; its sources still hard-code the name) accepts only the WebSocket
subprotocol ``foxglove.sdk.v1`` and answers HTTP 400 to a client that offers only ``foxglove.websocket.v1``, the name
of the same protocol before the SDK (Foxglove says the two are the same protocol today). Clients that still offer only
the old name: the ``@foxglove/ws-protocol`` client by default, Lichtblick before its pull request #819,
roslibjs-foxglove. The SDK has no option for it, so this front listens where users connect, forwards each connection
to the SDK server on a private loopback port and, for a client that offers only the old name, rewrites two handshake
headers: the request's ``Sec-WebSocket-Protocol`` names ``foxglove.sdk.v1``, the 101 answer's names
``foxglove.websocket.v1`` (``Sec-WebSocket-Accept`` depends only on the key, so both stay valid). Everything else, and
everything after the handshake, flows through unchanged.

Written by hand because no library does this: WebSocket proxies terminate and re-frame the protocol, which would copy
every 4 MiB frame through Python. Here the bytes after the handshake move kernel to kernel (``os.splice`` through a
pipe, Linux), so a slow client pushes back on the SDK server as it would directly (whose per-client backlog then
drops the oldest messages) and the front itself holds at most 64 KiB per direction and connection.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import threading
from collections.abc import Callable

SDK_SUBPROTOCOL = "foxglove.sdk.v1"
LEGACY_SUBPROTOCOL = "foxglove.websocket.v1"
MAX_HEAD_BYTES = 16 * 1024  # an HTTP request or response head larger than this is refused
HANDSHAKE_TIMEOUT_S = 10.0  # a client that does not finish its request head in this time is dropped
MAX_CONNECTIONS = 64
PIPE_BYTES = 64 * 1024  # Linux's default pipe capacity: what one direction of a connection holds in the kernel
_PROTOCOL_HEADER = b"sec-websocket-protocol"


def _split_head(head: bytes) -> list[bytes]:
    return head.split(b"\r\n")


def _header_name(line: bytes) -> bytes:
    """A header line's name, lower case; empty for a line that is no header (no colon)."""
    name, colon, _ = line.partition(b":")
    return name.strip().lower() if colon else b""


def rewrite_request(head: bytes) -> tuple[bytes, bool]:
    """An HTTP request head (up to and without the blank line) as the SDK server accepts it, and whether the client
    asked for the legacy name only (its answer must then name the legacy subprotocol)."""
    lines = _split_head(head)
    offered = [token.strip().decode("latin-1") for line in lines[1:] if _header_name(line) == _PROTOCOL_HEADER
               for token in line.split(b":", 1)[1].split(b",")]
    if SDK_SUBPROTOCOL in offered or LEGACY_SUBPROTOCOL not in offered:
        return head, False
    kept = [line for line in lines if _header_name(line) != _PROTOCOL_HEADER]
    kept.insert(1, b"Sec-WebSocket-Protocol: " + SDK_SUBPROTOCOL.encode())
    return b"\r\n".join(kept), True


def rewrite_response(head: bytes) -> bytes:
    """The SDK server's answer head for a legacy client: a 101 answer names the legacy subprotocol."""
    lines = _split_head(head)
    if not lines[0].split(b" ")[1:2] == [b"101"]:
        return head
    return b"\r\n".join(b"Sec-WebSocket-Protocol: " + LEGACY_SUBPROTOCOL.encode()
                        if _header_name(line) == _PROTOCOL_HEADER else line for line in lines)


def _read_head(sock: socket.socket) -> tuple[bytes, bytes] | None:
    """An HTTP head read from ``sock`` (without the blank line) and the bytes that followed it in the same reads;
    None if the peer closed, timed out or sent a head larger than MAX_HEAD_BYTES."""
    received = bytearray()
    while True:
        end = received.find(b"\r\n\r\n")
        if end >= 0:
            return bytes(received[:end]), bytes(received[end + 4:])
        if len(received) > MAX_HEAD_BYTES:
            return None
        chunk = sock.recv(4096)
        if not chunk:
            return None
        received += chunk


class SubprotocolRelay:
    """Listens on (host, port) and relays every connection to the SDK server on 127.0.0.1:``backend_port``."""

    def __init__(self, host: str, port: int, backend_port: int, log: logging.Logger):
        family = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)[0][0]
        self.listener = socket.create_server((host, port), family=family, backlog=MAX_CONNECTIONS)
        self.port: int = self.listener.getsockname()[1]
        self.backend_port = backend_port
        self.log = log
        self.lock = threading.Lock()
        self.connections: set[socket.socket] = set()
        self.threads: set[threading.Thread] = set()
        self.stopping = False
        self.acceptor = threading.Thread(target=self._accept, name="relay-accept", daemon=True)
        self.acceptor.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop listening and end every connection."""
        with self.lock:
            self.stopping = True
            connections = list(self.connections)
            threads = list(self.threads)
        with contextlib.suppress(OSError):
            self.listener.shutdown(socket.SHUT_RDWR)  # wakes the blocked accept()
        self.listener.close()
        for sock in connections:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)  # wakes the blocked splice() calls
        self.acceptor.join(timeout_s)
        for thread in threads:
            thread.join(timeout_s)

    def _accept(self) -> None:
        while True:
            try:
                client, address = self.listener.accept()
            except OSError:
                return  # stop() closed the listener
            with self.lock:
                stopping, full = self.stopping, len(self.threads) >= MAX_CONNECTIONS
            if stopping:
                client.close()
                return
            if full:
                self.log.warning("refused a connection from %s: %d connections open", address[0], MAX_CONNECTIONS)
                with contextlib.suppress(OSError):
                    client.sendall(b"HTTP/1.1 503 Service Unavailable\r\nConnection: close\r\n\r\n")
                client.close()
                continue
            self._start(self._serve, client, address[0])

    def _start(self, target: Callable[..., None], *args: object) -> None:
        thread = threading.Thread(target=self._run, args=(target, *args), daemon=True)
        with self.lock:
            self.threads.add(thread)
        thread.start()

    def _run(self, target: Callable[..., None], *args: object) -> None:
        try:
            target(*args)
        finally:
            with self.lock:
                self.threads.discard(threading.current_thread())

    def _track(self, *sockets: socket.socket) -> bool:
        with self.lock:
            if self.stopping:
                return False
            self.connections.update(sockets)
            return True

    def _serve(self, client: socket.socket, address: str) -> None:
        backend: socket.socket | None = None
        try:
            if not self._track(client):
                return
            client.settimeout(HANDSHAKE_TIMEOUT_S)
            request = _read_head(client)
            if request is None:
                return
            head, legacy = rewrite_request(request[0])
            backend = socket.create_connection(("127.0.0.1", self.backend_port), timeout=HANDSHAKE_TIMEOUT_S)
            if not self._track(backend):
                return
            backend.sendall(head + b"\r\n\r\n" + request[1])
            if legacy:
                answer = _read_head(backend)
                if answer is None:
                    return
                client.sendall(rewrite_response(answer[0]) + b"\r\n\r\n" + answer[1])
                self.log.info("client at %s offers only %s: relayed as %s", address, LEGACY_SUBPROTOCOL,
                              SDK_SUBPROTOCOL)
            client.settimeout(None)
            backend.settimeout(None)
            upstream = threading.Thread(target=_pump, args=(client, backend), daemon=True)
            upstream.start()
            _pump(backend, client)
            upstream.join()
        except OSError as error:
            self.log.info("connection from %s ended: %s", address, error)
        finally:
            for sock in (client, backend):
                if sock is not None:
                    with self.lock:
                        self.connections.discard(sock)
                    sock.close()


def _pump(source: socket.socket, target: socket.socket) -> None:
    """Move bytes from ``source`` to ``target`` through a kernel pipe until ``source`` ends; then end ``target``'s
    sending side (a failed write ends both sockets)."""
    read_end, write_end = os.pipe()
    try:
        while True:
            moved = os.splice(source.fileno(), write_end, PIPE_BYTES)
            if moved == 0:
                break
            while moved:
                moved -= os.splice(read_end, target.fileno(), moved)
        with contextlib.suppress(OSError):
            target.shutdown(socket.SHUT_WR)
    except OSError:
        for sock in (source, target):
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
    finally:
        os.close(read_end)
        os.close(write_end)
