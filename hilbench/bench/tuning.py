"""Parameters as config fragments: what `ctl save` and `sweep --save` write and `run` loads back."""

from __future__ import annotations

import errno
from pathlib import Path
from typing import Mapping

from hilbench.bench.fileio import held_by_another, open_held
from hilbench.bench.recorder import journal_path_of


def params_fragment(params: Mapping[str, float], comment: str | None = None) -> str:
    """A `[target]` table with the given parameters, loadable with `hilbench run --gains-file`."""
    lines = [f"# {comment}"] if comment else []
    lines.append("[target]")
    for name, value in params.items():
        lines.append(f"{name} = {float(value):.6f}")
    return "\n".join(lines) + "\n"


def saved_fragment(get_reply: Mapping[str, object]) -> str:
    """What `ctl save` writes: the tunable parameters of a control socket `get` reply's data."""
    params = dict(get_reply.get("params", {}))  # type: ignore[call-overload]
    tunable = list(get_reply.get("tunable") or params)  # type: ignore[call-overload]
    return params_fragment({name: params[name] for name in tunable if name in params})


def write_fragment(path: Path | str, text: str, *, reader_wait_s: float | None = None) -> None:
    """A saved fragment written to ``path``, refused with an OSError when a running session records
    to that file (its rows, or an NPZ recording's journal: the archive would take the name after):
    a save must not cut a recording short, nor be replaced by one. A FIFO's reader is waited for
    ``reader_wait_s`` (`open_held`'s default when None)."""
    if held_by_another(journal_path_of(Path(path))):
        raise OSError(errno.EBUSY, "a running session records to it (its journal is being written)", str(path))
    with open_held(path, reader_wait_s=reader_wait_s) as handle:
        handle.write(text)
