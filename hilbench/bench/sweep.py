"""Offline step tests over many parameter sets, on an executor, ranked; resumable; robust to tolerances.

Every point is the same step test `hilbench step` runs (`steptest.StepTest`), through the same
session, on the configured target's in-process model — there is no second simulation loop. Points
that break the firmware's own constraints (its profile's `check_params`) are skipped and counted.
Tasks are chunks of points on an executor (`executors.open_executor`: this process, a local pool,
a Dask cluster); each point is seeded from the config alone, so results do not depend on which
worker ran it, and they come back in point order. With a store (a JSON-lines file) every finished
point is appended as it arrives, and a restarted sweep runs only the points the store lacks. With
motor tolerances each point runs once per tolerance case and reports its worst case.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import itertools
import json
import math
import os
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

from hilbench.bench.executors import Executor, open_executor, tasks_in_flight
from hilbench.bench.metrics import METRIC_COLUMNS, StepMetrics
from hilbench.bench.outputs import open_output
from hilbench.bench.sampling import Axis, Point, zoom
from hilbench.bench.steptest import StepResult, StepTest, require_speed_loop
from hilbench.config import BenchConfig, clipped
from hilbench.errors import ConfigError, ParamError, RecordingError
from hilbench.targets.profile import TargetProfile

__all__ = [
    "SweepPoint",
    "SweepResult",
    "Tolerances",
    "best_fragment",
    "held_params",
    "grid_values",
    "parse_axis",
    "parse_grid_spec",
    "refine",
    "sweep_grid",
    "sweep_points",
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
CHUNK_TESTS = 8  # step tests per task: enough to amortise a worker's start-up and the pickling

Params = Point


@dataclass(frozen=True)
class Tolerances:
    """Motor parameter tolerances, ± fractions: each point runs at every corner of the box."""

    rs: float = 0.0
    l: float = 0.0  # noqa: E741 - the inductance
    psi: float = 0.0
    j: float = 0.0

    def cases(self) -> list[dict[str, float]]:
        """Multipliers of (rs, l, psi, j) at each corner; one nominal case when there are none."""
        spans = [(name, value) for name, value in dataclasses.asdict(self).items() if value]
        if not spans:
            return [{}]
        if any(not 0 < v < 1 for _, v in spans):
            raise ConfigError("sweep tolerances: each must be a fraction between 0 and 1 (e.g. 0.1 for ±10 %)")
        return [{name: 1.0 + sign * v for (name, v), sign in zip(spans, signs)}
                for signs in itertools.product((-1.0, 1.0), repeat=len(spans))]


def _with_tolerance(cfg: BenchConfig, case: dict[str, float]) -> BenchConfig:
    if not case:
        return cfg
    motor = cfg.motor
    scaled: dict[str, Any] = {"rs_ohm": motor.rs_ohm * case.get("rs", 1.0), "j_kgm2": motor.j_kgm2 * case.get("j", 1.0)}
    for name in ("l_h", "ld_h", "lq_h"):
        if getattr(motor, name) is not None:
            scaled[name] = getattr(motor, name) * case.get("l", 1.0)
    for name in ("psi_wb", "ke_v_per_krpm"):
        if getattr(motor, name) is not None:
            scaled[name] = getattr(motor, name) * case.get("psi", 1.0)
    return cfg.replace(motor=dataclasses.replace(motor, **scaled))


@dataclass(frozen=True)
class SweepPoint:
    """One point: simulated (result set; the worst tolerance case) or skipped for a broken constraint."""

    params: Params
    constraint: str | None = None  # the broken constraint, None when simulated
    result: StepResult | None = None  # its figures; curves only on the sweep's best point (bounded memory)
    rank: int | None = None
    cases: int = 1  # tolerance cases run

    @property
    def skipped(self) -> bool:
        return self.constraint is not None

    @property
    def label(self) -> str:
        return "/".join(f"{v:.4g}" for _, v in self.params)


@dataclass(frozen=True)
class SweepResult:
    """A whole sweep: every point in order, the ranking, and the skipped count."""

    metric: str  # a StepMetrics key
    axes: tuple[str, ...]
    points: tuple[SweepPoint, ...]
    ranked: tuple[SweepPoint, ...]  # simulated points, best first
    skipped: int
    test: StepTest
    sim_s: float = 0.0  # simulated plant-seconds in this call (resumed points not counted)
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def best(self) -> SweepPoint | None:
        return self.ranked[0] if self.ranked else None

    @property
    def step_tests(self) -> int:
        return sum(p.cases for p in self.points if not p.skipped)


# ---------------------------------------------------------------------------- parsing
def grid_values(start: float, stop: float, count: int) -> tuple[float, ...]:
    """``count`` evenly spaced values from start to stop inclusive (count 1: start)."""
    if count < 1:
        raise ConfigError(f"sweep grid: count must be >= 1, got {count}")
    return Axis("", start, stop, count).values()


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
        if values and all(math.isfinite(v) for v in values):
            return values
    except (ValueError, OverflowError):
        pass
    raise ConfigError(f"sweep {name} {clipped(repr(text), 60)}: expected A:B:N (e.g. 0.05:0.5:10, N <= 10000) or a single number")


def parse_axis(text: str) -> tuple[str, tuple[float, ...]]:
    """``NAME=A:B:N`` (a `--param` word) → (NAME, values)."""
    name, sep, spec_text = text.partition("=")
    if not sep or not name.strip() or not name.strip().replace("_", "a").isalnum():
        raise ConfigError(f"sweep --param {text!r}: expected NAME=A:B:N, e.g. kp=0.05:0.5:10")
    return name.strip(), parse_grid_spec(spec_text, f"--param {name.strip()}")


def _metric_key(metric: str) -> str:
    key = METRIC_ALIASES.get(metric, metric)
    if key not in {k for k, _, _ in METRIC_COLUMNS}:
        known = ", ".join(sorted(METRIC_ALIASES))
        raise ConfigError(f"sweep --metric {metric!r}: unknown (choose from {known})")
    return key


def _order(result: StepResult, key: str) -> tuple[int, float]:
    """Smaller is better; stalled or unmeasured responses last."""
    v = getattr(result.metrics, key)
    if result.stalled or v is None or (isinstance(v, float) and math.isnan(v)):
        return (1, 0.0)
    return (0, abs(v) if key in ("ss_error", "ss_error_pct") else float(v))


# ---------------------------------------------------------------------------- checks and tasks
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


def _run_task(cfgs: list[BenchConfig], test: StepTest, jobs: list[tuple[int, int, dict[str, float]]]) -> list[tuple[int, StepResult]]:
    """One task: step tests of a few (point index, tolerance case, parameters) (a worker runs this)."""
    from hilbench.bench.run import run_step_tests

    return [(index, run_step_tests(cfgs[case], test, [params])[0]) for index, case, params in jobs]


class SweepStore:
    """Finished points as JSON lines, appended as they arrive; the key names the sweep they belong to.

    Reading one back is reading input: at most STORE_MAX_BYTES, lines of at most
    STORE_LINE_MAX_BYTES, each a row of this sweep's shape (`_store_row`), or one line naming the
    file, the line and what is wrong. Only the last line may be cut (a kill while appending)."""

    def __init__(self, path: Path, key: str, n_points: int, family: str | None = None) -> None:
        """``family``: the rounds of one `refine` share a file; rows of its other rounds are skipped."""
        from hilbench.limits import STORE_LINE_MAX_BYTES, STORE_MAX_BYTES, check_path_size

        self.path = path
        self.key = key
        self.family = family
        self.done: dict[int, tuple[StepMetrics, bool, int]] = {}
        #: where a last line cut by a kill starts (removed before the first append), and whether the
        #: last line, whole, lacks its newline: appended rows must start a line of their own
        self._cut_at: int | None = None
        self._newline_first = False
        if not path.exists():
            return
        check_path_size(path, STORE_MAX_BYTES, RecordingError, f"sweep store {path}")
        try:
            with path.open("rb") as handle:
                n = 0
                while line := handle.readline(STORE_LINE_MAX_BYTES + 1):
                    n += 1
                    if len(line) > STORE_LINE_MAX_BYTES:
                        raise RecordingError(f"sweep store {path}:{n}: a line longer than {STORE_LINE_MAX_BYTES} bytes")
                    last = not line.endswith(b"\n") and not handle.peek(1)
                    row = _store_line(path, n, line, last)
                    if row is None:
                        self._cut_at = handle.tell() - len(line)
                        break  # a line cut by a kill: the point runs again
                    self._newline_first = last
                    if row.get("key") != key and family is not None and row.get("family") == family:
                        continue  # another round of the same refined sweep
                    if row.get("key") != key:
                        raise ConfigError(f"sweep store {path}: it holds another sweep (other config, test or points); "
                                          "give a new file to start over")
                    index, metrics, stalled, cases = _store_row(path, n, row, n_points)
                    self.done[index] = (metrics, stalled, cases)
        except OSError as exc:
            raise RecordingError(f"sweep store {path}: unreadable ({exc.strerror or exc})") from None

    def append(self, index: int, result: StepResult, cases: int) -> None:
        row = {"key": self.key, "index": index, "params": result.gains, "metrics": result.metrics.as_dict(),
               "stalled": result.stalled, "cases": cases, **({"family": self.family} if self.family else {})}
        text = ("\n" if self._newline_first else "") + json.dumps(row) + "\n"
        try:
            if self._cut_at is not None:
                os.truncate(self.path, self._cut_at)
            with self.path.open("a", encoding="utf-8") as handle:
                handle.write(text)
            self._cut_at, self._newline_first = None, False
        except OSError as exc:
            raise RecordingError(f"sweep store {self.path}: cannot write ({exc.strerror})") from None


def _store_line(path: Path, n: int, line: bytes, last: bool) -> dict[str, Any] | None:
    """Line ``n`` as a JSON object; None for a last line cut short."""
    try:
        row = json.loads(line.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        if last:
            return None
        raise RecordingError(f"sweep store {path}:{n}: not a JSON line") from None
    except RecursionError:
        raise RecordingError(f"sweep store {path}:{n}: nested too deep to be a sweep point") from None
    if not isinstance(row, dict):
        raise RecordingError(f"sweep store {path}:{n}: a JSON {type(row).__name__}, not a sweep point (an object)")
    return row


_METRIC_FIELDS = {f.name: f for f in dataclasses.fields(StepMetrics)}


def _store_row(path: Path, n: int, row: dict[str, Any], n_points: int) -> tuple[int, StepMetrics, bool, int]:
    """A stored point's (index, metrics, stalled, cases), each checked (RecordingError naming line n)."""
    where = f"sweep store {path}:{n}"
    index, stalled, cases, metrics = row.get("index"), row.get("stalled"), row.get("cases"), row.get("metrics")
    if not isinstance(index, int) or isinstance(index, bool) or not 0 <= index < n_points:
        raise RecordingError(f"{where}: index {str(index)[:20]} is not a point of this sweep (0..{n_points - 1})")
    if not isinstance(stalled, bool):
        raise RecordingError(f"{where}: stalled must be true or false")
    if not isinstance(cases, int) or isinstance(cases, bool) or not 1 <= cases <= 1_000_000:
        raise RecordingError(f"{where}: cases must be a whole number >= 1")
    if not isinstance(metrics, dict) or set(metrics) != set(_METRIC_FIELDS):
        raise RecordingError(f"{where}: metrics must hold exactly {', '.join(_METRIC_FIELDS)}")
    for name, value in metrics.items():
        optional = "None" in str(_METRIC_FIELDS[name].type)
        if not (_a_float(value) or (optional and value is None)):
            raise RecordingError(f"{where}: metrics {name} is {str(value)[:20]}, not a number")
    if not isinstance(metrics["n_samples"], int):
        raise RecordingError(f"{where}: metrics n_samples must be a whole number")
    return index, StepMetrics(**metrics), stalled, cases


