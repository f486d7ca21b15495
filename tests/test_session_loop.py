"""The session's loop: parts act only in the periods they ask for, and the tight lockstep loop
records exactly what its readable form (`Session._periods_one_by_one`) records."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import hilbench
from hilbench.bench.parts import HistoryPart, ScenarioPart

ROOT = Path(__file__).resolve().parent.parent
RANDOM = ROOT / "tests" / "golden" / "random_an1017.toml"


@pytest.mark.parametrize("target, config, scenario, seconds", [
    ("inprocess:an1017", None, RANDOM, 1.7),  # live writes, every sensor fault kind, load, bus, buttons
    ("inprocess:foc", ROOT / "bench_configs" / "servo_200w.toml", None, 0.6),
])
def test_the_tight_loop_records_what_its_readable_form_records(target: str, config: Path | None,
                                                                scenario: Path | None, seconds: float) -> None:
    tight, tight_events = _run(False, target, config, scenario, seconds)
    readable, readable_events = _run(True, target, config, scenario, seconds)
    assert tight.keys() == readable.keys() and len(tight["t_s"]) > 1000
    changed = [name for name in tight if not np.array_equal(tight[name], readable[name], equal_nan=True)]
    assert not changed
    assert tight_events == readable_events


def _run(readable: bool, target: str, config: Path | None, scenario: Path | None,
         seconds: float) -> tuple[dict[str, np.ndarray], tuple[str, ...]]:
    cfg = hilbench.load_config(config, [f'link.target="{target}"', f"run.duration_s={seconds}"], scenario_path=scenario)
    with hilbench.Bench(cfg, scenario=True) as bench:
        assert bench.session is not None
        bench.session._readable_periods = readable  # type: ignore[attr-defined]
        bench.run()
        signals = bench.signals()
        return {name: np.asarray(signals[name]) for name in signals}, bench.events


@pytest.mark.parametrize("c_span", [False, True])
def test_the_parts_act_only_in_their_periods(monkeypatch: pytest.MonkeyPatch, c_span: bool) -> None:
    """The history sample every 20 periods and the scenario in its events' periods; between them
    the loop runs plain periods. The C span takes the history samples itself: the part is then due
    only where it has more to do (none here: no display, no observer, no recorder to flush)."""
    seen: dict[str, list[int]] = {"history": [], "scenario": []}
    history_run, scenario_run = HistoryPart.run, ScenarioPart.run

    def history(self: HistoryPart, k: int) -> None:
        seen["history"].append(k)
        history_run(self, k)

    def scenario(self: ScenarioPart, k: int) -> None:
        seen["scenario"].append(k)
        scenario_run(self, k)

    monkeypatch.setattr(HistoryPart, "run", history)
    monkeypatch.setattr(ScenarioPart, "run", scenario)
    with hilbench.Bench(target="inprocess:an1017") as bench:
        session = bench.session
        assert session is not None
        session.c_span = c_span  # type: ignore[misc]
        bench.set_reference(1000)  # at period 0
        bench.run(0.01)
        bench.press("s2")  # at period 200; released 2 ms (40 periods) later
        bench.run(0.01)
        sampled = [round(t_s / session.period.s) for t_s, _, _, _ in session.history]
        in_c = session._span_samples is not None
    assert sampled == list(range(0, 400, 20))
    assert seen["history"] == ([] if c_span and in_c else list(range(0, 400, 20)))
    assert seen["scenario"] == [0, 200, 240]
