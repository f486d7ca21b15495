"""Plant cost per 50 us period and real-time factor (both bench motors, both backends, 1 and 2
RK4 substeps), sensor-read and OFF-coast cost, the switching inverter's cost per period against the
averaged one in the same run, the FOC closed loop's real-time factor in process with each (goal for
the switching model: >= 5x real time at 10 kHz), and the same open-loop start-up of the Hurst motor
on gym-electric-motor and motulator next to ours in one table.

Run: python benchmarks/bench_plant.py [--switching-only]   (medians of 5 runs; the VM is noisy,
compare ratios)

Peers are never project dependencies. They run in their own interpreter: $HILBENCH_PEER_PYTHON,
else /tmp/peers/bin/python if it exists, else this one. Install them with
    python -m venv /tmp/peers && /tmp/peers/bin/pip install gym-electric-motor motulator numpy
(about a minute). Each peer run is a subprocess that builds the model, times its start-up loop
itself (time.perf_counter around the loop only) and prints JSON.
"""

from __future__ import annotations

import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from hilbench.bench.settings import load_config

from hilbench.config import plant_params_from_config
from hilbench.plant import Plant
from hilbench.plant.model import DEFAULT_SUBSTEPS, available_backends

ROOT = Path(__file__).resolve().parent.parent
DT = 50e-6
PHI = (0.0, -2.0 * math.pi / 3.0, 2.0 * math.pi / 3.0)


def startup_cost_us(cfg_name: str, backend: str, substeps: int, vq_frac: float = 0.45, n: int = 4000) -> tuple[float, float]:
    """Median cost (us) of one plant.step and, as a baseline, of computing the duties alone."""
    params = plant_params_from_config(load_config(ROOT / "bench_configs" / cfg_name))
    vbus = params.inverter.vbus_v
    vq = vq_frac * vbus
    duty_list = []
    plant = Plant(params, backend=backend, substeps=substeps)
    for _ in range(n):  # record the duty sequence once, then time step() alone
        d = tuple(0.5 + vq * math.cos(plant.theta_e + math.pi / 2 + ph) / vbus for ph in PHI)
        duty_list.append(d)
        plant.step(*d, 1, DT)
    runs = []
    for _ in range(5):
        plant = Plant(params, backend=backend, substeps=substeps)
        step = plant.step
        t0 = time.perf_counter()
        for d in duty_list:
            step(d[0], d[1], d[2], 1, DT)
        runs.append((time.perf_counter() - t0) / n * 1e6)
    base = []
    for _ in range(5):
        t0 = time.perf_counter()
        for d in duty_list:
            pass
        base.append((time.perf_counter() - t0) / n * 1e6)
    return statistics.median(runs), statistics.median(base)


def sensor_and_off_cost_us(backend: str) -> tuple[float, float]:
    """Median cost (us) of the bench's per-period sensor reads, and of an OFF period while coasting."""
    params = plant_params_from_config(load_config(ROOT / "bench_configs" / "hurst_mclv.toml"))
    plant = Plant(params, backend=backend)
    plant.reset(speed_rad_s=100.0)
    n = 20000
    reads, off = [], []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(n):
            plant.hall_bits, plant.last_edge_s, plant.encoder_count, plant.adc_codes((1, 2, 3))
            plant.i_abc, plant.i_bus
        reads.append((time.perf_counter() - t0) / n * 1e6)
        t0 = time.perf_counter()
        for _ in range(n):
            plant.step(0.0, 0.0, 0.0, 0, DT)
        off.append((time.perf_counter() - t0) / n * 1e6)
    return statistics.median(reads), statistics.median(off)


