"""The live dashboard and the summary render a real session's figures."""

from __future__ import annotations

import io
from pathlib import Path

from rich.console import Console

from conftest import hurst_bench_config
from hilbench.bench.run import RunRequest, load_run_config, run_bench
from hilbench.ui.dashboard import Dashboard, sparkline, summary_table, summary_text


def test_dashboard_and_summary_show_the_run(tmp_path: Path) -> None:
    cfg = load_run_config(RunRequest(str(hurst_bench_config(tmp_path, 0.5)), target="inprocess:an1017"))
    out = io.StringIO()
    console = Console(file=out, width=120, force_terminal=True)
    dashboard = Dashboard("inprocess:an1017", 0.5, console=console, max_fps=1000.0)
    frames: list[float] = []

    def observe(snap):  # type: ignore[no-untyped-def]
        frames.append(snap.t_s)
        dashboard(snap)

    with dashboard:
        summary = run_bench(cfg, observer=observe, on_ready=dashboard.attach)
    assert frames and frames[-1] > 0.4
    text = out.getvalue()
    for needle in ("reference", "speed (plant)", "RUNNING", "kp", "periods/s", "simulated"):
        assert needle in text, needle
    console.print(summary_table(summary))
    assert "mode" in out.getvalue()
    plain = summary_text(summary)
    assert "ref +1000 rpm" in plain and "error" in plain


def test_sparkline_spans_the_whole_series() -> None:
    line = sparkline([float(i) for i in range(1000)], width=10)
    assert len(line) == 10 and line[0] == "▁" and line[-1] == "█"
