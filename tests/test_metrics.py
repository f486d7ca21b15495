"""Step metrics against analytic responses (expectations derived independently of the code).

Second-order underdamped unit step (ζ < 1):
    y(t) = 1 - exp(-ζωn t) / sqrt(1-ζ²) · sin(ωd t + φ),  ωd = ωn sqrt(1-ζ²),  φ = arccos ζ
    peak time π/ωd, overshoot exp(-ζπ/sqrt(1-ζ²)); extrema of y-1 at t_k = kπ/ωd with
    |y(t_k) - 1| = exp(-kζπ/sqrt(1-ζ²)).  Rise times and the 2 % settling time are found by
    root finding (brentq) on the analytic expression, not on sampled data.
First-order unit step y = 1 - exp(-t/τ): t10 = τ ln(10/9), t90 = τ ln 10, rise = τ ln 9,
    2 % settling = τ ln 50, ∫|e| = τ, ∫t|e| = τ².
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from hilbench.bench.metrics import METRIC_COLUMNS, StepMetrics, compare_table, step_metrics
from hilbench.errors import ConfigError

CASES = [(0.2, 50.0), (0.5, 20.0), (0.7, 100.0), (0.8, 10.0)]  # (ζ, ωn rad/s)


def second_order(t: np.ndarray | float, zeta: float, wn: float) -> np.ndarray | float:
    wd = wn * math.sqrt(1 - zeta**2)
    phi = math.acos(zeta)
    return 1 - np.exp(-zeta * wn * t) / math.sqrt(1 - zeta**2) * np.sin(wd * t + phi)


def analytic_second_order(zeta: float, wn: float, band: float = 0.02) -> dict[str, float]:
    wd = wn * math.sqrt(1 - zeta**2)
    phi = math.acos(zeta)
    f = lambda t: float(second_order(t, zeta, wn))  # noqa: E731
    t_peak = math.pi / wd
    t10 = brentq(lambda t: f(t) - 0.1, 0.0, t_peak, xtol=1e-14)
    t90 = brentq(lambda t: f(t) - 0.9, 0.0, t_peak, xtol=1e-14)
    # Last extremum still outside the band; the exit lies between it and the next zero of y-1.
    k = 0
    while math.exp(-(k + 1) * zeta * math.pi / math.sqrt(1 - zeta**2)) > band:
        k += 1
    t_k = k * math.pi / wd
    t_zero = ((k + 1) * math.pi - phi) / wd
    t_settle = brentq(lambda t: abs(f(t) - 1) - band, t_k, t_zero, xtol=1e-14)
    return {
        "overshoot_pct": 100 * math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2)),
        "peak_time_s": t_peak,
        "rise_time_s": t90 - t10,
        "settling_time_s": t_settle,
    }


def sampled(zeta: float, wn: float, *, y0: float, y1: float, n: int = 20001) -> tuple[np.ndarray, np.ndarray, float]:
    t_end = 3 * 4.6 / (zeta * wn)  # ~3 × the 1 % envelope time: the last 10 % is well settled
    t = np.linspace(0.0, t_end, n)
    return t, y0 + (y1 - y0) * second_order(t, zeta, wn), t[1] - t[0]


@pytest.mark.parametrize("zeta,wn", CASES)
def test_second_order_matches_analytic(zeta: float, wn: float) -> None:
    t, y, dt = sampled(zeta, wn, y0=1000.0, y1=2000.0)
    m = step_metrics(t, y, y0=1000.0, y_final_ref=2000.0)
    exp = analytic_second_order(zeta, wn)
    assert m.overshoot_pct == pytest.approx(exp["overshoot_pct"], rel=1e-4, abs=1e-6)
    assert m.peak_time_s == pytest.approx(exp["peak_time_s"], abs=dt)
    assert m.rise_time_s == pytest.approx(exp["rise_time_s"], rel=1e-4)
    assert m.settling_time_s == pytest.approx(exp["settling_time_s"], abs=dt)
    assert m.ss_error == pytest.approx(0.0, abs=1e-3 * 1000)
    assert m.settled


def test_overshoot_below_band_settles_on_first_approach() -> None:
    # ζ = 0.8: overshoot 1.5 % < 2 %, so the settling time is the first entry into the band.
    exp = analytic_second_order(0.8, 10.0)
    assert exp["overshoot_pct"] < 2.0
    t, y, dt = sampled(0.8, 10.0, y0=0.0, y1=1.0)
    m = step_metrics(t, y, y0=0.0, y_final_ref=1.0)
    assert m.settling_time_s == pytest.approx(exp["settling_time_s"], abs=dt)
    assert m.settling_time_s < exp["peak_time_s"]


@pytest.mark.parametrize("zeta,wn", CASES)
def test_negative_step_equals_mirrored_positive(zeta: float, wn: float) -> None:
    t, y_down, _ = sampled(zeta, wn, y0=1000.0, y1=-500.0)
    y_up = 2 * 1000.0 - y_down  # mirror about y0: 1000 → 2500
    down = step_metrics(t, y_down, y0=1000.0, y_final_ref=-500.0)
    up = step_metrics(t, y_up, y0=1000.0, y_final_ref=2500.0)
    for key in ("rise_time_s", "overshoot_pct", "peak_time_s", "settling_time_s", "ss_error", "ss_error_pct",
                "ss_ripple", "iae", "itae"):
        assert getattr(down, key) == pytest.approx(getattr(up, key), rel=1e-9, abs=1e-9), key
    exp = analytic_second_order(zeta, wn)
    assert down.overshoot_pct == pytest.approx(exp["overshoot_pct"], rel=1e-4)
    assert down.peak_value < -500.0  # the excursion goes past the reference downwards
    assert down.step_size == -1500.0


def test_first_order_rise_settle_iae_itae() -> None:
    tau, delta = 0.05, 800.0
    t = np.linspace(0.0, 20 * tau, 20001)
    y = 200.0 + delta * (1 - np.exp(-t / tau))
    m = step_metrics(t, y, y0=200.0, y_final_ref=1000.0)
    dt = t[1] - t[0]
    assert m.overshoot_pct == 0.0
    assert m.peak_time_s is None
    assert m.t10_s == pytest.approx(tau * math.log(10 / 9), rel=1e-5)
    assert m.t90_s == pytest.approx(tau * math.log(10), rel=1e-5)
    assert m.rise_time_s == pytest.approx(tau * math.log(9), rel=1e-5)
    assert m.settling_time_s == pytest.approx(tau * math.log(50), abs=dt)
    assert m.iae == pytest.approx(tau * delta, rel=1e-5)
    assert m.itae == pytest.approx(tau**2 * delta, rel=1e-5)
    assert m.ss_error == pytest.approx(0.0, abs=1e-3)


def test_first_order_negative_step_iae() -> None:
    tau, delta = 0.02, 1500.0
    t = np.linspace(0.0, 20 * tau, 20001)
    y = 1000.0 - delta * (1 - np.exp(-t / tau))
    m = step_metrics(t, y, y0=1000.0, y_final_ref=-500.0)
    assert m.rise_time_s == pytest.approx(tau * math.log(9), rel=1e-5)
    assert m.iae == pytest.approx(tau * delta, rel=1e-5)
    assert m.itae == pytest.approx(tau**2 * delta, rel=1e-5)


def test_sustained_oscillation_never_settles() -> None:
    # ζ = 0: y = 1 - cos(ωn t), swinging between 0 and 2 forever.
    wn = 2 * math.pi * 5.0
    t = np.linspace(0.0, 2.0, 4001)
    y = 1 - np.cos(wn * t)
    m = step_metrics(t, y, y0=0.0, y_final_ref=1.0)
    assert m.settling_time_s is None and not m.settled
    assert m.overshoot_pct == pytest.approx(100.0, rel=1e-6)
    assert m.ss_ripple == pytest.approx(2.0, rel=1e-3)  # last 0.2 s holds a full 0.2 s period


def test_oscillation_ending_inside_band_by_chance_is_not_settled() -> None:
    # The record ends exactly at a zero crossing of y - 1: the last sample is inside the band.
    wn = 2 * math.pi * 5.0
    t_end = 2 * math.pi * 9 / wn  # sin(wn t_end) = 0
    t = np.linspace(0.0, t_end, 5001)
    y = 1 + 0.3 * np.sin(wn * t) * (t > 0)
    assert abs(y[-1] - 1) < 0.02
    assert step_metrics(t, y, y0=0.0, y_final_ref=1.0).settling_time_s is None


def test_offset_larger_than_band_reports_error_and_no_settling() -> None:
    tau = 0.01
    t = np.linspace(0.0, 0.5, 5001)
    for y0, ref in ((1000.0, 2000.0), (2000.0, 1000.0)):
        y = y0 + 0.95 * (ref - y0) * (1 - np.exp(-t / tau))  # stops 5 % short
        m = step_metrics(t, y, y0=y0, y_final_ref=ref)
        assert m.settling_time_s is None
        assert m.ss_error == pytest.approx(50.0, rel=1e-6)  # positive: short of the reference
        assert m.ss_error_pct == pytest.approx(5.0, rel=1e-6)
        assert m.ss_ripple == pytest.approx(0.0, abs=1e-6)


def test_never_reaches_90_percent() -> None:
    tau = 1.0
    t = np.linspace(0.0, 1.0, 1001)  # one τ: reaches 63 %
    m = step_metrics(t, 1 - np.exp(-t / tau), y0=0.0, y_final_ref=1.0)
    assert m.t10_s == pytest.approx(tau * math.log(10 / 9), rel=1e-5)
    assert m.t90_s is None and m.rise_time_s is None
    assert m.settling_time_s is None


def test_noisy_sampled_first_order_is_sane() -> None:
    # 1 kHz samples (the AN1017 speed-loop rate), 0.2 % of the step Gaussian noise, integer rpm.
    rng = np.random.default_rng(1234)
    tau, y0, y1 = 0.1, 1000.0, 2000.0
    t = np.arange(0, 2001) * 1e-3
    y = np.round(y0 + (y1 - y0) * (1 - np.exp(-t / tau)) + rng.normal(0.0, 2.0, t.size))
    m = step_metrics(t, y, y0=y0, y_final_ref=y1)
    assert m.rise_time_s == pytest.approx(tau * math.log(9), rel=0.03)
    assert m.settling_time_s == pytest.approx(tau * math.log(50), rel=0.1)
    assert m.overshoot_pct < 1.0
    assert abs(m.ss_error) < 1.0  # mean of 200 samples with σ = 2 rpm
    assert 4.0 < m.ss_ripple < 20.0  # peak-to-peak of 200 N(0, 2) samples is ~5-6 σ
    assert m.iae == pytest.approx(tau * 1000.0, rel=0.05)


def test_pre_step_samples_and_current() -> None:
    tau = 0.01
    t = np.linspace(-0.1, 0.3, 4001)
    y = np.where(t < 0.0, 500.0, 500.0 + 500.0 * (1 - np.exp(-np.clip(t, 0, None) / tau)))
    i = np.where(t < 0, 9.0, 2.0 * np.exp(-np.clip(t, 0, None) / tau))  # a spike before the step is ignored
    i[-5] = -3.5
    m = step_metrics(t, y, y0=500.0, y_final_ref=1000.0, current_a=i, t_step_s=0.0)
    assert m.rise_time_s == pytest.approx(tau * math.log(9), rel=1e-4)
    assert m.peak_current_a == pytest.approx(3.5)
    assert m.duration_s == pytest.approx(0.3)


def test_bad_inputs_raise_config_error() -> None:
    t = np.linspace(0, 1, 11)
    with pytest.raises(ConfigError):
        step_metrics(t, t, y0=1.0, y_final_ref=1.0)  # zero step
    with pytest.raises(ConfigError):
        step_metrics(t, t[:-1], y0=0.0, y_final_ref=1.0)
    with pytest.raises(ConfigError):
        step_metrics(t[::-1], t, y0=0.0, y_final_ref=1.0)
    with pytest.raises(ConfigError):
        step_metrics(t, t, y0=0.0, y_final_ref=1.0, settle_band=0.0)
    with pytest.raises(ConfigError):
        step_metrics(t, t, y0=0.0, y_final_ref=1.0, current_a=t[:3])


def _fake(label_itae: float | None, settle: float | None) -> StepMetrics:
    base = step_metrics([0.0, 1.0], [0.0, 1.0], y0=0.0, y_final_ref=1.0)
    from dataclasses import replace

    return replace(base, itae=label_itae, settling_time_s=settle)


def test_compare_table_plain_data_and_ranking() -> None:
    rows = [("a", _fake(3.0, 0.2)), ("b", _fake(1.0, None)), ("c", _fake(2.0, 0.1))]
    unsorted = compare_table(rows)
    assert [r["label"] for r in unsorted] == ["a", "b", "c"]
    assert all(r["rank"] is None for r in unsorted)
    assert set(k for k, _, _ in METRIC_COLUMNS) <= set(unsorted[0])
    by_itae = compare_table(rows, sort_by="itae")
    assert [(r["label"], r["rank"]) for r in by_itae] == [("b", 1), ("c", 2), ("a", 3)]
    by_settle = compare_table(rows, sort_by="settling_time_s")
    assert [r["label"] for r in by_settle] == ["c", "a", "b"]  # never settled ranks last
    assert by_settle[-1]["settled"] is False
    with pytest.raises(ConfigError):
        compare_table(rows, sort_by="nope")
