"""A test helper: a target served over TCP by this process (hilbench.link.tcp.serve_tcp_once in a
thread), for tests that reach it through socket:// from this process or from a CLI process."""

from __future__ import annotations

import queue
import threading
from typing import Any, Callable

from hilbench.link import serve_tcp_once
from hilbench.targets import make_target
from hilbench.targets.serve import serve


class ServedInThread:
    """serve_tcp_once(0, serve(target)) in a thread; .url once it listens; joined on close."""

    def __init__(self, target_name: str = "an1017", make_link: Callable[[Any], Any] | None = None) -> None:
        self.urls: queue.Queue[str] = queue.Queue()
        self.stop = threading.Event()
        self.error: BaseException | None = None
        self.report: Any = None
        target = make_target(target_name)

        def handler(link: Any) -> Any:
            return serve(target, link if make_link is None else make_link(link), stop_event=self.stop)

        def run() -> None:
            try:
                self.report = serve_tcp_once(0, handler, accept_timeout_s=20.0, announce=self.urls.put,
                                             stop_event=self.stop)
            except BaseException as exc:  # noqa: BLE001 - reported by close()
                self.error = exc

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()
        self.url = self.urls.get(timeout=10)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=10)
        assert not self.thread.is_alive(), "the TCP server thread did not stop"
