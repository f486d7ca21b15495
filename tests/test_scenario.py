"""Scenario tables: validated all at once, replayed in time order, ramps linear."""

from __future__ import annotations

import pytest

from hilbench.bench.scenario import Event, Ramp, ScenarioPlayer, default_scenario, scenario_from_list
from hilbench.errors import ConfigError


def test_every_problem_reported_at_once() -> None:
    raw = [
        {"at_s": 0.1, "ref_rmp": 1500},
        {"at_s": -1, "press": "s9"},
        {"at_s": 0.2, "fault": "hall_a_hi"},
        {"at_s": 0.3, "pot": 1.5},
    ]
    with pytest.raises(ConfigError) as info:
        scenario_from_list(raw, "bench.toml")
    text = str(info.value)
    assert "#1 ref_rmp: unknown key (did you mean 'ref_rpm'?)" in text
    assert "#2 at_s" in text and "#2 press" in text
    assert "did you mean 'hall_a_high'?" in text
    assert "#4 pot: must be within 0..1" in text
    assert "\n" not in text


def test_events_sorted_and_due_in_order() -> None:
    events = scenario_from_list([{"at_s": 0.5, "press": "s2"}, {"at_s": 0.1, "ref_rpm": 100}], "f")
    player = ScenarioPlayer(events)
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
