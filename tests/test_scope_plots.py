"""The report's PNGs: min/max envelopes keep a one-sample spike, a window draws every period,
halls as digital traces, event markers, and no link plot for a lockstep run."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

matplotlib = pytest.importorskip("matplotlib", reason="the plot extra (matplotlib) is not installed")

from hilbench.bench.recorder import COLUMN_NAMES, RecordingData  # noqa: E402
from hilbench.errors import ConfigError  # noqa: E402
from hilbench.ui.plots import MAX_POINTS, _mark_events, _pyplot, _trace, parse_window, plot_recording  # noqa: E402


def recording(tmp_path: Path, lateness_us: float = 0.0) -> RecordingData:
    """One second at 20 kHz: a 50 Hz current with a one-sample 5 A spike at t = 0.3 s."""
    t = np.arange(20_000) * 50e-6
    columns = {name: np.zeros_like(t) for name in COLUMN_NAMES}
    columns["t_s"] = t
    columns["ia_a"] = np.sin(2 * np.pi * 50 * t)
    columns["ia_a"][6000] = 5.0
    columns["hall"] = np.array([1, 3, 2, 6, 4, 5])[(t * 300).astype(int) % 6].astype(float)
    columns["lateness_us"] = np.full_like(t, lateness_us)
    return RecordingData(tmp_path / "run.npz", columns, {}, ("t=0.250000 set kp=0.2", "t=0.500000 ref 2000 rpm"))


def test_envelope_keeps_a_one_sample_spike(tmp_path: Path) -> None:
    data = recording(tmp_path)
    plt = _pyplot()
    fig, ax = plt.subplots()
    _trace(ax, data.columns["t_s"], data.columns["ia_a"], "i_a", {"lw": 0.6})
    band = ax.collections[0]
    top = max(path.vertices[:, 1].max() for path in band.get_paths())
    bottom = min(path.vertices[:, 1].min() for path in band.get_paths())
    assert top == pytest.approx(5.0) and bottom == pytest.approx(-1.0, abs=1e-3)
    assert len(ax.lines[0].get_xdata()) <= MAX_POINTS
    plt.close(fig)


def test_event_markers_at_their_times(tmp_path: Path) -> None:
    plt = _pyplot()
    fig, ax = plt.subplots()
    _mark_events(ax, [(0.25, "set kp=0.2"), (0.5, "ref 2000 rpm"), (0.501, "press s2"), (2.0, "outside")], 0.0, 1.0,
                 label=True)
    assert sorted(line.get_xdata()[0] for line in ax.lines) == [0.25, 0.5]
    assert {text.get_text().strip() for text in ax.texts} == {"set kp=0.2", "ref 2000 rpm; press s2"}
    plt.close(fig)


def test_no_link_plot_in_lockstep_and_one_in_real_time(tmp_path: Path) -> None:
    lockstep = {p.name for p in plot_recording(recording(tmp_path), tmp_path / "a")}
    assert lockstep == {"run_speed.png", "run_currents.png", "run_duties.png", "run_hall.png"}
    realtime = {p.name for p in plot_recording(recording(tmp_path, lateness_us=12.0), tmp_path / "b")}
    assert "run_link.png" in realtime


def test_a_window_and_its_errors(tmp_path: Path) -> None:
    assert parse_window("1.0:1.05") == (1.0, 1.05) and parse_window(None) is None
    for bad in ("1.0", "a:b", "2:1"):
        with pytest.raises(ConfigError, match="--window"):
            parse_window(bad)
    written = plot_recording(recording(tmp_path), tmp_path / "w", window=(0.29, 0.31))
    assert all(p.stat().st_size > 5_000 for p in written)
    with pytest.raises(ConfigError, match="spans"):
        plot_recording(recording(tmp_path), tmp_path / "x", window=(5.0, 6.0))


def test_a_whole_run_is_readable(tmp_path: Path) -> None:
    """Issue 22, item 7: over a whole run the three phase currents and duties were one block on one
    axis, the halls solid bars and the link's symlog axis half negative. Now: a lane per phase, the
    hall edge rate when there are too many edges to draw, a log axis starting at LINK_FLOOR_US."""
    from hilbench.ui.plots import LINK_FLOOR_US, MAX_HALL_EDGES, _hall_figure, _lanes_figure

    data = recording(tmp_path, lateness_us=-3.0)
    c = data.columns
    c["hall"] = np.array([1, 3, 2, 6, 4, 5])[(c["t_s"] * 3000).astype(int) % 6].astype(float)  # a new code every 1/3000 s
    from hilbench.bench.column_chunks import ArrayChunks
    from hilbench.ui.plot_data import view

    plt = _pyplot()
    v = view(ArrayChunks(c), ("ia_a", "ib_a", "ic_a", "hall", "sector"))  # what the figures draw, read in chunks
    fig = _lanes_figure(plt, v, [(n, n, "A", {"color": f"C{k}"}) for k, n in enumerate(("ia_a", "ib_a", "ic_a"))],
                        "currents")
    assert len(fig.axes) == 3 and len({ax.lines[0].get_color() for ax in fig.axes}) == 3
    plt.close(fig)
    edges = int(np.count_nonzero(np.diff(c["hall"])))
    assert edges > MAX_HALL_EDGES  # 2999 over the second
    fig = _hall_figure(plt, v, [])
    rate = fig.axes[0].lines[0].get_ydata()
    assert np.median(rate) == pytest.approx(3000, rel=0.02)  # one edge per code change: 3000 per second
    plt.close(fig)
    paths = plot_recording(data, tmp_path / "c")
    assert any(p.name == "run_link.png" for p in paths)
    assert LINK_FLOOR_US > 0


#: a monitor-mode or custom-firmware layout: no plant currents, no duties, no link timing
_NO_DUTIES = (("t_s", "s", "%.6f"), ("seq", "", "%d"), ("hall", "bits CBA", "%d"), ("sector", "", "%d"),
              ("measured_speed_rpm", "rpm", "%.3f"), ("ref_speed_rpm", "rpm", "%.3f"), ("iq_ref_q15", "q15", "%d"),
              ("fault", "", "%d"), ("marker", "", "%d"))


def _no_duty_recording(path: Path) -> Path:
    """Half a second at 1 kHz of the _NO_DUTIES columns, written by the recorder as a run writes it."""
    from _recordings import write_recording

    k = np.arange(500)
    columns = {"t_s": k * 1e-3, "seq": k % 256, "hall": np.array([1, 3, 2, 6, 4, 5])[(k // 10) % 6],
               "sector": (k // 10) % 6, "measured_speed_rpm": np.full(500, 990.0),
               "ref_speed_rpm": np.full(500, 1000.0), "iq_ref_q15": 1200 + k, "fault": 0 * k, "marker": 0 * k}
    return write_recording(path, columns, specs=_NO_DUTIES, metadata={"period_us": 1000, "mode": "monitor"})


def test_a_recording_without_duties_plots_what_it_has_and_names_what_it_left_out(tmp_path: Path) -> None:
    """`report --plot` on a layout with no duty, current or link columns: no traceback (it crashed
    in subplots(0, 1)), the speed, telemetry and hall PNGs, and one line naming what it left out."""
    from conftest import run_cli

    for name in ("mon.npz", "mon.csv"):
        path = _no_duty_recording(tmp_path / name)
        out = tmp_path / f"plots_{name}"
        done = run_cli("report", str(path), "--plot", str(out), "--json")
        assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr[-2000:]
        info = json.loads(done.stdout)
        stem = name.split(".")[0]
        assert sorted(Path(p).name for p in info["plots"]) == [f"{stem}_{x}.png" for x in ("hall", "speed", "telemetry")]
        assert all(Path(p).stat().st_size > 5_000 for p in info["plots"])
        assert info["plots_left_out"] == ("currents (no ia_a, ib_a, ic_a, ibus_a); duties (no duty_a, duty_b, duty_c); "
                                          "link (no rtt_us, lateness_us)")
        table = run_cli("report", str(path), "--plot", str(out))
        assert table.returncode == 0 and "plots left out" in table.stdout and "duty_a" in table.stdout


def test_a_lane_missing_is_named_and_an_overlay_without_speed_is_drawn_without_it(tmp_path: Path) -> None:
    from hilbench.bench.column_chunks import ArrayChunks
    from hilbench.bench.recording_head import RecordingHead
    from hilbench.ui.plots import plot_speed_overlay_chunks

    data = recording(tmp_path)
    del data.columns["duty_c"]
    plots = plot_recording(data, tmp_path / "a")
    assert "run_duties.png" in {p.name for p in plots}
    assert plots.left_out == ("duties (no duty_c)",) and plots.note() == "plots left out: duties (no duty_c)"
    assert plot_recording(recording(tmp_path), tmp_path / "b").note() is None
    full = recording(tmp_path)
    speedless = {n: v for n, v in full.columns.items() if n not in ("speed_rpm", "measured_speed_rpm")}
    heads = [(RecordingHead(tmp_path / name, {}, (), {}, {}), ArrayChunks(columns))
             for name, columns in (("hil.npz", full.columns), ("motor.npz", speedless))]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "No artists with labels" warning either
        overlay = plot_speed_overlay_chunks(heads, tmp_path / "o")
    assert overlay.paths[0].stat().st_size > 5_000
    assert overlay.left_out == ("overlay of motor.npz (no speed_rpm or measured_speed_rpm with values)",)


def test_dense_halls_and_sectors_are_drawn_as_their_rates_with_their_ticks(tmp_path: Path) -> None:
    """One function draws both rates (duplicates D3: _hall_rate and _sector_rate were one shape):
    3000 codes a second in either lane, an invalid hall code every 997th period and a sector jump
    every 1301st, each counted here from the arrays."""
    from hilbench.bench.column_chunks import ArrayChunks
    from hilbench.ui.plot_data import view
    from hilbench.ui.plots import _hall_figure

    c = recording(tmp_path).columns
    step = (c["t_s"] * 3000).astype(int)
    c["hall"] = np.array([1, 3, 2, 6, 4, 5])[step % 6].astype(float)
    c["hall"][::997] = 7
    c["sector"] = (step % 6).astype(float)
    c["sector"][::1301] = 3
    invalid = int(np.count_nonzero(c["hall"] == 7))
    sector = c["sector"].astype(int)
    before, after = sector[:-1], sector[1:]
    changed = before != after
    jumps = int(np.count_nonzero(changed & ((after - before) % 6 != 1) & ((before - after) % 6 != 1)))
    plt = _pyplot()
    fig = _hall_figure(plt, view(ArrayChunks(c), ("hall", "sector")), [])
    halls, sectors = fig.axes
    assert halls.get_ylabel() == "hall edges / s" and sectors.get_ylabel() == "sector changes / s"
    assert [t.get_text() for t in halls.get_legend().get_texts()] == \
        ["hall edges per second", f"invalid hall code ({invalid} periods)"]
    assert [t.get_text() for t in sectors.get_legend().get_texts()] == \
        ["sector changes per second", f"out-of-sequence changes ({jumps})"]
    assert np.median(sectors.lines[0].get_ydata()) == pytest.approx(3000, rel=0.02)
    assert "too many to draw as steps" in halls.texts[0].get_text() and not sectors.texts
    plt.close(fig)
