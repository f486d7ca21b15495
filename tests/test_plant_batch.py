"""The batch plant agrees with the scalar plant (same equations, same method)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from conftest import require_c_plant

from hilbench.plant import LoadProfile, Plant, PlantParams
from hilbench.plant.batch import BatchPlant
from hilbench.plant.model import available_backends

PHI = (0.0, -2.0 * math.pi / 3.0, 2.0 * math.pi / 3.0)


def q_duties(theta, vq, vbus=24.0):
    return [0.5 + vq * np.cos(theta + math.pi / 2 + ph) / vbus for ph in PHI]


@pytest.mark.parametrize("backend", available_backends())
@pytest.mark.parametrize("substeps", [1, 2])
def test_batch_matches_scalar_plants(backend, substeps):
    base = PlantParams.hurst()
    params = [
        base,
        dataclasses.replace(base, load=LoadProfile("step", step_time_s=0.02, step_torque_nm=0.01)),
        dataclasses.replace(base, motor=dataclasses.replace(base.motor, rs_ohm=3.0, lq_h=2.6e-3)),
        dataclasses.replace(base, motor=dataclasses.replace(base.motor, coulomb_nm=2e-3)),
    ]
    vq = np.array([12.0, 10.0, 8.0, 6.0])
    batch = BatchPlant(params, substeps=substeps, backend=backend)
    singles = [Plant(p, substeps=substeps, backend="python") for p in params]
    for _ in range(1200):
        da, db, dc = q_duties(batch.theta_e, vq)
        batch.step(da, db, dc, 1, 50e-6)
        for k, pl in enumerate(singles):
            pl.step(*q_duties(pl.theta_e, vq[k]), 1, 50e-6)
            assert batch.hall_bits[k] == pl.hall_bits
            if pl.last_edge_s is None:
                assert math.isnan(batch.last_edge_s[k])
            else:
                assert batch.last_edge_s[k] == pytest.approx(pl.last_edge_s, abs=1e-12)
    for k, pl in enumerate(singles):
        assert batch.w_m[k] == pytest.approx(pl.w_m, rel=1e-9)
        assert batch.i_q[k] == pytest.approx(pl.i_q, rel=1e-9, abs=1e-12)
        assert batch.theta_e[k] == pytest.approx(pl.theta_e, abs=1e-9)


def _mixed_params():
    base = PlantParams.hurst()
    return [
        base,
        dataclasses.replace(base, load=LoadProfile("step", step_time_s=0.01, step_torque_nm=0.01)),
        dataclasses.replace(base, motor=dataclasses.replace(base.motor, coulomb_nm=2e-3)),
        dataclasses.replace(base, load=LoadProfile("locked")),
        dataclasses.replace(base, load=LoadProfile("linear", coeff=2e-5)),
        dataclasses.replace(base, motor=dataclasses.replace(base.motor, rs_ohm=3.0, lq_h=2.6e-3)),
    ]


@pytest.mark.skipif(not require_c_plant(), reason="C plant core not built")
@pytest.mark.parametrize("substeps", [1, 2])
def test_batch_c_and_numpy_backends_agree(substeps):
    """Same arithmetic in both batch backends: 1e-12 relative in every state over start-up,
    reversal, LOW_SIDE and a restart, with stiction, a locked rotor and a load step."""
    params = _mixed_params()
    vq = np.array([12.0, 10.0, 8.0, 12.0, 9.0, 11.0])
    plants = [BatchPlant(params, substeps=substeps, backend=b) for b in ("c", "python")]
    n = 1600
    for k in range(n):
        mode, sign = (1, 1.0) if k < 600 else (1, -1.0) if k < 1000 else (2, 0.0) if k < 1200 else (1, 1.0)
        for bp in plants:
            d = q_duties(bp.theta_e, sign * vq)
            bp.step(d[0], d[1], d[2], mode, 50e-6)
        c, py = plants
        for name in ("i_d", "i_q", "w_m", "theta_e"):
            x, y = getattr(c, name), getattr(py, name)
            assert np.all(np.abs(x - y) <= 1e-12 * np.maximum(np.maximum(np.abs(x), np.abs(y)), 1e-9)), (k, name)
        assert np.array_equal(c.hall_bits, py.hall_bits), k
        assert np.array_equal(np.isnan(c.last_edge_s), np.isnan(py.last_edge_s)), k
        both = ~np.isnan(c.last_edge_s)
        assert np.all(np.abs(c.last_edge_s[both] - py.last_edge_s[both]) <= 1e-12), k
    assert plants[0].w_m[3] == 0.0  # the locked rotor stayed put
    assert plants[0].w_m[0] > 100.0  # and the others ran


@pytest.mark.parametrize("backend", available_backends())
def test_batch_state_arrays_are_updated_in_place(backend):
    """The attributes are the plant's own arrays (views), refreshed by step and reset; scalar duties broadcast."""
    bp = BatchPlant([PlantParams.hurst()] * 3, backend=backend)
    arrays = [bp.i_d, bp.i_q, bp.w_m, bp.theta_e, bp.hall_bits, bp.last_edge_s]
    kept = bp.w_m.copy()
    for _ in range(200):
        bp.step(0.3, 0.9, 0.3, 1, 50e-6)  # a fixed voltage vector at 120 deg: the rotor turns towards it
    assert all(a is b for a, b in zip(arrays, [bp.i_d, bp.i_q, bp.w_m, bp.theta_e, bp.hall_bits, bp.last_edge_s]))
    assert np.all(kept == 0.0) and np.all(bp.w_m != 0.0)
    bp.reset()
    assert all(a is b for a, b in zip(arrays, [bp.i_d, bp.i_q, bp.w_m, bp.theta_e, bp.hall_bits, bp.last_edge_s]))
    assert np.all(bp.w_m == 0.0) and np.all(np.isnan(bp.last_edge_s))


