"""The plant owns its time: `advance` integrates one exchange period in chunks of at most 50 us,
with the actuation delay in front, keeps one clock with the bench's period index, lists every
hall edge of the period, and asks nobody else whether its integrator can follow a motor."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from hilbench.bench.settings import load_config

from hilbench.config import plant_params_from_config
from hilbench.plant import Plant
from hilbench.plant.model import OUTPUT_OFF, OUTPUT_PWM, available_backends
from hilbench.plant.params import MotorParams
from hilbench.plant.period import MAX_STEP_US, Period
from hilbench.plant.stiffness import stiff_modes

CONFIGS = Path(__file__).resolve().parent.parent / "bench_configs"
PHI = (0.0, -2.0 * math.pi / 3.0, 2.0 * math.pi / 3.0)


def params():
    return plant_params_from_config(load_config(CONFIGS / "hurst_mclv.toml"))


def q_duties(theta: float, vq_frac: float) -> tuple[float, float, float]:
    return tuple(min(1.0, max(0.0, 0.5 + vq_frac * math.cos(theta + math.pi / 2 + ph))) for ph in PHI)  # type: ignore[return-value]


@pytest.mark.parametrize("backend", available_backends())
def test_a_long_period_is_its_chunks_and_lists_every_edge(backend: str) -> None:
    """A 400 us period is eight 50 us steps with the duties held; its last edge is timed from the
    period's start and every chunk's edge is listed with the hall bits after it."""
    fast, slow = Plant(params(), seed=1, backend=backend), Plant(params(), seed=1, backend=backend)
    fast.set_period(400)
    h = Period(400).chunk_s  # 400e-6 / 8: not the literal 50e-6 to the last bit
    n_edges = 0
    for _ in range(400):
        duties = q_duties(fast.theta_e, 0.4)
        edge_s = fast.advance(*duties, OUTPUT_PWM)
        want = []
        for i in range(8):
            sub = slow.step(*duties, OUTPUT_PWM, h)
            if sub is not None:
                want.append((i * h + sub, slow.hall_bits))
        assert (fast.w_m, fast.i_a, fast.theta_e) == (slow.w_m, slow.i_a, slow.theta_e)
        assert fast.edges() == tuple(want)
        assert edge_s == (want[-1][0] if want else None) == fast.last_edge_s
        n_edges += len(want)
    assert n_edges > 50 and fast.w_m > 100.0  # it turned, edges were timed (several per period)


@pytest.mark.parametrize("backend", available_backends())
def test_the_plant_clock_is_the_period_index(backend: str) -> None:
    """After k periods the plant's time is exactly Period.t_s(k): one time base with the bench."""
    plant = Plant(params(), backend=backend)
    period = Period(150)
    plant.set_period(period.us)
    for k in range(1, 2001):
        plant.advance(0.5, 0.5, 0.5, OUTPUT_PWM)
        assert plant.t_s == period.t_s(k)


@pytest.mark.parametrize("backend", available_backends())
def test_the_actuation_delay_holds_the_switches_open_then_applies_each_period_in_turn(backend: str) -> None:
    delayed, direct = Plant(params(), backend=backend), Plant(params(), backend=backend)
    delayed.set_period(50, actuation_delay_periods=3)
    direct.set_period(50)
    duties = [q_duties(0.1 * k, 0.3) for k in range(60)]
    for _ in range(3):
        direct.advance(0.0, 0.0, 0.0, OUTPUT_OFF)
    for k in range(60):
        delayed.advance(*duties[k], OUTPUT_PWM)
        if k + 3 < 60:
            direct.advance(*duties[k], OUTPUT_PWM)
    assert direct.t_s == Period(50).t_s(60) == delayed.t_s
    assert (direct.w_m, direct.i_a, direct.i_b) == (delayed.w_m, delayed.i_a, delayed.i_b)


