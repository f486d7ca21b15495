"""Parameters as config fragments: what `ctl save` and `sweep --save` write and `run` loads back."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

from hilbench.bench.fileio import open_held


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


def write_fragment(path: Path | str, text: str) -> None:
    """A saved fragment written to ``path``, refused with an OSError when a running session records
    to that file: a save must not cut a recording short."""
    with open_held(path) as handle:
        handle.write(text)
