"""Recordings: one row per period, written incrementally so a crash loses at most the last chunks.

Two formats share one column schema:

* CSV (``run.csv``): ``#``-prefixed metadata lines (JSON: config, target HELLO, versions, seed),
  a header whose names carry units, then rows. Events (parameter changes, faults, scenario
  actions) are ``# event`` comment lines between rows, at the row where they happened, and the
  ``marker`` column is non-zero on that row. numpy.loadtxt and pandas (comment="#") read it.
* NPZ (``run.npz``): rows go to an append-only binary journal ``run.npz.journal`` flushed every
  chunk; a clean close writes the ``.npz`` (one float64 array per column) atomically and removes
  the journal. ``read_recording`` reads either, so a killed run is still readable.

The hot loop appends *raw* rows: the period's values in their own types (firmware integers stay
integers), packed by a `RowLayout` that also says how each column is made of them (a field times a
scale). The journal keeps raw rows as they are, with the layout in its header, so it is written
without a conversion and a killed run's journal reads back on its own.

A chunk is ``flush_rows`` periods (by default one simulated second at the run's period).

An NPZ run that says how many rows it plans (`Recorder.expect_rows`) has its archive written while
it runs (`npzwriter.BackgroundArchive`): its chunk becomes BACKGROUND_CHUNK_ROWS rows (at most
``flush_rows``), each flush hands the chunk to a thread (copied into a buffer it reuses: the
simulating thread neither writes the journal nor touches fresh pages, which on a virtual machine
cost more than the run's rows), and the thread writes it to the journal, then converts and writes
its columns, so the close only finishes the archive. A killed run loses at most the pending chunk
and the two the thread holds; the memory the rows take stays that of one small chunk. A run that
ends with another number of rows (or a fault marker on a row already in the journal, which is then
patched there) has its archive written from the journal at the close. A journal write that fails
(a full disk) gives the archive up, its file emptied, and is written again: the journal, not the
archive, keeps the rows.

A CSV run's rows are formatted and written by the C row writer's thread (`_csvrows.RowWriter`,
when built): settled rows are handed to it every BACKGROUND_CHUNK_ROWS rows (the newest kept back,
for `mark_last`) and at each flush, which returns once they are written; `_format_csv` is its
reference (without it, or for a format it does not take).
"""

from __future__ import annotations

import contextlib
import errno
import functools
import json
import math
import os
import re
import stat
import struct
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, NoReturn, Sequence

import numpy as np

from hilbench.bench.fileio import HELD_REASON, held_elsewhere, interrupts_held, open_held, pwrite_all
from hilbench.errors import RecordingError

try:  # CSV rows in C from raw rows, on a thread (optional; `Recorder._format_csv` is the reference)
    from hilbench.bench import _csvrows
except ImportError:  # pragma: no cover - no compiler at install time
    _csvrows = None  # type: ignore[assignment]

#: (name, unit, CSV format) of the columns every bench recording has, in order; a target's
#: telemetry columns (from its profile) go after ``speed_rpm`` (see hilbench.bench.columns).
COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("t_s", "s", "%.6f"),
    ("seq", "", "%d"),
    ("hall", "bits CBA", "%d"),
    ("sector", "", "%d"),
    ("theta_e_deg", "deg", "%.3f"),
    ("speed_rpm", "rpm", "%.3f"),
    ("measured_speed_rpm", "rpm", "%.3f"),
    ("ref_speed_rpm", "rpm", "%.3f"),
    ("control_output_q15", "q15", "%d"),
    ("ia_a", "A", "%.5f"),
    ("ib_a", "A", "%.5f"),
    ("ic_a", "A", "%.5f"),
    ("ibus_a", "A", "%.5f"),
    ("duty_a", "counts", "%d"),
    ("duty_b", "counts", "%d"),
    ("duty_c", "counts", "%d"),
    ("output_mode", "", "%d"),
    ("state", "", "%d"),
    ("fault", "", "%d"),
    ("load_nm", "N*m", "%.5f"),
    ("rtt_us", "us", "%.1f"),
    ("lateness_us", "us", "%.1f"),
    ("marker", "", "%d"),
)
COLUMN_NAMES: tuple[str, ...] = tuple(name for name, _, _ in COLUMNS)
N_COLUMNS = len(COLUMNS)

#: Values of the ``marker`` column.
MARKER_NONE = 0
MARKER_EVENT = 1
MARKER_PARAM = 2
MARKER_FAULT = 3
MARKER_END = 4
MARKER_SKIPPED = 5  # real time: the host missed the period's slot, no exchange (the Drive is held)

_JOURNAL_MAGIC = b"HBJ2"
#: rows an NPZ run with a background archive flushes at a time (its chunk), and a CSV run hands to
#: its row writer's thread between flushes
BACKGROUND_CHUNK_ROWS = 4096
#: rows a planned NPZ run leaves for the close (one more flush before them: there, when the C span hands
#: the chunks over, else at the session's next observe period, every 400 by default): the rows the
#: close waits for the background archive's thread to convert
LAST_CHUNK_ROWS = 1024
#: rows a CSV run's writer thread may have waiting (handed over, not written yet): its memory bound
CSV_WRITER_MAX_ROWS = 2 * BACKGROUND_CHUNK_ROWS

#: struct codes a layout may use and their NumPy types (little-endian, packed without padding)
_CODE_DTYPES = {"B": "u1", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4", "q": "<i8", "Q": "<u8",
                "f": "<f4", "d": "<f8"}


def csv_header(columns: Sequence[tuple[str, str, str]] = COLUMNS) -> str:
    """The CSV header line: ``name[unit]`` per column."""
    return ",".join(f"{name}[{unit}]" if unit else name for name, unit, _ in columns)


def fields_struct(fields: Sequence[tuple[str, str]]) -> struct.Struct:
    """The packer of (name, code) fields, little-endian without padding: a part of a raw row."""
    return struct.Struct("<" + "".join(code for _, code in fields))


