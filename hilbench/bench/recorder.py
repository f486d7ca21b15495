"""Recordings: one row per period, written incrementally so a crash loses at most one chunk.

Two formats share one column schema:

* CSV (``run.csv``): ``#``-prefixed metadata lines (JSON: config, target HELLO, versions, seed),
  a header whose names carry units, then rows. Events (parameter changes, faults, scenario
  actions) are ``# event`` comment lines between rows, at the row where they happened, and the
  ``marker`` column is non-zero on that row. numpy.loadtxt and pandas (comment="#") read it.
* NPZ (``run.npz``): rows go to an append-only binary journal ``run.npz.journal`` (float64
  records) flushed every chunk; a clean close writes the ``.npz`` atomically and removes the
  journal. ``read_recording`` reads either, so a killed run is still readable.

A chunk is ``flush_rows`` periods (by default one simulated second at the run's period).
"""

from __future__ import annotations

import io
import json
import os
import struct
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from hilbench.errors import RecordingError

#: (name, unit, CSV format) of every column, in order.
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

_JOURNAL_MAGIC = b"HBJ1"


def csv_header() -> str:
    """The CSV header line: ``name[unit]`` per column."""
    return ",".join(f"{name}[{unit}]" if unit else name for name, unit, _ in COLUMNS)


class RowBuffer:
    """Rows of float64 packed into one bytearray: cheap to append (struct), free to view (numpy).

    The hot path binds ``pack`` and ``extend`` and calls ``extend(pack(v0, v1, ...))``: about 0.3 µs
    for a row of 22 numbers, where array('d').extend(tuple) costs 1.5 µs.
    """

    def __init__(self, width: int = N_COLUMNS) -> None:
        self.configure(width)

    def configure(self, width: int) -> None:
        """Set the row width (empties the buffer: call it before the first row)."""
        self.width = width
        self.struct = struct.Struct(f"<{width}d")
        self.pack = self.struct.pack
        self.data = bytearray()
        self.extend = self.data.extend

    def append(self, row: Sequence[float]) -> None:
        self.extend(self.pack(*row))

    def __len__(self) -> int:
        return len(self.data) // self.struct.size

    def mark_last(self, value: float) -> None:
        """Overwrite the last value of the newest row (the marker column)."""
        if self.data:
            struct.pack_into("<d", self.data, len(self.data) - 8, value)

    def table(self) -> np.ndarray:
        return np.frombuffer(self.data, dtype="<f8").reshape(-1, self.width).copy()

    def clear(self) -> None:
        del self.data[:]


