"""Cost of the AN1017 firmware model per PWM period, and its real-time factor.

Runs one simulated second (20 000 PWM periods) of a running motor with a scripted hall stream
(≈ 1000 rpm), in lockstep steps of 50 µs (one Drive per PWM period) and of 1000 µs, and a trivial
baseline loop (a function call building a Drive per step) measured in the same run.
Prints medians over repeats. Usage: python benchmarks/bench_an1017.py [--repeats N] [--profile]
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import statistics
import time

from hilbench.protocol import Drive, Sensors
from hilbench.targets.an1017 import An1017Target

HALL_OF_SECTOR = (0b100, 0b110, 0b010, 0b011, 0b001, 0b101)
SIM_S = 1.0
PWM_PERIODS = 20_000


def make_stream(step_us: int, sector_us: float = 2000.0) -> list[Sensors]:
    n = int(SIM_S * 1e6) // step_us
    out, idx, next_edge = [], 0, 17.3
    for k in range(n):
        t0, t1 = k * step_us, (k + 1) * step_us
        edge = 0xFFFF
        while t0 <= next_edge < t1:
            idx += 1
            edge = int(round((next_edge - t0) * 10))
            next_edge += sector_us
        out.append(Sensors(k & 0xFF, HALL_OF_SECTOR[idx % 6], edge, 0, (900, 0, 0)))
    return out


def warm_target(step_us: int) -> An1017Target:
    """A target already running (bootstrap done), so the timed second is steady operation."""
    t = An1017Target()
    t.period_us = step_us
    t._period_tcy = step_us * 20
    t.start()
    for s in make_stream(step_us)[: 20_000 // step_us]:
        t.step(s)
    return t


def time_model(step_us: int, stream: list[Sensors]) -> float:
    t = warm_target(step_us)
    step = t.step
    t0 = time.perf_counter()
    for s in stream:
        step(s)
    return time.perf_counter() - t0


def time_baseline(stream: list[Sensors]) -> float:
    def step(s: Sensors) -> Drive:
        return Drive(s.seq, 499, 499, 499, 1, 2, 0, False, False, 0, (0, 0, 0))

    t0 = time.perf_counter()
    for s in stream:
        step(s)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--profile", action="store_true")
    args = ap.parse_args()
    streams = {50: make_stream(50), 1000: make_stream(1000)}
    if args.profile:
        pr = cProfile.Profile()
        t = warm_target(50)
        pr.enable()
        for s in streams[50]:
            t.step(s)
        pr.disable()
        pstats.Stats(pr).sort_stats("tottime").print_stats(12)
        return
    res: dict[str, list[float]] = {"base50": [], "m50": [], "m1000": []}
    for _ in range(args.repeats):
        res["base50"].append(time_baseline(streams[50]))
        res["m50"].append(time_model(50, streams[50]))
        res["m1000"].append(time_model(1000, streams[1000]))
    med = {k: statistics.median(v) for k, v in res.items()}
    print(f"AN1017 model, {SIM_S:.0f} simulated s = {PWM_PERIODS} PWM periods, median of {args.repeats}")
    print(f"  baseline (call + Drive per 50 us step): {med['base50'] * 1e3:7.2f} ms  "
          f"{med['base50'] / PWM_PERIODS * 1e6:.3f} us/period")
    for key, label in (("m50", "50 us steps  "), ("m1000", "1000 us steps")):
        per = med[key] / PWM_PERIODS * 1e6
        print(f"  model, {label}: {med[key] * 1e3:7.2f} ms  {per:.3f} us/PWM period  "
              f"real-time factor {SIM_S / med[key]:6.1f}x  ({med[key] / med['base50']:.2f}x baseline)")


if __name__ == "__main__":
    main()
