"""Starting a scope from the command line: for a run, for a running session, for a recording."""

from __future__ import annotations

import os
from pathlib import Path

from hilbench.errors import ConfigError


def _server_class():  # type: ignore[no-untyped-def]
    try:
        import aiohttp  # noqa: F401

        from hilbench.scope.server import ScopeServer
    except ImportError as exc:  # aiohttp is the extra's dependency
        raise ConfigError(f"scope: needs the scope extra (pip install 'hilbench[scope]'): {exc}") from None
    return ScopeServer


def start_scope(source: object, port: int = 0, open_browser: bool = False) -> "object":
    """Serve ``source`` on 127.0.0.1 in a thread; print the URL (and open it when asked)."""
    import click

    server = _server_class()(source, port=port).start()  # type: ignore[arg-type]
    click.echo(f"scope: {server.url}  (127.0.0.1 only; over SSH: ssh -L {server.port}:127.0.0.1:{server.port} HOST)",
               err=True)
    if open_browser:
        from hilbench.scope.server import open_in_browser

        open_in_browser(server)  # a one-shot URL: no token file left behind
    return server


def check_session_socket(socket_path: str | os.PathLike[str], timeout_s: float = 5.0) -> None:
    """A session listens at ``socket_path`` and is this user's (LinkError in one line otherwise):
    `hilbench scope --socket /nonexistent.sock` fails at once instead of serving nothing."""
    from hilbench.bench.control import ControlClient

    ControlClient(socket_path, timeout_s=timeout_s).close()


def scope_for_socket(socket_path: str | os.PathLike[str], port: int = 0, open_browser: bool = False) -> "object":
    from hilbench.scope.server import ControlSource

    check_session_socket(socket_path)
    return start_scope(ControlSource(Path(socket_path)), port, open_browser)


def scope_for_recording(path: str | os.PathLike[str], port: int = 0, open_browser: bool = False) -> "object":
    from hilbench.scope.server import RecordingSource

    return start_scope(RecordingSource(path), port, open_browser)


class ScopeProcess:
    """`hilbench scope --socket PATH` as a child process (what `run --scope` starts): the page's
    server and its JSON work then never take the session's interpreter lock, which matters in real
    time. It is started with ``python -P`` (a `hilbench/` folder in the working directory cannot
    shadow the package) and dies with its parent (hilbench.processes). Of its stderr only its own
    one-line messages reach the session's terminal (the URL, "scope: ..." and "hilbench: ..."
    lines); anything else (a traceback) is counted in `hidden_lines`, never shown under the run.
    `close()` stops it."""

    def __init__(self, socket_path: str | os.PathLike[str], port: int = 0, open_browser: bool = False,
                 timeout_s: float = 30.0) -> None:
        import subprocess
        import sys
        import threading

        from hilbench.processes import spawn

        command = [sys.executable, "-P", "-m", "hilbench", "scope", "--socket", str(socket_path), "--port", str(port)]
        if open_browser:
            command.append("--open")
        self.url = ""
        self.hidden_lines = 0
        self.last_hidden = ""
        self._found = threading.Event()
        self.proc = spawn(command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                          text=True, errors="replace")
        self._reader = threading.Thread(target=self._read, name="hilbench-scope-stderr", daemon=True)
        self._reader.start()
        if not self._found.wait(timeout_s) or not self.url:
            self.close()
            why = f": {self.last_hidden}" if self.last_hidden else ""
            raise ConfigError(f"scope: `hilbench scope` printed no URL within {timeout_s:g} s{why}")

    def _read(self) -> None:
        import re
        import sys

        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            if line.startswith(("scope: ", "hilbench: ")) and len(line) <= 400:
                sys.stderr.write(line)
            else:
                self.hidden_lines += 1
                if line.strip():
                    self.last_hidden = line.strip()[:160]
            match = re.search(r"scope: (http://\S+)", line)
            if match and not self.url:
                self.url = match.group(1)
                self._found.set()
        self._found.set()  # the child ended (with or without its URL)

    def close(self, grace_s: float = 0.0) -> None:
        """Stop it; with ``grace_s``, first let it end by itself (after the session's control socket
        closed it relays the replies on their way, closes its pages and exits)."""
        import subprocess

        from hilbench.processes import reap

        if grace_s > 0:
            try:
                self.proc.wait(grace_s)
            except subprocess.TimeoutExpired:
                pass
        reap(self.proc, 5.0)
        self._reader.join(5)
        if self.proc.stderr is not None:
            self.proc.stderr.close()


__all__ = ["ScopeProcess", "check_session_socket", "scope_for_recording", "scope_for_socket", "start_scope"]
