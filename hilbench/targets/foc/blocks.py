"""TI Digital Motor Control blocks in IQ24, as the F2812 firmware uses them (docs/foc.md).

Generation: DMC library v3.20 C functions (the F281x reference project PMSM3_1's blocks), plus
the v4.3 clamping PI as an option. Equations only; every product is `_IQmpy` (floor, wrap),
every sum a 32-bit `long` (wraps). Each block is a small object with the TI field names in
snake case and a `calc()` that does what the TI function does.
"""

from __future__ import annotations

from hilbench.targets.foc.iqmath import (
    ONE,
    cos_pu,
    cos_pu_q15,
    iq,
    iq21_to_iq,
    iq_mpy,
    iq_sat,
    iq_to_iq21,
    iqn,
    sin_pu,
    sin_pu_q15,
    wrap32,
)

__all__ = [
    "INV_SQRT3", "TWO", "clarke", "sin_cos", "park", "ipark", "PidReg3", "PiClamp", "SpeedFr", "Qep",
]

INV_SQRT3 = iq(0.57735026918963)  # _IQ(1/sqrt(3)) = 9 686 330
TWO = iq(2.0)


def clarke(a_s: int, b_s: int) -> tuple[int, int]:
    """CLARKE v3.20: Alpha = As; Beta = _IQmpy(As + _IQmpy(_IQ(2), Bs), _IQ(1/√3)) (ic implied)."""
    return a_s, iq_mpy(wrap32(a_s + iq_mpy(TWO, b_s)), INV_SQRT3)


def sin_cos(angle: int) -> tuple[int, int]:
    """(_IQsinPU(angle), _IQcosPU(angle)); a Q15 angle shifted to Q24 reads the table."""
    if angle & 0x1FF == 0:
        k = (angle >> 9) & 0x7FFF
        return sin_pu_q15(k), cos_pu_q15(k)
    return sin_pu(angle), cos_pu(angle)


def park(alpha: int, beta: int, sine: int, cosine: int) -> tuple[int, int]:
    """PARK v3.20: Ds = α·cos + β·sin, Qs = β·cos − α·sin."""
    return (wrap32(iq_mpy(alpha, cosine) + iq_mpy(beta, sine)),
            wrap32(iq_mpy(beta, cosine) - iq_mpy(alpha, sine)))


def ipark(ds: int, qs: int, sine: int, cosine: int) -> tuple[int, int]:
    """IPARK v3.20: α = Ds·cos − Qs·sin, β = Qs·cos + Ds·sin."""
    return (wrap32(iq_mpy(ds, cosine) - iq_mpy(qs, sine)),
            wrap32(iq_mpy(qs, cosine) + iq_mpy(ds, sine)))


class PidReg3:
    """PID_REG3 v3.20: PID with back-calculation anti-windup (Kc feeds back last call's SatErr).

        Err = Ref − Fdb; Up = Kp·Err; Ui += Ki·Up + Kc·SatErr; Ud = Kd·(Up − Up1)
        OutPreSat = Up + Ui + Ud; Out = sat(OutPreSat); SatErr = Out − OutPreSat; Up1 = Up

    Ki multiplies Up, so the integral gain per call is Kp·Ki (Ki = Kp-independent T/Ti)."""

    __slots__ = ("ref", "fdb", "err", "kp", "up", "ui", "ud", "out_presat", "out_max", "out_min",
                 "out", "sat_err", "ki", "kc", "kd", "up1")

    def __init__(self, kp: int, ki: int, kc: int, out_max: int, out_min: int, kd: int = 0) -> None:
        self.kp, self.ki, self.kc, self.kd = kp, ki, kc, kd
        self.out_max, self.out_min = out_max, out_min
        self.reset()

    def reset(self) -> None:
        self.ref = self.fdb = self.err = self.up = self.ui = self.ud = 0
        self.out_presat = self.out = self.sat_err = self.up1 = 0

    def calc(self) -> int:
        err = wrap32(self.ref - self.fdb)
        up = iq_mpy(self.kp, err)
        ui = wrap32(self.ui + iq_mpy(self.ki, up) + iq_mpy(self.kc, self.sat_err))
        ud = iq_mpy(self.kd, wrap32(up - self.up1)) if self.kd else 0
        pre = wrap32(up + ui + ud)
        out = self.out_max if pre > self.out_max else self.out_min if pre < self.out_min else pre
        self.err, self.up, self.ui, self.ud, self.out_presat, self.out = err, up, ui, ud, pre, out
        self.sat_err = wrap32(out - pre)
        self.up1 = up
        return out