# ------------------------------------------------------------------ peers
# The start-up every model runs: Hurst motor from rest, no load torque (viscous friction only);
# each 50 us period the duties put vq = 0.45 * Vbus on the q axis of the angle at the period
# start, held over the period (what a controller does). One script, run by the peer's
# interpreter; it times its own loop and prints one JSON line.
PEER_SCRIPT = r"""
import json, math, sys, time
peer, cfg = sys.argv[1], json.loads(sys.argv[2])
R, L, PSI, P, J, B, VBUS = (cfg[k] for k in ("r_ohm", "l_h", "psi_wb", "pole_pairs", "j_kgm2", "b_nms", "vbus_v"))
DT, N, VQ = cfg["dt_s"], cfg["periods"], cfg["vq_v"]
PHI = (0.0, -2.0 * math.pi / 3.0, 2.0 * math.pi / 3.0)

def duties(th):
    return [0.5 + VQ * math.cos(th + math.pi / 2 + ph) / VBUS for ph in PHI]

if peer == "gym-electric-motor":
    import gym_electric_motor as gem
    env = gem.make("Cont-SC-PMSM-v0",
                   motor=dict(motor_parameter=dict(p=P, l_d=L, l_q=L, j_rotor=J / 2, r_s=R, psi_p=PSI),
                              limit_values=dict(i=100.0, omega=2000.0, u=100.0, torque=10.0),
                              nominal_values=dict(i=50.0, omega=1000.0, u=VBUS, torque=1.0)),
                   load=dict(load_parameter=dict(a=0.0, b=B, c=0.0, j_load=J / 2)),  # rotor + load = J
                   supply=dict(u_nominal=VBUS), tau=DT, constraints=())
    env.reset(seed=0)
    ps = env.unwrapped.physical_system
    names = list(ps.state_names)
    ie, iw, iq = names.index("epsilon"), names.index("omega"), names.index("i_sq")
    lim = ps.limits
    th = 0.0
    t0 = time.perf_counter()
    for _ in range(N):
        s = ps.simulate([2.0 * d - 1.0 for d in duties(th)])  # B6 bridge action a = 2 * duty - 1
        th = s[ie] * lim[ie]
    t1 = time.perf_counter()
    out = dict(cost_us=(t1 - t0) / N * 1e6, speed_rad_s=float(s[iw] * lim[iw]), iq_a=float(s[iq] * lim[iq]),
               how=f"physical_system.simulate per period ({type(ps._ode_solver).__name__}: scipy.integrate.ode "
                   "dopri5, default tolerances); it Parks the phase voltages at the period start and holds the "
                   "dq voltage (we and motulator hold the stator-frame voltage), hence its different speed")
elif peer == "motulator":
    import numpy as np
    from motulator.drive import model
    from motulator.drive.utils import SynchronousMachinePars
    from motulator.common.model._simulation import Delay
    par = SynchronousMachinePars(n_p=P, R_s=R, L_d=L, L_q=L, psi_f=PSI)
    mdl = model.Drive(model.VoltageSourceConverter(u_dc=VBUS), model.SynchronousMachine(par),
                      model.StiffMechanicalSystem(J=J, B_L=B))
    mdl.delay = Delay(0)  # duties act in the period they are computed for, as in our loop

    class OpenLoop:
        n = 0

        def __call__(self, m):
            self.n += 1
            return DT, duties(float(np.angle(m.machine.state.exp_j_theta_m)))

        def post_process(self):
            pass

    ctrl = OpenLoop()
    sim = model.Simulation(mdl, ctrl)
    t0 = time.perf_counter()
    sim.simulate(t_stop=(N - 1) * DT)  # loops while t <= t_stop: N periods
    t1 = time.perf_counter()
    out = dict(cost_us=(t1 - t0) / ctrl.n * 1e6, speed_rad_s=float(mdl.mechanics.data.w_M[-1]),
               iq_a=float(np.imag(mdl.machine.data.i_s[-1])),
               how="Simulation.simulate: scipy solve_ivp RK45 per period (default rtol 1e-3, atol 1e-6), "
                   "zero-order-held duties, computational delay 0; time includes its post-processing")
print(json.dumps(out))
"""

PEERS = (("gym-electric-motor", "gym_electric_motor"), ("motulator", "motulator"))
INSTALL_HINT = "python -m venv /tmp/peers && /tmp/peers/bin/pip install gym-electric-motor motulator numpy"


def peer_python() -> str:
    env = os.environ.get("HILBENCH_PEER_PYTHON")
    if env:
        return env
    return "/tmp/peers/bin/python" if Path("/tmp/peers/bin/python").exists() else sys.executable


def startup_case(params, periods: int) -> dict:
    m = params.motor
    return dict(r_ohm=m.rs_ohm, l_h=m.ld_h, psi_wb=m.psi_wb, pole_pairs=m.pole_pairs, j_kgm2=m.j_kgm2,
                b_nms=m.b_nms_per_rad, vbus_v=params.inverter.vbus_v, dt_s=DT, periods=periods,
                vq_v=0.45 * params.inverter.vbus_v)


def ours_startup(params, case: dict, backend: str, runs: int = 5) -> tuple[float, float, float]:
    """Median cost (us/period) of our plant on the peers' start-up loop (duties computed in the loop)."""
    vq, vbus = case["vq_v"], case["vbus_v"]
    c0, c1, c2 = (math.pi / 2 + ph for ph in PHI)
    costs = []
    for _ in range(runs):
        plant = Plant(params, backend=backend)
        step, cos = plant.step, math.cos
        t0 = time.perf_counter()
        for _ in range(case["periods"]):
            th = plant.theta_e
            step(0.5 + vq * cos(th + c0) / vbus, 0.5 + vq * cos(th + c1) / vbus, 0.5 + vq * cos(th + c2) / vbus, 1, DT)
        costs.append((time.perf_counter() - t0) / case["periods"] * 1e6)
    return statistics.median(costs), plant.w_m, plant.i_q