@dataclass(frozen=True)
class RowLayout:
    """What one raw row holds and how the recording's columns are made of it.

    ``fields`` are (name, struct code) packed little-endian in order; ``columns`` are, in the
    recording's order, (column name, unit, CSV format, source field, scale): column = field × scale
    (a NaN scale marks a quantity the target does not report). ``wrap`` names columns kept within
    [0, modulo) after scaling (an angle). A ``marker`` field and ``t_s`` and ``marker`` columns are
    required: events and faults are written into the marker.
    """

    fields: tuple[tuple[str, str], ...]
    columns: tuple[tuple[str, str, str, str, float], ...]
    wrap: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        names = [name for name, _ in self.fields]
        bad = [code for _, code in self.fields if code not in _CODE_DTYPES]
        missing = [c[3] for c in self.columns if c[3] not in names]
        column_names = [c[0] for c in self.columns]
        if bad or missing or "marker" not in names or not {"t_s", "marker"} <= set(column_names) \
                or len(set(column_names)) != len(column_names):
            raise ValueError(f"RowLayout: bad codes {bad}, unknown fields {missing}, columns {column_names}, "
                             f"marker field: {'marker' in names}")
        wrapped = [name for name, _ in self.wrap]
        bad_modulo = [(name, modulo) for name, modulo in self.wrap if not 0.0 < modulo < math.inf]
        if bad_modulo or len(set(wrapped)) != len(wrapped):  # one conversion: to_column's and the C writer's
            raise ValueError(f"RowLayout: a wrap needs a positive, finite modulo and one entry a column: "
                             f"{list(self.wrap)}")

    @property
    def column_specs(self) -> tuple[tuple[str, str, str], ...]:
        """(name, unit, CSV format) of each column, in order."""
        return tuple((name, unit, fmt) for name, unit, fmt, _, _ in self.columns)

    @functools.cached_property  # (a run's set-up asks several times; the layout is frozen)
    def column_names(self) -> tuple[str, ...]:
        return tuple(c[0] for c in self.columns)

    @functools.cached_property
    def dtype(self) -> np.dtype:
        return np.dtype([(name, _CODE_DTYPES[code]) for name, code in self.fields])

    def to_columns(self, raw: Any) -> dict[str, np.ndarray]:
        """Raw rows (bytes or a structured array; a torn last row is dropped) to one contiguous
        float64 array per column."""
        rows = self._rows(raw)
        return {name: self.to_column(rows, name) for name in self.column_names}

    def to_column(self, raw: Any, name: str) -> np.ndarray:
        """One column of raw rows (as `to_columns` takes them), without converting the others."""
        rows = self._rows(raw)
        for column, _, _, src, scale in self.columns:
            if column == name:
                field_values = rows[src]  # strided view into the rows
                values = field_values.astype(np.float64) if scale == 1.0 else np.multiply(field_values, scale, dtype=np.float64)
                for wrapped, modulo in self.wrap:
                    if wrapped == name:
                        np.mod(values, modulo, out=values)
                return values
        raise KeyError(name)

    def _rows(self, raw: Any) -> np.ndarray:
        """Raw rows as a structured array (a view of bytes; a torn last row is dropped)."""
        if isinstance(raw, np.ndarray):
            return raw
        dtype = self.dtype
        return np.frombuffer(raw, dtype=dtype, count=len(raw) // dtype.itemsize)

    def as_json(self) -> dict[str, Any]:
        return {"fields": [list(f) for f in self.fields], "columns": [list(c) for c in self.columns],
                "wrap": [list(w) for w in self.wrap]}

    @classmethod
    def from_json(cls, obj: Any) -> "RowLayout":
        """The layout a journal's header describes. The header is input (a damaged or hand-edited
        journal), so its shape is checked here first: ValueError naming the field, never a TypeError
        from deep inside, nor a layout that fails later when rows are read."""
        if not isinstance(obj, dict):
            raise ValueError(f"layout is {_json_shown(obj)}, not a table")
        raw_fields = obj.get("fields")
        if not isinstance(raw_fields, list) or not raw_fields:
            raise ValueError(f"layout fields is {_json_shown(raw_fields)}, not a list of [name, type code]")
        for i, f in enumerate(raw_fields):
            if not (isinstance(f, list) and len(f) == 2 and all(isinstance(x, str) for x in f)):
                raise ValueError(f"layout field {i} is {_json_shown(f)}, not [name, type code]")
        fields = tuple((str(n), str(c)) for n, c in raw_fields)
        names = [n for n, _ in fields]
        for n, code in fields:
            if code not in _CODE_DTYPES:
                raise ValueError(f"layout field {_json_shown(n)} has type code {_json_shown(code)}, not one of "
                                 f"{''.join(_CODE_DTYPES)}")
            if names.count(n) > 1:
                raise ValueError(f"layout field {_json_shown(n)} appears more than once")
        if "marker" not in names:
            raise ValueError("layout fields have no marker field")
        raw_columns = obj.get("columns")
        legacy = isinstance(raw_columns, list) and bool(raw_columns) and isinstance(raw_columns[0], list) \
            and len(raw_columns[0]) == 2  # journals written before columns had names
        width, what = (2, "[field, scale]") if legacy else (5, "[name, unit, format, field, scale]")
        if not isinstance(raw_columns, list) or not raw_columns:
            raise ValueError(f"layout columns is {_json_shown(raw_columns)}, not a list of {what}")
        for i, c in enumerate(raw_columns):
            if not (isinstance(c, list) and len(c) == width and all(isinstance(x, str) for x in c[:-1])):
                raise ValueError(f"layout column {i} is {_json_shown(c)}, not {what}")
        if legacy:
            columns = tuple((name, unit, fmt, src, k) for (name, unit, fmt), (src, k) in zip(COLUMNS, raw_columns))
        else:
            columns = tuple((n, u, f, src, k) for n, u, f, src, k in raw_columns)
        column_names = [c[0] for c in columns]
        for name, _, _, src, scale in columns:
            if not _json_number(scale) or math.isinf(scale):  # NaN: a quantity the target does not report
                raise ValueError(f"layout column {_json_shown(name)} has scale {_json_shown(scale)}, not a finite number")
            if src not in names:
                raise ValueError(f"layout column {_json_shown(name)} reads field {_json_shown(src)}, not in the fields")
            if column_names.count(name) > 1:
                raise ValueError(f"layout column {_json_shown(name)} appears more than once")
        for required in ("t_s", "marker"):
            if required not in column_names:
                raise ValueError(f"layout columns have no {required} column")
        raw_wrap = obj.get("wrap", [])
        if not isinstance(raw_wrap, list):
            raise ValueError(f"layout wrap is {_json_shown(raw_wrap)}, not a list of [column, positive modulo]")
        for i, w in enumerate(raw_wrap):
            if not (isinstance(w, list) and len(w) == 2 and isinstance(w[0], str) and _json_number(w[1])
                    and 0.0 < w[1] < math.inf):
                raise ValueError(f"layout wrap {i} is {_json_shown(w)}, not [column, positive modulo]")
        wrapped = [name for name, _ in raw_wrap]
        if len(set(wrapped)) != len(wrapped):
            raise ValueError(f"layout wrap names a column more than once: {_json_shown(raw_wrap)}")
        return cls(fields, tuple((n, u, f, src, float(k)) for n, u, f, src, k in columns),
                   tuple((str(n), float(m)) for n, m in raw_wrap))


def _json_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _json_shown(value: Any) -> str:
    """A value of a recording's JSON as a message shows it: as JSON (null, not None), 40 characters at most."""
    try:
        text = json.dumps(value)
    except (ValueError, TypeError, RecursionError):
        text = type(value).__name__
    return text if len(text) <= 40 else text[:37] + "..."


def float_layout(columns: Sequence[tuple[str, str, str]]) -> RowLayout:
    """Rows that already are the columns, as float64 (tests, exports, a caller without its own layout)."""
    return RowLayout(tuple((name, "d") for name, _, _ in columns),
                     tuple((name, unit, fmt, name, 1.0) for name, unit, fmt in columns))


#: The bench's base columns as float64 rows.
COLUMN_LAYOUT = float_layout(COLUMNS)


class RowBuffer:
    """Raw rows packed into one bytearray: cheap to append (struct), free to view (numpy).

    The hot path binds ``pack`` and ``extend`` and calls ``extend(pack(v0, v1, ...))``: a few
    hundred ns per row, where array('d').extend(tuple) costs 1.5 µs.
    """

    def __init__(self, layout: RowLayout = COLUMN_LAYOUT) -> None:
        self.configure(layout)

    def configure(self, layout: RowLayout) -> None:
        """Set the row layout (empties the buffer: call it before the first row)."""
        self.layout = layout
        self.dropped = 0  # rows let go from the front (written out): the buffer's row 0 is the run's row `dropped`
        self.struct = fields_struct(layout.fields)
        self.pack = self.struct.pack
        self.data = bytearray()
        self.extend = self.data.extend
        names = [name for name, _ in layout.fields]
        marker = names.index("marker")
        self._marker_code = "<" + layout.fields[marker][1]
        self._marker_offset = fields_struct(layout.fields[:marker]).size

    def append(self, row: Sequence[float]) -> None:
        self.extend(self.pack(*row))

    def __len__(self) -> int:
        return len(self.data) // self.struct.size

    def mark(self, index: int, value: int) -> None:
        """Set the marker field of pending row ``index``."""
        struct.pack_into(self._marker_code, self.data, index * self.struct.size + self._marker_offset, value)

    def mark_row(self, row: bytearray, value: int) -> None:
        """Set the marker field of one packed row of this layout (a row read back from a journal)."""
        struct.pack_into(self._marker_code, row, self._marker_offset, value)

    def marker_at(self, index: int) -> int:
        return int(struct.unpack_from(self._marker_code, self.data, index * self.struct.size + self._marker_offset)[0])

    def settle(self, events: list[tuple[int, str, int]], n_rows: int | None = None) -> None:
        """Make the pending rows final: cut a row left half-appended (an interrupt between its two
        appends), then write the markers of pending events into their rows and forget them
        (entries kept for their text). The last event of a row wins among events; a marker the
        row already has (a skipped period, a fault) is kept. ``n_rows``: only the first n_rows, the
        buffer's size left alone (the C span's, which is writing after them: `Recorder.span_rows`)."""
        if n_rows is None:
            extra = len(self.data) % self.struct.size
            if extra:
                del self.data[-extra:]
            n_rows = len(self)
        by_row: dict[int, int] = {}
        for i, (index, text, marker) in enumerate(events):
            if marker and index < n_rows:
                by_row[index] = marker
                events[i] = (index, text, MARKER_NONE)
        for index, marker in by_row.items():
            if self.marker_at(index) == MARKER_NONE:
                self.mark(index, marker)

    def mark_last(self, value: int) -> None:
        """Set the marker field of the newest whole row."""
        if len(self):
            self.mark(len(self) - 1, value)

    def columns(self, names: Sequence[str] | None = None, *, in_place: bool = False) -> dict[str, np.ndarray]:
        """Every column (or those named) of the pending rows as float64 arrays of their own.
        The rows are copied first: while a view into the buffer lives, the buffer cannot grow, and
        a run on another thread may be appending. ``in_place``: the run that appended them has
        ended (a closed recorder's), so they are read where they are (a step test's 20 000 rows
        are 3 MB). The view lives only during this call (an unknown name is refused before it
        exists: an error's traceback would keep it alive), so a later run on this thread (`Bench.run`
        after `summary`) appends as before."""
        layout = self.layout
        wanted = layout.column_names if names is None else tuple(names)
        unknown = [name for name in wanted if name not in layout.column_names]
        if unknown:
            raise KeyError(unknown[0])
        rows = layout._rows(self.data if in_place else bytes(self.data))
        return {name: layout.to_column(rows, name) for name in wanted}

    def clear(self) -> None:
        self.dropped += len(self)
        del self.data[:]


@dataclass
class Recorder:
    """Collects raw rows in memory and writes them out every ``flush_rows`` rows."""

    path: Path
    metadata: dict[str, Any]
    flush_rows: int = 20_000
    rows: RowBuffer = field(default_factory=RowBuffer, repr=False)
    _events: list[tuple[int, str, int]] = field(default_factory=list, repr=False)
    _file: Any = field(default=None, repr=False)
    rows_written: int = 0
    closed: bool = False
    started: bool = False
    _background: Any = field(default=None, repr=False)  # npzwriter.BackgroundArchive, when the rows are planned
    _handed: int = field(default=0, repr=False)  # a CSV's pending rows already handed to its writer's thread
    _span_taken: int = field(default=0, repr=False)  # rows a C span's interrupted hand-over took (`span_stopped`)
    _journal_start: int = field(default=0, repr=False)  # the journal's row 0
    _csv_writer: Any = field(default=None, repr=False)  # _csvrows.RowWriter: a CSV's rows written on a thread
    _next_row_marker: int = field(default=MARKER_NONE, repr=False)  # an event's, flushed before its row came
    _last_flush_at: int = field(default=0, repr=False)  # a planned run's rows at its last flush before the close
    _events_file: Any = field(default=None, repr=False)  # an NPZ's events side file, once it has some
    _csv_regular: bool = field(default=True, repr=False)  # a CSV to a regular file: a write runs to its end

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        suffix = self.path.suffix.lower()
        if suffix not in (".csv", ".npz"):
            raise RecordingError(f"recording {self.path}: unknown format {suffix!r} (use .csv or .npz)")
        self.is_npz = suffix == ".npz"
        try:  # open now, so an unwritable path (or one another session records to) fails before the run starts
            if held_by_a_running_session(self.path):  # (by any of its names: an NPZ's events, its final name)
                raise OSError(errno.EBUSY, HELD_REASON)
            if self.is_npz:
                self._file = open_held(self._journal_path(), binary=True, read_too=True)  # `_mark_journal_row` reads
                try:
                    _events_path(self._journal_path()).unlink(missing_ok=True)  # a killed earlier run's
                    self._tmp_path().unlink(missing_ok=True)  # and its unfinished archive
                except OSError:  # (a directory there): the journal let go, not held until collected
                    self._file.close()
                    raise
            else:
                self._file = open_held(self.path)
                self._csv_regular = stat.S_ISREG(os.fstat(self._file.fileno()).st_mode)
        except OSError as exc:
            raise RecordingError(f"recording {self.path}: cannot write ({exc.strerror or exc})") from None
        self.append = self.rows.append

    def start(self, layout: RowLayout = COLUMN_LAYOUT) -> None:
        """Fix the row layout and write the header (before the first row; flush starts a
        recorder that was not started with COLUMN_LAYOUT)."""
        if self.started:
            if layout != self.rows.layout:
                raise RecordingError(f"recording {self.path}: row layout changed after the start")
            return
        if layout != self.rows.layout:
            if len(self.rows):
                raise RecordingError(f"recording {self.path}: rows were appended before the layout was set")
            self.rows.configure(layout)
            self.append = self.rows.append
        try:
            if self.is_npz:
                head = json.dumps({"layout": layout.as_json(), "metadata": self.metadata}, default=str).encode()
                self._file.write(_JOURNAL_MAGIC + struct.pack("<I", len(head)) + head)
                self._journal_start = 8 + len(head)
            else:
                # the header first: pandas.read_csv(f, comment="#") and numpy.loadtxt(f, delimiter=",",
                # skiprows=1) read the file with no line counting (metadata and events are # lines)
                self._file.write(csv_header(layout.column_specs) + "\n")
                for key, value in self.metadata.items():
                    self._file.write(f"# {key}: {json.dumps(value, default=str)}\n")
            self._file.flush()
        except OSError as exc:
            raise RecordingError(f"recording {self.path}: write failed ({exc.strerror})") from None
        self.started = True
        if not self.is_npz:
            self._csv_writer = _csv_row_writer(self._file.fileno(), layout)

    def _journal_path(self) -> Path:
        return journal_path_of(self.path)

    def _tmp_path(self) -> Path:
        return _tmp_archive_path_of(self.path)

    def expect_rows(self, n_rows: int) -> None:
        """The run plans ``n_rows`` rows (call it after `start`, before the first row): an NPZ
        archive of that many is written while it runs; without the compiled column writer, or for
        a CSV, nothing changes."""
        if not self.is_npz or not self.started or self.closed or self._background is not None or n_rows <= 0 \
                or self.rows_written or len(self.rows):
            return
        from hilbench.bench import npzwriter

        if npzwriter._npzcolumns is None:
            return
        try:
            self._background = npzwriter.BackgroundArchive(self._tmp_path(), self.rows.layout, n_rows,
                                                           self._journal_path(), self._journal_start)
        except Exception:  # noqa: BLE001 - an accelerator's failure, whatever it is: the close writes the
            self._background = None  # archive from the journal (the reference; it says so if it cannot)
            self._tmp_path().unlink(missing_ok=True)
            return
        self.flush_rows = min(self.flush_rows, BACKGROUND_CHUNK_ROWS)
        self._last_flush_at = n_rows - LAST_CHUNK_ROWS  # (a plan that small: no flush more)

    def hand_over_at(self) -> int:
        """The count of pending rows at which the session's C span hands them over (`span_rows`):
        a planned NPZ run's chunk (its background archive's), or its last flush; 0: not handed over
        from inside a span (no background archive: the parts' flushes write them)."""
        if self._background is None or self.closed:
            return 0
        rows = self.flush_rows
        if self._last_flush_at > 0:
            rows = min(rows, self._last_flush_at - self.rows_written)
        return max(rows, 1)

    def span_rows(self, n_rows: int) -> int:
        """The first ``n_rows`` pending rows, which the C span has written and writes on after,
        flushed as `maybe_flush` would (the buffer's size is the span's: not changed here; the span
        writes on from its start once this returns). Returns the next `hand_over_at`."""
        written, dropped = self.rows_written, self.rows.dropped
        try:
            if 0 < self._last_flush_at <= self.rows_written + n_rows:
                self._last_flush_at = 0  # once: the last chunk, the close's, is small
            self._settle(n_rows)
            self._write_out(n_rows)
            self.rows.dropped += n_rows  # (the span writes its next rows over them)
            return self.hand_over_at()
        except BaseException:  # a Ctrl-C after the rows were taken: the span stops with them still
            with interrupts_held():  # in its buffer, which `span_stopped` empties (a second Ctrl-C after)
                if self.rows_written != written:
                    self._written_out()
                    self.rows.dropped = dropped
                    self._span_taken = n_rows
            raise

    def span_stopped(self) -> None:
        """A C span stopped by an exception: rows a hand-over had taken (written, counted) before it
        are let go from the buffer, where the span left them, so the close does not write them again."""
        n_rows, self._span_taken = self._span_taken, 0
        if n_rows:
            del self.rows.data[:n_rows * self.rows.struct.size]
            self.rows.dropped += n_rows

    def rows_to_write(self) -> int:
        """How many more rows before `maybe_flush` has work: a flush, or rows for a CSV's writer thread."""
        pending = len(self.rows)
        rows = self.flush_rows - pending
        if self._last_flush_at > 0:  # (0: none, or done)
            rows = min(rows, self._last_flush_at - self.rows_written - pending)
        if self._csv_writer is not None:  # (the newest row is kept back: mark_last may still mark it)
            rows = min(rows, BACKGROUND_CHUNK_ROWS + 1 - (pending - self._handed))
        return rows

    def event(self, text: str, marker: int = MARKER_NONE) -> None:
        """Note an event at the next row to be appended; a marker goes into that row. The text is
        one line of UTF-8: every line break a reader splits on (a CSV is read with universal newlines,
        a journal's events file with str.splitlines) a space, a lone surrogate (which a control
        client's JSON can carry) as its escape (a CSV or an events file could not take it)."""
        line = text.translate(_ONE_LINE).encode("utf-8", "backslashreplace").decode("utf-8")
        self._events.append((len(self.rows), line, marker))

    def mark_last(self, marker: int) -> None:
        """Set the marker of the newest row (the last good period): it wins over events. An NPZ's
        newest row already flushed (none pending) is patched in the journal."""
        self._settle()
        if len(self.rows) or not self.is_npz or not self.rows_written:
            self.rows.mark_last(marker)
            return
        if self._background is not None:
            self._background.abandon()  # its thread may have read that row without the marker
        self._mark_journal_row(self.rows_written - 1, marker)

    def _mark_journal_row(self, index: int, marker: int) -> None:
        """Set the marker of row ``index`` of the journal (read, marked, written back in place)."""
        size = self.rows.struct.size
        offset = self._journal_start + index * size
        try:
            self._file.flush()
            row = bytearray(os.pread(self._file.fileno(), size, offset))
            if len(row) != size:
                raise OSError(errno.EIO, f"row {index} is not in the journal")
            self.rows.mark_row(row, marker)
            os.pwrite(self._file.fileno(), row, offset)
        except OSError as exc:
            raise RecordingError(f"recording {self.path}: write failed ({exc.strerror})") from None

    def maybe_flush(self) -> None:
        """Write out the pending chunk if it is full (else hand the background archive its next
        rows when enough wait); cheap to call every period."""
        pending = len(self.rows)
        if pending >= self.flush_rows:
            self._flush()
        elif 0 < self._last_flush_at <= self.rows_written + pending:
            self._last_flush_at = 0  # once: the last chunk, the close's, is small
            self._flush()
        elif self._csv_writer is not None and pending - 1 - self._handed >= BACKGROUND_CHUNK_ROWS:
            self._settle()
            self._hand_over_csv(len(self.rows) - 1)  # the newest kept back: mark_last may mark it

    def _hand_over_csv(self, end: int) -> None:
        """Pending rows (settled) up to ``end`` and the events before them (those at ``end`` too
        when it is every pending row: after the last) handed to the CSV writer's thread, which
        writes their text while the run goes on (it waits while CSV_WRITER_MAX_ROWS rows wait)."""
        rows, events, first = self.rows, self._events, self._handed
        n_events = sum(1 for index, _, _ in events if index < end or (index == end == len(rows)))
        lines = [(index - first, f"# event: {text}\n".encode()) for index, text, _ in events[:n_events]]
        size = rows.struct.size
        writer = self._csv_writer
        accepted = writer.accepted
        try:
            with memoryview(rows.data) as whole, whole[first * size:end * size] as data:  # copied by submit
                writer.submit(data, lines)
        except OSError as exc:
            raise RecordingError(f"recording {self.path}: write failed ({exc.strerror})") from None
        except ValueError as exc:  # its thread gone after a failed write: one line, not a traceback
            raise RecordingError(f"recording {self.path}: {exc}") from None
        finally:  # the chunk taken, whatever came after (a Ctrl-C raised as submit returns): never twice
            if writer.accepted != accepted:
                del events[:n_events]
                self._handed = end

    def _journal_rows(self, n_rows: int) -> None:
        """The pending rows to the journal, at their place: handed to the background archive's thread
        (which journals them, then converts them), or written here when there is none (any more)."""
        background = self._background
        if background is not None and n_rows and background.journal_failed is None:
            size = self.rows.struct.size
            try:
                with memoryview(self.rows.data) as whole, whole[:n_rows * size] as data:  # copied by the writer
                    if background.submit_rows(self.rows_written, data):
                        return
            except OSError as exc:
                self._journal_lost(exc)
        if background is not None and background.journal_failed is not None:  # nothing goes after a hole
            self._journal_lost(background.journal_failed)
        self._write_journal(0, n_rows)

    def _journal_lost(self, exc: OSError) -> NoReturn:
        """A journal write on the archive's thread failed twice: the journal cut to the rows it
        holds whole, and a RecordingError saying how many."""
        background = self._background
        kept = background.journaled if background is not None else self.rows_written
        try:
            os.truncate(self._journal_path(), self._journal_start + kept * self.rows.struct.size)
        except OSError:
            pass
        raise RecordingError(f"recording {self.path}: write failed ({exc.strerror}); "
                             f"{self._journal_path()} keeps the first {kept} rows") from None

    def _write_events_file(self, text: str) -> None:
        """Events appended to the journal's side file. A failed write while a background archive
        takes space (a full disk) gives that archive up, its blocks freed, and is tried once more
        (what part of the failed one landed cut off)."""
        data = text.encode("utf-8")
        if self._events_file is None:  # open until the close (a flush's open and close: ~30 µs each)
            self._events_file = open(_events_path(self._journal_path()), "ab", buffering=0)
        fd = self._events_file.fileno()
        offset = os.fstat(fd).st_size  # (appended: a write lands at the end, wherever this says)
        try:
            try:
                pwrite_all(fd, memoryview(data), offset)
            except OSError:
                background = self._background
                if background is None or background.given_up:
                    raise
                background.abandon()  # (every row handed over journaled first)
                os.ftruncate(fd, offset)
                pwrite_all(fd, memoryview(data), offset)
        except OSError:  # no torn line left for the next flush to append after
            with contextlib.suppress(OSError):
                os.ftruncate(fd, offset)
            raise

    def _write_journal(self, first: int, end: int) -> None:
        """Pending rows first..end-1 written at their place in the journal (pwrite: no buffer left
        holding a failed write's bytes)."""
        offset = self._journal_start + (self.rows_written + first) * self.rows.struct.size
        try:
            self._pwrite_rows(first, end, offset)
        except OSError as exc:
            raise RecordingError(f"recording {self.path}: write failed ({exc.strerror})") from None

    def _pwrite_rows(self, first: int, end: int, offset: int) -> None:
        size = self.rows.struct.size
        with memoryview(self.rows.data) as whole, whole[first * size:end * size] as data:  # released whatever fails
            pwrite_all(self._file.fileno(), data, offset)

    def flush(self) -> None:
        """Write every pending row and event and push them to the OS (an NPZ's background archive's
        thread has journaled every row when this returns: a reader of the journal sees them all)."""
        self._flush()
        background = self._background
        if background is not None:
            try:
                background.sync()
            except OSError as exc:
                self._journal_lost(exc)

    def _flush(self) -> None:
        """`flush`, an NPZ's rows only handed to its background archive's thread (which journals them
        a moment later): the run's own flushes, which must not wait."""
        if not self.started:
            self.start()
        self._settle()
        n_rows = len(self.rows)
        if not n_rows and not self._events:
            return
        written = self.rows_written
        try:
            self._write_out(n_rows)
        finally:  # (also under a Ctrl-C once they are counted: the close must not write them again)
            if self.rows_written != written:  # (no call before the rows are let go: a Ctrl-C lands at calls)
                rows = self.rows
                del rows.data[:]
                rows.dropped += n_rows
                self._written_out()

    def _written_out(self) -> None:
        """What `_write_out` ends with once its rows are counted, done again after an exception there
        (a Ctrl-C): the events went with the rows, a CSV's rows all left the buffer for its file."""
        self._events.clear()
        self._handed = 0

    def _write_out(self, n_rows: int) -> None:
        """The first ``n_rows`` pending rows (settled) and every pending event written; the caller
        empties the buffer of them."""
        events = self._events
        rows = self.rows
        markers = [marker for _, _, marker in events if marker != MARKER_NONE]  # settled: those of the next row
        # no row written: an earlier flush's marker still waits for its row (settling took it otherwise)
        next_row_marker = markers[-1] if markers else self._next_row_marker if n_rows == 0 else MARKER_NONE
        if self.is_npz:  # raw rows as they are (the layout is in the header)
            self._journal_rows(n_rows)
        try:
            if self.is_npz:
                if events:  # the side file keeps them until the close, the metadata at the close
                    texts = [text for _, text, _ in events]
                    kept = self.metadata.setdefault("events", [])
                    with interrupts_held():  # written and noted so together (a Ctrl-C between: written twice)
                        self._write_events_file("".join(f"{text}\n" for text in texts))
                        kept.extend(texts)
                        events.clear()
                self._file.flush()
            elif self._csv_writer is not None:  # the rest to the thread; the flush returns when it is written
                self._hand_over_csv(n_rows)
                self._csv_writer.drain()
                self._file.flush()
            else:  # the reference (those a thread took before an interrupted close are written)
                first = self._handed
                columns = rows.columns()
                table = np.column_stack([columns[name][first:] for name in rows.layout.column_names]) \
                    if n_rows > first else np.zeros((0, len(columns)))
                csv_text = self._format_csv(list(map(tuple, table.tolist())),
                                            [(index - first, text, marker) for index, text, marker in events])
                try:
                    self._file.write(csv_text)
                    self._file.flush()
                except Exception:  # the write's own error (a full disk, no memory): nothing counted
                    raise
                except BaseException:  # a signal's (Ctrl-C), raised as the write returns (a regular file's
                    if self._csv_regular:  # write runs to its end): its rows are in the file, not to write again
                        self.rows_written += n_rows  # (a pipe's can stop part-way: how far is unknown)
                        self._next_row_marker = next_row_marker
                    raise
        except OSError as exc:
            raise RecordingError(f"recording {self.path}: write failed ({exc.strerror})") from None
        self.rows_written += n_rows
        self._next_row_marker = next_row_marker
        events.clear()
        self._handed = 0

    def _close_events_file(self) -> None:
        events_file, self._events_file = self._events_file, None
        if events_file is not None:
            events_file.close()

    def no_more_rows(self) -> None:
        """No more rows come: an NPZ's pending rows handed to its background archive's thread now, so
        it converts them while the caller does other work before `close`."""
        if self.is_npz and self._background is not None and not self.closed:
            self._flush()

    def _settle(self, n_rows: int | None = None) -> None:
        """`RowBuffer.settle`, and the marker of an event a flush wrote before its row came (noted
        at the next row when the chunk ended) set on that row, the chunk's first, unless it has one."""
        self.rows.settle(self._events, n_rows)
        if self._next_row_marker != MARKER_NONE and (len(self.rows) if n_rows is None else n_rows):
            if self.rows.marker_at(0) == MARKER_NONE:
                self.rows.mark(0, self._next_row_marker)
            self._next_row_marker = MARKER_NONE

    def _format_csv(self, rows: list[tuple[float, ...]], events: list[tuple[int, str, int]]) -> str:
        """The CSV text of these rows (the columns' values) and events: the reference of the C
        row writer (hilbench/bench/_csvrows.c; the same text, tests/test_csv_rows.py)."""
        formats = [f for _, _, f in self.rows.layout.column_specs]
        fmt = ",".join(formats) + "\n"
        parts: list[str] = []
        start = 0
        for index, text, _ in events:
            parts.extend(_csv_line(fmt, formats, row) for row in rows[start:index])
            parts.append(f"# event: {text}\n")
            start = index
        parts.extend(_csv_line(fmt, formats, row) for row in rows[start:])
        return "".join(parts)

    def _restart_csv_writer(self) -> None:
        """An interrupted close: the rows handed over written and the thread joined, and a new
        thread for what a later close hands over (the file's offset is shared: it appends)."""
        try:
            self._csv_writer.close()
        except OSError:
            self._csv_writer.abandon()
            return
        self._csv_writer = _csv_row_writer(self._file.fileno(), self.rows.layout)

    def close(self, final_note: str | None = None) -> None:
        """Flush, note how the run ended, and (NPZ) write the archive atomically."""
        if self.closed:
            return
        if final_note:
            self.event(final_note)
            self.metadata["end"] = final_note
        try:  # (no sync: an NPZ archive's thread journals every row before `finish` or `abandon` returns,
            self._flush()  # and its last rows are converted meanwhile)
            if self._csv_writer is not None:  # every row written: its thread joined
                self._csv_writer.close()
        except BaseException as exc:
            try:
                if self._background is not None:  # its thread joined: the journal keeps the rows
                    self._background.abandon()
                if self._csv_writer is not None:
                    if isinstance(exc, (OSError, RecordingError)):  # a failed write: nothing more is written
                        self._csv_writer.abandon()
                    else:  # Ctrl-C: the queued chunks are the only copy of their rows
                        self._restart_csv_writer()
            finally:
                self._close_events_file()
            raise
        self.closed = True
        try:  # an NPZ's journal stays open, its lock keeping another session off the path, until the
            if self.is_npz:  # archive is in place and the journal gone (`_close_archive`)
                try:
                    self._file.flush()
                except BaseException:  # (closed: not held until collected)
                    with contextlib.suppress(OSError):
                        self._file.close()
                    raise
            else:
                self._file.close()
        finally:
            self._close_events_file()
        if self.is_npz:
            self._close_archive()

    def _close_archive(self) -> None:
        """The archive written under the recording's name, the journal removed, then its descriptor
        (and lock) let go; on every path, the journal's."""
        try:
            if "events" in self.metadata:  # after "end", however many flushes came first: the same bytes
                self.metadata["events"] = self.metadata.pop("events")
            self.metadata["columns"] = [list(spec) for spec in self.rows.layout.column_specs]  # name, unit, CSV format
            background, self._background = self._background, None
            try:
                self._write_archive(background)
                journal = self._journal_path()
                journal.unlink()
                _events_path(journal).unlink(missing_ok=True)
            finally:  # the archive's descriptor on the journal, on every path: once the journal is unlinked,
                if background is not None:  # this last close frees its pages, on another thread
                    background.release_journal()
        finally:
            self._file.close()

    def _write_archive(self, background: Any) -> None:
        """The archive, from the background archive's thread or else from the journal, under the
        recording's name; a RecordingError (the journal kept) when it cannot be written."""
        tmp = self._tmp_path()
        try:
            if background is None or not background.finish(np.asarray(json.dumps(self.metadata, default=str))):
                _write_npz_from_journal(tmp, self._journal_path(), self.metadata)  # the reference
            os.replace(tmp, self.path)
        except (OSError, RecordingError) as exc:  # a full disk, a file size limit: the journal stays
            tmp.unlink(missing_ok=True)
            reason = (exc.strerror or str(exc)) if isinstance(exc, OSError) else str(exc)
            if background is not None and background.journal_failed is not None:  # a late chunk's journal write
                self._journal_lost(background.journal_failed)
            raise RecordingError(f"recording {self.path}: the archive could not be written ({reason}); "
                                 f"every row is kept in {self._journal_path()}") from None


#: the characters str.splitlines (a journal's events file) and universal newlines (a CSV) break lines at
_ONE_LINE = str.maketrans({c: " " for c in "\n\r\v\f\x1c\x1d\x1e\x85\u2028\u2029"})


def _csv_line(fmt: str, formats: Sequence[str], row: tuple[float, ...]) -> str:
    """``fmt % row``; a NaN or an infinity in a whole-number column (which ``%d`` refuses: a target
    that does not report the quantity) written as ``%.0f`` writes it, ``nan``, ``inf`` or ``-inf``,
    which readers (float, numpy.loadtxt, pandas) take back."""
    try:
        return fmt % row
    except (ValueError, OverflowError):
        return ",".join("%.0f" % x if f.endswith(("d", "i", "u")) and not math.isfinite(x) else f % x
                        for f, x in zip(formats, row)) + "\n"


def _csv_row_writer(fd: int, layout: RowLayout) -> Any:
    """A `_csvrows.RowWriter` for ``layout``'s rows on ``fd`` (its thread writes them as
    `Recorder._format_csv` would), or None: not built, a format it leaves to the reference, or any
    failure to start it (the flush then formats the rows itself)."""
    if _csvrows is None:
        return None
    from hilbench.bench.npzwriter import _field_offsets

    offsets, wraps = _field_offsets(layout), dict(layout.wrap)
    columns = [(*offsets[src], scale, wraps.get(name, 0.0), fmt) for name, _, fmt, src, scale in layout.columns]
    try:
        return _csvrows.RowWriter(fd, layout.dtype.itemsize, columns, CSV_WRITER_MAX_ROWS)
    except Exception:  # noqa: BLE001 - an accelerator's failure, whatever it is: the reference writes the rows
        return None


#: rows converted at a time when an NPZ archive is written from its journal (bounded memory)
NPZ_CHUNK_ROWS = 65536


def _write_npz_from_journal(path: Path, journal: Path, metadata: dict[str, Any]) -> None:
    """The archive from the journal in one pass: NPZ_CHUNK_ROWS raw rows at a time are read into
    one reused buffer, every column of them converted and written at its place in the archive
    (hilbench.bench.npzwriter). The close's memory is one chunk however long the run (a mapping
    of the whole journal counted every page in the process's RSS: 1.5 GB at the close of a 600 s
    run), and the journal is read once, not once per column."""
    from hilbench.bench.npzwriter import ColumnArchive

    _, layout, _ = _read_journal_rows(journal, head_only=True)
    with open(journal, "rb") as handle:
        handle.seek(4)
        (head_len,) = struct.unpack("<I", handle.read(4))
        start = 8 + head_len
        handle.seek(start)
        itemsize = layout.dtype.itemsize
        n_rows = max(0, (os.fstat(handle.fileno()).st_size - start) // itemsize)  # a torn last row is dropped
        names = [name for name, _, _ in layout.column_specs]
        # uninitialised: readinto fills what is used (zeroing a bytearray cost ~1 instruction a byte
        # of every row under callgrind, whose count of `rep stosb` is per byte)
        buffer = np.empty(min(NPZ_CHUNK_ROWS, max(n_rows, 1)) * itemsize, dtype=np.uint8)
        with ColumnArchive(path, names, n_rows) as archive:
            for first in range(0, n_rows, NPZ_CHUNK_ROWS):
                count = min(NPZ_CHUNK_ROWS, n_rows - first)
                view = memoryview(buffer)[: count * itemsize]
                if handle.readinto(view) != len(view):  # the journal is read in order, once
                    raise RecordingError(f"recording {journal}: shorter than it was a moment ago")
                rows = np.frombuffer(view, dtype=layout.dtype, count=count)
                for name in names:  # one column alive at a time: its block is reused, not a chunk's worth
                    archive.write(first, {name: layout.to_column(rows, name)})
                del rows
            archive.add("metadata", np.asarray(json.dumps(metadata, default=str)))


def _write_npz_deterministic(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """np.savez stamps the wall clock into the zip; fixed stamps keep runs identical.

    Stored, not deflated: compressing costs more than the whole run at 20 kHz (gzip it if needed)."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED) as archive:
        for name, array in arrays.items():
            info = zipfile.ZipInfo(name + ".npy", date_time=(1980, 1, 1, 0, 0, 0))
            with archive.open(info, "w", force_zip64=True) as member:  # streamed: no copy in memory
                data = np.ascontiguousarray(array) if np.ndim(array) else np.asarray(array)
                np.lib.format.write_array(member, data, allow_pickle=False)


@dataclass(frozen=True)
class RecordingData:
    """A recording read back: columns as arrays, metadata, events."""

    path: Path
    columns: dict[str, np.ndarray]
    metadata: dict[str, Any]
    events: tuple[str, ...]
    units: dict[str, str] = field(default_factory=dict)
    formats: dict[str, str] = field(default_factory=dict)  # each column's CSV format, when the file says

    @property
    def n_rows(self) -> int:
        return len(self.columns["t_s"])


def recording_path(path: str | Path) -> Path:
    """The file that holds a recording: ``path``, or the journal of an NPZ run killed before its
    close; RecordingError when neither exists."""
    path = Path(path)
    if not path.exists():
        journal = journal_path_of(path)
        if path.suffix == ".npz" and journal.exists():
            check_regular(journal)
            return journal
        raise RecordingError(f"recording {path}: no such file")
    check_regular(path)
    return path


def check_regular(path: Path) -> None:
    """Refuse what is not a regular file (after symlinks) before it is opened: a FIFO's open blocks
    for ever, a device such as /dev/zero reads without end (zipfile would hold all of it)."""
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        raise RecordingError(f"recording {path}: cannot read ({exc.strerror or 'stat failed'})") from None
    if not stat.S_ISREG(mode):
        kind = "a directory" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode) else \
            "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "a socket" if stat.S_ISSOCK(mode) else "special"
        raise RecordingError(f"recording {path}: not a regular file ({kind})")


def parse_json(where: str | Path, what: str, text: str | bytes) -> Any:
    """JSON a recording holds (its metadata, a journal's header), one RecordingError line when it
    is not: text that is not JSON, or nests deeper than the parser's stack (a hostile file)."""
    try:
        return json.loads(text)
    except RecursionError:
        raise RecordingError(f"recording {where}: {what} nests too deeply to be read") from None
    except json.JSONDecodeError as exc:
        raise RecordingError(f"recording {where}: {what} is not valid JSON (line {exc.lineno}, column {exc.colno})") \
            from None
    except (ValueError, TypeError):  # bytes that are not UTF-8
        raise RecordingError(f"recording {where}: {what} is not JSON text") from None


def unreadable(where: str | Path, exc: BaseException) -> RecordingError:
    """A reader's failure the checks did not name, in words for the user (no Python exception text)."""
    if isinstance(exc, zipfile.BadZipFile):
        crc = re.match(r"Bad CRC-32 for file '(.{1,80})'", str(exc))
        reason = f"member {crc.group(1)} is damaged (its CRC-32 does not match)" if crc else \
            "not an NPZ archive (not a zip file, or cut short)" if "not a zip file" in str(exc) else \
            "a damaged NPZ archive"
    elif isinstance(exc, UnicodeDecodeError):
        reason = "not UTF-8 text"
    elif isinstance(exc, json.JSONDecodeError):
        reason = f"not valid JSON (line {exc.lineno}, column {exc.colno})"
    elif isinstance(exc, RecursionError):
        reason = "nests too deeply to be read"
    elif isinstance(exc, KeyError) and "no item named" in str(exc):
        member = re.search(r"named '(.{1,80})'", str(exc))
        reason = f"no member {member.group(1)} in the archive" if member else "a member is missing from the archive"
    elif isinstance(exc, OSError):
        reason = f"cannot read ({exc.strerror or 'I/O error'})"
    elif isinstance(exc, (EOFError, struct.error)):
        reason = "cut short"
    elif isinstance(exc, MemoryError):
        reason = "needs more memory than there is"
    else:
        reason = "damaged, or not a recording written by hilbench"
    return RecordingError(f"recording {where}: unreadable ({reason})")


def read_recording(path: str | Path) -> RecordingData:
    """Read a CSV, NPZ or NPZ journal recording; a truncated tail is tolerated. What is read is
    checked (hilbench.bench.recording_checks): a damaged file is one RecordingError line."""
    path = recording_path(path)
    try:
        if path.name.endswith(JOURNAL_SUFFIX):
            data = _read_journal(path)
        elif path.suffix.lower() == ".npz":
            data = _read_npz(path)
        else:
            data = _read_csv(path)
        return _checked(data)
    except RecordingError:
        raise
    except (OSError, ValueError, KeyError, EOFError, IndexError, TypeError, AttributeError, OverflowError,
            RecursionError, struct.error, zipfile.BadZipFile, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise unreadable(path, exc) from None  # (NumPy's advice for foreign bytes, allow_pickle, never given)


def _checked(data: RecordingData) -> RecordingData:
    from hilbench.bench import recording_checks as check

    where = str(data.path)
    metadata = check.check_metadata(where, data.metadata)
    columns = check.check_columns(where, data.columns, ("t_s", "marker"))
    events = check.check_events(where, data.events)
    units = {str(k): str(v) for k, v in data.units.items()}
    formats = {str(k): str(v) for k, v in data.formats.items() if _csv_format(v)}
    return RecordingData(data.path, columns, metadata, events, units, formats)


def _csv_format(text: object) -> bool:
    """A printf format of one number (what export_csv may use), e.g. %.3f or %d; nothing else."""
    import re

    return isinstance(text, str) and re.fullmatch(r"%[-+ 0#]?\d{0,2}(\.\d{1,2})?[dfgeE]", text) is not None


def _csv_lines(handle: Any, path: Path) -> Any:
    """The file's lines, each within its limit (a ``#`` line RECORDING_META_MAX_BYTES, a row or the
    header RECORDING_LINE_MAX_BYTES): RecordingError at the first longer one."""
    from hilbench.limits import RECORDING_LINE_MAX_BYTES, RECORDING_META_MAX_BYTES

    while line := handle.readline(RECORDING_META_MAX_BYTES + 1):
        if len(line) > RECORDING_META_MAX_BYTES and not line.endswith("\n"):
            raise RecordingError(f"recording {path}: a line longer than {RECORDING_META_MAX_BYTES} characters")
        if len(line) > RECORDING_LINE_MAX_BYTES and not line.startswith("#"):
            raise RecordingError(f"recording {path}: a row or header longer than {RECORDING_LINE_MAX_BYTES} characters")
        yield line


def _csv_comment(line: str, metadata: dict[str, Any], events: list[str]) -> bool:
    """A ``# event: ...`` or ``# key: JSON`` line into events or metadata (False: not a comment)."""
    if line.startswith("# event: "):
        events.append(line[len("# event: "):].rstrip("\n"))
        return True
    if not line.startswith("# "):
        return False
    key, _, value = line[2:].partition(": ")
    try:
        metadata[key] = json.loads(value)
    except (json.JSONDecodeError, RecursionError):
        metadata[key] = value.rstrip("\n")
    return True


def _csv_header(path: Path, line: str) -> tuple[list[str], dict[str, str]]:
    from hilbench.bench.recording_checks import check_columns_fit

    cells = line.strip().split(",")
    names = [cell.split("[", 1)[0] for cell in cells]
    units = {cell.split("[", 1)[0]: cell.split("[", 1)[1].rstrip("]") for cell in cells if "[" in cell}
    if "t_s" not in names or "marker" not in names or len(set(names)) != len(names):
        raise RecordingError(f"recording {path}: not a hilbench CSV (header does not match)")
    check_columns_fit(str(path), len(names), 0)
    return names, units


def _read_csv(path: Path) -> RecordingData:
    from hilbench.bench.recording_checks import check_columns_fit

    metadata: dict[str, Any] = {}
    events: list[str] = []
    header: dict[str, Any] = {}
    blocks: list[np.ndarray] = []
    for block in csv_blocks(path, metadata, events, header):
        blocks.append(block)
        if len(block) == 4096:
            check_columns_fit(str(path), len(header["names"]), 4096 * len(blocks))
    names: list[str] = header["names"]
    table = np.concatenate(blocks) if len(blocks) > 1 else blocks[0]
    columns = {name: table[:, i].copy() for i, name in enumerate(names)}
    return RecordingData(path, columns, metadata, tuple(events), header["units"])


def csv_blocks(path: Path, metadata: dict[str, Any], events: list[str], header: dict[str, Any],
               block_rows: int = 4096) -> Iterator[np.ndarray]:
    """A CSV recording's rows as float64 blocks of ``block_rows`` rows (the last one shorter, maybe
    empty); its header's names and units go into ``header`` before the first block, its metadata
    and events into theirs as they are read. A row cut by a crash ends the file; one with rows
    after it is a damaged file (RecordingError)."""
    block: list[list[float]] = []
    names: list[str] | None = None
    torn: tuple[int, int] | None = None  # (line, cells) of a row cut by a crash: only the last row may be
    n = 0
    with open(path, encoding="utf-8") as handle:
        lines = _csv_lines(handle, path)
        while True:
            try:
                line = next(lines, None)
            except UnicodeDecodeError:  # (decoded a few KB ahead of the lines: the line is not exact)
                raise RecordingError(f"recording {path}: not UTF-8 text (at or after line {n + 1})") from None
            if line is None:
                break
            n += 1
            if _csv_comment(line, metadata, events):
                continue
            if names is None:
                names, header["units"] = _csv_header(path, line)
                header["names"] = names
                continue
            if torn is not None:  # rows after a damaged one: not a crash's cut, the file is damaged
                raise RecordingError(f"recording {path}: line {torn[0]}: a row of {torn[1]} values, the header names "
                                     f"{len(names)}, and rows follow it")
            cells = line.rstrip("\n").split(",")
            if len(cells) != len(names) or not line.endswith("\n"):
                torn = (n, len(cells))  # a row cut by a crash: everything before it stands
                continue
            try:
                block.append([float(cell) for cell in cells])
            except ValueError:
                column, cell = next((names[i], c) for i, c in enumerate(cells) if not _is_float(c))
                raise RecordingError(f"recording {path}: line {n}: column {column[:40]}: {_json_shown(cell)} is not a "
                                     f"number") from None
            if len(block) >= block_rows:  # rows into arrays as they come: a list of floats is 4x their size
                yield np.asarray(block, dtype=float)
                block = []
    if names is None:
        raise RecordingError(f"recording {path}: no header line (empty or not a hilbench CSV)")
    yield np.asarray(block, dtype=float).reshape(-1, len(names))


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _read_journal_rows(path: Path, head_only: bool = False) -> tuple[dict[str, Any], RowLayout, Any]:
    """A journal's metadata, row layout and raw rows (to_columns drops a torn last row; with
    ``head_only`` no rows are read; else they are mapped, not read into memory)."""
    from hilbench.limits import RECORDING_META_MAX_BYTES

    with open(path, "rb") as handle:
        raw = handle.read(8)
        if raw[:4] != _JOURNAL_MAGIC or len(raw) < 8:
            raise RecordingError(f"recording {path}: not a hilbench journal (or written before its first row)")
        (head_len,) = struct.unpack_from("<I", raw, 4)
        if head_len > RECORDING_META_MAX_BYTES:
            raise RecordingError(f"recording {path}: a header of {head_len} bytes, more than the limit of "
                                 f"{RECORDING_META_MAX_BYTES // (1024 * 1024)} MiB")
        head_bytes = handle.read(head_len)
    if len(head_bytes) < head_len:
        raise RecordingError(f"recording {path}: the header is cut short")
    head = parse_json(path, "the header", head_bytes)
    if not isinstance(head, dict) or not isinstance(head.get("layout"), dict):
        raise RecordingError(f"recording {path}: not a hilbench journal (no row layout in its header)")
    try:
        layout = RowLayout.from_json(head["layout"])
    except ValueError as exc:  # from_json's own words, naming the field
        raise RecordingError(f"recording {path}: header: {exc}") from None
    if head_only:
        return head.get("metadata"), layout, b""
    start = 8 + head_len
    n_rows = max(0, (path.stat().st_size - start) // layout.dtype.itemsize)  # a torn last row is dropped
    from hilbench.bench.recording_checks import check_columns_fit

    check_columns_fit(str(path), len(layout.columns), n_rows)
    rows = np.memmap(path, dtype=layout.dtype, mode="r", offset=start, shape=(n_rows,)) if n_rows else \
        np.zeros(0, dtype=layout.dtype)
    return head.get("metadata"), layout, rows


#: the names of an NPZ recording's files while its run goes on: its journal, the journal's events
#: side file, and the archive before it takes the recording's name (each the recording's name + these)
JOURNAL_SUFFIX, EVENTS_SUFFIX, TMP_ARCHIVE_SUFFIX = ".journal", ".events", ".tmp.npz"


def journal_path_of(path: Path) -> Path:
    """The journal an NPZ recording's rows go to while its run goes on (kept when it is killed)."""
    return path.with_name(path.name + JOURNAL_SUFFIX)


def held_by_a_running_session(path: Path | str) -> bool:
    """Whether ``path``, after symlinks, names a file of a recording a running session writes: the
    recording (a CSV), an NPZ's journal, events side file or temporary archive, or the name the NPZ's
    archive takes at its end. What another output (a save, a step's CSV, a plot) must not write."""
    real = Path(os.path.realpath(path))
    if not real.name:  # ("/": nothing a recording is named)
        return False
    names = [real, journal_path_of(real)]
    if real.name.endswith(JOURNAL_SUFFIX + EVENTS_SUFFIX):  # (an events side file: its journal's)
        names.append(real.with_name(real.name[:-len(EVENTS_SUFFIX)]))
    if real.name.endswith(TMP_ARCHIVE_SUFFIX):  # (a temporary archive: its recording's journal)
        names.append(journal_path_of(real.with_name(real.name[:-len(TMP_ARCHIVE_SUFFIX)])))
    return any(held_elsewhere(name) for name in names)


def _tmp_archive_path_of(path: Path) -> Path:
    """Where an NPZ recording's archive is written before it takes the recording's name."""
    return path.with_name(path.name + TMP_ARCHIVE_SUFFIX)


def _events_path(journal: Path) -> Path:
    """The side file where an NPZ run's events wait, a line each, until the archive is written."""
    return journal.with_name(journal.name + EVENTS_SUFFIX)


def _read_journal(path: Path) -> RecordingData:
    from hilbench.limits import RECORDING_META_MAX_BYTES, read_text_bounded

    metadata, layout, rows = _read_journal_rows(path)
    with np.errstate(over="ignore", invalid="ignore"):  # a huge scale: infinities, judged by the checks
        columns = layout.to_columns(rows)
    del rows
    side = _events_path(path)
    events = read_text_bounded(side, RECORDING_META_MAX_BYTES, RecordingError, f"recording {side}").splitlines() \
        if side.exists() else []
    units = {name: unit for name, unit, _ in layout.column_specs}
    formats = {name: fmt for name, _, fmt in layout.column_specs}
    return RecordingData(path, columns, metadata, tuple(events), units, formats)


def _npz_members(path: Path, archive: zipfile.ZipFile) -> None:
    """Refuse an archive before NumPy reads it: too many members, a metadata member beyond its
    limit, a member whose header promises more values than the member holds (np.load would
    allocate what the header says), or more column data than a recording may have."""
    from hilbench.bench.recording_checks import check_columns_fit
    from hilbench.limits import RECORDING_META_MAX_BYTES

    infos = archive.infolist()
    check_columns_fit(str(path), len(infos) - 1, 0)
    n_rows = 0
    for info in infos:
        if info.filename == "metadata.npy":
            if info.file_size > RECORDING_META_MAX_BYTES:
                raise RecordingError(f"recording {path}: metadata of {info.file_size} bytes, more than the limit of "
                                     f"{RECORDING_META_MAX_BYTES // (1024 * 1024)} MiB")
            continue
        with archive.open(info) as member:
            shape, dtype = npy_header(path, info.filename, member)
            header_end = member.tell()
        count = int(np.prod(shape, dtype=np.int64)) if shape else 1
        if dtype.hasobject or count < 0 or header_end + count * dtype.itemsize > info.file_size:
            raise RecordingError(f"recording {path}: member {info.filename[:40]} promises {count} values of "
                                 f"{dtype} in {info.file_size} bytes")
        n_rows = max(n_rows, count)
    check_columns_fit(str(path), len(infos) - 1, n_rows)


def npy_header(path: Path, name: str, member: Any) -> tuple[tuple[int, ...], np.dtype]:
    """An NPZ member's shape and dtype from its header; RecordingError naming the member when the
    header is not one NumPy writes."""
    try:
        version = np.lib.format.read_magic(member)
        read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else \
            np.lib.format.read_array_header_2_0
        shape, _, dtype = read_header(member)
    except (ValueError, TypeError, SyntaxError, EOFError, struct.error):
        raise RecordingError(f"recording {path}: member {name[:40]} has no valid NumPy array header") from None
    return tuple(shape), dtype


def npz_metadata(path: Path, archive: zipfile.ZipFile) -> Any:
    """The metadata member of an NPZ archive as parsed JSON (its type not yet checked)."""
    if "metadata.npy" not in archive.namelist():
        raise RecordingError(f"recording {path}: no metadata member (metadata.npy) in the archive")
    with archive.open("metadata.npy") as member:
        try:
            text = str(np.lib.format.read_array(member, allow_pickle=False))
        except (ValueError, TypeError, SyntaxError, EOFError, struct.error):
            raise RecordingError(f"recording {path}: member metadata.npy is not a NumPy array of text") from None
    return parse_json(path, "metadata", text)


def _read_npz(path: Path) -> RecordingData:
    with zipfile.ZipFile(path) as archive:
        _npz_members(path, archive)
        metadata = npz_metadata(path, archive)
    with np.load(path, allow_pickle=False) as archive:
        if not isinstance(metadata, dict):
            raise RecordingError(f"recording {path}: metadata is not a table")
        specs = metadata.get("columns") or [list(spec) for spec in COLUMNS]  # [name, unit(, format)]
        if not isinstance(specs, list) or not all(isinstance(s, list) and len(s) in (2, 3) for s in specs):
            raise RecordingError(f"recording {path}: metadata columns is not a list of [name, unit(, format)]")
        members = set(archive.files)
        missing = [str(spec[0]) for spec in specs if str(spec[0]) not in members]
        if missing:
            raise RecordingError(f"recording {path}: no column {missing[0][:40]} in the archive")
        columns = {str(spec[0]): archive[str(spec[0])] for spec in specs}
    units = {str(spec[0]): str(spec[1]) for spec in specs}
    formats = {str(spec[0]): str(spec[2]) for spec in specs if len(spec) > 2}
    return RecordingData(path, columns, metadata, tuple(metadata.get("events", ())), units, formats)


class MemoryRecorder:
    """The Recorder interface kept in memory: every row, for step tests and analysis."""

    def __init__(self, metadata: dict[str, Any] | None = None) -> None:
        self.path = Path("<memory>")
        self.metadata = dict(metadata or {})
        self.rows = RowBuffer()
        self.events: list[tuple[int, str, int]] = []
        self.append = self.rows.append
        self.closed = False

    def start(self, layout: RowLayout = COLUMN_LAYOUT) -> None:
        if layout != self.rows.layout:
            self.rows.configure(layout)
            self.append = self.rows.append

    @property
    def rows_written(self) -> int:
        return len(self.rows)

    def event(self, text: str, marker: int = MARKER_NONE) -> None:
        self.events.append((self.rows_written, text, marker))

    def mark_last(self, marker: int) -> None:
        self.rows.settle(self.events)
        self.rows.mark_last(marker)

    def maybe_flush(self) -> None:
        """Nothing to flush: rows stay in memory."""

    def flush(self) -> None:
        """Nothing to flush: rows stay in memory."""

    def close(self, final_note: str | None = None) -> None:
        if final_note:
            self.event(final_note)
        self.closed = True

    def columns(self, names: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """Every column (or those named: a step test's few) as an array, markers applied (read in
        place once the run has closed the recorder: its rows are no longer appended to meanwhile)."""
        self.rows.settle(self.events)
        return self.rows.columns(names, in_place=self.closed)


class WindowRecorder:
    """Rows kept only for a live view, never saved: a run without a recording whose scope asked for
    its stream. At most ``flush_rows`` rows are held; each flush drops them (the scope's display
    stream takes them just before), so memory stays flat however long the run. ``path`` is None and
    ``rows_written`` 0: nothing is recorded."""

    path = None
    closed = False

    def __init__(self, flush_rows: int) -> None:
        self.flush_rows = max(1, flush_rows)
        self.metadata: dict[str, Any] = {}
        self.rows = RowBuffer()
        self.events: list[tuple[int, str, int]] = []
        self.append = self.rows.append
        self.rows_written = 0

    def start(self, layout: RowLayout = COLUMN_LAYOUT) -> None:
        if layout != self.rows.layout:
            self.rows.configure(layout)
            self.append = self.rows.append

    def event(self, text: str, marker: int = MARKER_NONE) -> None:
        self.events.append((len(self.rows), text, marker))
        if len(self.events) > 4 * _WINDOW_EVENTS:  # a script writing events in a loop: keep the newest
            del self.events[:-_WINDOW_EVENTS]

    def mark_last(self, marker: int) -> None:
        self.rows.settle(self.events)
        self.rows.mark_last(marker)

    def maybe_flush(self) -> None:
        if len(self.rows) >= self.flush_rows:
            self.flush()

    def rows_to_write(self) -> int:
        """How many more rows before `maybe_flush` drops them."""
        return self.flush_rows - len(self.rows)

    def flush(self) -> None:
        """Drop the rows held (the buffer object stays: the session's loop holds it); events noted at
        the next row to come move to the new first row."""
        n_rows = len(self.rows)
        self.events = [(index - n_rows, text, marker) for index, text, marker in self.events if index >= n_rows]
        self.rows.clear()

    def close(self, final_note: str | None = None) -> None:
        self.closed = True


#: events a `WindowRecorder` keeps at least
_WINDOW_EVENTS = 1000


def export_csv(data: RecordingData, path: str | Path) -> Path:
    """Write a recording (e.g. a fast NPZ one) as the same CSV a `--record run.csv` run writes."""
    from hilbench.bench.column_chunks import ArrayChunks
    from hilbench.bench.csv_export import export_csv_chunks
    from hilbench.bench.recording_head import RecordingHead

    head = RecordingHead(data.path, data.metadata, data.events, data.units, data.formats)
    return export_csv_chunks(head, ArrayChunks(data.columns, data.units), path)
