"""Issue 23: `hilbench report` on damaged recordings is one line and exit 6, never a traceback.
Each repro of the issue runs as the real command (memory capped)."""

from __future__ import annotations

import json
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest

import hilbench
from _hostile import assert_one_line_error, hilbench as run_hilbench
from hilbench.bench.recorder import read_recording
from hilbench.errors import RecordingError


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A short run recorded as CSV and as NPZ (in process)."""
    folder = tmp_path_factory.mktemp("rec")
    out = {}
    for suffix in ("csv", "npz"):
        path = folder / f"run.{suffix}"
        with hilbench.Bench(target="inprocess:an1017", record=path) as bench:
            bench.set_reference(1000)
            bench.press("s2")
            bench.run(0.02)
        out[suffix] = path
    return out


def _npz_arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as archive:
        return {name: archive[name] for name in archive.files}


def _save(path: Path, arrays: dict[str, np.ndarray]) -> Path:
    np.savez(path, **arrays)  # type: ignore[arg-type]
    return path


@pytest.mark.parametrize("value, shown", [(np.nan, "nan"), (np.inf, "inf")])
def test_t_s_nan_or_inf(recorded: dict[str, Path], tmp_path: Path, value: float, shown: str) -> None:
    """Repro: a recording whose t_s is NaN (ValueError) or Inf (OverflowError)."""
    arrays = _npz_arrays(recorded["npz"])
    arrays["t_s"] = arrays["t_s"].copy()
    arrays["t_s"][5] = value
    path = _save(tmp_path / "bad.npz", arrays)
    result = run_hilbench("report", str(path), "--json")
    assert_one_line_error(result, 6, "bad.npz", f"t_s is {shown} at row 5")


def test_a_string_column(recorded: dict[str, Path], tmp_path: Path) -> None:
    arrays = _npz_arrays(recorded["npz"])
    arrays["speed_rpm"] = arrays["speed_rpm"].astype(str)
    path = _save(tmp_path / "text.npz", arrays)
    assert_one_line_error(run_hilbench("report", str(path)), 6, "text.npz", "column speed_rpm holds", "not numbers")


def test_garbled_csv_metadata(recorded: dict[str, Path], tmp_path: Path) -> None:
    """Repro: garbled `#` metadata lines in a CSV (a hello that is no table, a period that is text)."""
    text = recorded["csv"].read_text()
    for line, words in (('# target_hello: [1, 2]\n', ("metadata target_hello", "not a table")),
                        ('# period_us: "fifty"\n', ("metadata period_us", "not a positive number")),
                        ('# history_every_periods: 0\n', ("metadata history_every_periods",))):
        path = tmp_path / "garbled.csv"
        path.write_text(text + line)  # a later line of a key wins
        assert_one_line_error(run_hilbench("report", str(path)), 6, "garbled.csv", *words)


def test_a_short_column_with_plot(recorded: dict[str, Path], tmp_path: Path) -> None:
    """Repro: a column shorter than the others, with --plot."""
    arrays = _npz_arrays(recorded["npz"])
    arrays["ia_a"] = arrays["ia_a"][:-3]
    path = _save(tmp_path / "short.npz", arrays)
    result = run_hilbench("report", str(path), "--plot", str(tmp_path / "plots"))
    assert_one_line_error(result, 6, "short.npz", "column ia_a has 397 rows, t_s has 400")


def test_a_header_that_promises_more_than_the_member_holds(recorded: dict[str, Path], tmp_path: Path) -> None:
    """np.load allocates what an array's header says: a member claiming 10**12 values is refused
    before NumPy reads it."""
    path = tmp_path / "liar.npz"
    with zipfile.ZipFile(recorded["npz"]) as src, zipfile.ZipFile(path, "w") as dst:
        for info in src.infolist():
            data = src.read(info)
            if info.filename == "ia_a.npy":
                data = data.replace(b"(400,)", b"(10**12,)".replace(b"10**12", b"1000000000000"), 1)
            dst.writestr(info, data)
    result = run_hilbench("report", str(path))
    assert_one_line_error(result, 6, "liar.npz", "member ia_a.npy promises 1000000000000 values")


def test_a_journal_header_beyond_its_limit(recorded: dict[str, Path], tmp_path: Path) -> None:
    path = tmp_path / "run.npz.journal"
    path.write_bytes(b"HBJ2" + struct.pack("<I", 2**32 - 1) + b"{}")
    with pytest.raises(RecordingError, match="a header of 4294967295 bytes, more than the limit of 16 MiB"):
        read_recording(path)


def test_t_s_that_goes_back(recorded: dict[str, Path], tmp_path: Path) -> None:
    arrays = _npz_arrays(recorded["npz"])
    arrays["t_s"] = arrays["t_s"].copy()
    arrays["t_s"][10] = 0.0
    with pytest.raises(RecordingError, match="t_s does not increase at row 10"):
        read_recording(_save(tmp_path / "back.npz", arrays))


def test_a_segment_event_with_an_infinite_time(recorded: dict[str, Path], tmp_path: Path) -> None:
    arrays = _npz_arrays(recorded["npz"])
    meta = json.loads(str(arrays["metadata"]))
    meta["events"] = ["segment: ref at inf ref 1000.0 ramp 0.0"]
    arrays["metadata"] = np.asarray(json.dumps(meta))
    with pytest.raises(RecordingError, match="event 0: segment event .* not finite"):
        read_recording(_save(tmp_path / "inf.npz", arrays))


def test_a_csv_row_beyond_the_line_limit(recorded: dict[str, Path], tmp_path: Path) -> None:
    path = tmp_path / "long.csv"
    path.write_text(recorded["csv"].read_text() + "1" * 70_000 + "\n")
    with pytest.raises(RecordingError, match="longer than 65536 characters"):
        read_recording(path)


def test_the_recordings_read_back_whole(recorded: dict[str, Path]) -> None:
    """The checks take nothing away from a good recording: both formats read the same rows."""
    a, b = read_recording(recorded["csv"]), read_recording(recorded["npz"])
    assert a.n_rows == b.n_rows == 400
    np.testing.assert_allclose(a.columns["speed_rpm"], b.columns["speed_rpm"], atol=1e-3)


def test_a_damaged_row_in_the_middle_of_a_csv_is_refused_not_cut(recorded: dict[str, Path], tmp_path: Path) -> None:
    """Only the last row may be cut (a crash while writing it): a row that lost a value with rows
    after it used to end the reading there, silently dropping every later row."""
    whole = recorded["csv"].read_text().splitlines(keepends=True)
    rows = [n for n, line in enumerate(whole) if line[:1].isdigit() or line[:1] == "-"]
    middle = rows[len(rows) // 2]
    lines = list(whole)
    lines[middle] = lines[middle].rsplit(",", 1)[0] + "\n"
    damaged = tmp_path / "damaged.csv"
    damaged.write_text("".join(lines))
    assert_one_line_error(run_hilbench("report", str(damaged)), 6, "damaged.csv", f"line {middle + 1}:", "rows follow")
    torn = tmp_path / "torn.csv"  # a crash's cut: the last row without its end, every earlier row stands
    torn.write_text("".join(whole[:rows[-1]]) + whole[rows[-1]][:7])
    assert read_recording(torn).n_rows == len(rows) - 1


@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_a_fault_row_whose_seq_is_not_a_number(recorded: dict[str, Path], tmp_path: Path, value: float) -> None:
    """Repro: `report` on a recording whose fault row has seq NaN (or infinity) ended in a traceback
    (ValueError/OverflowError converting it to the fault row's number); seq and marker are whole
    numbers in every row the recorder writes."""
    from hilbench.bench.recorder import MARKER_FAULT

    arrays = _npz_arrays(recorded["npz"])
    arrays["marker"][50] = MARKER_FAULT
    arrays["seq"][50] = value
    path = _save(tmp_path / "seq.npz", arrays)
    assert_one_line_error(run_hilbench("report", str(path)), 6, "seq.npz", f"seq is {value} at row 50")


def test_a_segment_event_beyond_any_period(recorded: dict[str, Path], tmp_path: Path) -> None:
    """Repro (a seeded fuzz of report's inputs): a `segment:` event at 1e308 s (finite, so the event
    check let it by) ended `report` in an OverflowError traceback rounding its period index."""
    arrays = _npz_arrays(recorded["npz"])
    metadata = json.loads(str(arrays["metadata"]))
    metadata["events"] = ["segment: ref at 1e308 ref 2000.0 ramp 0.0", *metadata.get("events", [])]
    arrays["metadata"] = np.asarray(json.dumps(metadata))
    path = _save(tmp_path / "far.npz", arrays)
    result = run_hilbench("report", str(path), "--json")
    assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr[-2000:]
    assert json.loads(result.stdout)["rows"] == read_recording(recorded["npz"]).n_rows


# --- reading side, round 2: files that are not files, exports onto their source, deep JSON, bad
# journal layouts, non-finite summaries and messages that named Python's exceptions


def _journal(path: Path, layout: object, n_rows: int = 0, head: bytes | None = None) -> Path:
    """A journal as a killed NPZ run leaves it: magic, header length, JSON header, float64 rows."""
    from hilbench.bench.recorder import COLUMNS, float_layout

    if head is None:
        head = json.dumps({"layout": layout, "metadata": {}}).encode()
    rows = np.zeros((n_rows, len(COLUMNS)))
    rows[:, 0] = np.arange(n_rows) * 5e-5  # t_s: increasing
    assert float_layout(COLUMNS).column_names[0] == "t_s"
    path.write_bytes(b"HBJ2" + struct.pack("<I", len(head)) + head + rows.astype("<f8").tobytes())
    return path


def _layout_json() -> dict:
    from hilbench.bench.recorder import COLUMNS, float_layout

    return json.loads(json.dumps(float_layout(COLUMNS).as_json()))


@pytest.mark.parametrize("kind", ["device.npz", "fifo.csv", "fifo.npz"])
def test_a_recording_that_is_not_a_regular_file(tmp_path: Path, kind: str) -> None:
    """Repro: `report` of a symlink to /dev/zero grew without end (zipfile read it all), of a FIFO
    hung in its open: refused before it is opened."""
    import os

    path = tmp_path / kind
    if kind.startswith("device"):
        path.symlink_to("/dev/zero")
    else:
        os.mkfifo(path)
    result = run_hilbench("report", str(path), timeout_s=60)
    assert_one_line_error(result, 6, kind, "not a regular file")


def test_a_csv_export_into_a_fifo_with_no_reader(recorded: dict[str, Path], tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """Repro: `report run.npz --csv fifo` hung in open() for ever when nothing read the FIFO."""
    import os

    from hilbench.bench import fileio
    from hilbench.bench.column_chunks import recording_chunks
    from hilbench.bench.csv_export import export_csv_chunks
    from hilbench.bench.recording_head import read_head

    monkeypatch.setattr(fileio, "FIFO_READER_WAIT_S", 0.0)  # (the wait for a reader a moment behind)
    fifo = tmp_path / "out.csv"
    os.mkfifo(fifo)
    source = recording_chunks(recorded["npz"])
    with pytest.raises(RecordingError, match="out.csv: cannot write .*FIFO with no reader"):
        export_csv_chunks(read_head(source), source, fifo)


def test_an_export_onto_the_recording_it_reads(recorded: dict[str, Path], tmp_path: Path) -> None:
    """Repro: `report y.csv --csv y.csv` cut the recording to its header and exited 0. The same file
    by another name (a symlink) and a journal that an NPZ export would write over are refused too."""
    copy = tmp_path / "y.csv"
    copy.write_bytes(recorded["csv"].read_bytes())
    (tmp_path / "link.csv").symlink_to(copy)
    for target in (copy, tmp_path / "link.csv"):
        result = run_hilbench("report", str(copy), "--csv", str(target))
        assert_one_line_error(result, 6, target.name, "would overwrite", "y.csv")
        assert copy.read_bytes() == recorded["csv"].read_bytes()
    journal = _journal(tmp_path / "run.npz.journal", _layout_json(), n_rows=20)
    before = journal.read_bytes()
    result = run_hilbench("report", str(journal), "--csv", str(tmp_path / "run.npz"))
    assert_one_line_error(result, 6, "run.npz", "would overwrite", "run.npz.journal")
    assert journal.read_bytes() == before


def test_deeply_nested_metadata_or_journal_header(recorded: dict[str, Path], tmp_path: Path) -> None:
    """Repro: metadata (or a journal's header) of 100000 nested lists ended in a RecursionError traceback."""
    deep = "[" * 100_000 + "]" * 100_000
    arrays = _npz_arrays(recorded["npz"])
    arrays["metadata"] = np.asarray(deep)
    npz = _save(tmp_path / "deep.npz", arrays)
    assert_one_line_error(run_hilbench("report", str(npz)), 6, "deep.npz", "metadata nests too deeply")
    journal = _journal(tmp_path / "deep.npz.journal", None, head=deep.encode())
    assert_one_line_error(run_hilbench("report", str(journal)), 6, "deep.npz.journal", "header nests too deeply")
    for path in (npz, journal):
        with pytest.raises(RecordingError, match="nests too deeply"):
            read_recording(path)


@pytest.mark.parametrize("key, value, words", [
    ("wrap", None, "layout wrap is null"),
    ("wrap", -1, "layout wrap is -1"),
    ("wrap", [1], "layout wrap 0 is 1"),
    ("columns", None, "layout columns is null"),
    ("columns", 7, "layout columns is 7"),
    ("columns", "scale", "layout column \"speed_rpm\" has scale null"),
    ("columns", "empty", "layout column 3 is []"),
])
def test_a_journal_with_a_malformed_layout(tmp_path: Path, key: str, value: object, words: str) -> None:
    """Repro: a journal header whose layout.wrap or layout.columns had the wrong shape (or a column
    a null scale) ended in a TypeError traceback in RowLayout.from_json."""
    from hilbench.bench.column_chunks import recording_chunks

    layout = _layout_json()
    if value == "scale":
        next(c for c in layout["columns"] if c[0] == "speed_rpm")[4] = None
    elif value == "empty":
        layout["columns"][3] = []
    else:
        layout[key] = value
    path = _journal(tmp_path / "bad.npz.journal", layout, n_rows=5)
    for read in (read_recording, recording_chunks):
        with pytest.raises(RecordingError) as caught:
            read(path)
        assert str(caught.value).startswith(f"recording {path}: header: {words}"), str(caught.value)
    assert_one_line_error(run_hilbench("report", str(path)), 6, "bad.npz.journal", words)


def test_report_json_of_an_infinite_column_is_valid_json(recorded: dict[str, Path], tmp_path: Path) -> None:
    """Repro: `report --json` of a recording with an infinite speed printed `Infinity` (no JSON
    parser takes it). `json_safe` makes the summary valid JSON: a number that is not finite is the
    string "inf", "-inf" or "nan". (The dump itself is the CLI's: it has to call json_safe.)"""
    from hilbench.bench.column_chunks import recording_chunks
    from hilbench.bench.recording_head import read_head
    from hilbench.bench.report import json_safe, summarise_chunks

    arrays = _npz_arrays(recorded["npz"])
    arrays["speed_rpm"] = np.full_like(arrays["speed_rpm"], np.inf)
    arrays["ia_a"] = np.full_like(arrays["ia_a"], np.nan)
    source = recording_chunks(_save(tmp_path / "inf.npz", arrays))
    info = json_safe(summarise_chunks(read_head(source), source))
    text = json.dumps(info, allow_nan=False, default=str)  # (ValueError for a NaN or infinity left)
    assert (json.loads(text)["max_speed_rpm"], json.loads(text)["max_phase_current_a"]) == ("inf", "nan")
    assert json_safe({"a": [float("-inf"), 1.5, (2.0,)]}) == {"a": ["-inf", 1.5, [2.0]]}


def test_messages_name_the_place_not_the_python_exception(recorded: dict[str, Path], tmp_path: Path) -> None:
    """Repro: a text cell said `could not convert string to float: 'abc'` (no line), a journal
    column without its fields `not enough values to unpack`, a damaged NPZ member header
    `Cannot parse header: ...`."""
    lines = recorded["csv"].read_text().splitlines(keepends=True)
    row = next(n for n, line in enumerate(lines) if line[:1].isdigit())
    header = next(line for line in lines if not line.startswith("#"))
    column = header.split(",")[2].split("[")[0]
    cells = lines[row + 3].split(",")
    cells[2] = "abc"
    lines[row + 3] = ",".join(cells)
    text = tmp_path / "text.csv"
    text.write_text("".join(lines))
    assert_one_line_error(run_hilbench("report", str(text)), 6, "text.csv", f"line {row + 4}: column {column}: "
                          '"abc" is not a number')

    layout = _layout_json()
    layout["columns"][5] = ["speed_rpm"]
    journal = _journal(tmp_path / "cut.npz.journal", layout)
    line = assert_one_line_error(run_hilbench("report", str(journal)), 6, "cut.npz.journal", "layout column 5 is")
    assert "unpack" not in line

    path = tmp_path / "member.npz"
    with zipfile.ZipFile(recorded["npz"]) as src, zipfile.ZipFile(path, "w") as dst:
        for info in src.infolist():
            data = src.read(info)
            if info.filename == "ia_a.npy":
                data = data.replace(b"'shape': (400,)", b"'shape': (4\xdf0,)", 1)
            dst.writestr(info, data)
    line = assert_one_line_error(run_hilbench("report", str(path)), 6, "member.npz",
                                 "member ia_a.npy has no valid NumPy array header")
    assert "Cannot parse" not in line
