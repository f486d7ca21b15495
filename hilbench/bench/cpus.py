"""Where and how a real-time run's processes run: the host loop and the emulator it started, on one
CPU, and ahead of the machine's other work (SCHED_FIFO) when allowed: from the start, or (the
default) once overruns say other work takes that CPU (`pacing.ContentionWatch`).

In a real-time exchange the host and the target take turns (one waits while the other works), so
they need one CPU, not two. On a VM each vCPU is stalled now and then by the hypervisor; with
the two processes on two vCPUs either vCPU's stall hits the run, with both on one only that one's
does. On these machines that halved the overruns of a 1 kHz run (median 0.35 % -> 0.16 %).

With other work on that CPU (a build, a browser, the test suite), a normally scheduled host or
emulator waits its turn behind it; under SCHED_FIFO it runs as soon as it is woken (the kernel keeps
5 % of each second for normal tasks, /proc/sys/kernel/sched_rt_runtime_us). With two CPU-bound
processes beside a 10 s run at 1 kHz here: 1 659 and 1 684 overruns without it, 33 and 31 with it
from the start, 41 and 67 raised once contended. On an idle CPU FIFO costs overruns instead (the
pty's kernel worker is kept off a FIFO task's CPU: README, "real time"): median 61 against 36 of
nine 30 s runs each.
"""

from __future__ import annotations

import os
import threading
from typing import Iterable, Literal, get_args

from hilbench.errors import ConfigError


#: when a real-time run's host loop and emulator get SCHED_FIFO ([link] realtime_fifo)
FifoWhen = Literal["contended", "always"]
FIFO_WHEN: tuple[str, ...] = get_args(FifoWhen)


def default_cpu() -> int:
    """The last CPU this process may use (CPU 0 usually takes most interrupts)."""
    return max(os.sched_getaffinity(0))


class CpuPinning:
    """Pin the calling thread and ``pids`` to one CPU for a run; the thread's CPUs come back after.

    Only the calling thread moves (Linux affinity is per thread): threads started before it, such
    as the dashboard's refresh, keep the other CPUs, away from the real-time loop.
    """

    def __init__(self, pids: Iterable[int], cpu: int | None = None) -> None:
        allowed = os.sched_getaffinity(0)
        if cpu is not None and cpu not in allowed:
            raise ConfigError(f"[link] realtime_cpu {cpu}: not one of this process's CPUs "
                              f"({', '.join(map(str, sorted(allowed)))})")
        self.cpu = default_cpu() if cpu is None else cpu
        self.pids = tuple(pids)
        self._previous = allowed
        self.status = "not pinned"

    def __enter__(self) -> "CpuPinning":
        pinned = ["host"]
        try:
            os.sched_setaffinity(0, {self.cpu})
            for pid in self.pids:
                for tid in _threads(pid):
                    os.sched_setaffinity(tid, {self.cpu})
                pinned.append(f"pid {pid}")
        except OSError as exc:
            self.status = f"not pinned: {exc.strerror}"
            return self
        self.status = f"{' and '.join(pinned)} on CPU {self.cpu}"
        return self

    def __exit__(self, *exc_info: object) -> None:
        try:
            os.sched_setaffinity(0, self._previous)
        except OSError:
            pass


def _threads(pid: int) -> list[int]:
    """Every thread of a process (affinity is per thread); just the pid where /proc is missing."""
    try:
        return [int(tid) for tid in os.listdir(f"/proc/{pid}/task")]
    except OSError:
        return [pid]


class FifoPriority:
    """SCHED_FIFO at ``priority`` for the calling thread and ``pids`` while a real-time run lasts; the
    calling thread's policy comes back after (the processes end with the run).

    ``when="always"`` (this class's default, for a caller that asks for FIFO outright) raises them
    as the run starts; ``"contended"`` (the bench's default, [link] realtime_fifo) leaves them
    normally scheduled until `engage` (the pacing calls it once overruns say other work takes the
    run's CPU: `pacing.ContentionWatch`), since on an idle CPU FIFO costs overruns (the pty's kernel
    worker is kept off the FIFO task's CPU, README "real time"). `engage` raises the thread that
    calls it (the run's loop) and the exit restores that thread, whichever thread exits. It needs
    root or CAP_SYS_NICE (or an RLIMIT_RTPRIO): without, the run goes on normally scheduled and
    ``status`` says why (with "contended", once the CPU was). SCHED_RESET_ON_FORK: nothing the run
    starts inherits the priority.
    """

    def __init__(self, pids: Iterable[int], priority: int, *, when: FifoWhen = "always") -> None:
        if when not in FIFO_WHEN:
            raise ValueError(f"FifoPriority: when={when!r}, not one of {FIFO_WHEN}")
        self.pids = tuple(pids)
        self.priority = priority
        self.when = when
        self._previous: tuple[int, os.sched_param] | None = None
        self._thread = 0  # the raised thread (0: none)
        self.status = "normal scheduling"

    def __enter__(self) -> "FifoPriority":
        if self.when == "contended":
            self.status = f"normal scheduling (SCHED_FIFO {self.priority} once the CPU is contended: not needed)"
        else:
            self.engage()
        return self

    def engage(self, at_s: float | None = None) -> None:
        """SCHED_FIFO for the calling thread and ``pids`` from now on (``at_s``: the run's time, for
        the status); once."""
        if self._previous is not None:
            return
        policy = os.SCHED_FIFO | os.SCHED_RESET_ON_FORK
        param = os.sched_param(self.priority)
        since = "" if at_s is None else f" from {at_s:.3f} s (the CPU was contended)"
        try:
            previous = (os.sched_getscheduler(0), os.sched_getparam(0))
            os.sched_setscheduler(0, policy, param)
        except OSError as exc:
            self.status = f"normal scheduling (SCHED_FIFO {self.priority}{since}: {exc.strerror})"
            return
        self._previous, self._thread = previous, threading.get_native_id()
        raised = ["host"]
        for pid in self.pids:
            try:
                os.sched_setscheduler(pid, policy, param)
                raised.append(f"pid {pid}")
            except OSError as exc:
                raised.append(f"not pid {pid} ({exc.strerror})")
        self.status = f"SCHED_FIFO {self.priority}{since}: {', '.join(raised)}"

    def __exit__(self, *exc_info: object) -> None:
        if self._previous is not None:
            # keep reset-on-fork set: only a CAP_SYS_NICE thread may clear it (an RLIMIT_RTPRIO user
            # restoring plain SCHED_OTHER would get EPERM and stay SCHED_FIFO)
            policy, param = self._previous
            try:
                os.sched_setscheduler(self._thread, policy | os.SCHED_RESET_ON_FORK, param)
            except ProcessLookupError:  # that thread has ended: nothing of it to restore
                pass
            except OSError as exc:
                self.status += f"; not restored: {exc.strerror}"
            self._previous = None
