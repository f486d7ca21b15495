"""The F2812 FOC paper's target: sensored FOC with the simplified SVPWM on a TMS320F2812 (IQ24).

Modules: iqmath (IQmath semantics), blocks (TI DMC blocks), svpwm (the paper's simplified SVPWM), firmware
(the ISR, start-up, options and gains), target (the Target interface). docs/foc.md says what it
models and how. This module declares the target's PROFILE: its `[target]` options (FocOptions),
tunable speed-loop gains, the speed reference as the `speed_rpm` parameter, telemetry columns.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hilbench.pwm import PwmTiming
from hilbench.protocol import TelemetryId
from hilbench.targets.foc.firmware import FocOptions
from hilbench.targets.profile import MotorBuild, ParamReference, TargetProfile, TelemetryColumn
from hilbench.targets.qemu import QemuStarter
from hilbench.targets.starters import HostExecutableStarter, SimavrStarter

#: the AVR the FOC build runs on in simavr (its 32 KB sine table needs more flash than a 328P has)
AVR_MCU = "atmega1284p"

if TYPE_CHECKING:
    from hilbench.targets.base import Target

#: telemetry is Q15 per unit: speed of BaseRpm 3000, currents of the 5 A base (FocOptions defaults)
RPM_PER_Q15 = 3000 / 32768
AMP_PER_Q15 = 5.0 / 32768


def _tid(name: str, fallback: int) -> int:
    return int(getattr(TelemetryId, name, fallback))


#: the one telemetry table: (FocFirmware.telemetry_q15 key, id, column, unit, scale, format), in the
#: order the Drive carries them. Ids are protocol v2's where it names them, else 0x80-0xFE. At most
#: 8 (the protocol's max_telemetry): the i_d reference is a parameter, read with get_param.
TELEMETRY_SPEC: tuple[tuple[str, int, str, str, float, str], ...] = (
    ("ref_speed", _tid("REF_SPEED", 1), "ref_speed_rpm", "rpm", RPM_PER_Q15, "%.3f"),
    ("speed", _tid("MEASURED_SPEED", 2), "measured_speed_rpm", "rpm", RPM_PER_Q15, "%.3f"),
    ("iq_ref", _tid("IQ_REF", int(TelemetryId.CONTROL_OUTPUT)), "iq_ref_a", "A", AMP_PER_Q15, "%.4f"),
    ("i_d", _tid("ID", 5), "i_d_a", "A", AMP_PER_Q15, "%.4f"),
    ("i_q", _tid("IQ", 6), "i_q_a", "A", AMP_PER_Q15, "%.4f"),
    ("theta_e", _tid("THETA_E", 0x82), "fw_theta_e_deg", "deg", 360 / 32768, "%.3f"),
    ("v_d", _tid("VD", 0x83), "v_d_pu", "pu of Udc/sqrt3", 1 / 32768, "%.4f"),
    ("v_q", _tid("VQ", 0x84), "v_q_pu", "pu of Udc/sqrt3", 1 / 32768, "%.4f"),
)


def _make(options: FocOptions | None) -> "Target":
    from hilbench.targets.foc.target import FocTarget

    return FocTarget(options if isinstance(options, FocOptions) else FocOptions())


def _twin(options: FocOptions | None) -> "Target":
    """The in-process target on the firmware's own C source (the `c` backend), bit-exact with its
    builds: the twin of speculation."""
    from hilbench.targets.foc.target import FocTarget

    return FocTarget(options if isinstance(options, FocOptions) else FocOptions(), backend="c")


def _sil_exe(options: object) -> Any:
    from hilbench.targets.foc.build import build_sil

    return build_sil(options if isinstance(options, FocOptions) else FocOptions())


def _avr_elf(options: object) -> Any:
    from hilbench.targets.foc.build import build_avr

    return build_avr(options)


def _m4_build(options: object) -> Any:
    from hilbench.targets.foc.build import qemu_build

    return qemu_build(options)


def make_foc_target(**options: Any) -> "Target":
    """A `FocTarget` with `FocOptions` fields as keyword options."""
    from hilbench.targets.foc.target import make_foc_target as _make_named

    return _make_named(**options)


PROFILE: TargetProfile[FocOptions] = TargetProfile(
    name="foc",
    firmware_name="F2812FOC",
    make=_make,
    twin=_twin,
    description="sensored FOC with the simplified SVPWM, TMS320F2812 in IQ24 (the 200 W servo of the F2812 FOC paper)",
    options_type=FocOptions,
    tunable=("spd_kp", "spd_ki", "spd_kc"),
    reference=ParamReference("ref_rpm", 1.0),
    telemetry=tuple(TelemetryColumn(tid, col, unit, scale, fmt) for _, tid, col, unit, scale, fmt in TELEMETRY_SPEC),
    speed_column="measured_speed_rpm",
    built_for=lambda options: MotorBuild(pole_pairs=getattr(options, "pole_pairs", 3), max_speed_rpm=3000.0),
    capabilities=frozenset({"speed_loop", "realtime", "tuning", "encoder"}),
    sweep_defaults=(("spd_kp", "0.2:1.2:6"), ("spd_ki", "0.002:0.03:6")),
    starters={
        "sil": HostExecutableStarter(_sil_exe, name="foc"),
        "simavr": SimavrStarter(_avr_elf, mcu=AVR_MCU, name="foc"),
        "qemu": QemuStarter(_m4_build, name="foc"),
    },
    # F2812 Event Manager, timer 1 continuous up/down, active-high outputs: high while T1CNT > CMPR,
    # so the pulses are centred on the counter's peak (period match); the ADC starts on underflow
    pwm_timing=PwmTiming(pulse_centre="peak", adc_sample_phase=0.0),
)

__all__ = ["PROFILE", "FocOptions", "TELEMETRY_SPEC", "make_foc_target"]
