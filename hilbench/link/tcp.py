"""The far end of a socket:// link: listen on a TCP port, take one connection, hand it over as a Link.

    serve_tcp_once(0, lambda link: serve(target, link), announce=print)   # prints socket://127.0.0.1:PORT

The host then opens the announced `socket://HOST:PORT`. The accepted connection is a file
descriptor, so it gets the same fast path, deadlines and statistics as a pty. Nagle is off on
both ends: a lockstep exchange is one small frame each way.
"""

from __future__ import annotations

import socket
import threading
import time
from typing import Callable, TypeVar

from hilbench.errors import ConfigError, LinkClosed, LinkError, LinkTimeout
from hilbench.link.link import DEFAULT_TIMEOUT_S, Link
from hilbench.link.transport import FdTransport

T = TypeVar("T")
_STOP_POLL_S = 0.2  # how often a waiting accept looks at stop_event


class TcpListener:
    """A listening TCP socket on host:port (port 0: the system picks a free one).

    `url` is what the host opens; accept() waits for one connection and returns it as a Link.
    """

    def __init__(self, port: int = 0, host: str = "127.0.0.1") -> None:
        if not 0 <= port < 65536:
            raise ConfigError(f"tcp: port must be in 0..65535, got {port}")
        try:
            self._sock = socket.create_server((host, port), backlog=1)
        except OSError as exc:
            raise LinkError(f"tcp {host}:{port}: cannot listen: {exc.strerror or exc}") from None
        self.host: str = self._sock.getsockname()[0]
        self.port: int = self._sock.getsockname()[1]

    @property
    def url(self) -> str:
        """The pyserial URL the host opens to reach this listener."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"socket://{host}:{self.port}"

    def accept(self, timeout_s: float | None = None, *, link_timeout_s: float = DEFAULT_TIMEOUT_S,
               stop_event: threading.Event | None = None) -> Link:
        """The next connection as a Link; LinkTimeout after timeout_s (None: wait for ever),
        LinkClosed when stop_event is set first."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            if stop_event is not None and stop_event.is_set():
                raise LinkClosed(f"tcp {self.host}:{self.port}: stopped before anyone connected")
            wait = None if deadline is None else max(0.0, deadline - time.monotonic())
            if stop_event is not None:
                wait = _STOP_POLL_S if wait is None else min(wait, _STOP_POLL_S)
            self._sock.settimeout(wait)
            try:
                conn, peer = self._sock.accept()
                break
            except (socket.timeout, BlockingIOError):
                if deadline is not None and time.monotonic() >= deadline:
                    raise LinkTimeout(
                        f"tcp {self.host}:{self.port}: nobody connected within {timeout_s * 1000:.0f} ms"  # type: ignore[operator]
                    ) from None
        try:
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError:  # pragma: no cover - not a TCP socket after all
            pass
        name = f"tcp:{peer[0]}:{peer[1]}"
        fd = conn.detach()
        return Link(FdTransport(fd, name), name, timeout_s=link_timeout_s)

    def close(self) -> None:
        self._sock.close()

    def __enter__(self) -> "TcpListener":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def parse_tcp_listen(text: str) -> tuple[str, int]:
    """`tcp:PORT` or `tcp:HOST:PORT` (a far end's --port: where to listen) -> (host, port).

    HOST defaults to 127.0.0.1 (listening on every interface must be asked for: tcp:0.0.0.0:PORT);
    PORT 0 lets the system pick. ConfigError otherwise.
    """
    body = text.strip()
    if not body.startswith("tcp:"):
        raise ConfigError(f"listen spec {text!r}: expected tcp:PORT or tcp:HOST:PORT")
    host, _, port = body[len("tcp:"):].rpartition(":")
    host = host.strip("[]") or "127.0.0.1"
    if not port.isdigit() or not 0 <= int(port) < 65536:
        raise ConfigError(f"listen spec {text!r}: port must be a whole number in 0..65535 (0: any free port)")
    return host, int(port)


def serve_tcp_once(port: int, handler: Callable[[Link], T], *, host: str = "127.0.0.1",
                   accept_timeout_s: float | None = None, link_timeout_s: float = DEFAULT_TIMEOUT_S,
                   announce: Callable[[str], None] | None = None,
                   stop_event: threading.Event | None = None) -> T:
    """Listen on host:port, announce the socket:// URL, accept one connection, stop listening,
    and return handler(link); the link is closed afterwards whatever happens.

    For `serve(target, link)` from hilbench.targets.serve as the handler: it returns when the
    host hangs up.
    """
    with TcpListener(port, host) as listener:
        if announce is not None:
            announce(listener.url)
        link = listener.accept(accept_timeout_s, link_timeout_s=link_timeout_s, stop_event=stop_event)
    with link:
        return handler(link)


__all__ = ["TcpListener", "parse_tcp_listen", "serve_tcp_once"]
