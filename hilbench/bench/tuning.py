"""Parameters as config fragments: what `ctl save` and `sweep --save` write and `run` loads back."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Mapping

from hilbench.bench.outputs import open_output
from hilbench.errors import TargetError
from hilbench.limits import is_finite_number


def params_fragment(params: Mapping[str, float], comment: str | None = None) -> str:
    """A `[target]` table with the given parameters, loadable with `hilbench run --gains-file`."""
    lines = [f"# {comment}"] if comment else []
    lines.append("[target]")
    for name, value in params.items():
        lines.append(f"{name} = {float(value):.6f}")
    return "\n".join(lines) + "\n"


#: a parameter name a fragment can hold as a bare TOML key
_BARE_KEY = re.compile(r"[A-Za-z0-9_-]{1,64}")


def saved_fragment(get_reply: object) -> str:
    """What `ctl save` writes: the tunable parameters of a control socket `get` reply's data, checked
    (a socket that is not a hilbench session's, or another version's, is a TargetError, not a crash
    or a file that does not load)."""
    params = get_reply.get("params") if isinstance(get_reply, dict) else None
    tunable = get_reply.get("tunable") if isinstance(get_reply, dict) else None
    if not isinstance(params, dict) or not isinstance(tunable, (list, type(None))):
        raise TargetError("ctl save: the session's `get` reply holds no params and tunable list "
                          "(not a hilbench session of this version?)")
    for name in [*params, *(tunable or ())]:
        if not isinstance(name, str) or not _BARE_KEY.fullmatch(name):
            raise TargetError(f"ctl save: the session's `get` reply names a parameter {str(name)[:40]!r}, not a name "
                              "a config holds")
    values = {name: params[name] for name in (tunable or params) if name in params}
    if not all(is_finite_number(v) for v in values.values()):
        raise TargetError("ctl save: the session's `get` reply holds a parameter value that is not a finite number")
    return params_fragment(values)


def write_fragment(path: Path | str, text: str, *, reader_wait_s: float | None = None) -> None:
    """A saved fragment written to ``path`` (`open_output`: refused with an OSError when a running
    session records to that file: a save must not cut a recording short, nor be replaced by one).
    A FIFO's reader is waited for ``reader_wait_s`` (`open_held`'s default when None)."""
    with open_output(path, reader_wait_s=reader_wait_s) as handle:
        handle.write(text)
