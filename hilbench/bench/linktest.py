"""The link test: N lockstep periods against a target, timing every round trip and counting errors.

Default target: the Python loopback target as its own process (`python -m hilbench emulate
loopback`) on a pty pair this process makes. Against a loopback target every Drive is checked
field by field against the documented mapping, so a corrupted frame accepted as good shows up
as a mismatch.
"""

from __future__ import annotations

import os
import select
import subprocess
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from hilbench.errors import LinkError, LinkTimeout
from hilbench.link import open_link
from hilbench.protocol import INPUT_S3, MODE_LOCKSTEP, Sensors
from hilbench.targets.loopback.target import LoopbackTarget
from hilbench.targets.remote import RemoteTarget

DEFAULT_TARGET = "pty"
_READY_TIMEOUT_S = 15.0
_MAX_CONSECUTIVE_TIMEOUTS = 20


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
                argv = [sys.executable, "-m", "hilbench", "emulate", target_name, "-q",
                        "--port", str(self.link.peer_path), *emulate_args]
            else:
                argv = [program, str(self.link.peer_path)]
            self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                         stdin=subprocess.DEVNULL)
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


def run_link_test(target: str = DEFAULT_TARGET, *, periods: int = 10_000, period_us: int = 50,
                  timeout_s: float = 1.0, progress: Callable[[int], None] | None = None,
                  link_wrapper: Callable[[Any], Any] | None = None) -> LinkTestResult:
    """Run `periods` lockstep exchanges against target: a link spec, "pty" (spawn the Python
    loopback emulator on a pty pair) or "exec:PROGRAM" (spawn PROGRAM with the pty path).

    link_wrapper (for example a FaultyLink factory) wraps the host's link before use.
    """
    if periods <= 0:
        raise LinkError(f"link-test: periods must be positive, got {periods}")
    spawned: _Spawned | None = None
    if target in ("pty", "loopback"):
        spawned = _Spawned("loopback", timeout_s)
        link = spawned.link
    elif target.startswith("exec:"):
        spawned = _Spawned("", timeout_s, program=target[len("exec:"):])
        link = spawned.link
    else:
        link = open_link(target, timeout_s=timeout_s)
    try:
        host_link = link_wrapper(link) if link_wrapper is not None else link
        remote = RemoteTarget(host_link, timeout_s=timeout_s)
        hello = remote.handshake(period_us, MODE_LOCKSTEP, 0, attempts=5)
        check = LoopbackTarget() if hello.firmware_name == "loopback" else None
        rtt_ns = np.zeros(periods, dtype=np.int64)
        good = timeouts = mismatches = consecutive = 0
        step = remote.step
        clock = time.perf_counter_ns
        every = max(1, periods // 100)
        t_start = clock()
        interrupted = False
        attempted = 0
        for k in range(periods):
            sensors = sensors_for_period(k)
            t0 = clock()
            try:
                drive = step(sensors)
            except KeyboardInterrupt:  # Ctrl-C: keep the figures so far (issue 16, item 18)
                interrupted = True
                break
            except LinkTimeout:
                timeouts += 1
                consecutive += 1
                if consecutive >= _MAX_CONSECUTIVE_TIMEOUTS:
                    raise LinkError(
                        f"link {link.name}: {consecutive} periods in a row without a Drive (period {k})"
                    ) from None
                continue
            rtt_ns[good] = clock() - t0
            good += 1
            consecutive = 0
            if check is not None and drive != check.step(sensors):
                mismatches += 1
            attempted = k + 1
            if progress is not None and k % every == 0:
                progress(k)
        else:
            attempted = periods
        elapsed_s = (clock() - t_start) / 1e9
        status: dict[str, int] = {}
        try:
            if interrupted:
                raise LinkError("interrupted: no status request")
            st = remote.status()
            status = {name: int(getattr(st, name)) for name in st._fields if name != "seq"}
        except LinkError:
            pass
        rtt_us = rtt_ns[:good] / 1000.0
        return LinkTestResult(
            target=target if spawned is None else f"{target} process on {link.name}",
            firmware_name=hello.firmware_name,
            periods=periods,
            good=good,
            timeouts=timeouts,
            mismatches=mismatches,
            elapsed_s=elapsed_s,
            round_trips_per_s=good / elapsed_s if elapsed_s > 0 else 0.0,
            rtt_p50_us=float(np.percentile(rtt_us, 50)) if good else float("nan"),
            rtt_p99_us=float(np.percentile(rtt_us, 99)) if good else float("nan"),
            rtt_max_us=float(rtt_us.max()) if good else float("nan"),
            link=link.stats.as_dict(),
            remote={"stale_frames": remote.stale_frames, "error_reports": remote.error_reports},
            target_status=status,
            interrupted=interrupted,
            attempted=attempted,
        )
    finally:
        if spawned is not None:
            spawned.close()
        else:
            link.close()


__all__ = ["LinkTestResult", "run_link_test", "sensors_for_period"]
