"""Offline step tests over many parameter sets: a grid, run on a local executor, ranked.

Every point is the same step test `hilbench step` runs (`steptest.StepTest`), through the same
session, on the configured target's in-process model — there is no second simulation loop. Points
that break the firmware's own constraints (its profile's `check_params`) are skipped and counted.
Points run in chunks on a process pool (one worker per core by default, ``workers=1`` in this
process); each point is seeded from the config alone, so the results do not depend on which
worker ran it, and they come back in grid order.
"""

from __future__ import annotations

import csv
import dataclasses
import itertools
import math
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from hilbench.bench.metrics import METRIC_COLUMNS
from hilbench.bench.steptest import StepResult, StepTest, require_speed_loop
from hilbench.config import BenchConfig
from hilbench.errors import ConfigError, ParamError
from hilbench.targets.profile import TargetProfile

__all__ = [
    "SweepPoint",
    "SweepResult",
    "best_fragment",
    "grid_values",
    "parse_axis",
    "parse_grid_spec",
    "sweep_grid",
    "write_sweep_csv",
]

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
CHUNK_POINTS = 8  # points per task: enough to amortise a worker's start-up and the pickling

Params = tuple[tuple[str, float], ...]


@dataclass(frozen=True)
class SweepPoint:
    """One grid point: simulated (result set) or skipped for a broken firmware constraint."""

    params: Params
    constraint: str | None = None  # the broken constraint, None when simulated
    result: StepResult | None = None
    rank: int | None = None

    @property
    def skipped(self) -> bool:
        return self.constraint is not None

    @property
    def label(self) -> str:
        return "/".join(f"{v:.4g}" for _, v in self.params)


@dataclass(frozen=True)
class SweepResult:
    """A whole grid: every point in grid order, the ranking, and the skipped count."""

    metric: str  # a StepMetrics key
    axes: tuple[str, ...]
    points: tuple[SweepPoint, ...]
    ranked: tuple[SweepPoint, ...]  # simulated points, best first
    skipped: int
    test: StepTest
    sim_s: float = 0.0  # simulated plant-seconds
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def best(self) -> SweepPoint | None:
        return self.ranked[0] if self.ranked else None


# ---------------------------------------------------------------------------- grids
def grid_values(start: float, stop: float, count: int) -> tuple[float, ...]:
    """``count`` evenly spaced values from start to stop inclusive (count 1: start)."""
    if count < 1:
        raise ConfigError(f"sweep grid: count must be >= 1, got {count}")
    if count == 1:
        return (float(start),)
    return tuple(float(x) for x in np.linspace(start, stop, count))


def parse_grid_spec(text: str, name: str = "grid") -> tuple[float, ...]:
    """``A:B:N`` (N values from A to B) or a single value ``A``, e.g. ``0.05:0.5:10``."""
    parts = text.split(":")
    try:
        if len(parts) == 1:
            values: tuple[float, ...] = (float(parts[0]),)
        elif len(parts) == 3 and math.isfinite(float(parts[0]) + float(parts[1])) and 1 <= int(parts[2]) <= 10_000:
            values = grid_values(float(parts[0]), float(parts[1]), int(parts[2]))
        else:
            values = ()
        if values and all(math.isfinite(v) for v in values) and len(values) <= 10_000:
            return values
    except (ValueError, OverflowError):
        pass
    raise ConfigError(f"sweep {name} {text!r}: expected A:B:N (e.g. 0.05:0.5:10, N <= 10000) or a single number")


def parse_axis(text: str) -> tuple[str, tuple[float, ...]]:
    """``NAME=A:B:N`` (a `--param` word) → (NAME, values)."""
    name, sep, grid = text.partition("=")
    if not sep or not name.strip() or not name.strip().replace("_", "a").isalnum():
        raise ConfigError(f"sweep --param {text!r}: expected NAME=A:B:N, e.g. kp=0.05:0.5:10")
    return name.strip(), parse_grid_spec(grid, f"--param {name.strip()}")


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


def _constraint_checker(profile: TargetProfile, period_us: int) -> Callable[[Params], str | None]:
    """Judge a point as the session would: each value encoded and range-checked as `ctl set` does
    (a bad value is a ConfigError), then the firmware's constraints on the tunable set, with the
    parameters the point does not set at the firmware's defaults."""
    from hilbench.bench.livetuning import GuardSettings, LiveTuning
    from hilbench.protocol import PROTOCOL_VERSION, HostHello

    target = profile.make(profile.default_options())
    hello = target.hello(HostHello(0, PROTOCOL_VERSION, period_us, 0, 0))
    tuning = LiveTuning(target, profile, f"sweep ({profile.name})", GuardSettings(enabled=False))
    tuning.declare(hello.n_params)
    defaults = {name: info.value for name, info in tuning.info.items()}

    def check(params: Params) -> str | None:
        raw = dict(defaults)
        for name, value in params:
            try:
                raw[name] = tuning.encode(name, value)[1]
            except ParamError as exc:
                raise ConfigError(f"sweep --param {name}: {exc}") from None
        return profile.check_params(raw) if profile.check_params is not None else None

    return check


