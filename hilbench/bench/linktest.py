"""The link test: N lockstep periods against a target, timing every round trip and counting errors.

Default target: the registry's link-test target (`targets.registry.LINK_TEST_TARGET`) as its own
process (`python -m hilbench emulate NAME`) on a pty pair this process makes. Against a target
whose profile declares "link_check" (every Drive a documented function of the Sensors alone) every
Drive is checked field by field against its in-process model, so a corrupted frame accepted as
good shows up as a mismatch.
"""

from __future__ import annotations

import math
import os
import select
import subprocess
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from hilbench.errors import ConfigError, LinkError, LinkTimeout
from hilbench.link import FaultyLink, Link, open_link, parse_target_spec
from hilbench.processes import spawn
from hilbench.protocol import INPUT_S3, MODE_LOCKSTEP, Sensors
from hilbench.targets.base import Target
from hilbench.targets.registry import LINK_TEST_TARGET, profile_for_firmware
from hilbench.targets.remote import RemoteTarget

DEFAULT_TARGET = "pty"
_READY_TIMEOUT_S = 15.0
_MAX_CONSECUTIVE_TIMEOUTS = 20
#: how long link-test keeps sending HostHello at least, whatever --timeout-ms says
HANDSHAKE_S = 5.0


@dataclass(frozen=True)
class LinkTestResult:
    """Round-trip figures and every error counter of one link test."""

    target: str
    firmware_name: str
    periods: int
    good: int
    timeouts: int
    mismatches: int
    elapsed_s: float
    round_trips_per_s: float
    rtt_p50_us: float
    rtt_p99_us: float
    rtt_max_us: float
    link: dict[str, int] = field(default_factory=dict)
    remote: dict[str, int] = field(default_factory=dict)
    target_status: dict[str, int] = field(default_factory=dict)
    #: Ctrl-C ended the test early: the figures are those of the periods run (``attempted``)
    interrupted: bool = False
    attempted: int = 0

    @property
    def errors(self) -> int:
        """Everything that went wrong, host side and target side."""
        return (self.timeouts + self.mismatches + self.link.get("frame_errors", 0) + self.link.get("seq_gaps", 0)
                + self.remote.get("stale_frames", 0) + self.target_status.get("rx_errors", 0))

    @property
    def failure(self) -> str | None:
        """Why the test failed (periods without a Drive, Drives the model disagrees with), or None.

        Frame errors a retry recovered are counted, not a failure: the link delivered every period."""
        if self.interrupted:
            return None
        lost = self.periods - self.good
        problems = []
        if lost:
            problems.append(f"{lost} of {self.periods} periods got no Drive (the target went silent or the link "
                            "lost them)")
        if self.mismatches:
            problems.append(f"{self.mismatches} Drives differ from the {self.firmware_name} model")
        return f"link-test {self.target}: " + "; ".join(problems) if problems else None


def sensors_for_period(k: int) -> Sensors:
    """A deterministic Sensors that exercises every field (never S2, so no start/stop toggling):
    none, one or two edges."""
    halls = (1, 3, 2, 6, 4, 5, 0, 7)[k & 7]
    inputs = halls | (INPUT_S3 if (k >> 3) & 1 else 0)
    edges = (((k * 37) % 500, halls), ((k * 37) % 500 + 100, halls))[: k % 3]
    return Sensors(k & 0xFF, inputs, edges, (k * 911) & 0xFFFF, (k & 0x3FF, (k * 7) & 0x3FF, 1023 - (k & 0x3FF)))


