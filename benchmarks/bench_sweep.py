"""Sweeps of speed-step tests on executors, and the refinement against a full grid.

Prints, in one run (medians of --repeats, interleaved so machine load hits every figure alike):
  * a G × G grid of 1-second step tests (kp × ki, the default target) on 1 worker, on every local
    core and on a local Dask cluster: wall time, speed-up over 1 worker (goal ≥ 1.7× on 2 cores) and
    simulated plant-seconds per wall second;
  * the refinement (a 5 × 5 grid, then rounds zooming around the best point) against the full grid:
    the best ITAE each finds and how many step tests each needed (goal: at least as good with fewer
    than a quarter of the tests).

With ``--baseline-python PY`` it instead times the G × G grid on one worker under this tree and
under another installation of hilbench (e.g. a venv of the main before a change), interleaved, and
prints the medians and their ratio (issue 28's "sweep 3x" line).

    python benchmarks/bench_sweep.py [--grid 20] [--repeats 3] [--no-dask] [--baseline-python PY]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import hilbench
from hilbench.bench.sampling import Axis
from hilbench.bench.steptest import StepTest
from hilbench.bench.sweep import refine, sweep_grid
from hilbench import load_config

KP, KI = (0.05, 0.85), (0.005, 0.12)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--grid", type=int, default=20, help="points per axis (kp × ki)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-dask", action="store_true", help="skip the local Dask cluster")
    parser.add_argument("--baseline-python", default=None, metavar="PY",
                        help="time the grid on one worker here and under this interpreter's hilbench, interleaved")
    parser.add_argument("--measure-one", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    cfg = load_config(None)
    test = StepTest(1000.0, 2000.0, 0.5, 0.5)
    axes = [("kp", Axis("kp", *KP, args.grid).values()), ("ki", Axis("ki", *KI, args.grid).values()), ("kd", (0.0,))]
    if args.measure_one:  # one timing of the grid on one worker, as JSON (for --baseline-python)
        t0 = time.perf_counter()
        result = sweep_grid(cfg, axes, test, executor="local", workers=1)
        print(json.dumps({"wall_s": time.perf_counter() - t0, "sim_s": result.sim_s}))
        return
    if args.baseline_python:
        compare(args)
        return
    cores = os.cpu_count() or 1
    runs = {"1 worker": ("local", 1), f"{cores} local workers": ("local", cores)}
    if not args.no_dask:
        runs[f"local Dask cluster, {cores} workers"] = (f"local-dask:{cores}", None)
    walls: dict[str, list[float]] = {name: [] for name in runs}
    result = None
    for _ in range(args.repeats):
        for name, (executor, workers) in runs.items():
            t0 = time.perf_counter()
            result = sweep_grid(cfg, axes, test, executor=executor, workers=workers)
            walls[name].append(time.perf_counter() - t0)
    assert result is not None
    one = statistics.median(walls["1 worker"])
    print(f"{args.grid} x {args.grid} grid of 1 s step tests: {len(result.points)} points, {result.skipped} skipped by the "
          f"firmware's constraints, {result.sim_s:.0f} simulated s; median of {args.repeats} ({cores} cores)")
    for name in runs:
        wall = statistics.median(walls[name])
        print(f"  {name:28s}: {wall:6.2f} s wall, {result.sim_s / wall:6.1f} plant-s/s, speed-up {one / wall:4.2f}x")
    box = [Axis("kp", *KP, 5), Axis("ki", *KI, 5), Axis("kd", 0.0, 0.0, 1)]
    refined = refine(cfg, box, test, rounds=3, shrink=0.4)
    best_grid, best_refined = result.best, refined.best
    assert best_grid is not None and best_refined is not None
    print(f"  full grid : best ITAE {best_grid.result.metrics.itae:.4f} at {dict(best_grid.params)} "
          f"({result.step_tests} step tests)")
    print(f"  refinement: best ITAE {best_refined.result.metrics.itae:.4f} at {dict(best_refined.params)} "
          f"({refined.step_tests} step tests = {refined.step_tests / result.step_tests:.0%} of the grid's; goal < 25 % "
          f"and ITAE <= the grid's: {'yes' if best_refined.result.metrics.itae <= best_grid.result.metrics.itae else 'no'})")
    default = hilbench.step_test(params={"kp": 0.1, "ki": 0.01, "kd": 0.0})
    print(f"  the firmware's default gains 0.1/0.01/0: ITAE {default.metrics.itae:.4f}")


def one_worker_wall(python: str, grid: int) -> tuple[float, float]:
    """(wall s, simulated s) of the grid on one worker, timed by ``python`` running this file."""
    out = subprocess.run([python, __file__, "--measure-one", "--grid", str(grid)], capture_output=True, text=True,
                         timeout=3600, cwd=tempfile.gettempdir(), check=True)
    figures = json.loads(out.stdout.strip().splitlines()[-1])
    return float(figures["wall_s"]), float(figures["sim_s"])


def compare(args: argparse.Namespace) -> None:
    """This tree against --baseline-python, interleaved: the grid on one worker."""
    walls: dict[str, list[float]] = {"this": [], "baseline": []}
    sim_s = 0.0
    for _ in range(args.repeats):
        wall, sim_s = one_worker_wall(sys.executable, args.grid)
        walls["this"].append(wall)
        walls["baseline"].append(one_worker_wall(args.baseline_python, args.grid)[0])
    this, base = statistics.median(walls["this"]), statistics.median(walls["baseline"])
    print(f"{args.grid} x {args.grid} grid of 1 s step tests on 1 worker ({sim_s:.0f} simulated s), median of "
          f"{args.repeats} interleaved runs:")
    print(f"  this tree : {this:7.2f} s wall  [{', '.join(f'{w:.2f}' for w in walls['this'])}]")
    print(f"  baseline  : {base:7.2f} s wall  [{', '.join(f'{w:.2f}' for w in walls['baseline'])}] ({args.baseline_python})")
    paired = statistics.median(b / t for b, t in zip(walls["baseline"], walls["this"]))
    print(f"ratio sweep baseline / this tree (speed-up): {base / this:.2f}  (median of the repeats' own "
          f"ratios, each pair back to back: {paired:.2f})")


if __name__ == "__main__":
    main()