class PiClamp:
    """PI v4.3 (math_blocks PI_MACRO): series PI with clamping anti-windup.

        up = Kp·(Ref − Fbk); ui = (Out == v1) ? Ki·up + i1 : i1; i1 = ui; v1 = up + ui; Out = sat(v1)

    The integrator holds for the call after one whose output saturated. Kc is not used."""

    __slots__ = ("ref", "fdb", "kp", "ki", "kc", "kd", "up", "ui", "i1", "v1", "out", "out_max", "out_min")

    def __init__(self, kp: int, ki: int, kc: int, out_max: int, out_min: int, kd: int = 0) -> None:
        self.kp, self.ki, self.kc, self.kd = kp, ki, kc, kd
        self.out_max, self.out_min = out_max, out_min
        self.reset()

    def reset(self) -> None:
        self.ref = self.fdb = self.up = self.ui = self.i1 = self.v1 = self.out = 0

    def calc(self) -> int:
        up = iq_mpy(self.kp, wrap32(self.ref - self.fdb))
        ui = wrap32(iq_mpy(self.ki, up) + self.i1) if self.out == self.v1 else self.i1
        self.i1 = ui
        v1 = wrap32(up + ui)
        out = self.out_max if v1 > self.out_max else self.out_min if v1 < self.out_min else v1
        self.up, self.ui, self.v1, self.out = up, ui, v1, out
        return out


class SpeedFr:
    """SPEED_FR v3.20: speed from the electrical angle's difference, 1st-order low-pass.

        if 0.1 < θ < 0.9: Tmp = K1·(θ − θ_old)   (Q21 = Q21·Q24)   else Tmp = Speed (Q21)
        Tmp = K2·Speed + K3·Tmp; Speed = sat(Tmp, ±1) (Q21 → Q24); θ_old = θ; rpm = BaseRpm·Speed

    K1 = _IQ21(1/(f_base·T)), K2 = _IQ(1/(1 + T·2π·f_c)), K3 = _IQ(1) − K2 (PMSM3_1's formulas).

    `unwrap=True` is the math_blocks v4.3 SPEED_FR_MACRO instead: every sample is used, the
    difference unwrapped by ±1 turn when it exceeds ±0.5 (no hold near the wrap)."""

    __slots__ = ("elec_theta", "old_elec_theta", "speed", "speed_rpm", "k1", "k2", "k3", "base_rpm", "unwrap")

    def __init__(self, base_freq_hz: float, isr_period_s: float, cutoff_hz: float, base_rpm: int,
                 unwrap: bool = False) -> None:
        import math

        self.k1 = iqn(1.0 / (base_freq_hz * isr_period_s), 21)
        self.k2 = iq(1.0 / (1.0 + isr_period_s * 2.0 * math.pi * cutoff_hz))
        self.k3 = ONE - self.k2
        self.base_rpm = base_rpm
        self.unwrap = unwrap
        self.elec_theta = self.old_elec_theta = self.speed = self.speed_rpm = 0

    def calc(self) -> int:
        theta = self.elec_theta
        if self.unwrap:  # v4.3
            d = wrap32(theta - self.old_elec_theta)
            if d < -(ONE >> 1):
                d = wrap32(d + ONE)
            elif d > ONE >> 1:
                d = wrap32(d - ONE)
            tmp = iq_mpy(self.k1, d)
        elif 1677721 < theta < 15099494:  # _IQ(0.1) < θ < _IQ(0.9)
            tmp = iq_mpy(self.k1, wrap32(theta - self.old_elec_theta))
        else:
            tmp = iq_to_iq21(self.speed)
        tmp = wrap32(iq_mpy(self.k2, iq_to_iq21(self.speed)) + iq_mpy(self.k3, tmp))
        tmp = iq_sat(tmp, 1 << 21, -(1 << 21))
        self.speed = iq21_to_iq(tmp)
        self.old_elec_theta = theta
        self.speed_rpm = iq_mpy(self.base_rpm, self.speed)  # BaseRpm (Q0) · Speed (Q24) → Q0
        return self.speed


