"""What the host needs to know about a firmware it meets by name in the HELLO.

The wire carries raw fixed-point telemetry; a profile says how to read it (speed scale) and how
to ask for a speed through the pot, so the bench never hard-codes a firmware's numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

#: AN1017: MeasuredSpeed = trunc(312·32768/Period) and rpm = 1 875 000/Period (Table 6), so one
#: Q15 step of speed is 1 875 000/(312·32768) rpm; 32767 ≈ 6009.6 rpm.
AN1017_RPM_PER_Q15 = 1_875_000 / (312 * 32768)


@dataclass(frozen=True)
class TargetProfile:
    """How the host reads one firmware's telemetry and drives its reference."""

    firmware_name: str
    rpm_per_speed_q15: float | None  # None: the target reports no speed
    pot_counts_per_q15: float | None  # AN1017: RefSpeed = (code - 512)·64
    gain_params: tuple[str, ...] = ()
    constraint_module: str | None = None  # module with check_gain_constraints and GAIN_CONSTRAINT_NAMES

    def gain_constraint_broken(self, gains_q15: dict[str, int]) -> str | None:
        """The firmware's own gain constraint that ``gains_q15`` breaks, as text, or None."""
        if self.constraint_module is None or not all(name in gains_q15 for name in self.gain_params):
            return None
        import importlib

        module = importlib.import_module(self.constraint_module)
        broken = module.check_gain_constraints(*(gains_q15[name] for name in self.gain_params))
        return None if broken is None else f"constraint #{broken} {module.GAIN_CONSTRAINT_NAMES[broken]}"

    def speed_rpm(self, speed_q15: int) -> float:
        """Telemetry speed (Q15) in rpm, or NaN where the target has no speed scale."""
        if self.rpm_per_speed_q15 is None:
            return float("nan")
        return speed_q15 * self.rpm_per_speed_q15

    def pot_code_for_rpm(self, speed_rpm: float) -> int:
        """The 10-bit pot code whose RefSpeed is nearest to ``speed_rpm`` (clamped to the pot)."""
        if self.rpm_per_speed_q15 is None or self.pot_counts_per_q15 is None:
            return 512
        ref_q15 = speed_rpm / self.rpm_per_speed_q15
        code = 512 + round(ref_q15 * self.pot_counts_per_q15)
        return min(1023, max(0, code))


AN1017_PROFILE = TargetProfile(
    "AN1017", AN1017_RPM_PER_Q15, 1 / 64, ("kp", "ki", "kd"), "hilbench.targets.an1017_firmware"
)
#: F2812 FOC: speed telemetry is SPEED_FR's Speed (pu of BaseRpm 3000) shifted to Q15; no pot.
F2812FOC_PROFILE = TargetProfile("F2812FOC", 3000 / 32768, None)
GENERIC_PROFILE = TargetProfile("generic", None, None)

_PROFILES = {"AN1017": AN1017_PROFILE, "F2812FOC": F2812FOC_PROFILE}


def profile_for(firmware_name: str) -> TargetProfile:
    """The profile of a firmware by its HELLO name; a neutral one for unknown firmware."""
    return _PROFILES.get(firmware_name.strip().upper(), GENERIC_PROFILE)
