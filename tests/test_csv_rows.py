"""CSV rows in C (hilbench/bench/_csvrows.c) write, from a recording's raw rows, what the reference
writes from the float64 columns: Python's `fmt % row` (a NaN or an infinity in a whole-number
column as `%.0f` writes it); a recording's CSV is the same text with the writer's thread and with
the reference, events and markers included; a failed write is a RecordingError; a whole-number
column of NaN (a quantity the target does not report) reads back as NaN."""

from __future__ import annotations

import errno
import math
import os
import signal
from pathlib import Path

import numpy as np
import pytest

from _recordings import every_code_layout, hostile_rows
from hilbench.bench import recorder as recorder_module
from hilbench.bench.npzwriter import _field_offsets
from hilbench.bench.recorder import RowLayout, read_recording
from hilbench.errors import RecordingError

_csvrows = recorder_module._csvrows
pytestmark = [pytest.mark.skipif(_csvrows is None, reason="the CSV row writer is not built"),
              pytest.mark.filterwarnings("ignore::RuntimeWarning")]  # the reference's casts of hostile values

FORMATS = ["%d", "%.0f", "%.1f", "%.3f", "%.4f", "%.5f", "%.6f", "%.9f"]


def _edge_values() -> np.ndarray:
    """Ties at every precision, signed zeros, NaN and infinities, huge, tiny and subnormal values,
    values next to powers of two and ten, and a seeded spread."""
    special = [0.0, -0.0, 0.5, -0.5, 1.5, 2.5, -2.5, 0.125, 0.375, -0.625, 1e-7, -1e-7, 5e-7, 4.9999999e-7,
               0.05, 0.15, 0.25, 0.35, 1.0005, 2.675, 1e15, -1e15, 9.2e18 - 2048, 9.2e18, 2.0 ** 63, -(2.0 ** 63),
               2.0 ** 64, 1e19, 1e300, -1e300, 1.7976931348623157e308, -1.7976931348623157e308, 5e-324, -5e-324,
               2.2250738585072014e-308, 123456.7890125, 999.9995, 0.9999995, 9.5, 10.5, float("nan"), -float("nan"),
               float("inf"), -float("inf"), 1499.99999999, 2 ** 52 + 0.5, 2.0 ** 53, 99.5, -99.5, 1e9 - 0.5]
    rng = np.random.default_rng(7)
    spread = np.concatenate([rng.standard_normal(2000) * 10.0 ** rng.integers(-9, 22, 2000),
                             np.round(rng.standard_normal(2000) * 1e4, 7) + 5e-8,  # near the 7th digit's ties
                             np.arange(-1000, 1000) / 8.0])  # exact binary ties
    return np.concatenate([np.asarray(special), spread])


def _columns(layout: RowLayout) -> list[tuple[int, str, float, float, str]]:
    """The writer's column descriptions of a layout (as the recorder makes them)."""
    offsets, wraps = _field_offsets(layout), dict(layout.wrap)
    return [(*offsets[src], scale, wraps.get(name, 0.0), fmt) for name, _, fmt, src, scale in layout.columns]


def _reference(layout: RowLayout, raw: bytes) -> str:
    """The reference's text of raw rows: RowLayout.to_columns, then the recorder's line of each row."""
    columns = layout.to_columns(raw)
    formats = [fmt for _, _, fmt in layout.column_specs]
    fmt = ",".join(formats) + "\n"
    table = np.column_stack([columns[name] for name in layout.column_names])
    return "".join(recorder_module._csv_line(fmt, formats, row) for row in map(tuple, table.tolist()))


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_cell_is_what_percent_formatting_writes(fmt: str) -> None:
    values = _edge_values()
    layout = RowLayout((("x", "d"), ("marker", "B")), (("t_s", "s", fmt, "x", 1.0), ("marker", "", "%d", "marker", 1.0)))
    raw = np.zeros(len(values), dtype=layout.dtype)
    raw["x"] = values
    text = _csvrows.format_rows(raw.tobytes(), layout.dtype.itemsize, _columns(layout))
    cells = [line.split(",")[0] for line in text.splitlines()]
    expected = [fmt % x if math.isfinite(x) else "%.0f" % x for x in values.tolist()]  # `%d` refuses the others
    assert cells == expected
    assert text == _reference(layout, raw.tobytes())


def test_raw_rows_of_every_code_are_the_references_text() -> None:
    layout = every_code_layout()
    raw = hostile_rows(layout, 5000, seed=3)
    assert _csvrows.format_rows(raw, layout.dtype.itemsize, _columns(layout)) == _reference(layout, raw)


