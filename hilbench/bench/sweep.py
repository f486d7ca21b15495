"""Offline speed-step tests over many gain sets at once: the batch AN1017 firmware and the batch plant.

One step test (the same definition `hilbench step` uses with the scalar session, see
`step_scenario`): the pot is at ``from_rpm`` from t = 0 and S2 is pressed at ``press_at_s``
(held `BUTTON_HOLD_S`, the firmware starts on the release), the motor runs up and settles, the
pot steps to ``to_rpm`` at ``step_at_s``, and the record ends at ``duration_s``. Metrics
(`step_metrics`) are taken on the plant speed from the step on, with the firmware's quantised
references (the pot codes' RefSpeed in rpm) as ``y0`` and ``y_final_ref``.

Everything the scalar session does per period is mirrored exactly: event and button-release
periods are found with the session's float comparisons, the pot ADC code carries the plant's
seeded noise (same generator, same draw order as `Plant.adc_codes` with the AN1017 ADC roles),
the edge time is ``min(int(edge_s·1e7), 499)`` and duties reach the plant as counts/1000. So a
gain set gives the same firmware inputs here as in the scalar loop, and the results differ only
by the plant's float arithmetic (numpy vs math).

Limits (documented, not hidden): the batch plant models PWM and LOW_SIDE outputs only. An
instance whose firmware output is OFF gets zero duties on all phases (zero line voltage): exact
while the rotor is at rest before S2, an approximation (braking instead of coasting through the
freewheel diodes) after a stall stop. Such instances are flagged ``stalled`` and rank last.
"""

from __future__ import annotations

import csv
import dataclasses
import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from hilbench.bench.metrics import METRIC_COLUMNS, StepMetrics, step_metrics
from hilbench.bench.scenario import Event
from hilbench.bench.session import BUTTON_HOLD_S
from hilbench.errors import ConfigError
from hilbench.targets.an1017_batch import EDGE_NONE, An1017Batch
from hilbench.targets.an1017_firmware import (
    GAIN_CONSTRAINT_NAMES,
    STATE_STALLED,
    An1017Options,
    check_gain_constraints,
)
from hilbench.targets.profiles import AN1017_PROFILE

__all__ = [
    "StepResult",
    "SweepPoint",
    "SweepResult",
    "step_scenario",
    "run_step_batch",
    "sweep_grid",
    "grid_values",
    "parse_grid_spec",
    "write_sweep_csv",
    "best_fragment",
    "gains_q15",
]

PERIOD_US = 50
PERIOD_S = PERIOD_US * 1e-6
EDGE_LIMIT = PERIOD_US * 10 - 1  # the session's cap on the edge time (100 ns units)
ADC_ROLES = (1, 2, 3)  # AN1017's declared ADC roles: POT, IBUS, VBUS
ROLE_NAMES = {1: "pot", 2: "ibus", 3: "vbus", 4: "ia", 5: "ib"}
NOISE_BLOCK = 4096  # Plant draws its ADC noise in blocks of this many normals
METRIC_ALIASES = {
    "itae": "itae",
    "iae": "iae",
    "rise": "rise_time_s",
    "overshoot": "overshoot_pct",
    "settling": "settling_time_s",
    "ss_error": "ss_error",
    "ripple": "ss_ripple",
    "peak_current": "peak_current_a",
}

Gains = tuple[float, float, float]


@dataclass(frozen=True, eq=False)
class StepResult:
    """One gain set's step test: decimated trace, metrics, and how the firmware ended."""

    gains: Gains  # (kp, ki, kd) as fractions
    gains_q15: tuple[int, int, int]
    t_s: np.ndarray  # sample times (s from power-on), every `record_every` periods
    speed_rpm: np.ndarray  # plant speed at those times
    metrics: StepMetrics  # from the step on; peak_current_a = peak |i_dq| after the step
    ref_from_rpm: float  # the firmware's quantised references
    ref_to_rpm: float
    final_state: int
    stalled: bool  # the firmware stopped on its stall timer (metrics are not meaningful)


