"""The monitor's web page: one page, its files and a WebSocket of snapshots, served by the monitor itself.

:class:`PageServer` runs aiohttp (HTTP and WebSocket) on an asyncio loop in a thread of its own, beside the DDS side,
which stays in the program's main thread (automotive.tools.monitor.monitor). The DDS side makes a snapshot at most once
a second while someone watches, serializes it once (:meth:`Snapshot.to_json`) and hands the text to :meth:`publish`;
every connected page gets that same text. A page that is slower than that skips to the latest snapshot.

What it serves, all from package data (``page/``: index.html, app.js, style.css and the vendored cytoscape.js; no
CDN, no internet):

- ``/``: the page; ``/static/<file>``: its files;
- ``/ws``: the WebSocket: each message one snapshot as JSON (the document of ``automotive monitor --json``);
- ``/snapshot.json``: the latest snapshot, for a script or a quick look (made fresh if the last one is old;
  ``?next=1``: the next one, a script's way to follow the snapshots without polling faster than they come);
- ``/lidar.png``: the LiDAR cloud as an image, when the DDS side gives a renderer (404 otherwise).

Safety: bound to a loopback address (the default, 127.0.0.1) it answers only requests whose Host is a loopback name
(a web site the user visits cannot reach it through DNS rebinding), and the WebSocket only pages of its own origin (a
web site cannot read the domain through the user's browser). Bound to any other address it needs a token
(``--token``): every request without it (in ``?token=``, the cookie the page sets, or ``Authorization: Bearer``) is
refused with 403. :func:`bind_problem` says when a bind is refused.
"""

from __future__ import annotations

import asyncio
import hmac
import ipaddress
import logging
import threading
import time
from collections.abc import Awaitable, Callable
from importlib import resources
from urllib.parse import quote, urlsplit

from aiohttp import WSMsgType, web

CYTOSCAPE_VERSION = "3.34.4"  # page/vendor/cytoscape.min.js: see page/vendor/README.md (what, why, how to update)
DEFAULT_BIND = "127.0.0.1"
DEFAULT_PORT = 8780
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")
TOKEN_COOKIE = "automotive_monitor_token"
MAX_CLIENTS = 32  # pages connected at once: each costs a send per second
FRESH_S = 2.0  # /snapshot.json waits for a new snapshot when the last one is older than this
SNAPSHOT_WAIT_S = 5.0  # ... at most this long
WATCHED_FOR_S = 10.0  # a /snapshot.json request keeps the snapshots coming this long (a script polling it)
LIDAR_EVERY_S = 1.0  # the LiDAR image is rendered at most once a second, whoever asks
# The page's files: name -> content type.
FILES = {
    "index.html": "text/html; charset=utf-8",
    "app.js": "text/javascript; charset=utf-8",
    "style.css": "text/css; charset=utf-8",
    "vendor/cytoscape.min.js": "text/javascript; charset=utf-8",
    "vendor/cytoscape.LICENSE": "text/plain; charset=utf-8",
}
HEADERS = {
    # Everything is the page's own: no other origin is ever loaded or connected to.
    "Content-Security-Policy": "default-src 'none'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
                               "img-src 'self' data: blob:; connect-src 'self'; base-uri 'none'; "
                               "form-action 'none'; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-store",
}

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


def is_loopback(bind: str) -> bool:
    """127.0.0.1 (any of 127/8), ::1, localhost."""
    if bind.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(bind.strip("[]")).is_loopback
    except ValueError:
        return False


def bind_problem(bind: str, token: str | None) -> str | None:
    """Why serving on ``bind`` is refused (the one line the user sees), or None."""
    if token is not None and not token.strip():
        return "--token: expected a non-empty token"
    if not is_loopback(bind) and token is None:
        return (f"--bind {bind}: serving beyond this host needs --token T (every request must then carry it); "
                f"without it, bind to {DEFAULT_BIND}")
    return None


def page_url(bind: str, port: int, token: str | None) -> str:
    host = bind
    if bind in ("0.0.0.0", "::", ""):
        host = "127.0.0.1"  # reachable here; from elsewhere, the host's own address
    elif ":" in host and not host.startswith("["):
        host = f"[{host}]"
    return f"http://{host}:{port}/" + (f"?token={quote(token, safe='')}" if token else "")


def load_files() -> dict[str, tuple[bytes, str]]:
    """The page's files from package data, read once."""
    folder = resources.files("automotive.tools.monitor") / "page"
    found: dict[str, tuple[bytes, str]] = {}
    for name, content_type in FILES.items():
        item = folder
        for part in name.split("/"):
            item = item / part
        found[name] = (item.read_bytes(), content_type)
    return found


