"""The switching inverter against ngspice on long runs, and the FOC servo's phase-current THD checked
on the duties its own closed loop made.

(a) Open loop, one whole electrical turn each (tests/test_switching_spice.py runs 10 ms of these;
    here the FOC's 400 rpm: 50 ms = 500 PWM periods): per-phase RMS difference (% of rated) and
    fundamental difference against ngspice, light and rated load, with and without the dead time.
(b) The 200 W servo's closed loop (F2812 FOC target, switching plant, dead time on) at 400 rpm
    under 0.05 N·m and 0.637 N·m: its Drives over two electrical turns (100 ms, after 1.4 s) are
    replayed open loop, at the loop's mean speed from its state at the window's start, into ngspice,
    the switching plant and the averaged plant (dead band "sign" and "edges"). Each prints the THD
    of phase a's PWM-period means (harmonics 2..40 of 20 Hz), next to the closed loop's own; the
    switching plant's equal to ngspice's says the closed-loop figure in docs/foc.md is the circuit's.

    python benchmarks/bench_switching.py [--only open|replay]   (needs ngspice; minutes)
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from _foc_bench import IndexPlant, servo_params, thd  # noqa: E402
from _spice import BridgeCase, fundamental, run_ngspice, run_plant, steady_duties  # noqa: E402

from hilbench.bench.scenario import Event  # noqa: E402
from hilbench.bench.session import Session, SessionOptions  # noqa: E402
from hilbench.targets.foc.target import FocTarget  # noqa: E402

SERVO = dict(rs_ohm=5.4, l_h=6.64e-3, psi_wb=0.08336, pole_pairs=3)
RATED_A = 1.2
KT = 1.5 * 3 * 0.08336


def pwm_means(t: np.ndarray, i: np.ndarray, t_pwm: float, n: int) -> np.ndarray:
    """Means of each column over [k T, (k+1) T), k < n, from samples (linear between them)."""
    grid = np.linspace(0.0, n * t_pwm, n * 1000 + 1)
    fine = np.column_stack([np.interp(grid, t, i[:, k]) for k in range(i.shape[1])])
    seg = fine[:-1].reshape(n, 1000, -1)
    return (seg.sum(axis=1) - seg[:, 0] / 2 + fine[1000::1000] / 2) / 1000


def open_loop(ngspice: str) -> None:
    print("(a) open loop at 400 rpm (20 Hz), one electrical turn = 500 PWM periods, against ngspice")
    for i_q, dead in ((1.697, 0.0), (1.697, 3.2e-6), (0.133, 0.0), (0.133, 3.2e-6)):
        comp = 4 / math.pi * dead * 1e4 * 311.1
        duties = steady_duties(**SERVO, speed_rpm=400.0, vbus_v=311.1, period_s=50e-6, n_periods=1000, counts=7500,
                               i_q_a=i_q, theta0_rad=0.3, dead_comp_v=comp)
        case = BridgeCase(**SERVO, speed_rpm=400.0, vbus_v=311.1, pwm_freq_hz=1e4, dead_s=dead, pulse_centre="peak",
                          period_s=50e-6, counts=7500, duties=duties, theta0_rad=0.3, i0_dq=(0.0, i_q))
        t0 = time.perf_counter()
        ts, i_spice = run_ngspice(ngspice, case, max_step_s=5e-7)
        spice_s = time.perf_counter() - t0
        tm, i_model = run_plant(case, points=10)
        i_ref = np.column_stack([np.interp(tm, ts, i_spice[:, k]) for k in range(3)])
        rms = np.sqrt(np.mean((i_model - i_ref) ** 2, axis=0)) / RATED_A * 100
        fs = [fundamental(tm, i_ref[:, k], 20.0) for k in range(3)]
        fm = [fundamental(tm, i_model[:, k], 20.0) for k in range(3)]
        rel = [abs(a - b) / abs(a) * 100 for a, b in zip(fs, fm)]
        print(f"  i_q {i_q} A, dead time {dead * 1e6:.1f} us: RMS difference {np.round(rms, 3)} % of rated, "
              f"fundamental {abs(fs[0]):.4f} A, differs by {np.round(rel, 3)} % (ngspice {spice_s:.1f} s)")


def closed_loop_window(load_nm: float, t0_s: float, turns: int):
    """The switching plant's FOC closed loop at 400 rpm: (duties per exchange over the window, the
    plant's state at its start, mean speed, the recorded phase-a current over it)."""
    plant = IndexPlant(servo_params(dead_time_enabled=True, model="switching"), seed=0, substeps=1)
    target = FocTarget()
    k0 = round(t0_s / 50e-6)
    k0 -= k0 % 2  # an underflow
    n = turns * 1000  # 50 ms per turn at 20 Hz = 1000 exchanges
    rows: list[tuple[float, float, float]] = []
    state: dict[str, float] = {}
    speeds: list[float] = []
    currents: list[float] = []
    scale = 1.0 / 7500
    inner = target.step

    def step(sensors):  # type: ignore[no-untyped-def]
        d = inner(sensors)
        k = len(calls)  # the exchange's index: the plant is at its period's start
        calls.append(1)
        if k == k0:
            state.update(theta=plant.theta_e, i_d=plant.i_d, i_q=plant.i_q, sw_u=plant._sw_u)
        if k0 <= k < k0 + n:
            rows.append((d.duty_a * scale, d.duty_b * scale, d.duty_c * scale))
            speeds.append(plant.w_m)
        if k0 < k <= k0 + n:
            currents.append(plant.i_a)
        return d

    calls: list[int] = []
    target.step = step  # type: ignore[method-assign]
    events = [Event(at_s=0.0, press="s2"), Event(at_s=0.2, load_nm=load_nm), Event(at_s=0.25, params=(("ref_rpm", 400.0),)),
              Event(at_s=(k0 + n + 4) * 50e-6, end=True)]
    Session(target, plant, events, SessionOptions(period_us=50, observe_every_periods=10 ** 9)).run()
    return tuple(rows), state, float(np.mean(speeds)), np.array(currents)


