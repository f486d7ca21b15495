"""CSV rows in C (hilbench/bench/_csvrows.c) write what Python's `fmt % row` writes, cell for cell,
and a recording's CSV is the same text with the accelerator and with the reference."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from hilbench.bench import recorder as recorder_module

_csvrows = recorder_module._csvrows
pytestmark = pytest.mark.skipif(_csvrows is None, reason="the CSV row formatter is not built")

FORMATS = ["%d", "%.0f", "%.1f", "%.3f", "%.4f", "%.5f", "%.6f", "%.9f", "%.12f", "%.6g", "%.3e", "%.17g"]


def _edge_values() -> np.ndarray:
    """Ties at every precision, signed zeros, NaN and infinities, huge, tiny and subnormal values,
    values next to powers of two and ten, and a seeded spread."""
    special = [0.0, -0.0, 0.5, -0.5, 1.5, 2.5, -2.5, 0.125, 0.375, -0.625, 1e-7, -1e-7, 5e-7, 4.9999999e-7,
               0.05, 0.15, 0.25, 0.35, 1.0005, 2.675, 1e15, -1e15, 9.2e18 - 2048, 2.0 ** 63, -(2.0 ** 63), 1e300,
               -1e300, 5e-324, -5e-324, 2.2250738585072014e-308, 123456.7890125, 999.9995, 0.9999995, 9.5, 10.5,
               float("nan"), -float("nan"), float("inf"), -float("inf"), 1499.99999999, 2 ** 52 + 0.5, 2.0 ** 53]
    rng = np.random.default_rng(7)
    spread = np.concatenate([rng.standard_normal(2000) * 10.0 ** rng.integers(-9, 12, 2000),
                             np.round(rng.standard_normal(2000) * 1e4, 7) + 5e-8,  # near the 7th digit's ties
                             np.arange(-1000, 1000) / 8.0])  # exact binary ties
    return np.concatenate([np.asarray(special), spread])


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_cell_is_what_percent_formatting_writes(fmt: str) -> None:
    values = _edge_values()
    if fmt == "%d":  # int(x): NaN, infinities and values from 2^63 send their block to Python
        finite = values[np.isfinite(values) & (np.abs(values) < 9e18)]
        text = _csvrows.format_rows([finite], [fmt], 0, len(finite))
        assert text is not None
        assert text.splitlines() == [fmt % x for x in finite.tolist()]
        assert _csvrows.format_rows([values], [fmt], 0, len(values)) is None
        return
    text = _csvrows.format_rows([values], [fmt], 0, len(values))
    assert text is not None
    assert text.splitlines() == [fmt % x for x in values.tolist()]


def test_rows_join_their_columns_and_take_a_slice() -> None:
    values = _edge_values()
    finite = values[np.isfinite(values)][:500]
    columns = [finite, finite * 3.0, np.arange(len(finite), dtype=np.float64)]
    formats = ["%.6f", "%.1f", "%d"]
    text = _csvrows.format_rows(columns, formats, 17, 301)
    fmt = ",".join(formats) + "\n"
    assert text == "".join(fmt % row for row in zip(*(c[17:301].tolist() for c in columns)))


def test_formats_it_does_not_take_go_to_python() -> None:
    column = np.arange(5, dtype=np.float64)
    for fmt in ("%8.3f", "%+.2f", "%g", "%.2E", "%5d", "%.123f", "x"):
        assert _csvrows.format_rows([column], [fmt], 0, 5) is None
    assert _csvrows.format_rows([column.astype(np.float32)], ["%.3f"], 0, 5) is None  # float64 only
    assert _csvrows.format_rows([column], ["%.3f"], 0, 6) is None  # past the end


@pytest.mark.parametrize("with_c", [True, False])
def test_a_csv_recording_is_the_same_text_with_the_accelerator(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                with_c: bool) -> None:
    """Rows with events between them, at the start and after the last row; a huge value in a %d column
    sends its flush to Python, and the text stays the same."""
    texts = []
    for use_c in (True, False):
        monkeypatch.setattr(recorder_module, "_csvrows", _csvrows if use_c else None)
        path = tmp_path / f"r{use_c}.csv"
        rec = recorder_module.Recorder(path, {"test": 1}, flush_rows=50)
        rec.start()
        columns = len(rec.rows.layout.fields)
        rng = np.random.default_rng(3)
        rec.event("at the start")
        for i in range(173):
            row = rng.standard_normal(columns) * 1000.0
            if not with_c and i == 120:
                row[:] = 1e30  # beyond the C path's %d: the flush goes to Python
            rec.append(tuple(float(x) for x in row))
            if i % 37 == 0:
                rec.event(f"event {i}")
        rec.close("the end")
        texts.append(path.read_text())
    assert texts[0] == texts[1] and texts[0].count("\n") > 180
    assert struct.calcsize("<d") == 8
