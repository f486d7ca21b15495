"""A target from an outside package: found through the `hilbench.targets` entry point alone, it runs
through `run` (emulator process and in-process), the recorder, `report`, `step`, `sweep` and `ctl`
with its own options, parameters and telemetry columns, and no edit to hilbench.

The package is tests/plugin_tiny (the module `tinytarget` and its dist-info with the entry point);
each test runs the real CLI in a process whose PYTHONPATH holds it, as `pip install` would.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from conftest import REPO_ROOT

PLUGIN_DIR = REPO_ROOT / "tests" / "plugin_tiny"


def _env(**extra: str) -> dict[str, str]:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(PLUGIN_DIR), os.environ.get("PYTHONPATH", "")]))
    env.update(extra)
    return env


def _cli(*args: str, timeout: float = 120.0, **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hilbench", *args], capture_output=True, text=True,
                          timeout=timeout, env=_env(**env), cwd=REPO_ROOT)


def test_the_plugin_is_listed_and_the_bench_does_not_know_it_otherwise() -> None:
    listed = _cli("targets")
    assert listed.returncode == 0, listed.stderr
    assert "tiny" in listed.stdout and "TINY" in listed.stdout
    alone = subprocess.run([sys.executable, "-m", "hilbench", "run", "--target", "inprocess:tiny", "--no-ui"],
                           capture_output=True, text=True, timeout=60, cwd=REPO_ROOT)
    assert alone.returncode == 2 and "unknown target 'tiny'" in alone.stderr


@pytest.mark.slow
def test_run_on_the_plugin_emulator_records_its_columns_and_reports_them(tmp_path: Path) -> None:
    out = tmp_path / "tiny.csv"
    config = tmp_path / "tiny.toml"
    config.write_text((REPO_ROOT / "bench_configs" / "hurst_mclv.toml").read_text() + """
[link]
target = "emulator:tiny"

[target]
pole_pairs = 5

[[scenario]]
at_s = 0.0
ref_rpm = 800.0

[[scenario]]
at_s = 0.01
press = "s2"

[[scenario]]
at_s = 0.3
set = { v_per_krpm = 38 }

[[scenario]]
at_s = 0.6
end = true
""")
    run = _cli("run", str(config), "--record", str(out), "--json", "--no-control", timeout=180)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary["firmware"] == "TINY" and summary["params"]["v_per_krpm"] == 38
    rows = list(csv.DictReader(line for line in out.open() if not line.startswith("#")))
    assert "tiny_modulation" in rows[0] and "tiny_angle_deg[deg]" in rows[0]
    assert abs(float(rows[-1]["speed_rpm[rpm]"]) - 800.0) < 20.0  # it follows its reference (accel 4000 rpm/s)
    report = _cli("report", str(out), "--json", "--plot", str(tmp_path / "plots"))
    assert report.returncode == 0, report.stderr
    assert any(p.endswith("_telemetry.png") for p in json.loads(report.stdout)["plots"])


def test_step_and_sweep_use_the_plugins_parameters(tmp_path: Path) -> None:
    step = _cli("step", "--target", "inprocess:tiny", "--from", "300", "--to", "600", "--settle", "0.2",
                "--after", "0.2", "--gains", "v_per_krpm=36", "--json")
    assert step.returncode == 0, step.stderr
    (row,) = json.loads(step.stdout)
    assert row["v_per_krpm"] == 36 and row["rise_time_s"] == pytest.approx(300 * 0.8 / 4000, abs=0.01)
    sweep = _cli("sweep", "--set", 'link.target="inprocess:tiny"', "-p", "v_per_krpm=30:40:2", "--from", "300",
                 "--to", "600", "--duration", "0.4", "--step-at", "0.2", "--json", "--workers", "1")
    assert sweep.returncode == 0, sweep.stderr
    assert sorted(r["v_per_krpm"] for r in json.loads(sweep.stdout)) == [30.0, 40.0]


@pytest.mark.slow
def test_ctl_sets_and_reads_the_plugins_parameters(tmp_path: Path) -> None:
    config = tmp_path / "hold.toml"  # a scenario with no end: the run lasts until `ctl stop`
    config.write_text((REPO_ROOT / "bench_configs" / "hurst_mclv.toml").read_text()
                      + "\n[[scenario]]\nat_s = 0.0\nref_rpm = 500.0\n\n[[scenario]]\nat_s = 0.01\npress = \"s2\"\n")
    with tempfile.TemporaryDirectory(prefix="hb") as runtime:  # a short path for the Unix socket
        env = {"XDG_RUNTIME_DIR": runtime}
        process = subprocess.Popen([sys.executable, "-m", "hilbench", "run", str(config), "--target", "inprocess:tiny",
                                    "--duration", "86400", "--no-ui", "--set", "tuning.guard=false"],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(**env),
                                   cwd=REPO_ROOT)
        try:
            sessions = Path(runtime) / "hilbench" / "sessions"  # one discovery file per session

            def published() -> bool:
                return sessions.is_dir() and any(sessions.glob("*.session"))

            deadline = time.monotonic() + 30
            while not published() and time.monotonic() < deadline and process.poll() is None:
                time.sleep(0.05)  # polling for the session's socket with a deadline
            assert published(), process.stderr.read() if process.poll() is not None else "no socket"
            changed = _cli("ctl", "set", "v_per_krpm=33", timeout=30, **env)
            assert changed.returncode == 0, changed.stderr
            got = _cli("ctl", "get", timeout=30, **env)
            assert '"v_per_krpm": 33.0' in got.stdout
            refused = _cli("ctl", "set", "v_per_krpm=300", timeout=30, **env)
            assert refused.returncode != 0 and "out of range" in refused.stderr
            stopped = _cli("ctl", "stop", timeout=30, **env)
            assert stopped.returncode == 0, stopped.stderr
            out, err = process.communicate(timeout=30)
            assert process.returncode == 0, err
            assert "stopped by ctl" in out
        finally:
            if process.poll() is None:
                process.kill()
                process.communicate(timeout=10)
