"""`hilbench report` read a chunk at a time: the same summary, CSV bytes and PNG bytes as reading the
recording whole, on a recording with several segments, faults, skipped periods, NaNs and a target
column, from an NPZ, its journal and a CSV cut into chunks many ways; compared with a whole-array
computation written here, and with the report as it was before it read in chunks (loaded from git,
where git can show it); and the peak memory of a report does not grow with the recording's length."""

from __future__ import annotations

import json
import math
import textwrap
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from _recordings import Cut, every_kind, module_at, peak_rss_kib, write_archive
from hilbench.bench import segments as segmentation
from hilbench.bench.chunk_quantiles import spread
from hilbench.bench.column_chunks import recording_chunks
from hilbench.bench.csv_export import export_csv_chunks
from hilbench.bench.display import envelope
from hilbench.bench.recorder import COLUMNS, MARKER_FAULT, MARKER_SKIPPED, read_recording
from hilbench.bench.recording_head import read_head
from hilbench.bench.report import summarise_chunks
from hilbench.plant.period import Period

#: main when report read the recording whole (tests/test_report_bounded.py was written against it)
WHOLE_READ_COMMIT = "9bc25df"
PERIOD_US = 1000
N_ROWS = 6000
NAN_ROW = 2600
SPECS = (*COLUMNS, ("iq_ref_q15", "q15", "%d"))  # one column of the target's own
NAMES = tuple(name for name, _, _ in SPECS)
#: (row, event): four holds (one after a ramp), a stop, a fault, a parameter change
EVENTS = ((0, segmentation.reference_event(0.0, 1000.0)), (500, "t=0.500000 set kp=0.1"),
          (1200, segmentation.reference_event(1.2, 2000.0, 0.2)), (2500, segmentation.reference_event(2.5, -1500.0)),
          (3000, "t=3.000000 fault overcurrent"), (3600, segmentation.press_event(3.6)),
          (4000, segmentation.reference_event(4.0, 800.0)), (5200, segmentation.reference_event(5.2, 1200.0)))


