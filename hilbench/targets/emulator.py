"""Run a named target model as a server on a port: the far end of a virtual serial pair or a tty."""

from __future__ import annotations

import threading
from typing import Any, Callable, Mapping

from hilbench.link import open_link
from hilbench.targets import make_target
from hilbench.targets.serve import ServeReport, serve


def serve_on_port(name: str, port_spec: str = "pty", mode: int | None = None,
                  options: Mapping[str, Any] | None = None, *, watchdog_ms: int | None = None,
                  announce: Callable[[str], None] | None = None,
                  stop_event: threading.Event | None = None) -> ServeReport:
    """Build target `name` and serve it on `port_spec` until the link closes or stop_event is set.

    port_spec "pty" makes a pair and serves on its master; any other spec (a tty path,
    serial:..., fd:N) is opened as it is. `announce` gets the path the host should open
    (the pty slave, or port_spec itself) once the server is ready to answer.
    """
    target = make_target(name, **dict(options or {}))
    link = open_link(port_spec, timeout_s=1.0)
    try:
        if announce is not None:
            announce(link.peer_path if link.peer_path is not None else port_spec)
        return serve(target, link, stop_event=stop_event, mode=mode, watchdog_ms=watchdog_ms)
    finally:
        link.close()


__all__ = ["serve_on_port"]
