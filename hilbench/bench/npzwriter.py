"""An NPZ archive of equal-length float64 columns written in one pass over the rows.

`np.savez` and `zipfile` write one member after another, so an archive of columns made from rows
either holds every row in memory or reads the rows once per column. Here every member's size is
known before the first byte (a stored, uncompressed ZIP64 member: the .npy header plus 8 bytes a
row), so each chunk of rows is converted once and each column's piece written at its own place in
the file, its CRC-32 carried along; the headers are written last, with the CRCs. Memory is one
chunk, whatever the number of rows; the rows are read once.

The file is a plain ZIP64 archive as `zipfile` writes one (stored members, fixed 1980-01-01
stamps, so equal columns give equal bytes), read by `np.load` and any unzip.

`BackgroundArchive` writes the same archive while a run goes on: the recorder hands it each chunk of
raw rows, which a thread of its own (hilbench/bench/_npzcolumns.c, without the GIL) writes to the
run's journal, then converts and writes into an archive sized for the rows the run plans; the close
then only writes the metadata and the directory. A run that records another number of rows has its
archive written from the journal at the close, as before.
"""

from __future__ import annotations

import functools
import io
import os
import struct
import zlib
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

from hilbench.bench.fileio import pwrite_all

try:  # the columns written on a thread of their own (optional; the journal path is the reference)
    from hilbench.bench import _npzcolumns
except ImportError:  # pragma: no cover - no compiler at install time
    _npzcolumns = None  # type: ignore[assignment]

if TYPE_CHECKING:
    from hilbench.bench.recorder import RowLayout


_DOS_DATE = (0 << 9) | (1 << 5) | 1  # 1980-01-01
_DOS_TIME = 0
_VERSION = 45  # ZIP64
_MADE_BY = (3 << 8) | _VERSION  # Unix
_FULL32 = 0xFFFFFFFF


def _npy(array: np.ndarray) -> bytes:
    """The .npy bytes of a small array (the metadata): numpy's own version 1.0 header, then the data
    as it is in memory (write_array's bytes for these, without its chunked copy loop: ~80 us of a run's
    close, measured cold after a 1 s run). Records (whose header may need version 2.0), objects and
    other orders go to write_array itself."""
    out = io.BytesIO()
    if array.dtype.hasobject or array.dtype.names is not None or not array.flags.c_contiguous:
        np.lib.format.write_array(out, array, allow_pickle=False)
    else:
        np.lib.format.write_array_header_1_0(out, np.lib.format.header_data_from_array_1_0(array))
        out.write(array.tobytes())
    return out.getvalue()


@functools.lru_cache(maxsize=16)  # (a sweep's runs plan the same rows)
def _column_header(n_rows: int) -> bytes:
    out = io.BytesIO()
    np.lib.format.write_array_header_1_0(out, {"descr": "<f8", "fortran_order": False, "shape": (n_rows,)})
    return out.getvalue()


_LOCAL_FIXED = 30 + 20  # a local header's fixed fields and its ZIP64 extra field (name between them)


def _local_header(name: bytes, crc: int, size: int) -> bytes:
    extra = struct.pack("<HHQQ", 0x0001, 16, size, size)
    return struct.pack("<IHHHHHIIIHH", 0x04034B50, _VERSION, 0, 0, _DOS_TIME, _DOS_DATE, crc, _FULL32, _FULL32,
                       len(name), len(extra)) + name + extra


def _central_header(name: bytes, crc: int, size: int, offset: int) -> bytes:
    extra = struct.pack("<HHQQQ", 0x0001, 24, size, size, offset)
    return struct.pack("<IHHHHHHIIIHHHHHII", 0x02014B50, _MADE_BY, _VERSION, 0, 0, _DOS_TIME, _DOS_DATE, crc,
                       _FULL32, _FULL32, len(name), len(extra), 0, 0, 0, 0o600 << 16, _FULL32) + name + extra