def run_peer(py: str, script: str, name: str, case: dict, runs: int = 3) -> tuple[dict | None, str]:
    """Median of `runs` subprocess runs, or None and why not."""
    results = []
    for _ in range(runs):
        try:
            proc = subprocess.run([py, script, name, json.dumps(case)], capture_output=True, text=True, timeout=600)
        except (OSError, subprocess.TimeoutExpired) as exc:
            return None, f"could not run {py}: {exc}"
        if proc.returncode != 0:
            last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
            return None, f"failed: {last}"
        results.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    res = dict(results[-1])
    res["cost_us"] = statistics.median(r["cost_us"] for r in results)
    return res, ""


def peers_table(periods: int = 2000) -> None:
    params = plant_params_from_config(load_config(ROOT / "bench_configs" / "hurst_mclv.toml"))
    case = startup_case(params, periods)
    print(f"\nsame open-loop start-up on every model: Hurst (R {case['r_ohm']} ohm, L {case['l_h'] * 1e3:.2f} mH, "
          f"psi {case['psi_wb'] * 1e3:.3f} mWb, p {case['pole_pairs']}, J {case['j_kgm2']:g}, B {case['b_nms']:g}, "
          f"{case['vbus_v']:g} V), vq {case['vq_v']:.1f} V on the q axis of the period-start angle, from rest, "
          f"{periods} periods of 50 us ({periods * DT:g} s)")
    rows = []
    for backend in available_backends():  # the default backend first: it is the baseline
        cost, w, iq = ours_startup(params, case, backend)
        rows.append((f"hilbench ({backend})", cost, w, iq,
                     f"RK4 in dq, {DEFAULT_SUBSTEPS} substeps per period, stator-frame voltage held"))
    py = peer_python()
    with tempfile.TemporaryDirectory() as tmp:
        script = str(Path(tmp) / "peer_startup.py")
        Path(script).write_text(PEER_SCRIPT)
        for name, mod in PEERS:
            probe = subprocess.run([py, "-c", f"import {mod}"], capture_output=True, text=True)
            if probe.returncode != 0:
                print(f"{name}: not importable by {py} (install: {INSTALL_HINT})")
                continue
            res, why = run_peer(py, script, name, case)
            if res is None:
                print(f"{name}: could not run the start-up: {why}")
                continue
            rows.append((name, res["cost_us"], res["speed_rad_s"], res["iq_a"], res["how"]))
    ref = rows[0][1]
    print(f"{'model':22s} {'us/period':>10s} {'real-time':>10s} {'cost/ours':>9s} {'end speed':>10s} {'end iq':>8s}  integrates")
    for name, cost, w, iq, how in rows:
        print(f"{name:22s} {cost:10.2f} {50.0 / cost:9.2f}x {cost / ref:8.1f}x {w:6.2f} r/s {iq:6.4f} A  {how}")
    print(f"(medians: ours of 5 runs, peers of 3 subprocess runs; cost/ours against {rows[0][0]}; peers via {py})")


def switching_params(cfg_name: str, model: str):
    """A bench config's plant with its dead time on and the inverter `model`; the PWM timing of the
    target each config is written for (Hurst: AN1017's dsPIC, pulses on the counter's zero; servo:
    the F2812's, on its peak)."""
    import dataclasses

    from hilbench.plant.params import PwmTiming

    from hilbench.plant.params import ProtectionParams

    params = plant_params_from_config(load_config(ROOT / "bench_configs" / cfg_name))
    inv = dataclasses.replace(params.inverter, model=model, dead_time_enabled=True)
    return dataclasses.replace(params, inverter=inv, pwm=PwmTiming("zero" if "hurst" in cfg_name else "peak"),
                               protection=ProtectionParams(0.0, False, 0.0, 0.0, 0.0))


