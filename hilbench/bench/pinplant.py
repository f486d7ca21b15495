"""The bench's plant for a pin-level harness: a simulated chip's pins against the config's motor.

A harness that runs a firmware free on a simulated MCU (a port's run_motor.c: simavr, a
real-motor build) embeds Python and calls `PinPlant.period` once per PWM period at the
period boundary with the compare registers as fractions of the PWM's top and the bridge enable;
the plant (the same `Plant` and C core a HIL session integrates, built from the same config)
advances one PWM period with those duties held, and the harness puts every hall edge of it on the
hall pins at its own time (cycle-exact), and the pot's voltage on the ADC pin. So the same motor
runs under a free-running firmware (monitor mode) and under a lockstep session at a period of one
PWM period, and the two can be compared.
"""

from __future__ import annotations

from typing import Sequence

from hilbench.bench.assembly import build_plant
from hilbench.bench.settings import configured_target_profile, load_config
from hilbench.protocol import OutputMode
from hilbench.targets.profile import PotReference

OUTPUT_OFF = int(OutputMode.OFF)
OUTPUT_PWM = int(OutputMode.PWM)


class PinPlant:
    """The config's plant stepped one PWM period at a time by a harness."""

    def __init__(self, config_path: str | None, overrides: Sequence[str] = (), pwm_period_us: int = 50,
                 pot_full_scale_mv: float = 5000.0) -> None:
        cfg = load_config(config_path or None, tuple(overrides))
        profile = configured_target_profile(cfg)
        self.plant = build_plant(cfg, profile)
        if isinstance(profile.reference, PotReference):  # the board's pot where it asks for no speed
            self.plant.pot_fraction = profile.reference.pot_fraction(0.0)
        self.plant.set_period(int(pwm_period_us), 0, 1.0)
        self.pot_full_scale_mv = float(pot_full_scale_mv)
        self.periods = 0

    @property
    def hall_bits(self) -> int:
        """The hall lines now (bit 0 = A, 1 = B, 2 = C)."""
        return int(self.plant.hall_bits)

    def pot_mv(self) -> int:
        """The pot wiper's voltage on the ADC pin, in millivolts."""
        return int(round(self.plant.pot_fraction * self.pot_full_scale_mv))

    def period(self, duty_a: float, duty_b: float, duty_c: float, enabled: bool) -> tuple[tuple[float, int], ...]:
        """One PWM period with these duties (fractions 0..1) held, the bridge on or off: every hall
        edge of it as (seconds from the period's start, the hall bits after it)."""
        self.plant.advance(duty_a, duty_b, duty_c, OUTPUT_PWM if enabled else OUTPUT_OFF)
        self.periods += 1
        return self.plant.edges()

    def speed_rpm(self) -> float:
        """The rotor's speed (for the harness's own log)."""
        return float(self.plant.speed_rpm)


__all__ = ["PinPlant"]