@dataclass(frozen=True)
class SweepPoint:
    """One grid point: simulated (result set) or skipped for a broken AN1017 constraint."""

    gains: Gains
    constraint: int | None = None  # the broken constraint (1, 2, 3), None when simulated
    result: StepResult | None = None
    rank: int | None = None

    @property
    def skipped(self) -> bool:
        return self.constraint is not None


@dataclass(frozen=True)
class SweepResult:
    """A whole grid: every point in grid order, the ranking, and the skipped count."""

    metric: str  # a StepMetrics key
    points: tuple[SweepPoint, ...]
    ranked: tuple[SweepPoint, ...]  # simulated points, best first
    skipped: int
    from_rpm: float
    to_rpm: float
    duration_s: float
    step_at_s: float
    sim_s: float = 0.0  # simulated plant-seconds (all instances)
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def best(self) -> SweepPoint | None:
        return self.ranked[0] if self.ranked else None


# ---------------------------------------------------------------------------- step definition
def step_scenario(
    from_rpm: float, to_rpm: float, step_at_s: float, duration_s: float, press_at_s: float = 0.0
) -> tuple[Event, ...]:
    """The step test as session events (what `hilbench step` plays with the scalar session)."""
    if not 0.0 <= press_at_s < step_at_s < duration_s:
        raise ConfigError(
            f"step test: need 0 <= press_at_s < step_at_s < duration_s (got {press_at_s}, {step_at_s}, {duration_s})"
        )
    return (
        Event(at_s=0.0, ref_rpm=float(from_rpm)),
        Event(at_s=press_at_s, press="s2"),
        Event(at_s=step_at_s, ref_rpm=float(to_rpm)),
        Event(at_s=duration_s, end=True),
    )


def _event_period(at_s: float, period_s: float) -> int:
    """First period k at which the session applies an event at at_s.

    The session gates on ``t_s >= next_t_s`` (no tolerance) before its ``due`` check, with
    t_s = k·period_s and period_s = 50·1e-6 (slightly below 5e-5): an event at 0.2 s is applied
    at k = 4001, not 4000. Mirrored here so both paths step the pot in the same period.
    """
    k = max(0, math.floor(at_s / period_s) - 2)
    while not (k * period_s >= at_s and at_s <= k * period_s + 1e-12):
        k += 1
    return k


def _release_period(k_press: int, period_s: float) -> int:
    """Period at which the session lets S2 go (t_s >= press time + BUTTON_HOLD_S)."""
    release_s = k_press * period_s + BUTTON_HOLD_S
    k = k_press
    while not k * period_s >= release_s:
        k += 1
    return k


def gains_q15(gains: Gains) -> tuple[int, int, int]:
    """Q15 words as the session writes them: round(x·32768), 1.0 → 32767."""
    out = []
    for x in gains:
        raw = 32767 if x == 1.0 else round(x * 32768.0)
        out.append(int(raw))
    return (out[0], out[1], out[2])