def replay(ngspice: str) -> None:
    print("(b) the FOC closed loop's own duties (switching plant, dead time 3.2 us, 400 rpm), replayed open loop")
    for load in (0.05, 0.637):
        duties, st, w, i_closed = closed_loop_window(load, 1.4, 2)
        rpm = w * 60 / (2 * math.pi)
        case = BridgeCase(**SERVO, speed_rpm=rpm, vbus_v=311.1, pwm_freq_hz=1e4, dead_s=3.2e-6, pulse_centre="peak",
                          period_s=50e-6, counts=7500, duties=duties, theta0_rad=st["theta"], i0_dq=(st["i_d"], st["i_q"]))
        n_pwm = len(duties) // 2
        f1 = rpm / 60 * 3
        closed = thd(i_closed.reshape(-1, 2).mean(axis=1), 1e-4, f1)  # the loop's own, per PWM period
        out = [f"closed loop {closed * 100:.2f} %"]
        t0 = time.perf_counter()
        ts, i_spice = run_ngspice(ngspice, case, max_step_s=5e-7)
        spice_s = time.perf_counter() - t0
        out.append(f"ngspice {thd(pwm_means(ts, i_spice, 1e-4, n_pwm)[:, 0], 1e-4, f1) * 100:.2f} %")
        for model in ("switching", "average", "average-edges"):
            tm, im = run_plant(case, model=model, points=10 if model == "switching" else 1)
            out.append(f"{model} {thd(pwm_means(tm, im, 1e-4, n_pwm)[:, 0], 1e-4, f1) * 100:.2f} %")
        print(f"  {load} N*m (i_q ~ {load / KT:.3f} A), {rpm:.1f} rpm: THD of i_a: " + ", ".join(out)
              + f" (ngspice {spice_s:.0f} s)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=("open", "replay"))
    args = ap.parse_args()
    ngspice = shutil.which("ngspice")
    if ngspice is None:
        sys.exit("bench_switching: ngspice is not on PATH (apt-get install ngspice)")
    if args.only != "replay":
        open_loop(ngspice)
    if args.only != "open":
        replay(ngspice)


if __name__ == "__main__":
    main()
