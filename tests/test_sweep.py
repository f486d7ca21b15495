"""Offline sweep: the same step test as `hilbench step`, on an executor, grid bookkeeping, CSV, fragment."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from hilbench.bench.run import in_process, run_step_tests
from hilbench.bench.steptest import StepTest, step_scenario
from hilbench.bench.sweep import best_fragment, parse_axis, parse_grid_spec, sweep_grid, write_sweep_csv
from hilbench.bench.settings import load_config
from hilbench.config import default_config_text
from hilbench.errors import ConfigError

SHORT = StepTest(800.0, 1200.0, 0.08, 0.04)


def test_step_scenario_order_and_validation() -> None:
    events = step_scenario(1000, 2000, 0.5, 1.0)
    assert [e.ref_rpm for e in events if e.ref_rpm is not None] == [1000, 2000]
    assert [e.press for e in events if e.press] == ["s2"]
    with pytest.raises(ConfigError):
        step_scenario(1000, 2000, 1.5, 1.0)


def test_sweep_skips_constraint_breakers_ranks_and_reports_progress(tmp_path) -> None:
    cfg = load_config(None)
    seen: list[tuple[int, int]] = []
    # kp + ki + kd < 0.9999 (the firmware's constraint 1): 0.95 + 0.1 breaks it, 0.95 + 0.01 does not
    axes = [("kp", (0.2, 0.95)), ("ki", (0.01, 0.1)), ("kd", (0.0,))]
    sweep = sweep_grid(cfg, axes, SHORT, metric="itae", workers=1, progress=lambda d, t: seen.append((d, t)))
    assert sweep.skipped == 1
    skipped = [p for p in sweep.points if p.skipped]
    assert [p.params for p in skipped] == [(("kp", 0.95), ("ki", 0.1), ("kd", 0.0))]
    assert skipped[0].constraint is not None and "#1" in skipped[0].constraint
    assert [p.rank for p in sweep.ranked] == [1, 2, 3]
    values = [p.result.metrics.itae for p in sweep.ranked if not p.result.stalled]
    assert values == sorted(values)
    assert seen[0] == (0, 3) and seen[-1] == (3, 3)
    path = write_sweep_csv(tmp_path / "sweep.csv", sweep)
    rows = list(csv.DictReader(path.open()))
    assert len(rows) == 4 and sum(r["status"] == "skipped" for r in rows) == 1
    frag = tmp_path / "best.toml"
    frag.write_text(default_config_text() + "\n" + best_fragment(sweep))
    loaded = load_config(frag)
    assert (("kp", loaded.target.kp), ("ki", loaded.target.ki), ("kd", loaded.target.kd)) == sweep.best.params


def test_sweep_point_equals_the_step_command_and_workers_do_not_matter() -> None:
    """Every point is the scalar step test itself; a process pool returns the same, in grid order."""
    cfg = load_config(None)
    axes = [("kp", (0.1, 0.3)), ("ki", (0.01, 0.05))]
    alone = sweep_grid(cfg, axes, SHORT, workers=1)
    pooled = sweep_grid(cfg, axes, SHORT, workers=2)
    assert [p.params for p in alone.points] == [p.params for p in pooled.points]
    for a, b in zip(alone.points, pooled.points):
        assert a.result.metrics.as_dict() == b.result.metrics.as_dict()
    assert alone.best.params == pooled.best.params
    np.testing.assert_array_equal(alone.best.result.speed_rpm, pooled.best.result.speed_rpm)
    scalar = run_step_tests(in_process(cfg), SHORT, [dict(p.params) for p in alone.points])
    for point, alone_step in zip(alone.points, scalar):
        assert point.result.metrics.as_dict() == alone_step.metrics.as_dict()
    best_alone = scalar[[p.params for p in alone.points].index(alone.best.params)]
    np.testing.assert_array_equal(best_alone.speed_rpm, alone.best.result.speed_rpm)


def test_a_sweep_keeps_the_curves_of_its_best_point_only() -> None:
    """Memory bounded by one step test's curves whatever the number of points (a
    10 000-point sweep kept 2.4 GB at 240 kB a step test): every point keeps its figures, the best its response too."""
    cfg = load_config(None)
    sweep = sweep_grid(cfg, [("kp", (0.05, 0.1, 0.2, 0.3)), ("ki", (0.01, 0.05))], SHORT, workers=1)
    with_curves = [p for p in sweep.points if p.result is not None and len(p.result.speed_rpm)]
    assert [p.params for p in with_curves] == [sweep.best.params]
    assert len(sweep.best.result.t_s) == len(sweep.best.result.speed_rpm) > 100
    assert all(p.result is not None and p.rank is not None for p in sweep.points)  # every point ranked by its figures


def test_grid_spec_parsing() -> None:
    assert parse_grid_spec("0.1:0.5:5") == pytest.approx((0.1, 0.2, 0.3, 0.4, 0.5))
    assert parse_grid_spec("0.25") == (0.25,)
    assert parse_axis("kp=0.1:0.2:2") == ("kp", (0.1, 0.2))
    for bad in ("0.1:0.5", "nan", "1:2:1e9", "0.1:inf:3"):
        with pytest.raises(ConfigError, match="A:B:N"):
            parse_grid_spec(bad)
    with pytest.raises(ConfigError, match="NAME=A:B:N"):
        parse_axis("0.1:0.2:2")
    with pytest.raises(ConfigError, match="metric"):
        sweep_grid(load_config(None), [("kp", (0.1,))], SHORT, metric="speed")
    with pytest.raises(ConfigError, match="out of range"):
        sweep_grid(load_config(None), [("kp", (1.5,))], SHORT, workers=1)
    with pytest.raises(ConfigError, match="unknown parameter"):
        sweep_grid(load_config(None), [("kq", (0.1,))], SHORT, workers=1)


# ---------------------------------------------------------------- executors, resume, tolerances, refinement
import json  # noqa: E402
import os  # noqa: E402
import shutil  # noqa: E402
import signal  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

from conftest import REPO_ROOT  # noqa: E402
from hilbench.bench.sampling import Axis, grid, latin_hypercube, random_points  # noqa: E402
from hilbench.bench.sweep import Tolerances, refine, sweep_points  # noqa: E402

AXES = [("kp", (0.1, 0.3, 0.5)), ("ki", (0.01, 0.05))]


def _fingerprint(result) -> list[tuple]:  # type: ignore[no-untyped-def]
    return [(p.params, p.constraint, None if p.result is None else p.result.metrics.as_dict()) for p in result.points]


def test_the_same_sweep_in_process_on_a_pool_and_on_a_dask_cluster_is_identical() -> None:
    """Results and order do not depend on what ran them (each point seeded from the config)."""
    if shutil.which("gcc") is None and os.environ.get("HILBENCH_REQUIRE_TOOLS") != "1":
        pytest.skip("needs the compiled cores for speed")
    pytest.importorskip("distributed", reason="the dask extra is not installed (pip install 'hilbench[dask]')") \
        if os.environ.get("HILBENCH_REQUIRE_TOOLS") != "1" else None
    cfg = load_config(None)
    alone = sweep_grid(cfg, AXES, SHORT, executor="local", workers=1)
    pooled = sweep_grid(cfg, AXES, SHORT, executor="local", workers=2)
    dask = sweep_grid(cfg, AXES, SHORT, executor="local-dask:2")
    assert _fingerprint(alone) == _fingerprint(pooled) == _fingerprint(dask)
    assert "Dask" in dask.extras["executor"]


def test_an_interrupted_sweep_resumes_with_only_the_missing_points(tmp_path) -> None:
    store = tmp_path / "sweep.jsonl"
    cfg = load_config(None)
    points = grid([Axis("kp", 0.1, 0.5, 3), Axis("ki", 0.01, 0.05, 2)])

    def interrupt_after_two(done: int, total: int) -> None:
        if done >= 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        sweep_points(cfg, points, SHORT, workers=1, store=store, progress=interrupt_after_two)
    assert len(store.read_text().splitlines()) == 2
    resumed = sweep_points(cfg, points, SHORT, workers=1, store=store)
    assert resumed.sim_s == pytest.approx(4 * SHORT.duration_s)  # only the 4 missing points ran
    whole = sweep_points(cfg, points, SHORT, workers=1)
    assert [p.result.metrics.itae for p in resumed.points] == [p.result.metrics.itae for p in whole.points]
    with pytest.raises(ConfigError, match="another sweep"):
        sweep_points(cfg, points[:3], SHORT, workers=1, store=store)


@pytest.mark.slow
def test_ctrl_c_on_the_cli_sweep_then_a_restart_finishes_only_the_missing_points(tmp_path) -> None:
    store = tmp_path / "s.jsonl"
    args = [sys.executable, "-m", "hilbench", "sweep", "-p", "kp=0.1:0.5:10", "-p", "ki=0.01:0.05:6", "-p", "kd=0",
            "--duration", "1.0", "--step-at", "0.5", "--workers", "1", "--resume", str(store), "--json"]
    process = subprocess.Popen(args, cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and process.poll() is None:
            if store.exists() and len(store.read_text().splitlines()) >= 3:
                break
            time.sleep(0.02)  # polling the store with a deadline
        process.send_signal(signal.SIGINT)
        _, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate(timeout=10)
    assert process.returncode == 130 and "Traceback" not in err, err
    kept = len(store.read_text().splitlines())
    assert 3 <= kept < 60
    again = subprocess.run(args, cwd=REPO_ROOT, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert len(store.read_text().splitlines()) == 60 and len(json.loads(again.stdout)) == 10  # --top 10 of 60


def test_a_tolerance_sweep_reports_the_worst_case_of_each_point() -> None:
    cfg = load_config(None)
    nominal = sweep_grid(cfg, [("kp", (0.2,)), ("ki", (0.02,))], SHORT, workers=1)
    robust = sweep_grid(cfg, [("kp", (0.2,)), ("ki", (0.02,))], SHORT, workers=1, tolerances=Tolerances(rs=0.2, j=0.3))
    point = robust.points[0]
    assert point.cases == 4 and robust.step_tests == 4
    assert point.result.metrics.itae >= nominal.points[0].result.metrics.itae
    with pytest.raises(ConfigError, match="fraction"):
        Tolerances(rs=1.5).cases()


def test_samplers_are_seeded_and_stay_in_the_box() -> None:
    box = [Axis("kp", 0.1, 0.5, 1), Axis("ki", 0.01, 0.05, 1)]
    lhs = latin_hypercube(box, 8, seed=3)
    assert lhs == latin_hypercube(box, 8, seed=3) and lhs != latin_hypercube(box, 8, seed=4)
    kp = sorted(v for (_, v), _ in lhs)
    assert all(0.1 + 0.4 * i / 8 <= x < 0.1 + 0.4 * (i + 1) / 8 for i, x in enumerate(kp))  # one per stratum
    assert all(0.01 <= ki <= 0.05 for _, (_, ki) in random_points(box, 20, seed=1))


def test_refinement_zooms_around_the_best_point_and_keeps_every_round() -> None:
    cfg = load_config(None)
    box = [Axis("kp", 0.05, 0.85, 3), Axis("ki", 0.005, 0.12, 3)]
    once = refine(cfg, box, SHORT, rounds=1, workers=1)
    thrice = refine(cfg, box, SHORT, rounds=3, workers=1)
    assert len(thrice.points) > len(once.points)
    assert thrice.best.result.metrics.itae <= once.best.result.metrics.itae


def test_a_failed_task_cancels_the_queued_ones() -> None:
    """A sweep whose task fails (a diverged plant, a lost target) stops there: the tasks still
    queued are cancelled, not run first (a 800-point sweep reported its first task's error after
    every other task had run)."""
    import time

    from hilbench.bench.executors import open_executor

    queued = []
    with pytest.raises(ValueError):
        with open_executor("local", 2) as (pool, _):
            failing = pool.submit(int, "not a number")
            queued = [pool.submit(time.sleep, 0.05) for _ in range(400)]  # 10 s of work for two workers
            failing.result()
    assert sum(f.cancelled() for f in queued) > 300


def test_the_saved_best_is_what_the_firmware_holds(tmp_path: Path) -> None:
    """Issue 22, item 10: `sweep --save` wrote kp = 0.7611111111111111, a value no Q15 register holds.
    By hand: 0.7611111 × 32768 = 24940.09, so the firmware holds 24940/32768; 0.01 × 32768 = 327.68 → 328."""
    from hilbench.bench.sweep import held_params

    cfg = load_config(None)
    sweep = sweep_grid(cfg, [("kp", (0.7611111111111111,)), ("ki", (0.01,)), ("kd", (0.0,))], SHORT, workers=1)
    held = held_params(cfg, sweep.best.params)
    assert held == {"kp": 24940 / 32768, "ki": 328 / 32768, "kd": 0.0}
    text = best_fragment(sweep, held)
    assert "kp = 0.7611083984375  # as the firmware holds it (swept: 0.7611111111)" in text
    assert "kd = 0.0\n" in text
    frag = tmp_path / "best.toml"
    frag.write_text(default_config_text() + "\n" + text)
    assert load_config(frag).target.kp == 24940 / 32768


def test_a_pooled_sweep_holds_a_window_of_results_not_the_whole_sweep() -> None:
    """With a process pool, a finished future keeps its results (every step test's curves): the
    sweep keeps only tasks_in_flight tasks submitted and drops each future once read, so what it
    holds at once is a window, however many points (it held every point's curves before)."""
    import tracemalloc

    from hilbench.bench.sweep import CHUNK_TESTS

    cfg = load_config(None)
    tiny = StepTest(800.0, 1200.0, 0.025, 0.02)
    one = run_step_tests(in_process(cfg), tiny, [{"kp": 0.1}])[0]
    curve_bytes = one.t_s.nbytes + one.speed_rpm.nbytes + (one.firmware_ref_rpm.nbytes if one.firmware_ref_rpm is not None else 0)
    points = [("kp", tuple(0.05 + 0.001 * i for i in range(240))), ("ki", (0.01, 0.02))]  # 480 points
    tracemalloc.start()
    try:
        sweep = sweep_grid(cfg, points, tiny, workers=2)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    window_tests = 2 * 2 * CHUNK_TESTS  # tasks_in_flight of a pool of 2, CHUNK_TESTS step tests a task
    assert len(sweep.points) == 480 and all(p.result is not None for p in sweep.points)
    print(f"peak {peak / 1e6:.1f} MB, a step test's curves {curve_bytes / 1e3:.0f} kB, all of them {480 * curve_bytes / 1e6:.1f} MB")
    assert peak < 480 * curve_bytes / 2, (peak, curve_bytes)  # all the curves at once: 480 * curve_bytes
    assert peak < 3 * window_tests * curve_bytes + 4_000_000, (peak, curve_bytes)
