"""Where a target's PWM puts its pulses and when its ADC samples: a fact of the target's hardware
that its profile states and the plant's switching inverter reads. It sits below both layers
(docs/architecture.md, "common"), so neither the targets nor the plant name the other.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class PwmTiming:
    """Where a target's PWM puts its pulses and samples its currents, in the carrier's own terms.

    The carrier is a centre-aligned (up/down) counter whose zero falls on t = 0, T, 2T, ... of the
    plant's time (T = 1/pwm_freq_hz). `pulse_centre`: each leg's high-side pulse of duty d is d·T
    wide and centred on the counter's "zero" (the dsPIC30F MCPWM in up/down mode: active while
    PTMR < PDC) or on its "peak" (the F2812 Event Manager with active-high outputs: high while
    T1CNT > CMPR). `adc_sample_phase`: the instant, as a fraction of T after the counter's zero, at
    which the ADC samples the phase currents (0: at the zero). Only the switching inverter model
    reads it; the averaged model has no instant within a period."""

    pulse_centre: Literal["zero", "peak"] = "peak"
    adc_sample_phase: float = 0.0


__all__ = ["PwmTiming"]
