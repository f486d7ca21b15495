"""The scope's web server: one page and one WebSocket on 127.0.0.1, behind a token.

Who may look: the URL carries a 128-bit random token (``/s/<token>/``; anything else is 403), and
every connection's peer must be a socket of this user: on Linux the kernel's socket tables
(/proc/net/tcp, /proc/net/tcp6) name the owner uid of the client's end of a loopback connection,
so another local user holding the URL is still refused (an SSH port-forward arrives from the
user's own sshd process, so it passes). The browser is given a one-shot URL (``/o/<nonce>``,
valid once for two minutes) that redirects to the page, so the token never shows in a process
list and no file holding it is left behind.

What a page may do is bounded: at most MAX_PAGES pages at once, WebSocket messages of at most
MAX_WS_MESSAGE bytes checked by `hilbench.scope.messages` (a bad one is refused, the page goes
on), HTTP requests within aiohttp's parser limits (HTTP_MAX_LINE, HTTP_MAX_FIELD,
HTTP_MAX_HEADERS), and a malformed request is one rate-limited line (`hilbench.scope.httplog`),
never a traceback.

Where the data comes from (a `Source`):

* `ControlSource`: a running session's control socket (the one `hilbench ctl` finds). Every page
  of a scope shares one connection (a stream connection: the session keeps its ctl connections
  for `ctl`); for each page the server asks ``stream`` a dozen times a second and relays the
  frames, and relays the page's commands (`messages.PAGE_COMMANDS`: get, set, ref, load, press,
  step, guard, stop; never save) unchanged, so a change from the page takes the same checked,
  guarded path as `hilbench ctl`.
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
import threading
from pathlib import Path
from typing import Any, Callable, Protocol

import numpy as np

from hilbench.bench.control import MAX_REPLY_BYTES
from hilbench.errors import ConfigError
from hilbench.scope.httplog import RateLimitedLog, scope_logger
from hilbench.scope.messages import Command, Refused, Subscribe, parse_page_message, refusal

STATIC = Path(__file__).with_name("static")
POLL_EVERY_S = 0.08  # the page's stream requests (a session answers within one observe period)
MAX_WS_MESSAGE = 64 * 1024  # the page sends commands only
REPLY_LIMIT = MAX_REPLY_BYTES  # the longest reply line from the control socket
#: how long the one-shot URL given to the browser (`--open`) stays valid
OPEN_VALID_S = 120.0
#: pages open at once on one scope (a page more gets 503)
MAX_PAGES = 8
#: a page's commands waiting for the session at once (more are refused as busy)
MAX_RELAYS_PER_PAGE = 8
#: aiohttp's HTTP parser limits: a request line, a header field, the number of headers
HTTP_MAX_LINE = 8190
HTTP_MAX_FIELD = 8190
HTTP_MAX_HEADERS = 64


class Source(Protocol):
    """Where a page's data comes from: `serve` runs while the page is open and gets the page's
    checked messages (hilbench.scope.messages) through ``inbox``."""

    async def serve(self, send: Callable[[dict[str, Any]], Any], inbox: "asyncio.Queue[Subscribe | Command]") -> None: ...


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


#: how long the replies on their way may take to reach a page once the run has ended
RELAY_GRACE_S = 2.0
#: how often `hilbench scope --socket` looks whether its session has gone
GONE_POLL_S = 0.1


class _Upstream:
    """One connection to the session's control socket, shared by every page of this scope: pages
    never hold control connections of their own (the session keeps MAX_CONNECTIONS for `ctl`)."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._reader = reader
        self._writer = writer
        self._ids = itertools.count(1)
        self._waiting: dict[int, asyncio.Future[dict[str, Any]]] = {}
        self.closed = False
        self._reading = asyncio.ensure_future(self._read_replies())

    async def _read_replies(self) -> None:
        try:
            while True:
                line = await self._reader.readline()
                if not line:
                    break
                try:
                    reply = json.loads(line)
                except (ValueError, RecursionError):
                    continue
                future = self._waiting.pop(reply.get("id"), None) if isinstance(reply, dict) else None
                if future is not None and not future.done():
                    future.set_result(reply)
        except (ConnectionError, OSError, ValueError, asyncio.LimitOverrunError):
            pass  # a reply over REPLY_LIMIT or a reset: the connection is done
        finally:
            self.close()

    async def ask(self, request: dict[str, Any]) -> dict[str, Any]:
        """Send one request, wait for its reply (ConnectionError when the session went away)."""
        from hilbench.bench.control import MAX_LINE_BYTES

        if self.closed:
            raise ConnectionError("the session closed its control socket")
        rid = next(self._ids)
        line = json.dumps({**request, "id": rid}, allow_nan=False, separators=(",", ":")).encode()
        if len(line) > MAX_LINE_BYTES:
            return {"ok": False, "message": f"request longer than {MAX_LINE_BYTES} bytes", "data": None}
        future: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
        self._waiting[rid] = future
        self._writer.write(line + b"\n")
        await self._writer.drain()
        return await future

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._writer.close()
        for future in self._waiting.values():
            if not future.done():
                future.set_exception(ConnectionError("the session closed its control socket"))
        self._waiting.clear()


