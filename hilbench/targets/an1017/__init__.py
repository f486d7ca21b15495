"""The AN1017 sinusoidal-drive firmware (dsPIC30F2010, PICDEM MC LV) as a hilbench target.

`firmware` is the readable fixed-point model, `target` puts it behind the Target interface (with
the compiled core `_core` as its accelerator), `svm` and `fixedpoint` are the firmware's tables and
Q15 arithmetic. This module declares the target's PROFILE: its `[target]` options, gains and their
constraints, the pot that carries the speed reference, and its telemetry columns.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Literal, Mapping

from hilbench.fieldspec import spec
from hilbench.pwm import PwmTiming
from hilbench.protocol import TelemetryId
from hilbench.targets.profile import MotorBuild, ParamReference, PotReference, TargetProfile, TelemetryColumn

from hilbench.targets.qemu import QemuStarter
from hilbench.targets.starters import HostExecutableStarter, SimavrStarter

if TYPE_CHECKING:
    from pathlib import Path

    from hilbench.targets.qemu import M4Build

    from hilbench.targets.base import Target

#: MeasuredSpeed = trunc(312·32768/Period) and rpm = 1 875 000/Period (the application note's
#: Table 6), so one Q15 step of speed is 1 875 000/(312·32768) rpm; 32767 ≈ 6009.6 rpm. That is
#: the note's build (10 poles, 6000 rpm); other builds: `firmware.rpm_per_speed_q15`.
RPM_PER_SPEED_Q15 = 1_875_000 / (312 * 32768)
#: the pot in ADC FORM = 11 (signed fractional): RefSpeed = (code − 512) << 6
POT_MID_CODE = 512
POT_Q15_PER_COUNT = 64
POT_MAX_CODE = 1023
GAIN_NAMES = ("kp", "ki", "kd")
POLE_PAIRS = 5  # the Hurst DMB0224C10002: 10 poles (the note's build; `[target] pole_pairs`)
MAX_SPEED_RPM = 6000  # the note's MINPERIOD: "6000 max rpm and 10 poles motor"


def ref_speed_q15_for_code(code: int) -> int:
    """The firmware's RefSpeed for a 10-bit pot code."""
    return ((code & 0x3FF) - POT_MID_CODE) * POT_Q15_PER_COUNT


def pot_code_for_rpm(speed_rpm: float, rpm_per_speed_q15: float = RPM_PER_SPEED_Q15) -> int:
    """The 10-bit pot code whose RefSpeed is nearest to ``speed_rpm`` (clamped to the pot)."""
    ref_q15 = speed_rpm / rpm_per_speed_q15
    code = POT_MID_CODE + round(ref_q15 / POT_Q15_PER_COUNT)
    return min(POT_MAX_CODE, max(0, code))


def rpm_for_pot_code(code: int, rpm_per_speed_q15: float = RPM_PER_SPEED_Q15) -> float:
    """The speed reference in rpm the firmware makes of a pot code."""
    return ref_speed_q15_for_code(code) * rpm_per_speed_q15


@dataclass(frozen=True)
class An1017Settings:
    """[target] for AN1017: the firmware variant, the gains written after the handshake, and the
    motor the firmware is built for (the note's build constants; defaults: its 10-pole, 6000 rpm)."""

    variant: Literal["appnote", "v11", "seed"] = field(default="appnote", metadata=spec(
        doc="appnote: the AN1017 application note's behaviour; v11: the v1.1 firmware source's (what a board "
            "flashed with Microchip's v1.1 build runs); \"seed\" is an older name for appnote"))
    kp: float | None = field(default=None, metadata=spec(ge=0, lt=1, doc="speed PID Kp (Q15 fraction; default: the firmware's 0.1)"))
    ki: float | None = field(default=None, metadata=spec(ge=0, lt=1, doc="speed PID Ki (default 0.01)"))
    kd: float | None = field(default=None, metadata=spec(ge=0, lt=1, doc="speed PID Kd (default 0)"))
    pole_pairs: int = field(default=POLE_PAIRS, metadata=spec(ge=1, le=32, doc="the motor the firmware is built for: its speed scale (MINPERIOD, MAXPERIOD, the pot's and telemetry's rpm)"))
    max_speed_rpm: int = field(default=MAX_SPEED_RPM, metadata=spec(ge=100, le=60000, doc="the build's maximum speed: MeasuredSpeed 1.0 (MINPERIOD)"))