@pytest.mark.parametrize("backend", available_backends())
def test_batch_startup_and_load_step_match_scipy_reference(backend):
    """The batch's own accuracy against the independent abc-frame reference of test_plant_accuracy."""
    from scipy.integrate import solve_ivp

    from test_plant_accuracy import duties_for_vq, reference_rhs

    params = PlantParams.hurst()
    t_step, load_nm, vq, dt = 0.05, 0.02, 12.0, 50e-6
    params = dataclasses.replace(params, load=LoadProfile("step", torque_nm=0.0, step_time_s=t_step, step_torque_nm=load_nm))
    bp = BatchPlant([params], backend=backend)
    y = [0.0, 0.0, 0.0, 0.0]
    ref, got = [], []
    for k in range(2000):
        t0 = k * dt
        tl = load_nm if t0 >= t_step - 1e-12 else 0.0
        sol = solve_ivp(reference_rhs(params.motor, 24.0, duties_for_vq(y[3], vq, 24.0), tl), (t0, t0 + dt), y,
                        method="DOP853", rtol=1e-10, atol=1e-14)
        y = list(sol.y[:, -1])
        d = duties_for_vq(float(bp.theta_e[0]), vq, 24.0)
        bp.step(d[0], d[1], d[2], 1, dt)
        th, i_d, i_q = float(bp.theta_e[0]), float(bp.i_d[0]), float(bp.i_q[0])
        ref.append((y[2], y[0]))
        got.append((float(bp.w_m[0]), i_d * math.cos(th) - i_q * math.sin(th)))
    ref_a, got_a = np.array(ref), np.array(got)
    assert np.max(np.abs(got_a[:, 0] - ref_a[:, 0])) <= 1e-6 * np.max(np.abs(ref_a[:, 0]))
    assert np.max(np.abs(got_a[:, 1] - ref_a[:, 1])) <= 1e-6 * np.max(np.abs(ref_a[:, 1]))
