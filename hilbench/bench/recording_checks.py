"""What a recording read back must be before anything uses it (report, plots, the scope's viewer).

A file on disk is input like any other: a damaged or hand-edited recording is refused here with
one line naming the file and what is wrong (a column, a row, a metadata key), so `hilbench report`
and the rest never meet a NaN time, a text column or a column shorter than the others.

The rules are what the recorder itself always writes: the base columns (`recorder.COLUMNS`), each
a 1-D array of numbers as long as ``t_s``; ``t_s`` finite and increasing; the metadata keys the
readers use with their types; events as text, ``segment:`` events with finite numbers.
"""

from __future__ import annotations

from typing import Any, Callable, Mapping

import numpy as np

from hilbench.bench.segments import parse_segment_event
from hilbench.errors import RecordingError
from hilbench.limits import RECORDING_MAX_BYTES, RECORDING_MAX_COLUMNS, is_finite_number, size_text


def _positive_number(value: Any) -> bool:
    return is_finite_number(value) and value > 0


def _positive_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 1


def _text_list(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(v, str) for v in value)


def _column_specs(value: Any) -> bool:
    return isinstance(value, list) and all(
        isinstance(v, list) and len(v) in (2, 3) and all(isinstance(x, str) for x in v) for v in value)


#: metadata key -> (what it must be, the check); keys not named here are kept as they are
METADATA_TYPES: Mapping[str, tuple[str, Callable[[Any], bool]]] = {
    "period_us": ("a positive number", _positive_number),
    "history_every_periods": ("a whole number >= 1", _positive_int),
    "target_hello": ("a table", lambda v: isinstance(v, dict)),
    "config": ("a table", lambda v: isinstance(v, dict)),
    "params": ("a table", lambda v: isinstance(v, dict)),
    "mode": ("text", lambda v: isinstance(v, str)),
    "target": ("text", lambda v: isinstance(v, str)),
    "end": ("text", lambda v: isinstance(v, str)),
    "events": ("a list of text", _text_list),
    "columns": ("a list of [name, unit(, format)]", _column_specs),
}


#: columns the recorder writes as whole numbers in every row (a report names fault rows by seq)
WHOLE_COLUMNS = ("seq", "marker")


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def check_metadata(where: str, metadata: Any) -> dict[str, Any]:
    """The metadata as a dict whose known keys have their types (RecordingError naming the key)."""
    if not isinstance(metadata, dict):
        raise RecordingError(f"recording {where}: metadata is {type(metadata).__name__}, not a table")
    for key, (what, good) in METADATA_TYPES.items():
        if key in metadata and not good(metadata[key]):
            raise RecordingError(f"recording {where}: metadata {key} is {_shown(metadata[key])}, not {what}")
    return metadata


def check_columns_fit(where: str, n_columns: int, n_rows: int) -> None:
    """A recording's size before its columns are read: at most RECORDING_MAX_COLUMNS columns and
    RECORDING_MAX_BYTES of float64 data."""
    if n_columns > RECORDING_MAX_COLUMNS:
        raise RecordingError(f"recording {where}: {n_columns} columns, more than the limit of {RECORDING_MAX_COLUMNS}")
    if n_columns * n_rows * 8 > RECORDING_MAX_BYTES:
        raise RecordingError(f"recording {where}: {n_rows} rows of {n_columns} columns need more than the limit of "
                             f"{size_text(RECORDING_MAX_BYTES)} in memory")


def _numbers(where: str, name: str, values: Any, n_rows: int | None) -> np.ndarray:
    array = np.asarray(values)
    if array.ndim != 1:
        raise RecordingError(f"recording {where}: column {name} has shape {array.shape}, not one value per row")
    if array.dtype.kind not in "biuf":
        raise RecordingError(f"recording {where}: column {name} holds {array.dtype} values, not numbers")
    if n_rows is not None and len(array) != n_rows:
        raise RecordingError(f"recording {where}: column {name} has {len(array)} rows, t_s has {n_rows}")
    return array if array.dtype == np.float64 else array.astype(np.float64)