def _make(settings: An1017Settings | None) -> "Target":
    from hilbench.targets.an1017.firmware import An1017Options
    from hilbench.targets.an1017.target import An1017Target

    if not isinstance(settings, An1017Settings):
        settings = An1017Settings()
    return An1017Target(An1017Options(variant=settings.variant, pole_pairs=settings.pole_pairs,
                                      max_speed_rpm=settings.max_speed_rpm))


def _twin(settings: An1017Settings | None) -> "Target":
    """The in-process target on the firmware's own C source (the `c` backend): bit-exact with the
    sil:, simavr: and qemu: builds (tests/test_golden_recordings.py), the twin of speculation."""
    from hilbench.targets.an1017.firmware import An1017Options
    from hilbench.targets.an1017.target import An1017Target

    if not isinstance(settings, An1017Settings):
        settings = An1017Settings()
    return An1017Target(An1017Options(variant=settings.variant, pole_pairs=settings.pole_pairs,
                                      max_speed_rpm=settings.max_speed_rpm), backend="c")


def _settings(settings: object) -> An1017Settings:
    return settings if isinstance(settings, An1017Settings) else An1017Settings()


def _build_variant(settings: object) -> Literal["seed", "v11"]:
    return "v11" if _settings(settings).variant == "v11" else "seed"  # the firmware build's own word


def _defines(settings: object) -> tuple[str, ...]:
    from hilbench.targets.sil import motor_defines

    return motor_defines(_settings(settings).pole_pairs, _settings(settings).max_speed_rpm)


def _sil_exe(settings: object) -> "Path":
    """The board firmware (firmware/an1017 on the runtime) built for this host."""
    from hilbench.targets.sil import build_sil

    return build_sil(defines=_defines(settings))


def _avr_elf(settings: object) -> "Path":
    """The board firmware built for the ATmega328P of simavr."""
    from hilbench.targets.sil import build_avr

    return build_avr(_build_variant(settings), _defines(settings))


def _m4_build(settings: object) -> "M4Build":
    """The board firmware built for the Cortex-M4 in QEMU (firmware/runtime/ports/cortex_m4, goal an1017)."""
    from hilbench.targets.qemu import REPO, M4Build

    variant = _build_variant(settings)
    return M4Build("an1017", f"an1017_m4_{variant}.elf", (f"VARIANT={variant}", "DEFS=" + " ".join(_defines(settings))),
                   (REPO / "firmware" / "an1017", REPO / "firmware" / "runtime", REPO / "firmware_protocol"))


def _check_gains(raw: Mapping[str, int]) -> str | None:
    from hilbench.targets.an1017.firmware import GAIN_CONSTRAINT_NAMES, check_gain_constraints

    if not all(name in raw for name in GAIN_NAMES):
        return None
    broken = check_gain_constraints(raw["kp"], raw["ki"], raw["kd"])
    return None if broken is None else f"constraint #{broken} {GAIN_CONSTRAINT_NAMES[broken]}"


def _initial_params(settings: An1017Settings | None) -> dict[str, float]:
    if not isinstance(settings, An1017Settings):
        return {}
    return {name: value for name in GAIN_NAMES if (value := getattr(settings, name)) is not None}


