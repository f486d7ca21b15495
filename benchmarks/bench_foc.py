"""The F2812 FOC target's closed loop in process: periods/s with every exchange recorded (NPZ).

One PWM period (10 kHz) is two 50 us exchanges (docs/foc.md "Exchange"). Prints medians over
repeats of
  (a) the FOC closed loop on the 200 W servo: PWM periods/s, exchanges/s, ratio to real time
      (goal >= 10x);
  (b) the baseline measured in the same run: the AN1017 in-process loop on the Hurst plant at
      its 50 us period (the README's ~14x);
  (c) a profile split of (a) (a timed run): the share of the wall time spent inside FocTarget.step,
      and the pure-Python firmware's speed for comparison.

With ``--baseline-python PY`` it runs (a) alternately under this tree and under another
installation of hilbench (e.g. /work/venv-730876f/bin/python) and prints the ratio of the medians;
with ``--instructions`` (needs valgrind) it counts (a)'s CPU instructions per exchange under
callgrind instead, for this tree and the baseline: deterministic where wall medians scatter.

    python benchmarks/bench_foc.py [--seconds 1.0] [--repeats 3] [--baseline-python PY] [--instructions]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from hilbench.bench.recorder import Recorder
from hilbench.bench.scenario import Event
from hilbench.bench.session import Session, SessionOptions
from hilbench import load_config  # the name both this tree and the baseline (730876f) export
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


def measure_in(python: str, seconds: float) -> float:
    """(a)'s wall seconds measured by another interpreter (another hilbench installation) running this file."""
    out = subprocess.run([python, __file__, "--measure-foc", "--seconds", str(seconds)], capture_output=True,
                         text=True, timeout=600, cwd=tempfile.gettempdir(), check=True)
    return float(json.loads(out.stdout.strip().splitlines()[-1])["wall_s"])


def instructions_per_exchange(python: str, short_s: float = 0.3, long_s: float = 1.3) -> float:
    """(a)'s CPU instructions per 50 us exchange under ``python``, counted by callgrind (deterministic)."""
    totals = []
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONHASHSEED="0")
    with tempfile.TemporaryDirectory() as tmp:
        for seconds in (short_s, long_s):
            out = Path(tmp) / "callgrind.out"
            subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", python, __file__,
                            "--measure-foc", "--seconds", str(seconds)],
                           capture_output=True, text=True, timeout=1800, cwd=tmp, env=env, check=True)
            line = next(ln for ln in out.read_text().splitlines() if ln.startswith(("summary:", "totals:")))
            totals.append(int(line.split()[1]))
    return (totals[1] - totals[0]) / ((long_s - short_s) * 2e4)


def compare(args: argparse.Namespace) -> None:
    """(a) under this tree and under --baseline-python, alternating; or their instruction counts."""
    base_py = args.baseline_python
    if args.instructions:
        if shutil.which("valgrind") is None:
            raise SystemExit("bench_foc: --instructions needs valgrind on PATH (apt-get install valgrind)")
        this, base = instructions_per_exchange(sys.executable), instructions_per_exchange(base_py)
        print(f"(a) FOC closed loop in process, CPU instructions per exchange (callgrind): this tree {this:,.0f}, "
              f"baseline ({base_py}) {base:,.0f}; baseline/this {base / this:.3f} (above 1: fewer than the baseline)")
        return
    this_w, base_w = [], []
    for _ in range(args.repeats):
        this_w.append(measure_in(sys.executable, args.seconds))
        base_w.append(measure_in(base_py, args.seconds))
    this, base = statistics.median(this_w), statistics.median(base_w)
    print(f"(a) FOC closed loop in process, {args.seconds:g} s simulated, median of {args.repeats} alternating runs: "
          f"this tree {args.seconds * 2e4 / this:,.0f} exchanges/s, baseline ({base_py}) "
          f"{args.seconds * 2e4 / base:,.0f}; speed ratio this/baseline {base / this:.3f}")
    print(f"    walls (s): this {', '.join(f'{w:.3f}' for w in this_w)}; baseline {', '.join(f'{w:.3f}' for w in base_w)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=1.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--baseline-python", default=None, metavar="PY",
                    help="also run (a) under this interpreter (another hilbench installation) and print the ratio")
    ap.add_argument("--instructions", action="store_true",
                    help="with --baseline-python: compare callgrind instruction counts per exchange instead")
    ap.add_argument("--measure-foc", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.measure_foc:  # one (a) figure for --baseline-python, as JSON
        with tempfile.TemporaryDirectory() as tmp:
            print(json.dumps({"wall_s": foc_run(args.seconds, Path(tmp) / "foc.npz")[0]}))
        return
    if args.baseline_python:
        compare(args)
        return
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
