"""The live page's server: aiohttp (HTTP and WebSockets) on its own event loop, in its own
thread, so that serving pages never runs in the listener's loop.

Routes: ``/`` the page, its decisions so far rendered on the server (so a page without
script, or ``chromium --dump-dom``, shows them); ``/static/...`` its script and style (shipped
with the package, no network); ``/ws`` the WebSocket that feeds the page (a ``hello`` with the
whole current state, then decisions, statistics and display frames; whatever a page sends is
ignored: no command reaches the controller from it); ``/state.json`` the ``hello`` message.

Security defaults: the server binds loopback addresses only, unless ``public=True``
(``eskin listen --web-public``); served on loopback, it answers only requests whose Host is a
loopback name or address (a page elsewhere cannot reach it through a DNS name that resolves to
127.0.0.1), and a WebSocket only from a page of its own origin.
"""

from __future__ import annotations

import asyncio
import errno
import ipaddress
import json
import socket
import threading
import time
from pathlib import Path
from typing import Any, Optional

from eskin.link.web._state import LiveState

__all__ = ["WebServer", "parse_web_address"]

STATIC = Path(__file__).resolve().parent / "static"
#: display frames a second (the page draws at most this often too)
TICK_HZ = 10.0
#: messages waiting for one page, at most; a page further behind skips display frames, and
#: one that misses a decision gets the whole state again
CLIENT_QUEUE = 64
_LOOPBACK_NAMES = ("localhost", "localhost.localdomain", "ip6-localhost")


def _is_loopback(host: str) -> bool:
    """True when every address ``host`` names is a loopback one."""
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, None, proto=socket.IPPROTO_TCP)
    except OSError:
        return False
    return bool(infos) and all(
        ipaddress.ip_address(i[4][0].split("%")[0]).is_loopback for i in infos)


def parse_web_address(value: str, public: bool = False, option: str = "--web"
                      ) -> tuple[str, int]:
    """``[HOST:]PORT`` (``8765``, ``127.0.0.1:8765``, ``localhost:0``, ``[::1]:8765``) ->
    (host, port); the host defaults to 127.0.0.1 and must be a loopback address unless
    ``public``. Raises ValueError naming ``option`` and the value."""
    text = value.strip()
    host, sep, port_text = text.rpartition(":")
    if not sep:
        host, port_text = "127.0.0.1", text
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    elif ":" in host:
        raise ValueError(f"{option} {value}: an IPv6 address goes in brackets, "
                         f"e.g. [::1]:8765")
    if not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
        raise ValueError(f"{option} {value}: expected [HOST:]PORT with a port 0..65535 "
                         f"(0: any free port)")
    if not host:
        raise ValueError(f"{option} {value}: the host is empty (give PORT alone for "
                         f"127.0.0.1)")
    if not public and not _is_loopback(host):
        raise ValueError(f"{option} {value}: {host} is not a loopback address; the page is "
                         f"served to other machines only with --web-public")
    return host, int(port_text)


def _host_of(header: str) -> str:
    """The host part of a Host header (``127.0.0.1:8765``, ``[::1]:8765``, ``localhost``)."""
    if header.startswith("["):
        return header[1:].partition("]")[0]
    return header.rpartition(":")[0] if header.count(":") == 1 else header