def _end_records(n_members: int, directory_offset: int, directory_size: int) -> bytes:
    zip64_end = struct.pack("<IQHHIIQQQQ", 0x06064B50, 44, _MADE_BY, _VERSION, 0, 0, n_members, n_members,
                            directory_size, directory_offset)
    locator = struct.pack("<IIQI", 0x07064B50, 0, directory_offset + directory_size, 1)
    end = struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, min(n_members, 0xFFFF), min(n_members, 0xFFFF),
                      min(directory_size, _FULL32), _FULL32, 0)
    return zip64_end + locator + end


class ColumnArchive:
    """Write ``names`` (float64 columns of ``n_rows``) and then ``extra`` small arrays into ``path``.

        with ColumnArchive(path, names, n_rows) as archive:
            for first in range(0, n_rows, chunk):
                archive.write(first, {name: values, ...})   # every column's rows first.. (any order)
            archive.add("metadata", np.asarray(text))
    """

    def __init__(self, path: Path, names: Sequence[str], n_rows: int, *, write_headers: bool = True) -> None:
        """``write_headers=False``: each column's ZIP local header (`local_header`, with the CRC
        `written` gives) and .npy header (`column_header`), before its row 0, are the caller's to write
        (`BackgroundArchive`'s thread)."""
        self.path = path
        self.n_rows = n_rows
        self._write_headers = write_headers
        self._header = _column_header(n_rows)
        self._members: list[tuple[bytes, int, int, int]] = []  # name, local header offset, data offset, size
        size = len(self._header) + 8 * n_rows
        offset = 0
        for name in names:
            member = f"{name}.npy".encode()
            data_offset = offset + _LOCAL_FIXED + len(member)
            self._members.append((member, offset, data_offset, size))
            offset = data_offset + size
        self._end = offset
        self._crc: dict[str, int] = {}
        self._written = dict.fromkeys(names, 0)
        self._index = {name: i for i, name in enumerate(names)}
        self._small: list[tuple[bytes, int, bytes]] = []  # name, crc, bytes
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o644)
        try:
            header_crc = zlib.crc32(self._header)
            for name, (_, _, data_offset, _) in zip(names, self._members):
                if write_headers:
                    pwrite_all(self._fd, memoryview(self._header), data_offset)
                self._crc[name] = header_crc
        except BaseException:  # a full disk already: no descriptor left open
            self.abandon()
            raise

    @property
    def column_header(self) -> bytes:
        """The .npy header every column's member starts with."""
        return self._header

    def write(self, first: int, columns: dict[str, np.ndarray]) -> None:
        """Rows ``first..`` of each column; a column's pieces come in row order."""
        for name, values in columns.items():
            if self._written[name] != first:
                raise ValueError(f"column {name}: rows from {first}, expected from {self._written[name]}")
            data = np.ascontiguousarray(values, dtype="<f8").data.cast("B")
            _, _, data_offset, _ = self._members[self._index[name]]
            pwrite_all(self._fd, data, data_offset + len(self._header) + 8 * first)
            self._crc[name] = zlib.crc32(data, self._crc[name])
            self._written[name] = first + len(values)

    def local_header(self, index: int) -> bytes:
        """Column ``index``'s ZIP local header, its CRC-32 0 (at byte 14: the writer puts it there)."""
        member, _, _, size = self._members[index]
        return _local_header(member, 0, size)

    def places(self) -> list[tuple[int, int]]:
        """(file offset of row 0, CRC-32 so far) of each column, in order: where a writer of
        their rows (`BackgroundArchive`) puts them."""
        return [(data_offset + len(self._header), self._crc[name])
                for name, (_, _, data_offset, _) in zip(self._written, self._members)]

    def written(self, n_rows: int, crcs: Sequence[int]) -> None:
        """Every column's rows ``..n_rows`` were written elsewhere, with these CRCs (in order)."""
        for name, crc in zip(self._written, crcs, strict=True):
            self._crc[name] = crc
            self._written[name] = n_rows

    def add(self, name: str, array: np.ndarray) -> None:
        """A small array after the columns (the metadata)."""
        data = _npy(array)
        self._small.append((f"{name}.npy".encode(), zlib.crc32(data), data))

    def close(self) -> None:
        """The local headers with their CRCs (unless the caller writes them), the small members, the
        central directory."""
        short = [name for name, n in self._written.items() if n != self.n_rows]
        if short:
            raise ValueError(f"column {short[0]}: {self._written[short[0]]} of {self.n_rows} rows written")
        directory: list[bytes] = []
        for name, (member, offset, _, size) in zip(self._written, self._members):
            if self._write_headers:
                pwrite_all(self._fd, memoryview(_local_header(member, self._crc[name], size)), offset)
            directory.append(_central_header(member, self._crc[name], size, offset))
        offset = self._end
        for member, crc, data in self._small:
            local = _local_header(member, crc, len(data))
            pwrite_all(self._fd, memoryview(local + data), offset)
            directory.append(_central_header(member, crc, len(data), offset))
            offset += len(local) + len(data)
        table = b"".join(directory)
        pwrite_all(self._fd, memoryview(table + _end_records(len(directory), offset, len(table))), offset)
        fd, self._fd = self._fd, -1  # a close that fails has still released the number: never close it twice
        os.close(fd)

    def abandon(self) -> None:
        if self._fd >= 0:
            fd, self._fd = self._fd, -1
            os.close(fd)

    def __enter__(self) -> "ColumnArchive":
        return self

    def __exit__(self, kind: object, *rest: object) -> None:
        try:
            if kind is None:
                self.close()
        finally:
            self.abandon()  # the descriptor is closed whatever went wrong, a failed close too


