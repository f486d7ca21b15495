"""`hilbench report`: the summary and plots of a recording, from CSV, NPZ and a killed run's journal."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conftest import hurst_bench_config, run_cli


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_report_summarises_and_plots(tmp_path: Path, suffix: str) -> None:
    record = tmp_path / f"run{suffix}"
    config = hurst_bench_config(tmp_path, 0.4)
    result = run_cli("run", str(config), "--target", "inprocess:an1017", "--record", str(record), "--no-ui", "--no-control")
    assert result.returncode == 0, result.stderr
    report = run_cli("report", str(record), "--plot", str(tmp_path / "plots"), "--json")
    assert report.returncode == 0, report.stderr
    info = json.loads(report.stdout)
    assert info["rows"] == 8000
    assert info["target"].startswith("AN1017")
    assert info["fault_rows"] == []
    assert any("press s2" in e for e in info["events"])
    assert 0 < info["max_speed_rpm"] < 1500  # the pot asks for 1000 rpm
    plots = [Path(p) for p in info["plots"]]
    assert {p.name.split("_", 1)[1] for p in plots} == {"speed.png", "currents.png", "duties.png", "hall.png"}  # no link plot in lockstep
    assert all(p.stat().st_size > 10_000 for p in plots)


def test_npz_recording_exports_the_same_csv_as_a_csv_run(tmp_path: Path) -> None:
    config = hurst_bench_config(tmp_path, 0.1)
    for suffix in (".csv", ".npz"):
        result = run_cli("run", str(config), "--target", "inprocess:an1017", "--record", str(tmp_path / f"run{suffix}"),
                         "--no-ui", "--no-control")
        assert result.returncode == 0, result.stderr
    export = run_cli("report", str(tmp_path / "run.npz"), "--csv", str(tmp_path / "export.csv"), "--json")
    assert export.returncode == 0, export.stderr

    def rows(path: Path) -> list[str]:
        return [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]

    assert rows(tmp_path / "export.csv") == rows(tmp_path / "run.csv")


def test_report_of_a_realtime_recording_gives_its_timing(tmp_path: Path) -> None:
    """Lateness and RTT spreads from the rows, and the periods the host skipped (marker 5)."""
    from hilbench.bench.recorder import COLUMN_NAMES, MARKER_SKIPPED, Recorder, read_recording
    from hilbench.bench.report import summarise

    path = tmp_path / "rt.csv"
    rec = Recorder(path, {"mode": "realtime", "period_us": 1000})
    for k in range(100):
        row = dict.fromkeys(COLUMN_NAMES, 0.0)
        skipped = k in (50, 51)
        lateness = {50: 2500.0, 51: 1500.0}.get(k, 1.0)
        row.update(t_s=k * 1e-3, seq=k, rtt_us=0.0 if skipped else 100.0 + k, lateness_us=lateness,
                   marker=MARKER_SKIPPED if skipped else 0)
        rec.append(tuple(row[name] for name in COLUMN_NAMES))
    rec.close("end")
    info = summarise(read_recording(path))
    assert info["skipped_periods"] == 2
    assert info["lateness_us"].endswith("max 2500.0")
    assert info["rtt_us"].startswith("p50 148.5") and info["rtt_us"].endswith("max 199.0")  # skipped rows left out
