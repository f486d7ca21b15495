"""Turn a target spec into a connected Target, and always clean up what was started.

Specs (NAME is any registered target, see `hilbench.targets.known_targets()`):

* ``emulator:NAME`` — the target's model as its own process (``python -m
  hilbench.targets.emulator NAME --port PTY``) on a virtual serial pair made here;
* ``inprocess:NAME`` — the same model stepped in this process (fast, for tests and sweeps);
* ``sil:NAME``, ``simavr:NAME``, ``qemu:NAME`` — a build of the target's C firmware as a process
  (hilbench.targets.starters); ``sil:PATH`` … — a build of any firmware on the runtime;
* ``serial:/dev/ttyUSB0?baud=250000``, a device path or a pyserial URL (``socket://host:port``,
  ``rfc2217://host:port``, ``loop://``) — a board, or anything that speaks the protocol there.

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
from typing import TYPE_CHECKING, Any, Callable

from hilbench.errors import ConfigError, LinkError
from hilbench.link.spec import FIRMWARE_KINDS
from hilbench.processes import reap, spawn
from hilbench.targets.base import Target
from hilbench.targets.profile import TargetProfile

if TYPE_CHECKING:
    from hilbench.link import Link
    from hilbench.link.spec import TargetSpec
    from hilbench.targets.remote import RemoteTarget
    from hilbench.targets.starters import FirmwareStarter, Started



@dataclass
class TargetHandle:
    """A connected target plus what must be closed when the run ends."""

    target: Target
    label: str
    link: "Link | None" = None
    process: subprocess.Popen[bytes] | None = None
    child_log: Any = None
    started: "Started | None" = None  # a firmware build's process (sil:, simavr:, qemu:)
    _closers: list[Callable[[], None]] = field(default_factory=list)

    def link_stats(self) -> dict[str, int]:
        """The link's counters as plain ints, with the host's retries (empty for an in-process target)."""
        if self.link is None:
            return {}
        stats = self.link.stats.as_dict()
        stats["retries"] = int(getattr(self.target, "retries", 0))
        link = getattr(self.link, "inner", self.link)  # under a fault injector, the link it wraps
        overrun = getattr(getattr(link, "transport", None), "rx_overrun_bytes", None)
        if overrun is not None:  # a wire throttle (?wire_baud=): what a far end far ahead of it lost
            stats["wire_rx_overrun_bytes"] = int(overrun)
        speculation = getattr(self.target, "speculation_stats", None)
        if speculation is not None:  # twin-speculative lockstep (hilbench.bench.speculative)
            stats.update(speculation())
        return stats

    def child_status(self) -> str:
        """How the emulator or firmware process is doing, for error lines."""
        if self.started is not None:
            return self.started.exit_note()
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


def open_target(
    spec: str,
    *,
    profile: TargetProfile | None = None,
    options: object | None = None,
    mode: str = "lockstep",
    timeout_s: float = 0.5,
    watchdog_ms: int | None = 100,
    retry_s: float = 0.1,
) -> TargetHandle:
    """Connect to the target named by ``spec`` (the link layer's one grammar, see
    `hilbench.link.describe_spec_forms`); ``profile`` and its ``options`` build an in-process model
    or an emulator process. Fault-injection keys in the spec's query wrap the link."""
    from hilbench.link import open_link, parse_target_spec
    from hilbench.targets.registry import get_profile
    from hilbench.targets.remote import RemoteTarget

    parsed = parse_target_spec(spec)
    if parsed.kind in FIRMWARE_KINDS:
        return _start_firmware(parsed, profile, options, timeout_s, retry_s)
    if parsed.kind in ("inprocess", "emulator"):
        profile = profile if profile is not None and profile.name == parsed.name else get_profile(parsed.name)
        options = profile.default_options() if options is None else options
        if parsed.kind == "inprocess":
            return TargetHandle(profile.make(options), label=spec)  # type: ignore[arg-type]
        link = open_link(parsed, timeout_s=timeout_s)  # a pty pair made here (with the spec's faults)
        remote = RemoteTarget(link, timeout_s=timeout_s, retry_s=min(retry_s, timeout_s))
        return _spawn_emulator(profile, options, mode, watchdog_ms, remote)
    if parsed.kind == "port":
        link = open_link(parsed, timeout_s=timeout_s)
        return TargetHandle(RemoteTarget(link, timeout_s=timeout_s, retry_s=min(retry_s, timeout_s)), label=spec, link=link)
    raise ConfigError(f"target {spec!r}: a {parsed.kind}: target is started by its own tool "
                      "(use emulator:NAME, inprocess:NAME, sil:NAME, simavr:NAME or a port)")