def _signals() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(5)
    t = np.arange(N_ROWS) * (PERIOD_US * 1e-6)
    c = {name: np.zeros(N_ROWS) for name in NAMES}
    ref = np.zeros(N_ROWS)
    for start_s, value in ((0.0, 1000.0), (1.2, 2000.0), (2.5, -1500.0), (3.6, 0.0), (4.0, 800.0), (5.2, 1200.0)):
        ref[t >= start_s] = value
    speed = np.zeros(N_ROWS)
    for k in range(1, N_ROWS):
        speed[k] = speed[k - 1] + (ref[k] - speed[k - 1]) * 0.02
    speed += rng.normal(0.0, 3.0, N_ROWS)
    w = 2 * math.pi * 40
    hall_cycle = np.array([1, 3, 2, 6, 4, 5])
    hall = hall_cycle[(np.arange(N_ROWS) // 7) % 6].astype(float)
    hall[[100, 2001, 2002, 4500]] = [0, 7, 7, 0]  # invalid codes
    sector = ((np.arange(N_ROWS) // 7) % 6).astype(float)
    sector[[300, 3333]] = [3, 7]  # out of sequence
    c.update(t_s=t, seq=np.arange(N_ROWS) % 256.0, hall=hall, sector=sector, speed_rpm=speed,
             measured_speed_rpm=np.round(speed * 0.999, 1), ref_speed_rpm=ref,
             ia_a=np.round(2.0 * np.sin(w * t), 3), ib_a=np.round(2.0 * np.sin(w * t - 2.0944), 3),
             ic_a=np.round(2.0 * np.sin(w * t + 2.0944), 3), ibus_a=0.5 * np.cos(3 * t),
             duty_a=rng.integers(0, 1000, N_ROWS).astype(float), duty_b=rng.integers(0, 1000, N_ROWS).astype(float),
             rtt_us=np.round(rng.gamma(4.0, 30.0, N_ROWS), 1), lateness_us=np.round(rng.normal(2.0, 20.0, N_ROWS), 1),
             iq_ref_q15=np.round(1000 * np.sin(t)))
    c["measured_speed_rpm"][1500:1510] = np.nan
    c["ibus_a"][2500] = np.nan
    c["marker"][[3000, 3001, 5000]] = MARKER_FAULT
    c["marker"][[700, 701, 702, 4100]] = MARKER_SKIPPED
    c["rtt_us"][[700, 701, 702, 4100]] = 0.0
    c["lateness_us"][[700, 701]] = [2500.0, 1500.0]
    return c


def _recordings(tmp_path: Path) -> list[Path]:
    """The signals as an NPZ, the journal of a run killed before its close, and a CSV."""
    columns = _signals()
    metadata = {"period_us": PERIOD_US, "mode": "realtime", "target": "synthetic", "seed": 3,
                "target_hello": {"firmware_name": "SYNTH"}}

    def columns_for(name: str) -> dict[str, np.ndarray]:
        # a %d column with a NaN: the export writes it as %.6g (a CSV run cannot write it at all)
        columns["control_output_q15"][NAN_ROW] = np.nan if name.endswith(".npz") else 0.0
        return columns

    return every_kind(tmp_path, columns_for, specs=SPECS, metadata=metadata, events=dict(EVENTS))


def _expected_summary(path: Path) -> dict[str, object]:
    """The summary from the whole arrays, computed here with NumPy (np.max, np.percentile) and the
    segments replayed over the whole columns."""
    data = read_recording(path)
    c, meta = data.columns, data.metadata
    t = c["t_s"]
    period_s = Period(PERIOD_US).s
    segments = segmentation.replay(data.events, t, c["speed_rpm"], c["measured_speed_rpm"], period_s, 20,
                                   (round(float(t[-1]) / period_s) + 1) * period_s)
    skipped = c["marker"] == MARKER_SKIPPED

    def text(values: np.ndarray) -> str:
        p50, p99 = np.percentile(values, [50, 99])
        return f"p50 {p50:.1f}, p99 {p99:.1f}, max {np.max(values):.1f}"

    timed = [(float(e[2:].split(" ", 1)[0]), e.split(" ", 1)[1]) for e in data.events if e.startswith("t=")]
    return {
        "file": str(data.path), "rows": N_ROWS, "time_s": f"{t[0]:.6f} .. {t[-1]:.6f}",
        "target": "SYNTH via synthetic", "mode": "realtime", "period_us": PERIOD_US, "seed": 3,
        "ended": _expected_end(path, meta, data.events, float(t[-1])),
        "fault_rows": [int(c["seq"][i]) for i in np.flatnonzero(c["marker"] == MARKER_FAULT)],
        "max_speed_rpm": round(float(np.max(np.abs(c["speed_rpm"]))), 2),
        "max_phase_current_a": round(float(np.max(np.abs(np.stack([c["ia_a"], c["ib_a"], c["ic_a"]])))), 4),
        "max_bus_current_a": round(float(np.max(np.abs(c["ibus_a"]))), 4),
        "lateness_us": text(c["lateness_us"]), "rtt_us": text(c["rtt_us"][~skipped]),
        "skipped_periods": int(np.sum(skipped)),
        "segments": [f"{round(s.t_start_s, 4):.2f}-{round(s.t_end_s, 4):.2f} s: ref {s.ref_rpm:+.0f} rpm, "
                     f"plant {round(s.plant_rpm, 2):+.1f}, firmware {round(s.measured_rpm, 2):+.1f}, "
                     f"error {round(s.error_pct, 3):+.2f} %" for s in segments],
        "events": [f"{when:.4f} s {what}" for when, what in timed],
    }


def _expected_end(path: Path, meta: dict[str, object], events: tuple[str, ...], t_last_s: float) -> str:
    if path.suffix == ".journal":  # killed: no end note
        return f"cut short (no end note: killed or truncated) after t={t_last_s:.6f} s, {N_ROWS} rows"
    if path.suffix == ".npz":
        return str(meta["end"])
    return next(e for e in reversed(events) if e.startswith("end:"))  # a CSV's header was written at its start


def test_the_summary_read_in_chunks_is_the_whole_array_summary_at_every_cut(tmp_path: Path) -> None:
    for path in _recordings(tmp_path):
        source = recording_chunks(path)
        expected = json.dumps(_expected_summary(Path(source.where)), default=str)
        assert "NaN" in expected or "nan" in expected  # the NaN bus current ran
        head = read_head(source)
        for rows in (7, 333, 997, 4096, 10 * N_ROWS):
            got = json.dumps(summarise_chunks(head, Cut(source, rows)), default=str)
            assert got == expected, (path.name, rows)
    assert len(json.loads(expected)["segments"]) == 5


def test_the_csv_export_is_the_same_bytes_at_every_cut_and_the_rows_a_csv_run_writes(tmp_path: Path) -> None:
    npz, journal, csv = _recordings(tmp_path)
    source = recording_chunks(npz)
    head = read_head(source)
    whole = export_csv_chunks(head, Cut(source, 10 * N_ROWS), tmp_path / "whole.csv").read_bytes()
    for rows in (1, 333, 4096):
        assert export_csv_chunks(head, Cut(source, rows), tmp_path / f"cut{rows}.csv").read_bytes() == whole
    assert export_csv_chunks(read_head(recording_chunks(journal)), recording_chunks(journal),
                             tmp_path / "journal.csv").read_text().splitlines()[1:] != []

    def rows(text: str) -> list[str]:
        return [line for line in text.splitlines() if not line.startswith("#")]

    exported, written = rows(whole.decode()), rows(csv.read_text())
    assert len(exported) == len(written) == N_ROWS + 1
    assert [k for k, (a, b) in enumerate(zip(exported, written)) if a != b] == [1 + NAN_ROW]  # as a CSV run wrote them
    assert ",nan," in exported[1 + NAN_ROW]  # but the NaN in a %d column, written as %.6g


def test_decimation_from_chunks_is_the_envelope_of_the_whole_trace() -> None:
    from hilbench.ui.plot_data import MAX_POINTS, TraceBuilder

    rng = np.random.default_rng(2)
    for n in (10, 2 * MAX_POINTS, 2 * MAX_POINTS + 1, 12345):
        t, y = np.arange(n) * 1e-4, rng.normal(size=n)
        y[n // 3] = np.nan
        bucket = 1 if n <= 2 * MAX_POINTS else -(-n // MAX_POINTS)
        for cut in (1, 77, 4096, n):
            builder = TraceBuilder(n)
            for first in range(0, n, cut):
                builder.add(t[first:first + cut], y[first:first + cut])
            trace = builder.trace()
            if bucket == 1:
                assert trace.hi is None and np.array_equal(trace.lo, y, equal_nan=True)
            else:
                lo, hi = envelope(y, bucket)
                assert np.array_equal(trace.t_s, t[::bucket])
                assert np.array_equal(trace.lo, lo, equal_nan=True) and np.array_equal(trace.hi, hi, equal_nan=True)


def test_percentiles_by_radix_selection_are_numpys() -> None:
    rng = np.random.default_rng(9)
    for trial in range(60):
        n = int(rng.integers(1, 2000))
        values = [rng.normal(0, 100, n), np.round(rng.normal(0, 3, n)), -rng.exponential(5, n),
                  np.where(rng.random(n) < 0.5, -0.0, 2.5)][trial % 4]
        cut = int(rng.integers(1, 300))
        got = spread(lambda: (values[i:i + cut] for i in range(0, n, cut)), (50, 99, 0, 100, 37.5))
        want = np.percentile(values, [50, 99, 0, 100, 37.5])
        assert list(got.percentiles) == want.tolist() and got.max_value == np.max(values)  # -0.0 == 0.0


def test_the_plots_read_in_chunks_are_the_same_png_bytes_at_every_cut(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    from hilbench.ui.plots import plot_recording_chunks, plot_speed_overlay_chunks

    path = _recordings(tmp_path)[0]
    source = recording_chunks(path)
    head = read_head(source)
    for window in (None, (1.0, 1.5)):  # decimated, every row (and the halls as steps)
        whole = plot_recording_chunks(head, Cut(source, 10 * N_ROWS), tmp_path / "whole", window=window)
        cut = plot_recording_chunks(head, Cut(source, 333), tmp_path / "cut", window=window)
        assert [p.read_bytes() for p in cut] == [p.read_bytes() for p in whole], window
    names = {p.name for p in plot_recording_chunks(head, source, tmp_path / "n")}
    assert names == {f"run_{x}.png" for x in ("speed", "telemetry", "currents", "duties", "hall", "link")}
    (cut,) = plot_speed_overlay_chunks([(head, Cut(source, 333)), (head, source)], tmp_path / "o1")
    (whole,) = plot_speed_overlay_chunks([(head, source), (head, source)], tmp_path / "o2")
    assert cut.read_bytes() == whole.read_bytes()


def _whole_read_module(tmp_path: Path, module_path: str) -> ModuleType | None:
    """``module_path`` as it was when report read the recording whole; None where git cannot show it."""
    return module_at(WHOLE_READ_COMMIT, module_path, tmp_path)


def test_the_report_is_what_it_was_when_it_read_the_recording_whole(tmp_path: Path) -> None:
    """The summary, the CSV bytes and the PNG bytes of the report before it read in chunks."""
    report = _whole_read_module(tmp_path, "hilbench/bench/report.py")
    recorder = _whole_read_module(tmp_path, "hilbench/bench/recorder.py")
    if report is None or recorder is None:
        pytest.skip(f"git cannot show {WHOLE_READ_COMMIT} here (the whole-array comparison above still ran)")
    for path in _recordings(tmp_path):
        data = read_recording(path)
        source = recording_chunks(path)
        head = read_head(source)
        assert json.dumps(summarise_chunks(head, Cut(source, 333)), default=str) == \
            json.dumps(report.summarise(data), default=str), path.name
        old = recorder.export_csv(recorder.read_recording(path), tmp_path / "old.csv").read_bytes()
        assert export_csv_chunks(head, Cut(source, 333), tmp_path / "new.csv").read_bytes() == old, path.name
    pytest.importorskip("matplotlib")
    plots = _whole_read_module(tmp_path, "hilbench/ui/plots.py")
    assert plots is not None
    from hilbench.ui.plots import plot_recording_chunks, plot_speed_overlay_chunks

    data = read_recording(tmp_path / "run.npz")
    source = recording_chunks(tmp_path / "run.npz")
    head = read_head(source)
    for window in (None, (1.0, 1.5)):
        old_pngs = plots.plot_recording(data, tmp_path / "old", window=window)
        new_pngs = plot_recording_chunks(head, Cut(source, 333), tmp_path / "new", window=window)
        assert [p.name for p in new_pngs] == [p.name for p in old_pngs]
        for old_png, new_png in zip(old_pngs, new_pngs):
            assert new_png.read_bytes() == old_png.read_bytes(), (window, new_png.name)
    window = (1.0, 1.5)  # the overlay was drawn point by point: the same where it is not decimated
    old_overlay = plots.plot_speed_overlay([data, data], tmp_path / "old", window=window)
    (new_overlay,) = plot_speed_overlay_chunks([(head, Cut(source, 333)), (head, source)], tmp_path / "new", window)
    assert new_overlay.read_bytes() == old_overlay.read_bytes()


_CHILD = textwrap.dedent("""
    import resource, sys
    from pathlib import Path
    from hilbench.bench.column_chunks import recording_chunks
    from hilbench.bench.csv_export import export_csv_chunks
    from hilbench.bench.recording_head import read_head
    from hilbench.bench.report import summarise_chunks

    path, out = sys.argv[1], Path(sys.argv[2])
    source = recording_chunks(path)
    head = read_head(source)
    info = summarise_chunks(head, source)
    assert info["skipped_periods"] > 0 and len(info["segments"]) == 2, info
    export_csv_chunks(head, source, out / "export.csv")
    try:
        from hilbench.ui.plots import plot_recording_chunks
    except ImportError:
        pass
    else:
        assert len(plot_recording_chunks(head, source, out / "plots")) >= 4
    print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
""")

_LONG = ("t_s", "seq", "marker", "speed_rpm", "ref_speed_rpm", "ia_a", "ib_a", "ic_a", "ibus_a", "hall", "sector",
         "duty_a", "duty_b", "duty_c", "rtt_us", "lateness_us")


def _long_recording(path: Path, n_rows: int) -> Path:
    """``n_rows`` periods at 20 kHz of a real-time run with two holds, written a chunk at a time."""
    def chunk(k: np.ndarray) -> dict[str, np.ndarray]:
        t = k * 5e-5
        phase = 2 * np.pi * 50 * t
        return {"t_s": t, "seq": (k % 256).astype(float), "marker": np.where(k % 1000 == 7, MARKER_SKIPPED, 0.0),
                "speed_rpm": 1000.0 * (1 - np.exp(-t / 0.1)), "ref_speed_rpm": np.full(len(k), 1000.0),
                "ia_a": np.sin(phase), "ib_a": np.sin(phase - 2.0944), "ic_a": np.sin(phase + 2.0944),
                "ibus_a": 0.3 * np.cos(phase), "hall": np.array([1, 3, 2, 6, 4, 5.0])[(k // 67) % 6],
                "sector": ((k // 67) % 6).astype(float), "duty_a": (k * 31 % 1000).astype(float),
                "duty_b": (k * 37 % 1000).astype(float), "duty_c": (k * 41 % 1000).astype(float),
                "rtt_us": 50.0 + (k * 7919 % 1000) / 10.0, "lateness_us": (k * 104729 % 2000) / 10.0 - 50.0}

    events = [segmentation.reference_event(0.0, 1000.0), segmentation.reference_event(n_rows * 2.5e-5, 1200.0)]
    return write_archive(path, _LONG, n_rows, chunk,
                         {"period_us": 50, "mode": "realtime", "events": events, "end": "end: completed"})


def _peak_kib(path: Path, out: Path) -> int:
    out.mkdir()
    return peak_rss_kib(_CHILD, str(path), str(out))


def test_a_report_of_a_recording_ten_times_longer_takes_no_more_memory(tmp_path: Path) -> None:
    """200 000 and 2 000 000 rows (10 s and 100 s at 20 kHz; 16 columns, 256 MB): summary with its
    percentiles and segments, the CSV export and the plots. Read whole they held every column
    (256 MB) and more; in chunks the peak moves by less than 16 MB."""
    short, long = tmp_path / "short.npz", tmp_path / "long.npz"
    _long_recording(short, 200_000)
    _long_recording(long, 2_000_000)
    grew_kib = _peak_kib(long, tmp_path / "long") - _peak_kib(short, tmp_path / "short")
    assert grew_kib < 16 * 1024, f"peak RSS grew by {grew_kib / 1024:.1f} MB for 10x the rows"


def _whole_frame(path: Path, columns: list[str], max_buckets: int) -> dict[str, object]:
    """The scope's frame of a recording computed here from its whole arrays: min/max envelopes of
    buckets of ceil(rows / max_buckets) rows, the hall bits from the hall codes."""
    from hilbench.bench.display import b64_f32

    c = read_recording(path).columns
    t = c["t_s"]
    bucket = max(1, -(-len(t) // max_buckets))
    cols = {}
    for name in columns:
        bit = {"hall_a": 0, "hall_b": 1, "hall_c": 2}.get(name)
        values = c[name] if name in c else (c["hall"].astype(np.int64) >> bit) & 1 if bit is not None else None
        if values is not None:
            lo, hi = envelope(np.asarray(values, dtype=np.float64), bucket)
            cols[name] = [b64_f32(lo), b64_f32(hi)]
    return {"seq": 1, "t0": float(t[0]), "dt": bucket * float(np.median(np.diff(t[:1000]))),
            "n": -(-len(t) // bucket), "cols": cols}


def test_report_open_sends_the_frames_of_the_whole_arrays_read_in_chunks(tmp_path: Path) -> None:
    """`report --open`'s source (the scope's RecordingSource) read a chunk at a time: the frames the
    whole arrays give, every row (6000 <= MAX_BUCKETS) and in buckets of 9 and 13 rows."""
    pytest.importorskip("aiohttp", reason="the scope extra (aiohttp) is not installed")
    from hilbench.scope.server import RecordingSource

    columns = ["speed_rpm", "ibus_a", "hall_b", "hall_c", "measured_speed_rpm", "nope", "iq_ref_q15", "t_s"]
    for path in _recordings(tmp_path):
        source = RecordingSource(path)
        for max_buckets in (RecordingSource.MAX_BUCKETS, 700, 462):
            source.MAX_BUCKETS = max_buckets
            assert source.frame(columns) == _whole_frame(Path(source.source.where), columns, max_buckets), \
                (path.name, max_buckets)
        assert source.n_rows == N_ROWS and len(source.markers()) == len([e for e in EVENTS if e[1].startswith("t=")])


_OPEN_CHILD = textwrap.dedent("""
    import resource, sys
    from hilbench.scope.server import RecordingSource

    source = RecordingSource(sys.argv[1])
    frame = source.frame([name for name, _ in source._names()])
    assert frame["n"] == RecordingSource.MAX_BUCKETS and len(frame["cols"]) == 19, frame["n"]
    print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
""")


def test_report_open_of_a_recording_ten_times_longer_takes_no_more_memory(tmp_path: Path) -> None:
    """200 000 and 2 000 000 rows (16 columns, 256 MB): the scope's source of `report --open` read
    every column whole (the peak grew by ~250 MB); in chunks it moves by less than 16 MB."""
    pytest.importorskip("aiohttp", reason="the scope extra (aiohttp) is not installed")
    short, long = tmp_path / "short.npz", tmp_path / "long.npz"
    _long_recording(short, 200_000)
    _long_recording(long, 2_000_000)
    grew_kib = peak_rss_kib(_OPEN_CHILD, str(long)) - peak_rss_kib(_OPEN_CHILD, str(short))
    assert grew_kib < 16 * 1024, f"peak RSS grew by {grew_kib / 1024:.1f} MB for 10x the rows"


def test_a_recording_full_of_faults_names_the_first_fault_rows_and_counts_the_rest(tmp_path: Path) -> None:
    """50 000 periods, every one a fault: the report listed 50 000 fault rows (a list as long as the
    recording); now the first MAX_FAULT_ROWS by their seq, and how many more there are."""
    from conftest import run_cli
    from hilbench.bench.report import MAX_FAULT_ROWS

    n_rows = 50_000
    names = ("t_s", "seq", "marker", "speed_rpm")
    path = write_archive(tmp_path / "faults.npz", names, n_rows, lambda k: {
        "t_s": k * 5e-5, "seq": (k % 256).astype(float), "marker": np.full(len(k), float(MARKER_FAULT)),
        "speed_rpm": np.zeros(len(k))}, {"period_us": 50}, chunk_rows=4096)
    source = recording_chunks(path)
    info = summarise_chunks(read_head(source), Cut(source, 333))
    assert info["fault_rows"] == [k % 256 for k in range(MAX_FAULT_ROWS)]
    assert info["fault_rows_left_out"] == n_rows - MAX_FAULT_ROWS
    done = run_cli("report", str(path))
    assert done.returncode == 0 and "fault rows left out" in done.stdout and str(n_rows - MAX_FAULT_ROWS) in done.stdout
    few = summarise_chunks(read_head(recording_chunks(_recordings(tmp_path)[0])), recording_chunks(tmp_path / "run.npz"))
    assert "fault_rows_left_out" not in few and len(few["fault_rows"]) == 3
