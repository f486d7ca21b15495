"""The scope's web server: one page and one WebSocket on 127.0.0.1, behind a token.

Who may look: the URL carries a 128-bit random token (``/s/<token>/``; anything else is 403), and
every connection's peer must be a socket of this user: on Linux the kernel's socket tables
(/proc/net/tcp, /proc/net/tcp6) name the owner uid of the client's end of a loopback connection,
so another local user holding the URL is still refused (an SSH port-forward arrives from the
user's own sshd process, so it passes). The browser is opened on a 0600 file in a 0700 directory
that redirects to the URL, so the token never shows in a process list.

Where the data comes from (a `Source`):

* `ControlSource`: a running session's control socket (the one `hilbench ctl` finds). Each page
  gets its own connection; the server asks ``stream`` a dozen times a second and relays the
  frames, and relays the page's commands (set, ref, load, press, step, guard, stop) unchanged, so
  a change from the page takes the same checked, guarded path as `hilbench ctl`.
* `RecordingSource`: a recording file, sent once as frames of the same shape (min/max envelopes).

The page and its script are files of this package (``static/``): no third-party code, no network.
"""

from __future__ import annotations

import asyncio
import hmac
import itertools
import json
import os
import secrets
import socket
import tempfile
import threading
from pathlib import Path
from typing import Any, Callable, Protocol

import numpy as np

from hilbench.errors import ConfigError

STATIC = Path(__file__).with_name("static")
POLL_EVERY_S = 0.08  # the page's stream requests (a session answers within one observe period)
MAX_WS_MESSAGE = 64 * 1024  # the page sends commands only
REPLY_LIMIT = 64 * 1024 * 1024  # the longest reply line from the control socket


class Source(Protocol):
    """Where a page's data comes from."""

    async def serve(self, send: Callable[[dict[str, Any]], Any], inbox: "asyncio.Queue[dict[str, Any]]") -> None: ...


# --------------------------------------------------------------------------------------------
# who is connecting


def _port_of(address: str) -> tuple[str, int]:
    host, port = address.rsplit(":", 1)
    return host, int(port, 16)


def socket_owner(peer_port: int, local_port: int, tables: tuple[str, ...] = ("/proc/net/tcp", "/proc/net/tcp6")) -> int | None:
    """The uid owning the client's end of a loopback TCP connection (its local port is the peer's
    port, its remote port ours), from the kernel's socket tables; None when not found."""
    for table in tables:
        try:
            lines = Path(table).read_text(encoding="ascii").splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            parts = line.split()
            if len(parts) < 8:
                continue
            _, lport = _port_of(parts[1])
            _, rport = _port_of(parts[2])
            if lport == peer_port and rport == local_port:
                return int(parts[7])
    return None


# --------------------------------------------------------------------------------------------
# sources


