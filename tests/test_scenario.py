"""Scenario tables: validated all at once, replayed in time order, ramps linear."""

from __future__ import annotations

import pytest

from hilbench.bench.scenario import Event, Ramp, ScenarioPlayer, default_scenario
from hilbench.bench.settings import load_config, scenario_events
from hilbench.errors import ConfigError


def test_every_problem_reported_at_once() -> None:
    """The [[scenario]] tables are validated with the whole config: one ConfigError, a line each."""
    raw = ('scenario=[{at_s = 0.1, ref_rmp = 1500.0}, {at_s = -1.0, press = "s9"}, '
           '{at_s = 0.2, fault = "hall_a_hi"}, {at_s = 0.3, pot = 1.5}]')
    with pytest.raises(ConfigError) as info:
        load_config(None, [raw])
    lines = info.value.lines  # type: ignore[attr-defined]
    assert any("[scenario[0]] ref_rmp: unknown key (did you mean 'ref_rpm'?)" in ln for ln in lines)
    assert any("[scenario[1]] at_s" in ln for ln in lines) and any("[scenario[1]] press" in ln for ln in lines)
    assert any("[scenario[2]] fault" in ln and "did you mean 'hall_a_high'?" in ln for ln in lines)
    assert any("[scenario[3]] pot: 1.5 is out of range" in ln for ln in lines)


def test_events_sorted_and_due_in_order() -> None:
    cfg = load_config(None, ['scenario=[{at_s = 0.5, press = "s2"}, {at_s = 0.1, ref_rpm = 100.0}]'])
    player = ScenarioPlayer(scenario_events(cfg))
    assert player.next_t_s == 0.1
    assert player.due(0.05) == []
    assert [e.ref_rpm for e in player.due(0.1)] == [100.0]
    assert player.next_t_s == 0.5
    assert [e.press for e in player.due(1.0)] == ["s2"]
    assert player.next_t_s == float("inf")


def test_ramp_is_linear_and_ends_on_target() -> None:
    ramp = Ramp(1.0, 1.5, 0.0, 1000.0)
    assert ramp.value(1.25) == pytest.approx(500.0)
    assert ramp.value(2.0) == 1000.0


def test_default_scenario_matches_the_issue() -> None:
    events = default_scenario()
    refs = [e.ref_rpm for e in events if e.ref_rpm]
    assert refs == [1500.0, 2500.0, -1500.0]
    presses = [e for e in events if e.press == "s2"]
    assert len(presses) == 2  # start, then stop
    player = ScenarioPlayer(events)
    assert player.end_s is not None and player.end_s > presses[-1].at_s
    assert player.reference_at(1.5) == 2500.0
    assert isinstance(events[0], Event)
