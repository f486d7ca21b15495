"""Whether the plant's integrator can follow a motor at a period: its fastest modes against RK4.

The plant integrates a period in chunks of at most `period.MAX_STEP_US`, each in ``substeps`` RK4
steps. RK4 is stable on the negative real axis for |lambda dt| < 2.785; a mode faster than that
makes the simulation diverge. The fastest rates of a PMSM: electrical R/L, mechanical B/J and the
electromechanical oscillation sqrt(1.5 p^2 psi^2 / (L J)) (the speed/current loop through the
back-EMF). The config asks here before a run starts and names the key at fault.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hilbench.plant.params import MotorParams
from hilbench.plant.period import Period

#: RK4's stability limit on the negative real axis is |lambda dt| < 2.785; keep a margin
RK4_MAX_LAMBDA_DT = 2.5


@dataclass(frozen=True)
class StiffMode:
    """A mode of the motor too fast for the integrator at a period."""

    what: str  # e.g. "R/L = 2.54 ohm / 0.00221 H"
    rate_per_s: float
    substeps_needed: float  # RK4 steps per chunk the mode needs (inf: none suffice)
    #: the MotorParams fields the rate depends on, most specific first
    depends_on: tuple[str, ...]


def stiff_modes(motor: MotorParams, period_us: int, substeps: int) -> list[StiffMode]:
    """The motor's modes the plant cannot follow at ``period_us`` with ``substeps`` RK4 steps per
    chunk (empty: it can). Raises ArithmeticError/ValueError when the values overflow the equations."""
    chunk_s = Period(period_us).chunk_s
    l_min = min(motor.ld_h, motor.lq_h)
    modes = (
        (motor.rs_ohm / l_min, f"R/L = {motor.rs_ohm:g} ohm / {l_min:g} H", ("ld_h", "lq_h", "rs_ohm")),
        (motor.b_nms_per_rad / motor.j_kgm2, f"B/J = {motor.b_nms_per_rad:g} / {motor.j_kgm2:g} kg*m^2",
         ("b_nms_per_rad", "j_kgm2")),
        (math.sqrt(1.5 * motor.pole_pairs**2 * motor.psi_wb**2 / (l_min * motor.j_kgm2)),
         "the back-EMF loop sqrt(1.5 p^2 psi^2/(L J))", ("j_kgm2", "ld_h", "lq_h", "psi_wb", "pole_pairs")),
    )
    out = []
    for rate, what, keys in modes:
        needed = rate * chunk_s / RK4_MAX_LAMBDA_DT
        if not math.isfinite(needed) or needed > substeps:
            out.append(StiffMode(what, rate, needed if math.isfinite(needed) else math.inf, keys))
    return out


__all__ = ["RK4_MAX_LAMBDA_DT", "StiffMode", "stiff_modes"]
