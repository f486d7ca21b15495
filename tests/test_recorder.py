"""Recordings: every row kept, readable after a crash, identical for identical runs."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path
from typing import TextIO

import numpy as np
import pytest

from hilbench.bench import recorder as recorder_module
from hilbench.bench.recorder import (
    COLUMN_NAMES,
    COLUMNS,
    MARKER_EVENT,
    MARKER_FAULT,
    N_COLUMNS,
    MemoryRecorder,
    Recorder,
    RowLayout,
    read_recording,
)
from hilbench.errors import RecordingError


def _row(k: int) -> tuple[float, ...]:
    values = [0.0] * N_COLUMNS
    values[0] = k * 50e-6
    values[1] = k
    values[5] = 100.0 + k
    return tuple(values)


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_round_trip_keeps_every_row_and_event(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"run{suffix}"
    rec = Recorder(path, {"seed": 3, "target": "x"}, flush_rows=7)
    for k in range(20):
        if k == 5:
            rec.event("set kp=0.2")
        rec.append(_row(k))
        rec.maybe_flush()
    rec.close("end: completed")
    data = read_recording(path)
    assert data.n_rows == 20
    assert list(data.columns["seq"]) == list(range(20))
    assert data.columns["speed_rpm"][19] == pytest.approx(119.0)
    assert data.metadata["seed"] == 3
    assert "set kp=0.2" in data.events
    assert data.events[-1] == "end: completed"


def test_csv_header_carries_units_and_loads_with_numpy(tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    rec = Recorder(path, {"seed": 1})
    rec.append(_row(1))
    rec.event("press s2")
    rec.append(_row(2))
    rec.close()
    text = path.read_text()
    assert "t_s[s]" in text and "speed_rpm[rpm]" in text and "ia_a[A]" in text
    lines = [ln for ln in text.splitlines() if not ln.startswith("#")][1:]
    table = np.loadtxt(lines, delimiter=",", ndmin=2)
    assert table.shape == (2, N_COLUMNS)


def test_killed_writer_leaves_a_readable_recording(tmp_path: Path) -> None:
    """kill -9 mid-run: the rows flushed before it are readable (CSV and NPZ journal)."""
    script = f"""
import os, signal
from hilbench.bench.recorder import Recorder, N_COLUMNS
for suffix in ('.csv', '.npz'):
    rec = Recorder({str(tmp_path)!r} + '/run' + suffix, {{'seed': 1}}, flush_rows=100)
    for k in range(250):
        if k == 50:
            rec.event('press s2')
        rec.append(tuple([float(k)] * N_COLUMNS))
        rec.maybe_flush()
os.kill(os.getpid(), signal.SIGKILL)
"""
    proc = subprocess.run([sys.executable, "-c", script], timeout=60)
    assert proc.returncode == -9
    for name in ("run.csv", "run.npz"):
        data = read_recording(tmp_path / name)
        assert data.n_rows == 200  # two full chunks flushed, the third lost
        assert list(data.columns["seq"][:3]) == [0.0, 1.0, 2.0]
        assert data.events == ("press s2",)  # events flushed with their chunk survive too


def test_npz_is_byte_identical_for_identical_rows(tmp_path: Path) -> None:
    blobs = []
    for i in range(2):
        path = tmp_path / f"r{i}.npz"
        rec = Recorder(path, {"seed": 9})
        for k in range(50):
            rec.append(_row(k))
        rec.close("end")
        blobs.append(path.read_bytes())
    assert blobs[0] == blobs[1]


def test_fault_marker_on_last_row(tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    rec = Recorder(path, {})
    rec.append(_row(0))
    rec.append(_row(1))
    rec.mark_last(MARKER_FAULT)
    rec.close("fault at period 1: link gone")
    data = read_recording(path)
    assert data.columns["marker"][-1] == MARKER_FAULT
    assert data.events[-1].startswith("fault")


def test_unreadable_recordings_raise_recording_error(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="no such file"):
        read_recording(tmp_path / "missing.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("hello,world\n1,2\n")
    with pytest.raises(RecordingError, match="not a hilbench CSV"):
        read_recording(bad)
    with pytest.raises(RecordingError, match="unknown format"):
        Recorder(tmp_path / "x.txt", {})
    assert COLUMN_NAMES[0] == "t_s"


def _raw_layout() -> RowLayout:
    """A layout like the session's: integers kept as integers, columns made by scaling."""
    fields = (("k", "Q"), ("speed_raw", "i"), ("amps", "d"), ("marker", "B"))
    sources = {"t_s": ("k", 50e-6), "seq": ("k", 1.0), "speed_rpm": ("speed_raw", 0.5),
               "measured_speed_rpm": ("speed_raw", float("nan")), "ia_a": ("amps", 1.0), "marker": ("marker", 1.0)}
    return RowLayout(fields, tuple((name, unit, fmt, *sources.get(name, ("k", 0.0))) for name, unit, fmt in COLUMNS))


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_raw_layout_rows_become_scaled_columns_with_event_markers(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"run{suffix}"
    rec = Recorder(path, {"seed": 2}, flush_rows=4)
    rec.start(_raw_layout())
    for k in range(10):
        if k == 6:
            rec.event("press s2", MARKER_EVENT)
        rec.rows.append((k, 2 * k, 0.25 * k, 0))
        rec.maybe_flush()
    rec.close("end")
    data = read_recording(path)
    assert data.n_rows == 10
    assert data.columns["t_s"][3] == pytest.approx(3 * 50e-6)
    assert list(data.columns["speed_rpm"]) == [float(k) for k in range(10)]  # 2k x 0.5
    assert np.isnan(data.columns["measured_speed_rpm"]).all()  # a quantity the target does not report
    assert data.columns["ia_a"][9] == 2.25
    assert list(np.flatnonzero(data.columns["marker"])) == [6]
    assert data.columns["marker"][6] == MARKER_EVENT


def test_journal_with_a_torn_row_reads_every_whole_row(tmp_path: Path) -> None:
    path = tmp_path / "run.npz"
    rec = Recorder(path, {}, flush_rows=3)
    rec.start(_raw_layout())
    for k in range(6):
        rec.rows.append((k, k, 0.0, 0))
        rec.maybe_flush()
    journal = tmp_path / "run.npz.journal"
    with open(journal, "ab") as handle:  # a crash in the middle of a write
        handle.write(b"\x07" * 5)
    data = read_recording(path)
    assert list(data.columns["seq"]) == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]


