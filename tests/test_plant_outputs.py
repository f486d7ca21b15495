"""What the plant records is its declaration: every declared output is a column with its unit, and
the electrical torque column obeys the motor's equations on the other recorded columns."""

from __future__ import annotations

import math

import numpy as np

import hilbench
from hilbench.plant.model import OUTPUTS, Plant
from hilbench.plant.params import PlantParams, psi_from_ke


def test_every_declared_output_is_a_recorded_column_with_its_unit() -> None:
    with hilbench.Bench(target="inprocess:an1017") as bench:
        bench.run(0.01)
        signals = bench.signals()
    for out in OUTPUTS:
        assert out.column in signals and signals.unit(out.column) == out.unit
    assert Plant(PlantParams.hurst()).outputs == OUTPUTS


def test_the_electrical_torque_is_kt_times_iq_and_balances_friction_at_a_held_speed() -> None:
    """The Hurst (Ld = Lq): Te = 1.5 p psi iq, iq from the recorded phase currents and angle (Park);
    held at 1500 rpm with no load, the mean torque carries the viscous friction B w."""
    with hilbench.Bench(target="inprocess:an1017") as bench:
        bench.set_reference(1500)
        bench.press("s2")
        bench.run(1.2)
        signals = bench.signals()
    p, b = 5, 1.53e-5  # the packaged config's Hurst motor
    psi = psi_from_ke(7.32, p)
    theta = np.radians(signals["theta_e_deg"])
    i_alpha = signals["ia_a"]
    i_beta = (signals["ia_a"] + 2.0 * signals["ib_a"]) / math.sqrt(3.0)
    i_q = -i_alpha * np.sin(theta) + i_beta * np.cos(theta)
    np.testing.assert_allclose(signals["torque_nm"], 1.5 * p * psi * i_q, rtol=1e-9, atol=1e-12)
    held = signals["t_s"] > 0.9
    w_m = signals["speed_rpm"][held] * 2.0 * math.pi / 60.0
    mean_te = float(np.mean(signals["torque_nm"][held]))
    assert abs(mean_te - b * float(np.mean(w_m))) < 0.05 * b * float(np.mean(w_m))
