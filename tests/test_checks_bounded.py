"""[[check]] tables judged a chunk of rows at a time: the same verdicts as the whole-array evaluation
(`run_checks` before it read in chunks, loaded from git) on one recording with several segments and
every run kind, read from an NPZ, its journal and a CSV and cut into chunks of 1 row and more; and
the peak memory of judging a recording does not grow with its length."""

from __future__ import annotations

import json
import math
import textwrap
from pathlib import Path
from types import ModuleType
from typing import Sequence

import numpy as np
import pytest

from _recordings import Cut, every_kind, module_at, peak_rss_kib, write_archive
from hilbench.bench.checks import CheckEntry, CheckResult, run_checks
from hilbench.bench.column_chunks import ColumnChunks, recording_chunks
from hilbench.bench.npzwriter import ColumnArchive
from hilbench.bench.recorder import COLUMN_NAMES, read_recording
from hilbench.bench.summary import Segment, Summary

#: main when the checks began to read in chunks: its run_checks evaluated whole arrays
WHOLE_ARRAY_COMMIT = "fe6a6bf"
DT_S = 1e-3
N_ROWS = 4000
SEGMENTS = (  # (from_s, to_s, ref_rpm): settles, never settles, always within, leaves at its last row
    (0.0, 0.8, 1000.0), (0.8, 1.6, 2000.0), (1.6, 2.2, -1500.0), (2.2, 3.0, 500.0), (3.0, 4.0, 800.0))


def _signals() -> dict[str, np.ndarray]:
    """4 s at 1 kHz over five held references, with exact ties, a NaN current and two faults."""
    t = np.arange(N_ROWS) * DT_S
    columns = {name: np.zeros(N_ROWS) for name in COLUMN_NAMES}
    speed = np.zeros(N_ROWS)
    for start, end, ref in SEGMENTS:
        rows = (t >= start) & (t < end)
        speed[rows] = ref * (1.0 - np.exp(-(t[rows] - start) / 0.05))
        columns["ref_speed_rpm"][rows] = ref
    rows = (t >= 0.8) & (t < 1.6)
    speed[rows] = np.minimum(2000.0 + 400.0 * np.sin(2 * math.pi * 7 * t[rows]), 2300.0)  # ties at 2300
    speed[(t >= 1.6) & (t < 2.2)] = -1500.0
    speed[(t >= 2.2) & (t < 3.0)] = 500.0
    speed[np.flatnonzero(t < 3.0)[-1]] = 700.0  # outside the band at the segment's last row only
    w = 2 * math.pi * 50
    columns.update(t_s=t, seq=np.arange(N_ROWS) % 256.0, speed_rpm=speed, measured_speed_rpm=speed * 0.999,
                   ia_a=np.round(2.0 * np.sin(w * t), 3), ib_a=np.round(2.0 * np.sin(w * t - 2 * math.pi / 3), 3),
                   ic_a=np.round(2.0 * np.sin(w * t + 2 * math.pi / 3), 3), ibus_a=0.5 * np.cos(3 * t),
                   load_nm=0.01 * t)
    columns["ib_a"][3500] = np.nan
    columns["ibus_a"][2500] = np.nan
    columns["fault"][3000:3010] = 3.0
    columns["fault"][3800] = 5.0
    columns["marker"][3000] = 3.0
    return columns


def _summary() -> Summary:
    summary = Summary("synthetic", "lockstep", 1000, periods=N_ROWS, sim_s=N_ROWS * DT_S, overruns=2)
    summary.firmware = "AN1017"
    summary.segments = [Segment(a, b, ref, plant_rpm=ref * 1.004, measured_rpm=ref) for a, b, ref in SEGMENTS]
    return summary


