"""A recording written out as CSV a chunk of rows at a time: `report --csv` of a 600 s run in the
memory of one chunk (the whole table stacked at once took 1.25 GB for a 60 s run)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hilbench.bench.column_chunks import ColumnChunks
from hilbench.bench.recorder import COLUMNS, Recorder, float_layout
from hilbench.bench.recording_head import RecordingHead

#: rows formatted at a time (their text is ~200 bytes a row, several copies on the way)
EXPORT_CHUNK_ROWS = 16384


def export_csv_chunks(head: RecordingHead, source: ColumnChunks, path: str | Path) -> Path:
    """Write the recording as the same CSV a `--record run.csv` run writes, byte for byte the text
    of the whole-table export: each row's text depends on that row only."""
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


__all__ = ["export_csv_chunks"]