def emulator_command(profile: TargetProfile, options: object, port: str, mode: str, watchdog_ms: int | None) -> list[str]:
    """The emulator process's command line (mode "any" and watchdog_ms None: as each HostHello asks). ``-P``: the working directory is not put on the import
    path, so a folder named like a package there cannot shadow hilbench."""
    import json

    forced = ([] if mode == "any" else ["--mode", mode]) + ([] if watchdog_ms is None else ["--watchdog-ms", str(watchdog_ms)])
    return [
        sys.executable, "-P", "-m", profile.emulator_module, profile.name, "--port", port, *forced,
        "--options", json.dumps(profile.options_as_dict(options)),
    ]


def _spawn_emulator(profile: TargetProfile, options: object, mode: str, watchdog_ms: int | None,
                    remote: "RemoteTarget") -> TargetHandle:
    """The target's model as its own process, serving the far end of the remote's pty."""
    link = remote.link
    command = emulator_command(profile, options, link.peer_path, mode, watchdog_ms)
    log = tempfile.TemporaryFile()  # the child's stderr: a file never fills up and blocks it
    try:
        process = spawn(  # it dies with this process, whatever kills it (hilbench.processes)
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
        raise LinkError(f"emulator {profile.name}: cannot start ({exc.strerror})") from None
    label = f"emulator:{profile.name} on {link.peer_path} (pid {process.pid})"
    handle = TargetHandle(remote, label=label, link=link, process=process)
    handle._closers.append(log.close)
    handle.child_log = log
    try:
        _wait_ready(process, label, log)
    except BaseException:
        handle.close()
        raise
    return handle


def _starter(parsed: "TargetSpec", profile: TargetProfile | None) -> tuple["FirmwareStarter", object | None, str]:
    """The starter a firmware spec names: a registered target's build, or a build at a path."""
    from hilbench.targets.registry import get_profile
    from hilbench.targets.starters import PATH_STARTERS, starter_for

    if parsed.program:
        make = PATH_STARTERS.get(parsed.kind)
        if make is None:
            raise ConfigError(f"target {parsed.text!r}: {parsed.kind}:PATH is not available in this hilbench")
        return make(parsed.program), None, parsed.program
    profile = profile if profile is not None and profile.name == parsed.name else get_profile(parsed.name)
    starters = dict(profile.starters)
    if "sil" not in starters and profile.start_sil is not None:  # the older single-function form
        start_sil = profile.start_sil
        starters["sil"] = _LegacySil(start_sil, profile.name)  # type: ignore[assignment]
    return starter_for(parsed.kind, starters, profile.name), profile, profile.name


@dataclass(frozen=True)
class _LegacySil:
    """A profile's start_sil (options, tty) -> process, as a starter."""

    start_sil: Callable[[object, str], subprocess.Popen[bytes]]
    name: str
    kind: str = "sil"
    serves_host_pty: bool = True

    def start(self, options: object, host_tty: str | None) -> "Started":
        from hilbench.targets.starters import Started

        assert host_tty is not None
        process = self.start_sil(options, host_tty)
        return Started(process, host_tty, f"sil:{self.name} on {host_tty} (pid {process.pid})")


def _start_firmware(parsed: "TargetSpec", profile: TargetProfile | None, options: object | None,
                    timeout_s: float, retry_s: float) -> TargetHandle:
    """A build of a firmware as its own process (built first if needed), on a pty: the host's pty
    pair's slave, or the pty the process made. The spec's faults wrap the link either way."""
    from hilbench.link import open_link
    from hilbench.link.ports import apply_link_options
    from hilbench.targets.remote import RemoteTarget

    starter, profile, name = _starter(parsed, profile)
    if profile is not None:
        options = profile.default_options() if options is None else options
    if starter.serves_host_pty:
        link = open_link(parsed, timeout_s=timeout_s)
        try:
            started = starter.start(options, link.peer_path)
        except BaseException:
            link.close()
            raise
    else:
        started = starter.start(options, None)
        try:
            link = apply_link_options(open_link(started.tty_path, timeout_s=timeout_s), parsed)
        except BaseException:
            started.close()
            raise
    label = f"{parsed.kind}:{name} on {started.tty_path} (pid {started.process.pid})"
    remote = RemoteTarget(link, timeout_s=timeout_s, retry_s=min(retry_s, timeout_s))
    handle = TargetHandle(remote, label=label, link=link)
    handle._closers.append(started.close)  # reaps the process after the link is closed
    handle.started = started
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
