"""Lockstep closed-loop speed of the bench: AN1017 firmware + Hurst plant, every period recorded.

Prints, in one run (medians over repeats; the machine is a noisy 2-core VM):
  (a) periods/s and real-time factor with the firmware in-process (goal >= 10x at 20 kHz periods),
  (b) periods/s with the firmware as its own process on a pty (goal >= 50 % of the raw echo),
  and a raw two-process pty echo of the same frame sizes as the baseline for (b).

With ``--baseline-python PY`` it also runs (a) under another installation of hilbench (e.g. the
commit before a change, installed in its own venv), interleaved with this one, and prints the
ratio: the "no slowdown" check of a redesign, measured in the same run.

With ``--instructions`` (needs valgrind) it counts the CPU instructions of (a) per period instead,
for this tree and the baseline: deterministic, so a few-percent difference is visible on a shared,
noisy machine where wall-clock medians scatter by as much. Each interpreter runs (a) under
callgrind for a short and a long scenario; the difference over the extra periods is the per-period
cost with start-up, handshake and imports cancelled out (the close of the recording stays in).

    python benchmarks/bench_session.py [--seconds 1.0] [--repeats 3] [--baseline-python PY] [--instructions]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from hilbench.bench import settings  # noqa: E402
from hilbench.bench.launcher import open_target  # noqa: E402
from hilbench.bench.recorder import Recorder  # noqa: E402
from hilbench.bench.scenario import Event  # noqa: E402
from hilbench.bench.session import Session  # noqa: E402
from hilbench import load_config  # noqa: E402
from hilbench.config import plant_params_from_config  # noqa: E402
from hilbench.plant.model import Plant  # noqa: E402

PERIOD_US = 50


def scenario(seconds: float) -> tuple[Event, ...]:
    """Running at speed for the whole timed span: pot at 1500 rpm, S2, a step to 2000 rpm."""
    return (
        Event(at_s=0.0, ref_rpm=1500.0),
        Event(at_s=0.01, press="s2"),
        Event(at_s=seconds / 2, ref_rpm=2000.0),
        Event(at_s=seconds, end=True),
    )


def closed_loop(spec: str, seconds: float, record_dir: str, fmt: str) -> tuple[float, str, float, float]:
    """Periods/s of one lockstep run against ``spec``, every period recorded to ``fmt``.

    Returns (periods/s including closing the recording, plant backend, periods/s of the loop alone,
    periods per CPU second of this process including the close: time the machine's other load took
    from it left out).
    """
    cfg = load_config(None)
    options = dataclasses.replace(settings.session_options(cfg), duration_s=seconds, period_us=PERIOD_US)
    plant = Plant(plant_params_from_config(cfg), seed=0, substeps=cfg.plant.substeps)
    with open_target(spec, timeout_s=2.0) as handle:
        recorder = Recorder(Path(record_dir) / f"bench.{fmt}", {"bench": True}, flush_rows=20_000)
        session = Session(handle.target, plant, scenario(seconds), options, recorder=recorder,
                          link_stats=handle.link_stats, target_label=spec)
        session.handshake()
        t0, cpu0 = time.perf_counter(), time.process_time()
        summary = session.run()
        elapsed, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    return (summary.periods / elapsed, getattr(plant, "backend", "python"), summary.periods / summary.wall_s,
            summary.periods / cpu if cpu > 0 else float("nan"))


def measure_in(python: str, seconds: float) -> tuple[float, float, float]:
    """(a) measured by another interpreter (another hilbench installation) running this file:
    (periods/s with the recording's close, periods/s of the loop alone, periods per CPU second)."""
    out = subprocess.run([python, __file__, "--measure-inprocess", "--seconds", str(seconds)], capture_output=True,
                         text=True, timeout=600, cwd=tempfile.gettempdir(), check=True)
    figures = json.loads(out.stdout.strip().splitlines()[-1])
    return float(figures["rate"]), float(figures.get("loop_rate", "nan")), float(figures.get("cpu_rate", "nan"))


def instructions_per_period(python: str, short_s: float = 0.2, long_s: float = 1.2) -> float:
    """(a)'s CPU instructions per period under ``python``, counted by callgrind (deterministic)."""
    totals = []
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONHASHSEED="0")  # no BLAS threads spinning, fixed hashes
    with tempfile.TemporaryDirectory() as tmp:
        for seconds in (short_s, long_s):
            out = Path(tmp) / "callgrind.out"
            subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", python, __file__,
                            "--measure-inprocess", "--seconds", str(seconds)],
                           capture_output=True, text=True, timeout=900, cwd=tmp, env=env, check=True)
            line = next(ln for ln in out.read_text().splitlines() if ln.startswith(("summary:", "totals:")))
            totals.append(int(line.split()[1]))
    return (totals[1] - totals[0]) / ((long_s - short_s) * 1e6 / PERIOD_US)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=1.0, help="simulated seconds per run")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--baseline-python", default=None, metavar="PY",
                        help="an interpreter with another hilbench installed: (a) is measured there too")
    parser.add_argument("--instructions", action="store_true",
                        help="count (a)'s instructions per period with valgrind (this tree and the baseline) and stop")
    parser.add_argument("--measure-inprocess", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.instructions:
        if shutil.which("valgrind") is None:
            parser.error("--instructions needs valgrind on PATH (apt-get install valgrind)")
        this = instructions_per_period(sys.executable)
        print(f"(a) in-process with NPZ recording, CPU instructions per period (callgrind): this tree {this:,.0f}")
        if args.baseline_python:
            base = instructions_per_period(args.baseline_python)
            print(f"    baseline ({args.baseline_python}) {base:,.0f}; ratio {this / base:.3f} "
                  f"(below 1: fewer instructions than the baseline)")
        return
    if args.measure_inprocess:  # one (a) figure for --baseline-python, as JSON
        with tempfile.TemporaryDirectory() as tmp:
            rate, _, loop_rate, cpu_rate = closed_loop("inprocess:an1017", args.seconds, tmp, "npz")
            print(json.dumps({"rate": rate, "loop_rate": loop_rate, "cpu_rate": cpu_rate}))
        return
    if args.baseline_python:
        pairs: dict[str, list[tuple[float, float, float]]] = {"this": [], "baseline": []}
        for _ in range(args.repeats):  # interleaved: both see the same machine load
            pairs["this"].append(measure_in(sys.executable, args.seconds))
            pairs["baseline"].append(measure_in(args.baseline_python, args.seconds))
        for i, what in enumerate(("with NPZ recording", "the loop alone (without the .npz's close)",
                                  "per CPU second of the process, with the close (the machine's other load left out)")):
            this = statistics.median(r[i] for r in pairs["this"])
            base = statistics.median(r[i] for r in pairs["baseline"])
            print(f"(a) in-process, {what}, median of {args.repeats}: this tree {this:,.0f} periods/s, "
                  f"baseline ({args.baseline_python}) {base:,.0f} periods/s, ratio {this / base:.3f}")
            print(f"    runs this: {', '.join(f'{r[i]:,.0f}' for r in pairs['this'])}; "
                  f"baseline: {', '.join(f'{r[i]:,.0f}' for r in pairs['baseline'])}")
    from bench_link import frame_sizes, raw_echo  # this tree's only: the baseline interpreter skips it

    sensors_len, drive_len = frame_sizes()
    rates: dict[str, list[float]] = {"inproc_npz": [], "inproc_npz_loop": [], "inproc_csv": [], "pty": [], "raw": []}
    backend = "?"
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):  # interleaved, so drifts in machine load hit every figure alike
            rate, backend, loop_rate, _ = closed_loop("inprocess:an1017", args.seconds, tmp, "npz")
            rates["inproc_npz"].append(rate)
            rates["inproc_npz_loop"].append(loop_rate)
            rates["inproc_csv"].append(closed_loop("inprocess:an1017", args.seconds, tmp, "csv")[0])
            rates["pty"].append(closed_loop("emulator:an1017", args.seconds, tmp, "npz")[0])
            rates["raw"].append(raw_echo(int(args.seconds * 20_000), sensors_len, drive_len).rate)
    med = {k: statistics.median(v) for k, v in rates.items()}
    real = 1e6 / PERIOD_US
    print(f"AN1017 + Hurst closed loop, lockstep, {PERIOD_US} us periods, {args.seconds:g} s simulated, "
          f"median of {args.repeats} (plant backend: {backend})")
    print(f"  (a) in-process, NPZ recording : {med['inproc_npz']:9,.0f} periods/s = {med['inproc_npz'] / real:5.2f}x real time (goal >= 10x)")
    print(f"      the same, loop only       : {med['inproc_npz_loop']:9,.0f} periods/s = {med['inproc_npz_loop'] / real:5.2f}x real time (without writing the final .npz)")
    print(f"      in-process, CSV recording : {med['inproc_csv']:9,.0f} periods/s = {med['inproc_csv'] / real:5.2f}x real time")
    print(f"  (b) emulator process on a pty : {med['pty']:9,.0f} periods/s = {med['pty'] / real:5.2f}x real time")
    print(f"      raw pty echo {sensors_len}/{drive_len} B    : {med['raw']:9,.0f} round trips/s")
    print(f"      (b) / raw echo            : {med['pty'] / med['raw']:6.1%} (goal >= 50 %)")


if __name__ == "__main__":
    main()
