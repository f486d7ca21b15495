"""Run a registered target model as a server on a port: the far end of a virtual serial pair or a tty.

The bench starts emulator processes as ``python -m hilbench.targets.emulator NAME --port PATH
[--mode lockstep|realtime] [--watchdog-ms N] [--options JSON]`` — not through the CLI, so the bench
does not depend on the CLI's flag names. The process prints the path it serves on one line once it
answers, and serves until the host hangs up or it is terminated.
"""

from __future__ import annotations

import argparse
import json
import os
import select
import sys
import threading
import time
from typing import Callable, Mapping

from hilbench.errors import LinkClosed
from hilbench.link import Link, open_link, parse_tcp_listen, serve_tcp_once
from hilbench.link.tcp import TcpListener
from hilbench.processes import watch_parent
from hilbench.targets.registry import get_profile
from hilbench.targets.serve import ServeReport, serve


def serve_on_port(name: str, port_spec: str = "pty", mode: int | None = None,
                  options: Mapping[str, object] | None = None, *, watchdog_ms: int | None = None,
                  announce: Callable[[str], None] | None = None,
                  stop_event: threading.Event | None = None, keep_serving: bool = False) -> ServeReport:
    """Build target `name` and serve it on `port_spec` until the link closes or stop_event is set.

    port_spec "pty" makes a pair and serves on its master; "tcp:PORT" or "tcp:HOST:PORT" listens
    there (port 0: any free one) and serves the first host that connects (with ``keep_serving``:
    one host after another on the same port); any other spec (a tty
    path, serial:..., fd:N, a pyserial URL) is opened as it is. `announce` gets the path the host should open
    (the pty slave, or port_spec itself) once the server is ready to answer. `options` are the
    profile's `[target]` options as plain values. ``keep_serving`` (a pty or a TCP port): serve one
    host after another, as a board does, until stop_event or Ctrl-C — the pty's slave is held open
    here, the TCP port keeps listening, so a host hanging up is not the end.
    """
    profile = get_profile(name)
    target = profile.make(profile.options_from(dict(options or {})))
    if port_spec.startswith("tcp:"):  # a TCP port (socket://HOST:PORT)
        host, port = parse_tcp_listen(port_spec)

        def handler(link: Link) -> ServeReport:
            return serve(target, link, stop_event=stop_event, mode=mode, watchdog_ms=watchdog_ms)

        if not keep_serving:
            return serve_tcp_once(port, handler, host=host, announce=announce, stop_event=stop_event)
        return _serve_tcp_hosts(host, port, handler, announce, stop_event)
    link = open_link(port_spec, timeout_s=1.0)
    held: int | None = None
    try:
        if keep_serving and link.peer_path is not None:
            held = os.open(link.peer_path, os.O_RDWR | os.O_NOCTTY)  # the master never sees a hang-up
        if announce is not None:
            announce(link.peer_path if link.peer_path is not None else port_spec)
        return serve(target, link, stop_event=stop_event, mode=mode, watchdog_ms=watchdog_ms)
    finally:
        link.close()
        if held is not None:
            os.close(held)


#: a TCP client that sends nothing this long after it connected is dropped for the next: a host's
#: HostHello comes at once, and one silent client must not hold the port from the real host
SILENT_CLIENT_S = 3.0
_WATCH_S = 0.1


def _speaks_within(link: Link, stop_event: threading.Event | None, seconds: float) -> bool:
    """Whether the client just accepted sent something within ``seconds`` (False: silent, or
    stop_event set). Looked at before serving, so the serve loop (its C loop with no stop_event)
    is the one every host gets."""
    fd = link.fileno()
    if fd is None:
        return True
    deadline = time.monotonic() + seconds
    while stop_event is None or not stop_event.is_set():
        left = deadline - time.monotonic()
        if left <= 0:
            return False
        ready, _, _ = select.select([fd], [], [], min(left, _WATCH_S))
        if ready:
            return True
    return False


def _serve_tcp_hosts(host: str, port: int, handler: Callable[[Link], ServeReport],
                     announce: Callable[[str], None] | None, stop_event: threading.Event | None) -> ServeReport:
    """One host after another on one listening port, as a board serves whoever opens its port
    next, until stop_event or Ctrl-C (a host hanging up is not the end; a client silent for
    SILENT_CLIENT_S is dropped); the totals of every host."""
    total = ServeReport(reason="stopped")
    with TcpListener(port, host) as listener:
        if announce is not None:
            announce(listener.url)
        while stop_event is None or not stop_event.is_set():
            try:
                link = listener.accept(stop_event=stop_event)
            except LinkClosed:
                break
            with link:
                if not _speaks_within(link, stop_event, SILENT_CLIENT_S):
                    if stop_event is not None and stop_event.is_set():
                        break
                    print(f"hilbench emulate: {link.name}: said nothing in {SILENT_CLIENT_S:g} s after it connected: "
                          "dropped for the next host", file=sys.stderr, flush=True)
                    continue
                report = handler(link)
            total.sensors += report.sensors
            total.requests += report.requests
            total.error_reports += report.error_reports
            total.watchdog_trips += report.watchdog_trips
            total.handler_faults += report.handler_faults
            total.duplicates += report.duplicates
            total.mode = report.mode
    return total


def main(argv: list[str] | None = None) -> int:
    """The emulator process's entry point (see the module docstring)."""
    from hilbench.errors import HilbenchError

    parser = argparse.ArgumentParser(prog="python -m hilbench.targets.emulator")
    parser.add_argument("name")
    parser.add_argument("--port", default="pty")
    parser.add_argument("--mode", choices=("lockstep", "realtime"), default=None)
    parser.add_argument("--watchdog-ms", type=int, default=None)
    parser.add_argument("--options", default="{}", help="the profile's [target] options as JSON")
    args = parser.parse_args(argv)
    watch_parent()  # the bench that started this process may be killed: then this one ends too
    mode = None if args.mode is None else (0 if args.mode == "lockstep" else 1)
    try:
        options = json.loads(args.options)
        serve_on_port(args.name, args.port, mode, options, watchdog_ms=args.watchdog_ms,
                      announce=lambda path: print(path, flush=True))
    except HilbenchError as exc:
        print(f"emulator {args.name}: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())

__all__ = ["main", "serve_on_port"]
