"""Plant parameters: frozen dataclasses in SI units (unit in the name where it is not SI).

Flux from a back-EMF constant. Ke is quoted as volts line-to-line *peak* per 1000 rpm of the
shaft. At n rpm the shaft turns at wm = n*2*pi/60 rad/s, the electrical speed is we = p*wm, a
sinusoidal PM flux psi (peak per phase) gives a phase back-EMF of peak we*psi and a line-to-line
peak of sqrt(3)*we*psi. Hence

    psi = Ke / (sqrt(3) * p * 1000 * 2*pi/60)

Hurst DMB0224C10002: Ke = 7.32 V/krpm, p = 5 -> psi = 8.071 mWb (Kt = 1.5*p*psi = 60.5 mN*m/A).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from hilbench.pwm import PwmTiming  # a target's PWM timing, which the plant reads (the common layer: targets name it too)

__all__ = [
    "MotorParams",
    "InverterParams",
    "HallParams",
    "EncoderParams",
    "AdcChannel",
    "LoadProfile",
    "LOAD_IS_ACTIVE",
    "ProtectionParams",
    "PlantParams",
    "PwmTiming",
    "psi_from_ke",
    "ke_from_psi",
    "ADC_ROLE_CODES",
    "default_adc_channels",
]

RPM_PER_KRPM_RAD_S = 1000.0 * 2.0 * math.pi / 60.0  # 1000 rpm in rad/s


def psi_from_ke(ke_v_per_krpm: float, pole_pairs: int) -> float:
    """PM flux linkage (Wb, peak per phase) from Ke in V line-line peak per 1000 rpm (mechanical)."""
    return ke_v_per_krpm / (math.sqrt(3.0) * pole_pairs * RPM_PER_KRPM_RAD_S)


def ke_from_psi(psi_wb: float, pole_pairs: int) -> float:
    """Inverse of `psi_from_ke`."""
    return psi_wb * math.sqrt(3.0) * pole_pairs * RPM_PER_KRPM_RAD_S


@dataclass(frozen=True)
class MotorParams:
    """Surface or interior PMSM in the rotor (dq) frame, amplitude-invariant transform."""

    rs_ohm: float
    ld_h: float
    lq_h: float
    psi_wb: float
    pole_pairs: int
    j_kgm2: float
    b_nms_per_rad: float = 0.0
    coulomb_nm: float = 0.0

    @classmethod
    def from_ke(
        cls,
        *,
        rs_ohm: float,
        l_h: float | None = None,
        ld_h: float | None = None,
        lq_h: float | None = None,
        ke_v_per_krpm: float,
        pole_pairs: int,
        j_kgm2: float,
        b_nms_per_rad: float = 0.0,
        coulomb_nm: float = 0.0,
    ) -> "MotorParams":
        """Build from Ke (V line-line peak per krpm); `l_h` sets Ld = Lq when they are not given."""
        ld = ld_h if ld_h is not None else l_h
        lq = lq_h if lq_h is not None else l_h
        if ld is None or lq is None:
            raise ValueError("MotorParams.from_ke: give l_h or both ld_h and lq_h")
        return cls(
            rs_ohm=rs_ohm,
            ld_h=ld,
            lq_h=lq,
            psi_wb=psi_from_ke(ke_v_per_krpm, pole_pairs),
            pole_pairs=pole_pairs,
            j_kgm2=j_kgm2,
            b_nms_per_rad=b_nms_per_rad,
            coulomb_nm=coulomb_nm,
        )

    @property
    def kt_nm_per_a(self) -> float:
        """Torque per peak phase ampere on the q axis (id = 0)."""
        return 1.5 * self.pole_pairs * self.psi_wb


@dataclass(frozen=True)
class InverterParams:
    """Two-level three-phase inverter.

    model: "average" (the default) applies each period's mean leg voltages; "switching" switches
    every leg at its PWM edges, with the dead time at each edge and the conducting device chosen by
    the phase current at that instant (hilbench/plant/switching.py).
    average_dead_time: the averaged model's dead-band term. "sign" (the default): duty minus
    sign(i)·Td·f, with i the phase current at the period's start; "edges": what the switching model
    does on average, one Td per PWM edge inside the period with the current's sign at that edge
    (estimated from the period-start current, its mean slope and the PWM ripple the duties make),
    and none for a leg that does not switch (duty 0 or 1)."""

    vbus_v: float = 24.0
    pwm_freq_hz: float = 20000.0
    dead_time_s: float = 0.8e-6
    dead_time_enabled: bool = False
    model: Literal["average", "switching"] = "average"
    average_dead_time: Literal["sign", "edges"] = "sign"


@dataclass(frozen=True)
class HallParams:
    """Hall placement. offset_deg = 0 reproduces docs/facts.md §2.5:
    A = 1 for theta_e in [30, 210), B = 1 for [270, 90), C = 1 for [150, 330) (degrees electrical,
    theta_e = rotor d-axis angle, 0 = phase-1 axis). A positive offset moves every edge to a
    larger angle."""

    offset_deg: float = 0.0


@dataclass(frozen=True)
class EncoderParams:
    """Quadrature encoder: `lines` per mechanical turn, x4 decoding, 16-bit counter.

    Counts increase with theta (forward rotation) unless `reverse`; zero at theta_e = 0 plus
    `offset_counts`. Forward rotation means channel A leads B by 90 deg (the seed's Fig. 10): the
    x4 states run (A, B) = 00, 10, 11, 01. The index mark sits at `index_counts` x4 counts of
    forward rotation from theta_m = 0 (before `reverse`/`offset_counts`), once per turn."""

    lines: int = 500
    reverse: bool = False
    offset_counts: int = 0
    index_counts: int = 0


# ADC roles as in docs/design.md (NONE=0, POT=1, IBUS=2, VBUS=3, IA=4, IB=5).
ADC_ROLE_CODES: dict[str, int] = {"none": 0, "pot": 1, "ibus": 2, "vbus": 3, "ia": 4, "ib": 5}


@dataclass(frozen=True)
class AdcChannel:
    """One ADC channel: code = round(offset_codes + gain_codes_per_unit * x + noise), 0..2^bits - 1.

    x is the role's physical quantity: pot fraction 0..1, bus current A, bus voltage V, phase
    current A. `noise_lsb` is the standard deviation of seeded Gaussian noise in codes. `bits`:
    10 for the dsPIC30F2010, 12 for the F2812's converter."""

    role: Literal["pot", "ibus", "vbus", "ia", "ib"]
    gain_codes_per_unit: float
    offset_codes: float = 0.0
    noise_lsb: float = 0.0
    bits: int = 10


def default_adc_channels(vbus_v: float = 24.0) -> tuple[AdcChannel, ...]:
    """Documented defaults; the MCLV shunt amplifier and divider values are unknown (facts §6).

    Current channels: 0.1 ohm shunt, amplifier gain 7.5, 5 V full scale, mid-scale offset
    (512) so that negative current is visible: 0.1*7.5*1023/5 = 153.45 codes/A (range +-3.3 A).
    Bus voltage: divider chosen so that 1.6 x the nominal bus reads full scale.
    """
    i_gain = 0.1 * 7.5 * 1023.0 / 5.0
    return (
        AdcChannel("pot", 1023.0, 0.0, 0.0),
        AdcChannel("ibus", i_gain, 512.0, 0.0),
        AdcChannel("vbus", 1023.0 / (1.6 * vbus_v), 0.0, 0.0),
        AdcChannel("ia", i_gain, 512.0, 0.0),
        AdcChannel("ib", i_gain, 512.0, 0.0),
    )


@dataclass(frozen=True)
class LoadProfile:
    """Load torque (N*m, positive opposes forward rotation).

    kind: "constant" (torque_nm), "step" (torque_nm before step_time_s, step_torque_nm from the
    first period that starts at or after it), "linear" (coeff * w, w in rad/s), "quadratic"
    (coeff * w*|w|), "locked" (rotor held at its angle)."""

    kind: Literal["constant", "step", "linear", "quadratic", "locked"] = "constant"
    torque_nm: float = 0.0
    step_time_s: float = 0.0
    step_torque_nm: float = 0.0
    coeff: float = 0.0


#: Whether a load kind can drive the motor (active: a weight, gravity; it turns a stopped motor
#: backwards until a bench limit stops the run) or only opposes motion (passive: a fan, viscous
#: drag, a brake that holds).
LOAD_IS_ACTIVE: dict[str, bool] = {"constant": True, "step": True, "linear": False, "quadratic": False, "locked": False}


@dataclass(frozen=True)
class ProtectionParams:
    """Board and bench protections (docs/design.md, protections). Defaults: the Hurst motor on
    the MCLV board.

    overcurrent_a: the board's overcurrent comparator on the peak phase current (A; 0: none). Its
    output is latched and drives the target's FAULT input (the dsPIC's FLTA pin); the MCLV's trip
    level is set by a resistor (R60) whose value is not public, so the default 3.0 A is the
    Hurst075 motor file's overcurrent limit (Microchip hurst075.h, six-step project): 1.8 x the
    motor's rated 1.64 A peak, 4.4 x the default run's 0.68 A peak.
    gate_off_on_fault: the comparator also opens every switch in hardware (the PWM module's fault
    input), whatever the firmware does, until the firmware turns its outputs off (its stop).
    overspeed_rpm: a bench limit (0: none): the run ends with a fault. Default 4000 rpm: the
    Hurst's maximum in Microchip's Harmony motor table (hurst075.h: 3500 rpm with field
    weakening), above the 3.2-3.3 krpm the motor reaches at 24 V (Ke = 7.32 V/krpm) and below
    the speed at which its back-EMF, rectified by the open bridge's diodes, would drive more than
    1 A into the 24 V bus ((7.32 x 4 - 24) V / 2 Rs).
    bus_capacitance_f: the bus capacitor that regeneration charges (0: a stiff bus, the default:
    the MCLV's capacitance and its supply's behaviour are not public). With it the supply only
    sources: Vbus rises above the supply's voltage while the bridge returns energy.
    overvoltage_v: a bench limit on that bus voltage (0: none)."""

    overcurrent_a: float = 3.0
    gate_off_on_fault: bool = True
    overspeed_rpm: float = 4000.0
    bus_capacitance_f: float = 0.0
    overvoltage_v: float = 0.0


@dataclass(frozen=True)
class PlantParams:
    motor: MotorParams
    inverter: InverterParams = field(default_factory=InverterParams)
    hall: HallParams = field(default_factory=HallParams)
    encoder: EncoderParams = field(default_factory=EncoderParams)
    adc: tuple[AdcChannel, ...] = field(default_factory=default_adc_channels)
    load: LoadProfile = field(default_factory=LoadProfile)
    #: a bare plant has no board around it (physics tests drive it past any limit); a bench
    #: config's [protection] table (its defaults: ProtectionParams()) gives it the board's
    protection: ProtectionParams = field(default_factory=lambda: ProtectionParams(0.0, False, 0.0, 0.0, 0.0))
    #: the target's PWM geometry (its profile's `pwm_timing`; the bench fills it in)
    pwm: PwmTiming = field(default_factory=PwmTiming)

    @classmethod
    def hurst(cls) -> "PlantParams":
        """The Hurst DMB0224C10002 on the MCLV board (docs/facts.md §5, recommended defaults)."""
        motor = MotorParams.from_ke(
            rs_ohm=2.54, l_h=2.21e-3, ke_v_per_krpm=7.32, pole_pairs=5,
            j_kgm2=5.5e-6, b_nms_per_rad=1.53e-5, coulomb_nm=0.0,
        )
        return cls(motor=motor)