class ControlSource:
    """A running session, through its control socket."""

    def __init__(self, socket_path: str | os.PathLike[str], poll_every_s: float = POLL_EVERY_S) -> None:
        self.socket_path = Path(socket_path)
        self.poll_every_s = poll_every_s

    async def serve(self, send: Callable[[dict[str, Any]], Any], inbox: "asyncio.Queue[dict[str, Any]]") -> None:
        try:
            reader, writer = await asyncio.open_unix_connection(str(self.socket_path), limit=REPLY_LIMIT)
        except OSError as exc:
            await send({"type": "closed", "reason": f"control socket {self.socket_path}: {exc.strerror or exc}"})
            return
        ids = itertools.count(1)
        waiting: dict[int, asyncio.Future[dict[str, Any]]] = {}
        state: dict[str, Any] = {"since": -1, "columns": []}

        async def read_replies() -> None:
            while True:
                line = await reader.readline()
                if not line:
                    break
                reply = json.loads(line)
                future = waiting.pop(reply.get("id"), None)
                if future is not None and not future.done():
                    future.set_result(reply)
            for future in waiting.values():
                if not future.done():
                    future.set_exception(ConnectionError("the session closed its control socket"))

        async def ask(request: dict[str, Any]) -> dict[str, Any]:
            rid = next(ids)
            future: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
            waiting[rid] = future
            writer.write(json.dumps({**request, "id": rid}).encode() + b"\n")
            await writer.drain()
            return await future

        async def commands() -> None:
            while True:
                message = await inbox.get()
                if message.get("type") == "subscribe":
                    state["columns"] = [str(c) for c in message.get("columns", [])][:48]
                    state["since"] = -1
                elif message.get("type") == "cmd":
                    request = {k: v for k, v in message.items() if k not in ("type", "id")}
                    asyncio.ensure_future(relay(message.get("id"), request))

        async def relay(page_id: Any, request: dict[str, Any]) -> None:
            try:
                reply = await ask(request)
            except ConnectionError as exc:
                reply = {"ok": False, "message": str(exc), "data": None}
            await send({"type": "reply", "id": page_id, "cmd": request.get("cmd"), "ok": reply.get("ok"),
                        "message": reply.get("message"), "data": reply.get("data")})

        reading = asyncio.ensure_future(read_replies())
        handling = asyncio.ensure_future(commands())
        try:
            while True:
                since = state["since"]
                reply = await ask({"cmd": "stream", "since": since, "columns": state["columns"]})
                if not reply.get("ok"):
                    await send({"type": "closed", "reason": reply.get("message", "stream refused")})
                    return
                data = reply["data"]
                if state["since"] == since:  # not re-subscribed meanwhile
                    state["since"] = data["seq"]
                    await send({"type": "stream", **data})
                if data["status"].get("ended"):
                    await send({"type": "closed", "reason": "the run has ended"})
                    return
                await asyncio.sleep(self.poll_every_s)
        except (ConnectionError, OSError, json.JSONDecodeError):
            await send({"type": "closed", "reason": "the session closed its control socket"})
        finally:
            reading.cancel()
            handling.cancel()
            writer.close()