def _a_float(value: Any) -> bool:
    """An int or a float that a float holds: not an int of 400 digits, which overflows every figure
    made from it (inf and NaN are taken, as before: a metric may be inf)."""
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return False
    try:
        float(value)
    except OverflowError:
        return False
    return True


def _sweep_key(cfg: BenchConfig, test: StepTest, points: Sequence[Params], tolerances: Tolerances, metric: str) -> str:
    from hilbench.bench.settings import config_metadata

    text = json.dumps([config_metadata(cfg), dataclasses.asdict(test), points, dataclasses.asdict(tolerances)],
                      sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


# ---------------------------------------------------------------------------- the sweep
def sweep_points(
    cfg: BenchConfig,
    points: Sequence[Params],
    test: StepTest,
    metric: str = "itae",
    *,
    executor: str | None = None,
    workers: int | None = None,
    tolerances: Tolerances = Tolerances(),
    store: str | Path | None = None,
    progress: Callable[[int, int], None] | None = None,
    store_family: str | None = None,
) -> SweepResult:
    """Step-test every point; constraint breakers are skipped and counted. ``executor``: None/local
    (``workers`` processes, one per core by default; 1: this process), local-dask[:N] or a Dask
    scheduler's tcp:// address. ``progress(done, total)`` counts points."""
    from hilbench.bench.run import in_process, settings_profile

    key = _metric_key(metric)
    cfg = in_process(cfg)
    profile = settings_profile(cfg)
    require_speed_loop(profile, "sweep")
    if not points or not points[0]:
        raise ConfigError("sweep: no points (give --param NAME=A:B:N)")
    check = _constraint_checker(profile, cfg.link.period_us)
    swept = [SweepPoint(tuple(p), check(tuple(p))) for p in points]
    cases = tolerances.cases()
    saved = (SweepStore(Path(store), _sweep_key(cfg, test, points, tolerances, key), len(swept), store_family)
             if store is not None else None)
    run = _SweepRun(swept, len(cases), key, saved, progress)
    jobs = [(i, c, dict(swept[i].params)) for i in run.to_run() for c in range(len(cases))]
    cfgs = [_with_tolerance(cfg, case) for case in cases]
    with open_executor(executor, workers) as (pool, where):
        run.collect(pool, ((cfgs, test, jobs[i:i + CHUNK_TESTS]) for i in range(0, len(jobs), CHUNK_TESTS)),
                    tasks_in_flight(pool))
    final, ranked = _rank(run.final_points(), key)
    return SweepResult(metric=key, axes=tuple(name for name, _ in points[0]), points=final, ranked=ranked,
                       skipped=len(swept) - run.total, test=test, sim_s=len(jobs) * test.duration_s,
                       extras={"executor": where})


class _SweepRun:
    """The points of one sweep as their step tests come back: resumed from a store, appended to it,
    counted for ``progress``; a point's result is its worst tolerance case.

    Memory stays bounded whatever the number of points: a finished point keeps its figures, and
    only the best point so far keeps its response curves (240 kB for a 1 s step test); the curves of a
    point whose tolerance cases are still coming are dropped once it is finished."""

    def __init__(self, swept: list[SweepPoint], n_cases: int, key: str, saved: "SweepStore | None",
                 progress: Callable[[int, int], None] | None) -> None:
        self.swept, self.n_cases, self.key, self.saved, self.progress = swept, n_cases, key, saved, progress
        self.pending: dict[int, list[StepResult]] = {}  # points whose tolerance cases are still coming
        self.finished: dict[int, tuple[StepResult, int]] = {}  # point -> (worst case, cases run)
        self._best: int | None = None  # the finished point whose curves are kept
        if saved is not None:
            for index, (metrics, stalled, cases) in saved.done.items():
                self.finished[index] = (StepResult("resumed", dict(swept[index].params), metrics, np.empty(0),
                                                   np.empty(0), metrics.y_final_ref, stalled), cases)
        self.total = sum(1 for p in swept if not p.skipped)
        self.done = len(self.finished)
        if progress is not None:
            progress(self.done, self.total)

    def to_run(self) -> list[int]:
        return [i for i, p in enumerate(self.swept) if not p.skipped and i not in self.finished]

    def collect(self, pool: Executor, tasks: Iterable[tuple[list[BenchConfig], StepTest, list[tuple[int, int, dict[str, float]]]]],
                window: int) -> None:
        """Every task's results, in point order whatever finishes first. At most ``window`` tasks
        are submitted at once and each future is dropped once read: a finished future keeps its
        results (every step test's curves), so holding them all held the whole sweep's."""
        in_flight: deque[Any] = deque()
        for args in tasks:
            in_flight.append(pool.submit(_run_task, *args))
            if len(in_flight) >= window:
                self._take(in_flight.popleft())
        while in_flight:
            self._take(in_flight.popleft())

    def _take(self, future: Any) -> None:
        for index, result in future.result():
            self._add(index, result)

    def _add(self, index: int, result: StepResult) -> None:
        runs = self.pending.setdefault(index, [])
        runs.append(result)
        if len(runs) < self.n_cases:
            return
        del self.pending[index]
        worst = max(runs, key=lambda r: _order(r, self.key))
        self._finish(index, worst, len(runs))
        self.done += 1  # the point's last tolerance case
        if self.saved is not None:
            self.saved.append(index, worst, self.n_cases)
        if self.progress is not None:
            self.progress(self.done, self.total)

    def _finish(self, index: int, worst: StepResult, cases: int) -> None:
        """Keep the point's figures; its curves only if it is the best so far (ties: the first
        point, as the ranking orders them)."""
        best = self._best
        if best is None or (_order(worst, self.key), index) < (_order(self.finished[best][0], self.key), best):
            if best is not None:
                old, old_cases = self.finished[best]
                self.finished[best] = (_figures_only(old), old_cases)
            self._best = index
        else:
            worst = _figures_only(worst)
        self.finished[index] = (worst, cases)

    def final_points(self) -> list[SweepPoint]:
        out = []
        for index, point in enumerate(self.swept):
            if index in self.finished:
                worst, cases = self.finished[index]
                point = dataclasses.replace(point, result=worst, cases=cases)
            out.append(point)
        return out


def _figures_only(result: StepResult) -> StepResult:
    """A step result without its response curves (a sweep keeps those of its best point only)."""
    return dataclasses.replace(result, t_s=np.empty(0), speed_rpm=np.empty(0), firmware_ref_rpm=None)


def _rank(points: Sequence[SweepPoint], key: str) -> tuple[tuple[SweepPoint, ...], tuple[SweepPoint, ...]]:
    """Every point with its rank by ``key`` (simulated ones; best 1), and the ranked ones in order."""
    ordered = sorted((p for p in points if p.result is not None), key=lambda p: _order(p.result, key))  # type: ignore[arg-type]
    ranks = {id(p): n for n, p in enumerate(ordered, start=1)}
    final = tuple(dataclasses.replace(p, rank=ranks.get(id(p))) for p in points)
    return final, tuple(sorted((p for p in final if p.rank is not None), key=lambda p: p.rank or 0))


def sweep_grid(cfg: BenchConfig, axes: Sequence[tuple[str, Sequence[float]]], test: StepTest, metric: str = "itae",
               **options: Any) -> SweepResult:
    """Every combination of the axes' values (the first axis slowest); see `sweep_points`."""
    names = [name for name, _ in axes]
    points = [tuple(zip(names, values)) for values in itertools.product(*(v for _, v in axes))]
    if not names:
        raise ConfigError("sweep: the grid is empty (give --param NAME=A:B:N)")
    return sweep_points(cfg, points, test, metric, **options)


def refine(cfg: BenchConfig, axes: Sequence[Axis], test: StepTest, metric: str = "itae", *, rounds: int = 3,
           shrink: float = 0.4, **options: Any) -> SweepResult:
    """A grid over ``axes``, then ``rounds - 1`` grids as many points, ``shrink`` times as wide,
    centred on the best point so far and kept inside the first grid's box; every point of every
    round is in the result, ranked together."""
    if rounds < 1:
        raise ConfigError("refine: rounds must be >= 1")
    limits = [(a.low, a.high) for a in axes]
    window = list(axes)
    seen: dict[Params, SweepPoint] = {}
    last: SweepResult | None = None
    sim_s = 0.0
    family = None
    for _ in range(rounds):
        names = [a.name for a in window]
        points = [p for p in (tuple(zip(names, v)) for v in itertools.product(*(a.values() for a in window)))
                  if p not in seen]
        if family is None and options.get("store") is not None:  # every round's points in one file
            from hilbench.bench.run import in_process

            family = "refine:" + _sweep_key(in_process(cfg), test, points, options.get("tolerances", Tolerances()),
                                            f"{_metric_key(metric)}:{rounds}:{shrink}")
        if points:
            last = sweep_points(cfg, points, test, metric, store_family=family, **options)
            sim_s += last.sim_s
            seen.update({p.params: p for p in last.points})
        best = min((p for p in seen.values() if p.result is not None), key=lambda p: _order(p.result, _metric_key(metric)),  # type: ignore[arg-type]
                   default=None)
        if best is None:
            break
        window = zoom(window, best.params, shrink, limits)
    assert last is not None
    key = last.metric
    final, ranked = _rank(list(seen.values()), key)
    return SweepResult(metric=key, axes=last.axes, points=final, ranked=ranked,
                       skipped=sum(p.skipped for p in final), test=test, sim_s=sim_s,
                       extras={**last.extras, "rounds": rounds})


# ---------------------------------------------------------------------------- output
def write_sweep_csv(path: str | Path, sweep: SweepResult) -> Path:
    """Every point, one row each, in order (skipped points with their constraint)."""
    out = Path(path)
    try:
        with open_output(out) as fh:  # (not onto a recording a session writes)
            writer = csv.writer(fh)
            writer.writerow((*sweep.axes, "status", "constraint", "rank", "stalled", "settled", "cases",
                             *(k for k, _, _ in METRIC_COLUMNS)))
            for p in sweep.points:
                r = p.result
                row: list[Any] = [v for _, v in p.params]
                if r is None:
                    row += ["skipped", p.constraint, "", "", "", ""] + [""] * len(METRIC_COLUMNS)
                else:
                    m = r.metrics
                    row += ["ok", "", p.rank, int(r.stalled), int(m.settled), p.cases]
                    row += ["" if (v := getattr(m, k)) is None else repr(float(v)) for k, _, _ in METRIC_COLUMNS]
                writer.writerow(row)
    except OSError as exc:
        raise RecordingError(f"sweep --csv {out}: cannot write ({exc.strerror})") from None
    return out


def best_fragment(sweep: SweepResult, held: Mapping[str, float] | None = None) -> str:
    """The best parameter set as a config fragment a later run can load (``[target]`` table);
    ``held``: the values the firmware holds for them (`held_params`), written instead, the swept
    value in a comment (0.7611111111111111 is 24940/32768 = 0.7611083984375 in Q15)."""
    best = sweep.best
    if best is None or best.result is None:
        raise ConfigError("sweep: no simulated parameter set to save (all were skipped)")
    value = getattr(best.result.metrics, sweep.metric)
    lines = [f"# best of a {len(sweep.points)}-point sweep by {sweep.metric} = {value:.6g}, "
             f"step {sweep.test.from_rpm:g} -> {sweep.test.to_rpm:g} rpm", "[target]"]
    for name, v in best.params:
        kept = (held or {}).get(name)
        lines.append(f"{name} = {v!r}" if kept is None or kept == v else
                     f"{name} = {kept!r}  # as the firmware holds it (swept: {v:.10g})")
    return "\n".join(lines) + "\n"


def held_params(cfg: BenchConfig, params: Sequence[tuple[str, float]]) -> dict[str, float]:
    """What the configured firmware holds for these parameter values (its fixed-point types: a Q15
    gain is a whole number of 1/32768), from the in-process target's own declarations."""
    from hilbench.bench.bench import Bench
    from hilbench.bench.livetuning import raw_per_unit
    from hilbench.bench.run import in_process

    with Bench(in_process(cfg), keep_rows=False) as bench:
        tuning = bench.session.tuning  # type: ignore[union-attr]
        return {name: tuning.encode(name, value)[1] / raw_per_unit(tuning.info[name].ptype) for name, value in params}
