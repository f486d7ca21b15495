"""The F2812 FOC target's closed loop in process: periods/s with every exchange recorded (NPZ).

One PWM period (10 kHz) is two 50 us exchanges (docs/foc.md "Exchange"). Prints medians over
repeats of
  (a) the FOC closed loop on the 200 W servo: PWM periods/s, exchanges/s, ratio to real time
      (goal >= 10x);
  (b) the baseline measured in the same run: the AN1017 in-process loop on the Hurst plant at
      its 50 us period (the README's ~14x);
  (c) a profile split of (a) (a timed run): the share of the wall time spent inside FocTarget.step,
      and the pure-Python firmware's speed for comparison.

    python benchmarks/bench_foc.py [--seconds 1.0] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

from hilbench.bench.recorder import Recorder
from hilbench.bench.scenario import Event
from hilbench.bench.session import Session, SessionOptions
from hilbench.bench.settings import load_config
from hilbench.config import plant_params_from_config
from hilbench.plant.model import Plant
from hilbench.targets import make_target
from hilbench.targets.foc.firmware import FocOptions
from hilbench.targets.foc.target import FocTarget, available_backends

ROOT = Path(__file__).resolve().parents[1]


def foc_run(seconds: float, out: Path, backend: str | None = None, timed: bool = False) -> tuple[float, float]:
    """(wall s, share of it inside target.step or NaN) of `seconds` of 1000 rpm closed loop, recorded.

    `timed` wraps the step in a timer (a Python frame per exchange: slower, for the split only)."""
    cfg = load_config(ROOT / "bench_configs" / "servo_200w.toml")
    plant = Plant(plant_params_from_config(cfg), seed=0, substeps=cfg.plant.substeps)
    target = FocTarget(FocOptions(), backend=backend)
    inner = target.step
    spent = [0.0]
    perf = time.perf_counter

    def timed_step(sensors):  # type: ignore[no-untyped-def]
        t0 = perf()
        d = inner(sensors)
        spent[0] += perf() - t0
        return d

    if timed:
        target.step = timed_step
    events = (Event(at_s=0.0, press="s2"), Event(at_s=0.2, params=(("ref_rpm", 1000.0),)),
              Event(at_s=seconds, end=True))
    session = Session(target, plant, events, SessionOptions(period_us=50, observe_every_periods=10 ** 9),
                      recorder=Recorder(out, {"bench": "foc"}))
    session.handshake()
    t0 = perf()
    session.run()
    wall = perf() - t0
    return wall, (spent[0] / wall if timed else float("nan"))


def an1017_run(seconds: float, out: Path) -> float:
    cfg = load_config(None)
    plant = Plant(plant_params_from_config(cfg), seed=0, substeps=cfg.plant.substeps)
    events = (Event(at_s=0.0, ref_rpm=1500.0), Event(at_s=0.01, press="s2"), Event(at_s=seconds, end=True))
    session = Session(make_target("an1017"), plant, events, SessionOptions(period_us=50, observe_every_periods=10 ** 9),
                      recorder=Recorder(out, {"bench": "an1017"}))
    session.handshake()
    t0 = time.perf_counter()
    session.run()
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=1.0)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    foc, share, base, py = [], [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.repeats):
            foc.append(foc_run(args.seconds, Path(tmp) / f"foc{r}.npz")[0])
            share.append(foc_run(args.seconds, Path(tmp) / f"foct{r}.npz", timed=True)[1])
            py.append(foc_run(args.seconds, Path(tmp) / f"focp{r}.npz", backend="python")[0])
            base.append(an1017_run(args.seconds, Path(tmp) / f"an{r}.npz"))
    wall = statistics.median(foc)
    rt = args.seconds / wall
    base_rt = args.seconds / statistics.median(base)
    print(f"FOC closed loop, in process, NPZ recording, {args.seconds:g} s simulated, median of {args.repeats}:")
    print(f"  {args.seconds * 1e4 / wall:,.0f} PWM periods/s ({args.seconds * 2e4 / wall:,.0f} exchanges/s), "
          f"{rt:.2f}x real time (goal >= 10x)")
    backend = FocTarget(FocOptions()).backend
    print(f"  firmware backend {backend!r} (available: {', '.join(available_backends())}); inside its step: "
          f"{100 * statistics.median(share):.0f} % of the wall time (timed run)")
    print(f"  pure-Python firmware: {args.seconds / statistics.median(py):.2f}x real time")
    print(f"baseline, same run: AN1017 in process at 50 us: {args.seconds * 2e4 / statistics.median(base):,.0f} "
          f"periods/s, {base_rt:.2f}x real time")
    print(f"FOC / AN1017 speed ratio: {rt / base_rt:.2f}")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
