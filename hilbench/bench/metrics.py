"""Step-response metrics: one definition of "how good was that step" for run, step and sweep.

Every figure is computed on the normalised response ``z = (y - y0) / (y_final_ref - y0)``, so a
step down (1000 → -500 rpm) gives exactly the same rise, overshoot, settling, error and ripple
as its mirror image going up. Conventions (fixed here, used everywhere):

- Time is measured from the step (``t_step_s``, default the first sample); samples before the
  step are ignored.
- Rise time: 10 % → 90 % of the step, first crossings, linearly interpolated between samples.
- Overshoot: how far the response goes past the *reference* in the step's direction, in % of the
  step size; 0 when it never passes it.
- Settling time: the band is ``±settle_band × |step|`` around the *reference* final value (not the
  measured one): the question the user asks is "how long until the speed is within 2 % of what I
  asked for"; a loop with a steady-state offset larger than the band never settles, and its
  offset is reported separately. Settling time is the interpolated time of the last exit from
  the band. The response counts as settled only if the whole steady-state window (the last
  ``ss_fraction`` of the record) is inside the band; otherwise ``settling_time_s`` is ``None``
  (a sustained oscillation can be inside the band at the last sample by chance).
- Steady-state error: mean of ``(y_final_ref - y) · sign(step)`` over the steady-state window:
  positive means the response stops short of the reference. Ripple: peak-to-peak of y there.
- IAE = ∫|e| dt, ITAE = ∫ (t - t_step)·|e| dt with ``e = y_final_ref - y``, trapezoidal, over
  the whole record after the step, in y-units·s and y-units·s².
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Sequence

import numpy as np

from hilbench.errors import ConfigError


@dataclass(frozen=True)
class StepMetrics:
    """Figures of one step response (y-units are the caller's, e.g. rpm; times in s from the step)."""

    y0: float
    y_final_ref: float
    step_size: float  # y_final_ref - y0, signed
    rise_time_s: float | None  # 10-90 %; None if the response never reaches 90 %
    t10_s: float | None
    t90_s: float | None
    overshoot_pct: float  # >= 0, % of |step_size| past the reference
    peak_time_s: float | None  # time of the largest excursion past the reference; None if none
    peak_value: float  # extreme y in the step's direction
    settling_time_s: float | None  # None: not inside the band over the steady-state window
    settle_band: float  # fraction of |step_size|
    ss_error: float  # y-units, positive = short of the reference
    ss_error_pct: float  # % of |step_size|
    ss_ripple: float  # peak-to-peak y-units over the steady-state window
    ss_ripple_pct: float
    iae: float  # y-units·s
    itae: float  # y-units·s²
    peak_current_a: float | None  # max |current| after the step, if currents were given
    duration_s: float  # record length after the step
    n_samples: int

    @property
    def settled(self) -> bool:
        return self.settling_time_s is not None

    def as_dict(self) -> dict[str, Any]:
        """Plain data (for JSON replies, CSV rows, recordings)."""
        return asdict(self)


def _first_crossing(t: np.ndarray, z: np.ndarray, level: float) -> float | None:
    """Interpolated time at which z first reaches ``level`` (z rising towards it), or None."""
    hits = np.flatnonzero(z >= level)
    if hits.size == 0:
        return None
    i = int(hits[0])
    if i == 0:
        return float(t[0])
    z0, z1 = z[i - 1], z[i]
    frac = (level - z0) / (z1 - z0)
    return float(t[i - 1] + frac * (t[i] - t[i - 1]))


def step_metrics(
    t_s: Sequence[float] | np.ndarray,
    y: Sequence[float] | np.ndarray,
    *,
    y0: float,
    y_final_ref: float,
    current_a: Sequence[float] | np.ndarray | None = None,
    settle_band: float = 0.02,
    ss_fraction: float = 0.1,
    t_step_s: float | None = None,
) -> StepMetrics:
    """Measure one step response; see the module docstring for every definition.

    ``t_s`` must be increasing. ``current_a`` (same length) may be phase or bus current; its
    largest magnitude after the step is reported.
    """
    step = float(y_final_ref) - float(y0)
    _check_shape(step, y0, y_final_ref, settle_band, ss_fraction)
    t, yy, cur = _after_step(t_s, y, current_a, t_step_s)
    z = (yy - y0) / step  # normalised: 0 before, 1 at the reference, in the step's direction
    abs_step = abs(step)
    duration = float(t[-1])
    t10 = _first_crossing(t, z, 0.1)
    t90 = _first_crossing(t, z, 0.9)
    i_peak = int(np.argmax(z))
    z_peak = float(z[i_peak])
    # steady state: the last ss_fraction of the record (by time, at least one sample)
    win = t >= duration * (1.0 - ss_fraction)
    if not np.any(win):
        win[-1] = True
    y_win = yy[win]
    ss_error = float(np.mean(y_final_ref - y_win)) * math.copysign(1.0, step)
    ss_ripple = float(np.max(y_win) - np.min(y_win))
    iae, itae = _integrals(t, np.abs(y_final_ref - yy))
    return StepMetrics(
        y0=float(y0), y_final_ref=float(y_final_ref), step_size=step,
        rise_time_s=(t90 - t10) if (t10 is not None and t90 is not None) else None, t10_s=t10, t90_s=t90,
        overshoot_pct=max(0.0, (z_peak - 1.0) * 100.0), peak_time_s=float(t[i_peak]) if z_peak > 1.0 else None,
        peak_value=float(yy[i_peak]), settling_time_s=_settling(t, z, win, settle_band),
        settle_band=float(settle_band), ss_error=ss_error, ss_error_pct=ss_error / abs_step * 100.0,
        ss_ripple=ss_ripple, ss_ripple_pct=ss_ripple / abs_step * 100.0, iae=iae, itae=itae,
        peak_current_a=float(np.max(np.abs(cur))) if cur is not None else None,
        duration_s=duration, n_samples=int(t.size),
    )


def _check_shape(step: float, y0: float, y_final_ref: float, settle_band: float, ss_fraction: float) -> None:
    if step == 0.0 or not math.isfinite(step):
        raise ConfigError(f"step_metrics: step size must be finite and non-zero (y0={y0}, y_final_ref={y_final_ref})")
    if not 0.0 < settle_band < 1.0:
        raise ConfigError(f"step_metrics: settle_band must be in (0, 1), got {settle_band}")
    if not 0.0 < ss_fraction <= 1.0:
        raise ConfigError(f"step_metrics: ss_fraction must be in (0, 1], got {ss_fraction}")


def _after_step(t_s: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray,
                current_a: Sequence[float] | np.ndarray | None,
                t_step_s: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The samples from the step on, time from the step (checked: 1-D, equal lengths, increasing)."""
    t = np.asarray(t_s, dtype=float)
    yy = np.asarray(y, dtype=float)
    if t.ndim != 1 or t.shape != yy.shape:
        raise ConfigError(f"step_metrics: t_s and y must be 1-D of equal length (got {t.shape} and {yy.shape})")
    cur = None
    if current_a is not None:
        cur = np.asarray(current_a, dtype=float)
        if cur.shape != t.shape:
            raise ConfigError(f"step_metrics: current_a has shape {cur.shape}, t_s has {t.shape}")
    t_step = (float(t[0]) if t.size else 0.0) if t_step_s is None else float(t_step_s)
    keep = t >= t_step
    t = t[keep] - t_step
    if t.size < 2:
        raise ConfigError(f"step_metrics: need at least 2 samples after the step at t={t_step} s, got {t.size}")
    if np.any(np.diff(t) <= 0.0):
        raise ConfigError("step_metrics: t_s must be strictly increasing")
    return t, yy[keep], (cur[keep] if cur is not None else None)


def _settling(t: np.ndarray, z: np.ndarray, win: np.ndarray, settle_band: float) -> float | None:
    """When the normalised response enters the band for good (None: outside it in the steady window)."""
    out = np.abs(z - 1.0) - settle_band  # > 0: outside the band
    outside = out > 0.0
    if np.any(outside[win]):
        return None
    if not np.any(outside):
        return 0.0
    i = int(np.flatnonzero(outside)[-1])  # last sample outside; i + 1 is inside (window is)
    d0, d1 = out[i], out[i + 1]
    return float(t[i] + (t[i + 1] - t[i]) * d0 / (d0 - d1))


def _integrals(t: np.ndarray, err: np.ndarray) -> tuple[float, float]:
    """IAE and ITAE by the trapezoid rule (np.trapz/trapezoid differ by numpy version)."""
    dt = np.diff(t)
    iae = float(np.dot(0.5 * (err[1:] + err[:-1]), dt))
    te = t * err
    return iae, float(np.dot(0.5 * (te[1:] + te[:-1]), dt))


# (key in StepMetrics, column header, unit) in the order tables and CSVs show them.
METRIC_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("rise_time_s", "rise 10-90 %", "s"),
    ("overshoot_pct", "overshoot", "%"),
    ("settling_time_s", "settling 2 %", "s"),
    ("ss_error", "ss error", "y"),
    ("ss_error_pct", "ss error", "%"),
    ("ss_ripple", "ripple p-p", "y"),
    ("iae", "IAE", "y·s"),
    ("itae", "ITAE", "y·s²"),
    ("peak_current_a", "peak |I|", "A"),
)

_SORT_KEYS = {key for key, _, _ in METRIC_COLUMNS}


def compare_table(
    rows: Sequence[tuple[str, StepMetrics]],
    *,
    sort_by: str | None = None,
) -> list[dict[str, Any]]:
    """Rows of plain data for a comparison table: ``{"label": …, <metric key>: value, "rank": n}``.

    Values are floats or None (never formatted: that is the face's job). With ``sort_by`` (a key
    of METRIC_COLUMNS, smaller is better; for ``ss_error`` the magnitude counts) rows are ranked,
    best first, and None (e.g. never settled) ranks last; without it the input order is kept and
    ``rank`` is None.
    """
    if sort_by is not None and sort_by not in _SORT_KEYS:
        raise ConfigError(f"compare_table: unknown metric {sort_by!r} (choose from {', '.join(sorted(_SORT_KEYS))})")
    table: list[dict[str, Any]] = []
    for label, m in rows:
        row: dict[str, Any] = {"label": str(label)}
        for key, _, _ in METRIC_COLUMNS:
            row[key] = getattr(m, key)
        row["settled"] = m.settled
        row["rank"] = None
        table.append(row)
    if sort_by is not None:

        def order(r: dict[str, Any]) -> tuple[int, float]:
            v = r[sort_by]
            if v is None or (isinstance(v, float) and math.isnan(v)):
                return (1, 0.0)
            return (0, abs(v) if sort_by == "ss_error" or sort_by == "ss_error_pct" else v)

        table.sort(key=order)  # stable: ties keep input order
        for n, r in enumerate(table, start=1):
            r["rank"] = n
    return table


__all__ = ["StepMetrics", "step_metrics", "compare_table", "METRIC_COLUMNS"]