@dataclass
class Recorder:
    """Collects rows in memory and writes them out every ``flush_rows`` rows."""

    path: Path
    metadata: dict[str, Any]
    flush_rows: int = 20_000
    rows: RowBuffer = field(default_factory=RowBuffer, repr=False)
    _events: list[tuple[int, str]] = field(default_factory=list, repr=False)
    _file: Any = field(default=None, repr=False)
    rows_written: int = 0
    closed: bool = False
    #: turns a chunk of appended rows (an array) into the COLUMNS; the session appends raw values
    #: cheaply (``rows.configure(width)``) and scales them here, once per chunk
    transform: Any = None

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        suffix = self.path.suffix.lower()
        if suffix not in (".csv", ".npz"):
            raise RecordingError(f"recording {self.path}: unknown format {suffix!r} (use .csv or .npz)")
        self.is_npz = suffix == ".npz"
        try:
            if self.is_npz:
                self._file = open(self._journal_path(), "wb")
                meta = json.dumps(self.metadata, default=str).encode()
                self._file.write(_JOURNAL_MAGIC + struct.pack("<II", N_COLUMNS, len(meta)) + meta)
            else:
                self._file = open(self.path, "w", encoding="utf-8", newline="\n")
                for key, value in self.metadata.items():
                    self._file.write(f"# {key}: {json.dumps(value, default=str)}\n")
                self._file.write(csv_header() + "\n")
            self._file.flush()
        except OSError as exc:
            raise RecordingError(f"recording {self.path}: cannot write ({exc.strerror})") from None
        self._fmt = ",".join(fmt for _, _, fmt in COLUMNS) + "\n"
        self.append = self.rows.append

    def _journal_path(self) -> Path:
        return self.path.with_name(self.path.name + ".journal")

    def event(self, text: str) -> None:
        """Note an event at the next row to be appended (after the rows appended so far)."""
        self._events.append((len(self.rows), text.replace("\n", " ")))

    def mark_last(self, marker: int) -> None:
        """Set the marker (the last value) of the newest pending row: the last good period."""
        self.rows.mark_last(float(marker))

    def maybe_flush(self) -> None:
        """Write out the pending chunk if it is full; cheap to call every period."""
        if len(self.rows) >= self.flush_rows:
            self.flush()

    def flush(self) -> None:
        """Write every pending row and event and push them to the OS."""
        events = self._events
        n_rows = len(self.rows)
        if not n_rows and not events:
            return
        try:
            table = self._table() if n_rows else np.zeros((0, N_COLUMNS))
            if self.is_npz:
                if n_rows:
                    self._file.write(np.ascontiguousarray(table, dtype="<f8").tobytes())
                for _, text in events:  # NPZ keeps events in the metadata at close
                    self.metadata.setdefault("events", []).append(text)
            else:
                self._file.write(self._format_csv(list(map(tuple, table.tolist())), events))
            self._file.flush()
        except OSError as exc:
            raise RecordingError(f"recording {self.path}: write failed ({exc.strerror})") from None
        self.rows_written += n_rows
        self.rows.clear()
        events.clear()

    def _table(self) -> np.ndarray:
        table = self.rows.table()
        if self.transform is not None:
            table = self.transform(table)
        if table.ndim != 2 or table.shape[1] != N_COLUMNS:
            raise RecordingError(f"recording {self.path}: rows have {table.shape} columns, expected {N_COLUMNS}")
        return table

    def _format_csv(self, rows: list[tuple[float, ...]], events: list[tuple[int, str]]) -> str:
        fmt = self._fmt
        if not events:
            return "".join([fmt % row for row in rows])
        parts: list[str] = []
        start = 0
        for index, text in events:
            parts.extend(fmt % row for row in rows[start:index])
            parts.append(f"# event: {text}\n")
            start = index
        parts.extend(fmt % row for row in rows[start:])
        return "".join(parts)

    def close(self, final_note: str | None = None) -> None:
        """Flush, note how the run ended, and (NPZ) write the archive atomically."""
        if self.closed:
            return
        if final_note:
            self.event(final_note)
            self.metadata["end"] = final_note
        self.flush()
        self.closed = True
        self._file.close()
        if self.is_npz:
            table = _journal_table(self._journal_path())
            tmp = self.path.with_name(self.path.name + ".tmp.npz")
            arrays: dict[str, np.ndarray] = {name: table[:, i] for i, name in enumerate(COLUMN_NAMES)}
            arrays["metadata"] = np.asarray(json.dumps(self.metadata, default=str))
            _write_npz_deterministic(tmp, arrays)
            os.replace(tmp, self.path)
            self._journal_path().unlink()


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

    @property
    def n_rows(self) -> int:
        return len(self.columns["t_s"])