class ControlSource:
    """A running session, through its control socket (one connection for every page)."""

    def gone(self) -> bool:
        """The session has ended: its control socket is no longer there."""
        return not self.socket_path.exists()

    def __init__(self, socket_path: str | os.PathLike[str], poll_every_s: float = POLL_EVERY_S) -> None:
        self.socket_path = Path(socket_path)
        self.poll_every_s = poll_every_s
        self._upstream: _Upstream | None = None
        self._opening: asyncio.Lock | None = None

    async def _connect(self) -> _Upstream:
        if self._opening is None:
            self._opening = asyncio.Lock()
        async with self._opening:
            if self._upstream is None or self._upstream.closed:
                reader, writer = await asyncio.open_unix_connection(str(self.socket_path), limit=REPLY_LIMIT)
                self._upstream = _Upstream(reader, writer)
            return self._upstream

    async def serve(self, send: Callable[[dict[str, Any]], Any], inbox: "asyncio.Queue[Subscribe | Command]") -> None:
        try:
            upstream = await self._connect()
        except OSError as exc:
            await send({"type": "closed", "reason": f"control socket {self.socket_path}: {exc.strerror or exc}"})
            return
        state: dict[str, Any] = {"since": -1, "columns": []}
        relays: set[asyncio.Future[None]] = set()
        wake = asyncio.Event()  # a command was answered: ask for the stream now, not at the next poll

        async def commands() -> None:
            while True:
                message = await inbox.get()
                if isinstance(message, Subscribe):
                    state["columns"], state["since"] = list(message.columns), -1
                elif len(relays) >= MAX_RELAYS_PER_PAGE:
                    await send(refusal(Refused(f"busy: {MAX_RELAYS_PER_PAGE} commands of this page are waiting",
                                               message.page_id), message.request.get("cmd")))
                else:
                    task = asyncio.ensure_future(relay(message))
                    relays.add(task)
                    task.add_done_callback(relays.discard)

        async def relay(message: Command) -> None:
            try:
                reply = await upstream.ask(message.request)
            except ConnectionError as exc:
                reply = {"ok": False, "message": str(exc), "data": None}
            await send({"type": "reply", "id": message.page_id, "cmd": message.request.get("cmd"),
                        "ok": reply.get("ok"), "message": reply.get("message"), "data": reply.get("data")})
            wake.set()  # its effect is in the session's next frames: fetch them without waiting out the poll

        async def settle() -> None:
            """The replies already on their way (a stop's, above all) reach the page before "closed"."""
            if relays:
                await asyncio.wait(set(relays), timeout=RELAY_GRACE_S)

        handling = asyncio.ensure_future(commands())
        try:
            while True:
                since = state["since"]
                reply = await upstream.ask({"cmd": "stream", "since": since, "columns": state["columns"]})
                if not reply.get("ok"):
                    await send({"type": "closed", "reason": reply.get("message", "stream refused")})
                    return
                data = reply["data"]
                if state["since"] == since:  # not re-subscribed meanwhile
                    state["since"] = data["seq"]
                    await send({"type": "stream", **data})
                if data["status"].get("ended"):
                    handling.cancel()
                    await settle()
                    await send({"type": "closed", "reason": "the run has ended"})
                    return
                try:
                    await asyncio.wait_for(wake.wait(), self.poll_every_s)
                except asyncio.TimeoutError:
                    pass
                wake.clear()
        except (ConnectionError, OSError, KeyError, TypeError, AttributeError):
            handling.cancel()
            await settle()
            await send({"type": "closed", "reason": "the session closed its control socket"})
        finally:
            handling.cancel()
            for task in list(relays):
                task.cancel()