ENTRIES = (
    CheckEntry(kind="speed_error", max_pct=2.0),
    CheckEntry(kind="speed_error", max_pct=0.1, segment=3),
    CheckEntry(kind="settling_time", max_s=0.3),
    CheckEntry(kind="settling_time", max_s=0.3, segment=1),
    CheckEntry(kind="settling_time", max_s=0.3, segment=3),
    CheckEntry(kind="settling_time", max_s=0.5, band_pct=1.0, segment=1),
    CheckEntry(kind="settling_time", max_s=0.5, band_pct=30.0, segment=2),
    CheckEntry(kind="settling_time", max_s=0.5, segment=4),
    CheckEntry(kind="settling_time", max_s=0.5, segment=9),
    CheckEntry(kind="settling_time", max_s=0.5, min_hold_s=10.0),
    CheckEntry(kind="peak_current", max_a=2.5),
    CheckEntry(kind="peak_current", max_a=1.5, to_s=3.0),
    CheckEntry(kind="peak_current", max_a=1.5, from_s=0.5, to_s=0.55),
    CheckEntry(kind="peak_current", max_a=1.5, from_s=100.0),
    CheckEntry(kind="speed_limit", max_rpm=2200.0),
    CheckEntry(kind="speed_limit", max_rpm=2500.0, from_s=1.7),
    CheckEntry(kind="signal", signal="ibus_a", max=0.4),
    CheckEntry(kind="signal", signal="ibus_a", min=-0.45, max=0.45, to_s=2.4),
    CheckEntry(kind="signal", signal="load_nm", min=0.001),
    CheckEntry(kind="signal", signal="speed_rpm", min=-1600.0, max=2400.0),
    CheckEntry(kind="signal", signal="nope", max=1.0),
    CheckEntry(kind="no_fault"),
    CheckEntry(kind="no_fault", to_s=2.9),
    CheckEntry(kind="no_fault", from_s=3.5),
    CheckEntry(kind="overruns", max=0),
    CheckEntry(kind="peak_current", max_a=1.0, firmware="OTHER"),
)


def _recordings(tmp_path: Path) -> list[Path]:
    """The signals as an NPZ, as the journal of a run killed before its close, and as a CSV."""
    columns = _signals()
    return every_kind(tmp_path, lambda name: columns)


def _whole_array_checks(tmp_path: Path) -> ModuleType | None:
    """hilbench/bench/checks.py as it was before it read in chunks (its judges take whole arrays); None
    where git cannot show it (a shallow clone, an unpacked sdist)."""
    return module_at(WHOLE_ARRAY_COMMIT, "hilbench/bench/checks.py", tmp_path)


def _dicts(results: Sequence[CheckResult]) -> list[dict[str, object]]:
    return [{k: ("nan" if isinstance(v, float) and math.isnan(v) else v) for k, v in r.as_dict().items()}
            for r in results]


def test_chunked_verdicts_equal_the_whole_array_ones_on_every_kind_and_every_cut(tmp_path: Path) -> None:
    """Every cut gives the verdicts of one chunk holding the whole recording, and those are the
    verdicts of the checks as they were before they read in chunks (where git can show that code)."""
    before = _whole_array_checks(tmp_path)
    summary = _summary()
    for path in _recordings(tmp_path):
        whole = read_recording(path).columns
        expected = _dicts(run_checks(ENTRIES, summary, lambda: Cut(recording_chunks(path), 10 * N_ROWS)))
        if before is not None:
            assert _dicts(before.run_checks(ENTRIES, summary, lambda: whole)) == expected, path.name
        assert len(expected) == len(ENTRIES)
        for rows in (1, 7, 333, 997, N_ROWS):
            got = _dicts(run_checks(ENTRIES, summary, lambda: Cut(recording_chunks(path), rows)))
            assert got == expected, (path.name, rows)
        in_memory = _dicts(run_checks(ENTRIES, summary, lambda: whole))  # rows kept in memory: views of them
        assert in_memory == expected
    figures = {r["name"] + str(i): r["figure"] for i, r in enumerate(expected)}
    assert "never (outside the band" in json.dumps(figures) and "nan" in json.dumps(figures)  # the delicate cases ran


def test_a_column_the_run_cannot_have_says_skip_as_before(tmp_path: Path) -> None:
    before = _whole_array_checks(tmp_path)
    if before is None:
        pytest.skip("git cannot show the checks before chunking (a shallow clone or an sdist)")
    columns = _signals()
    for name in ("ia_a", "ib_a", "ic_a", "speed_rpm"):
        del columns[name]
    absent = {"ia_a": "no plant", "speed_rpm": "no plant"}
    entries = ENTRIES[2:3] + ENTRIES[10:11] + ENTRIES[14:15] + ENTRIES[21:22]
    assert _dicts(run_checks(entries, _summary(), lambda: columns, absent=absent)) == \
        _dicts(before.run_checks(entries, _summary(), lambda: columns, absent=absent))