class RecordingSource:
    """A recording (CSV, NPZ or a killed run's journal), sent as envelope frames."""

    MAX_BUCKETS = 20_000

    def __init__(self, path: str | os.PathLike[str]) -> None:
        from hilbench.bench.recorder import read_recording

        self.path = Path(path)
        self.data = read_recording(self.path)

    def _names(self) -> list[tuple[str, str]]:
        from hilbench.bench.display import HALL_BITS

        names = [(name, self.data.units.get(name, "")) for name in self.data.columns]
        if "hall" in self.data.columns:
            at = [n for n, _ in names].index("hall") + 1
            names[at:at] = [(n, "bit") for _, n in HALL_BITS]
        return names

    def frame(self, columns: list[str]) -> dict[str, Any]:
        """Everything in one frame (buckets of a fixed size, at most MAX_BUCKETS of them)."""
        from hilbench.bench.display import HALL_BITS, b64_f32, envelope

        data = self.data
        t = np.asarray(data.columns["t_s"], dtype=np.float64)
        n = len(t)
        period_s = float(np.median(np.diff(t[: min(n, 1000)]))) if n > 1 else 1.0
        bucket = max(1, -(-n // self.MAX_BUCKETS))
        cols: dict[str, list[str]] = {}
        hall = data.columns.get("hall")
        for name in columns:
            values = data.columns.get(name)
            if values is None and hall is not None and name in {b for _, b in HALL_BITS}:
                bit = next(b for b, nm in HALL_BITS if nm == name)
                values = (np.asarray(hall).astype(np.int64) >> bit) & 1
            if values is None:
                continue
            lo, hi = envelope(np.asarray(values, dtype=np.float64), bucket)
            cols[name] = [b64_f32(lo), b64_f32(hi)]
        n_buckets = -(-n // bucket)
        return {"seq": 1, "t0": float(t[0]) if n else 0.0, "dt": bucket * period_s, "n": n_buckets, "cols": cols}

    def markers(self) -> list[list[Any]]:
        from hilbench.bench.display import marker_kind, parse_event

        out = []
        for text in self.data.events:
            parsed = parse_event(text)
            if parsed is not None:
                out.append([parsed[0], marker_kind(parsed[1], 0), parsed[1]])
        return out

    def meta(self) -> dict[str, Any]:
        return {"columns": [list(c) for c in self._names()], "params": {}, "tunable": [], "live": False,
                "target": str(self.path.name), "firmware": "", "mode": "recording",
                "period_s": None}

    async def serve(self, send: Callable[[dict[str, Any]], Any], inbox: "asyncio.Queue[dict[str, Any]]") -> None:
        t_end = float(self.data.columns["t_s"][-1]) if self.data.n_rows else 0.0
        status = {"t_s": t_end, "ended": True}
        await send({"type": "stream", "seq": 0, "frames": [], "status": status, "markers": self.markers(), "meta": self.meta()})
        while True:
            message = await inbox.get()
            if message.get("type") == "subscribe":
                columns = [str(c) for c in message.get("columns", [])]
                await send({"type": "stream", "seq": 1, "frames": [self.frame(columns)], "status": status,
                            "markers": [], "replace": True})
            elif message.get("type") == "cmd":
                await send({"type": "reply", "id": message.get("id"), "cmd": message.get("cmd"), "ok": False,
                            "message": "a recording cannot be steered", "data": None})


# --------------------------------------------------------------------------------------------
# the server


class ScopeServer:
    """Serves the page for one source on 127.0.0.1 in a thread of its own."""

    def __init__(self, source: Source, *, host: str = "127.0.0.1", port: int = 0, token: str | None = None,
                 check_owner: bool = True) -> None:
        self.source = source
        self.host = host
        self.port = port
        self.token = token or secrets.token_urlsafe(16)
        self.check_owner = check_owner
        self.uid = os.getuid()
        self.refused: dict[str, int] = {"token": 0, "user": 0}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._runner: Any = None
        self._stopping: asyncio.Event | None = None

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/s/{self.token}/"

    # ---- the app
    def app(self) -> Any:
        from aiohttp import web

        @web.middleware
        async def guard(request: web.Request, handler: Callable[[web.Request], Any]) -> Any:
            if self.check_owner and not self._same_user(request):
                self.refused["user"] += 1
                return web.Response(status=403, text="hilbench scope: this connection is not from the bench's user\n")
            if not hmac.compare_digest(request.match_info.get("token", ""), self.token):
                self.refused["token"] += 1
                return web.Response(status=403, text="hilbench scope: wrong or missing token\n")
            return await handler(request)

        app = web.Application(middlewares=[guard])
        app.router.add_get("/s/{token}/", self._page)
        app.router.add_get("/s/{token}/scope.js", self._script)
        app.router.add_get("/s/{token}/ws", self._websocket)
        app.router.add_get("/{tail:.*}", self._nothing)
        return app

    def _same_user(self, request: Any) -> bool:
        transport = request.transport
        if transport is None:
            return False
        peer = transport.get_extra_info("peername")
        local = transport.get_extra_info("sockname")
        if not peer or not local:
            return False
        return socket_owner(int(peer[1]), int(local[1])) == self.uid

    async def _nothing(self, request: Any) -> Any:
        from aiohttp import web

        return web.Response(status=403, text="hilbench scope: wrong or missing token\n")

    async def _page(self, request: Any) -> Any:
        from aiohttp import web

        return web.Response(text=(STATIC / "scope.html").read_text(encoding="utf-8"), content_type="text/html",
                            headers={"Cache-Control": "no-store", "Referrer-Policy": "no-referrer"})

    async def _script(self, request: Any) -> Any:
        from aiohttp import web

        return web.Response(text=(STATIC / "scope.js").read_text(encoding="utf-8"), content_type="application/javascript",
                            headers={"Cache-Control": "no-store"})

    async def _websocket(self, request: Any) -> Any:
        from aiohttp import WSMsgType, web

        # no per-message deflate: base64 float32 barely compresses, and deflating would cost the
        # session's process CPU (and GIL) for every frame
        ws = web.WebSocketResponse(max_msg_size=MAX_WS_MESSAGE, heartbeat=20.0, compress=False)
        await ws.prepare(request)
        inbox: asyncio.Queue[dict[str, Any]] = asyncio.Queue()

        async def send(message: dict[str, Any]) -> None:
            if not ws.closed:
                try:
                    await ws.send_str(json.dumps(message, allow_nan=False, default=_nan_none))
                except ConnectionError:  # the page went away mid-send: the receive loop ends too
                    pass

        serving = asyncio.ensure_future(self.source.serve(send, inbox))
        try:
            async for msg in ws:
                if msg.type != WSMsgType.TEXT:
                    continue
                try:
                    message = json.loads(msg.data)
                except json.JSONDecodeError:
                    continue
                if isinstance(message, dict):
                    await inbox.put(message)
        finally:
            serving.cancel()
        return ws

    # ---- the thread
    def start(self) -> "ScopeServer":
        """Serve in a daemon thread; returns once the port is bound (ConfigError if it cannot be)."""
        self._thread = threading.Thread(target=self._run, name="hilbench-scope", daemon=True)
        self._thread.start()
        self._ready.wait(10.0)
        if self._error is not None:
            raise ConfigError(f"scope: cannot serve on {self.host}:{self.port}: {self._error}")
        return self

    def _run(self) -> None:
        loop = self._loop = asyncio.new_event_loop()
        try:
            loop.run_until_complete(self._serve())
        except BaseException as exc:  # noqa: BLE001 - reported by start()
            self._error = exc
            self._ready.set()
        finally:
            loop.close()

    async def _serve(self) -> None:
        from aiohttp import web

        self._stopping = asyncio.Event()
        runner = self._runner = web.AppRunner(self.app(), access_log=None)
        await runner.setup()
        site = web.TCPSite(runner, self.host, self.port, reuse_address=True)
        await site.start()
        sock = site._server.sockets[0]  # type: ignore[union-attr]  # noqa: SLF001 - the port bound for port 0
        self.port = int(sock.getsockname()[1])
        self._ready.set()
        try:
            await self._stopping.wait()
        finally:
            await runner.cleanup()

    def close(self) -> None:
        """Stop serving (idempotent)."""
        if self._loop is not None and self._stopping is not None and not self._loop.is_closed():
            try:
                self._loop.call_soon_threadsafe(self._stopping.set)
            except RuntimeError:
                pass
        if self._thread is not None:
            self._thread.join(5.0)

    def __enter__(self) -> "ScopeServer":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def serve_forever(self) -> None:
        """Block until interrupted (the `hilbench scope` command)."""
        try:
            while self._thread is not None and self._thread.is_alive():
                self._thread.join(0.5)
        finally:
            self.close()


def _nan_none(value: Any) -> Any:
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    raise TypeError(f"not JSON: {type(value).__name__}")


def open_in_browser(url: str) -> Path:
    """Open ``url`` through a private redirect file (the token stays out of process lists)."""
    import webbrowser

    folder = Path(tempfile.mkdtemp(prefix="hilbench-scope-"))  # mode 0700
    page = folder / "open.html"
    fd = os.open(page, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(f'<!doctype html><meta http-equiv="refresh" content="0; url={url}"><a href="{url}">hilbench scope</a>\n')
    webbrowser.open(page.as_uri())
    return page


def free_port_hint() -> int:
    """A port free now on 127.0.0.1 (for tests that need to know it before serving)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


__all__ = ["ControlSource", "RecordingSource", "ScopeServer", "open_in_browser", "socket_owner"]
