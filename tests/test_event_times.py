"""Scenario events fire in the period that contains their time (issue 11, finding 5)."""

from __future__ import annotations

import math

import hilbench
from hilbench.bench.recorder import MARKER_EVENT
from hilbench.bench.scenario import Event, ScenarioPlayer, first_period_at

TS = 50 * 1e-6  # the session's period: period_us * 1e-6


def test_times_not_representable_in_binary_map_to_their_period() -> None:
    # in binary64 44 000 * TS = 2.1999999999999997 < 2.2: a search for k*TS >= t ends one period late
    assert 44_000 * TS != 2.2
    assert first_period_at(2.2, TS) == 44_000
    assert first_period_at(3.6, TS) == 72_000
    assert first_period_at(1.2, TS) == 24_000
    assert first_period_at(0.03, TS) == 600
    assert first_period_at(0.0, TS) == 0


def test_a_time_inside_a_period_belongs_to_that_period() -> None:
    # period k covers [k*Ts, (k+1)*Ts): 2.20002 s lies in period 44 000
    assert first_period_at(2.20002, TS) == 44_000
    assert first_period_at(2.20004999, TS) == 44_000
    assert first_period_at(2.20005, TS) == 44_001
    assert first_period_at(math.inf, TS) == math.inf
    for k in range(0, 200_000, 997):  # every period start, however it rounds, is its own period
        assert first_period_at(k * TS, TS) == k
        assert first_period_at(k / 20_000, TS) == k


def test_player_yields_events_in_their_period() -> None:
    player = ScenarioPlayer([Event(at_s=2.2, ref_rpm=1.0), Event(at_s=3.6, press="s2")])
    assert player.due(43_999 * TS, TS) == []
    assert [e.ref_rpm for e in player.due(44_000 * TS, TS)] == [1.0]
    assert [e.press for e in player.due(72_000 * TS, TS)] == ["s2"]


def test_default_scenario_events_fire_at_their_times() -> None:
    cfg = hilbench.load_config(None, ['link.target="inprocess:an1017"', "run.duration_s=3.7"])
    with hilbench.Bench(cfg, scenario=True) as bench:
        bench.run()
    data = bench.signals()
    t, marker = data["t_s"], data["marker"]
    fired = {round(float(t[k]), 9) for k in range(len(t)) if marker[k] == MARKER_EVENT}
    texts = " | ".join(bench.events)
    assert "t=2.200000 ref" in texts and "t=3.600000 press" in texts, texts
    assert {0.03, 1.2, 2.2, 3.6} <= fired, sorted(fired)
