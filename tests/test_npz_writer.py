"""Issue 23: an NPZ recording is written from its journal in one pass, a chunk at a time
(hilbench.bench.npzwriter), so the close's memory does not grow with the run's length
(benchmarks/bench_soak.py has the figures). The archive is a plain ZIP64 NPZ."""

from __future__ import annotations

import contextlib
import errno
import json
import os
import resource
import subprocess
import sys
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

import hilbench
from _hostile import assert_one_line_error
from _recordings import every_code_layout, hostile_rows
from hilbench.bench import npzwriter
from hilbench.bench import recorder as recorder_module
from hilbench.bench.npzwriter import ColumnArchive
from hilbench.bench.recorder import read_recording
from hilbench.errors import RecordingError

if TYPE_CHECKING:
    from hilbench.bench.session import Session


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


@pytest.mark.parametrize("array", [
    np.asarray(""), np.asarray('{"k": 1}'), np.asarray("\u00e9\u2028\U0001F600" * 300), np.asarray("x" * 70_000),
    np.arange(5.0), np.zeros((3, 4), dtype="<i2"), np.asfortranarray(np.ones((3, 4))), np.asarray(3.5),
    np.zeros(2, dtype=[(f"f{i}", "<f8") for i in range(5_000)]),
], ids=["empty", "json", "non-ascii", "long", "floats", "int16-2d", "fortran", "scalar", "record-header-v2"])
@pytest.mark.filterwarnings("ignore:Stored array in format 2.0")
def test_a_small_member_has_the_bytes_numpy_writes(array: np.ndarray) -> None:
    """The metadata member's .npy bytes are numpy's write_array's (its header, then the data as in
    memory), for text of any length and characters, and for other arrays (a Fortran-ordered one
    goes to write_array itself)."""
    import io

    out = io.BytesIO()
    np.lib.format.write_array(out, array, allow_pickle=False)
    assert npzwriter._npy(array) == out.getvalue()


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
    real = npzwriter.pwrite_all

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
            monkeypatch.setattr(npzwriter, "pwrite_all", disk_full_after_100_kb)
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
    real = npzwriter.pwrite_all
    zero_chunk = 4 << 20  # rows

    def holes_for_zeros(fd: int, data: memoryview, offset: int) -> None:
        if len(data) == 8 * zero_chunk and not any(data.cast("Q")):
            return
        real(fd, data, offset)

    monkeypatch.setattr(npzwriter, "pwrite_all", holes_for_zeros)
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


# ------------------------------------------------------------------ the archive written while the run goes on
needs_writer = pytest.mark.skipif(npzwriter._npzcolumns is None, reason="the background column writer is not built")
#: the reference's conversions of random bit patterns (signalling NaNs, overflows) warn; the values are the point
hostile_values = pytest.mark.filterwarnings("ignore::RuntimeWarning")


