"""Starting a scope from the command line: for a run, for a running session, for a recording."""

from __future__ import annotations

import os
from pathlib import Path

from hilbench.errors import ConfigError


def _server_class():  # type: ignore[no-untyped-def]
    try:
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


__all__ = ["scope_for_recording", "scope_for_socket", "start_scope"]