def check_columns(where: str, columns: Mapping[str, Any], required: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Every column a 1-D float64 array as long as t_s, the required ones present, t_s finite and
    increasing."""
    missing = [name for name in required if name not in columns]
    if missing:
        raise RecordingError(f"recording {where}: no column {missing[0]}")
    t = _numbers(where, "t_s", columns["t_s"], None)
    bad = np.flatnonzero(~np.isfinite(t))
    if len(bad):
        raise RecordingError(f"recording {where}: t_s is {t[bad[0]]} at row {bad[0]}")
    back = np.flatnonzero(np.diff(t) <= 0)
    if len(back):
        raise RecordingError(f"recording {where}: t_s does not increase at row {back[0] + 1} "
                             f"({t[back[0]]!r} then {t[back[0] + 1]!r})")
    out = {name: (t if name == "t_s" else _numbers(where, name, values, len(t))) for name, values in columns.items()}
    for name in WHOLE_COLUMNS:
        bad = np.flatnonzero(~np.isfinite(out[name])) if name in out else ()
        if len(bad):
            raise RecordingError(f"recording {where}: {name} is {out[name][bad[0]]} at row {bad[0]}")
    return out


def check_column_header(where: str, name: str, shape: tuple[int, ...], dtype: np.dtype, n_rows: int | None) -> None:
    """A column known by its header only (an NPZ member read in chunks) by `check_columns`' rules:
    one number per row, as many rows as t_s (``n_rows``; None: this is t_s)."""
    if len(shape) != 1:
        raise RecordingError(f"recording {where}: column {name} has shape {shape}, not one value per row")
    if dtype.kind not in "biuf":
        raise RecordingError(f"recording {where}: column {name} holds {dtype} values, not numbers")
    if n_rows is not None and shape[0] != n_rows:
        raise RecordingError(f"recording {where}: column {name} has {shape[0]} rows, t_s has {n_rows}")


def check_chunk(where: str, first_row: int, columns: Mapping[str, np.ndarray], t_before: float | None) -> None:
    """Rows ``first_row..`` of a recording read in chunks, by `check_columns`' rules and with its
    row numbers: t_s finite and increasing (from ``t_before``, the last t_s of the chunk before),
    the whole-number columns finite."""
    t = columns["t_s"]
    bad = np.flatnonzero(~np.isfinite(t))
    if len(bad):
        raise RecordingError(f"recording {where}: t_s is {t[bad[0]]} at row {first_row + bad[0]}")
    joined = t if t_before is None else np.concatenate(([t_before], t))
    back = np.flatnonzero(np.diff(joined) <= 0)
    if len(back):
        row = first_row + back[0] + (1 if t_before is None else 0)
        raise RecordingError(f"recording {where}: t_s does not increase at row {row} "
                             f"({joined[back[0]]!r} then {joined[back[0] + 1]!r})")
    for name in WHOLE_COLUMNS:
        bad = np.flatnonzero(~np.isfinite(columns[name])) if name in columns else ()
        if len(bad):
            raise RecordingError(f"recording {where}: {name} is {columns[name][bad[0]]} at row {first_row + bad[0]}")


def check_events(where: str, events: Any) -> tuple[str, ...]:
    """Events as text; a ``segment:`` event with numbers that are not finite is refused."""
    if not _text_list(list(events) if isinstance(events, tuple) else events):
        raise RecordingError(f"recording {where}: events are not a list of text")
    for n, text in enumerate(events):
        try:
            parse_segment_event(text)
        except ValueError as exc:
            raise RecordingError(f"recording {where}: event {n}: {exc}") from None
    return tuple(events)


__all__ = ["METADATA_TYPES", "WHOLE_COLUMNS", "check_chunk", "check_column_header", "check_columns", "check_columns_fit",
           "check_events", "check_metadata"]