def _record(path: Path, layout: recorder_module.RowLayout, raw: bytes, plan: int | None, *, flush_rows: int = 1000,
            mark_last: bool = False) -> recorder_module.Recorder:
    """A recording of ``raw`` rows appended a few at a time (the session's `maybe_flush` after each
    few), its background archive planned for ``plan`` rows (None: none)."""
    rec = recorder_module.Recorder(path, {"layout": "every code"}, flush_rows=flush_rows)
    rec.start(layout)
    if plan is not None:
        rec.expect_rows(plan)
    size = layout.dtype.itemsize
    for first in range(0, len(raw) // size, 37):
        rec.rows.extend(raw[first * size:(first + 37) * size])
        if first % 111 == 0:
            rec.event(f"note at {first}", recorder_module.MARKER_EVENT)
        rec.maybe_flush()
    if mark_last:
        rec.mark_last(recorder_module.MARKER_FAULT)
    rec.close("end")
    return rec


@needs_writer
@hostile_values
@pytest.mark.parametrize("n_rows", [0, 1, 4095, 4096, 10_000, 23_456])
def test_the_archive_written_while_the_run_goes_on_is_the_journals_byte_for_byte(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, n_rows: int) -> None:
    """Every struct code, NaN and infinite scales and values, wrapped columns (numpy.mod's sign and
    edges), markers and events: the background archive's bytes equal the archive written from the
    journal (the reference), and numpy reads the values `RowLayout.to_columns` gives."""
    monkeypatch.setattr(recorder_module, "BACKGROUND_CHUNK_ROWS", 300)  # many hand-overs between flushes
    layout = every_code_layout()
    raw = hostile_rows(layout, n_rows, seed=n_rows)
    finished = []
    real_finish = npzwriter.BackgroundArchive.finish

    def spy(self: npzwriter.BackgroundArchive, metadata: np.ndarray) -> bool:
        finished.append(real_finish(self, metadata))
        return finished[-1]

    monkeypatch.setattr(npzwriter.BackgroundArchive, "finish", spy)
    _record(tmp_path / "bg.npz", layout, raw, n_rows)
    _record(tmp_path / "ref.npz", layout, raw, None)
    assert finished == ([True] if n_rows else [])  # (no rows: nothing to plan)
    assert (tmp_path / "bg.npz").read_bytes() == (tmp_path / "ref.npz").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bg.npz", "ref.npz"]
    data = read_recording(tmp_path / "bg.npz")
    with np.errstate(all="ignore"):
        expected = layout.to_columns(np.frombuffer(raw, dtype=layout.dtype).copy())
    for name in layout.column_names:
        if name != "marker":
            np.testing.assert_array_equal(data.columns[name], expected[name], err_msg=name)


@needs_writer
@hostile_values
@pytest.mark.parametrize("plan, mark_last", [(9_000, False), (11_000, False), (10_000, True)])
def test_a_run_that_ends_otherwise_than_planned_gets_the_journals_archive(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                           plan: int, mark_last: bool) -> None:
    """Fewer rows than planned, more, or a fault marker on a row already handed over (every row is
    handed at once here): the archive is written from the journal at the close (the same bytes as
    without a plan, the marker in it), nothing else left."""
    monkeypatch.setattr(recorder_module, "BACKGROUND_CHUNK_ROWS", 1 if mark_last else 200)
    layout = every_code_layout()
    raw = hostile_rows(layout, 10_000, seed=3)
    finished = []
    real_finish = npzwriter.BackgroundArchive.finish
    monkeypatch.setattr(npzwriter.BackgroundArchive, "finish",
                        lambda self, metadata: finished.append(real_finish(self, metadata)) or finished[-1])
    _record(tmp_path / "bg.npz", layout, raw, plan, flush_rows=20_000, mark_last=mark_last)
    _record(tmp_path / "ref.npz", layout, raw, None, flush_rows=20_000, mark_last=mark_last)
    assert finished == [False]
    assert (tmp_path / "bg.npz").read_bytes() == (tmp_path / "ref.npz").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bg.npz", "ref.npz"]
    if mark_last:
        assert read_recording(tmp_path / "bg.npz").columns["marker"][-1] == recorder_module.MARKER_FAULT


@needs_writer
@hostile_values
def test_the_writer_thread_writes_the_crcs_once_the_planned_rows_are_in(tmp_path: Path) -> None:
    """Once every planned row is handed over, the thread writes each local header's CRC itself
    (the close's wait is shorter by those writes): they are in the unfinished archive before the
    close, right (the member's CRC-32 in the file), and the finished archive is the reference's."""
    import zlib

    layout = every_code_layout()
    n_rows = 5_000
    raw = hostile_rows(layout, n_rows, seed=11)
    rec = recorder_module.Recorder(tmp_path / "bg.npz", {"layout": "every code"}, flush_rows=2_000)
    rec.start(layout)
    rec.expect_rows(n_rows)
    rec.rows.extend(raw)
    rec.flush()  # every row handed over and journaled; the thread converts them
    archive = rec._background._archive
    unfinished = rec._tmp_path()

    def crcs_in_file() -> bool:
        data = unfinished.read_bytes()
        for member, offset, data_offset, size in archive._members:
            if len(data) < data_offset + size:
                return False
            (crc,) = np.frombuffer(data[offset + 14:offset + 18], "<u4")
            if crc != zlib.crc32(data[data_offset:data_offset + size]):
                return False
        return True

    assert _wait_for(crcs_in_file), "the thread did not write the CRCs before the close"
    rec.close("end")
    ref = recorder_module.Recorder(tmp_path / "ref.npz", {"layout": "every code"}, flush_rows=2_000)
    ref.start(layout)
    ref.rows.extend(raw)
    ref.close("end")  # no plan: the archive written from the journal at the close
    assert (tmp_path / "bg.npz").read_bytes() == (tmp_path / "ref.npz").read_bytes()


@needs_writer
def test_a_writer_takes_no_row_beyond_its_plan(tmp_path: Path) -> None:
    """The archive is sized for the planned rows: a chunk that would go past them is refused (one
    line), not written over the next member with a CRC already written for the plan."""
    fds = [os.open(tmp_path / name, os.O_WRONLY | os.O_CREAT | os.O_CLOEXEC, 0o644) for name in ("a", "j")]
    try:
        writer = npzwriter._npzcolumns.ColumnWriter(fds[0], fds[1], 0, 8, [(0, "d", 1.0, 0.0, 16, 0)], b"h" * 16,
                                                    planned_rows=4)
        writer.submit_rows(0, memoryview(np.arange(3.0).tobytes()))
        with pytest.raises(ValueError, match="rows up to 5, beyond the 4 planned"):
            writer.submit_rows(3, memoryview(np.arange(2.0).tobytes()))
        writer.submit_rows(3, memoryview(np.arange(1.0).tobytes()))
        assert writer.finish()[0] == 4
    finally:
        for fd in fds:
            os.close(fd)


def _threads() -> int:
    return len(os.listdir("/proc/self/task"))


@needs_writer
@hostile_values
def test_a_write_that_fails_on_the_thread_falls_back_and_every_thread_is_joined(tmp_path: Path) -> None:
    """The thread's pwrite fails (its descriptor made read-only under it: EBADF): the close writes
    the archive from the journal, which still has every row; no thread is left, nor the unfinished
    archive."""
    layout = every_code_layout()
    raw = hostile_rows(layout, 5000, seed=4)
    before = _threads()
    rec = recorder_module.Recorder(tmp_path / "bg.npz", {}, flush_rows=100_000)
    rec.start(layout)
    rec.expect_rows(5000)
    background = rec._background
    assert background is not None and _threads() == before + 1
    read_only = os.open(tmp_path / "bg.npz.journal", os.O_RDONLY)
    os.dup2(read_only, background._archive._fd)  # the thread's writes now fail
    os.close(read_only)
    size = layout.dtype.itemsize
    for first in range(0, 5000, 1000):
        rec.rows.extend(raw[first * size:(first + 1000) * size])
        rec.flush()
    rec.close("end")
    assert background.given_up and isinstance(background.failed, OSError) and background.failed.errno == errno.EBADF
    assert _threads() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bg.npz"]
    data = read_recording(tmp_path / "bg.npz")
    with np.errstate(all="ignore"):
        expected = layout.to_columns(np.frombuffer(raw, dtype=layout.dtype).copy())
    np.testing.assert_array_equal(data.columns["d"], expected["d"])


@needs_writer
def test_a_killed_runs_journal_reads_and_its_unfinished_archive_goes_with_the_next_run(tmp_path: Path) -> None:
    """A run killed while its archive was being written: the journal is the recording (read as
    before: every chunk but those the writer's thread may still have held when the kill came, two
    at most, the last perhaps in part); the unfinished archive beside it is removed when the next
    run records to that path."""
    script = (
        "import os, sys, numpy as np\n"
        "from hilbench.bench import recorder as r\n"
        "rec = r.Recorder(sys.argv[1], {'killed': True}, flush_rows=1000)\n"
        "rec.start(r.float_layout(r.COLUMNS))\n"
        "rec.expect_rows(10_000)\n"
        "for k in range(5_000):\n"
        "    rec.append([k * 5e-5] + [float(k)] * (r.N_COLUMNS - 1))\n"
        "    rec.maybe_flush()\n"
        "os.kill(os.getpid(), 9)\n"
    )
    path = tmp_path / "run.npz"
    done = subprocess.run([sys.executable, "-c", script, str(path)], capture_output=True, timeout=120)
    assert done.returncode == -9
    assert (tmp_path / "run.npz.tmp.npz").exists() and not path.exists()
    data = read_recording(path)  # the journal
    assert 3_000 <= data.n_rows <= 5_000 and data.metadata["killed"] is True
    np.testing.assert_array_equal(data.columns["seq"], np.arange(float(data.n_rows)))
    recorder_module.Recorder(path, {}).close()
    assert not (tmp_path / "run.npz.tmp.npz").exists()


@needs_writer
def test_a_planned_session_run_writes_its_archive_while_it_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`hilbench run`'s path (a session run to its planned end): the archive comes from the thread,
    and equals the one the journal gives."""
    finished = []
    real_finish = npzwriter.BackgroundArchive.finish
    monkeypatch.setattr(npzwriter.BackgroundArchive, "finish",
                        lambda self, metadata: finished.append(real_finish(self, metadata)) or finished[-1])
    paths = []
    for name, writer in (("bg.npz", npzwriter._npzcolumns), ("ref.npz", None)):
        monkeypatch.setattr(npzwriter, "_npzcolumns", writer)
        cfg = hilbench.load_config(None, ['link.target="inprocess:an1017"', "run.duration_s=0.6"])
        with hilbench.Bench(cfg, scenario=True, record=tmp_path / name) as bench:
            bench.run()
        paths.append(tmp_path / name)
    assert finished == [True]
    assert paths[0].read_bytes() == paths[1].read_bytes()
    assert read_recording(paths[0]).n_rows == 12_000


_FULL_DISK_RUN = (
    "import json, os, sys, hilbench\n"
    "disk = sys.argv[1]\n"
    "path = os.path.join(disk, 'run.npz')\n"
    "cfg = hilbench.load_config(None, ['link.target=\"inprocess:an1017\"', 'run.duration_s=1.0'])\n"
    "error = ''\n"
    "try:\n"
    "    with hilbench.Bench(cfg, scenario=True, record=path) as bench:\n"
    "        bench.run()\n"
    "except hilbench.HilbenchError as exc:\n"
    "    error = str(exc)\n"
    "data = hilbench.read_recording(path if os.path.exists(path) else path + '.journal')\n"
    "print(json.dumps({'error': error, 'rows': data.n_rows, 'columns': len(data.columns),\n"
    "                  'files': sorted(os.listdir(disk)), 'journal_bytes': os.path.getsize(path + '.journal')}))\n"
)


@needs_writer
def test_a_full_disk_gives_the_background_archive_up_and_the_journal_keeps_every_row(tmp_path: Path) -> None:
    """A 4 MiB tmpfs of its own (unshare -rm): the journal of a 1 s run fits, the journal and the
    archive growing beside it do not. The journal's write that fails gives the archive up (its
    blocks freed) and is written again: every row is kept, the close says the archive could not
    be written and where the rows are, no unfinished archive is left (the journal lost a third of
    the rows when the archive kept its blocks)."""
    from _firmware import require_tool

    unshare = require_tool("unshare", "a full disk: a small tmpfs in a namespace of its own")
    if subprocess.run([unshare, "-rm", "true"], capture_output=True, timeout=60).returncode != 0:
        pytest.skip("unshare -rm is not permitted here (no user namespaces): no tmpfs of the test's own")
    disk = tmp_path / "disk"
    disk.mkdir()
    size = 4 << 20
    done = subprocess.run([unshare, "-rm", "sh", "-c", f'mount -t tmpfs -o size={size} tmpfs "$1" && exec "$2" -c "$3" "$1"',
                           "sh", str(disk), sys.executable, _FULL_DISK_RUN], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    archive_bytes = 8 * out["rows"] * out["columns"]
    assert out["journal_bytes"] + 64 * 1024 < size < out["journal_bytes"] + archive_bytes  # the case: both do not fit
    assert out["rows"] == 20_000, out
    assert "archive could not be written" in out["error"] and "every row is kept" in out["error"], out
    assert out["files"] == ["run.npz.journal", "run.npz.journal.events"], out


@needs_writer
@hostile_values
def test_a_failed_journal_write_is_written_again_where_it_belongs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A journal write on the writer's thread that fails (ENOSPC) after some of its bytes and stray
    bytes beyond landed: the archive is given up (its file emptied, then removed), the write is done
    again at the rows' place (the stray bytes cut off), the later chunks still journaled, and the
    archive the close writes from the journal equals the one of a run that never failed."""
    layout = every_code_layout()
    raw = hostile_rows(layout, 10_000, seed=8)
    monkeypatch.setattr(recorder_module, "BACKGROUND_CHUNK_ROWS", 500)
    real_submit, real_finish = npzwriter.BackgroundArchive.submit_rows, npzwriter.BackgroundArchive.finish
    submitted, finished, seen = [], [], []

    def fails_fifth(self: npzwriter.BackgroundArchive, first_row: int, data: memoryview) -> bool:
        submitted.append(len(data))
        if len(submitted) == 5:
            seen.append(self)
            self._writer.fail_journal_writes(1, errno.ENOSPC)
        return real_submit(self, first_row, data)

    monkeypatch.setattr(npzwriter.BackgroundArchive, "submit_rows", fails_fifth)
    monkeypatch.setattr(npzwriter.BackgroundArchive, "finish",
                        lambda self, metadata: finished.append(real_finish(self, metadata)) or finished[-1])
    _record(tmp_path / "bg.npz", layout, raw, 10_000, flush_rows=3000)
    monkeypatch.undo()
    _record(tmp_path / "ref.npz", layout, raw, None, flush_rows=3000)
    assert len(submitted) > 6 and finished == [False]
    assert seen[0].given_up and isinstance(seen[0].failed, OSError) and seen[0].failed.errno == errno.ENOSPC
    assert seen[0].journal_failed is None
    assert (tmp_path / "bg.npz").read_bytes() == (tmp_path / "ref.npz").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bg.npz", "ref.npz"]


