"""Assertions on recorded signals, not on text: each failure is ONE line naming the signal, the
window, the bound and the worst value, e.g.

    speed_rpm not within 1500 ± 30 rpm over 0.800-1.500 s: worst 1420.3 rpm (-79.7) at 0.8123 s

Each takes a `Bench` (its signals so far) or any mapping of column -> array with a ``t_s`` column
(`bench.signals()`, `hilbench.read_recording(path).columns`), returns the figure it judged, and
records that figure as a test property (JUnit ``<property>``) when the hilbench pytest plugin is
running the test.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Callable, Mapping, Union

import numpy as np

from hilbench.limits import is_finite_number

if TYPE_CHECKING:
    from hilbench.bench.bench import Bench
    from hilbench.bench.checks import CheckResult
    from hilbench.bench.metrics import StepMetrics
    from hilbench.bench.steptest import StepResult

Source = Union["Bench", Mapping[str, np.ndarray]]

#: where figures go while the plugin runs a test (set and cleared by hilbench.testing.plugin)
_metric_sink: Callable[[str, object], None] | None = None


def record_metric(name: str, value: object) -> None:
    """Attach a figure to the running test's report (a JUnit property); no-op outside pytest."""
    if _metric_sink is not None:
        _metric_sink(name, value)


def _columns(source: Source) -> tuple[Mapping[str, np.ndarray], Callable[[str], str]]:
    signals = getattr(source, "signals", None)
    data = signals() if callable(signals) else source
    unit_of = getattr(data, "unit", None)
    return data, (unit_of if callable(unit_of) else (lambda name: ""))  # type: ignore[return-value]


def _window(data: Mapping[str, np.ndarray], name: str, from_s: float, to_s: float | None) -> tuple[np.ndarray, np.ndarray, str]:
    __tracebackhide__ = True
    if name not in data:
        raise AssertionError(f"no signal {name!r} recorded (columns: {', '.join(data)})")
    t = np.asarray(data["t_s"])
    end = math.inf if to_s is None else to_s
    mask = (t >= from_s - 1e-12) & (t <= end + 1e-12)
    last = float(t[-1]) if t.size else 0.0
    window = f"{from_s:.3f}-{min(end, last):.3f} s"
    if not mask.any():
        raise AssertionError(f"{name}: no samples over {window} (recorded 0.000-{last:.3f} s)")
    return t[mask], np.asarray(data[name])[mask], window


def _u(unit: str) -> str:
    return f" {unit}" if unit else ""


def assert_settles(source: Source, signal: str, reference: float, *, band: float, by_s: float,
                   until_s: float | None = None) -> float:
    """``signal`` is within ``reference ± band`` from ``by_s`` to ``until_s`` (default: the end);
    returns the worst deviation."""
    __tracebackhide__ = True
    if not (is_finite_number(reference) and is_finite_number(band) and band >= 0):
        raise ValueError(f"assert_settles: reference={reference!r}, band={band!r}: finite numbers, band >= 0 "
                         "(a NaN band would pass anything)")
    data, unit_of = _columns(source)
    t, y, window = _window(data, signal, by_s, until_s)
    dev = y - reference
    i = int(np.argmax(np.abs(dev)))
    worst = float(dev[i])
    record_metric(f"{signal}.dev_from_{by_s:g}s", round(worst, 6))
    unit = _u(unit_of(signal))
    if not abs(worst) <= band:
        raise AssertionError(f"{signal} not within {reference:g} ± {band:g}{unit} over {window}: "
                             f"worst {float(y[i]):.6g}{unit} ({worst:+.4g}) at {float(t[i]):.4f} s")
    return worst


def assert_within(source: Source, signal: str, *, min: float | None = None, max: float | None = None,  # noqa: A002
                  from_s: float = 0.0, to_s: float | None = None) -> float:
    """``signal`` stays within [min, max] over the window; returns its worst value."""
    __tracebackhide__ = True
    if min is None and max is None:
        raise ValueError("assert_within: give min, max or both")
    data, unit_of = _columns(source)
    t, y, window = _window(data, signal, from_s, to_s)
    lo = -math.inf if min is None else min
    hi = math.inf if max is None else max
    excess = np.maximum(lo - y, y - hi)
    i = int(np.argmax(np.where(np.isnan(y), np.inf, excess)))
    worst = float(y[i])
    record_metric(f"{signal}.worst_from_{from_s:g}s", round(worst, 6))
    unit = _u(unit_of(signal))
    if not excess[i] <= 0.0:
        bound = f"[{'' if min is None else format(min, 'g')}, {'' if max is None else format(max, 'g')}]{unit}"
        raise AssertionError(f"{signal} outside {bound} over {window}: worst {worst:.6g}{unit} at {float(t[i]):.4f} s")
    return worst


