"""A recording's columns a chunk of rows at a time: what judges a long run in bounded memory.

A run's [[check]] tables read a few columns of a recording that may hold 12 M rows (600 s at
20 kHz). Reading it whole (`read_recording`: every column as float64 at once, and copies) took
2.9 GB at the close of a 600 s run. A `ColumnChunks` hands out only the columns asked for,
CHUNK_ROWS rows at a time, from the NPZ archive, its journal (a killed run) or the CSV, each chunk
checked by the rules `read_recording` applies (hilbench.bench.recording_checks: numbers, as many
rows as t_s, t_s finite and increasing across chunks, the whole-number columns finite).

The NPZ members are read through `zipfile` (stored or deflated alike) into one chunk's bytes; a
memory map would count every page it touched in the process's RSS.
"""

from __future__ import annotations

import os
import struct
import zipfile
from abc import ABC, abstractmethod
from pathlib import Path
from typing import IO, Iterator, Mapping, Sequence

import numpy as np

from hilbench.bench import recording_checks as rules
from hilbench.bench.recorder import (COLUMNS, JOURNAL_SUFFIX, _npz_members, _read_journal_rows, csv_blocks, npy_header,
                                     npz_metadata, recording_path, unreadable)
from hilbench.errors import RecordingError

#: rows per chunk: 0.5 MB a float64 column
CHUNK_ROWS = 65536

Chunk = dict[str, np.ndarray]


