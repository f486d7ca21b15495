"""A gain sweep of speed-step tests: wall time on 1 worker and on every core, the speed-up, and the
simulated plant-seconds per wall second; the best gains against the firmware's default gains.

Every point is the scalar session's step test on the in-process model (the same code `hilbench step`
runs), so the figures are those of the real bench, on a process pool.

    python benchmarks/bench_sweep.py [--grid 10] [--repeats 3] [--from 1000 --to 2000]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import hilbench
from hilbench.bench.sweep import grid_values


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--grid", type=int, default=10, help="points per axis (kp × ki)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--from", dest="from_rpm", type=float, default=1000.0)
    parser.add_argument("--to", dest="to_rpm", type=float, default=2000.0)
    args = parser.parse_args()
    axes = {"kp": grid_values(0.05, 0.85, args.grid), "ki": grid_values(0.005, 0.12, args.grid), "kd": (0.0,)}
    cores = os.cpu_count() or 1
    walls: dict[int, list[float]] = {1: [], cores: []}
    result = None
    for _ in range(args.repeats):  # interleaved: both see the same machine load
        for workers in walls:
            t0 = time.perf_counter()
            result = hilbench.sweep(axes, from_rpm=args.from_rpm, to_rpm=args.to_rpm, workers=workers)
            walls[workers].append(time.perf_counter() - t0)
    assert result is not None
    simulated = result.sim_s
    one, many = statistics.median(walls[1]), statistics.median(walls[cores])
    print(f"{args.grid} x {args.grid} sweep of 1 s step tests ({len(result.points)} points, "
          f"{result.skipped} skipped by the firmware's constraints, {simulated:.0f} simulated s), median of {args.repeats}")
    print(f"  1 worker      : {one:6.2f} s wall, {simulated / one:6.1f} plant-s/s")
    print(f"  {cores} workers     : {many:6.2f} s wall, {simulated / many:6.1f} plant-s/s, speed-up {one / many:4.2f}x")
    best = result.best
    default = hilbench.step_test(from_rpm=args.from_rpm, to_rpm=args.to_rpm, params={"kp": 0.1, "ki": 0.01, "kd": 0.0})
    if best is not None and best.result is not None:
        print(f"  best {dict(best.params)}: ITAE {best.result.metrics.itae:.4f}; "
              f"the firmware's default gains 0.1/0.01/0: ITAE {default.metrics.itae:.4f}")


if __name__ == "__main__":
    main()