@needs_writer
@hostile_values
def test_a_journal_write_that_fails_twice_is_a_recording_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A journal write that fails again after the archive was given up: the flush that finds it
    raises RecordingError (one line naming the recording), the thread is joined, nothing is written
    after the hole, the journal keeps the rows before it."""
    layout = every_code_layout()
    raw = hostile_rows(layout, 4000, seed=10)
    before = _threads()
    rec = recorder_module.Recorder(tmp_path / "bg.npz", {}, flush_rows=1000)
    rec.start(layout)
    rec.expect_rows(4000)
    background = rec._background
    assert background is not None
    size = layout.dtype.itemsize
    rec.rows.extend(raw[:1000 * size])
    rec.flush()
    assert _wait_for(lambda: background._writer.journaled == 1000)
    background._writer.fail_journal_writes(2, errno.ENOSPC)
    rec.rows.extend(raw[1000 * size:2000 * size])
    rec._flush()  # handed over, not waited for: the thread fails on it
    with pytest.raises(RecordingError, match=r"bg\.npz: write failed \(No space left on device\); "
                                             r".*bg\.npz\.journal keeps the first 1000 rows"):
        rec.flush()  # (a flush returns once the thread has journaled what it holds: it sees the failure)
    assert background.given_up and background.journal_failed is not None
    rec._file.close()
    assert _threads() == before
    journal = read_recording(tmp_path / "bg.npz.journal")
    assert journal.n_rows == 1000  # what part of the failed writes landed cut off
    with np.errstate(all="ignore"):
        expected = layout.to_columns(np.frombuffer(raw[:1000 * size], dtype=layout.dtype).copy())
    np.testing.assert_array_equal(journal.columns["d"], expected["d"])


@needs_writer
@hostile_values
def test_a_chunk_handed_over_again_after_an_interruption_is_taken_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C after the writer took a chunk and before the recorder let it go (here: in the events
    side file's write): the next flush hands the same rows over again, the writer knows them by
    their first row and does not take them twice; the archive equals a run never interrupted."""
    monkeypatch.setattr(recorder_module, "BACKGROUND_CHUNK_ROWS", 500)
    layout = every_code_layout()
    raw = hostile_rows(layout, 3000, seed=11)
    real = recorder_module.Recorder._write_events_file
    interrupted = []

    def once(self: recorder_module.Recorder, text: str) -> None:
        if not interrupted and self.rows_written >= 1000:
            interrupted.append(self.rows_written)
            raise KeyboardInterrupt
        real(self, text)

    monkeypatch.setattr(recorder_module.Recorder, "_write_events_file", once)
    rec = recorder_module.Recorder(tmp_path / "bg.npz", {"layout": "every code"}, flush_rows=1000)
    rec.start(layout)
    rec.expect_rows(3000)
    size = layout.dtype.itemsize
    for first in range(0, 3000, 37):
        rec.rows.extend(raw[first * size:(first + 37) * size])
        if first % 111 == 0:
            rec.event(f"note at {first}", recorder_module.MARKER_EVENT)
        try:
            rec.maybe_flush()
        except KeyboardInterrupt:
            pass
    rec.close("end")
    assert interrupted
    monkeypatch.undo()
    _record(tmp_path / "ref.npz", layout, raw, None, flush_rows=1000)
    assert read_recording(tmp_path / "bg.npz").n_rows == 3000
    assert (tmp_path / "bg.npz").read_bytes() == (tmp_path / "ref.npz").read_bytes()


