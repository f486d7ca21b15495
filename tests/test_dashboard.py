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


def test_a_fault_is_shown_by_name() -> None:
    """Issue 22, item 9: faults were codes."""
    import io as io_module

    from hilbench.bench.summary import Snapshot
    from hilbench.ui.dashboard import render_snapshot

    snap = Snapshot(t_s=1.0, duration_s=5.0, period=20000, ref_rpm=-2000.0, speed_rpm=70.0, measured_rpm=60.0,
                    state=4, sector=2, direction_ccw=True, output_mode=0, duties=(0, 0, 0), i_abc=(0.0, 0.0, 0.0),
                    i_bus=0.0, telemetry={}, periods_per_s=1e4, rtt_p50_us=1.0, rtt_p99_us=2.0, link={}, overruns=0,
                    messages=[], history=[], fault=3)
    console = Console(file=io_module.StringIO(), width=160)
    console.print(render_snapshot(snap, {"kp": 0.1}, "inprocess:an1017"))
    assert "FAULT (OVERCURRENT), outputs off" in console.file.getvalue()  # type: ignore[attr-defined]