def _back(path: Path) -> Path:
    """The signals with t_s going back at row 1500 (no run writes that: straight into the archive)."""
    columns = _signals()
    columns["t_s"][1500] = columns["t_s"][1499]
    return write_archive(path, COLUMN_NAMES, N_ROWS, lambda k: {name: columns[name][k] for name in COLUMN_NAMES}, {})


def test_a_damaged_recording_read_in_chunks_is_one_recording_error(tmp_path: Path) -> None:
    """t_s that goes back across a chunk's cut is refused as read_recording refuses it, by its row."""
    from hilbench.errors import RecordingError

    path = _back(tmp_path / "back.npz")
    with pytest.raises(RecordingError) as whole:
        read_recording(path)
    with pytest.raises(RecordingError) as chunked:
        for _ in recording_chunks(path).chunks(["speed_rpm"], 1500):
            pass
    assert str(chunked.value) == str(whole.value) and "row 1500" in str(whole.value)


_CHILD = textwrap.dedent("""
    import resource, sys
    from hilbench.bench.checks import CheckEntry, run_checks
    from hilbench.bench.column_chunks import recording_chunks
    from hilbench.bench.summary import Segment, Summary

    path, n_rows = sys.argv[1], int(sys.argv[2])
    summary = Summary("long", "lockstep", 50, periods=n_rows, sim_s=n_rows * 5e-5)
    summary.segments = [Segment(0.0, n_rows * 5e-5, 1000.0, plant_rpm=1000.0)]
    entries = [CheckEntry(kind="settling_time", max_s=1.0), CheckEntry(kind="peak_current", max_a=2.0),
               CheckEntry(kind="speed_limit", max_rpm=3500.0), CheckEntry(kind="signal", signal="ia_a", max=3.0),
               CheckEntry(kind="no_fault")]
    results = run_checks(entries, summary, lambda: recording_chunks(path))
    assert all(r.passed for r in results), [r.line() for r in results]
    print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
""")


def _long_recording(path: Path, n_rows: int) -> Path:
    """``n_rows`` periods at 20 kHz of the columns the checks read, written a chunk at a time."""
    def chunk(k: np.ndarray) -> dict[str, np.ndarray]:
        t = k * 5e-5
        phase = 2 * np.pi * 50 * t
        return {"t_s": t, "speed_rpm": 1000.0 * (1 - np.exp(-t / 0.1)), "ia_a": np.sin(phase),
                "ib_a": np.sin(phase - 2.0944), "ic_a": np.sin(phase + 2.0944),
                "fault": np.zeros_like(t), "marker": np.zeros_like(t)}

    return write_archive(path, ["t_s", "speed_rpm", "ia_a", "ib_a", "ic_a", "fault", "marker"], n_rows, chunk,
                         {"period_us": 50})


def _peak_kib(path: Path, n_rows: int) -> int:
    return peak_rss_kib(_CHILD, str(path), str(n_rows), timeout_s=120)


def test_judging_a_recording_ten_times_longer_takes_no_more_memory(tmp_path: Path) -> None:
    """300 000 and 3 000 000 rows (15 s and 150 s at 20 kHz; 7 columns, 168 MB): the whole-array
    evaluation held 5 of them (120 MB) and copies; read in chunks the peak moves by less than
    16 MB (a chunk is 0.5 MB a column)."""
    short, long = tmp_path / "short.npz", tmp_path / "long.npz"
    _long_recording(short, 300_000)
    _long_recording(long, 3_000_000)
    grew_kib = _peak_kib(long, 3_000_000) - _peak_kib(short, 300_000)
    assert grew_kib < 16 * 1024, f"peak RSS grew by {grew_kib / 1024:.1f} MB for 10x the rows"