def _telemetry(rpm_per_speed_q15: float) -> tuple[TelemetryColumn, ...]:
    return (
        TelemetryColumn(int(TelemetryId.MEASURED_SPEED), "measured_speed_rpm", "rpm", rpm_per_speed_q15),
        TelemetryColumn(int(TelemetryId.REF_SPEED), "ref_speed_rpm", "rpm", rpm_per_speed_q15),
        TelemetryColumn(int(TelemetryId.CONTROL_OUTPUT), "control_output_q15", "q15", 1.0, "%d"),
    )


def _pot(rpm_per_speed_q15: float) -> PotReference:
    return PotReference(lambda rpm: pot_code_for_rpm(rpm, rpm_per_speed_q15),
                        lambda code: rpm_for_pot_code(code, rpm_per_speed_q15), POT_MAX_CODE)


def _built_for(settings: An1017Settings | None) -> MotorBuild:
    if not isinstance(settings, An1017Settings):
        settings = An1017Settings()
    return MotorBuild(pole_pairs=settings.pole_pairs, max_speed_rpm=float(settings.max_speed_rpm))


def _configure(settings: An1017Settings | None) -> "TargetProfile[An1017Settings]":
    """The profile of the build these options ask for: its pot and telemetry rpm scales."""
    if not isinstance(settings, An1017Settings) or (settings.pole_pairs, settings.max_speed_rpm) == (POLE_PAIRS, MAX_SPEED_RPM):
        return PROFILE
    from hilbench.targets.an1017.firmware import An1017Options, rpm_per_speed_q15

    An1017Options(pole_pairs=settings.pole_pairs, max_speed_rpm=settings.max_speed_rpm)  # checks the build
    scale = rpm_per_speed_q15(settings.pole_pairs, settings.max_speed_rpm)
    return replace(PROFILE, reference=_pot(scale), telemetry=_telemetry(scale), monitor_reference=_override(scale))


def _override(rpm_per_speed_q15: float) -> ParamReference:
    """Monitor mode: the reference override (ref_ovr_on, ref_override in Q15 of the speed scale)."""
    return ParamReference("ref_override", 1.0 / (rpm_per_speed_q15 * 32768.0), enable="ref_ovr_on")


PROFILE: TargetProfile[An1017Settings] = TargetProfile(
    name="an1017",
    firmware_name="AN1017",
    make=_make,
    twin=_twin,
    description="Microchip AN1017 hall-sensored sinusoidal drive, dsPIC30F2010 (PICDEM MC LV)",
    options_type=An1017Settings,
    tunable=GAIN_NAMES,
    check_params=_check_gains,
    reference=PotReference(pot_code_for_rpm, rpm_for_pot_code, POT_MAX_CODE),
    telemetry=_telemetry(RPM_PER_SPEED_Q15),
    speed_column="measured_speed_rpm",
    monitor_reference=_override(RPM_PER_SPEED_Q15),
    built_for=_built_for,
    initial_params=_initial_params,
    capabilities=frozenset({"speed_loop", "realtime", "fault_injection", "tuning", "hall_sensors"}),
    sweep_defaults=(("kp", "0.05:0.85:10"), ("ki", "0.005:0.12:10"), ("kd", "0")),
    starters={
        "sil": HostExecutableStarter(_sil_exe, lambda settings: ["--variant", _build_variant(settings)], "an1017"),
        "simavr": SimavrStarter(_avr_elf, name="an1017"),
        "qemu": QemuStarter(_m4_build, name="an1017"),
    },
    configure=_configure,
    # dsPIC30F MCPWM in continuous up/down mode (PTCON 0x8002): a pin is active while PTMR < PDC, so
    # the pulses are centred on the counter's zero; the ADC's special event (SEVTCMP = 1, counting
    # up) falls one Tcy (0.1 % of the period) after it: taken as the zero
    pwm_timing=PwmTiming(pulse_centre="zero", adc_sample_phase=0.0),
)

__all__ = ["An1017Settings", "PROFILE", "RPM_PER_SPEED_Q15", "pot_code_for_rpm", "rpm_for_pot_code"]
