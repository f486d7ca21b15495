"""Offline sweep: the batch step test against the scalar session, grid bookkeeping, CSV, fragment.

The expectation for the batch path is the scalar bench itself: `Session` with an in-process
An1017Target and the scalar Plant, playing `step_scenario`. The firmware is bit-exact (see
test_an1017_batch.py), so the metrics may differ only by the two plants' float arithmetic.
"""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from hilbench.bench.metrics import step_metrics
from hilbench.bench.session import Session, SessionOptions
from hilbench.bench.sweep import (
    gains_q15,
    best_fragment,
    parse_grid_spec,
    run_step_batch,
    step_scenario,
    sweep_grid,
    write_sweep_csv,
)
from hilbench.config import load_config, plant_from_config
from hilbench.errors import ConfigError
from hilbench.targets.an1017 import An1017Target

RPM_PER_Q15 = 1_875_000 / (312 * 32768)  # AN1017 Table 6: rpm = 1 875 000 / Period


class _RecordingPlant:
    """The config's scalar plant behind a proxy that remembers speed and |i_dq| after each period."""

    def __init__(self, inner: object) -> None:
        object.__setattr__(self, "_inner", inner)
        object.__setattr__(self, "speeds", [])
        object.__setattr__(self, "currents", [])
        object.__setattr__(self, "pots", [])

    def __getattr__(self, name: str) -> object:
        return getattr(self._inner, name)

    def __setattr__(self, name: str, value: object) -> None:
        setattr(self._inner, name, value)

    def step(self, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        inner = self._inner
        self.pots.append(inner.pot_fraction)
        inner.step(*args, **kwargs)
        self.speeds.append(inner.speed_rpm)
        self.currents.append(math.hypot(inner.i_d, inner.i_q))


def _scalar_step(cfg, gains, from_rpm, to_rpm, duration_s, step_at_s, record_every):  # type: ignore[no-untyped-def]
    plant = _RecordingPlant(plant_from_config(cfg))
    target = An1017Target()
    session = Session(target, plant, step_scenario(from_rpm, to_rpm, step_at_s, duration_s),
                      SessionOptions(duration_s=duration_s))
    session.handshake()
    session.set_params({"kp": gains[0], "ki": gains[1], "kd": gains[2]}, 0.0)
    session.run()
    pots = np.array(plant.pots)
    k_step = int(np.flatnonzero(pots != pots[0])[0])  # the period the pot moved
    speeds = np.array(plant.speeds)
    idx = np.arange(record_every - 1, speeds.size, record_every)
    t = (idx + 1) * 50e-6
    code_from = round(pots[0] * 1023)
    code_to = round(pots[-1] * 1023)
    y0 = (code_from - 512) * 64 * RPM_PER_Q15
    yf = (code_to - 512) * 64 * RPM_PER_Q15
    m = step_metrics(t, speeds[idx], y0=y0, y_final_ref=yf, t_step_s=k_step * 50e-6)
    peak = max(plant.currents[k_step:])
    return m, peak, speeds[idx]


@pytest.mark.slow
def test_batch_step_matches_scalar_session() -> None:
    cfg = load_config(None)
    gains = [(0.5, 0.05, 0.0), (0.3, 0.1, 0.0), (0.2, 0.02, 0.05)]
    args = (1000.0, 1500.0, 0.4, 0.2)
    batch = run_step_batch(cfg, gains, *args, record_every=4)
    for g, r in zip(gains, batch):
        m, peak, speeds = _scalar_step(cfg, g, *args, record_every=4)
        assert r.gains_q15 == gains_q15(g)
        assert not r.stalled
        np.testing.assert_allclose(r.speed_rpm, speeds, rtol=0, atol=1e-6 * 1500)
        b = r.metrics
        assert b.itae == pytest.approx(m.itae, rel=1e-6)
        assert b.iae == pytest.approx(m.iae, rel=1e-6)
        assert b.overshoot_pct == pytest.approx(m.overshoot_pct, abs=1e-6)
        assert b.rise_time_s == pytest.approx(m.rise_time_s, abs=1e-7)  # plant float differences: ~1e-5 rpm
        assert (b.settling_time_s is None) == (m.settling_time_s is None)
        if m.settling_time_s is not None:
            assert b.settling_time_s == pytest.approx(m.settling_time_s, abs=1e-7)  # plant float differences: ~1e-5 rpm
        assert b.peak_current_a == pytest.approx(peak, rel=1e-6)
        # the firmware's quantised references: code 512 + round(rpm/RPM_PER_Q15/64)
        assert r.ref_to_rpm == pytest.approx((round(1500 / RPM_PER_Q15 / 64)) * 64 * RPM_PER_Q15)


def test_step_scenario_order_and_validation() -> None:
    events = step_scenario(1000, 2000, 0.5, 1.0)
    assert [e.ref_rpm for e in events if e.ref_rpm is not None] == [1000, 2000]
    assert [e.press for e in events if e.press] == ["s2"]
    with pytest.raises(ConfigError):
        step_scenario(1000, 2000, 1.5, 1.0)


def test_sweep_skips_constraint_breakers_ranks_and_reports_progress(tmp_path) -> None:
    cfg = load_config(None)
    seen: list[tuple[int, int]] = []
    # kp + ki + kd < 0.9999 (seed constraint 1): 0.95 + 0.1 breaks it, 0.95 + 0.01 does not
    sweep = sweep_grid(cfg, [0.2, 0.95], [0.01, 0.1], [0.0], metric="itae",
                       from_rpm=800, to_rpm=1200, duration_s=0.12, step_at_s=0.08,
                       progress=lambda d, t: seen.append((d, t)))
    assert sweep.skipped == 1
    skipped = [p for p in sweep.points if p.skipped]
    assert [p.gains for p in skipped] == [(0.95, 0.1, 0.0)] and skipped[0].constraint == 1
    assert [p.rank for p in sweep.ranked] == [1, 2, 3]
    values = [p.result.metrics.itae for p in sweep.ranked if not p.result.stalled]
    assert values == sorted(values)
    assert seen[0] == (0, 3) and seen[-1] == (3, 3)
    assert all(a[0] <= b[0] for a, b in zip(seen, seen[1:]))
    path = write_sweep_csv(tmp_path / "sweep.csv", sweep)
    rows = list(csv.DictReader(path.open()))
    assert len(rows) == 4 and sum(r["status"] == "skipped" for r in rows) == 1
    import hilbench.bench.settings  # noqa: F401  (registers the [target] table)
    from hilbench.config import default_config_text

    frag = tmp_path / "best.toml"
    frag.write_text(default_config_text() + "\n" + best_fragment(sweep))
    loaded = load_config(frag)
    assert (loaded.target.kp, loaded.target.ki, loaded.target.kd) == sweep.best.gains


def test_grid_spec_parsing() -> None:
    assert parse_grid_spec("0.1:0.5:5") == pytest.approx((0.1, 0.2, 0.3, 0.4, 0.5))
    assert parse_grid_spec("0.25") == (0.25,)
    with pytest.raises(ConfigError, match="A:B:N"):
        parse_grid_spec("0.1:0.5")
    with pytest.raises(ConfigError, match="metric"):
        sweep_grid(load_config(None), [0.1], [0.01], metric="speed")