def _host_name(host: str) -> str:
    """``127.0.0.1:8780`` -> ``127.0.0.1``; ``[::1]:8780`` -> ``::1``."""
    if host.startswith("["):
        return host[1:].split("]", 1)[0]
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


class PageServer:
    """The page, its files and the snapshots' WebSocket, on an asyncio loop in a thread of its own."""

    def __init__(self, bind: str, port: int, token: str | None, log: logging.Logger,
                 lidar_png: Callable[[], bytes | None] | None = None):
        self.bind = bind
        self.port = port
        self.token = token
        self.log = log
        self.lidar_png = lidar_png
        self.files = load_files()
        self.url = ""
        self.latest: str | None = None  # the last snapshot's JSON (the loop's thread writes it)
        self.latest_at = 0.0  # time.monotonic() of it
        self.clients = 0  # WebSocket pages connected (read by the DDS side: is anyone watching?)
        self.asked_at = -WATCHED_FOR_S  # the last /snapshot.json request
        self._events: set[asyncio.Event] = set()  # one per connected page: a new snapshot is there
        self._fresh: asyncio.Event | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._thread: threading.Thread | None = None
        self._started = threading.Event()
        self._error: OSError | None = None
        self._lidar: tuple[float, bytes | None] = (-LIDAR_EVERY_S, None)
        self._lidar_lock: asyncio.Lock | None = None

    # -- the DDS side's calls (any thread) ------------------------------------------------------------------------
    def start(self) -> str:
        """Bind and serve; the page's URL. OSError (the port taken, an address not of this host) as it comes."""
        self._thread = threading.Thread(target=self._run, name="monitor-page", daemon=True)
        self._thread.start()
        self._started.wait()
        if self._error is not None:
            self._thread.join()
            raise self._error
        return self.url

    @property
    def watched(self) -> bool:
        """A page is connected, or a script asked for /snapshot.json lately: snapshots are wanted."""
        return self.clients > 0 or time.monotonic() - self.asked_at < WATCHED_FOR_S

    def publish(self, text: str) -> None:
        """Hand a new snapshot (JSON text) to every page."""
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        try:
            loop.call_soon_threadsafe(self._set_latest, text)
        except RuntimeError:  # the loop is closing
            pass

    def stop(self) -> None:
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(stop.set)
            except RuntimeError:
                pass
        if self._thread is not None:
            self._thread.join(timeout=10)

    # -- the loop's thread ----------------------------------------------------------------------------------------
    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        runner: web.AppRunner | None = None
        try:
            try:
                runner = loop.run_until_complete(self._serve())
            except OSError as error:
                self._error = error
                return
            finally:
                self._started.set()
            assert self._stop is not None
            loop.run_until_complete(self._stop.wait())
        finally:
            if runner is not None:
                loop.run_until_complete(runner.cleanup())
            loop.close()

    async def _serve(self) -> web.AppRunner:
        self._stop = asyncio.Event()
        self._fresh = asyncio.Event()
        self._lidar_lock = asyncio.Lock()
        app = web.Application(middlewares=[self._guard], client_max_size=64 * 1024)
        app.router.add_get("/", self._index)
        app.router.add_get("/static/{name:.+}", self._static)
        app.router.add_get("/ws", self._websocket)
        app.router.add_get("/snapshot.json", self._snapshot)
        app.router.add_get("/lidar.png", self._lidar_image)
        runner = web.AppRunner(app, access_log=None, handle_signals=False, shutdown_timeout=2.0)
        await runner.setup()
        site = web.TCPSite(runner, self.bind, self.port, reuse_address=True)
        try:
            await site.start()
        except OSError:
            await runner.cleanup()
            raise
        port = self.port
        for address in runner.addresses:  # the port the system chose for --port 0
            if isinstance(address, tuple) and len(address) >= 2:
                port = int(address[1])
                break
        self.port = port
        self.url = page_url(self.bind, port, self.token)
        self._loop = asyncio.get_running_loop()
        return runner

    def _set_latest(self, text: str) -> None:
        self.latest = text
        self.latest_at = time.monotonic()
        for event in self._events:
            event.set()
        if self._fresh is not None:
            self._fresh.set()
            self._fresh = asyncio.Event()

    # -- requests -------------------------------------------------------------------------------------------------
    def _token_given(self, request: web.Request) -> str | None:
        given = request.query.get("token") or request.cookies.get(TOKEN_COOKIE)
        authorization = request.headers.get("Authorization", "")
        if not given and authorization.startswith("Bearer "):
            given = authorization[len("Bearer "):]
        return given

    @web.middleware
    async def _guard(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        if self.token is not None:
            given = self._token_given(request)
            if given is None or not hmac.compare_digest(given.encode(), self.token.encode()):
                raise web.HTTPForbidden(text="403: this monitor needs its token (open the URL it printed, with "
                                             "?token=...)\n", headers=HEADERS)
        elif _host_name(request.host).lower() not in LOOPBACK_NAMES and not is_loopback(_host_name(request.host)):
            raise web.HTTPForbidden(text="403: this monitor answers requests to a loopback address only\n",
                                    headers=HEADERS)
        origin = request.headers.get("Origin")
        if request.path == "/ws" and origin is not None and urlsplit(origin).netloc.lower() != request.host.lower():
            raise web.HTTPForbidden(text="403: the snapshots are for this monitor's own page\n", headers=HEADERS)
        response = await handler(request)
        if not response.prepared:  # a WebSocket has sent its headers already
            response.headers.update(HEADERS)
            if self.token is not None and request.query.get("token"):
                # The page's files and its WebSocket then carry the token without it in every URL.
                response.set_cookie(TOKEN_COOKIE, self.token, httponly=True, samesite="Strict", path="/")
        return response

    async def _index(self, request: web.Request) -> web.Response:
        body, content_type = self.files["index.html"]
        return web.Response(body=body, headers={"Content-Type": content_type})

    async def _static(self, request: web.Request) -> web.Response:
        found = self.files.get(request.match_info["name"])
        if found is None:
            raise web.HTTPNotFound(text="404: no such file\n")
        body, content_type = found
        return web.Response(body=body, headers={"Content-Type": content_type})

    async def _snapshot(self, request: web.Request) -> web.Response:
        self.asked_at = time.monotonic()
        wait = self.latest is None or self.asked_at - self.latest_at > FRESH_S or "next" in request.query
        if wait and self._fresh is not None:
            try:
                await asyncio.wait_for(self._fresh.wait(), SNAPSHOT_WAIT_S)
            except TimeoutError:
                pass
        if self.latest is None:
            raise web.HTTPServiceUnavailable(text="503: no snapshot yet\n")
        return web.Response(text=self.latest, content_type="application/json")

    async def _lidar_image(self, request: web.Request) -> web.Response:
        render = self.lidar_png
        if render is None or self._lidar_lock is None:
            raise web.HTTPNotFound(text="404: no LiDAR image in this monitor\n")
        async with self._lidar_lock:  # one render at a time, at most one a second, whoever asks
            made_at, image = self._lidar
            if time.monotonic() - made_at >= LIDAR_EVERY_S:
                try:
                    image = await asyncio.get_running_loop().run_in_executor(None, render)
                except Exception as error:  # noqa: BLE001  (a render that fails is no reason to end the page)
                    self.log.debug("LiDAR image failed: %s", error)
                    image = None
                self._lidar = (time.monotonic(), image)
        if image is None:
            raise web.HTTPNotFound(text="404: no LiDAR cloud received yet\n")
        return web.Response(body=image, content_type="image/png")

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        if len(self._events) >= MAX_CLIENTS:
            raise web.HTTPServiceUnavailable(text=f"503: {MAX_CLIENTS} pages are connected already\n")
        socket = web.WebSocketResponse(heartbeat=30.0, compress=False, max_msg_size=4096)
        socket.headers.update(HEADERS)
        await socket.prepare(request)
        event = asyncio.Event()
        event.set()  # the latest snapshot at once
        self._events.add(event)
        self.clients = len(self._events)
        sender = asyncio.create_task(self._send(socket, event))
        try:
            async for message in socket:  # the page says nothing; this reads its pings and its close
                if message.type == WSMsgType.ERROR:
                    break
        finally:
            self._events.discard(event)
            self.clients = len(self._events)
            sender.cancel()
        return socket

    async def _send(self, socket: web.WebSocketResponse, event: asyncio.Event) -> None:
        sent: str | None = None
        try:
            while not socket.closed:
                await event.wait()
                event.clear()
                text = self.latest
                if text is not None and text is not sent:
                    sent = text
                    await socket.send_str(text)
        except (ConnectionError, RuntimeError):  # the page left while we sent
            pass


def describe(error: OSError, bind: str, port: int) -> str:
    """An OSError of binding, in one line."""
    reason = error.strerror or str(error)
    return f"cannot serve the page on {bind}:{port}: {reason}"


__all__ = ["DEFAULT_BIND", "DEFAULT_PORT", "PageServer", "bind_problem", "describe", "is_loopback", "page_url"]