def _pot_codes(cfg: Any, code_by_period: np.ndarray, seed: int) -> np.ndarray:
    """The pot ADC code the plant reports each period, noise included, as `Plant.adc_codes`."""
    channels = {ch.role: ch for ch in cfg.adc}
    noisy = [ROLE_NAMES[r] for r in ADC_ROLES if ROLE_NAMES[r] in channels and channels[ROLE_NAMES[r]].noise_lsb]
    pot = channels.get("pot")
    if pot is None:
        raise ConfigError("sweep: the config has no [[adc]] channel with role = \"pot\"")
    x = code_by_period / 1023.0
    v = pot.offset_codes + pot.gain_codes_per_unit * x
    if pot.noise_lsb:
        n = code_by_period.size
        per = len(noisy)
        rng = np.random.Generator(np.random.PCG64(seed))
        blocks = -(-(n * per) // NOISE_BLOCK)
        g = np.concatenate([rng.standard_normal(NOISE_BLOCK) for _ in range(blocks)])
        v = v + pot.noise_lsb * g[noisy.index("pot") :: per][:n]
    return np.clip(np.floor(v + 0.5), 0, 1023).astype(np.int64)


def _batch_plant(cfg: Any, n: int) -> Any:
    from hilbench.config import plant_params_from_config
    from hilbench.plant.batch import BatchPlant

    params = plant_params_from_config(cfg)
    plant_section = cfg.sections.get("plant")
    substeps = getattr(plant_section, "substeps", None)  # as plant_from_config gives the scalar plant
    try:
        if substeps is None:
            return BatchPlant([params] * n)
        return BatchPlant([params] * n, substeps=int(substeps))
    except ValueError as exc:
        raise ConfigError(f"sweep: {exc}") from None


def _options(cfg: Any, options: An1017Options | None) -> An1017Options:
    if options is not None:
        return options
    target = getattr(cfg, "target", None) if "target" in getattr(cfg, "sections", {}) else None
    return An1017Options(variant=getattr(target, "variant", "seed") if target is not None else "seed")


# ---------------------------------------------------------------------------- one batch
def run_step_batch(
    cfg: Any,
    gains: Sequence[Gains],
    from_rpm: float,
    to_rpm: float,
    duration_s: float,
    step_at_s: float,
    seed: int | None = None,
    *,
    press_at_s: float = 0.0,
    record_every: int = 4,
    options: An1017Options | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[StepResult]:
    """Run one step test per gain set, all together; results in the order of ``gains``.

    ``seed`` seeds the pot ADC noise (default: the config's [plant] seed, as the scalar
    session's plant); every instance sees the same noise, so gain sets are compared on equal
    inputs. ``progress(done_periods, total_periods)`` is called every 1000 periods.
    """
    step_scenario(from_rpm, to_rpm, step_at_s, duration_s, press_at_s)  # validates the times
    if not gains:
        raise ConfigError("sweep: no gain sets to run")
    if record_every < 1:
        raise ConfigError(f"sweep: record_every must be >= 1, got {record_every}")
    n = len(gains)
    q15 = [gains_q15(g) for g in gains]
    for g, q in zip(gains, q15):
        broken = check_gain_constraints(*q)
        if broken is not None or not all(0 <= x <= 32767 for x in q):
            why = GAIN_CONSTRAINT_NAMES.get(broken, "range 0..0.99997") if broken else "range 0..0.99997"
            raise ConfigError(f"sweep: gains kp={g[0]:g} ki={g[1]:g} kd={g[2]:g} break {why}")
    if seed is None:
        seed = int(cfg.plant.seed) if "plant" in cfg.sections else 0
    n_periods = max(1, round(duration_s / PERIOD_S))
    k_step = _event_period(step_at_s, PERIOD_S)
    k_press = _event_period(press_at_s, PERIOD_S)
    k_release = _release_period(k_press, PERIOD_S)
    code_from = AN1017_PROFILE.pot_code_for_rpm(from_rpm)
    code_to = AN1017_PROFILE.pot_code_for_rpm(to_rpm)
    codes = np.full(n_periods, code_from, dtype=np.int64)
    codes[k_step:] = code_to
    pot = _pot_codes(cfg, codes, seed).tolist()

    fw = An1017Batch(n, _options(cfg, options), np.array(q15, dtype=np.int64))
    plant = _batch_plant(cfg, n)
    n_rec = n_periods // record_every
    speed = np.empty((n_rec, n))
    peak_sq = np.zeros(n)
    cur_sq = np.empty(n)
    tmp = np.empty(n)
    edge = np.empty(n, dtype=np.int64)
    edge_f = np.empty(n)
    no_edge = np.empty(n, dtype=bool)
    fw_step = fw.step
    plant_step = plant.step
    duties = fw.duty_fractions
    rpm_per_rad_s = 60.0 / (2.0 * math.pi)
    row = 0
    for k in range(n_periods):
        # sample the plant at t_k (hall bits and the last edge of the previous period)
        e = plant.last_edge_s
        np.isnan(e, out=no_edge)
        if no_edge.all():
            edge.fill(EDGE_NONE)
        else:
            np.multiply(e, 1e7, out=edge_f)
            edge_f[no_edge] = 0.0
            np.minimum(edge_f.astype(np.int64), EDGE_LIMIT, out=edge)
            edge[no_edge] = EDGE_NONE
        fw_step(plant.hall_bits, edge, pot[k], k_press <= k < k_release)
        d = duties()
        plant_step(d[0], d[1], d[2], 1, PERIOD_S)
        if k >= k_step:
            np.multiply(plant.i_d, plant.i_d, out=cur_sq)
            np.multiply(plant.i_q, plant.i_q, out=tmp)
            cur_sq += tmp
            np.maximum(peak_sq, cur_sq, out=peak_sq)
        if (k + 1) % record_every == 0 and row < n_rec:
            np.multiply(plant.w_m, rpm_per_rad_s, out=speed[row])
            row += 1
        if progress is not None and (k + 1) % 1000 == 0:
            progress(k + 1, n_periods)
    if progress is not None and n_periods % 1000:
        progress(n_periods, n_periods)

    t = (np.arange(1, n_rec + 1) * record_every) * PERIOD_S
    t_step = k_step * PERIOD_S
    rpm_q15 = AN1017_PROFILE.rpm_per_speed_q15 or 0.0
    ref_from = ((code_from - 512) << 6) * rpm_q15
    ref_to = ((code_to - 512) << 6) * rpm_q15
    if ref_to == ref_from:
        raise ConfigError(f"sweep: from {from_rpm:g} and to {to_rpm:g} rpm give the same pot code {code_to}")
    peak = np.sqrt(peak_sq)
    results = []
    for i in range(n):
        m = step_metrics(t, speed[:, i], y0=ref_from, y_final_ref=ref_to, t_step_s=t_step)
        m = dataclasses.replace(m, peak_current_a=float(peak[i]))
        state = int(fw.state[i])
        results.append(
            StepResult(
                gains=tuple(float(x) for x in gains[i]),  # type: ignore[arg-type]
                gains_q15=q15[i],
                t_s=t,
                speed_rpm=speed[:, i].copy(),
                metrics=m,
                ref_from_rpm=ref_from,
                ref_to_rpm=ref_to,
                final_state=state,
                stalled=state == STATE_STALLED,
            )
        )
    return results


# ---------------------------------------------------------------------------- grids
def grid_values(start: float, stop: float, count: int) -> tuple[float, ...]:
    """``count`` evenly spaced values from start to stop inclusive (count 1: start)."""
    if count < 1:
        raise ConfigError(f"sweep grid: count must be >= 1, got {count}")
    if count == 1:
        return (float(start),)
    return tuple(float(x) for x in np.linspace(start, stop, count))


def parse_grid_spec(text: str, name: str = "grid") -> tuple[float, ...]:
    """``A:B:N`` (N values from A to B) or a single value ``A``, e.g. ``--kp 0.05:0.5:10``."""
    parts = text.split(":")
    try:
        if len(parts) == 1:
            return (float(parts[0]),)
        if len(parts) == 3:
            return grid_values(float(parts[0]), float(parts[1]), int(parts[2]))
    except ValueError:
        pass
    raise ConfigError(f"sweep --{name} {text!r}: expected A:B:N (e.g. 0.05:0.5:10) or a single number")


def _metric_key(metric: str) -> str:
    key = METRIC_ALIASES.get(metric, metric)
    if key not in {k for k, _, _ in METRIC_COLUMNS}:
        known = ", ".join(sorted(METRIC_ALIASES))
        raise ConfigError(f"sweep --metric {metric!r}: unknown (choose from {known})")
    return key


def _order(point: SweepPoint, key: str) -> tuple[int, float]:
    r = point.result
    assert r is not None
    v = getattr(r.metrics, key)
    if r.stalled or v is None or (isinstance(v, float) and math.isnan(v)):
        return (1, 0.0)
    return (0, abs(v) if key in ("ss_error", "ss_error_pct") else float(v))


def sweep_grid(
    cfg: Any,
    kp_values: Iterable[float],
    ki_values: Iterable[float],
    kd_values: Iterable[float] = (0.0,),
    metric: str = "itae",
    *,
    from_rpm: float = 1000.0,
    to_rpm: float = 2000.0,
    duration_s: float = 1.0,
    step_at_s: float = 0.5,
    seed: int | None = None,
    batch_size: int = 128,
    record_every: int = 4,
    options: An1017Options | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> SweepResult:
    """Step-test every (kp, ki, kd) of the grid; constraint breakers are skipped and counted.

    ``progress(done, total)`` counts simulated gain sets (total = the grid minus the skipped),
    advancing smoothly while a batch runs.
    """
    key = _metric_key(metric)
    grid = [tuple(float(x) for x in g) for g in itertools.product(kp_values, ki_values, kd_values)]
    if not grid:
        raise ConfigError("sweep: the grid is empty")
    points: list[SweepPoint] = []
    to_run: list[int] = []
    for index, g in enumerate(grid):
        q = gains_q15(g)  # type: ignore[arg-type]
        if not all(0 <= x <= 32767 for x in q):
            raise ConfigError(f"sweep: gain values must be within 0..1 (got kp={g[0]:g} ki={g[1]:g} kd={g[2]:g})")
        broken = check_gain_constraints(*q)
        points.append(SweepPoint(g, broken))  # type: ignore[arg-type]
        if broken is None:
            to_run.append(index)
    total = len(to_run)
    done = 0
    if progress is not None:
        progress(0, total)
    for start in range(0, total, max(1, batch_size)):
        chunk = to_run[start : start + batch_size]

        def chunk_progress(k: int, n_periods: int, _base: int = done, _size: int = len(chunk)) -> None:
            if progress is not None:
                progress(_base + (_size * k) // n_periods, total)

        results = run_step_batch(
            cfg,
            [grid[i] for i in chunk],  # type: ignore[misc]
            from_rpm,
            to_rpm,
            duration_s,
            step_at_s,
            seed,
            record_every=record_every,
            options=options,
            progress=chunk_progress if progress is not None else None,
        )
        for i, r in zip(chunk, results):
            points[i] = dataclasses.replace(points[i], result=r)
        done += len(chunk)
    simulated = [p for p in points if p.result is not None]
    ordered = sorted(simulated, key=lambda p: _order(p, key))
    ranks = {id(p): n for n, p in enumerate(ordered, start=1)}
    points = [dataclasses.replace(p, rank=ranks.get(id(p))) for p in points]
    ranked = tuple(sorted((p for p in points if p.rank is not None), key=lambda p: p.rank or 0))
    return SweepResult(
        metric=key,
        points=tuple(points),
        ranked=ranked,
        skipped=len(grid) - total,
        from_rpm=from_rpm,
        to_rpm=to_rpm,
        duration_s=duration_s,
        step_at_s=step_at_s,
        sim_s=total * max(1, round(duration_s / PERIOD_S)) * PERIOD_S,
    )


# ---------------------------------------------------------------------------- output
CSV_FIELDS = (
    ("kp", "ki", "kd", "kp_q15", "ki_q15", "kd_q15", "status", "constraint", "rank", "stalled", "settled")
    + tuple(k for k, _, _ in METRIC_COLUMNS)
)


def write_sweep_csv(path: str | Path, sweep: SweepResult) -> Path:
    """Every grid point, one row each, in grid order (skipped points with their constraint)."""
    out = Path(path)
    with out.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(CSV_FIELDS)
        for p in sweep.points:
            q = gains_q15(p.gains)
            r = p.result
            row: list[Any] = [*p.gains, *q]
            if r is None:
                row += ["skipped", p.constraint, "", "", ""] + [""] * len(METRIC_COLUMNS)
            else:
                m = r.metrics
                row += ["ok", "", p.rank, int(r.stalled), int(m.settled)]
                row += ["" if (v := getattr(m, k)) is None else repr(float(v)) for k, _, _ in METRIC_COLUMNS]
            writer.writerow(row)
    return out


def best_fragment(sweep: SweepResult) -> str:
    """The best gain set as a config fragment a later run can load (``[target]`` table)."""
    best = sweep.best
    if best is None or best.result is None:
        raise ConfigError("sweep: no simulated gain set to save (all were skipped)")
    kp, ki, kd = best.gains
    value = getattr(best.result.metrics, sweep.metric)
    return (
        f"# best of a {len(sweep.points)}-point sweep by {sweep.metric} = {value!r}, "
        f"step {sweep.from_rpm:g} -> {sweep.to_rpm:g} rpm\n"
        f"[target]\nkp = {kp!r}\nki = {ki!r}\nkd = {kd!r}\n"
    )
