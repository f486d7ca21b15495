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
    # protocol 3: 1 ms periods carry several hall edges each, which the AN1017 runtime reads in time
    ("inprocess:an1017", None, None, 1.5, ("link.period_us=1000",)),
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
    if any("overcurrent" in o for o in overrides):
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
            results.append((session.periods_done, session.drive, session._edge_s, session._hall_before, bytes(recorder.rows.data)
                            if recorder is not None and hasattr(recorder, "rows") else b""))
        monkeypatch.undo()
    assert results[0][0] > 100
    assert results[0] == results[1]


def test_the_c_span_builds_the_edges_sensing_builds() -> None:
    """Protocol 3's Sensors.edges in C (every hall edge and index mark of a period, the halls in force
    at a mark, time-ordered; None past the target's max_edges) equal hilbench.bench.sensing's, period
    after period of a coasting servo at long periods: several hall edges and index marks a period."""
    from hilbench.bench.sensing import hall_edges, with_index_marks
    from hilbench.protocol import OutputMode

    cfg = hilbench.load_config(SERVO, ['link.target="inprocess:foc"', "link.period_us=4000", "run.duration_s=0.1"])
    with hilbench.Bench(cfg, scenario=True) as bench:
        session = bench.session
        assert session is not None and session.profile.has("encoder")
        span, plant = session._c_span(None), session.plant
        assert span is not None
        limit, most = session.options.period_us * 10 - 1, session.target_max_edges()
        seen = {"marks": 0, "several": 0, "over": 0}
        for speed_rpm in (300.0, 1500.0, 3000.0, 6000.0, 30000.0):  # the last brakes through 16 edges
            plant.w_m = speed_rpm / model.RPM_PER_RAD_S
            hall_before = plant.hall_bits
            for _ in range(40):
                edge_s = plant.advance(0, 0, 0, int(OutputMode.OFF))
                index = plant.sense(())[2]
                edges = hall_edges(plant.edges(), limit) if edge_s is not None else ()
                if index:
                    edges = with_index_marks(edges, plant.index_marks(), limit, hall_before)
                    seen["marks"] += 1
                expected = None if len(edges) > most or len(plant.edges()) > most else edges
                seen["several"] += len(edges) > 2
                seen["over"] += expected is None
                assert span.edges(edge_s is not None, hall_before) == expected
                hall_before = plant.hall_bits
        assert seen["marks"] > 10 and seen["several"] > 10 and seen["over"] > 0