@pytest.mark.skipif(len(available_backends()) < 2, reason="the C plant core is not built")
def test_both_backends_advance_alike_over_a_long_period_with_a_delay() -> None:
    plants = [Plant(params(), seed=5, backend=b) for b in ("c", "python")]
    for plant in plants:
        plant.set_period(250, actuation_delay_periods=2)
    for k in range(600):
        mode = OUTPUT_PWM if k < 450 else OUTPUT_OFF
        duties = q_duties(plants[0].theta_e, 0.45)
        edges = [plant.advance(*duties, mode) for plant in plants]
        assert edges[0] == edges[1]
        assert plants[0].edges() == plants[1].edges()
        for name in ("w_m", "i_a", "i_b", "i_c", "i_bus", "theta_e", "t_s"):
            a, b = (getattr(p, name) for p in plants)
            assert abs(a - b) <= 1e-12 * max(abs(a), abs(b), 1e-9), (k, name, a, b)


def test_set_period_refuses_what_the_plant_cannot_hold() -> None:
    plant = Plant(params())
    with pytest.raises(ValueError, match="whole number"):
        plant.set_period(0)
    with pytest.raises(ValueError, match="steps of"):
        plant.set_period(MAX_STEP_US * 257)
    with pytest.raises(ValueError, match="actuation delay"):
        plant.set_period(50, actuation_delay_periods=-1)


def test_a_period_converts_once() -> None:
    period = Period(150)
    assert period.s == 150e-6 and period.t_s(3) == 3 * 150e-6 and period.count(0.3) == 2000
    assert (period.chunks, period.chunk_s) == (3, 150e-6 / 3)
    assert Period(50).index_at(2.2) == 44_000  # 2.2 / 50e-6 is 43999.99999999999 in binary
    assert Period(50).index_at(math.inf) == math.inf


def test_the_plant_says_which_mode_its_integrator_cannot_follow() -> None:
    """R/L of 1 ohm / 1 uH is 1e6/s: at 50 us one RK4 step has lambda dt = 50, so it needs 20 steps
    (lambda dt <= 2.5); the Hurst motor at 50 us needs none of that."""
    stiff = MotorParams(rs_ohm=1.0, ld_h=1e-6, lq_h=1e-6, psi_wb=0.01, pole_pairs=4, j_kgm2=1e-3)
    modes = stiff_modes(stiff, 50, 2)
    assert [m.what.split(" =")[0] for m in modes][:1] == ["R/L"]
    assert modes[0].substeps_needed == pytest.approx(20.0)
    assert modes[0].depends_on[-1] == "rs_ohm"
    assert stiff_modes(params().motor, 50, 2) == []
    assert stiff_modes(stiff, 50, 21) == []
    assert stiff_modes(stiff, 100, 19)[0].substeps_needed == pytest.approx(20.0)  # two 50 us chunks, not 40


@pytest.mark.parametrize("backend", available_backends())
def test_a_long_period_lists_every_index_mark(backend: str) -> None:
    """An index mark in any chunk of a long period is kept (sense() reports it, not only a mark in the
    last chunk) and timed at the start of its chunk, as the chunk-by-chunk steps see it."""
    fast, slow = Plant(params(), seed=1, backend=backend), Plant(params(), seed=1, backend=backend)
    fast.set_period(1000)
    for plant in (fast, slow):
        plant.reset(speed_rad_s=300.0)  # coasting with the switches open
    h = Period(1000).chunk_s
    marks = 0
    for _ in range(200):
        fast.advance(0.0, 0.0, 0.0, OUTPUT_OFF)
        want = []
        for i in range(20):
            slow.step(0.0, 0.0, 0.0, OUTPUT_OFF, h)
            if slow.encoder_index:
                want.append(i * h)
        assert fast.index_marks() == tuple(want)
        assert fast.encoder_index == bool(want) == fast.sense(())[2]
        marks += len(want)
    assert marks >= 5
