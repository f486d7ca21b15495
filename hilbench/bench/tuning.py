"""Gains as config fragments: what `ctl save` and `sweep --save` write and `run` loads back."""

from __future__ import annotations

from typing import Mapping

GAIN_NAMES = ("kp", "ki", "kd")


def gains_fragment(params: Mapping[str, float], comment: str | None = None) -> str:
    """A `[target]` table with the gains, loadable with `hilbench run CONFIG` or merged by hand."""
    lines = [f"# {comment}"] if comment else []
    lines.append("[target]")
    for name in GAIN_NAMES:
        if name in params:
            lines.append(f"{name} = {float(params[name]):.6f}")
    return "\n".join(lines) + "\n"
