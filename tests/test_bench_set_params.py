"""Bench.set_params takes keywords or one mapping; anything else is one ConfigError, never a silent
write of nothing (a dict passed positionally used to become the guard flag: an empty set the
firmware refused as a bad request)."""

from __future__ import annotations

import pytest

import hilbench
from hilbench.errors import ConfigError


def test_a_mapping_and_keywords_write_the_same() -> None:
    with hilbench.Bench(target="inprocess:an1017") as bench:
        bench.set_params({"kp": 0.2}, guard=False)
        assert bench.get_params()["kp"] == pytest.approx(0.2, abs=1 / 32768)
        bench.set_params(kp=0.3, guard=False)
        assert bench.get_params()["kp"] == pytest.approx(0.3, abs=1 / 32768)


@pytest.mark.parametrize("call", [
    lambda b: b.set_params(),
    lambda b: b.set_params([("kp", 0.1)]),
    lambda b: b.set_params(kp="fast"),
    lambda b: b.set_params({"kp": None}),
])
def test_a_wrong_call_is_one_config_error(call) -> None:  # type: ignore[no-untyped-def]
    with hilbench.Bench(target="inprocess:an1017") as bench:
        with pytest.raises(ConfigError, match="set_params"):
            call(bench)


def test_an_int_no_float_holds_is_out_of_range_not_a_traceback() -> None:
    """Third audit: set_params(kp=10**400) raised OverflowError."""
    with hilbench.Bench(target="inprocess:an1017") as bench:
        for huge in (10**400, -10**400):
            with pytest.raises(hilbench.HilbenchError, match="kp=-?inf is out of range"):
                bench.set_params(kp=huge)


@pytest.mark.parametrize(("call", "says"), [
    (lambda b: b.set_load(0.01, kind="Constant"), "set_load kind='Constant': one of constant, linear"),
    (lambda b: b.inject_fault("hall_a_high", float("nan")), "inject_fault duration_s=nan: expected a finite"),
    (lambda b: b.inject_fault("hall_a_high", -1.0), "inject_fault duration_s=-1.0: expected a finite"),
    (lambda b: b.inject_fault("hall_a_high", "x"), "inject_fault duration_s='x': expected a finite"),
])
def test_a_load_kind_or_fault_duration_out_of_its_set_is_refused(call, says: str) -> None:  # type: ignore[no-untyped-def]
    """Third audit: an unknown load kind locked the rotor; a NaN or negative fault duration was
    recorded, a string one raised TypeError in the period loop."""
    with hilbench.Bench(target="inprocess:an1017") as bench:
        with pytest.raises(ConfigError) as caught:
            call(bench)
        assert str(caught.value).startswith(says)
        assert not any("load" in e or "fault" in e for e in bench.events)


@pytest.mark.parametrize("record", [None, "run.npz"])
def test_a_closed_bench_runs_and_sets_nothing_and_its_results_stay(tmp_path, record) -> None:  # type: ignore[no-untyped-def]
    """Third audit: run() after close() simulated periods never written (a file) or not in the
    summary (in memory); with an emulator it raised 'flush of closed file'."""
    bench = hilbench.Bench(target="inprocess:an1017", record=None if record is None else tmp_path / record)
    bench.open()
    bench.run(0.02)
    summary = bench.close()
    assert summary is not None
    for call in (lambda: bench.run(0.02), lambda: bench.set_params(kp=0.1), lambda: bench.press("s2")):
        with pytest.raises(ConfigError, match=r"^Bench: closed"):
            call()
    assert len(bench.signals()["t_s"]) == summary.periods == bench.summary().periods
    with pytest.raises(ConfigError, match=r"^Bench: closed"):  # nor opened again
        bench.open()


def test_numpy_numbers_are_numbers() -> None:
    import numpy as np

    with hilbench.Bench(target="inprocess:an1017") as bench:
        bench.set_params(kp=np.float32(0.25), ki=np.int64(0), guard=False)
        assert bench.get_params()["kp"] == pytest.approx(0.25, abs=1 / 32768)
