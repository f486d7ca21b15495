"""The dashboard's command line: type `set kp=0.2`, `ref 1500`, `step 1000 2000`… and Enter.

Typed lines go through the session's own control socket, so they are checked and answered exactly
like `hilbench ctl` from another terminal. The terminal is put in cbreak mode without echo while the
dashboard runs (Ctrl-C still interrupts) and restored on every exit path.
"""

from __future__ import annotations

import os
import select
import sys
import termios
import threading
import tty
from pathlib import Path
from typing import Callable

from hilbench.errors import HilbenchError

PROMPT_HELP = "type: set kp=0.2 | ref 1500 | step 1000 2000 | get | help  (Enter)"
FULL_HELP = ("get | set NAME=V ... | ref RPM | load NM | step FROM TO | save FILE | guard on|off | press s2|s3 | "
             "start | stop")


class CommandLine:
    """A background reader of typed commands for a running session."""

    def __init__(self, socket_path: str | Path, on_message: Callable[[str], None]) -> None:
        self.socket_path = str(socket_path)
        self.on_message = on_message
        self.buffer = ""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._saved: list | None = None
        self._fd = sys.stdin.fileno() if sys.stdin is not None and sys.stdin.isatty() else None

    @property
    def active(self) -> bool:
        return self._fd is not None

    def __enter__(self) -> "CommandLine":
        if self._fd is not None:
            self._saved = termios.tcgetattr(self._fd)
            tty.setcbreak(self._fd)
            attrs = termios.tcgetattr(self._fd)
            attrs[3] &= ~termios.ECHO
            termios.tcsetattr(self._fd, termios.TCSANOW, attrs)
            self._thread = threading.Thread(target=self._read, name="hilbench-keys", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        if self._fd is not None and self._saved is not None:
            termios.tcsetattr(self._fd, termios.TCSADRAIN, self._saved)

    def _read(self) -> None:
        assert self._fd is not None
        while not self._stop.is_set():
            ready, _, _ = select.select([self._fd], [], [], 0.1)
            if not ready:
                continue
            try:
                chunk = os.read(self._fd, 64).decode(errors="ignore")
            except OSError:
                return
            for char in chunk:
                if char in "\r\n":
                    line, self.buffer = self.buffer.strip(), ""
                    if line:
                        self.on_message(self.execute(line))
                elif char in "\x7f\b":
                    self.buffer = self.buffer[:-1]
                elif char == "\x1b":
                    self.buffer = ""
                elif char.isprintable() and len(self.buffer) < 120:
                    self.buffer += char

    def execute(self, line: str) -> str:
        """Send one typed command; returns the one-line answer to show."""
        from hilbench.bench.control import ControlClient, parse_ctl_args

        if line.split()[:1] == ["help"]:
            return f"> help: {FULL_HELP}"
        try:
            request = parse_ctl_args(line.split())
            if request["cmd"] == "save":
                from hilbench.bench.tuning import saved_fragment, write_fragment

                reply = ControlClient(self.socket_path, timeout_s=5.0).request({"cmd": "get"}, timeout_s=5.0)
                try:
                    if not reply.get("ok"):
                        return f"> {line}: {reply.get('message', 'refused')}"
                    write_fragment(request["file"], saved_fragment(reply.get("data")),  # (never waiting
                                   reader_wait_s=0.0)  # for a FIFO's reader: the view would stop)
                except OSError as exc:
                    return f"> {line}: save {request['file']}: {exc.strerror or exc}"
                return f"> {line}: saved"
            reply = ControlClient(self.socket_path, timeout_s=5.0).request(request, timeout_s=15.0)
        except (HilbenchError, OSError) as exc:
            return f"> {line}: {exc}"
        if request["cmd"] == "get" and reply.get("ok") and isinstance(reply.get("data"), dict):
            data = reply["data"]
            params = " ".join(f"{k}={v:.5g}" for k, v in dict(data.get("params") or {}).items()
                              if isinstance(v, (int, float)))
            return f"> get: {params}; ref {data.get('ref_rpm', 0):g} rpm at t={data.get('t_s', 0):.3f} s"
        return f"> {line}: {'ok' if reply.get('ok') else 'refused'}: {reply.get('message', '')}"
