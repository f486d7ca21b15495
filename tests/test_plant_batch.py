"""The batch plant agrees with the scalar plant (same equations, same method)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

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
