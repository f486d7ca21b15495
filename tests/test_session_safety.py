"""Review findings on the session's hot path and the AN1017 core, kept as regressions:

* a parameter written by the observer (the dashboard, a user's callback) arms the guard at once,
  as one written between `advance` calls does;
* an error inside a period (a plant step that raises) ends the run with a fault marker and whole
  rows: nothing recorded is lost, and no later period is appended after a half-written row;
* the compiled AN1017 core answers only a repeat of its last Drive's own seq without stepping, as
  the Python reference does (a Sensors after a real-time `advance` with that seq is a new period);
* the core's build constants (divisors of the speed measurement) cannot be written from Python.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import hilbench
from hilbench.bench.recorder import MARKER_FAULT
from hilbench.bench.parts import LivePart
from hilbench.protocol import Sensors
from hilbench.targets.an1017.target import An1017Target, available_backends


def test_a_parameter_written_by_the_observer_arms_the_guard_at_once(monkeypatch: pytest.MonkeyPatch) -> None:
    looks: list[int] = []
    original = LivePart.run

    def spy(self: LivePart, k: int) -> None:
        if self.session.period.t_s(k) < self.session.tuning.watching:
            looks.append(k)
        original(self, k)

    monkeypatch.setattr(LivePart, "run", spy)
    armed: dict[str, float] = {}

    def observer(snapshot: hilbench.Snapshot) -> None:
        if not armed and snapshot.t_s > 0.3:
            bench.set_params(kp=0.2)
            armed["t_s"] = snapshot.t_s

    with hilbench.Bench(target="inprocess:an1017", observer=observer) as bench:
        bench.set_reference(1500)
        bench.press("s2")
        bench.run(0.6)
        period_s = bench.session.period.s
        every_s = bench.session.options.history_every_periods * period_s
    assert armed and looks, "the observer's write was never guarded"
    first_s = looks[0] * period_s
    assert first_s - armed["t_s"] <= 2 * every_s  # from the next history period on
    assert len(looks) >= (0.6 - armed["t_s"]) / every_s - 2  # and in every one after it


def test_an_error_inside_a_period_ends_the_run_with_whole_rows_and_a_fault_marker() -> None:
    with hilbench.Bench(target="inprocess:an1017") as bench:
        bench.set_reference(1500)
        bench.press("s2")
        bench.run(0.05)
        session = bench.session
        advance = session.plant.advance
        calls = {"n": 0}

        def flaky(*args: object) -> object:
            calls["n"] += 1
            if calls["n"] == 10:
                raise RuntimeError("plant hiccup")
            return advance(*args)

        session.plant.advance = flaky
        with pytest.raises(RuntimeError, match="plant hiccup"):
            bench.run(0.05)
        assert session.ended and session.summary.end_reason == "fault"
        assert "RuntimeError: plant hiccup" in session.summary.fault
        assert not bench.run(0.05)  # the run is over: nothing is appended after it
        signals = bench.signals()
    t_s = signals["t_s"]
    assert len(t_s) == 1000 + 9 and np.all(np.diff(t_s) > 0)
    assert signals["marker"][-1] == MARKER_FAULT


@pytest.mark.parametrize("backend", available_backends())
def test_a_sensors_after_advance_with_the_same_seq_is_a_new_period(backend: str) -> None:
    host = SimpleNamespace(seq=0, period_us=50, mode=0, watchdog_ms=0)
    target = An1017Target(backend=backend)
    target.hello(host)
    target.start()
    for k in range(1, 400):
        target.step(Sensors(k & 0xFF, 0b001, (), 0, (700, 0, 0)))
    target.advance(50.0, Sensors(5, 0b011, (), 0, (700, 0, 0)))
    before_us = target.time_us
    drive = target.step(Sensors(5, 0b011, (), 0, (700, 0, 0)))
    assert drive.seq == 5 and target.time_us - before_us == 50.0
    again = target.step(Sensors(5, 0b011, (), 0, (700, 0, 0)))  # a true repeat: the same Drive, no step
    assert again == drive and target.time_us - before_us == 50.0


def test_the_cores_build_constants_are_read_only() -> None:
    if "c" not in available_backends():
        pytest.skip("the compiled AN1017 core is not built")
    target = An1017Target(backend="c")
    with pytest.raises(AttributeError):
        target.fw.min_period = 0  # type: ignore[misc]
    with pytest.raises(AttributeError):
        target.fw.max_period = 0  # type: ignore[misc]
