"""Issue 23: an NPZ recording is written from its journal in one pass, a chunk at a time
(hilbench.bench.npzwriter), so the close's memory does not grow with the run's length
(benchmarks/bench_soak.py has the figures). The archive is a plain ZIP64 NPZ."""

from __future__ import annotations

import errno
import os
import resource
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

import hilbench
from _hostile import assert_one_line_error
from hilbench.bench import npzwriter
from hilbench.bench import recorder as recorder_module
from hilbench.bench.npzwriter import ColumnArchive
from hilbench.bench.recorder import read_recording
from hilbench.errors import RecordingError


def test_a_column_archive_is_an_npz_that_numpy_and_zip_read(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    columns = {"a": rng.normal(size=1000), "b": np.arange(1000.0), "c": np.full(1000, np.nan)}
    path = tmp_path / "x.npz"
    with ColumnArchive(path, list(columns), 1000) as archive:
        for first in range(0, 1000, 300):  # pieces in row order, columns in any order
            for name in reversed(list(columns)):
                archive.write(first, {name: columns[name][first:first + 300]})
        archive.add("metadata", np.asarray('{"k": 1}'))
    with zipfile.ZipFile(path) as z:
        assert z.testzip() is None  # every CRC holds
        assert [i.filename for i in z.infolist()] == ["a.npy", "b.npy", "c.npy", "metadata.npy"]
        assert all(i.compress_type == zipfile.ZIP_STORED and i.date_time == (1980, 1, 1, 0, 0, 0) for i in z.infolist())
    with np.load(path, allow_pickle=False) as npz:
        for name, values in columns.items():
            np.testing.assert_array_equal(npz[name], values)
        assert str(npz["metadata"]) == '{"k": 1}'
    again = tmp_path / "y.npz"
    with ColumnArchive(again, list(columns), 1000) as archive:
        archive.write(0, columns)
        archive.add("metadata", np.asarray('{"k": 1}'))
    assert again.read_bytes() == path.read_bytes()  # the same columns, the same bytes


def test_a_column_archive_refuses_pieces_out_of_order_and_missing_rows(tmp_path: Path) -> None:
    archive = ColumnArchive(tmp_path / "x.npz", ["a"], 10)
    with pytest.raises(ValueError, match="rows from 5, expected from 0"):
        archive.write(5, {"a": np.zeros(5)})
    archive.write(0, {"a": np.zeros(5)})
    with pytest.raises(ValueError, match="5 of 10 rows written"):
        archive.close()
    archive.abandon()


def test_an_empty_archive(tmp_path: Path) -> None:
    with ColumnArchive(tmp_path / "e.npz", ["t_s", "marker"], 0) as archive:
        archive.add("metadata", np.asarray("{}"))
    with np.load(tmp_path / "e.npz") as npz:
        assert npz["t_s"].shape == (0,)


def test_the_close_reads_the_journal_in_chunks_and_maps_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The regression of the 1.5 GB close: no mapping of the journal (its pages counted in RSS),
    a chunk of rows at a time (7 here), and the archive equal to the journal read whole."""
    monkeypatch.setattr(recorder_module, "NPZ_CHUNK_ROWS", 7)
    path = tmp_path / "run.npz"
    with hilbench.Bench(target="inprocess:an1017", record=path) as bench:
        bench.set_reference(1000)
        bench.press("s2")
        bench.run(0.01)
        bench.recorder.flush()
        whole = read_recording(path.with_name(path.name + ".journal"))

        def no_mapping(*args: object, **kwargs: object) -> None:
            raise AssertionError("the journal was mapped at close")

        monkeypatch.setattr(np, "memmap", no_mapping)
    monkeypatch.undo()
    data = read_recording(path)
    assert data.n_rows == 200
    for name, column in whole.columns.items():
        np.testing.assert_array_equal(data.columns[name], column, err_msg=name)
    with zipfile.ZipFile(path) as z:
        assert z.testzip() is None


def _open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def test_an_archive_that_cannot_be_written_keeps_the_journal_and_says_so(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """A full disk at the close: one RecordingError naming the recording and the journal that keeps
    every row, no half-written archive left beside it, no descriptor left open."""
    path = tmp_path / "run.npz"
    real = npzwriter._pwrite_all

    def disk_full_after_100_kb(fd: int, data: memoryview, offset: int) -> None:
        if offset + len(data) > 100_000:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(fd, data, offset)

    before = _open_fds()
    bench = hilbench.Bench(target="inprocess:an1017", record=path)
    with pytest.raises(RecordingError) as info:
        with bench:
            bench.set_reference(1000)
            bench.press("s2")
            bench.run(0.05)
            monkeypatch.setattr(npzwriter, "_pwrite_all", disk_full_after_100_kb)
    monkeypatch.undo()
    message = str(info.value)
    journal = path.with_name(path.name + ".journal")
    assert str(path) in message and str(journal) in message and os.strerror(errno.ENOSPC) in message, message
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.npz.journal", "run.npz.journal.events"]
    assert read_recording(path).n_rows == 1000  # the journal stands in for the archive
    assert _open_fds() == before


def _file_size_limit(n_bytes: int) -> None:
    resource.setrlimit(resource.RLIMIT_FSIZE, (n_bytes, n_bytes))  # Python ignores SIGXFSZ: EFBIG


def test_run_with_an_archive_it_cannot_write_is_a_recording_error(tmp_path: Path) -> None:
    """`hilbench run --record x.npz` whose archive outgrows the file size limit (the journal fits: 24
    float64 columns take more than the journal's packed rows) ends with exit 6 and one line, not
    "file error" with exit 1 and a half-written archive left."""
    command = [sys.executable, "-P", "-m", "hilbench", "run", "--target", "inprocess:an1017", "--duration", "0.5",
               "--no-ui", "--no-control", "--record", str(tmp_path / "r.npz")]
    done = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=300,
                          preexec_fn=lambda: _file_size_limit(1_600_000))
    assert_one_line_error(done, 6, "r.npz.journal", "archive could not be written")
    assert not (tmp_path / "r.npz.tmp.npz").exists()
    assert read_recording(tmp_path / "r.npz").n_rows == 10_000


@pytest.mark.slow
def test_members_beyond_4_gib_are_found_by_zip64(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two columns of 290 M rows (2.3 GB each): the metadata member starts beyond 4 GiB and the
    central directory after it, so zipfile and NumPy find them only through the ZIP64 fields. The
    file is sparse (the zero chunks are holes, which read as zeros; 75 MB on disk); every value
    still passes through the CRC."""
    real = npzwriter._pwrite_all
    zero_chunk = 4 << 20  # rows

    def holes_for_zeros(fd: int, data: memoryview, offset: int) -> None:
        if len(data) == 8 * zero_chunk and not any(data.cast("Q")):
            return
        real(fd, data, offset)

    monkeypatch.setattr(npzwriter, "_pwrite_all", holes_for_zeros)
    n_rows = 290_000_000
    path = tmp_path / "big.npz"
    zeros = np.zeros(zero_chunk)
    with ColumnArchive(path, ["a", "b"], n_rows) as archive:
        for first in range(0, n_rows, zero_chunk):
            count = min(zero_chunk, n_rows - first)
            if first == 0:
                head = np.zeros(count)
                head[:2] = (1.0, 2.0)
                archive.write(first, {"a": head, "b": -head})
            else:
                archive.write(first, {"a": zeros[:count], "b": zeros[:count]})
        archive.add("metadata", np.asarray('{"k": 1}'))
    assert path.stat().st_size > 4 * 1024**3
    with zipfile.ZipFile(path) as z:
        infos = {i.filename: i for i in z.infolist()}
        assert infos["metadata.npy"].header_offset > 4 * 1024**3 and infos["b.npy"].file_size > 8 * n_rows
        with z.open("b.npy") as member:
            np.lib.format.read_magic(member)
            assert np.lib.format.read_array_header_1_0(member)[0] == (n_rows,)
            assert np.frombuffer(member.read(16), "<f8").tolist() == [-1.0, -2.0]
    with np.load(path, allow_pickle=False) as npz:
        assert str(npz["metadata"]) == '{"k": 1}'  # read whole: its CRC, beyond 4 GiB, checked
