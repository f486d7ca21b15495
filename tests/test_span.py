"""The session's lockstep span in C (hilbench/bench/_span.c) records what the Python loop records:
column for column, with live writes, sensor faults and buttons at the parts' periods, the
comparator's trip (its period goes back to Python), and an error inside a span."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import hilbench
from hilbench.bench.session import Session, _span
from hilbench.plant import model

ROOT = Path(__file__).resolve().parent.parent
RANDOM = ROOT / "tests" / "golden" / "random_an1017.toml"
SERVO = ROOT / "bench_configs" / "servo_200w.toml"

pytestmark = pytest.mark.skipif(_span is None or model._CPlant is None, reason="the C span is not built")


def _run(mode: str, target: str, config: Path | None, scenario: Path | None, seconds: float,
         overrides: tuple[str, ...] = ()) -> tuple[dict[str, np.ndarray], tuple[str, ...], int]:
    """One run: mode "c" (the C span), "python" (the tight Python loop), "readable" (period by period).
    Returns the columns, the events and how many periods the C span ran."""
    cfg = hilbench.load_config(config, [f'link.target="{target}"', f"run.duration_s={seconds}", *overrides],
                               scenario_path=scenario)
    spans: list = []
    with hilbench.Bench(cfg, scenario=True) as bench:
        session = bench.session
        assert session is not None
        session.c_span = mode == "c"  # type: ignore[misc]
        session._readable_periods = mode == "readable"  # type: ignore[attr-defined]
        make = session._c_span
        session._c_span = lambda rows: spans.append(make(rows)) or spans[-1]  # type: ignore[method-assign]
        bench.run()
        signals = bench.signals()
        columns = {name: np.asarray(signals[name]) for name in signals}
        events = bench.events
    periods = sum(span.k for span in spans if span is not None)  # lower bound: k where each runner's last span stopped
    return columns, events, periods


def _same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> list[str]:
    assert a.keys() == b.keys() and len(a["t_s"]) > 1000
    return [name for name in a if not np.array_equal(a[name], b[name], equal_nan=True)]


@pytest.mark.parametrize("target, config, scenario, seconds, overrides", [
    ("inprocess:an1017", None, RANDOM, 1.7, ()),  # live writes, every sensor fault kind, load, bus, buttons
    ("inprocess:an1017", None, None, 0.5, ()),  # the default scenario
    # a comparator that trips under load: the trip's periods go back to Python, the stop re-arms it
    ("inprocess:an1017", None, RANDOM, 0.8, ("protection.overcurrent_a=0.35",)),
    ("inprocess:foc", SERVO, None, 0.6, ()),
])
def test_the_c_span_records_what_the_python_loop_records(target: str, config: Path | None, scenario: Path | None,
                                                         seconds: float, overrides: tuple[str, ...]) -> None:
    c, c_events, c_periods = _run("c", target, config, scenario, seconds, overrides)
    py, py_events, py_periods = _run("python", target, config, scenario, seconds, overrides)
    readable, readable_events, _ = _run("readable", target, config, scenario, seconds, overrides)
    assert not _same(c, py)
    assert not _same(c, readable)
    assert c_events == py_events == readable_events
    assert py_periods == 0
    assert c_periods > 0  # the C span ran
    if overrides:
        assert any("comparator tripped" in e for e in c_events)


def test_an_error_inside_a_span_leaves_what_the_python_loop_leaves(monkeypatch: pytest.MonkeyPatch) -> None:
    """The plant's Python step raising in the middle of a span: the same period, the same rows
    (the failing period's own fields written, the plant's not), the same Drive and edge after it."""
    results = []
    for mode in ("c", "python"):
        calls = {"n": 0}
        step_py = model.Plant._step_py

        def failing(self: model.Plant, *args: float) -> None:
            calls["n"] += 1
            if calls["n"] == 4321:
                raise RuntimeError("boom")
            step_py(self, *args)

        monkeypatch.setattr(model.Plant, "_step_py", failing)
        cfg = hilbench.load_config(None, ['link.target="inprocess:an1017"', "run.duration_s=0.5"])
        with hilbench.Bench(cfg, scenario=True) as bench:
            session = bench.session
            assert isinstance(session, Session)
            session.c_span = mode == "c"  # type: ignore[misc]
            session.plant.track_energy = True  # every step through Plant._step_py
            with pytest.raises(RuntimeError, match="boom"):
                bench.run()
            recorder = session.recorder
            results.append((session.periods_done, session.drive, session._edge_s, bytes(recorder.rows.data)
                            if recorder is not None and hasattr(recorder, "rows") else b""))
        monkeypatch.undo()
    assert results[0][0] > 100
    assert results[0] == results[1]
