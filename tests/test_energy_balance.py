"""The recorded bus current is the period average: a recording alone closes the energy balance
(issue 11, finding 4).

    sum(Vbus * ibus_k * Ts) = copper + friction + load + delta kinetic + delta magnetic energy

Every term is derived here from the recorded columns (end-of-period samples, trapezoid in time)
and the config's motor constants; nothing is read from the plant's own energy accounts.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import hilbench
from hilbench.plant.model import available_backends

RAD_S_PER_RPM = 2.0 * math.pi / 60.0


def _balance(cfg: hilbench.BenchConfig, signals: hilbench.Signals) -> tuple[float, float]:
    """(input energy from Vbus*ibus, the sum of where it went), in J."""
    motor = cfg.motor.to_params()
    assert motor.ld_h == motor.lq_h and motor.coulomb_nm == 0.0  # the terms below assume these
    ts = cfg.link.period_us * 1e-6
    vbus = cfg.inverter.vbus_v
    ibus = np.asarray(signals["ibus_a"], dtype=float)
    w = np.concatenate(([0.0], np.asarray(signals["speed_rpm"], dtype=float) * RAD_S_PER_RPM))  # state before period 0: rest
    i2 = sum(np.asarray(signals[c], dtype=float) ** 2 for c in ("ia_a", "ib_a", "ic_a"))
    i2 = np.concatenate(([0.0], i2))
    load = np.asarray(signals["load_nm"], dtype=float)  # the load over period k (row k: its end)
    e_in = float(np.sum(vbus * ibus) * ts)
    copper = float(np.sum(motor.rs_ohm * 0.5 * (i2[:-1] + i2[1:])) * ts)  # Rs (ia^2+ib^2+ic^2) = 1.5 Rs |i_dq|^2
    friction = float(np.sum(motor.b_nms_per_rad * 0.5 * (w[:-1] ** 2 + w[1:] ** 2)) * ts)
    load_j = float(np.sum(load * 0.5 * (w[:-1] + w[1:])) * ts)
    kinetic = 0.5 * motor.j_kgm2 * (w[-1] ** 2 - w[0] ** 2)
    magnetic = 0.5 * motor.ld_h * (i2[-1] - i2[0])  # 0.75 L |i_dq|^2 = 0.5 L (ia^2+ib^2+ic^2)
    return e_in, copper + friction + load_j + kinetic + magnetic


@pytest.mark.parametrize("backend", available_backends())
@pytest.mark.parametrize("loaded", [False, True], ids=["default", "loaded"])
def test_energy_balance_from_a_recording(backend: str, loaded: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HILBENCH_PLANT_BACKEND", backend)
    cfg = hilbench.load_config(None, ['link.target="inprocess:an1017"'])
    with hilbench.Bench(cfg, scenario=True) as bench:
        bench.run(1.0)
        if loaded:
            bench.set_load(0.02)  # N*m: a third of an ampere at Kt = 60.5 mN*m/A
        bench.run()
    signals = bench.signals()
    assert len(signals["t_s"]) > 70_000
    if loaded:
        assert float(np.max(signals["load_nm"])) == pytest.approx(0.02)
    e_in, spent = _balance(cfg, signals)
    assert e_in > 0.1
    print(f"energy in {e_in:.6f} J, spent {spent:.6f} J, gap {(e_in - spent) / e_in:+.3%}")
    assert abs(e_in - spent) <= 0.01 * e_in, (e_in, spent)


def test_bus_current_is_the_average_not_the_end_sample() -> None:
    """A period with a current ramping from 0: the average of d*i over the period is about half
    the end sample's d*i (independent reference: the first-order current rise, i = V/R (1 - e^-t/tau))."""
    from hilbench.plant.model import Plant
    from hilbench.plant.params import PlantParams

    for backend in available_backends():
        plant = Plant(PlantParams.hurst(), backend=backend, substeps=8)
        plant.step(1.0, 0.0, 0.0, 1, 50e-6)  # phase a to the bus, b and c to ground, rotor locked by inertia
        m = plant.params.motor
        r, l, v = m.rs_ohm, m.ld_h, 24.0 * 2.0 / 3.0  # va = Vbus (2 da - db - dc)/3 at theta = 0
        tau, t = l / r, 50e-6
        mean_ia = v / r * (1.0 - tau / t * (1.0 - math.exp(-t / tau)))
        assert plant.i_bus == pytest.approx(mean_ia, rel=2e-3), backend  # ibus = da*ia + db*ib + dc*ic = ia
        assert plant.i_a > 1.9 * plant.i_bus
