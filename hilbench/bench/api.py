"""Step tests and sweeps for Python callers: the functions behind `hilbench step` and `hilbench sweep`."""

from __future__ import annotations

import os
from typing import Callable, Mapping, Sequence

from hilbench.bench.bench import as_config
from hilbench.bench.run import in_process, run_step_tests, settings_profile
from hilbench.bench.steptest import StepResult, StepTest, require_speed_loop
from hilbench.bench.sweep import SweepResult, Tolerances, sweep_grid
from hilbench.config import BenchConfig
from hilbench.errors import ConfigError
from hilbench.limits import shown


def step_test(
    config: BenchConfig | str | os.PathLike[str] | None = None,
    *,
    target: str | None = None,
    from_rpm: float = 1000.0,
    to_rpm: float = 2000.0,
    settle_s: float = 0.5,
    after_s: float = 0.5,
    params: Mapping[str, float] | None = None,
    overrides: Sequence[str] = (),
) -> StepResult:
    """One speed step on a fresh target (default: the configured target's in-process model) with
    ``params`` written first; returns the response and its metrics (rise, overshoot, settling, …)."""
    if params is not None and not isinstance(params, Mapping):
        raise ConfigError(f"step_test params={shown(params)}: expected a mapping of names to values")
    cfg = as_config(config, target, overrides)
    if target is None:
        cfg = in_process(cfg)
    require_speed_loop(settings_profile(cfg), "step_test")
    return run_step_tests(cfg, StepTest(from_rpm, to_rpm, settle_s, after_s), [dict(params or {})])[0]


def sweep(
    axes: Mapping[str, Sequence[float]],
    config: BenchConfig | str | os.PathLike[str] | None = None,
    *,
    from_rpm: float = 1000.0,
    to_rpm: float = 2000.0,
    settle_s: float = 0.5,
    after_s: float = 0.5,
    metric: str = "itae",
    executor: str | None = None,
    workers: int | None = None,
    tolerances: Tolerances = Tolerances(),
    store: str | os.PathLike[str] | None = None,
    overrides: Sequence[str] = (),
    progress: Callable[[int, int], None] | None = None,
) -> SweepResult:
    """Step-test every point of a grid, e.g. ``sweep({"kp": [0.1, 0.2], "ki": [0.01, 0.02]})``, on
    ``executor`` (None: a local process pool of ``workers``, one per core by default; "local-dask:N";
    a Dask scheduler's "tcp://host:8786"), worst case over motor ``tolerances``, appending finished
    points to ``store`` (a restarted sweep runs only the missing ones); ranked by ``metric``."""
    if not isinstance(axes, Mapping) or not all(hasattr(values, "__iter__") and not isinstance(values, (str, bytes))
                                                for values in axes.values()):
        raise ConfigError(f"sweep axes={shown(axes)}: expected a mapping of names to lists of values, "
                          "e.g. {\"kp\": [0.1, 0.2]}")
    cfg = as_config(config, None, overrides)
    test = StepTest(from_rpm, to_rpm, settle_s, after_s)
    return sweep_grid(cfg, list(axes.items()), test, metric, executor=executor, workers=workers,
                      tolerances=tolerances, store=store, progress=progress)


__all__ = ["step_test", "sweep"]