def assert_no_fault(source: Source, *, from_s: float = 0.0, to_s: float | None = None) -> None:
    """The firmware's fault column stayed 0 over the window."""
    __tracebackhide__ = True
    data, _ = _columns(source)
    t, codes, window = _window(data, "fault", from_s, to_s)
    bad = np.flatnonzero(codes != 0)
    record_metric("fault.periods", int(bad.size))
    if bad.size:
        i = int(bad[0])
        raise AssertionError(f"fault not 0 over {window}: code {int(codes[i])} at {float(t[i]):.4f} s "
                             f"({bad.size} periods with a fault)")


def assert_param(bench: "Bench", name: str, expected: float, *, tol: float | None = None) -> float:
    """Parameter ``name`` reads back as ``expected`` (± tol; default: one Q15 step, 1/32768)."""
    __tracebackhide__ = True
    values = bench.get_params()
    if name not in values:
        raise AssertionError(f"parameter {name!r} not declared by the target (declared: {', '.join(values)})")
    value = float(values[name])
    bound = 1.0 / 32768 if tol is None else tol
    record_metric(f"param.{name}", value)
    if not abs(value - expected) <= bound:
        raise AssertionError(f"parameter {name} at t={bench.t_s:.3f} s reads back {value:.6g}, "
                             f"not {expected:g} ± {bound:.3g} (off by {value - expected:+.3g})")
    return value


#: assert_step's bounds: keyword -> (metric field, unit)
STEP_BOUNDS = {
    "max_rise_time_s": ("rise_time_s", "s"),
    "max_settling_time_s": ("settling_time_s", "s"),
    "max_overshoot_pct": ("overshoot_pct", "%"),
    "max_ss_error_pct": ("ss_error_pct", "%"),
    "max_ss_ripple_pct": ("ss_ripple_pct", "%"),
    "max_peak_current_a": ("peak_current_a", "A"),
    "max_iae": ("iae", ""),
    "max_itae": ("itae", ""),
}


def assert_step(result: "StepResult | StepMetrics", **bounds: float) -> "StepMetrics":
    """Step metrics within bounds, e.g. ``assert_step(r, max_rise_time_s=0.4, max_overshoot_pct=5)``
    (keywords: see STEP_BOUNDS; |ss_error_pct| is compared). Every metric is recorded."""
    __tracebackhide__ = True
    unknown = sorted(set(bounds) - set(STEP_BOUNDS))
    if unknown:
        raise ValueError(f"assert_step: unknown bound {', '.join(unknown)} (known: {', '.join(STEP_BOUNDS)})")
    metrics: Any = getattr(result, "metrics", result)
    label = getattr(result, "label", "")
    for key, value in metrics.as_dict().items():
        if isinstance(value, (int, float)) and value is not None:
            record_metric(f"step.{key}", round(float(value), 6))
    window = f"{0.0:.3f}-{metrics.duration_s:.3f} s after the step"
    what = f"step {metrics.y0:g} -> {metrics.y_final_ref:g}" + (f" ({label})" if label else "")
    for key, bound in bounds.items():
        field, unit = STEP_BOUNDS[key]
        value = getattr(metrics, field)
        shown = f" {unit}" if unit else ""
        if value is None:
            raise AssertionError(f"{what}: {field} never reached over {window}; bound {bound:g}{shown}")
        figure = abs(value) if field == "ss_error_pct" else value
        if not figure <= bound:
            raise AssertionError(f"{what}: speed_rpm {field} {value:.4g}{shown} > {bound:g}{shown} over {window}")
    return metrics


def assert_config_checks(bench: "Bench") -> "list[CheckResult]":
    """The bench config's run [[check]] tables hold for what the bench ran (call after the run:
    it closes the bench to make its summary)."""
    __tracebackhide__ = True
    from hilbench.bench.checks import run_checks

    summary = bench.summary()
    results = run_checks(bench.config.check, summary, bench.signal_chunks)
    for r in results:
        if r.value is not None:
            record_metric(f"check.{r.name}", round(float(r.value), 6))
    failed = [r for r in results if not r.passed]
    if failed:
        raise AssertionError("; ".join(f"check {r.name}: {r.figure}" for r in failed))
    return results


__all__ = [
    "STEP_BOUNDS",
    "assert_config_checks",
    "assert_no_fault",
    "assert_param",
    "assert_settles",
    "assert_step",
    "assert_within",
    "record_metric",
]
