"""Lockstep closed-loop speed of the bench: AN1017 firmware + Hurst plant (and the FOC on the servo),
every period recorded.

Prints, in one run (medians over interleaved repeats; the machine is a noisy 2-core VM), each as
periods/s and real-time factor at 20 kHz exchanges:
  the C floor: the plant's and the firmware's C steps alone, no session (the C span of
      hilbench/bench/_span.c run directly, nothing recorded, no part);
  (a) the firmware in-process with NPZ recording (the session's C span between events), the loop
      alone, the same with CSV recording, and the session's Python loop (HILBENCH_SESSION_SPAN=python);
      and the NPZ run, the CSV run and the C floor per CPU second of the simulating thread (an extra
      figure: the NPZ archive's columns and the CSV rows are written by threads of their own, whose
      CPU it leaves out; the acceptance figure is the wall-clock one);
  the FOC on the 200 W servo: its C floor and in-process with NPZ recording;
  (b) the firmware as its own process on a pty: the Python emulator and the SIL build of the C
      firmware, and a raw two-process pty echo of the same frame sizes as their baseline;
and ends with the ratios (issue 28's acceptance lines, wall clock, in the same run; each the median of
the repeats' own ratios, the ratio of the medians beside it): in-process NPZ / C floor, CSV / NPZ, FOC
NPZ / FOC C floor, emulator / raw echo, SIL / raw echo; and one extra line,
not an acceptance line: the NPZ run's and the C floor's periods per CPU second of the simulating
thread (the recording's own thread left out). Each NPZ run records to a fresh path (the previous
repeat's file removed before timing).

With ``--baseline-python PY`` it also runs (a) under another installation of hilbench (e.g. the
commit before a change, installed in its own venv), interleaved with this one, and prints the
ratio: the "no slowdown" check of a redesign, measured in the same run.

With ``--instructions`` (needs valgrind) it counts the CPU instructions of (a) per period instead,
for this tree and the baseline: deterministic, so a few-percent difference is visible on a shared,
noisy machine where wall-clock medians scatter by as much. Each interpreter runs (a) under
callgrind for a short and a long scenario; the difference over the extra periods is the per-period
cost with start-up, handshake and imports cancelled out (the close of the recording stays in).

    python benchmarks/bench_session.py [--seconds 1.0] [--repeats 5] [--no-process] [--baseline-python PY] [--instructions]
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


SERVO = Path(__file__).resolve().parent.parent / "bench_configs" / "servo_200w.toml"


def foc_scenario(seconds: float) -> tuple[Event, ...]:
    """The servo at 1000 rpm for the timed span (bench_foc.py's)."""
    return (Event(at_s=0.0, press="s2"), Event(at_s=0.2, params=(("ref_rpm", 1000.0),)), Event(at_s=seconds, end=True))


def _session(handle: object, spec: str, seconds: float | None, config: Path | None, events: tuple[Event, ...],
             recorder: Recorder | None) -> tuple[Session, Plant]:
    cfg = load_config(config)
    options = dataclasses.replace(settings.session_options(cfg), duration_s=seconds, period_us=PERIOD_US)
    plant = Plant(plant_params_from_config(cfg), seed=0, substeps=cfg.plant.substeps)
    session = Session(handle.target, plant, events, options, recorder=recorder,  # type: ignore[attr-defined]
                      link_stats=handle.link_stats, target_label=spec)  # type: ignore[attr-defined]
    session.handshake()
    return session, plant


def closed_loop(spec: str, seconds: float, record_dir: str, fmt: str, *, config: Path | None = None,
                c_span: bool = True) -> tuple[float, str, float, float, float]:
    """Periods/s of one lockstep run against ``spec``, every period recorded to ``fmt``.

    Returns (periods/s including closing the recording, plant backend, periods/s of the loop alone,
    periods per CPU second of this process including the close: time the machine's other load took
    from it left out, periods per CPU second of the simulating thread alone: the recording's own
    thread left out, as on a machine with a CPU free for it).
    """
    events = foc_scenario(seconds) if config == SERVO else scenario(seconds)
    path = Path(record_dir) / f"bench.{fmt}"
    path.unlink(missing_ok=True)  # the last repeat's recording: freeing its pages is not this run's work
    with open_target(spec, timeout_s=2.0) as handle:
        recorder = Recorder(path, {"bench": True}, flush_rows=20_000)
        session, plant = _session(handle, spec, seconds, config, events, recorder)
        session.c_span = c_span
        t0, cpu0, thread0 = time.perf_counter(), time.process_time(), time.thread_time()
        summary = session.run()
        elapsed, cpu = time.perf_counter() - t0, time.process_time() - cpu0
        thread = time.thread_time() - thread0
    return (summary.periods / elapsed, getattr(plant, "backend", "python"), summary.periods / summary.wall_s,
            summary.periods / cpu if cpu > 0 else float("nan"), summary.periods / thread if thread > 0 else float("nan"))


def warm_up(record_dir: str, seconds: float) -> None:
    """A run as long as the timed ones first (NPZ and CSV), so the timed ones hold no first-run costs:
    modules a run imports lazily (the NPZ writer at the close) are compiled from source at each run
    where no bytecode is cached (PYTHONDONTWRITEBYTECODE=1 on an editable tree, against a
    pip-installed baseline with its .pyc: ~14 ms of a 1 s run's ~100 ms), and the first run's page
    faults (its row buffers and the writers' chunk buffers, which later runs reuse: a process runs
    many runs, a sweep or a test suite). --instructions warms its short and long runs alike instead
    (the short run's length), so the warm-up cancels out of their difference; the long run's buffers
    beyond that length then fault in its own count, a small bias against the NPZ run."""
    for fmt in ("npz", "csv"):
        closed_loop("inprocess:an1017", seconds, record_dir, fmt)


def c_floor(spec: str, seconds: float, *, config: Path | None = None, thread_cpu: list[float] | None = None) -> float:
    """Periods/s of the plant's and the firmware's C steps alone: a session brought to speed (its
    scenario's start), then its C span run directly for ``seconds`` with nothing recorded (and the
    periods per CPU second of this thread appended to ``thread_cpu``)."""
    warm_s = 0.3 if config == SERVO else 0.05
    events = foc_scenario(warm_s + seconds) if config == SERVO else scenario(warm_s + seconds)
    with open_target(spec, timeout_s=2.0) as handle:
        session, _ = _session(handle, spec, None, config, events, None)
        session.begin()
        session.advance(int(warm_s * 1e6 / PERIOD_US))
        span = session._c_span(None, sampled=False)
        if span is None:
            raise SystemExit(f"{spec}: no C span here (the C cores are not built)")
        k, n = session.periods_done, int(seconds * 1e6 / PERIOD_US)
        t0, thread0 = time.perf_counter(), time.thread_time()
        done = span.run(k, k + n, session.scenario.buttons, session.ref_rpm, session._edge_s, session.drive,
                        session._hall_before) - k
        elapsed, thread = time.perf_counter() - t0, time.thread_time() - thread0
        if thread_cpu is not None:
            thread_cpu.append(n / thread if thread > 0 else float("nan"))
        session.end()
    if done < n:
        raise SystemExit(f"{spec}: the C floor's span stopped after {done} of {n} periods (the comparator tripped, or too many edges)")
    return n / elapsed


def measure_in(python: str, seconds: float) -> tuple[float, float, float]:
    """(a) measured by another interpreter (another hilbench installation) running this file:
    (periods/s with the recording's close, periods/s of the loop alone, periods per CPU second)."""
    out = subprocess.run([python, __file__, "--measure-inprocess", "--seconds", str(seconds)], capture_output=True,
                         text=True, timeout=600, cwd=tempfile.gettempdir(), check=True)
    figures = json.loads(out.stdout.strip().splitlines()[-1])
    return float(figures["rate"]), float(figures.get("loop_rate", "nan")), float(figures.get("cpu_rate", "nan"))


def instructions_per_period(python: str, short_s: float = 0.2, long_s: float = 1.2,
                            what: str = "--measure-inprocess") -> float:
    """(a)'s CPU instructions per period under ``python`` (``what="--measure-floor"``: the C
    floor's), counted by callgrind (deterministic)."""
    totals = []
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONHASHSEED="0")  # no BLAS threads spinning, fixed hashes
    with tempfile.TemporaryDirectory() as tmp:
        for seconds in (short_s, long_s):
            out = Path(tmp) / "callgrind.out"
            subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", python, __file__,
                            what, "--seconds", str(seconds), "--warm-seconds", str(short_s)],
                           capture_output=True, text=True, timeout=900, cwd=tmp, env=env, check=True)
            line = next(ln for ln in out.read_text().splitlines() if ln.startswith(("summary:", "totals:")))
            totals.append(int(line.split()[1]))
    return (totals[1] - totals[0]) / ((long_s - short_s) * 1e6 / PERIOD_US)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=1.0, help="simulated seconds per run")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--baseline-python", default=None, metavar="PY",
                        help="an interpreter with another hilbench installed: (a) is measured there too")
    parser.add_argument("--instructions", action="store_true",
                        help="count (a)'s instructions per period with valgrind (this tree and the baseline) and stop")
    parser.add_argument("--no-process", action="store_true",
                        help="leave out the process paths (emulator, SIL, raw echo): the in-process figures only")
    parser.add_argument("--measure-inprocess", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--measure-floor", action="store_true", help=argparse.SUPPRESS)
    # --instructions: the same warm-up in its short and long runs, so that it cancels out of their difference
    # (--measure-floor has no warm-up run and ignores it)
    parser.add_argument("--warm-seconds", type=float, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.instructions:
        if shutil.which("valgrind") is None:
            parser.error("--instructions needs valgrind on PATH (apt-get install valgrind)")
        this = instructions_per_period(sys.executable)
        floor = instructions_per_period(sys.executable, what="--measure-floor")
        print(f"(a) in-process with NPZ recording, CPU instructions per period (callgrind): this tree {this:,.0f}")
        print(f"    C floor (plant + firmware C steps, no session): {floor:,.0f}")
        print(f"ratio in-process NPZ / C floor (instructions, floor / NPZ): {floor / this:.2f}")
        if args.baseline_python:
            base = instructions_per_period(args.baseline_python)
            print(f"    baseline ({args.baseline_python}) {base:,.0f}; ratio {this / base:.3f} "
                  f"(below 1: fewer instructions than the baseline)")
        return
    if args.measure_floor:  # the C floor once (for --instructions)
        print(json.dumps({"rate": c_floor("inprocess:an1017", args.seconds)}))
        return
    if args.measure_inprocess:  # one (a) figure for --baseline-python, as JSON
        with tempfile.TemporaryDirectory() as tmp:
            warm_up(tmp, args.seconds if args.warm_seconds is None else args.warm_seconds)
            rate, _, loop_rate, cpu_rate, _ = closed_loop("inprocess:an1017", args.seconds, tmp, "npz")
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
    run_paths(args)


def run_paths(args: argparse.Namespace) -> None:
    """Every path of the module docstring, interleaved, then the figures and the ratio lines."""
    from bench_link import frame_sizes, raw_echo  # this tree's only: the baseline interpreter skips it
    from bench_sil import emulator_loop, sil_loop

    sensors_len, drive_len = frame_sizes()
    names = ("floor", "npz", "npz_loop", "csv", "python", "foc_floor", "foc_npz", "floor_thread", "npz_thread",
             "csv_thread") + (
        () if args.no_process else ("emulator", "sil", "raw"))
    rates: dict[str, list[float]] = {name: [] for name in names}
    backend = "?"
    exe = None
    if not args.no_process:
        from hilbench.targets.sil import build_sil

        exe = build_sil()
    seconds = args.seconds
    with tempfile.TemporaryDirectory() as tmp:
        warm_up(tmp, seconds)
        for _ in range(args.repeats):  # interleaved, so drifts in machine load hit every figure alike
            rates["floor"].append(c_floor("inprocess:an1017", seconds, thread_cpu=rates["floor_thread"]))
            rate, backend, loop_rate, _, thread_rate = closed_loop("inprocess:an1017", seconds, tmp, "npz")
            rates["npz"].append(rate)
            rates["npz_loop"].append(loop_rate)
            rates["npz_thread"].append(thread_rate)
            csv = closed_loop("inprocess:an1017", seconds, tmp, "csv")
            rates["csv"].append(csv[0])
            rates["csv_thread"].append(csv[4])
            rates["python"].append(closed_loop("inprocess:an1017", seconds, tmp, "npz", c_span=False)[0])
            rates["foc_floor"].append(c_floor("inprocess:foc", seconds, config=SERVO))
            rates["foc_npz"].append(closed_loop("inprocess:foc", seconds, tmp, "npz", config=SERVO)[0])
            if exe is not None:
                rates["emulator"].append(emulator_loop(seconds, tmp).rate)
                rates["sil"].append(sil_loop(exe, seconds, tmp).rate)
                rates["raw"].append(raw_echo(int(seconds * 1e6 / PERIOD_US), sensors_len, drive_len).rate)
    med = {k: statistics.median(v) for k, v in rates.items()}
    real = 1e6 / PERIOD_US

    def line(label: str, name: str, note: str = "") -> None:
        runs = ", ".join(f"{r:,.0f}" for r in rates[name])
        print(f"  {label:<38}: {med[name]:9,.0f} periods/s = {med[name] / real:6.2f}x real time{note}  [{runs}]")

    print(f"Closed loop, lockstep, {PERIOD_US} us exchanges, {seconds:g} s simulated per run, median of "
          f"{args.repeats} interleaved runs [each run] (plant backend: {backend})")
    line("C floor AN1017 (plant + firmware C)", "floor", " (no session, nothing recorded)")
    line("(a) in-process AN1017, NPZ recording", "npz", " (goal >= 50x, >= 70 % of the floor)")
    line("    the same, loop only", "npz_loop", " (without writing the final .npz)")
    line("    the same, per CPU s of its thread", "npz_thread", " (the recording's thread and other load left out)")
    line("    C floor, per CPU s of its thread", "floor_thread")
    line("    in-process AN1017, CSV recording", "csv", " (goal >= 60 % of NPZ)")
    line("    the same, per CPU s of its thread", "csv_thread", " (the CSV writer's thread and other load left out)")
    line("    the session's Python loop, NPZ", "python", " (HILBENCH_SESSION_SPAN=python: the reference)")
    line("C floor FOC (servo, plant + firmware C)", "foc_floor")
    line("FOC in-process, NPZ recording", "foc_npz", " (goal >= 40x)")
    if exe is not None:
        line("(b) emulator process on a pty", "emulator")
        line("    SIL firmware process on a pty", "sil")
        line(f"    raw pty echo {sensors_len}/{drive_len} B", "raw", " (round trips)")
    def ratio(label: str, top: str, bottom: str) -> None:
        """An acceptance ratio: the median of the repeats' own ratios (each repeat runs every path back
        to back, so a drift in the machine's load between repeats cancels), the ratio of the medians
        beside it."""
        paired = statistics.median(a / b for a, b in zip(rates[top], rates[bottom]))
        print(f"ratio {label}: {paired:.2f} (ratio of the medians {med[top] / med[bottom]:.2f})")

    ratio("in-process NPZ / C floor", "npz", "floor")
    print(f"extra, not an acceptance line: periods per CPU s of the simulating thread, NPZ run / C floor "
          f"{med['npz_thread'] / med['floor_thread']:.2f} (the recording's thread's CPU left out; no wall clock)")
    ratio("in-process CSV / NPZ", "csv", "npz")
    print(f"extra, not an acceptance line: periods per CPU s of the simulating thread, CSV run / NPZ run "
          f"{med['csv_thread'] / med['npz_thread']:.2f} (each writer's own thread's CPU left out)")
    ratio("in-process NPZ C span / Python loop", "npz", "python")
    ratio("FOC NPZ / FOC C floor", "foc_npz", "foc_floor")
    if exe is not None:
        ratio("emulator / raw echo", "emulator", "raw")
        ratio("SIL / raw echo", "sil", "raw")


if __name__ == "__main__":
    main()