def _run_chunk(cfg: BenchConfig, test: StepTest, sets: list[dict[str, float]]) -> list[StepResult]:
    """One task: step tests of a few parameter sets (a worker process runs this)."""
    from hilbench.bench.run import run_step_tests

    return run_step_tests(cfg, test, sets)


def sweep_grid(
    cfg: BenchConfig,
    axes: Sequence[tuple[str, Sequence[float]]],
    test: StepTest,
    metric: str = "itae",
    *,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> SweepResult:
    """Step-test every point of the grid over ``axes``; constraint breakers are skipped and counted.

    ``workers``: processes (None: one per core; 1: in this process). ``progress(done, total)``
    counts simulated points.
    """
    from hilbench.bench.run import in_process, settings_profile

    key = _metric_key(metric)
    cfg = in_process(cfg)
    profile = settings_profile(cfg)
    require_speed_loop(profile, "sweep")
    names = tuple(name for name, _ in axes)
    grid: list[Params] = [tuple(zip(names, values)) for values in itertools.product(*(v for _, v in axes))]
    if not grid or not names:
        raise ConfigError("sweep: the grid is empty (give --param NAME=A:B:N)")
    check = _constraint_checker(profile, cfg.link.period_us)
    points = [SweepPoint(p, check(p)) for p in grid]
    to_run = [i for i, p in enumerate(points) if not p.skipped]
    chunks = [to_run[i:i + CHUNK_POINTS] for i in range(0, len(to_run), CHUNK_POINTS)]
    n_workers = max(1, min(workers or os.cpu_count() or 1, len(chunks) or 1))
    if progress is not None:
        progress(0, len(to_run))
    done = 0

    def take(chunk: list[int], results: list[StepResult]) -> None:
        nonlocal done
        for i, r in zip(chunk, results):
            points[i] = dataclasses.replace(points[i], result=r)
        done += len(chunk)
        if progress is not None:
            progress(done, len(to_run))

    if n_workers == 1:
        for chunk in chunks:
            take(chunk, _run_chunk(cfg, test, [dict(grid[i]) for i in chunk]))
    else:
        with ProcessPoolExecutor(max_workers=n_workers) as pool:
            futures = [pool.submit(_run_chunk, cfg, test, [dict(grid[i]) for i in chunk]) for chunk in chunks]
            for chunk, future in zip(chunks, futures):  # grid order, whatever finishes first
                take(chunk, future.result())
    simulated = [p for p in points if p.result is not None]
    ordered = sorted(simulated, key=lambda p: _order(p, key))
    ranks = {id(p): n for n, p in enumerate(ordered, start=1)}
    final = tuple(dataclasses.replace(p, rank=ranks.get(id(p))) for p in points)
    ranked = tuple(sorted((p for p in final if p.rank is not None), key=lambda p: p.rank or 0))
    return SweepResult(metric=key, axes=names, points=final, ranked=ranked, skipped=len(grid) - len(to_run),
                       test=test, sim_s=len(to_run) * test.duration_s, extras={"workers": n_workers})


# ---------------------------------------------------------------------------- output
def write_sweep_csv(path: str | Path, sweep: SweepResult) -> Path:
    """Every grid point, one row each, in grid order (skipped points with their constraint)."""
    out = Path(path)
    with out.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow((*sweep.axes, "status", "constraint", "rank", "stalled", "settled",
                         *(k for k, _, _ in METRIC_COLUMNS)))
        for p in sweep.points:
            r = p.result
            row: list[Any] = [v for _, v in p.params]
            if r is None:
                row += ["skipped", p.constraint, "", "", ""] + [""] * len(METRIC_COLUMNS)
            else:
                m = r.metrics
                row += ["ok", "", p.rank, int(r.stalled), int(m.settled)]
                row += ["" if (v := getattr(m, k)) is None else repr(float(v)) for k, _, _ in METRIC_COLUMNS]
            writer.writerow(row)
    return out


def best_fragment(sweep: SweepResult) -> str:
    """The best parameter set as a config fragment a later run can load (``[target]`` table)."""
    best = sweep.best
    if best is None or best.result is None:
        raise ConfigError("sweep: no simulated parameter set to save (all were skipped)")
    value = getattr(best.result.metrics, sweep.metric)
    lines = [f"# best of a {len(sweep.points)}-point sweep by {sweep.metric} = {value!r}, "
             f"step {sweep.test.from_rpm:g} -> {sweep.test.to_rpm:g} rpm", "[target]"]
    lines += [f"{name} = {v!r}" for name, v in best.params]
    return "\n".join(lines) + "\n"
