"""`ctl step` and the page's step (issue 22, item 5): refused on a motor that is not running, the
scenario's events wait while a step owns the reference, and the reply carries its figures with units."""

from __future__ import annotations

from typing import Any

import hilbench
from hilbench.bench.parts import CTL_STEP_AFTER_S, CTL_STEP_HOLD_S


class Request:
    """A control request answered in process (what the control socket hands the session)."""

    def __init__(self, cmd: str, **args: Any) -> None:
        self.cmd, self.args = cmd, args
        self.answer: tuple[bool, str, Any] | None = None

    def reply(self, ok: bool, text: str, data: dict[str, Any] | None = None) -> None:
        assert self.answer is None, "answered twice"
        self.answer = (ok, text, data)


def _send(bench: hilbench.Bench, cmd: str, **args: Any) -> Request:
    request = Request(cmd, **args)
    bench.session.handle_control(request, bench.t_s)  # type: ignore[union-attr]
    return request


def test_a_step_on_a_stopped_motor_is_refused() -> None:
    with hilbench.Bench(target="inprocess:an1017") as bench:
        bench.set_reference(1500)
        bench.run(0.05)  # S2 never pressed: the firmware is stopped
        request = _send(bench, "step", from_rpm=1000.0, to_rpm=2000.0)
        assert request.answer is not None
        ok, text, _ = request.answer
        assert not ok and "not running (state STOPPED)" in text and "press s2" in text
        assert not bench.session.live.steps  # type: ignore[union-attr]


SCENARIO = 'scenario=[{at_s = 0.0, ref_rpm = 1500.0}, {at_s = 0.01, press = "s2"}, {at_s = 1.5, ref_rpm = 500.0}]'


def test_scenario_events_wait_for_the_step_and_the_reply_has_units() -> None:
    with hilbench.Bench(target="inprocess:an1017", overrides=(SCENARIO,), scenario=True) as bench:
        bench.run(1.0)
        step = _send(bench, "step", from_rpm=1000.0, to_rpm=2000.0)
        t_step = bench.t_s
        assert step.answer is None  # answered when the record after the step is complete
        bench.run(CTL_STEP_HOLD_S + CTL_STEP_AFTER_S + 0.05)
        assert step.answer is not None
        bench.run(0.5)
        events = bench.events
        speed_after = bench.speed_rpm
    ok, text, data = step.answer
    assert ok, text
    # the scenario's 1.5 s event (500 rpm) waited: the step went 1000 -> 2000 undisturbed
    assert abs(data["ss_error_pct"]) < 5 and speed_after < 1500  # then it ran
    held = next(e for e in events if e.startswith("t=1.000000 step 1000 -> 2000 rpm (ctl)"))
    assert "scenario events due from t=1.500 s wait until the step ends" in held
    late = next(e for e in events if e.endswith("ref 500 rpm"))
    assert float(late.split()[0][2:]) >= t_step + CTL_STEP_HOLD_S + CTL_STEP_AFTER_S - 1e-9
    # the figures, with units in the reply and in its one line
    assert data["units"]["rise_time_s"] == "s" and data["units"]["ss_error"] == "rpm"
    assert 0 < data["rise_time_s"] < 0.5 and data["settling_time_s"] is not None
    assert "rise " in text and " ms" in text and "overshoot" in text and " %," in text and "rpm*s" in text
    assert f"{data['rise_time_s'] * 1e3:.1f} ms" in text