class BackgroundArchive:
    """The archive of a run that plans ``n_rows`` rows of ``layout``, and its journal, written while
    it runs: `submit_rows(data)` hands a chunk of raw rows over (copied); a thread writes it to the
    journal at its place, then each column to the archive. `finish` completes the archive when
    exactly ``n_rows`` were handed over and written (False otherwise: the unfinished file is removed,
    the caller writes it from the journal). Every chunk handed over reaches the journal, whatever
    becomes of the archive, unless a journal write fails twice (`journal_failed`)."""

    def __init__(self, path: Path, layout: "RowLayout", n_rows: int, journal: Path, journal_offset: int) -> None:
        if _npzcolumns is None:
            raise RuntimeError("BackgroundArchive: the column writer is not built")
        self.path, self.n_rows = path, n_rows
        self.rows = 0  # handed over so far
        self.given_up = False  # more rows than planned, a failed write, or abandoned: `finish` says False
        self.failed: OSError | None = None  # the thread's failed archive write (or the journal write that gave it up)
        self.journal_failed: OSError | None = None  # a journal write that failed twice: rows not in the journal
        offsets, wraps = _field_offsets(layout), dict(layout.wrap)
        self._itemsize = layout.dtype.itemsize
        self._journal_fd = os.open(journal, os.O_WRONLY | os.O_CLOEXEC)
        try:
            self._archive = ColumnArchive(path, layout.column_names, n_rows, write_headers=False)
            columns = [(offsets[src][0], offsets[src][1], scale, wraps.get(name, 0.0), place, crc,
                        self._archive.local_header(j))
                       for j, ((name, _, _, src, scale), (place, crc)) in enumerate(zip(layout.columns,
                                                                                       self._archive.places()))]
            try:
                self._writer = _npzcolumns.ColumnWriter(self._archive._fd, self._journal_fd, journal_offset,
                                                        layout.dtype.itemsize, columns, self._archive.column_header,
                                                        planned_rows=n_rows)
            except BaseException:
                self._archive.abandon()
                raise
        except BaseException:
            os.close(self._journal_fd)
            raise

    def submit_rows(self, first_row: int, data: memoryview) -> bool:
        """Hand these whole raw rows over, the journal's rows from ``first_row`` on: True (taken, now
        or before: a chunk handed over again after an interruption is not taken twice), or False
        when the thread is done with (given up, or more rows than planned: the caller writes them to
        the journal itself). Raises OSError when a journal write failed twice (the rows of that chunk
        are not in it)."""
        n_rows = len(data) // self._itemsize
        taken = self.rows - first_row  # rows of these the writer took before (handed over, then interrupted)
        if taken >= n_rows:
            return True
        if taken > 0:
            data, first_row = data[taken * self._itemsize:], self.rows
        if self.given_up:
            return False
        if first_row + len(data) // self._itemsize > self.n_rows:  # more than planned: the journal writes the archive
            self.abandon()
            if self.journal_failed is not None:
                raise self.journal_failed
            return False
        try:
            self._writer.submit_rows(first_row, data)
        except OSError as exc:
            self.journal_failed = exc
            self.abandon()
            raise
        finally:  # (what the writer took, whatever interrupted it)
            self.rows = self._writer.queued
        return True

    def sync(self) -> None:
        """Return once every row handed over is in the journal (its reader sees them all). Raises
        OSError when a journal write failed twice."""
        if self.given_up:
            return
        try:
            self._writer.sync()
        except OSError as exc:
            self.journal_failed = exc
            self.abandon()
            raise

    @property
    def journaled(self) -> int:
        """Rows the thread has written to the journal."""
        return int(self._writer.journaled)

    def finish(self, metadata: np.ndarray) -> bool:
        """The archive complete with ``metadata`` (True: the journal's descriptor still open, for
        `release_journal`), or given up: another number of rows than
        planned, a failed write (False; the descriptors closed, the unfinished file removed; raises
        OSError when a journal write failed twice). Ctrl-C while the thread writes its last rows gives
        it up too (every row handed over journaled), and propagates."""
        if self.given_up or self.rows != self.n_rows:
            self.abandon()
            if self.journal_failed is not None:
                raise self.journal_failed
            return False
        try:
            n_rows, crcs = self._writer.finish()
            self._archive.written(n_rows, crcs)
            self._archive.add("metadata", metadata)
            self._archive.close()
        except OSError as exc:
            self.failed = exc
            self.abandon()
            if self.journal_failed is not None:
                raise self.journal_failed from None
            return False
        except BaseException:  # Ctrl-C while the thread finished: given up, the journal keeps every row
            self.abandon()
            raise
        return True

    def release_journal(self) -> None:
        """The journal's descriptor (kept open by `finish`) closed on a thread of its own: once the
        journal is unlinked, its last close frees its pages, work the run's close need not wait for."""
        fd, self._journal_fd = self._journal_fd, -1
        if fd >= 0:
            _npzcolumns.close_later(fd)

    def abandon(self) -> None:
        """The thread joined once every row handed over is in the journal (a journal write that failed
        twice: `journal_failed`), the archive's work dropped, the unfinished file emptied and removed
        (its blocks go back to a full disk, where the journal needs them), the descriptors closed
        (idempotent; a finished archive is left alone)."""
        self.given_up = True
        failed_errno = self._writer.abandon()
        if failed_errno is not None and self.journal_failed is None:
            self.journal_failed = OSError(failed_errno, os.strerror(failed_errno))
        if self._archive._fd >= 0:  # still ours: not finished
            try:
                os.ftruncate(self._archive._fd, 0)
                self.path.unlink(missing_ok=True)
            except OSError:  # the close writes the archive from the journal (or says why it cannot)
                pass
        self._archive.abandon()
        self._close_journal()

    def _close_journal(self) -> None:
        fd, self._journal_fd = self._journal_fd, -1  # (a close that fails has released the number: never twice)
        if fd >= 0:
            os.close(fd)

    def __del__(self) -> None:
        if getattr(self, "_writer", None) is not None:
            self.abandon()


def _field_offsets(layout: "RowLayout") -> dict[str, tuple[int, str]]:
    """Each field's (byte offset in a raw row, struct code)."""
    out, offset = {}, 0
    for name, code in layout.fields:
        out[name] = (offset, code)
        offset += struct.calcsize("<" + code)
    return out


__all__ = ["BackgroundArchive", "ColumnArchive"]