@needs_writer
def test_the_recorded_signals_after_a_run_hold_every_row(tmp_path: Path) -> None:
    """`Bench.signals()` right after `run()` (the recording not closed yet) reads the journal: its
    flush returns once the archive's thread has journaled every row handed over, so none is missing."""
    cfg = hilbench.load_config(None, ['link.target="inprocess:an1017"', "run.duration_s=0.6"])
    for _ in range(3):
        (tmp_path / "r.npz").unlink(missing_ok=True)
        with hilbench.Bench(cfg, scenario=True, record=tmp_path / "r.npz") as bench:
            bench.run()
            assert len(bench.signals()["t_s"]) == 12_000


@contextlib.contextmanager
def _session_of_30_periods(recorder: recorder_module.Recorder, mode: str) -> Iterator[Session]:
    """A session of the in-process AN1017 for 30 periods of 1 ms at 1000 rpm, recording to ``recorder``
    (its target open while the block runs)."""
    from hilbench.bench.launcher import open_target
    from hilbench.bench.scenario import Event
    from hilbench.bench.session import Session, SessionOptions
    from hilbench.bench.settings import load_config
    from hilbench.config import plant_params_from_config
    from hilbench.plant.model import Plant

    options = SessionOptions(period_us=1000, mode=mode, duration_s=0.03, cpu_latency_qos=False)  # type: ignore[arg-type]
    with open_target("inprocess:an1017", timeout_s=2.0) as handle:
        yield Session(handle.target, Plant(plant_params_from_config(load_config(None)), seed=0),
                      (Event(at_s=0.0, ref_rpm=1000.0),), options, recorder=recorder, target_label="in-process")


