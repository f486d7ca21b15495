"""The F2812 sensored-FOC firmware of the F2812 FOC paper as a deterministic step function in IQ24.

One `isr()` is the timer-1 underflow interrupt, once per 10 kHz PWM period, in the order of
TI's PMSM3_1 level 5 (docs/foc.md):

    ADC → CLARKE → PARK (angle of the previous ISR) → speed PI every `speed_loop_prescaler`
    ISRs → i_q and i_d PI → IPARK → the paper's SVPWM → CMPR1..3 (shadow) → QEP angle, SPEED_FR

Compare values written here are loaded by the Event Manager at the next period match (COMCONA
reload on underflow or period), half a PWM period later: `compare_active` is what the pins
follow, `compare_shadow` what the ISR wrote; `period_match()` and `underflow()` do the reloads.

Start-up (as PMSM3_1 does, sized for this motor): a vector on the phase-A axis (PMSM3_1's
angle −0.25 pu; its size from the current loops, 1 A, or a fixed voltage) pulls the rotor's d
axis to θe = 0 for `align_s`; then T2CNT is set to 0 (the aligned angle),
the controllers are reset and the loops close. Per-unit bases: current `base_current_a` (the
sensor's ± full scale), voltage Udc/√3 (SVPWM's linear limit; no bus compensation, as in TI's
projects), speed `base_rpm` (SPEED_FR's BaseRpm = 120·BASE_FREQ/POLES = 3000 rpm).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from hilbench.errors import ConfigError
from hilbench.targets.foc.blocks import PiClamp, PidReg3, Qep, SpeedFr, clarke, ipark, park, sin_cos
from hilbench.targets.foc.iqmath import ONE, iq, iq15_to_iq, iq_to_iq15
from hilbench.targets.foc.svpwm import T1PR, svpwm

__all__ = ["FocOptions", "FocFirmware", "firmware_config", "q15_word", "STATE_STOPPED", "STATE_ALIGN", "STATE_RUN", "STATE_FAULT",
           "FAULT_NONE", "FAULT_WATCHDOG", "ISR_PERIOD_S", "HALF_PERIOD_US"]

ISR_PERIOD_S = 1e-4  # 10 kHz, one ISR per PWM period (the paper)
HALF_PERIOD_US = 50  # one up- or down-count of timer 1
STATE_STOPPED, STATE_ALIGN, STATE_RUN, STATE_FAULT = 0, 1, 2, 4  # protocol State: ALIGN is BOOTSTRAP
FAULT_NONE, FAULT_WATCHDOG = 0, 1


@dataclass(frozen=True)
class FocOptions:
    """Build-time settings of the firmware (the [target] table). Gains are per unit, floats,
    converted with `_IQ()` (truncating) as the C source's `_IQ(...)` constants would be.

    Default gains: tuned for the paper's 200 W servo (Rs 5.4 Ω, L 6.64 mH, J 3.8e-5 kg·m²,
    ψ 0.0834 Wb) with base current 5 A and base voltage 311 V/√3 = 179.6 V; derivation in
    docs/foc.md "Gains". The reference project's (Kp 0.75, alignment 0.18 pu) do not fit it."""

    pi_form: Literal["pid_reg3", "pi_clamp"] = "pid_reg3"
    line_encoder: int = 2500
    pole_pairs: int = 3
    base_rpm: int = 3000
    base_current_a: float = 5.0
    speed_loop_prescaler: int = 10
    speed_filter_hz: float = 30.0
    speed_fr: Literal["v3.20", "v4.3"] = "v3.20"  # v3.20 holds near the wrap; v4.3 unwraps every sample
    t2pr: int | None = None  # None: the driver's 4*LineEncoder
    calibrated_angle: int = 0  # T2CNT offset of the d axis; the aligned start makes it 0
    learn_index: bool = True  # first index pulse: fold T2CNT into CalibratedAngle (angle stays continuous)
    qep_signed16: bool = False  # read RawTheta as signed in __qmpy32by16 (facts §3a, unverified)
    align_s: float = 0.2
    align_v_pu: float = 0.03  # voltage alignment: 5.4 V at 311 V = 1.0 A in 5.4 ohm (PMSM3_1's 0.18 pu: 6 A)
    # > 0: the alignment vector's size comes from the current loops (i_q PI to this current in
    # PMSM3_1's alignment frame, angle -0.25 pu), so the 3.2 us dead band (10 V) cannot eat it
    align_current_a: float = 1.0
    # current loops: crossover 2000 rad/s, zero on the electrical pole R/L
    cur_kp: float = 0.37
    cur_ki: float = 0.0813
    cur_kc: float = 0.2
    id_out_max: float = 0.3
    iq_out_max: float = 0.95
    # speed loop (1 kHz): Kp*Km = 110 rad/s (Km = 157 /s) under the 30 Hz speed filter's 188 rad/s pole,
    # integral zero at Ki/T = 10 rad/s; a type-2 loop overshoots a step, so the setpoint is slewed
    spd_kp: float = 0.7
    spd_ki: float = 0.01
    spd_kc: float = 0.2
    spd_out_max: float = 0.5  # i_q reference limit: 2.5 A peak
    # speed setpoint slew limit (rpm/s, 0 = none): the speed PI follows a ramp toward the
    # reference, as TI's RMPCNTL block does; not in the paper (its Fig. 12 shows a smooth rise)
    speed_ramp_rpm_per_s: float = 2500.0

    def check(self) -> list[tuple[str, str]]:
        """(key, reason) for every inconsistent setting (the config collects them)."""
        bad: list[tuple[str, str]] = []
        if self.speed_fr not in ("v3.20", "v4.3"):
            bad.append(("speed_fr", f"{self.speed_fr!r}: expected 'v3.20' or 'v4.3'"))
        if self.pi_form not in ("pid_reg3", "pi_clamp"):
            bad.append(("pi_form", f"{self.pi_form!r}: expected 'pid_reg3' or 'pi_clamp'"))
        for key in ("line_encoder", "pole_pairs", "base_rpm", "speed_loop_prescaler"):
            if getattr(self, key) <= 0:
                bad.append((key, "must be positive"))
        if not 0 <= self.align_current_a <= 2 * self.base_current_a:
            bad.append(("align_current_a", f"{self.align_current_a}: out of range 0..2 x base_current_a"))
        if not 0 <= self.align_v_pu <= 0.5:
            bad.append(("align_v_pu", f"{self.align_v_pu}: out of range 0..0.5"))
        if self.align_s < 0 or self.speed_ramp_rpm_per_s < 0 or self.base_current_a <= 0 or self.speed_filter_hz <= 0:
            bad.append(("align_s", "align_s, speed_ramp_rpm_per_s >= 0; base_current_a, speed_filter_hz > 0"))
        if self.base_rpm > 0 and self.pole_pairs > 0 and self.base_freq_hz * ISR_PERIOD_S <= 1 / 1024:
            # SPEED_FR's K1 = _IQ21(1/(BASE_FREQ*T)) must fit a 32-bit long (1024 in Q21)
            bad.append(("base_rpm", f"{self.base_rpm}: base_rpm x pole_pairs must exceed 586 (SPEED_FR's K1 in Q21)"))
        for key in ("cur_kp", "cur_ki", "cur_kc", "spd_kp", "spd_ki", "spd_kc"):
            if not 0 <= getattr(self, key) < 8:
                bad.append((key, f"{getattr(self, key)}: out of range 0..8"))
        for key in ("id_out_max", "iq_out_max", "spd_out_max"):
            if not 0 <= getattr(self, key) <= 1:
                bad.append((key, f"{getattr(self, key)}: out of range 0..1"))
        return bad

    @property
    def base_freq_hz(self) -> float:
        """BASE_FREQ: electrical frequency at base speed (150 Hz for 3000 rpm, 3 pole pairs)."""
        return self.base_rpm * self.pole_pairs / 60.0