def test_formats_it_does_not_take_are_refused() -> None:
    layout = RowLayout((("x", "d"), ("marker", "B")), (("t_s", "s", "%.3f", "x", 1.0), ("marker", "", "%d", "marker", 1.0)))
    for fmt in ("%8.3f", "%+.2f", "%g", "%.2E", "%5d", "%.12f", "%.10f", "x", "%.3e"):
        columns = [(0, "d", 1.0, 0.0, fmt), (8, "B", 1.0, 0.0, "%d")]
        with pytest.raises(ValueError, match="format"):
            _csvrows.format_rows(b"", layout.dtype.itemsize, columns)
        assert recorder_module._csv_row_writer(1, RowLayout(layout.fields, (("t_s", "s", fmt, "x", 1.0),
                                                                              layout.columns[1]))) is None
    with pytest.raises(ValueError, match="a field d at 4 of a 9-byte row"):
        _csvrows.format_rows(b"", 9, [(4, "d", 1.0, 0.0, "%d")])


def _record(path: Path, layout: RowLayout, raw: bytes, *, flush_rows: int, mark_last: bool) -> None:
    """A recording of ``raw`` rows appended a few at a time (the session's `maybe_flush` after each
    few), with events at the start, between rows, on chunk edges and after the last row."""
    rec = recorder_module.Recorder(path, {"layout": "every code"}, flush_rows=flush_rows)
    rec.start(layout)
    size = layout.dtype.itemsize
    rec.event("at the start", recorder_module.MARKER_EVENT)
    for first in range(0, len(raw) // size, 37):
        rec.rows.extend(raw[first * size:(first + 37) * size])
        if first % 111 == 0:
            rec.event(f"note at {first} é", recorder_module.MARKER_EVENT)
            rec.event("a second one on the same row")
        rec.maybe_flush()
    if mark_last:
        rec.mark_last(recorder_module.MARKER_FAULT)
    rec.close("the end")


@pytest.mark.parametrize("n_rows,flush_rows,chunk,mark_last", [(0, 1000, 4096, False), (1, 1000, 4096, True),
                                                               (5000, 1000, 4096, False), (10_000, 100_000, 500, True),
                                                               (10_000, 3000, 370, True), (2000, 10, 4096, False)])
def test_a_csv_recording_is_the_same_text_with_the_writer_and_the_reference(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, n_rows: int, flush_rows: int, chunk: int, mark_last: bool) -> None:
    """Rows handed to the writer's thread between flushes (chunk rows at a time, the newest kept
    back for mark_last) and at each flush are the reference's text, byte for byte."""
    layout = every_code_layout()
    raw = hostile_rows(layout, n_rows, seed=n_rows)
    monkeypatch.setattr(recorder_module, "BACKGROUND_CHUNK_ROWS", chunk)
    monkeypatch.setattr(recorder_module, "CSV_WRITER_MAX_ROWS", 2 * chunk)
    _record(tmp_path / "c.csv", layout, raw, flush_rows=flush_rows, mark_last=mark_last)
    monkeypatch.setattr(recorder_module, "_csvrows", None)
    _record(tmp_path / "ref.csv", layout, raw, flush_rows=flush_rows, mark_last=mark_last)
    text = (tmp_path / "c.csv").read_bytes()
    assert text == (tmp_path / "ref.csv").read_bytes()
    assert text.count(b"# event: ") == 2 + 2 * sum(1 for first in range(0, n_rows, 37) if first % 111 == 0)
    data = read_recording(tmp_path / "c.csv")
    assert data.n_rows == n_rows
    if n_rows:
        assert np.isnan(data.columns["nan"]).all()  # a whole-number column the target does not report
        if mark_last:
            assert data.columns["marker"][-1] == recorder_module.MARKER_FAULT


def test_a_whole_number_column_of_nan_and_infinities_reads_back(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`'%d' % nan` raises: a CSV run of a target that does not report a whole-number quantity (a NaN
    scale) crashed. It writes nan (and inf, -inf), read back as such, the same with the reference."""
    layout = RowLayout((("k", "Q"), ("x", "d"), ("marker", "B")),
                       (("t_s", "s", "%.6f", "k", 5e-5), ("control_output_q15", "q15", "%d", "x", 1.0),
                        ("missing", "", "%d", "k", float("nan")), ("marker", "", "%d", "marker", 1.0)))
    values = [1.0, float("nan"), float("inf"), -float("inf"), -2.5]
    texts = []
    for use_c in (True, False):
        monkeypatch.setattr(recorder_module, "_csvrows", _csvrows if use_c else None)
        path = tmp_path / f"r{use_c}.csv"
        rec = recorder_module.Recorder(path, {})
        rec.start(layout)
        for k, x in enumerate(values):
            rec.rows.append((k, x, 0))
        rec.close("end")
        data = read_recording(path)
        column = data.columns["control_output_q15"]
        assert column[0] == 1.0 and np.isnan(column[1]) and column[2] == np.inf and column[3] == -np.inf
        assert column[4] == -2.0  # int(x): truncated
        assert np.isnan(data.columns["missing"]).all()
        texts.append(path.read_text())
    assert texts[0] == texts[1]
    assert [line.split(",")[1] for line in texts[0].splitlines() if line[:1].isdigit()] == ["1", "nan", "inf", "-inf", "-2"]
    assert np.loadtxt([ln for ln in texts[0].splitlines() if ln[:1].isdigit()], delimiter=",")[1, 1] != 0.0


def test_a_layout_the_writer_refuses_is_written_by_the_reference(tmp_path: Path) -> None:
    layout = RowLayout((("k", "Q"), ("x", "d"), ("marker", "B")),
                       (("t_s", "s", "%.6f", "k", 5e-5), ("x", "", "%.3e", "x", 1.0), ("marker", "", "%d", "marker", 1.0)))
    rec = recorder_module.Recorder(tmp_path / "r.csv", {})
    rec.start(layout)
    assert rec._csv_writer is None
    rec.rows.append((0, 1234.5, 0))
    rec.close()
    assert (tmp_path / "r.csv").read_text().splitlines()[-1] == "0.000000,1.234e+03,0"


def test_a_write_that_fails_on_the_thread_is_a_recording_error_and_the_thread_is_joined(tmp_path: Path) -> None:
    """A full disk (/dev/full: ENOSPC): the thread's write fails; the flush that waits for it says so
    (one RecordingError line), so does the close, and no thread is left behind."""
    before = set(os.listdir("/proc/self/task"))
    rec = recorder_module.Recorder(tmp_path / "r.csv", {})
    rec.start()
    assert rec._csv_writer is not None
    with open("/dev/full", "wb") as full:  # the writer takes a descriptor of its own: one on a full disk
        rec._csv_writer = recorder_module._csv_row_writer(full.fileno(), rec.rows.layout)
    for k in range(10):
        rec.append(tuple([float(k)] * recorder_module.N_COLUMNS))
    with pytest.raises(RecordingError, match=f"write failed \\({os.strerror(errno.ENOSPC)}\\)"):
        rec.flush()
    with pytest.raises(RecordingError, match="write failed"):
        rec.close()
    del rec
    assert set(os.listdir("/proc/self/task")) == before


def test_the_writer_writes_on_a_descriptor_of_its_own(tmp_path: Path) -> None:
    """The caller's descriptor closed (and its number reused) while rows wait: they go to the file."""
    with open(tmp_path / "x.csv", "wb") as out:
        writer = _csvrows.RowWriter(out.fileno(), 8, [(0, "d", 1.0, 0.0, "%d")], 100)
    with open(tmp_path / "other", "wb") as other:  # likely the number just freed
        writer.submit(np.arange(3, dtype=np.float64).tobytes(), [])
        writer.close()
    assert (tmp_path / "x.csv").read_text() == "0\n1\n2\n"
    assert (tmp_path / "other").read_bytes() == b"" and other.closed


def test_the_writer_thread_blocks_every_signal(tmp_path: Path) -> None:
    before = set(os.listdir("/proc/self/task"))
    with open(tmp_path / "x.csv", "wb") as out:
        writer = _csvrows.RowWriter(out.fileno(), 8, [(0, "d", 1.0, 0.0, "%.3f")], 100)
        new = set(os.listdir("/proc/self/task")) - before
        assert len(new) == 1
        status = Path(f"/proc/self/task/{new.pop()}/status").read_text()
        blocked = int(next(line.split()[1] for line in status.splitlines() if line.startswith("SigBlk:")), 16)
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGALRM, signal.SIGCHLD, signal.SIGPIPE):
            assert blocked >> (sig - 1) & 1, f"{sig!r} not blocked (SigBlk {blocked:#x})"
        writer.submit(np.arange(5, dtype=np.float64).tobytes(), [(0, b"# event: x\n"), (5, b"# event: y\n")])
        writer.close()
    assert (tmp_path / "x.csv").read_text() == "# event: x\n0.000\n1.000\n2.000\n3.000\n4.000\n# event: y\n"
    assert set(os.listdir("/proc/self/task")) == before


def test_the_writer_holds_at_most_max_rows_waiting(tmp_path: Path) -> None:
    """A pipe nobody reads: the thread blocks in its write, and a submit beyond max_rows waiting
    blocks too (bounded memory) until the reader drains the pipe."""
    import fcntl
    import threading

    read_fd, write_fd = os.pipe()
    fcntl.fcntl(write_fd, fcntl.F_SETPIPE_SZ, 65536)  # the default, set: a 64 KiB-page kernel's pipe is 1 MiB
    writer = _csvrows.RowWriter(write_fd, 8, [(0, "d", 1.0, 0.0, "%.9f")], 1000)
    rows = np.full(1000, 123456.123456789).tobytes()  # 17 bytes a row: 8 chunks outgrow a pipe's 64 KiB
    submitted = []
    feeder = threading.Thread(target=lambda: [submitted.append(writer.submit(rows, [])) for _ in range(8)])
    feeder.start()
    import select
    import termios
    import time

    def unread() -> int:
        return int.from_bytes(fcntl.ioctl(read_fd, termios.FIONREAD, b"\0" * 4), "little")

    # The pipe full: its 16 pages taken, though not to the byte (a write of 17 000 B starts a new page
    # rather than share one it does not fit in: 59 808 B seen), so wait for 3/4 of 64 KiB. The chunk
    # the thread writes counts against max_rows (1000 = one chunk): it has taken the chunks in the
    # pipe and the one it is blocked in, 65 536 // 17 000 + 1 = 4, and no more; a second to let a
    # broken limit take a fifth (the join returns at once if the feeder finishes: the failure).
    deadline = time.monotonic() + 60
    while unread() < 49_152 and time.monotonic() < deadline:
        select.select([], [], [], 0.01)
    assert unread() >= 49_152, f"the pipe never filled: {unread()} B unread"
    feeder.join(timeout=1.0)
    assert feeder.is_alive() and len(submitted) <= 65536 // 17_000 + 1, len(submitted)  # waiting for room
    got = 0
    while got < 8 * 17_000 and time.monotonic() < deadline + 60:
        if select.select([read_fd], [], [], 1.0)[0]:
            got += len(os.read(read_fd, 1 << 16))
    assert got == 8 * 17_000
    feeder.join(timeout=60)
    assert not feeder.is_alive() and len(submitted) == 8
    writer.close()
    os.close(write_fd)
    assert os.read(read_fd, 10) == b""
    os.close(read_fd)


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_an_event_with_a_lone_surrogate_is_written_escaped(tmp_path: Path, suffix: str) -> None:
    """JSON from a control client may carry "\\ud800": the event is written with it escaped, not
    a UnicodeEncodeError out of the flush."""
    rec = recorder_module.Recorder(tmp_path / f"r{suffix}", {})
    rec.start()
    rec.event("set name=\ud800x")
    rec.append(tuple([0.0] * recorder_module.N_COLUMNS))
    rec.close("end")
    assert read_recording(tmp_path / f"r{suffix}").events[0] == "set name=\\ud800x"


@pytest.mark.parametrize("name", ["r.csv", "r.npz", "killed.npz"])
def test_an_event_with_any_line_break_stays_one_event_and_the_recording_readable(tmp_path: Path, name: str) -> None:
    """A carriage return (or another break str.splitlines knows) in an event's text: a CSV, read
    with universal newlines, had a line of one value in its rows (the whole recording unreadable), a
    killed run's events file one event per piece. Each break is a space, as a newline was."""
    rec = recorder_module.Recorder(tmp_path / name, {})
    rec.start()
    rec.append(tuple([0.0] * recorder_module.N_COLUMNS))
    rec.event("a\rb\r\nc\vd\x1ce\x85f\u2028g\nh")
    rec.append(tuple([1.0] * recorder_module.N_COLUMNS))
    if name == "killed.npz":
        rec.flush()
        data = read_recording(tmp_path / "killed.npz.journal")
    else:
        rec.close("end")
        data = read_recording(tmp_path / name)
    assert data.n_rows == 2
    assert data.events[0] == "a b  c d e f g h"


def test_starting_a_writer_thread_leaves_the_callers_signal_mask_as_it_was() -> None:
    """Both writers start their thread with every signal blocked (hilbench/bench/_writerthread.h:
    Ctrl-C stays the main thread's) by blocking them around pthread_create: the caller's own mask
    is restored, or a run after its first recording would never see Ctrl-C."""
    from hilbench.bench import npzwriter

    signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT])
    before = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    out = os.open(os.devnull, os.O_WRONLY | os.O_CLOEXEC)
    zero = os.open("/dev/zero", os.O_RDONLY | os.O_CLOEXEC)
    try:
        rows = _csvrows.RowWriter(out, 8, [(0, "d", 1.0, 0.0, "%.9f")], 1000)
        assert signal.pthread_sigmask(signal.SIG_BLOCK, []) == before
        rows.close()
        if npzwriter._npzcolumns is not None:
            columns = npzwriter._npzcolumns.ColumnWriter(out, zero, 0, 8, [(0, "d", 1.0, 0.0, 16, 0)], b"h" * 16)
            assert signal.pthread_sigmask(signal.SIG_BLOCK, []) == before
            columns.abandon()
    finally:
        os.close(out)
        os.close(zero)
