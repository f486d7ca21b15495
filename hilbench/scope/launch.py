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

        open_in_browser(server.url)
    return server


def scope_for_socket(socket_path: str | os.PathLike[str], port: int = 0, open_browser: bool = False) -> "object":
    from hilbench.scope.server import ControlSource

    return start_scope(ControlSource(Path(socket_path)), port, open_browser)


def scope_for_recording(path: str | os.PathLike[str], port: int = 0, open_browser: bool = False) -> "object":
    from hilbench.scope.server import RecordingSource

    return start_scope(RecordingSource(path), port, open_browser)




class ScopeProcess:
    """`hilbench scope --socket PATH` as a child process (what `run --scope` starts): the page's
    server and its JSON work then never take the session's interpreter lock, which matters in real
    time. Its URL line is passed on to stderr; `close()` stops it (and it dies with its parent)."""

    def __init__(self, socket_path: str | os.PathLike[str], port: int = 0, open_browser: bool = False,
                 timeout_s: float = 30.0) -> None:
        import subprocess
        import sys
        import threading

        command = [sys.executable, "-m", "hilbench", "scope", "--socket", str(socket_path), "--port", str(port)]
        if open_browser:
            command.append("--open")
        self.url = ""
        self._found = threading.Event()
        self.proc = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.PIPE, text=True, preexec_fn=_die_with_parent)
        self._reader = threading.Thread(target=self._read, name="hilbench-scope-stderr", daemon=True)
        self._reader.start()
        if not self._found.wait(timeout_s) or not self.url:
            self.close()
            raise ConfigError(f"scope: `hilbench scope` printed no URL within {timeout_s:g} s")

    def _read(self) -> None:
        import re
        import sys

        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            sys.stderr.write(line)
            match = re.search(r"scope: (http://\S+)", line)
            if match and not self.url:
                self.url = match.group(1)
                self._found.set()
        self._found.set()  # the child ended (with or without its URL)

    def close(self) -> None:
        import subprocess

        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self._reader.join(5)


def _die_with_parent() -> None:
    """In the child, before exec: SIGTERM when the parent dies (Linux prctl PR_SET_PDEATHSIG)."""
    try:
        import ctypes
        import signal

        ctypes.CDLL(None).prctl(1, int(signal.SIGTERM), 0, 0, 0)
    except (OSError, AttributeError):
        pass


__all__ = ["ScopeProcess", "scope_for_recording", "scope_for_socket", "start_scope"]
