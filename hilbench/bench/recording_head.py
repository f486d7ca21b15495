"""What a recording says besides its rows: metadata, events, units and CSV formats, read without
its columns (a `hilbench report` of a 600 s run reads those a chunk at a time).

NPZ: the metadata member only; a journal: its header and events side file; CSV: one pass that
keeps the ``#`` lines and drops each block of rows as it is parsed. Checked by the rules
`read_recording` applies to them (hilbench.bench.recording_checks).
"""

from __future__ import annotations

import struct
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hilbench.bench import recording_checks as rules
from hilbench.bench.column_chunks import ColumnChunks, CsvChunks, JournalChunks, NpzChunks
from hilbench.bench.recorder import _csv_format, _events_path, _read_journal_rows, csv_blocks, npz_metadata, unreadable
from hilbench.errors import RecordingError


@dataclass(frozen=True)
class RecordingHead:
    """A recording's metadata and events (as RecordingData holds them), its columns' units and formats."""

    path: Path
    metadata: dict[str, Any]
    events: tuple[str, ...]
    units: dict[str, str]
    formats: dict[str, str]


def read_head(source: ColumnChunks) -> RecordingHead:
    """The head of the file ``source`` reads (RecordingError, one line, for a damaged one)."""
    path = Path(source.where)
    try:
        if isinstance(source, NpzChunks):
            metadata, events, formats = _npz_head(path)
        elif isinstance(source, JournalChunks):
            metadata, events, formats = _journal_head(path)
        elif isinstance(source, CsvChunks):
            metadata, events, formats = _csv_head(path)
        else:
            raise RecordingError(f"recording {source.where}: not a file")
    except RecordingError:
        raise
    except (OSError, ValueError, KeyError, EOFError, TypeError, IndexError, RecursionError, MemoryError,
            struct.error, zipfile.BadZipFile, UnicodeDecodeError) as exc:
        raise unreadable(path, exc) from None
    where = str(path)
    return RecordingHead(path, rules.check_metadata(where, metadata), rules.check_events(where, tuple(events)),
                         dict(source.units), {str(k): str(v) for k, v in formats.items() if _csv_format(v)})


def _npz_head(path: Path) -> tuple[Any, list[str], dict[str, str]]:
    with zipfile.ZipFile(path) as archive:
        metadata = npz_metadata(path, archive)
    specs = metadata.get("columns") or [] if isinstance(metadata, dict) else []
    formats = {str(spec[0]): str(spec[2]) for spec in specs if isinstance(spec, list) and len(spec) > 2}
    return metadata, list(metadata.get("events", ())) if isinstance(metadata, dict) else [], formats


def _journal_head(path: Path) -> tuple[Any, list[str], dict[str, str]]:
    from hilbench.limits import RECORDING_META_MAX_BYTES, read_text_bounded

    metadata, layout, _ = _read_journal_rows(path, head_only=True)
    side = _events_path(path)
    events = read_text_bounded(side, RECORDING_META_MAX_BYTES, RecordingError, f"recording {side}").splitlines() \
        if side.exists() else []
    return metadata, events, {name: fmt for name, _, fmt in layout.column_specs}


def _csv_head(path: Path) -> tuple[Any, list[str], dict[str, str]]:
    metadata: dict[str, Any] = {}
    events: list[str] = []
    for _ in csv_blocks(path, metadata, events, {}):
        pass  # each block dropped as soon as it is parsed
    return metadata, events, {}


__all__ = ["RecordingHead", "read_head"]
