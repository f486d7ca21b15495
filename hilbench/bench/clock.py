"""Wall-clock pacing for real-time runs: sleep most of the wait, spin the last part.

``time.sleep`` overshoots by ~0.1 ms (timer slack) and sometimes by milliseconds, so the pacer
sleeps until ``spin_s`` before the deadline and spins on ``perf_counter`` for the rest. It never
catches up by skipping: a late period starts at once and its lateness is reported.
"""

from __future__ import annotations

import time
from dataclasses import dataclass


@dataclass
class Pacer:
    """Starts period k at ``t0 + k·period_s`` of the wall clock and reports its lateness."""

    period_s: float
    spin_s: float = 200e-6
    t0: float = 0.0

    def start(self) -> None:
        self.t0 = time.perf_counter() + self.period_s

    def wait_for(self, k: int) -> float:
        """Block until period k's start time; returns the lateness in seconds (>= 0)."""
        deadline = self.t0 + k * self.period_s
        clock = time.perf_counter
        now = clock()
        remaining = deadline - now
        if remaining > self.spin_s:
            time.sleep(remaining - self.spin_s)
        while True:
            now = clock()
            if now >= deadline:
                return now - deadline
