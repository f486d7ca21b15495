"""Real-time pacing: each period waits for its wall-clock slot; lateness, RTT and overruns measured.

A period whose slot has gone by the time its wait returns is not exchanged: the Drive is held
(as the board holds its PWM), the plant keeps to the wall clock, the row is marked and the
period counts as an overrun and a skipped period. Lockstep has no pacing object at all.
"""

from __future__ import annotations

import os
import time
from collections import deque
from typing import Callable

from hilbench.bench.clock import Pacer
from hilbench.bench.recorder import MARKER_SKIPPED
from hilbench.bench.streamstats import StreamingPercentiles
from hilbench.errors import HilbenchError
from hilbench.plant.period import Period
from hilbench.protocol import Drive, Sensors


#: the pacer's spin for a thread under a real-time policy: its sleeps have no timer slack (the kernel
#: gives SCHED_FIFO/RR threads none) and wake within 20 us (p50) / 51 us (p99) / 185 us (p99.9) of
#: the deadline on this VM with the CPU wake-up latency request held, so the last 200 us spun for a
#: normal thread (its 50 us slack, its later wake-ups) is CPU the loop's CPU could give away:
#: 100 us covers all but ~0.1 % of wake-ups (benchmarks/bench_realtime_cost.py: the host loop's CPU
#: per period with it)
REALTIME_POLICY_SPIN_S = 100e-6
#: overrun episodes (a run of consecutive overruns counts once) within CONTENDED_WINDOW_S that say
#: other work takes the run's CPU (`ContentionWatch`). An idle VM's hypervisor stalls skip periods
#: in runs and come a few at a time: no 30 s run at 1 kHz on a quiet machine here reached 8 in a
#: second (nine runs); with two CPU-bound processes beside the run 8 came within 0.08-0.13 s.
CONTENDED_EPISODES = 8
CONTENDED_WINDOW_S = 1.0
_REALTIME_POLICIES = frozenset(getattr(os, name) for name in ("SCHED_FIFO", "SCHED_RR") if hasattr(os, name))


def spin_for_this_thread(default_s: float) -> float:
    """How long the pacer spins before a deadline in the calling thread: less under a real-time
    policy (see REALTIME_POLICY_SPIN_S), ``default_s`` otherwise."""
    try:
        policy = os.sched_getscheduler(0) & ~getattr(os, "SCHED_RESET_ON_FORK", 0)
    except (OSError, AttributeError):
        return default_s
    return min(default_s, REALTIME_POLICY_SPIN_S) if policy in _REALTIME_POLICIES else default_s


class ContentionWatch:
    """Whether overruns come often enough to say other work takes the run's CPU: CONTENDED_EPISODES
    episodes within CONTENDED_WINDOW_S (a hypervisor stall skips many periods in a row and counts
    once; a busy CPU delays one period here, another there)."""

    def __init__(self, period_s: float) -> None:
        self.window_periods = max(1, round(CONTENDED_WINDOW_S / period_s))
        self._starts: deque[int] = deque(maxlen=CONTENDED_EPISODES)
        self._last = -2  # the last overrun's period

    def overrun(self, k: int) -> bool:
        """Period k overran: whether the CPU is contended now (only an overrun that begins an
        episode, its period before not one, can say so)."""
        begins, self._last = self._last != k - 1, k
        if not begins:
            return False
        starts = self._starts
        starts.append(k)
        return len(starts) == CONTENDED_EPISODES and k - starts[0] < self.window_periods


class SessionAborted(HilbenchError):
    """The session stopped on a fault; the recording is closed with a fault marker."""


class RealtimePacing:
    """The wall clock's side of a real-time session."""

    def __init__(self, period_us: int, *, abort_after: int | None, label: str,
                 on_contended: Callable[[float], None] | None = None) -> None:
        self.period_us = period_us
        self.period_s = Period(period_us).s
        self.on_contended = on_contended  # called once, with the run's time, when overruns say the CPU is contended
        self._contention = ContentionWatch(self.period_s)
        self.pacer = Pacer(self.period_s)
        self._spin_s = self.pacer.spin_s  # a normal thread's (start_at picks the thread's own)
        self.abort_after = abort_after  # consecutive overruns that end the run (None: never)
        self.label = label
        self.rtts = StreamingPercentiles()  # bounded memory however long the run
        self.lateness = StreamingPercentiles()
        self.overruns = 0
        self.consecutive = 0
        self.skipped = 0
        self.stall = 0  # skipped periods in a row so far
        self.longest_stall = 0  # the most skipped periods in a row (the Drive held that long)
        self.longest_stall_k = 0  # the first period of that stall
        self.rtt = 0.0
        self.late = 0.0
        self.marker = 0

    def start_at(self, k: int) -> None:
        """Period k starts one period from now (the run starts, or resumes after a pause), paced
        for the calling thread's scheduling policy (a real-time run sets it before its periods)."""
        self.pacer.spin_s = spin_for_this_thread(self._spin_s)
        self.pacer.start()
        self.pacer.t0 -= k * self.period_s

    def exchange(self, k: int, sensors: Sensors, drive: Drive | None, step: Callable[[Sensors], Drive]) -> Drive:
        """Wait for period k's slot, then exchange — or hold ``drive`` if the slot has gone."""
        self.late = late = self.pacer.wait_for(k)
        self.lateness.append(late)
        if late >= self.period_s and drive is not None:
            self.skipped += 1
            self.stall += 1
            if self.stall > self.longest_stall:
                self.longest_stall, self.longest_stall_k = self.stall, k + 1 - self.stall
            self.rtt = 0.0
            self.marker = MARKER_SKIPPED
            return drive
        self.stall = 0
        sent = time.perf_counter()
        drive = step(sensors)
        self.rtt = time.perf_counter() - sent
        self.rtts.append(self.rtt)
        self.marker = 0
        return drive

    def finished(self, k: int) -> None:
        """Period k's work is done: count an overrun if it ended after its slot."""
        if time.perf_counter() - self.pacer.t0 - k * self.period_s <= self.period_s:
            self.consecutive = 0
            return
        self.overruns += 1
        self.consecutive += 1
        if self.on_contended is not None and self._contention.overrun(k):
            self._contended(k)
        if self.abort_after is not None and self.consecutive >= self.abort_after:
            raise SessionAborted(
                f"{self.label}: {self.consecutive} consecutive overruns at period {k} "
                f"(period {self.period_us} us); try a longer period or --mode lockstep"
            )

    def _contended(self, k: int) -> None:
        """Tell the bench the CPU is contended (it raises the run to SCHED_FIFO), once; the pacer's
        spin follows the thread's policy."""
        on_contended, self.on_contended = self.on_contended, None
        assert on_contended is not None
        on_contended(k * self.period_s)
        self.pacer.spin_s = spin_for_this_thread(self._spin_s)


__all__ = ["ContentionWatch", "RealtimePacing", "SessionAborted"]
