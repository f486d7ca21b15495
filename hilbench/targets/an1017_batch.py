"""N independent AN1017 firmware instances stepped together with numpy, for offline gain sweeps.

Each instance is bit-exact with `An1017Firmware.run` over one 50 µs lockstep period (1000 Tcy,
one PWM period): the same integer arithmetic on int64 arrays (Q15 saturation, the 1.31
saturating accumulator with a truncating SAC, DIVF as a floor division of positive operands,
16-bit wraps) and the same ISRs at the same virtual times. The instances share the virtual clock;
their events differ, so every ISR runs on the subset of instances it fires for, in the scalar
model's order inside the period:

    events at the period start (T1, bootstrap end, hall edge) → PWM ISR (with the ADC ISR)
    → the remaining events in time order (ties: T1 / bootstrap end before a hall edge).

Why a separate module rather than numpy inside An1017Firmware: the scalar model is tuned for
one instance (plain ints are ~50× cheaper than numpy calls there); here one numpy call serves
all N instances, so a 10 × 10 gain grid costs about as much as one scalar run.

Scope: lockstep 50 µs periods only; the gains are fixed per instance at construction (no live
writes, no reference override, no watchdog). `tests/test_an1017_batch.py` compares every Drive
field against N scalar `An1017Target`s at every period.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from hilbench.errors import ConfigError
from hilbench.protocol import Drive
from hilbench.targets.an1017_firmware import (
    ADC_POSTSCALE_V11,
    BOOTSTRAP_TCY,
    FAULT_NONE,
    FAULT_STALL,
    FORCE_COMMUTATION_TICKS,
    MAXPERIOD,
    MINPERIOD,
    MINPERIOD_DIVF,
    MODE_LOW_SIDE,
    MODE_OFF,
    MODE_PWM,
    PHASE_VALUES,
    PHASEINC_NUMERATOR,
    PWM_PERIOD_TCY,
    SECTOR_INVALID,
    SECTOR_TABLE,
    STATE_BOOTSTRAP,
    STATE_RUNNING,
    STATE_STALLED,
    STATE_STOPPED,
    TIMER1_PERIOD_TCY,
    TMR3_PRESCALE,
    An1017Options,
    check_gain_constraints,
    max_phase_advance_from_deg,
)
from hilbench.targets.svm import SINE_TABLE, SIXTY_DEG, TPWM, VOLTS_LIMIT

__all__ = ["An1017Batch", "EDGE_NONE", "svm_batch"]

EDGE_NONE = 0xFFFF
PERIOD_TCY = PWM_PERIOD_TCY  # one lockstep period = one PWM period
I64 = np.int64

# hall CBA → sector as the firmware stores it (0..5, 0xFFFF invalid) and as a table index (0..6)
_SECTOR_U16 = np.array([s & 0xFFFF for s in SECTOR_TABLE], dtype=I64)
_SECTOR_IDX = np.array([6 if s < 0 else s for s in SECTOR_TABLE], dtype=I64)
_SECTOR_OUT = np.array([7 if s < 0 else s for s in SECTOR_TABLE], dtype=I64)  # Drive.sector
# direction set by the hall ISR of each input (CN5 = A, IC7 = B, IC8 = C), by sector index 0..6
_CCW_BY_ISR = np.array(
    [[s in (5, 2) for s in range(7)], [s in (3, 0) for s in range(7)], [s in (1, 4) for s in range(7)]],
    dtype=bool,
)
# lowest changed hall bit → the ISR that does the work (the others find the sector unchanged)
_FIRST_ISR = np.array([0, 0, 1, 0, 2, 0, 1, 0], dtype=I64)

# SVM per 16-bit angle: the two sine-table entries and the duty pattern of its sector
_ANGLES = np.arange(0x10000, dtype=I64)
_SVM_SECTOR = (
    (_ANGLES >= 0x2AAA).astype(I64) + (_ANGLES >= 0x5555) + (_ANGLES >= 0x8000) + (_ANGLES >= 0xAAAA)
    + (_ANGLES >= 0xD555)
)  # 0..5 = sectors 1..6
_VECTORS = np.array((0x0000, 0x2AAA, 0x5555, 0x8000, 0xAAAA, 0xD555), dtype=I64)
_A2 = _ANGLES - _VECTORS[_SVM_SECTOR]
_SINE = np.array(SINE_TABLE, dtype=I64)
_SIN1 = _SINE[(SIXTY_DEG - _A2) >> 6]
_SIN2 = _SINE[_A2 >> 6]
# duty = h + k1·t1 + k2·t2 per phase and sector (svm.py's six return patterns)
_K1 = np.array([[1, 1, 0, 0, 0, 1], [0, 1, 1, 1, 0, 0], [0, 0, 0, 1, 1, 1]], dtype=I64)
_K2 = np.array([[1, 0, 0, 0, 1, 1], [1, 1, 1, 0, 0, 0], [0, 0, 1, 1, 1, 0]], dtype=I64)
# flat (3·65536) tables indexed by angle + 65536·phase: one 1-D take serves all three phases
_K1_FLAT = np.ascontiguousarray(_K1[:, _SVM_SECTOR]).ravel()
_K2_FLAT = np.ascontiguousarray(_K2[:, _SVM_SECTOR]).ravel()
_PHASE_ROWS = (np.arange(3, dtype=I64) * 0x10000)[:, None]
_SIN12 = np.ascontiguousarray(np.stack([_SIN1, _SIN2]))  # (2, 65536)


def svm_batch(volts: np.ndarray, angle_u16: np.ndarray) -> np.ndarray:
    """`svm.svm` over arrays: (3, n) duty registers, exact (16-bit wraps included)."""
    v = np.minimum(volts, VOLTS_LIMIT)
    t1 = (((_SIN1[angle_u16] * v) >> 15) & 0xFFFF) * TPWM >> 15 & 0xFFFF
    t2 = (((_SIN2[angle_u16] * v) >> 15) & 0xFFFF) * TPWM >> 15 & 0xFFFF
    h = ((TPWM - t1 - t2) & 0xFFFF) >> 1
    rows = angle_u16 + _PHASE_ROWS
    return (h + _K1_FLAT.take(rows) * t1 + _K2_FLAT.take(rows) * t2) & 0xFFFF


def svm_batch_clipped(volts: np.ndarray, angle_u16: np.ndarray, out: np.ndarray) -> None:
    """min(svm(volts, angle), 1000) into out (3, n), for volts ≥ −1 (all the firmware makes).

    Why a second version: for 0 ≤ volts ≤ 28300 every product stays below 2^16 and
    t1 + t2 ≤ 862 < 998, so svm's 16-bit masks never act and duties stay ≤ 998; volts = −1
    (the CCW start-up transient) gives t1, t2 ∈ {0, 1995} and every duty wraps above 1000, so
    the clipped result is 1000 on all phases. tests/test_an1017_batch.py checks both cases.
    """
    v = np.minimum(volts, VOLTS_LIMIT)  # volts = −1 columns are overwritten below
    t = _SIN12.take(angle_u16, axis=1)
    t *= v
    t >>= 15
    t *= TPWM
    t >>= 15
    t1, t2 = t[0], t[1]
    h = TPWM - t1
    h -= t2
    h >>= 1
    rows = angle_u16 + _PHASE_ROWS
    np.multiply(_K1_FLAT.take(rows), t1, out=out)
    k2 = _K2_FLAT.take(rows)
    k2 *= t2
    out += k2
    out += h
    neg = volts < 0
    if neg.any():
        out[:, neg] = 1000


class An1017Batch:
    """`An1017Batch(n, options, gains_q15)`: n AN1017 firmwares with their own (Kp, Ki, Kd).

    `step(hall_bits, edge_time_100ns, pot_code, s2)` advances every instance by one 50 µs
    period (arrays of shape (n,) or scalars; edge 0xFFFF = none). After it: `duty` (3, n) counts
    in effect over that period (≤ 1000), `duty_fractions()` the same for the plant,
    `output_mode`, `state`, `fault`, `ref_speed`,
    `measured_speed`, `control_output`, `sector_out`, `cur_ccw`, `req_ccw`; `drive(i, seq)`
    builds instance i's Drive message.
    """

    def __init__(self, n: int, options: An1017Options = An1017Options(), gains_q15: Any = None) -> None:
        if n <= 0:
            raise ConfigError(f"an1017 batch: n must be positive, got {n}")
        opts = options.resolved()
        self.options = opts
        self.n = n
        if gains_q15 is None:
            from hilbench.targets.an1017_firmware import KD_DEFAULT_Q15, KI_DEFAULT_Q15, KP_DEFAULT_Q15

            gains_q15 = [(KP_DEFAULT_Q15, KI_DEFAULT_Q15, KD_DEFAULT_Q15)] * n
        g = np.asarray(gains_q15, dtype=I64).reshape(-1, 3)
        if g.shape[0] != n:
            raise ConfigError(f"an1017 batch: gains_q15 has {g.shape[0]} rows for n={n}")
        for row, (kp, ki, kd) in enumerate(g.tolist()):
            if not all(0 <= x <= 32767 for x in (kp, ki, kd)):
                raise ConfigError(f"an1017 batch: gains row {row} ({kp}, {ki}, {kd}) outside 0..32767")
            broken = check_gain_constraints(kp, ki, kd)
            if broken is not None:
                raise ConfigError(f"an1017 batch: gains row {row} ({kp}, {ki}, {kd}) breaks constraint {broken}")
        self.gains_q15 = g
        kp, ki, kd = g[:, 0], g[:, 1], g[:, 2]

        def wrap16(x: np.ndarray) -> np.ndarray:
            return ((x + 0x8000) & 0xFFFF) - 0x8000

        self._c0 = wrap16(kp + ki + kd)
        self._c1 = wrap16(-kp - 2 * kd) if opts.pid_c1_textbook else wrap16(-(ki + 2 * kd))
        self._c2 = wrap16(kd)
        self._adc_every = bool(opts.adc_every_pwm_period)
        self._phase_adv_on = bool(opts.phase_advance)
        self._max_ph_adv = max_phase_advance_from_deg(opts.max_phase_advance_deg)
        self.stall_limit = int(opts.stall_timeout_ms or 100)
        off = opts.phase_offset_ccw
        # hall re-sync phase by [required_ccw, sector index 0..6]; -1 = keep (CW with invalid sector)
        cw = [PHASE_VALUES[s] for s in range(6)] + [-1]
        ccw = [(PHASE_VALUES[((s + 3) & 0xFFFF) % 6] + off) & 0xFFFF for s in list(range(6)) + [0xFFFF]]
        self._phase_for = np.array([cw, ccw], dtype=I64)
        self.t = 0
        z = lambda: np.zeros(n, dtype=I64)  # noqa: E731
        f = lambda: np.zeros(n, dtype=bool)  # noqa: E731
        self.pot_code = np.full(n, 512, dtype=I64)
        self.hall = z()
        self.t3_zero = z()
        self.fifo_count = z()
        self.fifo_head = z()
        self.output_mode = np.full(n, MODE_OFF, dtype=I64)
        self.pend_v = z()
        self.pend_a = z()
        self.duty = np.full((3, n), 499, dtype=I64)  # active registers (svm(0, 0) = PTPER)
        self._pend_duty = np.full((3, n), 499, dtype=I64)
        self.running = f()
        self.booting = f()
        self.boot_end = z()
        self.state = np.full(n, STATE_STOPPED, dtype=I64)
        self.fault = np.full(n, FAULT_NONE, dtype=I64)
        self.ref_speed = z()
        self.measured_speed = z()
        self.control_output = z()
        self.e1 = z()
        self.e2 = z()
        self.phase = z()
        self.phase_inc = z()
        self.phase_adv = z()
        self.sector = np.full(n, SECTOR_INVALID, dtype=I64)
        self.last_sector = np.full(n, SECTOR_INVALID, dtype=I64)
        self.stall_counter = z()
        self.cur_ccw = f()
        self.req_ccw = f()
        self.period = np.full(n, MAXPERIOD, dtype=I64)
        self.actual_capture = z()
        self.past_capture = z()
        self.t1_next = z()
        self.s2_wait_release = f()
        self._n_running = 0
        self._t1_min = np.iinfo(I64).max  # earliest Timer1 among running instances
        self._boot_min = np.iinfo(I64).max
        self._any_wait = False
        self._changed = np.zeros(n, dtype=bool)
        self._scale = np.zeros(n)  # 1/1000 where the output is PWM, else 0
        self._frac = np.zeros((3, n))
        self._volts = z()  # PWM ISR amplitude, changes only in Timer1 / RunMotor
        self._dphase = z()  # Phase step per PWM period, changes in Timer1 / hall ISR / RunMotor

    # ---- bookkeeping -------------------------------------------------------------------------
    def _refresh(self) -> None:
        """Recompute the cached summaries after the run state or Timer1 times changed."""
        run = self.running
        self._n_running = int(np.count_nonzero(run))
        big = np.iinfo(I64).max
        self._t1_min = int(self.t1_next[run].min()) if self._n_running else big
        self._boot_min = int(self.boot_end[self.booting].min()) if self.booting.any() else big
        self._scale = np.where(self.output_mode == MODE_PWM, 1.0 / 1000.0, 0.0)

    def _stop(self, idx: np.ndarray, state: int, fault: int) -> None:
        """StopMotor() for the instances idx."""
        self.running[idx] = False
        self.booting[idx] = False
        self.output_mode[idx] = MODE_OFF
        self.state[idx] = state
        self.fault[idx] = fault

    def _buttons(self, s2: np.ndarray) -> bool:
        """main(): act on the release of S2 (start or stop); True if a run state changed."""
        free = ~self.booting
        release = free & ~s2 & self.s2_wait_release
        self.s2_wait_release |= free & s2
        self.s2_wait_release &= ~release
        self._any_wait = bool(self.s2_wait_release.any())
        if not release.any():
            return False
        stop = np.flatnonzero(release & self.running)
        start = np.flatnonzero(release & ~self.running)
        if stop.size:
            self._stop(stop, STATE_STOPPED, FAULT_NONE)
        if start.size:
            self.booting[start] = True
            self.state[start] = STATE_BOOTSTRAP
            self.fault[start] = FAULT_NONE
            self.output_mode[start] = MODE_LOW_SIDE
            self.boot_end[start] = self.t + BOOTSTRAP_TCY + 1
        return True

    # ---- ISRs over subsets of instances ------------------------------------------------------
    def _run_motor(self, idx: np.ndarray) -> None:
        """RunMotor() after ChargeBootstraps() for the instances idx."""
        now = self.boot_end[idx]
        self.booting[idx] = False
        self.output_mode[idx] = MODE_PWM
        self.pend_v[idx] = 0
        self.pend_a[idx] = 0
        self._pend_duty[:, idx] = 499
        self.duty[:, idx] = 499
        self.e1[idx] = 0
        self.e2[idx] = 0
        self.t1_next[idx] = now + TIMER1_PERIOD_TCY
        self.t3_zero[idx] = now
        self.actual_capture[idx] = MAXPERIOD
        self.past_capture[idx] = 0
        hall = self.hall[idx]
        s = _SECTOR_U16[hall]
        self.sector[idx] = s
        self.last_sector[idx] = s
        self.control_output[idx] = 0
        ccw = self.ref_speed[idx] < 0
        self.cur_ccw[idx] = ccw
        self.req_ccw[idx] = ccw
        new = self._phase_for[ccw.astype(I64), _SECTOR_IDX[hall]]
        self.phase[idx] = np.where(new < 0, self.phase[idx], new)
        self.stall_counter[idx] = 0
        self.phase_inc[idx] = PHASEINC_NUMERATOR // MAXPERIOD
        self.running[idx] = True
        self.state[idx] = STATE_RUNNING
        self._update_pwm_terms(idx)

    def _update_pwm_terms(self, idx: np.ndarray) -> None:
        """Cache the PWM ISR's amplitude and phase step for idx (their inputs just changed).

        volts = −(co+1) when CCW is required, else co; the phase moves by +PhaseInc (CW wanted
        and turning CW), −PhaseInc (CCW and CCW) and stays put while the two disagree.
        """
        co, req, cur, inc = self.control_output[idx], self.req_ccw[idx], self.cur_ccw[idx], self.phase_inc[idx]
        self._volts[idx] = np.where(req, -1 - co, co)
        self._dphase[idx] = np.where(req, np.where(cur, -inc, 0), np.where(cur, 0, inc))

    def _timer1(self, idx: np.ndarray) -> None:
        """Timer1 ISR for the instances idx: speed, PID (MAC sequence), phase advance, stall."""
        self.t1_next[idx] += TIMER1_PERIOD_TCY
        period = np.clip((self.actual_capture[idx] - self.past_capture[idx]) & 0xFFFF, MINPERIOD, MAXPERIOD)
        self.period[idx] = period
        self.phase_inc[idx] = PHASEINC_NUMERATOR // period
        ms = (MINPERIOD_DIVF << 15) // period  # DIVF: positive operands, |num| < |den|
        ms = np.where(self.cur_ccw[idx], -ms, ms)
        self.measured_speed[idx] = ms
        e0 = np.clip(self.ref_speed[idx] - ms, -32768, 32767)
        e1 = self.e1[idx]
        lo, hi = -0x80000000, 0x7FFFFFFF
        acc = np.clip((self.control_output[idx] << 16) + ((e0 * self._c0[idx]) << 1), lo, hi)
        acc = np.clip(acc + ((e1 * self._c1[idx]) << 1), lo, hi)
        acc = np.clip(acc + ((self.e2[idx] * self._c2[idx]) << 1), lo, hi)
        co = acc >> 16
        self.e2[idx] = e1
        self.e1[idx] = e0
        self.control_output[idx] = co
        req = co < 0
        self.req_ccw[idx] = req
        if self._phase_adv_on:
            self.phase_adv[idx] = np.clip((self._max_ph_adv * ms * 2) >> 16, -32768, 32767)
        else:
            self.phase_adv[idx] = 0
        sc = self.stall_counter[idx] + 1
        self.stall_counter[idx] = sc
        force = sc % FORCE_COMMUTATION_TICKS == 0
        if force.any():
            fi = idx[force]
            hall = self.hall[fi]
            self.sector[fi] = _SECTOR_U16[hall]
            new = self._phase_for[req[force].astype(I64), _SECTOR_IDX[hall]]
            valid = _SECTOR_IDX[hall] < 6
            self.phase[fi] = np.where(valid, new, self.phase[fi])
        stall = ~force & (sc >= self.stall_limit)
        if stall.any():
            self._stop(idx[stall], STATE_STALLED, FAULT_STALL)
        self._update_pwm_terms(idx)

    def _edges(self, idx: np.ndarray, new_hall: np.ndarray, t_edge: np.ndarray) -> None:
        """Hall inputs of instances idx change at t_edge: IC7 capture, then the hall ISR."""
        changed = self.hall[idx] ^ new_hall
        self.hall[idx] = new_hall
        b = (changed & 2) != 0
        if b.any():
            bi = idx[b]
            count = self.fifo_count[bi]
            val = ((t_edge[b] - self.t3_zero[bi]) // TMR3_PRESCALE) & 0xFFFF
            self.fifo_head[bi] = np.where(count == 0, val, self.fifo_head[bi])
            self.fifo_count[bi] = np.minimum(count + 1, 4)
        run = self.running[idx]
        if not run.all():
            if not run.any():
                return
            idx, new_hall, changed = idx[run], new_hall[run], changed[run]
        s = _SECTOR_U16[new_hall]
        self.sector[idx] = s
        act = s != self.last_sector[idx]
        if not act.all():
            if not act.any():
                return
            idx, new_hall, changed, s = idx[act], new_hall[act], changed[act], s[act]
        which = _FIRST_ISR[changed]
        ic7 = which == 1
        if ic7.any():
            ii = idx[ic7]
            self.past_capture[ii] = self.actual_capture[ii]
            full = self.fifo_count[ii] > 0
            self.actual_capture[ii] = np.where(full, self.fifo_head[ii], self.actual_capture[ii])
            self.fifo_count[ii] = 0
        self.stall_counter[idx] = 0
        sidx = _SECTOR_IDX[new_hall]
        self.cur_ccw[idx] = _CCW_BY_ISR[which, sidx]
        new = self._phase_for[self.req_ccw[idx].astype(I64), sidx]
        self.phase[idx] = np.where(new < 0, self.phase[idx], new)
        self.last_sector[idx] = s
        self._update_pwm_terms(idx)

    def _pwm(self) -> None:
        """The PWM period boundary at self.t: latch, ADC ISR, PWM ISR (phase ramp, SVM)."""
        if self._adc_every or (self.t // PWM_PERIOD_TCY) % ADC_POSTSCALE_V11 == 0:
            np.subtract(self.pot_code & 0x3FF, 512, out=self.ref_speed)
            np.left_shift(self.ref_speed, 6, out=self.ref_speed)
        # the registers written one period ago take effect (swap buffers: no copy)
        self.duty, self._pend_duty = self._pend_duty, self.duty
        nrun = self._n_running
        if nrun == 0:
            self._pend_duty[...] = self.duty
            return
        if nrun == self.n:
            phase = self.phase
            phase += self._dphase
            phase &= 0xFFFF
            angle = self.pend_a
            np.add(phase, self.phase_adv, out=angle)
            angle &= 0xFFFF
            self.pend_v[...] = self._volts
            svm_batch_clipped(self._volts, angle, self._pend_duty)
            return
        idx = np.flatnonzero(self.running)
        stopped = ~self.running
        self._pend_duty[:, stopped] = self.duty[:, stopped]
        phase = (self.phase[idx] + self._dphase[idx]) & 0xFFFF
        self.phase[idx] = phase
        angle = (phase + self.phase_adv[idx]) & 0xFFFF
        volts = self._volts[idx]
        self.pend_v[idx] = volts
        self.pend_a[idx] = angle
        d = np.empty((3, idx.size), dtype=I64)
        svm_batch_clipped(volts, angle, d)
        self._pend_duty[:, idx] = d

    # ---- the step function -------------------------------------------------------------------
    def step(self, hall_bits: Any, edge_time_100ns: Any, pot_code: Any, s2: Any = False) -> None:
        """One 50 µs lockstep period for every instance (An1017Target.step with these Sensors)."""
        n = self.n
        if pot_code is not None:
            self.pot_code[...] = pot_code
        if self._any_wait or (s2 is not False and bool(np.any(s2))):
            if self._buttons(np.broadcast_to(np.asarray(s2, dtype=bool), (n,))):
                self._refresh()
        t = self.t
        t_end = t + PERIOD_TCY
        hall_in = np.asarray(hall_bits, dtype=I64) & 7
        np.not_equal(hall_in, self.hall, out=self._changed)
        eidx = np.flatnonzero(self._changed)
        t1_due = self._t1_min < t_end
        boot_due = self._boot_min < t_end
        if eidx.size:
            if hall_in.ndim == 0:
                hall_in = np.broadcast_to(hall_in, (n,))
            ehall = hall_in[eidx]
            et = np.asarray(edge_time_100ns, dtype=I64)
            et = np.broadcast_to(et, (n,))[eidx] if et.ndim == 0 else et[eidx]
            eoff = np.where(et == EDGE_NONE, 0, np.minimum(et << 1, PERIOD_TCY - 1))
        if not (t1_due or boot_due):
            if eidx.size:
                first = eoff == 0
                if first.any():
                    self._edges(eidx[first], ehall[first], eoff[first] + t)
                self._pwm()
                later = ~first
                if later.any():
                    self._edges(eidx[later], ehall[later], eoff[later] + t)
            else:
                self._pwm()
            self.t = t_end
            return
        self._step_general(t, t_end, eidx, ehall if eidx.size else None, eoff if eidx.size else None)
        self.t = t_end

    def _step_general(self, t: int, t_end: int, eidx: np.ndarray, ehall: Any, eoff: Any) -> None:
        """A period with a Timer1 tick or a bootstrap end for some instance: full event order."""
        n = self.n
        big = PERIOD_TCY + 1
        o1 = np.full(n, big, dtype=I64)  # offset of this period's T1 / bootstrap end, big = none
        ob = np.full(n, big, dtype=I64)
        t1m = self.running & (self.t1_next < t_end)
        o1[t1m] = self.t1_next[t1m] - t
        bm = self.booting & (self.boot_end < t_end)
        ob[bm] = self.boot_end[bm] - t
        if eidx.size:
            oe = np.full(n, -1, dtype=I64)
            oe[eidx] = eoff
        # events at the period start, then the PWM boundary
        at0 = np.flatnonzero(o1 == 0)
        if at0.size:
            self._timer1(at0)
        at0 = np.flatnonzero(ob == 0)
        if at0.size:
            self._run_motor(at0)
        if at0.size or (o1 == 0).any():
            self._refresh()
        if eidx.size:
            first = eoff == 0
            if first.any():
                self._edges(eidx[first], ehall[first], t + eoff[first])
        self._pwm()
        # later events: an edge before its instance's T1 / bootstrap end, then those, then the rest
        if eidx.size:
            rest = eoff > 0
            early = rest & (eoff < o1[eidx]) & (eoff < ob[eidx])
            if early.any():
                self._edges(eidx[early], ehall[early], t + eoff[early])
            late = rest & ~early
        later_t1 = np.flatnonzero((o1 > 0) & (o1 < big))
        if later_t1.size:
            self._timer1(later_t1)
        later_b = np.flatnonzero((ob > 0) & (ob < big))
        if later_b.size:
            self._run_motor(later_b)
        self._refresh()
        if eidx.size and late.any():
            self._edges(eidx[late], ehall[late], t + eoff[late])

    # ---- outputs -----------------------------------------------------------------------------
    def duty_fractions(self) -> np.ndarray:
        """(3, n) duties as fractions 0..1 for the plant; 0 where the output is not PWM.

        Zero duties on all three phases mean zero line voltage, which is what LOW_SIDE applies;
        for OFF it is an approximation (see hilbench.bench.sweep). The array is reused.
        """
        return np.multiply(self.duty, self._scale, out=self._frac)

    @property
    def sector_out(self) -> np.ndarray:
        """Drive.sector: the firmware's Sector while running, else the hall table; 7 = invalid."""
        out = np.where(self.sector == SECTOR_INVALID, 7, self.sector)
        return np.where(self.running, out, _SECTOR_OUT[self.hall])

    def drive(self, i: int, seq: int = 0) -> Drive:
        """Instance i's outputs as the Drive message An1017Target.step would answer."""
        sector = int(self.sector_out[i])
        return Drive(
            seq & 0xFF,
            int(self.duty[0, i]),
            int(self.duty[1, i]),
            int(self.duty[2, i]),
            int(self.output_mode[i]),
            int(self.state[i]),
            sector,
            bool(self.cur_ccw[i]),
            bool(self.req_ccw[i]),
            int(self.fault[i]),
            (int(self.ref_speed[i]), int(self.measured_speed[i]), int(self.control_output[i])),
        )

    @property
    def time_us(self) -> float:
        """Virtual time since power-on, µs (shared by every instance)."""
        return self.t / 20.0


def gains_to_q15(gains: Sequence[tuple[float, float, float]]) -> np.ndarray:
    """(kp, ki, kd) fractions → Q15 words the way the bench writes them (round(x·32768))."""
    return np.array([[min(32767, round(x * 32768.0)) for x in g] for g in gains], dtype=I64).reshape(-1, 3)