class _Spawned:
    """A target process serving the far end of a pty pair this process made; always reaped.

    `python -m hilbench emulate NAME --port PATH` announces readiness on stdout; a program
    (exec:PROGRAM, e.g. the C loopback target) gets the path as its argument and is given time
    by the handshake's retries instead. `emulate_args` are further `emulate` options
    (e.g. `--mode realtime`).
    """

    def __init__(self, target_name: str, timeout_s: float, program: str | None = None,
                 emulate_args: Sequence[str] = ()) -> None:
        self.link = open_link("pty", timeout_s=timeout_s)
        self.proc: subprocess.Popen[bytes] | None = None
        try:
            if program is None:
                argv = [sys.executable, "-P", "-m", "hilbench", "emulate", target_name, "-q",
                        "--port", str(self.link.peer_path), *emulate_args]
            else:
                argv = [program, str(self.link.peer_path)]
            try:
                self.proc = spawn(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL)
            except OSError as exc:  # exec:PATH with nothing runnable there: as `sil:PATH` says it
                what = f"exec:{program}: no program to run there" if program is not None else \
                    f"link {self.link.name}: cannot start the {target_name} emulator"
                raise ConfigError(f"{what} ({exc.strerror or exc})") from None
            if program is None:
                self._wait_ready()
        except BaseException:
            self.close()
            raise

    def _wait_ready(self) -> None:
        """The emulator prints the path once it has the tty open; only then may we speak."""
        assert self.proc is not None and self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        deadline = time.monotonic() + _READY_TIMEOUT_S
        line = b""
        while not line.endswith(b"\n"):
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise LinkError(f"link {self.link.name}: emulator did not start within {_READY_TIMEOUT_S:.0f} s")
            ready, _, _ = select.select([fd], [], [], remaining)
            if not ready:
                continue
            chunk = os.read(fd, 4096)
            if not chunk:
                err = self._stderr_tail()
                raise LinkError(f"link {self.link.name}: emulator exited before it was ready: {err}")
            line += chunk

    def _stderr_tail(self) -> str:
        if self.proc is None or self.proc.stderr is None:
            return ""
        try:
            self.proc.wait(timeout=5)
            text = self.proc.stderr.read().decode(errors="replace").strip().splitlines()
        except Exception:  # noqa: BLE001 - best effort for an error message
            return "(no message)"
        return text[-1] if text else f"exit code {self.proc.returncode}"

    def close(self) -> None:
        self.link.close()
        proc = self.proc
        if proc is None:
            return
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        finally:
            for stream in (proc.stdout, proc.stderr):
                if stream is not None:
                    stream.close()


def _checker(firmware_name: str) -> Target | None:
    """The in-process model every Drive of this firmware is checked against (None: not checked)."""
    profile = profile_for_firmware(firmware_name)
    return profile.make(profile.default_options()) if profile.has("link_check") else None


def run_link_test(target: str = DEFAULT_TARGET, *, periods: int = 10_000, period_us: int = 50,
                  timeout_s: float = 1.0, progress: Callable[[int], None] | None = None,
                  link_wrapper: Callable[[Link], Link | FaultyLink] | None = None) -> LinkTestResult:
    """Run `periods` lockstep exchanges against target: a link spec, "pty" (spawn the link-test
    target's emulator on a pty pair), "exec:PROGRAM" (spawn PROGRAM with the pty path), or
    emulator:NAME / sil:NAME (started as `hilbench run` starts them; an unknown NAME is the same
    "unknown target" ConfigError).

    link_wrapper (for example a FaultyLink factory) wraps the host's link before use.
    """
    if periods <= 0:
        raise LinkError(f"link-test: periods must be positive, got {periods}")
    spawned, link = _open(target, timeout_s)
    try:
        remote = RemoteTarget(link_wrapper(link) if link_wrapper is not None else link, timeout_s=timeout_s)
        # a short per-exchange deadline must not make the handshake fragile (a target still starting,
        # a loaded machine): HostHello is sent again for HANDSHAKE_S at least
        hello = remote.handshake(period_us, MODE_LOCKSTEP, 0, attempts=max(5, math.ceil(HANDSHAKE_S / timeout_s)))
        run = _exchanges(remote, link.name, periods, _checker(hello.firmware_name), progress)
        rtt_us = run.rtt_ns[:run.good] / 1000.0
        good = run.good
        return LinkTestResult(
            target=target if spawned is None else f"{target} process on {link.name}",
            firmware_name=hello.firmware_name, periods=periods, good=good, timeouts=run.timeouts,
            mismatches=run.mismatches, elapsed_s=run.elapsed_s,
            round_trips_per_s=good / run.elapsed_s if run.elapsed_s > 0 else 0.0,
            rtt_p50_us=float(np.percentile(rtt_us, 50)) if good else float("nan"),
            rtt_p99_us=float(np.percentile(rtt_us, 99)) if good else float("nan"),
            rtt_max_us=float(rtt_us.max()) if good else float("nan"),
            link=link.stats.as_dict(),
            remote={"stale_frames": remote.stale_frames, "error_reports": remote.error_reports},
            target_status=_status(remote, run.interrupted), interrupted=run.interrupted, attempted=run.attempted,
        )
    finally:
        if spawned is not None:
            spawned.close()
        else:
            link.close()