def test_a_monitor_run_judges_the_measured_speed_as_speed_rpm_in_chunks(tmp_path: Path) -> None:
    """Monitor mode: the firmware's measured speed stands for speed_rpm (AliasChunks), read in chunks,
    as the whole-array checks judged a copy of the columns with speed_rpm replaced."""
    from hilbench.bench.column_chunks import AliasChunks

    before = _whole_array_checks(tmp_path)
    if before is None:
        pytest.skip("git cannot show the checks before chunking (a shallow clone or an sdist)")
    path = _recordings(tmp_path)[0]
    whole = dict(read_recording(path).columns)
    whole["speed_rpm"] = whole.pop("measured_speed_rpm")
    entries = ENTRIES[2:10] + ENTRIES[14:16]
    source = recording_chunks(path)
    got = run_checks(entries, _summary(), lambda: AliasChunks(Cut(source, 333), {"speed_rpm": "measured_speed_rpm"}))
    assert _dicts(got) == _dicts(before.run_checks(entries, _summary(), lambda: whole))


def _huge_npz(path: Path) -> str:
    """An NPZ whose two columns hold 1.1e9 rows each (17.6 GB, over RECORDING_MAX_BYTES): a sparse
    file, its rows never written, its headers whole. "" made, else why not."""
    n_rows = 1_100_000_000
    try:
        archive = ColumnArchive(path, ["t_s", "marker"], n_rows)
        archive.written(n_rows, [0, 0])  # the rows are holes: nothing reads them before the bound refuses the file
        archive.add("metadata", np.asarray(json.dumps({"period_us": 50})))
        archive.close()
    except OSError as exc:  # a file system without sparse files this large
        return f"cannot make a sparse 17.6 GB file in {path.parent}: {exc.strerror or exc}"
    return ""


def test_a_recording_the_checks_cannot_read_fails_them_as_a_recording_error_not_a_skip(tmp_path: Path) -> None:
    """A damaged header, a file over the reader's bound, a file gone, rows damaged on the way: every
    check that reads the rows FAILs naming the file and why, and raise_if_failed raises that one line
    as a RecordingError (exit code 6). They said SKIP "no rows were kept" (no_fault: PASS)."""
    from hilbench.bench.checks import raise_if_failed
    from hilbench.errors import RecordingError

    (tmp_path / "header.csv").write_text("t_s[s],garbage\x00\n0.0,1\n")
    (tmp_path / "header.npz").write_bytes(b"PK\x03\x04" + b"\x00" * 60)
    _back(tmp_path / "back.npz")
    cases = {"header.csv": "not a hilbench CSV", "header.npz": "unreadable", "gone.npz": "no such file",
             "huge.npz": "more than the limit of 16 GiB", "back.npz": "row 1500"}
    if _huge_npz(tmp_path / "huge.npz"):
        del cases["huge.npz"]  # (the other cases still run)
    reading = ENTRIES[2:3] + ENTRIES[10:11] + ENTRIES[16:17] + ENTRIES[21:22]  # settling, peak, signal, no_fault
    for name, why in cases.items():
        path = tmp_path / name
        results = run_checks(ENTRIES[:1] + reading, _summary(), lambda: recording_chunks(path))
        assert results[0].passed and not results[0].unreadable  # speed_error: judged on the summary alone
        for result in results[1:]:
            assert not result.passed and not result.skipped and result.unreadable, (name, result.line())
            assert result.line().startswith(f"check {result.name}: FAIL cannot be judged: recording {path}")
            assert why in result.figure, (name, result.figure)
        with pytest.raises(RecordingError) as raised:
            raise_if_failed(results)
        message = str(raised.value)
        assert raised.value.exit_code == 6 and "\n" not in message and str(path) in message and why in message


def test_a_run_that_recorded_nothing_still_says_skip(tmp_path: Path) -> None:
    """No --record: the signals source says so with a HilbenchError that is not a RecordingError."""
    from hilbench.bench.checks import raise_if_failed
    from hilbench.errors import ConfigError

    def nothing() -> ColumnChunks:
        raise ConfigError("Bench: nothing recorded yet")

    results = run_checks(ENTRIES[2:3] + ENTRIES[10:11] + ENTRIES[16:17], _summary(), nothing)
    assert all(r.passed and r.skipped and not r.unreadable and "no rows were kept" in r.figure for r in results)
    raise_if_failed(results)
