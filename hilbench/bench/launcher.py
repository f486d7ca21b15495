"""Turn a target spec into a connected Target, and always clean up what was started.

Specs:

* ``emulator:an1017`` (default), ``emulator:loopback`` — the firmware model as its own process
  (``python -m hilbench emulate NAME --port PTY``) on a virtual serial pair made here;
* ``inprocess:an1017`` — the same model stepped in this process (fast, for tests and sweeps);
* ``serial:/dev/ttyUSB0?baud=250000`` or a device path — a real board.

The session sees only the Target interface; this module owns the link and the child process and
reaps the child on every exit path.
"""

from __future__ import annotations

import os
import select
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from typing import Any, Callable

from hilbench.errors import ConfigError, LinkError

EMULATOR_PREFIX = "emulator:"
INPROCESS_PREFIX = "inprocess:"


@dataclass
class TargetHandle:
    """A connected target plus what must be closed when the run ends."""

    target: Any
    label: str
    link: Any = None
    process: subprocess.Popen[bytes] | None = None
    child_log: Any = None
    _closers: list[Callable[[], None]] = field(default_factory=list)

    def link_stats(self) -> dict[str, int]:
        """The link's counters as plain ints (empty for an in-process target)."""
        return {} if self.link is None else self.link.stats.as_dict()

    def child_status(self) -> str:
        """How the emulator process is doing, for error lines."""
        if self.process is None:
            return ""
        code = self.process.poll()
        return "" if code is None else f" (emulator process exited with code {code})"

    def close(self) -> None:
        """Stop the target if it still answers, close the link, reap the child."""
        try:
            if self.link is not None:
                self.link.close()
        except Exception:  # noqa: BLE001 - cleanup must not mask the run's own error
            pass
        if self.process is not None:
            reap(self.process)
            if self.process.stdout is not None:
                self.process.stdout.close()
        for closer in self._closers:
            closer()

    def __enter__(self) -> "TargetHandle":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def reap(process: subprocess.Popen[bytes], timeout_s: float = 3.0) -> int:
    """Terminate a child and wait for it; kill it if it will not go."""
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=timeout_s)
    return process.returncode


def open_target(
    spec: str,
    *,
    mode: str = "lockstep",
    timeout_s: float = 0.5,
    watchdog_ms: int = 100,
    emulator_args: tuple[str, ...] = (),
    target_options: dict[str, Any] | None = None,
) -> TargetHandle:
    """Connect to the target named by ``spec`` (see the module docstring)."""
    from hilbench.targets import make_target

    if spec.startswith(INPROCESS_PREFIX):
        name = spec[len(INPROCESS_PREFIX):]
        return TargetHandle(make_target(name, **(target_options or {})), label=spec)
    if spec.startswith(EMULATOR_PREFIX):
        return _spawn_emulator(spec[len(EMULATOR_PREFIX):], mode, timeout_s, watchdog_ms, emulator_args)
    if spec.startswith(("serial:", "/dev/", "loop://", "fd:")):
        from hilbench.link import open_link
        from hilbench.targets.remote import RemoteTarget

        link = open_link(spec, timeout_s=timeout_s)
        return TargetHandle(RemoteTarget(link, timeout_s=timeout_s), label=spec, link=link)
    raise ConfigError(
        f"target {spec!r}: unknown target spec (use emulator:an1017, emulator:loopback, "
        "inprocess:an1017, serial:/dev/ttyUSB0?baud=250000 or a device path)"
    )


def _spawn_emulator(name: str, mode: str, timeout_s: float, watchdog_ms: int, extra: tuple[str, ...]) -> TargetHandle:
    from hilbench.link import open_link
    from hilbench.targets import make_target
    from hilbench.targets.remote import RemoteTarget

    make_target(name)  # an unknown name fails here, before any process starts
    link = open_link("pty", timeout_s=timeout_s)
    command = [
        sys.executable, "-m", "hilbench", "emulate", name,
        "--port", link.peer_path, "--mode", mode, "--watchdog-ms", str(watchdog_ms), *extra,
    ]
    log = tempfile.TemporaryFile()  # the child's stderr: a file never fills up and blocks it
    try:
        process = subprocess.Popen(
            command,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=log,
            env=dict(os.environ, PYTHONUNBUFFERED="1"),
            start_new_session=True,  # Ctrl-C reaches the session, which stops and reaps the child
        )
    except OSError as exc:
        link.close()
        log.close()
        raise LinkError(f"emulator {name}: cannot start ({exc.strerror})") from None
    label = f"emulator:{name} on {link.peer_path} (pid {process.pid})"
    handle = TargetHandle(RemoteTarget(link, timeout_s=timeout_s), label=label, link=link, process=process)
    handle._closers.append(log.close)
    handle.child_log = log
    try:
        _wait_ready(process, label, log)
    except BaseException:
        handle.close()
        raise
    return handle


def _wait_ready(process: subprocess.Popen[bytes], label: str, log: Any, timeout_s: float = 20.0) -> None:
    """The emulator prints the port path once it listens; bytes sent before that could be lost."""
    assert process.stdout is not None
    ready, _, _ = select.select([process.stdout], [], [], timeout_s)
    line = process.stdout.readline() if ready else b""
    if not line:
        process.poll()
        log.seek(0)
        tail = log.read().decode(errors="replace").strip().splitlines()[-1:] or ["no output"]
        code = process.returncode
        state = f"exited with code {code}" if code is not None else f"not ready after {timeout_s:.0f} s"
        raise LinkError(f"{label}: emulator {state}: {tail[0]}")