def read_recording(path: str | Path) -> RecordingData:
    """Read a CSV, NPZ or NPZ journal recording; a truncated tail is tolerated."""
    path = Path(path)
    if not path.exists():
        journal = path.with_name(path.name + ".journal")
        if path.suffix == ".npz" and journal.exists():
            path = journal
        else:
            raise RecordingError(f"recording {path}: no such file")
    try:
        if path.name.endswith(".journal"):
            return _read_journal(path)
        if path.suffix.lower() == ".npz":
            return _read_npz(path)
        return _read_csv(path)
    except RecordingError:
        raise
    except (OSError, ValueError, KeyError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise RecordingError(f"recording {path}: unreadable ({exc})") from None


def _read_csv(path: Path) -> RecordingData:
    metadata: dict[str, Any] = {}
    events: list[str] = []
    values: list[list[float]] = []
    header_seen = False
    with open(path, encoding="utf-8") as handle:
        for line in handle:
            if line.startswith("# event: "):
                events.append(line[len("# event: "):].rstrip("\n"))
                continue
            if line.startswith("# "):
                key, _, value = line[2:].partition(": ")
                try:
                    metadata[key] = json.loads(value)
                except json.JSONDecodeError:
                    metadata[key] = value.rstrip("\n")
                continue
            if not header_seen:
                names = [cell.split("[", 1)[0] for cell in line.strip().split(",")]
                if tuple(names) != COLUMN_NAMES:
                    raise RecordingError(f"recording {path}: not a hilbench CSV (header does not match)")
                header_seen = True
                continue
            cells = line.rstrip("\n").split(",")
            if len(cells) != N_COLUMNS or not line.endswith("\n"):
                break  # a row cut by a crash: everything before it stands
            values.append([float(cell) for cell in cells])
    if not header_seen:
        raise RecordingError(f"recording {path}: no header line (empty or not a hilbench CSV)")
    table = np.asarray(values, dtype=float).reshape(-1, N_COLUMNS)
    return RecordingData(path, _columns(table), metadata, tuple(events))


def _journal_table(path: Path) -> np.ndarray:
    """The rows of a journal as an (n, columns) array read straight from the file."""
    with open(path, "rb") as handle:
        head = handle.read(12)
        if head[:4] != _JOURNAL_MAGIC:
            raise RecordingError(f"recording {path}: not a hilbench journal")
        n_columns, meta_len = struct.unpack_from("<II", head, 4)
        handle.seek(12 + meta_len)
        body = np.fromfile(handle, dtype="<f8")
    usable = len(body) - len(body) % n_columns
    return body[:usable].reshape(-1, n_columns)


def _read_journal(path: Path) -> RecordingData:
    raw = path.read_bytes()
    if raw[:4] != _JOURNAL_MAGIC:
        raise RecordingError(f"recording {path}: not a hilbench journal")
    n_columns, meta_len = struct.unpack_from("<II", raw, 4)
    start = 12 + meta_len
    metadata = json.loads(raw[12:start])
    body = raw[start:]
    usable = len(body) - len(body) % (8 * n_columns)
    table = np.frombuffer(body[:usable], dtype="<f8").reshape(-1, n_columns)
    return RecordingData(path, _columns(table), metadata, tuple(metadata.get("events", ())))


def _read_npz(path: Path) -> RecordingData:
    with np.load(path, allow_pickle=False) as archive:
        columns = {name: archive[name] for name in COLUMN_NAMES}
        metadata = json.loads(str(archive["metadata"]))
    return RecordingData(path, columns, metadata, tuple(metadata.get("events", ())))


def _columns(table: np.ndarray) -> dict[str, np.ndarray]:
    return {name: table[:, i].copy() for i, name in enumerate(COLUMN_NAMES)}


class MemoryRecorder:
    """The Recorder interface kept in memory: every row, for step tests and analysis."""

    def __init__(self, metadata: dict[str, Any] | None = None) -> None:
        self.path = Path("<memory>")
        self.metadata = dict(metadata or {})
        self.rows = RowBuffer()
        self.events: list[tuple[int, str]] = []
        self.append = self.rows.append
        self.closed = False
        self.transform: Any = None

    @property
    def rows_written(self) -> int:
        return len(self.rows)

    def event(self, text: str) -> None:
        self.events.append((self.rows_written, text))

    def mark_last(self, marker: int) -> None:
        self.rows.mark_last(float(marker))

    def maybe_flush(self) -> None:
        """Nothing to flush: rows stay in memory."""

    def flush(self) -> None:
        """Nothing to flush: rows stay in memory."""

    def close(self, final_note: str | None = None) -> None:
        if final_note:
            self.event(final_note)
        self.closed = True

    def columns(self) -> dict[str, np.ndarray]:
        """Every column as an array."""
        table = self.rows.table()
        if self.transform is not None and len(table):
            table = self.transform(table)
        return _columns(np.asarray(table).reshape(-1, N_COLUMNS))


def export_csv(data: RecordingData, path: str | Path) -> Path:
    """Write a recording (e.g. a fast NPZ one) as the same CSV a `--record run.csv` run writes."""
    out = Recorder(Path(path), dict(data.metadata), flush_rows=max(1, data.n_rows))
    table = np.column_stack([data.columns[name] for name in COLUMN_NAMES]) if data.n_rows else np.zeros((0, N_COLUMNS))
    out.rows.extend(np.ascontiguousarray(table, dtype="<f8").tobytes())
    out.close()
    return out.path