class Qep:
    """The F281x EV QEP circuit with GP timer 2, and the F281XQEP driver's angle calculation.

    Timer 2 in directional up/down mode counts 0 … T2PR *inclusive* (T2PR + 1 states), so with
    the driver's T2PR = 4·LineEncoder one revolution of 4·lines counts leaves T2CNT one count
    short of where it started: without the index reset the angle drifts one count per turn.

        RawTheta  = (Uint16)(T2CNT + CalibratedAngle)        (a negative sum wraps at 65 536)
        MechTheta = (MechScaler·RawTheta) >> 15 & 0x7FFF     (MechScaler = _IQ30(0.25/lines), Q15)
        ElecTheta = PolePairs·MechTheta & 0x7FFF             (Q15)
    Index (CAP3) ISR: QepCountIndex = T2CNT; T2CNT = 0; IndexSyncFlag = 0x00F0.

    RawTheta is a Uint16 passed to `__qmpy32by16(long, int, q)`, whose 16-bit operand is
    declared `int`. Read as unsigned (default, `signed16=False`), a negative T2CNT + Cal wraps at
    65 536, which is not a multiple of 4·lines: the angle is off by 65 536 mod 4·lines counts
    (5 536 for 2500 lines) while the sum is negative. Read as signed (`signed16=True`), the same
    sum stays negative and `& 0x7FFF` wraps it correctly. Which one the C28x does is unverified
    (facts §3a); the firmware avoids the question by keeping Cal in 0..T2PR.
    """

    __slots__ = ("line_encoder", "pole_pairs", "calibrated_angle", "mech_scaler", "t2pr", "t2cnt",
                 "direction", "raw_theta", "mech_theta", "elec_theta", "qep_count_index", "index_sync_flag", "signed16")

    def __init__(self, line_encoder: int, pole_pairs: int, calibrated_angle: int = 0, t2pr: int | None = None,
                 signed16: bool = False) -> None:
        self.signed16 = signed16
        self.line_encoder = line_encoder
        self.pole_pairs = pole_pairs
        self.calibrated_angle = calibrated_angle
        self.mech_scaler = iqn(0.25 / line_encoder, 30)
        self.t2pr = 4 * line_encoder if t2pr is None else t2pr
        self.t2cnt = 0
        self.direction = 1
        self.raw_theta = self.mech_theta = self.elec_theta = 0
        self.qep_count_index = 0
        self.index_sync_flag = 0

    def count(self, delta: int) -> None:
        """The QEP clock: `delta` quadrature edges (+ up, − down); 0..T2PR inclusive, wraps both ways."""
        if delta:
            self.t2cnt = (self.t2cnt + delta) % (self.t2pr + 1)
            self.direction = 1 if delta > 0 else 0

    def index(self) -> None:
        """CAP3/QEPI ISR of the driver."""
        self.qep_count_index = self.t2cnt
        self.t2cnt = 0
        self.index_sync_flag = 0x00F0

    def calc(self) -> int:
        """F281XQEP calc: the angles from T2CNT; returns ElecTheta (Q15)."""
        raw = (self.t2cnt + self.calibrated_angle) & 0xFFFF
        src16 = raw - 0x10000 if self.signed16 and raw & 0x8000 else raw
        mech = ((self.mech_scaler * (src16 << 16)) >> 31) & 0x7FFF  # __qmpy32by16(.., .., 31)
        self.raw_theta = raw
        self.mech_theta = mech
        self.elec_theta = (self.pole_pairs * mech) & 0x7FFF
        return self.elec_theta
