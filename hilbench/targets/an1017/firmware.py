"""The AN1017 sinusoidal-drive firmware (dsPIC30F2010) as a deterministic step function.

Virtual time is counted in Tcy = 50 ns (FCY = 20 MHz). Interrupts run at their own times inside
each span: the PWM ISR at every PWM period boundary (1000 Tcy), the ADC ISR at the PWM rate
(the application note) or every 16th period (v1.1), Timer1 every (PR1+1)·64 = 20096 Tcy after RunMotor, the hall
ISRs (CN5 = A, IC7 = B, IC8 = C) at the edge time the host reports. Simultaneous interrupts run in
the dsPIC's natural order (T1, ADC, CN, IC7, IC8, PWM). Duty registers written by the PWM ISR take
effect at the next period boundary (PWMCON2.IUE = 0).

This is the readable reference: every ISR runs as the firmware runs it, every PWM ISR with the
full SVM, nothing collapsed or cached. The one accelerator is the compiled core (the "c" backend
of hilbench.targets.an1017.target); tests/test_an1017_core.py requires its Drives to equal this
model's at every period over seeded random streams.

Where the AN1017 application note (Chinese edition) and the v1.1 firmware source differ
(An1017Options: default variant "appnote" = the note, "v11" = the source):
- ADC ISR rate. The note: "将 A/D 转换器配置为中断触发模式且中断频率为 PWM 速率（本应用中为 20 kHz）"
  and Table 4 "A/D 20 kHz" → every PWM period. v1.1: PWMCON2 SEVOPS 1:16 → every 16th period.
- PID C1. The note's Table 7: "PIDCoefficients[1] = -Kp - 2Kd". v1.1 RunMotor: -(Ki + 2*Kd).
- Phase advance. The note: "该算法可通过在 SinusoidalBLDC v1.1.c 文件中定义 PHASE_ADVANCE 来使能。
  在本应用笔记中该功能被禁止。" (disabled in this note) → off. v1.1 #defines PHASE_ADVANCE → on.
- Stall timeout. The note only says Timer1 "提供电机堵转保护" (Table 4) without a figure; the
  firmware's own Timer1 header says "(i.e. 100 ms)" and the 33F port uses _100MILLISEC, so the
  default is 100 ms (stop at the 101st tick without a hall edge, since 100 % 10 == 0 force-
  commutates). v1.1 uses _1000MILLISEC → stop at tick 1001.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Sequence

from hilbench.errors import ConfigError
from hilbench.targets.an1017.fixedpoint import divf, float_to_q15, sat16, wrap16
from hilbench.targets.an1017.svm import PTPER, svm

# ---- time base -------------------------------------------------------------------------------
FCY_HZ = 20_000_000
TCY_PER_US = 20
PWM_PERIOD_TCY = 1000  # 2·(PTPER+1) Tcy: 20 kHz centre-aligned
TIMER1_PERIOD_TCY = (313 + 1) * 64  # PR1 = 313 at Tcy/64 → 20096 Tcy = 1.0048 ms
TMR3_PRESCALE = 64  # TMR3 at Tcy/64 = 3.2 µs
BOOTSTRAP_TCY = 200_000  # ChargeBootstraps: 10 ms of low-side switches on
ADC_POSTSCALE_V11 = 16  # SEVOPS = 1111 → 1:16

# ---- firmware constants (facts §2, §3) -------------------------------------------------------
# The speed scale is a build constant of the motor: Period counts TMR3 ticks (Tcy/64 = 3.2 µs)
# between two hall-B edges (IC7 captures both), half an electrical revolution, so a motor with p
# pole pairs at n rpm gives Period = 60 s/(2·3.2 µs)/(p·n) = 9 375 000/(p·n). The note builds for
# 10 poles: "#define MINPERIOD 313 // For 6000 max rpm and 10 poles motor", MAXPERIOD 31250 for
# 60 rpm. MINPERIOD rounds up (the measured speed never exceeds the maximum); MAXPERIOD is kept
# within a signed 16-bit divisor (DIVF) for motors with more poles.
PERIOD_X_RPM_X_POLE_PAIRS = 9_375_000
POLE_PAIRS_DEFAULT = 5
MAX_SPEED_RPM_DEFAULT = 6000
MIN_SPEED_RPM = 60
MAXPERIOD_LIMIT = 32767


def build_periods(pole_pairs: int, max_speed_rpm: int) -> tuple[int, int]:
    """(MINPERIOD, MAXPERIOD) of a build for this motor: (313, 31250) for 5 pole pairs, 6000 rpm."""
    min_period = -(-PERIOD_X_RPM_X_POLE_PAIRS // (pole_pairs * max_speed_rpm))
    max_period = min(MAXPERIOD_LIMIT, PERIOD_X_RPM_X_POLE_PAIRS // (pole_pairs * MIN_SPEED_RPM))
    return min_period, max_period


def rpm_per_speed_q15(pole_pairs: int, max_speed_rpm: int) -> float:
    """One Q15 step of MeasuredSpeed = DIVF(MINPERIOD − 1, Period) in rpm (Table 6 for the note's build)."""
    min_period, _ = build_periods(pole_pairs, max_speed_rpm)
    return PERIOD_X_RPM_X_POLE_PAIRS / (pole_pairs * (min_period - 1) * 32768)


MINPERIOD, MAXPERIOD = build_periods(POLE_PAIRS_DEFAULT, MAX_SPEED_RPM_DEFAULT)  # 313, 31250
MINPERIOD_DIVF = MINPERIOD - 1  # _MINPERIOD = 312, so divf's |num| < |den| always holds
PHASE_VALUES = (57344, 2730, 13652, 24574, 35496, 46418)
PHASE_OFFSET_CCW = 4100
SECTOR_TABLE = (-1, 4, 2, 3, 0, 5, 1, -1)  # indexed by hall CBA; -1 = invalid
SECTOR_INVALID = 0xFFFF  # -1 stored in the firmware's `unsigned int Sector`
FORCE_COMMUTATION_TICKS = 10  # _10MILLISEC
PHASEINC_NUMERATOR = 512_000

KP_DEFAULT_Q15 = float_to_q15(0.1)  # 3277
KI_DEFAULT_Q15 = float_to_q15(0.01)  # 328
KD_DEFAULT_Q15 = float_to_q15(0.0)  # 0

# ---- states / modes (design.md constants) ----------------------------------------------------
STATE_STOPPED, STATE_BOOTSTRAP, STATE_RUNNING, STATE_STALLED, STATE_FAULT = 0, 1, 2, 3, 4
MODE_OFF, MODE_PWM, MODE_LOW_SIDE = 0, 1, 2
FAULT_NONE, FAULT_WATCHDOG, FAULT_STALL, FAULT_OVERCURRENT = 0, 1, 2, 3
INPUT_S2 = 0x08
INPUT_FAULT = 0x20  # the FLTA pin (the board's over-current comparator), as Sensors carries it

# ---- gain constraints (seed, PID section) ----------------------------------------------------
GAIN_LIMIT_Q15 = float_to_q15(0.9999)  # 32764
GAIN_CONSTRAINT_NAMES = {
    1: "Kp + Ki + Kd < 0.9999",
    2: "-Kp - 2*Kd > -1.0",
    3: "Kd < 0.9999",
}


def check_gain_constraints(kp_q15: int, ki_q15: int, kd_q15: int) -> int | None:
    """The application note's PID gain constraints; None when all hold, else the first broken one (1, 2, 3)."""
    if not kp_q15 + ki_q15 + kd_q15 < GAIN_LIMIT_Q15:
        return 1
    if not -kp_q15 - 2 * kd_q15 > -32768:
        return 2
    if not kd_q15 < GAIN_LIMIT_Q15:
        return 3
    return None


@dataclass(frozen=True)
class An1017Options:
    """Where the AN1017 application note and the v1.1 firmware source differ; defaults follow the
    application note's behaviour (variant "appnote"; "seed" is that variant's former name).

    `variant="v11"` switches every difference to the source's behaviour; the individual fields
    (None = take the variant's value) override single points.
    """

    variant: Literal["appnote", "v11", "seed"] = "appnote"
    adc_every_pwm_period: bool | None = None
    pid_c1_textbook: bool | None = None  # C1 = -Kp-2Kd (the note) vs -(Ki+2Kd) (v11)
    phase_advance: bool | None = None
    stall_timeout_ms: int | None = None
    phase_offset_ccw: int = PHASE_OFFSET_CCW
    max_phase_advance_deg: int = 40
    pole_pairs: int = POLE_PAIRS_DEFAULT  # the motor the firmware is built for (its speed scale)
    max_speed_rpm: int = MAX_SPEED_RPM_DEFAULT

    def __post_init__(self) -> None:
        if self.variant == "seed":  # the former name of the application note's behaviour
            object.__setattr__(self, "variant", "appnote")
        if self.variant not in ("appnote", "v11"):
            raise ConfigError(f"an1017 options variant: {self.variant!r} is not 'appnote' (the application note's "
                              f"behaviour) or 'v11' (the v1.1 firmware source's)")
        if not 1 <= self.pole_pairs <= 32:
            raise ConfigError(f"an1017 options pole_pairs: {self.pole_pairs} not in 1..32")
        if not 100 <= self.max_speed_rpm <= 60000:
            raise ConfigError(f"an1017 options max_speed_rpm: {self.max_speed_rpm} not in 100..60000")
        lo, hi = build_periods(self.pole_pairs, self.max_speed_rpm)
        if not 2 <= lo < hi:
            raise ConfigError(f"an1017 options: MINPERIOD {lo} for {self.pole_pairs} pole pairs at "
                              f"{self.max_speed_rpm} rpm is not within 2..{hi - 1}")
        if self.stall_timeout_ms is not None and not 10 <= self.stall_timeout_ms <= 30000:
            raise ConfigError(f"an1017 options stall_timeout_ms: {self.stall_timeout_ms} not in 10..30000")
        if not 0 <= self.max_phase_advance_deg <= 60:
            raise ConfigError(f"an1017 options max_phase_advance_deg: {self.max_phase_advance_deg} not in 0..60")
        if not -32768 <= self.phase_offset_ccw <= 32767:  # a 16-bit word on the chip
            raise ConfigError(f"an1017 options phase_offset_ccw: {self.phase_offset_ccw} not in -32768..32767")

    def resolved(self) -> "An1017Options":
        """All None fields replaced by the variant's value."""
        v11 = self.variant == "v11"
        return An1017Options(
            variant=self.variant,
            adc_every_pwm_period=(not v11) if self.adc_every_pwm_period is None else self.adc_every_pwm_period,
            pid_c1_textbook=(not v11) if self.pid_c1_textbook is None else self.pid_c1_textbook,
            phase_advance=v11 if self.phase_advance is None else self.phase_advance,
            stall_timeout_ms=(1000 if v11 else 100) if self.stall_timeout_ms is None else self.stall_timeout_ms,
            phase_offset_ccw=self.phase_offset_ccw,
            max_phase_advance_deg=self.max_phase_advance_deg,
            pole_pairs=self.pole_pairs,
            max_speed_rpm=self.max_speed_rpm,
        )


def max_phase_advance_from_deg(deg: int) -> int:
    """MAX_PH_ADV = (int)(deg/360·65536) in 16-bit angle units (40° → 7281)."""
    return int(deg / 360.0 * 65536.0)


def phase_for_sector(sector: int, required_ccw: bool, old_phase: int, offset: int) -> int:
    """The hall re-sync: PhaseValues[Sector] (CW) or PhaseValues[(Sector+3)%6] + PhaseOffset (CCW).

    With an invalid sector (0xFFFF) the CCW index wraps in 16-bit unsigned arithmetic to
    (0xFFFF+3) & 0xFFFF = 2; the CW read is out of bounds on the chip (PhaseValues[-1]), which
    cannot be reproduced, so Phase is left unchanged.
    """
    if required_ccw:
        idx = ((sector + 3) & 0xFFFF) % 6
        return (PHASE_VALUES[idx] + offset) & 0xFFFF
    if sector == SECTOR_INVALID:
        return old_phase
    return PHASE_VALUES[sector]


def speed_control(
    ref_speed: int, measured_speed: int, control_output: int, e1: int, e2: int, c0: int, c1: int, c2: int
) -> tuple[int, int]:
    """SpeedControl(): (ControlOutput, e0) after one update, exactly as the MAC sequence.

    e0 = SAC(SUB A) = sat16(Ref − Meas); A = LAC ControlOutput; three MACs with SATA (1.31
    saturation after each); ControlOutput = SAC A (bits 31:16, truncating).
    """
    e0 = sat16(ref_speed - measured_speed)
    acc = control_output << 16
    for e, c in ((e0, c0), (e1, c1), (e2, c2)):
        acc += (e * c) << 1
        if acc > 0x7FFFFFFF:
            acc = 0x7FFFFFFF
        elif acc < -0x80000000:
            acc = -0x80000000
    return sat16(acc >> 16), e0


class An1017Firmware:
    """Firmware state and its ISRs over virtual Tcy time. Plain ints in, plain ints out."""

    __slots__ = (
        "options",
        "_adc_every",
        "_c1_textbook",
        "phase_offset",
        "min_period",
        "max_period",
        "kp",
        "ki",
        "kd",
        "pending_gains",
        "phase_advance_on",
        "max_ph_adv_deg",
        "max_ph_adv",
        "ref_override_on",
        "ref_override",
        "stall_limit",
        "t",
        "t_frac_us",
        "hall",
        "pot_code",
        "t3_zero",
        "ic7_fifo",
        "output_mode",
        "pend_duty",
        "act_duty",
        "running",
        "booting",
        "boot_end",
        "state",
        "fault",
        "ref_speed",
        "measured_speed",
        "control_output",
        "e1",
        "e2",
        "c0",
        "c1",
        "c2",
        "phase",
        "phase_inc",
        "phase_adv",
        "sector",
        "last_sector",
        "stall_counter",
        "cur_ccw",
        "req_ccw",
        "period",
        "actual_capture",
        "past_capture",
        "t1_next",
        "s2_level",
        "s2_wait_release",
    )

    def __init__(self, options: An1017Options = An1017Options()) -> None:
        opts = options.resolved()
        self.options = opts
        self._adc_every = bool(opts.adc_every_pwm_period)
        self._c1_textbook = bool(opts.pid_c1_textbook)
        self.phase_offset = opts.phase_offset_ccw
        self.min_period, self.max_period = build_periods(opts.pole_pairs, opts.max_speed_rpm)
        # declared, tunable values
        self.kp = KP_DEFAULT_Q15
        self.ki = KI_DEFAULT_Q15
        self.kd = KD_DEFAULT_Q15
        self.pending_gains: tuple[int, int, int] | None = None
        self.phase_advance_on = bool(opts.phase_advance)
        self.max_ph_adv_deg = opts.max_phase_advance_deg
        self.max_ph_adv = max_phase_advance_from_deg(opts.max_phase_advance_deg)
        self.ref_override_on = False
        self.ref_override = 0
        self.stall_limit = int(opts.stall_timeout_ms or 100)
        # time
        self.t = 0  # Tcy since power-on
        self.t_frac_us = 0.0  # sub-Tcy remainder for advance()
        # peripherals
        self.hall = 0  # last applied hall bits (bit0 A, bit1 B, bit2 C)
        self.pot_code = 512
        self.t3_zero = 0  # time TMR3 was last cleared
        self.ic7_fifo: list[int] = []
        self.output_mode = MODE_OFF
        # duty registers PDC1..3: pending = written by the PWM ISR, active = latched at the last
        # period boundary (PWMCON2.IUE = 0)
        self.pend_duty = (PTPER, PTPER, PTPER)
        self.act_duty = (PTPER, PTPER, PTPER)
        # firmware variables
        self.running = False  # Flags.MotorRunning: T1/CN/IC7/IC8/PWM interrupts enabled
        self.booting = False
        self.boot_end = 0
        self.state = STATE_STOPPED
        self.fault = FAULT_NONE
        self.ref_speed = 0
        self.measured_speed = 0
        self.control_output = 0
        self.e1 = 0  # ControlDifference[1]
        self.e2 = 0  # ControlDifference[2]
        self.c0 = self.c1 = self.c2 = 0
        self.phase = 0
        self.phase_inc = 0
        self.phase_adv = 0
        self.sector = SECTOR_INVALID
        self.last_sector = SECTOR_INVALID
        self.stall_counter = 0
        self.cur_ccw = False
        self.req_ccw = False
        self.period = self.max_period
        self.actual_capture = 0
        self.past_capture = 0
        self.t1_next = 0
        self.s2_level = False
        self.s2_wait_release = False

    # ---- commands from the host --------------------------------------------------------------
    def press_start(self) -> None:
        """S2 while stopped: RunMotor() begins with ChargeBootstraps()."""
        if self.running or self.booting:
            return
        self.booting = True
        self.state = STATE_BOOTSTRAP
        self.fault = FAULT_NONE
        self.output_mode = MODE_LOW_SIDE  # OVDCON = 0x0015
        # the busy loop ends just after the 10 ms boundary; RunMotor's init runs then
        self.boot_end = self.t + BOOTSTRAP_TCY + 1

    def press_stop(self, state: int = STATE_STOPPED, fault: int = FAULT_NONE) -> None:
        """StopMotor(): OVDCON = 0 (all six switches off) and the motor interrupts disabled."""
        self.running = False
        self.booting = False
        self.output_mode = MODE_OFF
        self.state = state
        self.fault = fault

    def set_gains(self, kp: int, ki: int, kd: int) -> None:
        """New gains: applied now when stopped (RunMotor recomputes), else at the next Timer1 ISR."""
        if self.running:
            self.pending_gains = (kp, ki, kd)
        else:
            self.kp, self.ki, self.kd = kp, ki, kd
            self.pending_gains = None

    def declared_gains(self) -> tuple[int, int, int]:
        """Gains as last written by the host (pending ones included)."""
        return self.pending_gains if self.pending_gains is not None else (self.kp, self.ki, self.kd)

    # ---- internal firmware routines ----------------------------------------------------------
    def _coefficients(self) -> None:
        kp, ki, kd = self.kp, self.ki, self.kd
        self.c0 = wrap16(kp + ki + kd)
        self.c1 = wrap16(-kp - 2 * kd) if self._c1_textbook else wrap16(-(ki + 2 * kd))
        self.c2 = wrap16(kd)

    def _run_motor(self) -> None:
        """RunMotor() after ChargeBootstraps(): PDC = PTPER, OVDCON = 0x3F00, variables, interrupts."""
        self.booting = False
        self.output_mode = MODE_PWM
        self.pend_duty = self.act_duty = (PTPER, PTPER, PTPER)
        self.e1 = self.e2 = 0
        self._coefficients()
        now = self.boot_end
        self.t1_next = now + TIMER1_PERIOD_TCY  # TMR1 = 0
        self.t3_zero = now  # TMR3 = 0
        self.actual_capture = self.max_period
        self.past_capture = 0
        s = SECTOR_TABLE[self.hall]
        self.sector = self.last_sector = s & 0xFFFF
        self.control_output = 0
        ccw = self.ref_speed < 0
        self.cur_ccw = self.req_ccw = ccw
        self.phase = phase_for_sector(self.sector, ccw, self.phase, self.phase_offset)
        self.stall_counter = 0
        self.phase_inc = PHASEINC_NUMERATOR // self.max_period
        self.running = True
        self.state = STATE_RUNNING

    def _timer1(self) -> None:
        """Timer1 ISR: Period, PhaseInc, MeasuredSpeed, SpeedControl, PhaseAdvance, stall logic."""
        if self.pending_gains is not None:
            self.kp, self.ki, self.kd = self.pending_gains
            self.pending_gains = None
            self._coefficients()
        period = (self.actual_capture - self.past_capture) & 0xFFFF
        if period < self.min_period:
            period = self.min_period
        elif period > self.max_period:
            period = self.max_period
        self.period = period
        self.phase_inc = PHASEINC_NUMERATOR // period
        ms = divf(self.min_period - 1, period)  # DIVF(_MINPERIOD, Period), _MINPERIOD = MINPERIOD − 1
        if self.cur_ccw:
            ms = -ms
        self.measured_speed = ms
        co, e0 = speed_control(self.ref_speed, ms, self.control_output, self.e1, self.e2, self.c0, self.c1, self.c2)
        self.e2 = self.e1
        self.e1 = e0
        self.control_output = co
        self.req_ccw = co < 0
        # MPY MAX_PH_ADV*MeasuredSpeed, SAC A (truncating); without PHASE_ADVANCE the term is absent
        self.phase_adv = sat16((self.max_ph_adv * ms * 2) >> 16) if self.phase_advance_on else 0
        self.stall_counter += 1
        if self.stall_counter % FORCE_COMMUTATION_TICKS == 0:
            s = SECTOR_TABLE[self.hall]
            self.sector = s & 0xFFFF
            if s >= 0:
                self.phase = phase_for_sector(s, self.req_ccw, self.phase, self.phase_offset)
        elif self.stall_counter >= self.stall_limit:
            self.press_stop(STATE_STALLED, FAULT_STALL)

    def _hall_isr(self, which: int, t_edge: int) -> None:
        """CN5 (which=0, A), IC7 (1, B), IC8 (2, C): sector, direction, Phase re-sync."""
        s = SECTOR_TABLE[self.hall] & 0xFFFF
        self.sector = s
        if s == self.last_sector:
            return
        if which == 1:
            self.past_capture = self.actual_capture
            fifo = self.ic7_fifo
            if fifo:
                self.actual_capture = fifo.pop(0)
            del fifo[:3]  # three more reads of IC7BUF flush the FIFO
        self.stall_counter = 0
        if which == 0:
            self.cur_ccw = s == 5 or s == 2
        elif which == 1:
            self.cur_ccw = s == 3 or s == 0
        else:
            self.cur_ccw = s == 1 or s == 4
        self.phase = phase_for_sector(s, self.req_ccw, self.phase, self.phase_offset)
        self.last_sector = s

    def _apply_hall(self, new_bits: int, t_edge: int) -> None:
        """Hall inputs change at t_edge: capture hardware, then the enabled ISRs in natural order."""
        old = self.hall
        changed = old ^ new_bits
        self.hall = new_bits
        if changed & 2:  # IC7 captures every B edge, interrupt enabled or not; FIFO of 4
            if len(self.ic7_fifo) < 4:
                self.ic7_fifo.append(((t_edge - self.t3_zero) // TMR3_PRESCALE) & 0xFFFF)
        if not self.running:
            return
        if changed & 1:
            self._hall_isr(0, t_edge)
        if changed & 2 and self.running:
            self._hall_isr(1, t_edge)
        if changed & 4 and self.running:
            self._hall_isr(2, t_edge)

    def _ref_input(self) -> int:
        return self.ref_override if self.ref_override_on else ((self.pot_code & 0x3FF) - 512) << 6

    def _pwm_run(self, first_index: int, n: int) -> None:
        """n PWM period boundaries, indices first_index.. (index = time // 1000): latch + ISRs."""
        if self._adc_every:
            self.ref_speed = self._ref_input()
        else:
            # an ADC ISR happens at boundary k when k % 16 == 0
            if (-first_index) % ADC_POSTSCALE_V11 < n:
                self.ref_speed = self._ref_input()
        if not self.running:  # PDC keeps its value: the latch changes nothing after the first boundary
            self.act_duty = self.pend_duty
            return
        co = self.control_output
        if self.req_ccw:  # CCW drives with the one's complement of the negative output
            volts = -(co + 1)
            dphase = -self.phase_inc if self.cur_ccw else 0
        else:
            volts = co
            dphase = self.phase_inc if not self.cur_ccw else 0
        adv = self.phase_adv
        for _ in range(n):  # each boundary: the last period's registers take effect, the ISR writes new ones
            self.act_duty = self.pend_duty
            self.phase = (self.phase + dphase) & 0xFFFF
            self.pend_duty = svm(volts, (self.phase + adv) & 0xFFFF)

    def duties(self) -> tuple[int, int, int]:
        """The duty registers in effect now (latched at the last boundary)."""
        return self.act_duty

    def pending_duties(self) -> tuple[int, int, int]:
        """The duty registers the PWM ISR wrote last (they take effect at the next boundary)."""
        return self.pend_duty

    def _main_loop_buttons(self, inputs: int) -> None:
        """main(): if S2 is down, wait for its release, then toggle RunMotor/StopMotor."""
        s2 = bool(inputs & INPUT_S2)
        if self.booting:  # main is inside ChargeBootstraps' busy loop
            self.s2_level = s2
            return
        if s2:
            self.s2_wait_release = True
        elif self.s2_wait_release:
            self.s2_wait_release = False
            if self.running:
                self.press_stop()
            else:
                self.press_start()
        self.s2_level = s2

    def _flta(self, inputs: int) -> None:
        """FLTA (FLTACON = 0x0007, latched): the PWM module drives every output inactive and the FLTA
        ISR stops the motor with state FAULT, fault OVERCURRENT. Only a stop/start (S2) restarts it,
        and not while the pin is still asserted. The span's fault bit acts at the span's start."""
        if inputs & INPUT_FAULT and (self.running or self.booting):
            self.press_stop(STATE_FAULT, FAULT_OVERCURRENT)

    # ---- the step function -------------------------------------------------------------------
    def run(self, duration_tcy: int, inputs: int, edges: "int | None | Sequence[tuple[int, int]]",
            pot_code: int | None) -> None:
        """Advance by duration_tcy with these inputs. The halls change at `edges`: None, at the span's
        start if `inputs` differ from them; an offset in Tcy, then; or (protocol 3) a sequence of
        (offset_tcy, hall bits), each edge at its time (none: as None). Offsets beyond the span are
        served at its last Tcy; an edge listed out of order at the one before it."""
        if pot_code is not None:
            self.pot_code = pot_code
        self._main_loop_buttons(inputs)
        self._flta(inputs)
        t = self.t
        t_end = t + duration_tcy
        pending: list[tuple[int, int]] = []
        if edges is None or isinstance(edges, int) or not edges:
            if inputs & 7 != self.hall and duration_tcy > 0:
                pending.append((0 if not isinstance(edges, int) else edges, inputs & 7))
        else:
            pending = [(off, bits & 7) for off, bits in edges]
        last = 0
        for i, (off, bits) in enumerate(pending):  # clamped to the span, in time order
            off = max(last, min(max(off, 0), duration_tcy - 1))
            pending[i] = (t + off, bits)
            last = off
        pending.reverse()  # the next edge at the end: pop() it
        while True:
            nxt = t_end
            kind = 0
            if self.running and self.t1_next < nxt:
                nxt, kind = self.t1_next, 1
            if self.booting and self.boot_end < nxt:
                nxt, kind = self.boot_end, 2
            if pending and pending[-1][0] < nxt:
                nxt, kind = pending[-1][0], 3
            # PWM boundaries b·1000 with t ≤ b·1000 < nxt
            first = -(-t // PWM_PERIOD_TCY)
            last_b = -(-nxt // PWM_PERIOD_TCY)
            if last_b > first:
                self._pwm_run(first, last_b - first)
            t = nxt
            if kind == 0:
                break
            if kind == 1:
                self.t1_next += TIMER1_PERIOD_TCY
                self._timer1()
            elif kind == 2:
                self._run_motor()
            else:
                self._apply_hall(pending.pop()[1], nxt)
        self.t = t_end
