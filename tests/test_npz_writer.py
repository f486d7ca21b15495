"""Issue 23: an NPZ recording is written from its journal in one pass, a chunk at a time
(hilbench.bench.npzwriter), so the close's memory does not grow with the run's length
(benchmarks/bench_soak.py has the figures). The archive is a plain ZIP64 NPZ."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

import hilbench
from hilbench.bench import recorder as recorder_module
from hilbench.bench.npzwriter import ColumnArchive
from hilbench.bench.recorder import read_recording


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