class WebServer:
    """Serve ``state`` (a :class:`LiveState`) at ``host:port`` from a thread of its own.

    :meth:`start` binds (raising ValueError naming ``--web`` and the address when it cannot)
    and returns once the page is served; :meth:`stop` sends the pages the final "stopped"
    message, keeps serving for ``grace_s`` seconds (a page opened or reloaded then still shows
    the final state), then closes. ``cpu_s`` is the server thread's CPU time so far.
    """

    def __init__(self, state: LiveState, host: str = "127.0.0.1", port: int = 8765,
                 public: bool = False, tick_hz: float = TICK_HZ) -> None:
        self.state = state
        self.host = host
        self.port = int(port)
        self.public = bool(public)
        self.tick_s = 1.0 / float(tick_hz)
        self.cpu_s = 0.0
        self.frames_dropped = 0
        self._clients: set[asyncio.Queue] = set()
        self._thread: Optional[threading.Thread] = None
        self._loop: Optional[asyncio.AbstractEventLoop] = None
        self._ready = threading.Event()
        self._error: Optional[BaseException] = None
        self._stop: Optional[asyncio.Event] = None
        self._summary: list[str] = []
        self._grace_s = 0.0

    @property
    def clients(self) -> int:
        """Pages connected now."""
        return len(self._clients)

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    # -- the caller's thread ---------------------------------------------------------------
    def start(self, timeout: float = 10.0) -> WebServer:
        self._thread = threading.Thread(target=self._run, name="eskin-web", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise RuntimeError(f"the live page's server did not start within {timeout} s")
        if self._error is not None:
            self._thread.join(timeout)
            raise self._error
        return self

    def stop(self, summary: Optional[list[str]] = None, grace_s: float = 0.0) -> None:
        """Say "stopped" to the pages, serve ``grace_s`` more seconds, close (idempotent)."""
        loop, thread = self._loop, self._thread
        if loop is None or thread is None or not thread.is_alive():
            return
        self._summary = list(summary or [])
        self._grace_s = max(0.0, float(grace_s))
        try:
            loop.call_soon_threadsafe(self._stop_soon)
        except RuntimeError:  # the loop has already closed
            return
        thread.join(self._grace_s + 10.0)

    def _stop_soon(self) -> None:
        assert self._stop is not None
        self._stop.set()

    # -- the server's thread ---------------------------------------------------------------
    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._serve())
        except BaseException as exc:  # noqa: BLE001 - handed to start() or ends the thread
            if not self._ready.is_set():
                self._error = exc
                self._ready.set()
        finally:
            self.cpu_s = time.thread_time()
            loop.close()

    async def _serve(self) -> None:
        from aiohttp import web

        self._stop = asyncio.Event()

        @web.middleware
        async def guard(request: Any, handler: Any) -> Any:
            return await self._guard(request, handler)

        app = web.Application(middlewares=[guard])
        app.router.add_get("/", self._page)
        app.router.add_get("/ws", self._ws)
        app.router.add_get("/state.json", self._state_json)
        app.router.add_static("/static", STATIC, follow_symlinks=False)
        runner = web.AppRunner(app, access_log=None, handle_signals=False)
        await runner.setup()
        try:
            await self._bind(runner)
            self._ready.set()
            await self._ticks()
            self._broadcast(self.state.stopped(self._summary), droppable=False)
            await self._linger()
        finally:
            await runner.cleanup()

    async def _bind(self, runner: Any) -> None:
        from aiohttp import web

        site = web.TCPSite(runner, self.host, self.port, reuse_address=True)
        try:
            await site.start()
        except OSError as exc:
            where = f"{self.host}:{self.port}" if ":" not in self.host else \
                f"[{self.host}]:{self.port}"
            reason = ("address already in use" if exc.errno == errno.EADDRINUSE
                      else (exc.strerror or str(exc)))
            raise ValueError(f"--web {where}: {reason}") from None
        self.port = int(runner.addresses[0][1])

    async def _ticks(self) -> None:
        assert self._stop is not None
        while not self._stop.is_set():
            for msg in self.state.tick():
                self._broadcast(msg, droppable=msg["type"] == "frame")
            self.cpu_s = time.thread_time()
            try:
                await asyncio.wait_for(self._stop.wait(), self.tick_s)
            except asyncio.TimeoutError:
                pass
        for msg in self.state.tick():  # what the listener observed last
            self._broadcast(msg, droppable=msg["type"] == "frame")

    async def _linger(self) -> None:
        """Serve the final state for the grace period, then close the pages' sockets."""
        await asyncio.sleep(self._grace_s)
        for q in list(self._clients):
            while not q.empty():  # what a slow page has not taken yet: it is closing
                q.get_nowait()
            q.put_nowait(None)
        deadline = time.monotonic() + 2.0
        while self._clients and time.monotonic() < deadline:
            await asyncio.sleep(0.02)

    def _broadcast(self, msg: dict[str, Any], droppable: bool) -> None:
        text = json.dumps(msg, allow_nan=False)
        for q in list(self._clients):
            if not q.full():
                q.put_nowait(text)
            elif droppable:
                self.frames_dropped += 1
            else:  # behind by a decision: start this page again from the whole state
                while not q.empty():
                    q.get_nowait()
                q.put_nowait(json.dumps(self.state.hello(), allow_nan=False))

    # -- requests --------------------------------------------------------------------------
    async def _guard(self, request: Any, handler: Any) -> Any:
        """Loopback Host only (unless public), WebSockets from the page's own origin, GET."""
        from aiohttp import web

        if not self.public:
            host = _host_of(request.headers.get("Host", ""))
            if host not in _LOOPBACK_NAMES and not _is_ip_loopback(host):
                return web.Response(status=403, text="served on loopback only: Host refused\n")
        origin = request.headers.get("Origin")
        if request.path == "/ws" and origin is not None:
            if origin.partition("://")[2].rstrip("/") != request.headers.get("Host", ""):
                return web.Response(status=403, text="WebSocket from another origin refused\n")
        if request.method not in ("GET", "HEAD"):
            return web.Response(status=405, text="the live page is read-only\n")
        return await handler(request)

    async def _page(self, request: Any) -> Any:
        from aiohttp import web

        return web.Response(text=render_page(self.state), content_type="text/html",
                            headers={"Cache-Control": "no-store"})

    async def _state_json(self, request: Any) -> Any:
        from aiohttp import web

        return web.Response(text=json.dumps(self.state.hello(), allow_nan=False),
                            content_type="application/json",
                            headers={"Cache-Control": "no-store"})

    async def _ws(self, request: Any) -> Any:
        from aiohttp import WSMsgType, web

        ws = web.WebSocketResponse(heartbeat=20.0, max_msg_size=1024)
        await ws.prepare(request)
        q: asyncio.Queue = asyncio.Queue(maxsize=CLIENT_QUEUE)
        q.put_nowait(json.dumps(self.state.hello(), allow_nan=False))
        self._clients.add(q)
        sender = asyncio.ensure_future(self._send(ws, q))
        try:
            async for msg in ws:  # read-only: what a page sends is dropped
                if msg.type == WSMsgType.ERROR:
                    break
        finally:
            self._clients.discard(q)
            sender.cancel()
            await asyncio.gather(sender, return_exceptions=True)
        return ws

    async def _send(self, ws: Any, q: asyncio.Queue) -> None:
        while True:
            text = await q.get()
            if text is None:
                await ws.close(code=1001, message=b"the listener has stopped")
                return
            try:
                await ws.send_str(text)
            except (ConnectionError, RuntimeError):
                return


def _is_ip_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def render_page(state: LiveState) -> str:
    """The page with the state's decisions, status and header rendered in."""
    import html

    page = (STATIC / "index.html").read_text(encoding="utf-8")
    info = state.info
    header = html.escape(state.port) if info is None else html.escape(
        f"{state.port} \u00b7 grid {info['rows']}x{info['cols']} \u00b7 {info['rate']:g} Hz "
        f"\u00b7 classes: {', '.join(info['classes']) or '-'}")
    status = {"live": "live", "stopped": "stopped: the listener has ended"}[state.status]
    return (page.replace("<!--STATUS-->", html.escape(status))
            .replace("<!--STATUS_CLASS-->", state.status)
            .replace("<!--HEADER-->", header)
            .replace("<!--COUNT-->", str(state.n_decisions))
            .replace("<!--DECISIONS-->", state.decisions_html()))