def adc_to_iq(code12: int) -> int:
    """A 12-bit bipolar ADC result as the driver reads it: ADCRESULT holds code << 4; XOR 0x8000
    makes it a signed Q15 (mid-scale 2048 = 0), shifted to Q24: (code − 2048)/2048 pu."""
    q15 = ((code12 << 4) ^ 0x8000) & 0xFFFF
    if q15 & 0x8000:
        q15 -= 0x10000
    return iq15_to_iq(q15)


class FocFirmware:
    """State and ISR of the F2812 FOC firmware; plain ints, time in half PWM periods."""

    def __init__(self, options: FocOptions = FocOptions()) -> None:
        bad = options.check()
        if bad:
            raise ConfigError(f"foc option {bad[0][0]}: {bad[0][1]}")
        self.options = o = options
        pi = PidReg3 if o.pi_form == "pid_reg3" else PiClamp
        self.pid_id = pi(iq(o.cur_kp), iq(o.cur_ki), iq(o.cur_kc), iq(o.id_out_max), -iq(o.id_out_max))
        self.pid_iq = pi(iq(o.cur_kp), iq(o.cur_ki), iq(o.cur_kc), iq(o.iq_out_max), -iq(o.iq_out_max))
        self.pid_spd = pi(iq(o.spd_kp), iq(o.spd_ki), iq(o.spd_kc), iq(o.spd_out_max), -iq(o.spd_out_max))
        self.qep = Qep(o.line_encoder, o.pole_pairs, o.calibrated_angle, o.t2pr, o.qep_signed16)
        self.speed = SpeedFr(o.base_freq_hz, ISR_PERIOD_S, o.speed_filter_hz, o.base_rpm, unwrap=o.speed_fr == "v4.3")
        self.align_isrs = round(o.align_s / ISR_PERIOD_S)
        self.align_v = iq(o.align_v_pu)
        self.align_i = iq(o.align_current_a / o.base_current_a) if o.align_current_a > 0 else 0
        self.speed_ref = 0  # IQ24 pu of base_rpm: the reference as set
        self.speed_setpoint = 0  # what the speed PI follows (the reference through the slew limit)
        t_spd = ISR_PERIOD_S * o.speed_loop_prescaler
        self.ramp_step = iq(o.speed_ramp_rpm_per_s / o.base_rpm * t_spd) if o.speed_ramp_rpm_per_s > 0 else 0
        self.id_ref = 0
        self.iq_ref = 0
        self.torque_mode = False  # current-loop test: i_q reference from iq_ref_set, no speed loop
        self.iq_ref_set = 0
        self.state = STATE_STOPPED
        self.fault = FAULT_NONE
        self.isr_count = 0
        self.state_isrs = 0
        self.speed_loop_count = 0
        self.index_learned = False
        self.elec_theta = 0  # speed1.ElecTheta: IQ24, from the previous ISR's QEP read
        self.i_a = self.i_b = self.i_alpha = self.i_beta = self.i_d = self.i_q = 0
        self.v_d = self.v_q = self.v_alpha = self.v_beta = 0
        self.vdc_code = 0
        self.sector = 0
        self.compare_shadow = (T1PR, T1PR, T1PR)
        self.compare_active = (T1PR, T1PR, T1PR)
        self.outputs_on = False  # ACTRA/COMCONA full-compare outputs enabled
        self._enc_last: int | None = None

    # ---- host-side commands ---------------------------------------------------------------
    def set_speed_ref_rpm(self, rpm: int) -> None:
        """The speed reference parameter: `_IQ(rpm/BaseRpm)`, truncating, within ±1."""
        self.speed_ref = rpm_to_iq(rpm, self.options.base_rpm)

    def start(self) -> None:
        """Stopped → rotor alignment (outputs on), then closed loop."""
        if self.state in (STATE_STOPPED, STATE_FAULT):
            self.fault = FAULT_NONE
            self._enter(STATE_ALIGN)
            self.outputs_on = True

    def stop(self, state: int = STATE_STOPPED, fault: int = FAULT_NONE) -> None:
        """All six switches off (outputs disabled); the motor coasts."""
        self.state = state
        self.fault = fault
        self.outputs_on = False
        self.compare_shadow = self.compare_active = (T1PR, T1PR, T1PR)
        self.v_d = self.v_q = 0
        self.sector = 0

    def _enter(self, state: int) -> None:
        self.state = state
        self.state_isrs = 0
        for pid in (self.pid_id, self.pid_iq, self.pid_spd):
            pid.reset()
        self.iq_ref = 0
        self.speed_loop_count = 0
        self.speed_setpoint = 0

    def gain(self, loop: str, field: str) -> int:
        """A controller setting: loop "spd", "id" or "iq"; field "kp", "ki", "kc" or "out_max"."""
        return getattr(self._loop(loop), field)

    def set_gain(self, loop: str, field: str, value: int) -> None:
        """Write a controller setting; out_max also sets out_min = −out_max."""
        pi = self._loop(loop)
        setattr(pi, field, int(value))
        if field == "out_max":
            pi.out_min = -int(value)

    def _loop(self, loop: str) -> PidReg3 | PiClamp:
        return {"spd": self.pid_spd, "id": self.pid_id, "iq": self.pid_iq}[loop]

    # ---- the Event Manager -------------------------------------------------------------------
    def encoder(self, count16: int, index: bool) -> None:
        """The QEP circuit between two samples: T2 follows the encoder's edges, CAP3 the index."""
        last = self._enc_last
        self._enc_last = count16
        if last is not None:
            delta = ((count16 - last + 0x8000) & 0xFFFF) - 0x8000
            if delta:
                self.qep.count(delta)
        if index:
            self.index_isr()

    def index_isr(self) -> None:
        """CAP3 (QEPI) interrupt: the driver's T2CNT reset; the first one calibrates the angle."""
        qep = self.qep
        if self.options.learn_index and not self.index_learned:
            # keep RawTheta continuous: Cal = T2CNT + Cal, kept in 0..4*lines-1 (never negative)
            qep.calibrated_angle = (qep.t2cnt + qep.calibrated_angle) % (4 * qep.line_encoder)
            self.index_learned = True
        qep.index()

    def period_match(self) -> None:
        """T1CNT = T1PR: the shadow compare values are loaded."""
        self.compare_active = self.compare_shadow

    def underflow(self, adc_ia: int, adc_ib: int, adc_vdc: int) -> None:
        """T1CNT = 0: reload (shadow → active), start of conversion, then the ISR."""
        self.compare_active = self.compare_shadow
        self.isr(adc_ia, adc_ib, adc_vdc)

    # ---- the T1 underflow ISR ---------------------------------------------------------------
    def isr(self, adc_ia: int, adc_ib: int, adc_vdc: int) -> None:
        self.isr_count += 1
        self.vdc_code = adc_vdc
        ia = self.i_a = adc_to_iq(adc_ia)
        ib = self.i_b = adc_to_iq(adc_ib)
        alpha, beta = clarke(ia, ib)
        self.i_alpha, self.i_beta = alpha, beta
        state = self.state
        angle = self.elec_theta
        if state == STATE_ALIGN:
            angle = -(ONE >> 2) & (ONE - 1)  # −0.25 pu: Vq along −90° puts the vector on phase A
        sine, cosine = sin_cos(angle)
        i_d, i_q = park(alpha, beta, sine, cosine)
        self.i_d, self.i_q = i_d, i_q
        if state == STATE_RUN:
            self.speed_loop_count += 1
            if self.torque_mode:
                self.iq_ref = self.iq_ref_set
                self.speed_loop_count = 0
            elif self.speed_loop_count >= self.options.speed_loop_prescaler:
                self.speed_loop_count = 0
                spd = self.pid_spd
                ref = self.speed_ref
                step = self.ramp_step
                if step:
                    sp = self.speed_setpoint
                    ref = sp + step if ref > sp + step else sp - step if ref < sp - step else ref
                self.speed_setpoint = ref
                spd.ref = ref
                spd.fdb = self.speed.speed
                self.iq_ref = spd.calc()
            piq = self.pid_iq
            piq.ref = self.iq_ref
            piq.fdb = i_q
            v_q = piq.calc()
            pid = self.pid_id
            pid.ref = self.id_ref
            pid.fdb = i_d
            v_d = pid.calc()
        elif state == STATE_ALIGN:
            if self.align_i:
                piq = self.pid_iq
                piq.ref = self.align_i
                piq.fdb = i_q
                v_q = piq.calc()
                pid = self.pid_id
                pid.ref = 0
                pid.fdb = i_d
                v_d = pid.calc()
            else:
                v_d, v_q = 0, self.align_v
            self.state_isrs += 1
            if self.state_isrs >= self.align_isrs:
                self.qep.t2cnt = 0  # the rotor's d axis is at θe = 0 now
                self._enter(STATE_RUN)
        else:
            v_d = v_q = 0
        self.v_d, self.v_q = v_d, v_q
        if self.outputs_on:
            v_alpha, v_beta = ipark(v_d, v_q, sine, cosine)
            self.v_alpha, self.v_beta = v_alpha, v_beta
            n, c1, c2, c3 = svpwm(v_alpha, v_beta)
            self.sector = n
            self.compare_shadow = (c1, c2, c3)
        # QEP and speed: every ISR, outputs on or off
        theta_q15 = self.qep.calc()
        self.elec_theta = iq15_to_iq(theta_q15)
        sp = self.speed
        sp.elec_theta = self.elec_theta
        sp.calc()

    # ---- read-outs ------------------------------------------------------------------------------
    def telemetry_q15(self) -> dict[str, int]:
        """The values the target reports, as Q15 per unit (IQ24 >> 9) saturated to the wire's
        16 bits (+1.0 pu, e.g. a 3000 rpm reference, reads 32767)."""
        return {
            "ref_speed": q15_word(self.speed_setpoint if self.ramp_step else self.speed_ref),
            "speed": q15_word(self.speed.speed), "i_d": q15_word(self.i_d), "i_q": q15_word(self.i_q),
            "id_ref": q15_word(self.id_ref), "iq_ref": q15_word(self.iq_ref),
            "theta_e": q15_word(self.elec_theta), "v_d": q15_word(self.v_d), "v_q": q15_word(self.v_q),
        }


