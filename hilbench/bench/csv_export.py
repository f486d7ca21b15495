"""A recording written out as CSV a chunk of rows at a time: `report --csv` of a 600 s run in the
memory of one chunk (the whole table stacked at once took 1.25 GB for a 60 s run)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hilbench.bench.column_chunks import ColumnChunks
from hilbench.bench.fileio import file_identity
from hilbench.bench.recorder import (COLUMNS, JOURNAL_SUFFIX, Recorder, _events_path, _tmp_archive_path_of, float_layout,
                                     journal_path_of)
from hilbench.bench.recording_head import RecordingHead
from hilbench.errors import RecordingError

#: rows formatted at a time (their text is ~200 bytes a row, several copies on the way)
EXPORT_CHUNK_ROWS = 16384


def export_csv_chunks(head: RecordingHead, source: ColumnChunks, path: str | Path) -> Path:
    """Write the recording as the same CSV a `--record run.csv` run writes, byte for byte the text
    of the whole-table export: each row's text depends on that row only."""
    refuse_overwriting_source(source, Path(path))
    names = list(source.names)
    fmts = {name: fmt for name, _, fmt in COLUMNS}
    formats = {name: head.formats.get(name) or fmts.get(name, "%.6g") for name in names}
    whole_number = [name for name in names if formats[name].endswith("d")]
    if whole_number:  # "%d" cannot write NaN or infinity: such a column is written with "%.6g"
        finite = dict.fromkeys(whole_number, True)
        for chunk in source.chunks(whole_number):
            for name in whole_number:
                finite[name] = finite[name] and bool(np.isfinite(chunk[name]).all())
        formats.update({name: "%.6g" for name, ok in finite.items() if not ok})
    out = Recorder(Path(path), dict(head.metadata))
    out.metadata.pop("columns", None)
    out.start(float_layout([(name, head.units.get(name, ""), formats[name]) for name in names]))
    for chunk in source.chunks(names, EXPORT_CHUNK_ROWS):
        table = np.column_stack([chunk[name] for name in names])
        out.rows.extend(np.ascontiguousarray(table, dtype="<f8").tobytes())
        out.flush()
    out.close()
    return out.path


def refuse_overwriting_source(source: ColumnChunks, path: Path) -> None:
    """RecordingError when writing ``path`` would truncate a file the export reads: the recording
    itself (by any name: a link, another spelling) or its journal and events side file. The export
    reads the rows while it writes, so the recording would be lost and the export empty."""
    if source.where == ColumnChunks.where:  # rows in memory: no file to protect
        return
    read = Path(source.where)
    read_files = [read, _events_path(read)] if read.name.endswith(JOURNAL_SUFFIX) else [read]
    written = [path]
    if path.suffix.lower() == ".npz":  # an NPZ export writes its journal, then a temporary archive
        journal = journal_path_of(path)
        written += [journal, _events_path(journal), _tmp_archive_path_of(path)]
    taken = {file_identity(p) for p in read_files} - {None}
    for target in written:
        if file_identity(target) in taken:
            raise RecordingError(f"recording {path}: the export would overwrite {read}, the recording it reads: "
                                 f"give another path")


__all__ = ["export_csv_chunks", "refuse_overwriting_source"]
