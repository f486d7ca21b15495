"""Wall-clock pacing for real-time runs: sleep most of the wait, spin the last part; and a PM QoS
request that keeps idle CPUs from halting while a real-time run lasts.

``time.sleep`` overshoots by ~0.1 ms (timer slack) and sometimes by milliseconds, so the pacer
sleeps until ``spin_s`` before the deadline and spins on ``perf_counter`` for the rest (a thread
under SCHED_FIFO has no slack and spins less: `pacing.spin_for_this_thread`). The pacer
never skips: a late period starts at once and its lateness is reported (the session skips the
exchange of a period whose whole slot has gone).
"""

from __future__ import annotations

import os
import struct
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


#: Linux PM QoS: while this file is held open with a value written, no CPU enters an idle state
#: whose exit latency exceeds that many µs (0: idle CPUs poll instead of halting). cyclictest does
#: the same by default.
CPU_DMA_LATENCY = "/dev/cpu_dma_latency"
#: the cpuidle driver that honours the request; "none" when the kernel has none (idle is a plain halt)
CPUIDLE_DRIVER = "/sys/devices/system/cpu/cpuidle/current_driver"


class CpuLatencyRequest:
    """Keep idle CPUs awake for the length of a real-time run.

    On a VM a halted vCPU is woken by the hypervisor, which takes milliseconds when the host is
    busy: on the VMs this was first measured on (with a cpuidle driver) that alone made ~2 % of
    1 kHz periods start over 1 ms late; with the request held, ~0.1 %. It costs power (idle CPUs
    spin), so it is held only while pacing.
    Without permission (it needs root or write access to the file) the run goes on without it and
    ``status`` says why. A kernel with no cpuidle driver (some VMs: `CPUIDLE_DRIVER` reads "none")
    halts idle CPUs whatever is asked: ``status`` then says the request is held without effect
    (on such a VM, 1 kHz pty round trips measured with and without it were alike).
    """

    def __init__(self, max_latency_us: int = 0, path: str = CPU_DMA_LATENCY,
                 driver_path: str = CPUIDLE_DRIVER) -> None:
        self.max_latency_us = max_latency_us
        self.path = path
        self.driver_path = driver_path
        self._fd: int | None = None
        self.status = "not requested"

    def __enter__(self) -> "CpuLatencyRequest":
        try:
            fd = os.open(self.path, os.O_WRONLY)
        except OSError as exc:
            self.status = f"not held: {self.path}: {exc.strerror}"
            return self
        try:
            os.write(fd, struct.pack("=i", self.max_latency_us))
        except OSError as exc:
            os.close(fd)
            self.status = f"not held: {self.path}: {exc.strerror}"
            return self
        self._fd = fd
        self.status = f"held at {self.max_latency_us} us ({self.path})"
        if self._idle_driver() == "none":
            self.status += "; without effect: this kernel has no cpuidle driver, its idle CPUs halt"
        return self

    def _idle_driver(self) -> str | None:
        """The kernel's cpuidle driver ("none" if it has none), None where that is not known."""
        try:
            with open(self.driver_path, encoding="ascii", errors="replace") as driver:
                return driver.read(64).strip()
        except OSError:
            return None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def __exit__(self, *exc_info: object) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the file withdraws the request
            self._fd = None
