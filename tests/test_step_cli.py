"""`hilbench step` and `hilbench sweep` run the same step test and agree on its figures."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from conftest import run_cli


def test_step_cli_compares_gain_sets(tmp_path: Path) -> None:
    out = tmp_path / "steps.csv"
    plot = tmp_path / "steps.png"
    result = run_cli("step", "--gains", "0.1,0.01,0", "--gains", "0.3,0.05,0", "--csv", str(out), "--plot", str(plot), timeout=300)
    assert result.returncode == 0, result.stderr
    assert "0.1/0.01/0" in result.stdout and "0.3/0.05/0" in result.stdout
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 2
    assert float(rows[1]["itae"]) < float(rows[0]["itae"])  # the livelier gains settle faster
    assert plot.stat().st_size > 10_000


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("step", "--from", "1000", "--to", "1000"), "a step needs two speeds"),
        (("step", "--gains", "0.1,x"), "not numbers"),
        (("step", "--gains", "0.7,0.5,0"), "Kp + Ki + Kd < 0.9999"),
        (("sweep", "--param", "kp=0.1:0.2"), "--param kp"),
        (("step", "--target", "inprocess:loopback"), "no speed loop"),
    ],
)
def test_step_and_sweep_bad_input(args: tuple[str, ...], needle: str) -> None:
    result = run_cli(*args, timeout=120)
    assert result.returncode != 0
    assert "Traceback" not in result.stderr
    assert needle in result.stderr, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_sweep_cli_ranks_skips_and_saves(tmp_path: Path) -> None:
    save = tmp_path / "best.toml"
    table = tmp_path / "sweep.csv"
    result = run_cli("sweep", "-p", "kp=0.1:0.9:3", "-p", "ki=0.01:0.3:3", "-p", "kd=0", "--csv", str(table), "--save", str(save),
                     "--json", timeout=300)
    assert result.returncode == 0, result.stderr
    ranked = json.loads(result.stdout)
    itae = [r["itae"] for r in ranked]
    assert itae == sorted(itae)
    rows = list(csv.DictReader(table.open()))
    assert len(rows) == 9
    skipped = [r for r in rows if r["status"] == "skipped"]
    expected_skips = {(kp, ki) for kp in (0.1, 0.5, 0.9) for ki in (0.01, 0.155, 0.3) if kp + ki >= 0.9999}
    assert {(float(r["kp"]), float(r["ki"])) for r in skipped} == expected_skips  # Kp + Ki + Kd < 0.9999
    assert len(ranked) == 9 - len(expected_skips)
    # the saved fragment starts the next run with those gains
    run = run_cli("run", "--gains-file", str(save), "--target", "inprocess:an1017", "--duration", "0.05",
                  "--json", "--no-control", timeout=120)
    assert run.returncode == 0, run.stderr
    params = json.loads(run.stdout)["params"]
    assert params["kp"] == pytest.approx(ranked[0]["kp"], abs=1e-4)
    assert params["ki"] == pytest.approx(ranked[0]["ki"], abs=1e-4)


def test_step_record_is_refused_where_it_would_keep_nothing(tmp_path: Path) -> None:
    """--record keeps one real step's rows (--mode monitor, one gain set): in lockstep, or with
    several gain sets, it was silently ignored (or kept the first set's only); now one line, exit 2."""
    result = run_cli("step", "--record", str(tmp_path / "x.csv"), timeout=120)
    assert result.returncode == 2 and "step --record keeps the rows of one real step" in result.stderr, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and not (tmp_path / "x.csv").exists()
    many = run_cli("step", "--mode", "monitor", "--target", "serial:/dev/null", "--gains", "0.1,0.01,0",
                   "--gains", "0.2,0.02,0", "--record", str(tmp_path / "y.csv"), timeout=120)
    assert many.returncode == 2 and "give one --gains" in many.stderr, many.stderr