@needs_writer
@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_a_real_time_run_plans_no_background_archive(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, mode: str) -> None:
    """In real time the writer's thread would run on the CPU the run is pinned to (it inherits the
    affinity), beside the paced thread: a real-time run writes its archive from the journal at the
    close; a lockstep run of the same plan has its archive written while it runs."""
    planned: list[int] = []
    real_init = npzwriter.BackgroundArchive.__init__

    def spy(self: npzwriter.BackgroundArchive, path: Path, layout: recorder_module.RowLayout, n_rows: int,
            *rest: object) -> None:
        planned.append(n_rows)
        real_init(self, path, layout, n_rows, *rest)  # type: ignore[arg-type]

    monkeypatch.setattr(npzwriter.BackgroundArchive, "__init__", spy)
    with _session_of_30_periods(recorder_module.Recorder(tmp_path / "run.npz", {}), mode) as session:
        session.run()
    assert planned == ([] if mode == "realtime" else [30])
    assert read_recording(tmp_path / "run.npz").n_rows == 30
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.npz"]


@needs_writer
def test_a_full_disk_as_the_last_rows_go_is_said_at_the_close(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The disk fills just as the session hands the last rows and an event over (`no_more_rows`, before
    its summary): the summary is still made and the close says the error as a RecordingError (caught
    by a name the session had not imported, it was a NameError with a traceback)."""
    real = recorder_module.Recorder.no_more_rows
    raised: list[RecordingError] = []

    def disk_fills(self: recorder_module.Recorder) -> None:
        def full(*_: object) -> None:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        monkeypatch.setattr(recorder_module, "pwrite_all", full)  # every write from here on
        self.event("the last event")  # pending, so the hand-over writes it
        try:
            real(self)
        except RecordingError as exc:
            raised.append(exc)
            raise

    monkeypatch.setattr(recorder_module.Recorder, "no_more_rows", disk_fills)
    threads = _threads()
    recorder = recorder_module.Recorder(tmp_path / "run.npz", {})
    try:
        with _session_of_30_periods(recorder, "lockstep") as session, \
                pytest.raises(RecordingError, match="No space left on device"):
            session.run()  # the close, after the summary, meets the error again and says it
    finally:
        recorder._file.close()  # (a failed close leaves the journal to the collector)
    assert raised and os.strerror(errno.ENOSPC) in str(raised[0])  # the hand-over's, caught
    assert session.summary.periods == 30
    assert _threads() == threads


@needs_writer
@pytest.mark.parametrize("error", [ValueError("a column the writer refuses"), RuntimeError("no thread"), MemoryError()])
def test_a_background_archive_that_cannot_start_leaves_the_run_to_the_journal(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                              error: Exception) -> None:
    """Whatever the background archive raises when it is set up (before the run's first period, outside
    the run's own error handling): the run goes on without it, its archive written from the journal
    at the close, every row there, nothing left beside it."""
    def broken(self: npzwriter.BackgroundArchive, path: Path, *rest: object) -> None:
        path.write_bytes(b"half made")
        raise error

    monkeypatch.setattr(npzwriter.BackgroundArchive, "__init__", broken)
    cfg = hilbench.load_config(None, ['link.target="inprocess:an1017"', "run.duration_s=0.3"])
    with hilbench.Bench(cfg, scenario=True, record=tmp_path / "run.npz") as bench:
        bench.run()
    assert read_recording(tmp_path / "run.npz").n_rows == 6000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.npz"]


def test_a_write_that_writes_nothing_is_an_error_not_a_loop(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A pwrite that returns 0 for a non-empty piece (nothing written, no errno) is EIO: the write
    loop tried it again without end. (The C writer's pwrite_all has the same check; no file here
    makes pwrite return 0, so it is not exercised.)"""
    archive = ColumnArchive(tmp_path / "x.npz", ["a"], 10)
    calls: list[int] = []

    def writes_nothing(fd: int, data: bytes, offset: int) -> int:
        calls.append(offset)
        if len(calls) > 100:
            raise RuntimeError("the write loop goes on without end")
        return 0

    monkeypatch.setattr(os, "pwrite", writes_nothing)
    with pytest.raises(OSError) as info:
        archive.write(0, {"a": np.zeros(10)})
    monkeypatch.undo()
    archive.abandon()
    assert info.value.errno == errno.EIO and len(calls) == 1


#: the rows `_endless_writer`'s thread is given (32 MB), its columns (every one the same field, wrapped:
#: seconds of work for the thread)
ENDLESS_ROWS, ENDLESS_COLUMNS = 1 << 22, 64


def _endless_writer() -> tuple[object, list[int], str]:
    """A column writer whose thread has rows for a long while once `submit_rows` hands it
    ENDLESS_ROWS (its archive and its journal /dev/null), its descriptors and its thread's id."""
    fds = [os.open("/dev/null", os.O_WRONLY | os.O_CLOEXEC), os.open("/dev/null", os.O_WRONLY | os.O_CLOEXEC)]
    before = set(os.listdir("/proc/self/task"))
    columns = [(0, "d", 1.0, 360.0, 16 + j * 8 * (ENDLESS_ROWS + 16), 0) for j in range(ENDLESS_COLUMNS)]
    writer = npzwriter._npzcolumns.ColumnWriter(fds[0], fds[1], 0, 8, columns, b"h" * 16)
    new = set(os.listdir("/proc/self/task")) - before
    assert len(new) == 1
    return writer, fds, new.pop()


def _wait_for(condition: Callable[[], bool], timeout_s: float = 30.0) -> bool:
    """Whether the condition came true within the timeout (looked at every 10 ms)."""
    import time

    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def _thread_ended(tid: str, timeout_s: float = 30.0) -> bool:
    """Whether the thread is gone from /proc (joined, it may linger there for a moment)."""
    return _wait_for(lambda: not os.path.exists(f"/proc/self/task/{tid}"), timeout_s)


@needs_writer
def test_the_writer_thread_blocks_every_signal() -> None:
    """The writer's thread is created with every signal blocked: Ctrl-C, a timer or a child's end is
    the Python thread's to handle, never an EINTR or a handler on the writer."""
    import signal

    import time

    writer, fds, tid = _endless_writer()
    try:
        deadline = time.monotonic() + 30.0  # the thread runs its own code (SCHED_BATCH, its first act):
        while os.sched_getscheduler(int(tid)) != os.SCHED_BATCH:  # its start (all blocked) is over
            assert time.monotonic() < deadline, "the writer's thread did not start"
            time.sleep(0.01)
        status = Path(f"/proc/self/task/{tid}/status").read_text()
        blocked = int(next(line.split()[1] for line in status.splitlines() if line.startswith("SigBlk:")), 16)
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGALRM, signal.SIGCHLD, signal.SIGUSR1,
                    signal.SIGPIPE):
            assert blocked >> (sig - 1) & 1, f"{sig!r} not blocked (SigBlk {blocked:#x})"
    finally:
        writer.abandon()  # type: ignore[attr-defined]
        for fd in fds:
            os.close(fd)


@needs_writer
def test_ctrl_c_while_the_writer_finishes_drops_its_rows_and_joins_its_thread() -> None:
    """`finish` waits for the thread to write every row handed over; Ctrl-C in that wait ends it
    (KeyboardInterrupt, the rest dropped, the thread joined) instead of waiting it out. SIGINT is
    sent every 50 ms until one lands inside `finish` (one landing before it is raised there: finish
    is called again)."""
    import signal
    import threading

    total = ENDLESS_ROWS  # the thread takes some seconds to write them: the wait is still on when SIGINT comes
    state = {"raise": True}

    def on_sigint(signum: int, frame: object) -> None:
        if state["raise"]:
            state["raise"] = False
            raise KeyboardInterrupt

    writer, fds, tid = _endless_writer()
    writer.submit_rows(0, np.arange(total, dtype="<f8") * 1e3)  # type: ignore[attr-defined]
    stop = threading.Event()
    sender = threading.Thread(target=lambda: [os.kill(os.getpid(), signal.SIGINT) for _ in iter(lambda: stop.wait(0.05), True)])
    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        sender.start()
        for _ in range(1000):
            try:
                writer.finish()  # type: ignore[attr-defined]
                break  # (without the wait's signal check: every row written, then the interrupt)
            except KeyboardInterrupt:
                if writer.rows_done is not None:  # type: ignore[attr-defined]
                    break  # raised inside finish, the thread joined
                state["raise"] = True  # raised before finish began: again
    finally:
        state["raise"] = False
        stop.set()
        sender.join(timeout=60)
        signal.signal(signal.SIGINT, previous)
        writer.abandon()  # type: ignore[attr-defined]
        for fd in fds:
            os.close(fd)
    assert writer.rows_done is not None and writer.rows_done < total  # type: ignore[attr-defined]
    assert _thread_ended(tid)


@needs_writer
@hostile_values
def test_ctrl_c_while_the_close_finishes_the_archive_leaves_the_journal(tmp_path: Path) -> None:
    """Ctrl-C while the close waits for the writer's last rows: the archive is given up (its thread
    joined, its unfinished file removed), the interrupt propagates, the journal keeps every row."""
    layout = every_code_layout()
    raw = hostile_rows(layout, 5000, seed=9)
    path = tmp_path / "bg.npz"
    rec = recorder_module.Recorder(path, {}, flush_rows=100_000)
    rec.start(layout)
    rec.expect_rows(5000)
    background = rec._background
    assert background is not None
    writer = background._writer

    class Interrupted:  # the writer's finish as Ctrl-C in its wait ends it
        def submit_rows(self, first_row: int, data: memoryview) -> bool:
            return writer.submit_rows(first_row, data)

        def sync(self) -> None:
            writer.sync()

        @property
        def queued(self) -> int:
            return writer.queued

        def finish(self) -> None:
            writer.abandon()
            raise KeyboardInterrupt

        def abandon(self) -> int | None:
            return writer.abandon()

    background._writer = Interrupted()
    rec.rows.extend(raw)
    with pytest.raises(KeyboardInterrupt):
        rec.close("end")
    assert background.given_up
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bg.npz.journal", "bg.npz.journal.events"]
    assert read_recording(path).n_rows == 5000


def _closer_idle(timeout_s: float = 30.0) -> tuple[int, int, bool]:
    """The closer's state once nothing is queued or being closed."""
    closer = npzwriter._npzcolumns
    assert _wait_for(lambda: closer.closer_state()[0] == 0, timeout_s), closer.closer_state()
    return closer.closer_state()


def _journals_open() -> list[str]:
    """This process's descriptors on a deleted journal."""
    links = []
    for name in os.listdir("/proc/self/fd"):
        with contextlib.suppress(OSError):
            links.append(os.readlink(f"/proc/self/fd/{name}"))
    return [link for link in links if ".journal" in link and link.endswith("(deleted)")]


@needs_writer
def test_the_journals_last_descriptor_is_closed_by_the_closer_after_the_unlink(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A planned run's close unlinks the journal while the archive's descriptor on it is open (cheap),
    then hands that descriptor to the closer thread, whose close frees the journal's pages: the
    journal's name is gone when the close returns, the closer closes that descriptor, none is left."""
    handed: list[int] = []
    real = npzwriter._npzcolumns.close_later

    def close_later(fd: int) -> None:
        handed.append(fd)
        assert not (tmp_path / "run.npz.journal").exists()  # unlinked first: this close frees the pages
        real(fd)

    monkeypatch.setattr(npzwriter._npzcolumns, "close_later", close_later)
    _, closed_before, _ = _closer_idle()
    before = _open_fds()
    cfg = hilbench.load_config(None, ['link.target="inprocess:an1017"', "run.duration_s=0.2"])
    with hilbench.Bench(cfg, scenario=True, record=tmp_path / "run.npz") as bench:
        bench.run()
    assert len(handed) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.npz"]
    _, closed_after, _ = _closer_idle()
    assert closed_after == closed_before + 1  # by the closer thread, not at once on this one
    assert _open_fds() == before and not _journals_open()


@needs_writer
def test_an_archive_that_cannot_take_its_name_leaves_no_descriptor_on_the_journal(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The background archive finished, then its rename failed: one RecordingError, the journal kept
    (it stands in for the archive), and no descriptor on it left open while the error is held."""
    path = tmp_path / "run.npz"
    real_replace = os.replace

    def no_rename(src: object, dst: object) -> None:
        if str(dst) == str(path):
            raise OSError(errno.EXDEV, os.strerror(errno.EXDEV))
        real_replace(src, dst)

    finished: list[bool] = []
    real_finish = npzwriter.BackgroundArchive.finish
    monkeypatch.setattr(npzwriter.BackgroundArchive, "finish",
                        lambda self, metadata: finished.append(real_finish(self, metadata)) or finished[-1])
    monkeypatch.setattr(recorder_module.os, "replace", no_rename)
    before = _open_fds()
    cfg = hilbench.load_config(None, ['link.target="inprocess:an1017"', "run.duration_s=0.2"])
    with pytest.raises(RecordingError) as info:
        with hilbench.Bench(cfg, scenario=True, record=path) as bench:
            bench.run()
    monkeypatch.undo()
    assert finished == [True] and str(path.with_name("run.npz.journal")) in str(info.value)
    _closer_idle()
    assert _open_fds() == before  # (info, and the close's frame with it, still alive)
    assert read_recording(path.with_name("run.npz.journal")).n_rows == 4000


@needs_writer
def test_a_fork_with_descriptors_queued_closes_them_in_the_child_and_the_child_starts_its_own_closer(
        tmp_path: Path) -> None:
    """A child forked while the closer holds descriptors queued (a sweep's worker forked right after
    a run) closes its copies of them at once (it has no closer thread), and its own close_later
    starts a closer of its own; the parent's closer then closes the parent's."""
    closer = npzwriter._npzcolumns
    queued = os.open(tmp_path / "queued", os.O_WRONLY | os.O_CREAT | os.O_CLOEXEC, 0o600)
    later = os.open(tmp_path / "later", os.O_WRONLY | os.O_CREAT | os.O_CLOEXEC, 0o600)
    _, closed_before, _ = _closer_idle()
    closer.hold_closer(True)
    try:
        closer.close_later(queued)
        assert closer.closer_state()[0] == 1
        pid = os.fork()
        if pid == 0:  # the child: report by exit code, never return into pytest
            code = 9  # (an exception in its checks)
            try:
                code = _forked_child_checks(queued, later)
            finally:
                os._exit(code)
    finally:
        closer.hold_closer(False)
    os.close(later)
    status: list[int] = []

    def ended() -> bool:
        done, code = os.waitpid(pid, os.WNOHANG)
        if done:
            status.append(os.waitstatus_to_exitcode(code))
        return bool(done)

    if not _wait_for(ended, 60.0):
        os.kill(pid, 9)
        os.waitpid(pid, 0)
        pytest.fail("the forked child did not end within 60 s")
    assert status == [0], _forked_child_checks.__doc__
    _, closed_after, _ = _closer_idle()
    assert closed_after == closed_before + 1  # the parent's queued one, by the parent's closer


def _forked_child_checks(queued: int, later: int) -> int:
    """The forked child's checks as its exit code: 0 all hold; 1 its copy of the queued descriptor
    is still open; 2 it inherited the closer's queue or thread as running; 3 its own close_later did
    not start a closer that closed the descriptor; 9 an exception."""
    closer = npzwriter._npzcolumns
    try:
        os.fstat(queued)  # (the child is single-threaded here: the number cannot have been reused)
        return 1
    except OSError as exc:
        if exc.errno != errno.EBADF:
            return 1
    pending, closed, running = closer.closer_state()
    if pending or running:
        return 2
    closer.close_later(later)
    return 0 if _wait_for(lambda: closer.closer_state()[:2] == (0, closed + 1), 20.0) else 3