class RecordingSource:
    """A recording (CSV, NPZ or a killed run's journal), sent as envelope frames, read a chunk of
    rows at a time: memory is a chunk and at most MAX_BUCKETS envelope points a column, however
    long the recording (it was read whole: every column in memory)."""

    MAX_BUCKETS = 20_000
    #: rows of t_s the period is the median step of
    PERIOD_ROWS = 1000

    def __init__(self, path: str | os.PathLike[str]) -> None:
        from hilbench.bench.column_chunks import recording_chunks
        from hilbench.bench.recording_head import read_head

        self.path = Path(path)
        self.source = recording_chunks(self.path)
        self.head = read_head(self.source)
        self.n_rows, self.t_last_s, self._t_start = self._scan()

    def _scan(self) -> tuple[int, float, np.ndarray]:
        """Every column read once now, so a damaged recording is one line at the start (not an error
        in the server's thread later): the rows, the last time, and the first PERIOD_ROWS times."""
        n, t_last, start = 0, 0.0, np.zeros(0)
        for chunk in self.source.chunks(self.source.names):
            t = chunk["t_s"]
            if len(t):
                n, t_last = n + len(t), float(t[-1])
                if len(start) < self.PERIOD_ROWS:
                    start = np.concatenate([start, t[: self.PERIOD_ROWS - len(start)]])
        return n, t_last, start

    def _names(self) -> list[tuple[str, str]]:
        from hilbench.bench.display import HALL_BITS

        names = [(name, self.source.units.get(name, "")) for name in self.source.names]
        if "hall" in self.source.names:
            at = [n for n, _ in names].index("hall") + 1
            names[at:at] = [(n, "bit") for _, n in HALL_BITS]
        return names

    def frame(self, columns: list[str]) -> dict[str, Any]:
        """Everything in one frame (buckets of a fixed size, at most MAX_BUCKETS of them), the
        recording read a chunk at a time."""
        from hilbench.bench.display import HALL_BITS, b64_f32
        from hilbench.ui.plot_data import TraceBuilder

        n, t = self.n_rows, self._t_start
        period_s = float(np.median(np.diff(t))) if n > 1 else 1.0
        bucket = max(1, -(-n // self.MAX_BUCKETS))
        bits = {name: bit for bit, name in HALL_BITS} if "hall" in self.source.names else {}
        wanted = [name for name in dict.fromkeys(columns) if name in self.source.names or name in bits]
        builders = {name: TraceBuilder(n, bucket) for name in wanted}
        read = [name for name in wanted if name in self.source.names] + (["hall"] if set(wanted) & set(bits) else [])
        for chunk in self.source.chunks(list(dict.fromkeys(read))):
            for name, builder in builders.items():
                values = chunk.get(name)
                if values is None:  # a hall bit
                    values = (chunk["hall"].astype(np.int64) >> bits[name]) & 1
                builder.add(chunk["t_s"], values)
        cols: dict[str, list[str]] = {}
        for name, builder in builders.items():
            trace = builder.trace()
            cols[name] = [b64_f32(trace.lo), b64_f32(trace.lo if trace.hi is None else trace.hi)]
        n_buckets = -(-n // bucket)
        return {"seq": 1, "t0": float(t[0]) if n else 0.0, "dt": bucket * period_s, "n": n_buckets, "cols": cols}

    def markers(self) -> list[list[Any]]:
        from hilbench.bench.display import marker_kind, parse_event

        out = []
        for text in self.head.events:
            parsed = parse_event(text)
            if parsed is not None:
                out.append([parsed[0], marker_kind(parsed[1], 0), parsed[1]])
        return out

    def meta(self) -> dict[str, Any]:
        return {"columns": [list(c) for c in self._names()], "params": {}, "tunable": [], "live": False,
                "target": str(self.path.name), "firmware": "", "mode": "recording",
                "period_s": None}

    async def serve(self, send: Callable[[dict[str, Any]], Any], inbox: "asyncio.Queue[Subscribe | Command]") -> None:
        status = {"t_s": self.t_last_s if self.n_rows else 0.0, "ended": True}
        await send({"type": "stream", "seq": 0, "frames": [], "status": status, "markers": self.markers(), "meta": self.meta()})
        while True:
            message = await inbox.get()
            if isinstance(message, Subscribe):  # the file is read on a thread: other pages go on meanwhile
                frame = await asyncio.to_thread(self.frame, list(message.columns))
                await send({"type": "stream", "seq": 1, "frames": [frame], "status": status, "markers": [], "replace": True})
            else:
                await send(refusal(Refused("a recording cannot be steered", message.page_id), message.request.get("cmd")))


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
        #: refused requests: a wrong token, another user, a page over MAX_PAGES (malformed HTTP
        #: requests: ``log.count``)
        self.refused: dict[str, int] = {"token": 0, "user": 0, "pages": 0}
        self.log = RateLimitedLog()
        self.pages = 0
        self._open_nonce: str | None = None
        self._open_until_s = 0.0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._runner: Any = None
        self._stopping: asyncio.Event | None = None

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/s/{self.token}/"

    def open_url(self, valid_s: float = OPEN_VALID_S) -> str:
        """A URL that redirects to the page once, within ``valid_s``: what a browser is given (its
        command line shows no token, and no file holding one is left behind)."""
        import time

        self._open_nonce = secrets.token_urlsafe(16)
        self._open_until_s = time.monotonic() + valid_s
        return f"http://{self.host}:{self.port}/o/{self._open_nonce}"

    # ---- the app
    def app(self) -> Any:
        from aiohttp import web

        @web.middleware
        async def guard(request: web.Request, handler: Callable[[web.Request], Any]) -> Any:
            if self.check_owner and not self._same_user(request):
                self.refused["user"] += 1
                return web.Response(status=403, text="hilbench scope: this connection is not from the bench's user\n")
            if "nonce" in request.match_info:
                return self._opened(request.match_info["nonce"])
            if not hmac.compare_digest(request.match_info.get("token", ""), self.token):
                self.refused["token"] += 1
                return web.Response(status=403, text="hilbench scope: wrong or missing token\n")
            return await handler(request)

        app = web.Application(middlewares=[guard])
        app.router.add_get("/s/{token}/", self._page)
        app.router.add_get("/s/{token}/scope.js", self._script)
        app.router.add_get("/s/{token}/ws", self._websocket)
        app.router.add_get("/o/{nonce}", self._nothing)
        app.router.add_get("/{tail:.*}", self._nothing)
        return app

    def _opened(self, nonce: str) -> Any:
        """The one-shot open URL: a redirect to the page the first time, 403 after. Only the right
        nonce uses it up: a wrong one (a probe, a typo) must not burn the browser's link."""
        import time

        from aiohttp import web

        expected = self._open_nonce
        if expected is None or time.monotonic() > self._open_until_s or not hmac.compare_digest(nonce, expected):
            self.refused["token"] += 1
            return web.Response(status=403, text="hilbench scope: this link has been used or has expired\n")
        self._open_nonce = None
        return web.Response(status=303, headers={"Location": f"/s/{self.token}/", "Cache-Control": "no-store",
                                                 "Referrer-Policy": "no-referrer"})

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
        if self.pages >= MAX_PAGES:
            self.refused["pages"] += 1
            return web.Response(status=503, text=f"hilbench scope: {MAX_PAGES} pages are open already\n")
        ws = web.WebSocketResponse(max_msg_size=MAX_WS_MESSAGE, heartbeat=20.0, compress=False)
        await ws.prepare(request)
        self.pages += 1
        inbox: asyncio.Queue[Subscribe | Command] = asyncio.Queue(maxsize=64)

        async def send(message: dict[str, Any]) -> None:
            if not ws.closed:
                try:
                    await ws.send_str(json.dumps(message, allow_nan=False, default=_nan_none))
                except ConnectionError:  # the page went away mid-send: the receive loop ends too
                    pass

        serving = asyncio.ensure_future(self.source.serve(send, inbox))
        # the source is done (the run ended, the session went away): the page gets a clean close
        # after its last message instead of a connection cut when this process ends
        serving.add_done_callback(lambda _: asyncio.ensure_future(ws.close()))
        try:
            async for msg in ws:
                if msg.type != WSMsgType.TEXT:
                    continue
                try:
                    message = parse_page_message(msg.data)
                except Refused as exc:  # answered, and the page goes on
                    await send(refusal(exc))
                    continue
                if serving.done():
                    break
                await inbox.put(message)
        finally:
            self.pages -= 1
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
        asyncio.get_running_loop().set_exception_handler(self._loop_exception)
        runner = self._runner = web.AppRunner(  # aiohttp's parser limits, and its errors through our one-line log
            self.app(), access_log=None, logger=scope_logger(self.log), max_line_size=HTTP_MAX_LINE,
            max_field_size=HTTP_MAX_FIELD, max_headers=HTTP_MAX_HEADERS)
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

    def _loop_exception(self, loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        """An error nobody awaited (a page's task, a transport): one line through the log, no traceback."""
        import logging

        exc = context.get("exception")
        record = logging.LogRecord("hilbench.scope", logging.ERROR, __file__, 0, str(context.get("message", "error")),
                                   None, (type(exc), exc, None) if isinstance(exc, BaseException) else None)
        self.log.handle(record)

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
        """Block until interrupted (the `hilbench scope` command), or until a session's source is
        gone and every page has had its last message and its close (`run --scope` then waits for
        this process to end by itself, so a stop clicked on the page gets its reply)."""
        gone = getattr(self.source, "gone", None)
        try:
            while self._thread is not None and self._thread.is_alive():
                self._thread.join(GONE_POLL_S)
                if gone is not None and self.pages == 0 and gone():
                    break
        finally:
            self.close()


def _nan_none(value: Any) -> Any:
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    raise TypeError(f"not JSON: {type(value).__name__}")


def open_in_browser(server: "ScopeServer") -> str:
    """Open the page in the browser through the server's one-shot URL (no token on the browser's
    command line, no file left behind); returns the URL given to the browser."""
    import webbrowser

    url = server.open_url()
    webbrowser.open(url)
    return url


def free_port_hint() -> int:
    """A port free now on 127.0.0.1 (for tests that need to know it before serving)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


__all__ = ["ControlSource", "RecordingSource", "ScopeServer", "open_in_browser", "socket_owner"]
