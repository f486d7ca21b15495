"""The second seed's target: sensored FOC with the simplified SVPWM on a TMS320F2812 (IQ24).

`make_foc_target(**options)` builds it (options: `FocOptions` fields); docs/foc.md says what it
models and how. Modules: iqmath (IQmath semantics), blocks (TI DMC blocks), svpwm (the seed's
SVPWM), firmware (the ISR and start-up), target (the Target interface).
"""

from __future__ import annotations

from typing import Any


def make_foc_target(**options: Any) -> Any:
    """A `FocTarget` with `FocOptions` fields as keyword options."""
    from hilbench.targets.foc.target import make_foc_target as _make

    return _make(**options)


__all__ = ["make_foc_target"]
