"""Field metadata for config dataclasses: unit, one-line doc and a physical range.

It lives below every layer so that a target's options dataclass (hilbench.targets) can declare
its `[target]` table with the same metadata the config loader (hilbench.config) validates.
"""

from __future__ import annotations

from typing import Any


def spec(*, unit: str = "", doc: str = "", ge: float | None = None, gt: float | None = None,
         le: float | None = None, lt: float | None = None) -> dict[str, Any]:
    """Field metadata: unit, one-line doc and an inclusive/exclusive physical range."""
    return {"unit": unit, "doc": doc, "ge": ge, "gt": gt, "le": le, "lt": lt}


__all__ = ["spec"]