class ColumnChunks(ABC):
    """Named float64 columns of equal length, read ``chunk_rows`` rows at a time."""

    names: tuple[str, ...]
    units: dict[str, str]
    where = "in memory"  # the file, in a RecordingError

    @abstractmethod
    def _chunks(self, names: Sequence[str], chunk_rows: int) -> Iterator[Chunk]:
        """The columns ``names`` (t_s among them) in chunks of at most ``chunk_rows`` rows."""

    def chunks(self, names: Sequence[str], chunk_rows: int = CHUNK_ROWS) -> Iterator[Chunk]:
        """``names`` and t_s, chunk by chunk in row order (KeyError: a column the recording does not have)."""
        wanted = list(dict.fromkeys(["t_s", *names]))
        for name in wanted:
            if name not in self.names:
                raise KeyError(name)
        return self._read(wanted, max(1, chunk_rows))

    def _read(self, names: Sequence[str], chunk_rows: int) -> Iterator[Chunk]:
        """`_chunks`, a file that turns out damaged on the way as one RecordingError line."""
        try:
            yield from self._chunks(names, chunk_rows)
        except RecordingError:
            raise
        except (OSError, ValueError, EOFError, struct.error, zipfile.BadZipFile, MemoryError) as exc:
            raise unreadable(self.where, exc) from None

    def whole(self, names: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """The columns ``names`` (default: all) as whole arrays: for a short run only (a step test)."""
        pieces: dict[str, list[np.ndarray]] = {name: [] for name in (self.names if names is None else names)}
        for chunk in self.chunks(list(pieces)):
            for name, values in pieces.items():
                values.append(chunk[name])
        return {name: np.concatenate(values) if values else np.zeros(0) for name, values in pieces.items()}


class ArrayChunks(ColumnChunks):
    """Columns already in memory (a run that kept its rows): chunks are views, nothing is copied."""

    def __init__(self, columns: Mapping[str, np.ndarray], units: Mapping[str, str] | None = None) -> None:
        self._columns = columns
        self.names = tuple(columns)
        self.units = dict(units or {})

    def _chunks(self, names: Sequence[str], chunk_rows: int) -> Iterator[Chunk]:
        n_rows = len(self._columns["t_s"])
        for first in range(0, n_rows, chunk_rows):
            yield {name: np.asarray(self._columns[name][first:first + chunk_rows]) for name in names}


class AliasChunks(ColumnChunks):
    """Another source's columns with more names: ``aliases`` maps a new name to the column it reads
    (a monitor run's measured speed standing for ``speed_rpm``)."""

    def __init__(self, source: ColumnChunks, aliases: Mapping[str, str]) -> None:
        self._source = source
        self._aliases = {new: old for new, old in aliases.items() if old in source.names}
        self.names = tuple(dict.fromkeys([*source.names, *self._aliases]))
        self.units = {**source.units, **{new: source.units.get(old, "") for new, old in self._aliases.items()}}

    def _chunks(self, names: Sequence[str], chunk_rows: int) -> Iterator[Chunk]:
        read = list(dict.fromkeys(self._aliases.get(name, name) for name in names))
        for chunk in self._source.chunks(read, chunk_rows):
            yield {name: chunk[self._aliases.get(name, name)] for name in names}


class _Checked:
    """Each chunk of one file by `recording_checks`' rules, with the whole recording's row numbers."""

    def __init__(self, where: str) -> None:
        self.where = where
        self.first_row = 0
        self.t_last: float | None = None

    def __call__(self, chunk: Chunk) -> Chunk:
        rules.check_chunk(self.where, self.first_row, chunk, self.t_last)
        t = chunk["t_s"]
        if len(t):
            self.first_row += len(t)
            self.t_last = float(t[-1])
        return chunk


class NpzChunks(ColumnChunks):
    """The columns of an NPZ archive, each member read a chunk at a time."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.where = str(path)
        with zipfile.ZipFile(path) as archive:
            _npz_members(path, archive)  # a member promising more than it holds is refused before any read
            metadata = npz_metadata(path, archive)
            members = {info.filename for info in archive.infolist()}
        if not isinstance(metadata, dict):
            raise RecordingError(f"recording {path}: metadata is not a table")
        specs = metadata.get("columns") or [list(spec) for spec in COLUMNS]  # [name, unit(, format)]
        if not isinstance(specs, list) or not all(isinstance(s, list) and len(s) in (2, 3) for s in specs):
            raise RecordingError(f"recording {path}: metadata columns is not a list of [name, unit(, format)]")
        missing = [str(spec[0]) for spec in specs if f"{spec[0]}.npy" not in members]
        if missing:
            raise RecordingError(f"recording {path}: no column {missing[0][:40]} in the archive")
        self.names = tuple(str(spec[0]) for spec in specs)
        self.units = {str(spec[0]): str(spec[1]) for spec in specs}
        for name in ("t_s", "marker"):
            if name not in self.names:
                raise RecordingError(f"recording {path}: no column {name}")

    def _chunks(self, names: Sequence[str], chunk_rows: int) -> Iterator[Chunk]:
        checked = _Checked(self.where)
        with zipfile.ZipFile(self.path) as archive:
            members = {name: archive.open(f"{name}.npy") for name in names}
            try:
                n_rows: int | None = None
                dtypes: dict[str, np.dtype] = {}
                for name in names:  # t_s first: its length is every column's
                    shape, dtype = npy_header(self.path, f"{name}.npy", members[name])
                    rules.check_column_header(str(self.path), name, shape, dtype, n_rows)
                    n_rows = shape[0] if n_rows is None else n_rows
                    dtypes[name] = dtype
                assert n_rows is not None
                for first in range(0, n_rows, chunk_rows):
                    count = min(chunk_rows, n_rows - first)
                    yield checked({name: _read_values(members[name], dtypes[name], count, self.path)
                                   for name in names})
            finally:
                for member in members.values():
                    member.close()


def _read_values(member: IO[bytes], dtype: np.dtype, count: int, path: Path) -> np.ndarray:
    raw = member.read(count * dtype.itemsize)
    if len(raw) != count * dtype.itemsize:
        raise RecordingError(f"recording {path}: a member shorter than its header says")
    values = np.frombuffer(raw, dtype=dtype, count=count)
    return values.astype(np.float64)  # native float64, as `read_recording` gives every column


class JournalChunks(ColumnChunks):
    """The columns of an NPZ run's journal (a run killed before its archive was written)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.where = str(path)
        _, self._layout, _ = _read_journal_rows(path, head_only=True)
        self.names = self._layout.column_names
        self.units = {name: unit for name, unit, _ in self._layout.column_specs}

    def _chunks(self, names: Sequence[str], chunk_rows: int) -> Iterator[Chunk]:
        checked = _Checked(self.where)
        itemsize = self._layout.dtype.itemsize
        with open(self.path, "rb") as handle:
            (head_len,) = struct.unpack("<I", handle.read(8)[4:])
            start = 8 + head_len
            n_rows = max(0, (os.fstat(handle.fileno()).st_size - start) // itemsize)  # a torn last row is dropped
            handle.seek(start)
            for first in range(0, n_rows, chunk_rows):
                count = min(chunk_rows, n_rows - first)
                raw = handle.read(count * itemsize)
                if len(raw) != count * itemsize:
                    raise RecordingError(f"recording {self.path}: shorter than it was a moment ago")
                rows = np.frombuffer(raw, dtype=self._layout.dtype, count=count)
                with np.errstate(over="ignore", invalid="ignore"):  # a huge scale: infinities, judged by the checks
                    chunk = {name: self._layout.to_column(rows, name) for name in names}
                yield checked(chunk)


class CsvChunks(ColumnChunks):
    """The columns of a CSV recording, parsed a block of rows at a time."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.where = str(path)
        header: dict[str, object] = {}
        blocks = csv_blocks(path, {}, [], header, block_rows=1)
        try:
            next(blocks, None)  # the header line, and at most one row
        finally:
            blocks.close()
        names = header.get("names")
        units = header.get("units")
        assert isinstance(names, list) and isinstance(units, dict)
        self.names = tuple(names)
        self.units = {str(k): str(v) for k, v in units.items()}

    def _chunks(self, names: Sequence[str], chunk_rows: int) -> Iterator[Chunk]:
        checked = _Checked(self.where)
        index = {name: i for i, name in enumerate(self.names)}
        # parsed 4096 rows at a time at most: a row is a list of Python floats until its block is an array
        for block in csv_blocks(self.path, {}, [], {}, block_rows=min(chunk_rows, 4096)):
            if len(block):
                yield checked({name: block[:, index[name]].copy() for name in names})


def recording_chunks(path: str | Path) -> ColumnChunks:
    """A recording (CSV, NPZ, or the journal of an NPZ run killed before its close) to read in
    chunks; RecordingError, as `read_recording` says it, for a file that is not one."""
    path = recording_path(path)
    try:
        if path.name.endswith(JOURNAL_SUFFIX):
            return JournalChunks(path)
        if path.suffix.lower() == ".npz":
            return NpzChunks(path)
        return CsvChunks(path)
    except RecordingError:
        raise
    except (OSError, ValueError, KeyError, EOFError, TypeError, IndexError, RecursionError, MemoryError,
            struct.error, zipfile.BadZipFile, UnicodeDecodeError) as exc:
        raise unreadable(path, exc) from None


__all__ = ["AliasChunks", "ArrayChunks", "CHUNK_ROWS", "ColumnChunks", "CsvChunks", "JournalChunks", "NpzChunks",
           "recording_chunks"]
