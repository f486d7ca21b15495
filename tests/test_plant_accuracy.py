"""Plant vs an independent tight-tolerance reference (scipy DOP853, abc frame, rtol 1e-10).

The reference is written here from the phase equations, not from the plant's code:
    L di_x/dt = v_x - R i_x - e_x,  e_x = -we psi sin(theta - phi_x),  phi = 0, 120, 240 deg
    J dwm/dt = sum(e_x i_x)/wm - B wm - T_load
with v_x the phase-to-neutral voltage of the averaged inverter (duty minus the common mode).
Each period the test applies a q-axis voltage computed from each model's own angle at the
period start, held over the period (what a controller does)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from hilbench.bench.settings import load_config

from hilbench.config import plant_params_from_config
from hilbench.plant.params import ProtectionParams
from hilbench.plant import LoadProfile, Plant
from hilbench.plant.model import available_backends

CONFIGS = Path(__file__).resolve().parent.parent / "bench_configs"
PHI = (0.0, -2.0 * math.pi / 3.0, 2.0 * math.pi / 3.0)


def duties_for_vq(theta: float, vq: float, vbus: float) -> tuple[float, float, float]:
    """Phase voltages of amplitude vq along the q axis (theta + 90 deg) as duties around 50 %."""
    return tuple(0.5 + vq * math.cos(theta + math.pi / 2 + ph) / vbus for ph in PHI)  # type: ignore[return-value]


def reference_rhs(motor, vbus, duties, t_load):
    r, l, psi, p, j, b = motor.rs_ohm, motor.ld_h, motor.psi_wb, motor.pole_pairs, motor.j_kgm2, motor.b_nms_per_rad
    mean = sum(duties) / 3.0
    v = [vbus * (d - mean) for d in duties]

    def f(_t, y):
        ia, ib, wm, th = y
        ic = -ia - ib
        we = p * wm
        e = [-we * psi * math.sin(th + ph) for ph in PHI]
        # torque from the co-energy: T = -p psi sum(i_x sin(theta - phi_x))
        te = -p * psi * (ia * math.sin(th + PHI[0]) + ib * math.sin(th + PHI[1]) + ic * math.sin(th + PHI[2]))
        return [(v[0] - r * ia - e[0]) / l, (v[1] - r * ib - e[1]) / l, (te - b * wm - t_load) / j, we]

    return f


def run_both(cfg_name: str, vq: float, t_step: float, load_nm: float, n_periods: int, backend: str, substeps: int):
    cfg = load_config(CONFIGS / cfg_name)
    params = plant_params_from_config(cfg)
    # the reference is the ideal averaged inverter: no dead band (servo_200w.toml turns it on)
    # and no board protections (the 12 V startup's inrush passes the MCLV's 3 A overcurrent trip)
    params = dataclasses.replace(params, inverter=dataclasses.replace(params.inverter, dead_time_enabled=False),
                                 protection=ProtectionParams(0.0, False, 0.0))
    motor = params.motor
    assert motor.ld_h == motor.lq_h  # the abc reference is written for a round rotor
    vbus = params.inverter.vbus_v
    dt = 50e-6
    plant = Plant(params, backend=backend, substeps=substeps)
    plant.load = LoadProfile("step", torque_nm=0.0, step_time_s=t_step, step_torque_nm=load_nm)
    y = [0.0, 0.0, 0.0, 0.0]
    out_ref, out_plant = [], []
    for k in range(n_periods):
        t0 = k * dt
        tl = load_nm if t0 >= t_step - 1e-12 else 0.0
        d_ref = duties_for_vq(y[3], vq, vbus)
        sol = solve_ivp(reference_rhs(motor, vbus, d_ref, tl), (t0, t0 + dt), y, method="DOP853",
                        rtol=1e-10, atol=1e-14)
        y = list(sol.y[:, -1])
        plant.step(*duties_for_vq(plant.theta_e, vq, vbus), 1, dt)
        out_ref.append((y[2], y[0], y[1]))
        out_plant.append((plant.w_m, *plant.i_abc[:2]))
    return np.array(out_ref), np.array(out_plant)


@pytest.mark.parametrize(
    "cfg_name, vq, load_nm",
    [("hurst_mclv.toml", 12.0, 0.02), ("servo_200w.toml", 150.0, 0.3)],
)
@pytest.mark.parametrize("backend", available_backends())
@pytest.mark.parametrize("substeps", [1, 2])
def test_startup_and_load_step_match_reference(cfg_name, vq, load_nm, backend, substeps):
    ref, got = run_both(cfg_name, vq, t_step=0.05, load_nm=load_nm, n_periods=2000, backend=backend, substeps=substeps)
    w_peak = np.max(np.abs(ref[:, 0]))
    i_peak = np.max(np.abs(ref[:, 1:]))
    w_err = np.max(np.abs(got[:, 0] - ref[:, 0])) / w_peak
    i_err = np.max(np.abs(got[:, 1:] - ref[:, 1:])) / i_peak
    assert w_err <= 1e-6, w_err
    assert i_err <= 1e-6, i_err
    # the load step really happened: speed dropped after 50 ms
    assert ref[-1, 0] < ref[990, 0]
