"""10 × 10 gain sweep of 1-second speed-step tests (issue 6 acceptance: < 10 s on 2 cores).

Prints the sweep's wall time (median of --repeats), simulated plant-seconds per wall second,
and the same figure for the scalar in-process closed loop (Session + An1017Target + Plant)
measured in this run as the baseline; then the best gains and their ITAE next to the AN1017
default gains' (Kp 0.1, Ki 0.01, Kd 0) ITAE from the scalar session.

    python benchmarks/bench_sweep.py [--repeats 3] [--from 1000 --to 2000] [--profile]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from hilbench.bench.metrics import step_metrics
from hilbench.bench.session import Session, SessionOptions
from hilbench.bench.sweep import best_fragment, grid_values, run_step_batch, step_scenario, sweep_grid
from hilbench.config import load_config, plant_from_config
from hilbench.targets.an1017.target import An1017Target
from hilbench.targets.profiles import AN1017_PROFILE

DEFAULT_GAINS = (0.1, 0.01, 0.0)


class _Rec:
    """Plant proxy recording the speed after every period (for the scalar baseline's metrics)."""

    def __init__(self, inner: object) -> None:
        object.__setattr__(self, "_inner", inner)
        object.__setattr__(self, "speeds", [])

    def __getattr__(self, name: str) -> object:
        return getattr(self._inner, name)

    def __setattr__(self, name: str, value: object) -> None:
        setattr(self._inner, name, value)

    def step(self, *args: object) -> None:
        self._inner.step(*args)
        self.speeds.append(self._inner.speed_rpm)


def scalar_step(cfg, gains, from_rpm, to_rpm, duration_s, step_at_s):  # type: ignore[no-untyped-def]
    """One step test on the scalar bench; returns (ITAE, wall seconds)."""
    plant = _Rec(plant_from_config(cfg))
    session = Session(An1017Target(), plant, step_scenario(from_rpm, to_rpm, step_at_s, duration_s),
                      SessionOptions(duration_s=duration_s))
    session.handshake()
    session.set_params(dict(zip(("kp", "ki", "kd"), gains)), 0.0)
    t0 = time.perf_counter()
    session.run()
    wall = time.perf_counter() - t0
    speeds = np.array(plant.speeds)
    idx = np.arange(3, speeds.size, 4)
    t = (idx + 1) * (50 * 1e-6)
    q = AN1017_PROFILE.rpm_per_speed_q15 or 0.0
    y0 = (AN1017_PROFILE.pot_code_for_rpm(from_rpm) - 512) * 64 * q
    yf = (AN1017_PROFILE.pot_code_for_rpm(to_rpm) - 512) * 64 * q
    k_step = next(k for k in range(10**9) if k * (50 * 1e-6) >= step_at_s)
    m = step_metrics(t, speeds[idx], y0=y0, y_final_ref=yf, t_step_s=k_step * (50 * 1e-6))
    return m.itae, wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--from", dest="from_rpm", type=float, default=1000.0)
    ap.add_argument("--to", dest="to_rpm", type=float, default=2000.0)
    ap.add_argument("--duration", type=float, default=1.0)
    ap.add_argument("--step-at", type=float, default=0.5)
    ap.add_argument("--profile", action="store_true", help="cProfile one sweep instead of timing")
    args = ap.parse_args()
    cfg = load_config(None)
    kp = grid_values(0.05, 0.85, 10)
    ki = grid_values(0.005, 0.12, 10)
    step = (args.from_rpm, args.to_rpm, args.duration, args.step_at)
    if args.profile:
        import cProfile
        import pstats

        cProfile.runctx("sweep_grid(cfg, kp, ki, [0.0], from_rpm=step[0], to_rpm=step[1], duration_s=step[2], "
                        "step_at_s=step[3])", globals(), locals(), "/tmp/bench_sweep.prof")
        pstats.Stats("/tmp/bench_sweep.prof").sort_stats("tottime").print_stats(15)
        return

    default_itae, scalar_wall = scalar_step(cfg, DEFAULT_GAINS, *step)
    scalar_rate = args.duration / scalar_wall
    walls = []
    sweep = None
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        sweep = sweep_grid(cfg, kp, ki, [0.0], metric="itae", from_rpm=step[0], to_rpm=step[1],
                           duration_s=step[2], step_at_s=step[3])
        walls.append(time.perf_counter() - t0)
    assert sweep is not None and sweep.best is not None and sweep.best.result is not None
    wall = statistics.median(walls)
    rate = sweep.sim_s / wall
    # the default gains through the batch path too (cross-check of the scalar baseline's ITAE)
    batch_default = run_step_batch(cfg, [DEFAULT_GAINS], *step)[0].metrics.itae
    best = sweep.best
    bm = best.result.metrics
    print(f"sweep: {len(sweep.points)} points ({sweep.skipped} skipped), step {step[0]:g} -> {step[1]:g} rpm "
          f"at {step[3]:g} s, {step[2]:g} s each")
    print(f"wall time: median {wall:.2f} s over {len(walls)} runs ({', '.join(f'{w:.2f}' for w in walls)}); "
          f"goal < 10 s: {'met' if wall < 10 else 'NOT met'}")
    print(f"simulated plant-seconds per wall second: sweep {rate:.1f}, scalar closed loop {scalar_rate:.2f} "
          f"(ratio {rate / scalar_rate:.1f}x)")
    print(f"best: kp={best.gains[0]:.4g} ki={best.gains[1]:.4g} kd={best.gains[2]:.4g}  ITAE {bm.itae:.4g} rpm*s^2, "
          f"rise {bm.rise_time_s}, overshoot {bm.overshoot_pct:.2f} %, settling {bm.settling_time_s}")
    print(f"AN1017 default (kp 0.1 ki 0.01 kd 0): ITAE {default_itae:.4g} (scalar session), "
          f"{batch_default:.4g} (batch); best/default = {bm.itae / default_itae:.3f}; "
          f"{'best beats default' if bm.itae < default_itae else 'best does NOT beat default'}")
    print(best_fragment(sweep), end="")


if __name__ == "__main__":
    main()