def q15_word(value: int) -> int:
    """An IQ24 value as a telemetry word: `_IQtoIQ15`, saturated to a signed 16-bit value."""
    return max(-32768, min(32767, iq_to_iq15(value)))


def firmware_config(options: FocOptions) -> dict[str, int]:
    """The firmware's build settings as the integers the chip holds (firmware/foc/foc.h
    `foc_config_t`, by field name): what the C core is built from, in process or with -D."""
    fw = FocFirmware(options)
    q, sp = fw.qep, fw.speed
    return {
        "pi_form": int(options.pi_form == "pi_clamp"), "speed_fr_unwrap": int(sp.unwrap),
        "learn_index": int(options.learn_index), "qep_signed16": int(q.signed16),
        "line_encoder": q.line_encoder, "pole_pairs": q.pole_pairs, "t2pr": q.t2pr,
        "calibrated_angle": q.calibrated_angle, "mech_scaler": q.mech_scaler,
        "sp_k1": sp.k1, "sp_k2": sp.k2, "sp_k3": sp.k3, "base_rpm": sp.base_rpm,
        "speed_loop_prescaler": options.speed_loop_prescaler, "align_isrs": fw.align_isrs,
        "align_v": fw.align_v, "align_i": fw.align_i, "ramp_step": fw.ramp_step,
        "cur_kp": fw.pid_iq.kp, "cur_ki": fw.pid_iq.ki, "cur_kc": fw.pid_iq.kc,
        "id_out_max": fw.pid_id.out_max, "iq_out_max": fw.pid_iq.out_max,
        "spd_kp": fw.pid_spd.kp, "spd_ki": fw.pid_spd.ki, "spd_kc": fw.pid_spd.kc,
        "spd_out_max": fw.pid_spd.out_max,
    }


def rpm_to_iq(rpm: float, base_rpm: int) -> int:
    """The firmware's `_IQ(rpm/BaseRpm)` (truncating)."""
    return iq(max(-1.0, min(1.0, rpm / base_rpm)))


def iq_to_rpm(value: int, base_rpm: int) -> float:
    return value * base_rpm / ONE