def test_a_layout_set_after_rows_were_appended_is_refused(tmp_path: Path) -> None:
    rec = Recorder(tmp_path / "run.npz", {})
    rec.append(_row(0))
    with pytest.raises(RecordingError, match="before the layout"):
        rec.start(_raw_layout())


@pytest.mark.parametrize("wrap", [(("theta", 0.0),), (("theta", -360.0),), (("theta", float("nan")),),
                                  (("theta", float("inf")),), (("theta", 360.0), ("theta", 180.0))])
def test_a_layout_refuses_a_wrap_two_conversions_would_read_otherwise(wrap: tuple[tuple[str, float], ...]) -> None:
    """A wrap's modulo must be positive and finite, and a column wrapped once: numpy.mod by 0 or a
    negative modulo, or a column wrapped twice (to_column applies every entry, the archive's C
    writer one), gave the journal's and the background archive's columns two readings."""
    base = _raw_layout()
    fields = (*base.fields, ("angle", "d"))
    columns = (*base.columns, ("theta", "deg", "%.3f", "angle", 1.0))
    RowLayout(fields, columns, wrap=(("theta", 360.0),))  # the reference: fine
    with pytest.raises(ValueError, match="positive, finite modulo and one entry a column"):
        RowLayout(fields, columns, wrap=wrap)


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_a_fault_marker_wins_over_an_event_on_the_same_row(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"run{suffix}"
    rec = Recorder(path, {})
    rec.start(_raw_layout())
    rec.rows.append((0, 0, 0.0, 0))
    rec.event("ref 1500 rpm", MARKER_EVENT)
    rec.rows.append((1, 0, 0.0, 0))
    rec.mark_last(MARKER_FAULT)  # the last good period, which also had an event
    rec.close("fault at period 1")
    assert list(read_recording(path).columns["marker"]) == [0.0, MARKER_FAULT]


def test_an_event_keeps_the_marker_a_row_already_has(tmp_path: Path) -> None:
    """A real-time period the host skipped stays marked as skipped when an event also falls on it."""
    from hilbench.bench.recorder import MARKER_SKIPPED

    rec = MemoryRecorder()
    rec.start(_raw_layout())
    rec.event("press s2", MARKER_EVENT)
    rec.rows.append((0, 0, 0.0, MARKER_SKIPPED))
    rec.event("press s3", MARKER_EVENT)
    rec.rows.append((1, 0, 0.0, 0))
    assert list(rec.columns()["marker"]) == [MARKER_SKIPPED, MARKER_EVENT]


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_a_half_appended_row_is_dropped_not_fatal(tmp_path: Path, suffix: str) -> None:
    """An interrupt between a row's two appends (session fields, then the plant's) leaves a torn row."""
    path = tmp_path / f"run{suffix}"
    rec = Recorder(path, {})
    rec.start(_raw_layout())
    for k in range(3):
        rec.rows.append((k, k, 0.5, 0))
    rec.rows.extend(b"\x05\x00\x00\x00")  # the first part of row 3 only
    rec.mark_last(MARKER_FAULT)
    rec.close("interrupted at period 3")
    data = read_recording(path)
    assert list(data.columns["seq"]) == [0.0, 1.0, 2.0]
    assert data.columns["marker"][-1] == MARKER_FAULT


def test_columns_do_not_pin_the_row_buffer() -> None:
    rec = MemoryRecorder()
    rec.start(_raw_layout())
    rec.rows.append((0, 2, 0.0, 0))
    columns = rec.columns()  # kept alive, as an interrupted flush's frame would keep them
    rec.rows.clear()  # a view into the bytearray would make this raise BufferError
    rec.rows.append((1, 4, 0.0, 0))
    assert columns["speed_rpm"][0] == 1.0


def test_a_new_npz_run_does_not_inherit_a_killed_runs_events(tmp_path: Path) -> None:
    path = tmp_path / "run.npz"
    (tmp_path / "run.npz.journal.events").write_text("old run's event\n")  # left by a killed run
    rec = Recorder(path, {}, flush_rows=1)
    rec.start(_raw_layout())
    rec.event("new run's event")
    rec.rows.append((0, 0, 0.0, 0))
    rec.flush()  # then killed: the journal is what remains
    assert read_recording(path).events == ("new run's event",)


@pytest.mark.skipif(signal.getsignal(signal.SIGINT) is not signal.default_int_handler,
                    reason="SIGINT does not raise KeyboardInterrupt in this process (started with it ignored)")
def test_a_ctrl_c_as_an_npz_events_write_returns_leaves_each_event_once(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A SIGINT that lands just after the journal's side file took a flush's events: its
    KeyboardInterrupt comes once they are noted as written, so the next flush does not append them
    again (a run killed after it left them twice in its journal)."""
    path = tmp_path / "run.npz"
    rec = Recorder(path, {}, flush_rows=1000)
    rec.start(_raw_layout())
    real = Recorder._write_events_file

    def write_then_signal(self: Recorder, text: str) -> None:
        real(self, text)
        os.kill(os.getpid(), signal.SIGINT)  # (handled at the next bytecode, unless held)

    monkeypatch.setattr(Recorder, "_write_events_file", write_then_signal)
    rec.event("press s2")
    rec.rows.append((0, 0, 0.0, 0))
    with pytest.raises(KeyboardInterrupt):
        rec.flush()
    monkeypatch.undo()
    rec.flush()  # (as the close's flush would) then killed: the journal is what remains
    assert read_recording(path).events == ("press s2",)
    rec.close("end: interrupted")
    assert read_recording(path).events == ("press s2", "end: interrupted")


def test_wrapped_columns_stay_below_their_modulo() -> None:
    base = _raw_layout()
    layout = RowLayout(base.fields, tuple((*c[:3], "amps", 1.0) if c[0] == "theta_e_deg" else c
                                          for c in base.columns),
                       wrap=(("theta_e_deg", 360.0),))
    rec = MemoryRecorder()
    rec.start(layout)
    for amps in (359.5, 360.0, 0.25):
        rec.rows.append((0, 0, amps, 0))
    assert list(rec.columns()["theta_e_deg"]) == [359.5, 0.0, 0.25]
    assert RowLayout.from_json(layout.as_json()) == layout


def test_closed_memory_recorder_reads_its_rows_in_place_and_lets_them_grow_after(monkeypatch: pytest.MonkeyPatch) -> None:
    """A closed MemoryRecorder's columns are read from its buffer without a copy first (an open
    one's from a copy), as equal values of their own; no view outlives the call, even one that
    raised (the buffer can still grow and shrink: a live view would make that a BufferError)."""
    recorder = MemoryRecorder()
    recorder.start()
    for k in range(50):
        recorder.append([float(k + c) for c in range(N_COLUMNS)])
    read_from: list[bytes | bytearray] = []
    layout_rows = RowLayout._rows

    def noting_rows(self: RowLayout, raw: bytes | bytearray | np.ndarray) -> np.ndarray:
        if not isinstance(raw, np.ndarray):  # the buffers it reads (not the views made of them)
            read_from.append(raw)
        return layout_rows(self, raw)

    monkeypatch.setattr(RowLayout, "_rows", noting_rows)
    copied = recorder.columns()
    recorder.close()
    in_place = recorder.columns()
    assert type(read_from[0]) is bytes and read_from[1] is recorder.rows.data  # a copy while open, in place once closed
    read_from.clear()
    assert set(in_place) == set(copied)
    for name, values in copied.items():
        np.testing.assert_array_equal(in_place[name], values)
        assert not np.shares_memory(in_place[name], np.frombuffer(recorder.rows.data, dtype=np.uint8))
    with pytest.raises(KeyError) as raised:
        recorder.columns(("no_such_column",))
    recorder.rows.append([0.0] * N_COLUMNS)  # grows while the error's traceback is held: no view is left
    assert raised.tb is not None
    del recorder.rows.data[:]
    assert len(recorder.rows) == 0


class _ChunkWriteFails:
    """A CSV file whose writes after the header raise ``error`` once the text is written (``written``
    True: where CPython raises a Ctrl-C, as the write returns) or before (False: a write's own error)."""

    def __init__(self, file: TextIO, error: BaseException, written: bool) -> None:
        self.file, self.error, self.written = file, error, written

    def write(self, text: str) -> int:
        if self.written:
            self.file.write(text)
        raise self.error

    def __getattr__(self, name: str) -> object:
        return getattr(self.file, name)


def _reference_csv(path: Path, monkeypatch: pytest.MonkeyPatch, error: BaseException, written: bool) -> Recorder:
    """A started reference-path CSV recorder (no C row writer) with 5 rows pending, its next write
    failing with ``error``."""
    monkeypatch.setattr(recorder_module, "_csvrows", None)
    rec = Recorder(path, {}, flush_rows=1000)
    rec.start()
    assert rec._csv_writer is None
    rec._file = _ChunkWriteFails(rec._file, error, written)  # type: ignore[assignment]
    for k in range(5):
        rec.append(_row(k))
    return rec


def test_a_full_disk_on_the_reference_csv_path_is_one_clear_error_and_counts_no_row(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    rec = _reference_csv(tmp_path / "run.csv", monkeypatch, OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)), False)
    with pytest.raises(RecordingError, match=r"run\.csv: write failed \(No space left on device\)$"):
        rec.flush()
    assert rec.rows_written == 0


def test_a_ctrl_c_as_the_reference_csv_write_returns_counts_the_rows_only_on_a_regular_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A regular file's write runs to its end before the signal's exception: its rows are in the file.
    A FIFO's can stop part-way, so nothing is counted there (the close writes the chunk again)."""
    rec = _reference_csv(tmp_path / "run.csv", monkeypatch, KeyboardInterrupt(), True)
    with pytest.raises(KeyboardInterrupt):
        rec.flush()
    assert rec.rows_written == 5

    fifo = tmp_path / "fifo.csv"
    os.mkfifo(fifo)
    drained = bytearray()

    def drain() -> None:
        with open(fifo, "rb") as reader:
            while chunk := reader.read(65536):
                drained.extend(chunk)

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    piped = _reference_csv(fifo, monkeypatch, KeyboardInterrupt(), True)
    assert not piped._csv_regular
    with pytest.raises(KeyboardInterrupt):
        piped.flush()
    assert piped.rows_written == 0
    piped._file = piped._file.file  # type: ignore[attr-defined]
    piped._file.close()
    reader.join(timeout=30)
    assert not reader.is_alive() and drained.startswith(b"t_s[s],seq,")


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_a_flush_of_events_alone_keeps_the_marker_waiting_for_its_row(tmp_path: Path, suffix: str) -> None:
    """A fault noted with no row pending is written at once and its marker goes on the next row; a
    later flush with only unmarked events in it (a note, a live write) does not drop that marker."""
    path = tmp_path / f"run{suffix}"
    rec = Recorder(path, {}, flush_rows=1000)
    rec.append(_row(0))
    rec.flush()
    rec.event("fault: overcurrent", MARKER_FAULT)
    rec.flush()  # the event written before its row came
    rec.event("set kp=0.2")
    rec.flush()  # events alone
    rec.append(_row(1))
    rec.close("end: completed")
    markers = read_recording(path).columns["marker"]
    assert markers.tolist() == [0, MARKER_FAULT]


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_a_second_recorder_on_a_path_being_recorded_is_refused_and_cuts_nothing(tmp_path: Path, suffix: str) -> None:
    """Two sessions recording to one path: the second is refused before it truncates the first's
    file (it cut the first's journal and left a recording of both)."""
    path = tmp_path / f"same{suffix}"
    first = Recorder(path, {}, flush_rows=7)
    for k in range(20):
        first.append(_row(k))
        first.maybe_flush()
    with pytest.raises(RecordingError, match=rf"same\{suffix}: cannot write \(another process is writing it"):
        Recorder(path, {})
    for k in range(20, 30):
        first.append(_row(k))
    first.close()
    assert list(read_recording(path).columns["seq"]) == list(range(30))
    again = Recorder(path, {})  # closed: free again
    again.close()


def test_a_save_onto_a_recording_being_written_is_refused(tmp_path: Path) -> None:
    from hilbench.bench.tuning import write_fragment

    path = tmp_path / "rec.csv"
    rec = Recorder(path, {})
    rec.append(_row(0))
    rec.flush()
    with pytest.raises(OSError) as refused:
        write_fragment(path, "[target]\nkp = 0.1\n")
    assert (refused.value.filename, refused.value.strerror) == (str(path), "another process is writing it: a running session's recording?")
    rec.close()
    assert read_recording(path).n_rows == 1
    write_fragment(tmp_path / "gains.toml", "[target]\nkp = 0.1\n")
    assert (tmp_path / "gains.toml").read_text() == "[target]\nkp = 0.1\n"


def test_a_save_onto_the_path_of_an_npz_recording_being_written_is_refused(tmp_path: Path) -> None:
    """The rows go to the journal until the end, when the archive takes the recording's name: a save
    there (written then replaced by the archive, or replacing it) is refused while the journal is held."""
    from hilbench.bench.tuning import write_fragment

    path = tmp_path / "run.npz"
    rec = Recorder(path, {}, flush_rows=4)
    for k in range(10):
        rec.append(_row(k))
        rec.maybe_flush()
    with pytest.raises(OSError) as refused:
        write_fragment(path, "[target]\nkp = 0.1\n")
    assert (refused.value.filename, refused.value.strerror) == (
        str(path), "another process is writing it: a running session's recording?")
    assert not path.exists()
    rec.close()
    assert read_recording(path).n_rows == 10
    write_fragment(tmp_path / "other.toml", "[target]\nkp = 0.1\n")  # a journal left by a killed run: not held
    killed = tmp_path / "gains.toml"
    (tmp_path / "gains.toml.journal").write_bytes(b"left")
    write_fragment(killed, "[target]\nkp = 0.1\n")
    assert killed.read_text() == "[target]\nkp = 0.1\n"


def test_a_save_in_the_control_poll_never_waits_for_a_fifo_reader(tmp_path: Path) -> None:
    """The session's own save (a raw control client's) answers at once: a FIFO with no reader is
    refused without FIFO_READER_WAIT_S's wait, which would hold every period of the run."""
    from hilbench.bench.control import COMMANDS, ControlRequest

    fifo = tmp_path / "gains.toml"
    os.mkfifo(fifo)
    replies: list[bytes] = []

    class _Session:
        profile = type("P", (), {"tunable": ("kp",)})()
        tuning = type("T", (), {"trips": []})()
        ref_rpm = 0.0

        def param_values(self) -> dict[str, float]:
            return {"kp": 0.1}

    request = ControlRequest("save", {"file": str(fifo)}, 0.0, _send=replies.append)
    COMMANDS["save"].act(_Session(), request, 0.0)  # type: ignore[arg-type]
    assert b'"ok":false' in replies[0] and b"a FIFO with no reader within 0 s" in replies[0]


def test_a_csv_recording_to_a_fifo_with_no_reader_is_refused_not_waited_for(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from hilbench.bench import fileio

    monkeypatch.setattr(fileio, "FIFO_READER_WAIT_S", 0.05)
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    with pytest.raises(RecordingError, match=r"pipe\.csv: cannot write \(a FIFO with no reader within 0\.05 s\)"):
        Recorder(fifo, {})


def test_an_npz_path_stays_held_until_its_archive_is_in_place(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A second session opening the path while the first writes its archive is refused (the
    journal's lock went with its early close: the second cut the journal and lost the first's rows)."""
    path = tmp_path / "a.npz"
    first = Recorder(path, {}, flush_rows=7)
    for k in range(30):
        first.append(_row(k))
        first.maybe_flush()
    real = Recorder._write_archive
    refused: list[str] = []

    def write_archive(self: Recorder, background: object) -> None:
        try:
            Recorder(path, {})
        except RecordingError as exc:
            refused.append(str(exc))
        real(self, background)

    monkeypatch.setattr(Recorder, "_write_archive", write_archive)
    first.close()
    assert refused and "another process is writing it" in refused[0]
    assert list(read_recording(path).columns["seq"]) == list(range(30))
