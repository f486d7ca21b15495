"""An1017Batch against N scalar An1017Targets: every Drive field equal at every period.

Each instance has its own scalar plant and scalar target in a closed loop; the batch firmware is
fed exactly the Sensors the scalar targets get, so any divergence is the batch model's. The
scalar model is the independent expectation (tests/test_an1017*.py check it against the seed).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hilbench.config import load_config, plant_params_from_config
from hilbench.errors import ConfigError
from hilbench.plant import LoadProfile, Plant
from hilbench.protocol import HostHello, Sensors
from hilbench.targets.an1017 import PARAM_KD, PARAM_KI, PARAM_KP, An1017Target
from hilbench.targets.an1017_batch import EDGE_NONE, An1017Batch, gains_to_q15, svm_batch, svm_batch_clipped
from hilbench.targets.an1017_firmware import An1017Options
from hilbench.targets.svm import svm

PERIOD_S = 50e-6
S2 = 0x08


def _pot_code(rpm: float) -> int:
    # RefSpeed = (code - 512)·64 and 1 Q15 step = 1 875 000/(312·32768) rpm (AN1017 Table 6)
    return 512 + round(rpm / (1_875_000 / (312 * 32768)) / 64)


def _closed_loop(options, gains, loads, pot_rpm, s2_periods, n_periods, pot_changes=()):
    """Run n scalar loops and the batch side by side; return the number of periods compared."""
    n = len(gains)
    cfg = load_config(None)
    base = plant_params_from_config(cfg)
    plants = []
    targets = []
    for i in range(n):
        params = dataclasses.replace(base, load=loads[i])
        plants.append(Plant(params, seed=i))
        tg = An1017Target(options)
        tg.hello(HostHello(0, 1, 50, 0, 100))
        kp, ki, kd = gains_to_q15([gains[i]])[0].tolist()
        assert tg.set_params(((PARAM_KP, kp), (PARAM_KI, ki), (PARAM_KD, kd))).result == 0
        targets.append(tg)
    batch = An1017Batch(n, options, gains_to_q15(gains))
    pots = [_pot_code(pot_rpm[i]) for i in range(n)]
    changes = dict()
    for k, i, rpm in pot_changes:
        changes.setdefault(k, []).append((i, rpm))
    hall = np.zeros(n, dtype=np.int64)
    edge = np.zeros(n, dtype=np.int64)
    pot = np.zeros(n, dtype=np.int64)
    s2 = np.zeros(n, dtype=bool)
    states_seen = set()
    for k in range(n_periods):
        for i, rpm in changes.get(k, ()):
            pots[i] = _pot_code(rpm)
        drives = []
        for i in range(n):
            p = plants[i]
            p.pot_fraction = pots[i] / 1023.0
            e = p.last_edge_s
            edge[i] = EDGE_NONE if e is None else min(int(e * 1e7), 499)
            s2[i] = any(a <= k < b for a, b in s2_periods[i])
            hall[i] = p.hall_bits
            codes = p.adc_codes((1, 2, 3))
            pot[i] = codes[0]
            drives.append(targets[i].step(Sensors(k & 0xFF, hall[i] | (S2 if s2[i] else 0), int(edge[i]), 0, codes)))
        batch.step(hall, edge, pot, s2)
        for i in range(n):
            got = batch.drive(i, k)
            assert got == drives[i], f"period {k} instance {i}:\n batch  {got}\n scalar {drives[i]}"
            states_seen.add(drives[i].state)
            d = drives[i]
            plants[i].step(d.duty_a / 1000, d.duty_b / 1000, d.duty_c / 1000, d.output_mode, PERIOD_S)
    return states_seen, plants


def test_svm_batch_matches_scalar_svm_at_every_angle() -> None:
    angles = np.arange(0x10000, dtype=np.int64)
    for volts in (-1, 0, 1, 5000, 16384, 28300, 32767):
        got = svm_batch(np.full(angles.size, volts, dtype=np.int64), angles)
        want = np.array([svm(volts, int(a)) for a in angles[::7]]).T
        assert np.array_equal(got[:, ::7], want)
        clipped = np.empty_like(got)
        svm_batch_clipped(np.full(angles.size, volts, dtype=np.int64), angles, clipped)
        assert np.array_equal(clipped[:, ::7], np.minimum(want, 1000))


@pytest.mark.slow
def test_batch_equals_scalar_seed_variant_gains_reversal_stall() -> None:
    gains = [(0.1, 0.01, 0.0), (0.3, 0.05, 0.0), (0.05, 0.002, 0.02), (0.5, 0.1, 0.1)]
    loads = [LoadProfile("constant", torque_nm=0.0)] * 3 + [LoadProfile("locked", torque_nm=0.0)]
    # staggered S2 presses put Timer1 at different offsets from the hall edges per instance
    s2 = [[(0, 40)], [(7, 47)], [(13, 53), (4000, 4040)], [(21, 61)]]
    pot_changes = [(2500, 0, -1200.0), (2500, 1, 2500.0), (4200, 2, 1500.0)]
    states, plants = _closed_loop(
        An1017Options(), gains, loads, [1500.0, 1000.0, 800.0, 1000.0], s2, 7000, pot_changes
    )
    assert {0, 1, 2, 3} <= states  # stopped, bootstrap, running, stalled (the locked rotor)
    assert plants[0].speed_rpm < 0  # the reversal went through


@pytest.mark.slow
def test_batch_equals_scalar_v11_variant() -> None:
    gains = [(0.1, 0.01, 0.0), (0.2, 0.02, 0.01), (0.05, 0.05, 0.0)]
    loads = [LoadProfile("constant", torque_nm=0.002)] * 3
    s2 = [[(0, 40)], [(3, 43)], [(30, 70)]]
    pot_changes = [(3000, 0, -1500.0), (3000, 2, 3000.0)]
    _closed_loop(An1017Options(variant="v11"), gains, loads, [2000.0, 1200.0, 600.0], s2, 5000, pot_changes)


def test_batch_refuses_constraint_breaking_gains() -> None:
    # seed constraint 1: Kp + Ki + Kd < 0.9999 (32764 in Q15)
    with pytest.raises(ConfigError, match="constraint 1"):
        An1017Batch(1, An1017Options(), [[30000, 3000, 0]])
    with pytest.raises(ConfigError):
        An1017Batch(2, An1017Options(), [[3277, 328, 0]])