def switching_cost_us(cfg_name: str, backend: str, model: str, n: int) -> float:
    """Median cost (us) of one 50 us plant.step on an open-loop start-up (vq about 3 A worth of the
    motor's resistance at rest), dead time on."""
    params = switching_params(cfg_name, model)
    vbus = params.inverter.vbus_v
    vq = 3.0 * params.motor.rs_ohm
    duty_list = []
    plant = Plant(params, backend=backend, substeps=1)
    for _ in range(n):
        d = tuple(0.5 + vq * math.cos(plant.theta_e + math.pi / 2 + ph) / vbus for ph in PHI)
        duty_list.append(d)
        plant.step(*d, 1, DT)
    runs = []
    for _ in range(5):
        plant = Plant(params, backend=backend, substeps=1)
        step = plant.step
        t0 = time.perf_counter()
        for d in duty_list:
            step(d[0], d[1], d[2], 1, DT)
        runs.append((time.perf_counter() - t0) / n * 1e6)
    return statistics.median(runs)


def foc_closed_loop_rt(model: str, seconds: float) -> float:
    """Real-time factor of the FOC closed loop in process (FOC C core, C plant, NPZ recording,
    0 -> 1000 rpm, dead time on) with the inverter `model`."""
    import dataclasses

    from hilbench.bench.recorder import Recorder
    from hilbench.bench.scenario import Event
    from hilbench.bench.session import Session, SessionOptions
    from hilbench.targets.foc import PROFILE
    from hilbench.targets.foc.target import FocTarget

    cfg = load_config(ROOT / "bench_configs" / "servo_200w.toml")
    params = plant_params_from_config(cfg, PROFILE.pwm_timing)
    params = dataclasses.replace(params, inverter=dataclasses.replace(params.inverter, model=model))
    plant = Plant(params, seed=0, substeps=cfg.plant.substeps)
    events = (Event(at_s=0.0, press="s2"), Event(at_s=0.2, params=(("ref_rpm", 1000.0),)), Event(at_s=seconds, end=True))
    with tempfile.TemporaryDirectory() as tmp:
        session = Session(FocTarget(), plant, events, SessionOptions(period_us=50, observe_every_periods=10 ** 9),
                          recorder=Recorder(Path(tmp) / "foc.npz", {"bench": "switching"}))
        session.handshake()
        t0 = time.perf_counter()
        session.run()
        wall = time.perf_counter() - t0
    return seconds / wall


def switching_section(repeats: int = 3, seconds: float = 1.0) -> None:
    print("\nswitching inverter ([inverter] model = \"switching\", dead time on) against the averaged one, same run;"
          " one 50 us step each (Hurst: one 20 kHz PWM period; servo: half a 10 kHz one)")
    for cfg in ("hurst_mclv.toml", "servo_200w.toml"):
        for backend in available_backends():
            n = 2000 if backend == "c" else 300
            avg = switching_cost_us(cfg, backend, "average", n)
            sw = switching_cost_us(cfg, backend, "switching", n)
            per_pwm = sw * (1 if "hurst" in cfg else 2)
            print(f"  {cfg:16s} {backend:6s} switching {sw:7.2f} us/step ({per_pwm:7.2f} us per PWM period), "
                  f"averaged {avg:5.2f} us/step: ratio {sw / avg:5.1f}x")
    rts = {m: [] for m in ("average", "switching")}
    for _ in range(repeats):
        for model in rts:
            rts[model].append(foc_closed_loop_rt(model, seconds))
    avg_rt, sw_rt = statistics.median(rts["average"]), statistics.median(rts["switching"])
    print(f"  FOC closed loop in process (C firmware core, C plant, NPZ), {seconds:g} s simulated, median of {repeats}:"
          f" switching {sw_rt:.2f}x real time at 10 kHz (goal >= 5x), averaged {avg_rt:.2f}x; ratio {sw_rt / avg_rt:.2f}")


def main() -> None:
    if "--switching-only" in sys.argv:
        switching_section()
        return
    print("period 50 us (20 kHz); real-time factor = 50 us / cost; backends:", ", ".join(available_backends()))
    base = None
    for backend in available_backends()[::-1]:
        for substeps in (1, 2):
            for cfg in ("hurst_mclv.toml", "servo_200w.toml"):
                cost, loop = startup_cost_us(cfg, backend, substeps)
                if base is None:
                    base = cost
                print(f"{backend:6s} substeps {substeps} {cfg:16s} step {cost:6.2f} us/period (bare loop {loop:.2f} us)"
                      f"  real-time x{50.0 / cost:6.1f}  vs python/1-substep/hurst x{base / cost:5.1f}")
    for backend in available_backends()[::-1]:
        reads, off = sensor_and_off_cost_us(backend)
        print(f"{backend:6s} sensor reads (hall, edge, encoder, adc(1,2,3), i_abc, i_bus) {reads:5.2f} us;"
              f" OFF coast period {off:5.2f} us")
    switching_section()
    peers_table()


if __name__ == "__main__":
    main()
