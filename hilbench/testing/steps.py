"""A speed step on a test's own bench, so its recording (and a failure's plots) are the test's.

`hilbench.step_test` opens a target of its own; inside a pytest bench test the step should run on
the ``bench`` fixture instead: the same test (reference, S2, hold, step, record) and the same
metrics (`hilbench.bench.metrics`), on the target the test was parametrised with.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from hilbench.bench.bench import Bench
    from hilbench.bench.steptest import StepResult


def step_response(bench: "Bench", from_rpm: float, to_rpm: float, *, settle_s: float = 0.5,
                  after_s: float = 0.5) -> "StepResult":
    """Start at ``from_rpm`` (reference, then S2, at t = 0), hold ``settle_s``, step to ``to_rpm``,
    record ``after_s``; the response's metrics (rise, overshoot, settling, error, peak current).
    Needs a fresh bench (t = 0) on a target with a speed loop."""
    from hilbench.bench.steptest import StepTest, analyse, require_speed_loop
    from hilbench.plant.period import Period
    from hilbench.errors import ConfigError

    if bench.t_s != 0.0:
        raise ConfigError(f"step_response: needs a fresh bench (this one is at t={bench.t_s:.3f} s)")
    require_speed_loop(bench.profile, "step_response")
    test = StepTest(from_rpm, to_rpm, settle_s, after_s)
    bench.set_reference(from_rpm)
    bench.press("s2")
    bench.run(settle_s)
    bench.set_reference(to_rpm)
    bench.run(after_s)
    period_s = Period(bench.config.link.period_us).s
    return analyse(dict(bench.signals()), test, bench.profile, f"{from_rpm:g} -> {to_rpm:g} rpm", {}, period_s)


__all__ = ["step_response"]
