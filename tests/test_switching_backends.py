"""The switching inverter's two backends (hilbench/plant/switching.py, the reference, and
_switching.c in the C core) run the same arithmetic: every state and sensor agrees to 1e-12
relative (bit for bit on one libm) over start-up, reversal, outputs off (diode decay and coast),
low sides on, stiction, a step load, dead time on and off, both carriers (pulses on the counter's
zero and on its peak), whole and half PWM periods per step, 1 and 2 substeps, an ADC sampling
inside the period, and the averaged inverter's "edges" dead band."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from conftest import require_c_plant
from test_plant_backends import assert_close, q_duties, schedule, snapshot

from hilbench.bench.settings import load_config

from hilbench.config import plant_params_from_config
from hilbench.plant import LoadProfile, Plant
from hilbench.plant.params import PwmTiming

CONFIGS = Path(__file__).resolve().parent.parent / "bench_configs"
DT = 50e-6

needs_c = pytest.mark.skipif(not require_c_plant(), reason="C plant core not built")

VARIANTS = {
    # name: (config, inverter changes, PwmTiming, substeps, stiction)
    "hurst-zero-dead": ("hurst_mclv.toml", dict(model="switching", dead_time_enabled=True), PwmTiming("zero"), 1, False),
    "hurst-peak-nodead-2sub": ("hurst_mclv.toml", dict(model="switching"), PwmTiming("peak"), 2, False),
    "servo-peak-dead-stiction": ("servo_200w.toml", dict(model="switching"), PwmTiming("peak"), 1, True),
    "servo-sample-inside": ("servo_200w.toml", dict(model="switching"), PwmTiming("peak", 0.3), 1, False),
    "hurst-average-edges": ("hurst_mclv.toml", dict(average_dead_time="edges", dead_time_enabled=True),
                            PwmTiming("zero"), 1, True),
    "servo-average-edges": ("servo_200w.toml", dict(average_dead_time="edges"), PwmTiming("peak"), 2, False),
}


def close(a, b, where: str) -> None:
    """assert_close over the values that differ at all (infinities, no dead time pending, are equal)."""
    differ = [(x, y) for x, y in zip(a, b) if x != y]
    assert_close(tuple(x for x, _ in differ), tuple(y for _, y in differ), where)


def extended(p: Plant):
    return snapshot(p) + (p._sw_u, p._sw_s0, p._sw_s1, p._sw_s2, p._sw_e0, p._sw_e1, p._sw_e2, p._ia_s, p._ib_s,
                          p._adc_live, p.fault_input, p.encoder_count, p.encoder_index)


@needs_c
@pytest.mark.parametrize("name", list(VARIANTS))
def test_c_and_python_switching_agree(name):
    cfg_name, inv, timing, substeps, stiction = VARIANTS[name]
    params = plant_params_from_config(load_config(CONFIGS / cfg_name), timing)
    params = dataclasses.replace(params, inverter=dataclasses.replace(params.inverter, **inv))
    if stiction:
        params = dataclasses.replace(params, motor=dataclasses.replace(params.motor, coulomb_nm=0.02 * params.motor.kt_nm_per_a))
    plants = [Plant(params, seed=3, substeps=substeps, backend=b) for b in ("c", "python")]
    assert [p.backend for p in plants] == ["c", "python"]
    assert all(p._bridge is not None for p in plants)
    vbus = params.inverter.vbus_v
    n = 1500
    load_nm = 0.1 * params.motor.kt_nm_per_a
    for pl in plants:
        pl.load = LoadProfile("step", torque_nm=0.0, step_time_s=0.1 * n * DT, step_torque_nm=load_nm)
        pl.pot_fraction = 0.3
    edges = 0
    for k in range(n):
        mode, frac = schedule(k, n)
        frac *= 0.5 if "servo" in cfg_name else 1.0  # keep the servo under its 4 A comparator
        dt = DT if k % 7 else 0.5 * DT  # now and then a step that ends mid-carrier
        for pl in plants:
            d = q_duties(pl.theta_e, frac * vbus, vbus)
            pl.step(d[0], d[1], d[2], mode, dt)
        a, b = (extended(pl) for pl in plants)
        close(a, b, f"period {k}")
        edges += a[11] is not None
        if k % 5 == 0:
            roles = (1, 2, 3, 4, 5, 0)
            assert plants[0].adc_codes(roles) == plants[1].adc_codes(roles), f"period {k}"
    assert edges > 2  # hall edges were crossed and timed on both


@needs_c
@pytest.mark.parametrize("speed_rad_s", [300.0, 420.0])
def test_backends_agree_with_every_leg_open_at_once(speed_rad_s):
    """Equal duties from zero current on a spinning rotor: every leg's dead time starts at the same
    instant with no current, all three float (below the bus: no current; above it at 420 rad/s,
    28 V of line back-EMF on 24 V: the diodes clamp the extremes and current flows)."""
    params = plant_params_from_config(load_config(CONFIGS / "hurst_mclv.toml"), PwmTiming("zero"))
    params = dataclasses.replace(params, inverter=dataclasses.replace(params.inverter, model="switching",
                                                                      dead_time_enabled=True))
    plants = [Plant(params, seed=3, backend=b) for b in ("c", "python")]
    for pl in plants:
        pl.reset(theta_e=0.4, speed_rad_s=speed_rad_s)
    for k in range(200):
        for pl in plants:
            pl.step(0.5, 0.5, 0.5, 1, DT)
        close(extended(plants[0]), extended(plants[1]), f"period {k}")
    assert max(abs(x) for x in plants[0].i_abc) > 0.0
