"""Recordings for the tests that read them back (checks, report, plots): written by the recorder as
a run writes them (an NPZ, the journal of an NPZ run killed before its close, a CSV), or straight
into an NPZ archive a chunk at a time (a long run, a damaged one, one beyond a bound); a source
re-cut into other chunks; and a module as it was at an older commit, to compare with."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np

from conftest import REPO_ROOT
from hilbench.bench.column_chunks import Chunk, ColumnChunks
from hilbench.bench.npzwriter import ColumnArchive
from hilbench.bench.recorder import COLUMNS, Recorder, RowLayout, float_layout

#: (file name, closed): a run's NPZ, an NPZ run killed before its close (its journal), a CSV run
KINDS = (("run.npz", True), ("killed.npz", False), ("run.csv", True))


def write_recording(path: Path, columns: Mapping[str, np.ndarray], *,
                    specs: Sequence[tuple[str, str, str]] = COLUMNS, metadata: Mapping[str, Any] | None = None,
                    events: Mapping[int, str] | None = None, flush_rows: int = 997, close: bool = True) -> Path:
    """The rows of ``columns`` (those ``specs`` names, in its order) appended and flushed by the
    recorder as a run does, each event of ``events`` before its row; closed with an end note, or
    (``close`` False) flushed and left as a killed run leaves it. Returns ``path``."""
    names = [name for name, _, _ in specs]
    events = events or {}
    recorder = Recorder(path, dict(metadata or {"period_us": 1000}), flush_rows=flush_rows)
    recorder.start(float_layout(specs))
    for k, row in enumerate(zip(*(np.asarray(columns[name]).tolist() for name in names))):
        if k in events:
            recorder.event(events[k])
        recorder.append(row)
        recorder.maybe_flush()
    if close:
        recorder.close("end: completed")
    else:
        recorder.flush()
    return path


def every_kind(folder: Path, columns_for: Callable[[str], Mapping[str, np.ndarray]], **options: Any) -> list[Path]:
    """`write_recording` of each of KINDS into ``folder`` (``columns_for(file name)`` its columns),
    in KINDS' order; the killed run left as its journal only."""
    paths = [write_recording(folder / name, columns_for(name), close=closed, **options) for name, closed in KINDS]
    assert (folder / "killed.npz.journal").exists() and not (folder / "killed.npz").exists()
    return paths


def write_archive(path: Path, names: Sequence[str], n_rows: int, chunk: Callable[[np.ndarray], Mapping[str, np.ndarray]],
                  metadata: Mapping[str, Any], chunk_rows: int = 1 << 18) -> Path:
    """An NPZ of ``n_rows`` rows of ``names`` written straight into the archive, ``chunk(k)`` the
    columns of rows ``k`` (an array of row numbers) a chunk at a time: a long recording in the
    memory of one chunk, or rows a run would never write (t_s going back). ``metadata`` gets
    ``columns`` (unitless) unless it has them."""
    with ColumnArchive(path, list(names), n_rows) as archive:
        for first in range(0, n_rows, chunk_rows):
            archive.write(first, dict(chunk(np.arange(first, min(n_rows, first + chunk_rows)))))
        archive.add("metadata", np.asarray(json.dumps({"columns": [[n, ""] for n in names], **metadata})))
    return path


class Cut(ColumnChunks):
    """Another source's chunks, cut every ``rows`` rows."""

    def __init__(self, source: ColumnChunks, rows: int) -> None:
        self._source, self._rows = source, rows
        self.names, self.units, self.where = source.names, source.units, source.where

    def _chunks(self, names: Sequence[str], chunk_rows: int) -> Iterator[Chunk]:
        return self._source.chunks(names, self._rows)


def module_at(commit: str, module_path: str, folder: Path) -> ModuleType | None:
    """``module_path`` (e.g. hilbench/bench/checks.py) as it was at ``commit``, loaded from a copy in
    ``folder``; None where git cannot show it (a shallow clone, an unpacked sdist)."""
    shown = subprocess.run(["git", "-C", str(REPO_ROOT), "show", f"{commit}:{module_path}"],
                           capture_output=True, text=True, timeout=60)
    if shown.returncode != 0:
        return None
    name = f"at_{commit}_{Path(module_path).stem}"
    source = folder / f"{name}.py"
    source.write_text(shown.stdout)
    spec = importlib.util.spec_from_file_location(name, source)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    finally:
        del sys.modules[name]
    if getattr(module, "_csvrows", None) is not None:  # an old recorder's C rows took float64 columns (a call
        module._csvrows = None  # today's module no longer has): its reference writes the same text
    return module


def peak_rss_kib(code: str, *args: str, timeout_s: float = 300.0) -> int:
    """Run ``code`` in a fresh Python with ``args``; the last number it prints (its peak RSS, KiB on Linux)."""
    done = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=timeout_s,
                          cwd=REPO_ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    return int(done.stdout.split()[-1])


def every_code_layout(*, wrap: bool = True) -> RowLayout:
    """A row of every struct code a layout may use: scaled, unscaled, NaN-scaled (a whole-number
    column too) and wrapped columns, in every format the CSV writer takes (the NPZ writer's columns
    are float64 whatever the format: tests/test_csv_rows.py and tests/test_npz_writer.py)."""
    fields = (("k", "Q"), ("b", "B"), ("h", "h"), ("hu", "H"), ("i", "i"), ("iu", "I"), ("q", "q"), ("f", "f"),
              ("d", "d"), ("marker", "B"))
    columns = (("t_s", "s", "%.6f", "k", 5e-5), ("b", "", "%d", "b", 1.0), ("h", "", "%d", "h", 0.1),
               ("hu", "", "%.1f", "hu", 1.0), ("i", "", "%d", "i", 1.5), ("iu", "", "%.0f", "iu", 1.0),
               ("q", "", "%d", "q", 3.0), ("f", "", "%.5f", "f", 1.0), ("d", "", "%.9f", "d", 57.29577951308232),
               ("nan", "", "%d", "i", float("nan")), ("deg", "deg", "%.3f", "d", 57.29577951308232),
               ("neg", "", "%.4f", "q", -1.0), ("marker", "", "%d", "marker", 1.0))
    return RowLayout(fields, columns, wrap=(("deg", 360.0), ("neg", 7.0)) if wrap else ())


def hostile_rows(layout: RowLayout, n_rows: int, seed: int) -> bytes:
    """Random raw bytes of a layout with fields d (double), q (int64), marker and k (every integer,
    every double bit pattern: NaN, inf, subnormals, huge), some doubles on a 360-degree wrap's edges
    and integers at their limits; k increases (read_recording checks the time column)."""
    rng = np.random.default_rng(seed)
    rows = np.frombuffer(rng.bytes(n_rows * layout.dtype.itemsize), dtype=layout.dtype).copy()
    edges = np.array([0.0, -0.0, 360.0 / 57.29577951308232, -1e-300, 1e300, -720.0, np.inf, -np.inf, np.nan, 2.5])
    rows["d"][::3] = rng.choice(edges, size=len(rows["d"][::3]))
    rows["q"][::5] = rng.choice([0, -7, 7, -1, 14, -(2**63), 2**63 - 1], size=len(rows["q"][::5]))
    rows["marker"] = rng.integers(0, 4, size=n_rows)
    rows["k"] = np.arange(n_rows)
    return rows.tobytes()
