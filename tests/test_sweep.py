"""Offline sweep: the same step test as `hilbench step`, on an executor, grid bookkeeping, CSV, fragment."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from hilbench.bench.run import in_process, run_step_tests
from hilbench.bench.steptest import StepTest, step_scenario
from hilbench.bench.sweep import best_fragment, parse_axis, parse_grid_spec, sweep_grid, write_sweep_csv
from hilbench.config import default_config_text, load_config
from hilbench.errors import ConfigError

SHORT = StepTest(800.0, 1200.0, 0.08, 0.04)


def test_step_scenario_order_and_validation() -> None:
    events = step_scenario(1000, 2000, 0.5, 1.0)
    assert [e.ref_rpm for e in events if e.ref_rpm is not None] == [1000, 2000]
    assert [e.press for e in events if e.press] == ["s2"]
    with pytest.raises(ConfigError):
        step_scenario(1000, 2000, 1.5, 1.0)


def test_sweep_skips_constraint_breakers_ranks_and_reports_progress(tmp_path) -> None:
    cfg = load_config(None)
    seen: list[tuple[int, int]] = []
    # kp + ki + kd < 0.9999 (the firmware's constraint 1): 0.95 + 0.1 breaks it, 0.95 + 0.01 does not
    axes = [("kp", (0.2, 0.95)), ("ki", (0.01, 0.1)), ("kd", (0.0,))]
    sweep = sweep_grid(cfg, axes, SHORT, metric="itae", workers=1, progress=lambda d, t: seen.append((d, t)))
    assert sweep.skipped == 1
    skipped = [p for p in sweep.points if p.skipped]
    assert [p.params for p in skipped] == [(("kp", 0.95), ("ki", 0.1), ("kd", 0.0))]
    assert skipped[0].constraint is not None and "#1" in skipped[0].constraint
    assert [p.rank for p in sweep.ranked] == [1, 2, 3]
    values = [p.result.metrics.itae for p in sweep.ranked if not p.result.stalled]
    assert values == sorted(values)
    assert seen[0] == (0, 3) and seen[-1] == (3, 3)
    path = write_sweep_csv(tmp_path / "sweep.csv", sweep)
    rows = list(csv.DictReader(path.open()))
    assert len(rows) == 4 and sum(r["status"] == "skipped" for r in rows) == 1
    frag = tmp_path / "best.toml"
    frag.write_text(default_config_text() + "\n" + best_fragment(sweep))
    loaded = load_config(frag)
    assert (("kp", loaded.target.kp), ("ki", loaded.target.ki), ("kd", loaded.target.kd)) == sweep.best.params


def test_sweep_point_equals_the_step_command_and_workers_do_not_matter() -> None:
    """Every point is the scalar step test itself; a process pool returns the same, in grid order."""
    cfg = load_config(None)
    axes = [("kp", (0.1, 0.3)), ("ki", (0.01, 0.05))]
    alone = sweep_grid(cfg, axes, SHORT, workers=1)
    pooled = sweep_grid(cfg, axes, SHORT, workers=2)
    assert [p.params for p in alone.points] == [p.params for p in pooled.points]
    for a, b in zip(alone.points, pooled.points):
        np.testing.assert_array_equal(a.result.speed_rpm, b.result.speed_rpm)
        assert a.result.metrics.as_dict() == b.result.metrics.as_dict()
    scalar = run_step_tests(in_process(cfg), SHORT, [dict(alone.points[0].params)])[0]
    np.testing.assert_array_equal(scalar.speed_rpm, alone.points[0].result.speed_rpm)


def test_grid_spec_parsing() -> None:
    assert parse_grid_spec("0.1:0.5:5") == pytest.approx((0.1, 0.2, 0.3, 0.4, 0.5))
    assert parse_grid_spec("0.25") == (0.25,)
    assert parse_axis("kp=0.1:0.2:2") == ("kp", (0.1, 0.2))
    for bad in ("0.1:0.5", "nan", "1:2:1e9", "0.1:inf:3"):
        with pytest.raises(ConfigError, match="A:B:N"):
            parse_grid_spec(bad)
    with pytest.raises(ConfigError, match="NAME=A:B:N"):
        parse_axis("0.1:0.2:2")
    with pytest.raises(ConfigError, match="metric"):
        sweep_grid(load_config(None), [("kp", (0.1,))], SHORT, metric="speed")
    with pytest.raises(ConfigError, match="out of range"):
        sweep_grid(load_config(None), [("kp", (1.5,))], SHORT, workers=1)
    with pytest.raises(ConfigError, match="unknown parameter"):
        sweep_grid(load_config(None), [("kq", (0.1,))], SHORT, workers=1)