def _open(target: str, timeout_s: float) -> tuple[Any, Any]:
    """The link to the target: a process this spawns on a pty pair, or the spec opened."""
    if target in ("pty", LINK_TEST_TARGET):
        spawned = _Spawned(LINK_TEST_TARGET, timeout_s)
        return spawned, spawned.link
    if target.startswith("exec:"):
        spawned = _Spawned("", timeout_s, program=target[len("exec:"):])
        return spawned, spawned.link
    if parse_target_spec(target).spawns_process:  # emulator:NAME, sil:NAME: started as the bench starts them
        from hilbench.bench.launcher import open_target

        handle = open_target(target, mode="lockstep", timeout_s=timeout_s)  # unknown NAME: ConfigError, exit 2
        return handle, handle.link
    return None, open_link(target, timeout_s=timeout_s)


@dataclass
class _Run:
    """What the exchanges measured."""

    rtt_ns: np.ndarray
    good: int = 0
    timeouts: int = 0
    mismatches: int = 0
    elapsed_s: float = 0.0
    interrupted: bool = False
    attempted: int = 0


def _exchanges(remote: RemoteTarget, link_name: str, periods: int, check: Target | None,
               progress: Callable[[int], None] | None) -> _Run:
    """The lockstep periods, each round trip timed; Ctrl-C keeps the figures so far (issue 16, item 18)."""
    run = _Run(np.zeros(periods, dtype=np.int64))
    step, clock = remote.step, time.perf_counter_ns
    every = max(1, periods // 100)
    consecutive = 0
    t_start = clock()
    run.attempted = periods
    for k in range(periods):
        sensors = sensors_for_period(k)
        t0 = clock()
        try:
            drive = step(sensors)
        except KeyboardInterrupt:
            run.interrupted, run.attempted = True, k
            break
        except LinkTimeout:
            run.timeouts += 1
            consecutive += 1
            if consecutive >= _MAX_CONSECUTIVE_TIMEOUTS:
                raise LinkError(f"link {link_name}: {consecutive} periods in a row without a Drive (period {k})") from None
            continue
        run.rtt_ns[run.good] = clock() - t0
        run.good += 1
        consecutive = 0
        if check is not None and drive != check.step(sensors):
            run.mismatches += 1
        if progress is not None and k % every == 0:
            progress(k)
    run.elapsed_s = (clock() - t_start) / 1e9
    return run


def _status(remote: RemoteTarget, interrupted: bool) -> dict[str, int]:
    """The target's Status counters (none after an interrupt, or when it does not answer)."""
    if interrupted:
        return {}
    try:
        st = remote.status()
    except LinkError:
        return {}
    return {name: int(getattr(st, name)) for name in st._fields if name != "seq"}


__all__ = ["LinkTestResult", "run_link_test", "sensors_for_period"]
