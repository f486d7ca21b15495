"""The AN1017 firmware model behind the Target interface (docs/design.md, hilbench/targets/base.py).

The firmware itself lives in `an1017_firmware` (plain ints, Tcy time); this module translates
protocol messages to its inputs and its state to Drive, and owns the declared parameter table.

Drive semantics (the timing contract, docs/design.md "Timing"): `duty_a..c` are the duty
registers the PWM ISR wrote during the step's span, i.e. what PDC1..3 hold for the next PWM
period (PWMCON2.IUE = 0 latches them at the next boundary). The plant applies them in that next
period, so the chip's one-period register latency is there once and no more. PDC values above 1000
(only produced by the firmware's volts = −1 start-up transient in CCW) mean 100 % and are
reported as 1000.

Two backends with identical outputs (tests/test_an1017_core.py compares every Drive with the
reference path): "c" (hilbench/targets/_an1017core.c, an optional compiled extension holding the
firmware state in a C struct, exposed under An1017Firmware's attribute names) and "python"
(An1017Firmware with this module's fast path). "c" is chosen when the extension is built unless
HILBENCH_AN1017_BACKEND=python (or backend="python") asks otherwise; `reference=True` is always
pure Python (it is the readable spec). `target.backend` says which one runs.
"""

from __future__ import annotations

import os
from typing import Any

from hilbench.errors import ConfigError, ParamError
from hilbench.targets.an1017.firmware import (
    GAIN_CONSTRAINT_NAMES,
    INPUT_FAULT,
    INPUT_S2,
    PWM_PERIOD_TCY,
    STATE_FAULT,
    TIMER1_PERIOD_TCY,
    FAULT_WATCHDOG,
    SECTOR_INVALID,
    SECTOR_TABLE,
    TCY_PER_US,
    An1017Firmware,
    An1017Options,
    check_gain_constraints,
    max_phase_advance_from_deg,
)
from hilbench.targets.an1017.svm import SINE_TABLE, VOLTS_LIMIT, svm_fast

from hilbench.protocol import (
    PROTOCOL_VERSION,
    SCHEMA_FINGERPRINT,
    Access,
    AdcRole,
    Drive,
    Edge,
    ErrorCode,
    ParamInfo,
    ParamSetResult,
    ParamType,
    ParamValue,
    Result,
    Sensors,
    Status,
    TargetHello,
    TelemetryId,
)

# plain ints of the protocol constants (IntEnum members are slower in the per-period path)
EDGE_NONE = int(Edge.NONE)
PTYPE_Q15, PTYPE_INT, PTYPE_BOOL = int(ParamType.Q15), int(ParamType.INT), int(ParamType.BOOL)
ACCESS_RO, ACCESS_RW = int(Access.RO), int(Access.RW)
RESULT_OK = int(Result.OK)
RESULT_UNKNOWN_ID = int(Result.UNKNOWN_ID)
RESULT_READ_ONLY = int(Result.READ_ONLY)
RESULT_OUT_OF_RANGE = int(Result.OUT_OF_RANGE)
RESULT_CONSTRAINT = int(Result.CONSTRAINT)
RESULT_BAD_REQUEST = int(Result.BAD_REQUEST)
ADC_ROLES = (int(AdcRole.POT), int(AdcRole.IBUS), int(AdcRole.VBUS))
TELEMETRY_IDS = (int(TelemetryId.REF_SPEED), int(TelemetryId.MEASURED_SPEED), int(TelemetryId.CONTROL_OUTPUT))

FIRMWARE_NAME = "AN1017"
FIRMWARE_VERSION = 0x0101  # v1.1
PWM_PERIOD_COUNTS = 1000
PWM_FREQ_HZ = 20000
PWM_PERIOD_US = 50
DUTY_CACHE_MAX = 200_000  # entries of (a, b, c): bounded memory, cleared when full
_tuple_new = tuple.__new__  # Drive is a NamedTuple: this skips its Python-level __new__ (~3x cheaper)
if Drive._fields[1:4] != ("duty_a", "duty_b", "duty_c") or len(Drive._fields) != 11:
    # _finish/step build Drives from positional tuples: a changed message must not go unnoticed
    raise ConfigError(f"an1017: Drive fields changed to {Drive._fields}; update the tuple layout in an1017.py")
if Sensors._fields != ("seq", "inputs", "edge_time_100ns", "encoder", "adc"):
    raise ConfigError(f"an1017: Sensors fields changed to {Sensors._fields}; update the unpacking in step()")

# declared parameters: id → (name, ptype, access, min, max)
PARAM_KP, PARAM_KI, PARAM_KD = 0, 1, 2
PARAM_PH_ADV_ON, PARAM_PH_ADV_DEG = 3, 4
PARAM_REF_OVR_ON, PARAM_REF_OVR = 5, 6
PARAM_STALL_MS = 7
PARAMS: dict[int, tuple[str, int, int, int, int]] = {
    PARAM_KP: ("kp", PTYPE_Q15, ACCESS_RW, 0, 32767),
    PARAM_KI: ("ki", PTYPE_Q15, ACCESS_RW, 0, 32767),
    PARAM_KD: ("kd", PTYPE_Q15, ACCESS_RW, 0, 32767),
    PARAM_PH_ADV_ON: ("ph_adv_on", PTYPE_BOOL, ACCESS_RW, 0, 1),
    PARAM_PH_ADV_DEG: ("ph_adv_deg", PTYPE_INT, ACCESS_RW, 0, 60),
    PARAM_REF_OVR_ON: ("ref_ovr_on", PTYPE_BOOL, ACCESS_RW, 0, 1),
    PARAM_REF_OVR: ("ref_override", PTYPE_Q15, ACCESS_RW, -32768, 32767),
    PARAM_STALL_MS: ("stall_ms", PTYPE_INT, ACCESS_RW, 10, 30000),
}
GAIN_PARAM_OF_CONSTRAINT = {1: PARAM_KP, 2: PARAM_KP, 3: PARAM_KD}

__all__ = [
    "An1017Target",
    "available_backends",
    "An1017Options",
    "An1017Firmware",
    "check_gain_constraints",
    "GAIN_CONSTRAINT_NAMES",
    "PARAMS",
]


try:
    from hilbench.targets.an1017 import _core as _an1017core
except ImportError:  # pragma: no cover - built without a C compiler
    _an1017core = None
else:
    _an1017core.init(Drive, SINE_TABLE)


def available_backends() -> tuple[str, ...]:
    """The firmware-model backends usable here ("c" only when the extension is built)."""
    return ("c", "python") if _an1017core is not None else ("python",)


def _choose_backend(backend: str | None, reference: bool) -> str:
    """backend argument, else HILBENCH_AN1017_BACKEND, else "c" when built; reference → "python"."""
    choice = backend or os.environ.get("HILBENCH_AN1017_BACKEND", "") or ("c" if _an1017core is not None else "python")
    if choice not in ("c", "python"):
        raise ConfigError(f"an1017 backend {choice!r}: expected 'c' or 'python'")
    if reference:
        if backend == "c":
            raise ConfigError("an1017 backend 'c': the reference path (reference=True) is pure Python")
        return "python"
    if choice == "c" and _an1017core is None:
        raise ConfigError("an1017 backend 'c': hilbench.targets.an1017._core is not built (pip install . with a C compiler)")
    return choice


class DutyCache(dict):
    """Packed SVM arguments (volts << 16 | angle, see An1017Firmware.pend_key) → reported duties.

    Filled on first use (`__missing__`), so the per-period lookup is one subscript. It is what
    makes the SVM a one-off per amplitude: angles repeat from one electrical cycle to the next.
    PDC values above 1000 (volts = −1 only) are reported as 1000; the size is bounded.
    """

    __slots__ = ()

    def __missing__(self, key: int) -> tuple[int, int, int]:
        volts = key >> 16
        a, b, c = svm_fast(volts, key & 0xFFFF)
        if volts < 0:
            a, b, c = min(a, 1000), min(b, 1000), min(c, 1000)
        if len(self) >= DUTY_CACHE_MAX:
            self.clear()
        d = self[key] = (a, b, c)
        return d


class An1017Target:
    """AN1017 firmware as a Target: lockstep `step`, real-time `advance`, declared parameters.

    `fw` is up to date after every call and may be read freely. Change it only through these
    methods: `step` keeps a per-period context (see `_finish`) that direct writes to `fw`
    between steps would bypass.
    """

    firmware_name = FIRMWARE_NAME
    backend = "python"

    def __new__(cls, options: An1017Options = An1017Options(), *, reference: bool = False,
                backend: str | None = None) -> "An1017Target":
        if cls is An1017Target and _choose_backend(backend, reference) == "c":
            return object.__new__(_CAn1017Target)
        return object.__new__(cls)

    def __init__(self, options: An1017Options = An1017Options(), *, reference: bool = False,
                 backend: str | None = None) -> None:
        self.options = options.resolved()
        self.fw = (_CFirmware if self.backend == "c" else An1017Firmware)(options, reference=reference)
        self.period_us = PWM_PERIOD_US
        self._period_tcy = PWM_PERIOD_US * TCY_PER_US
        self.mode = 0
        self.watchdog_ms = 0
        self._last_seq = 0
        self._last_drive: Drive | None = None  # a repeated seq is answered with it, without a step
        self._frac_tcy = 0.0
        self.watchdog_trips = 0
        self.last_error = 0
        self._duty_cache = DutyCache()
        # the Drive after its duties (mode, state, sector, ccw, required ccw, fault, telemetry)
        self._tail: tuple = (0, 0, 7, False, False, 0, (0, 0, 0))
        self._ctx: tuple | None = None  # the plain-period context (see _finish)
        self._idle: tuple | None = None  # the stopped-motor context (see _finish)

    # ---- handshake and parameters ------------------------------------------------------------
    def hello(self, host: Any) -> TargetHello:
        """Agree the period (a whole number of 50 µs PWM periods) and the mode."""
        period_us = int(host.period_us)
        if period_us <= 0 or period_us % PWM_PERIOD_US:
            raise ConfigError(f"an1017 hello: period_us {period_us} is not a positive multiple of {PWM_PERIOD_US}")
        self.period_us = period_us
        self._period_tcy = period_us * TCY_PER_US
        self._ctx = self._idle = None
        self._last_drive = None
        self.mode = int(host.mode)
        self.watchdog_ms = int(host.watchdog_ms)
        return TargetHello(
            host.seq,
            PROTOCOL_VERSION,
            SCHEMA_FINGERPRINT,
            FIRMWARE_VERSION,
            PWM_PERIOD_COUNTS,
            PWM_FREQ_HZ,
            len(PARAMS),
            10,  # adc_bits: the dsPIC30F2010's 10-bit ADC
            FIRMWARE_NAME,
            ADC_ROLES,
            TELEMETRY_IDS,
        )

    def _value(self, param_id: int) -> int:
        fw = self.fw
        kp, ki, kd = fw.declared_gains()
        if param_id == PARAM_KP:
            return kp
        if param_id == PARAM_KI:
            return ki
        if param_id == PARAM_KD:
            return kd
        if param_id == PARAM_PH_ADV_ON:
            return int(fw.phase_advance_on)
        if param_id == PARAM_PH_ADV_DEG:
            return fw.max_ph_adv_deg
        if param_id == PARAM_REF_OVR_ON:
            return int(fw.ref_override_on)
        if param_id == PARAM_REF_OVR:
            return fw.ref_override
        if param_id == PARAM_STALL_MS:
            return fw.stall_limit
        raise ParamError(f"an1017 param {param_id}: unknown id")

    def describe(self, param_id: int) -> ParamInfo:
        """The declaration of one parameter; an unknown id raises ParamError."""
        if param_id not in PARAMS:
            raise ParamError(f"an1017 describe: unknown param id {param_id}")
        name, ptype, access, lo, hi = PARAMS[param_id]
        return ParamInfo(0, param_id, ptype, access, lo, hi, self._value(param_id), name)

    def get_param(self, param_id: int) -> ParamValue:
        """Read one parameter; result UNKNOWN_ID for an undeclared id."""
        if param_id not in PARAMS:
            return ParamValue(0, param_id, RESULT_UNKNOWN_ID, 0)
        return ParamValue(0, param_id, RESULT_OK, self._value(param_id))

    def set_params(self, pairs: tuple[tuple[int, int], ...]) -> ParamSetResult:
        """All or nothing: ids, ranges and the application note's gain constraints are checked before any write."""
        if not pairs or len(pairs) > 4:
            return ParamSetResult(0, RESULT_BAD_REQUEST, 0, 0)
        new = {pid: self._value(pid) for pid in PARAMS}
        for pid, value in pairs:
            if pid not in PARAMS:
                return ParamSetResult(0, RESULT_UNKNOWN_ID, pid, 0)
            _, _, access, lo, hi = PARAMS[pid]
            if access != ACCESS_RW:
                return ParamSetResult(0, RESULT_READ_ONLY, pid, 0)
            if not lo <= value <= hi:
                return ParamSetResult(0, RESULT_OUT_OF_RANGE, pid, 0)
            new[pid] = value
        gains_touched = [pid for pid, _ in pairs if pid in (PARAM_KP, PARAM_KI, PARAM_KD)]
        if gains_touched:
            broken = check_gain_constraints(new[PARAM_KP], new[PARAM_KI], new[PARAM_KD])
            if broken is not None:
                # name the written gain that takes part in the broken constraint
                involved = {1: (PARAM_KP, PARAM_KI, PARAM_KD), 2: (PARAM_KP, PARAM_KD), 3: (PARAM_KD,)}[broken]
                offender = next((p for p in gains_touched if p in involved), gains_touched[0])
                return ParamSetResult(0, RESULT_CONSTRAINT, offender, broken)
        fw = self.fw
        if gains_touched:
            fw.set_gains(new[PARAM_KP], new[PARAM_KI], new[PARAM_KD])
        fw.phase_advance_on = bool(new[PARAM_PH_ADV_ON])
        if new[PARAM_PH_ADV_DEG] != fw.max_ph_adv_deg:
            fw.max_ph_adv_deg = new[PARAM_PH_ADV_DEG]
            fw.max_ph_adv = max_phase_advance_from_deg(fw.max_ph_adv_deg)
        fw.ref_override_on = bool(new[PARAM_REF_OVR_ON])
        fw.ref_override = new[PARAM_REF_OVR]
        fw.stall_limit = new[PARAM_STALL_MS]
        self._ctx = self._idle = None  # the reference override is part of both contexts
        return ParamSetResult(0, RESULT_OK, pairs[-1][0], 0)

    # ---- run control -------------------------------------------------------------------------
    def start(self) -> None:
        """S2 as a command: start (ChargeBootstraps, then RunMotor) when stopped."""
        self.fw.press_start()
        self._ctx = self._idle = None

    def stop(self) -> None:
        """StopMotor(): all six switches off, motor coasts (also aborts a bootstrap)."""
        if self.fw.running or self.fw.booting:
            self.fw.press_stop()
        self._ctx = self._idle = None

    # ---- the per-period paths ------------------------------------------------------------------
    def _finish(self, seq: int) -> Drive:
        """The Drive after a step that was not a plain period, and the context for the next ones.

        The context (`_ctx`) caches what plain periods need — motor running, 50 µs lockstep, S2
        up, halls unchanged, no Timer1 tick in the period — which then change only Phase, the duty
        pipeline, time and, through the ADC ISR, RefSpeed. Everything in it stays valid until an
        ISR other than PWM/ADC runs or the host changes something; every such path ends here or
        sets `_ctx = None`. `_tail` is the Drive after its duties (mode … telemetry), reused
        while only the duties change.
        """
        fw = self.fw
        if fw.reference:
            a, b, c = fw.pend_duty
            if a > 1000 or b > 1000 or c > 1000:
                a, b, c = min(a, 1000), min(b, 1000), min(c, 1000)
        else:
            a, b, c = self._duty_cache[fw.pend_key]
        running = fw.running
        s = fw.sector if running else SECTOR_TABLE[fw.hall] & 0xFFFF
        co = fw.control_output
        tel = self._tail[6]
        if tel[0] != fw.ref_speed or tel[1] != fw.measured_speed or tel[2] != co:
            tel = (fw.ref_speed, fw.measured_speed, co)
        self._tail = tail = (
            fw.output_mode, fw.state, 7 if s == SECTOR_INVALID else s, fw.cur_ccw, fw.req_ccw, fw.fault, tel,
        )
        if (
            running
            and self._period_tcy == PWM_PERIOD_TCY
            and not fw.reference
            and fw.t % PWM_PERIOD_TCY == 0
            and not fw.s2_wait_release
            and (not fw._adc_every or fw.ref_speed == (  # the pot's value (see step())
                fw.ref_override if fw.ref_override_on else ((fw.pot_code & 0x3FF) - 512) << 6))
        ):
            if fw.req_ccw:
                volts = -(co + 1)
                dphase = -fw.phase_inc if fw.cur_ccw else 0
            else:
                volts = co
                dphase = 0 if fw.cur_ccw else fw.phase_inc
            self._ctx = (
                fw.hall,
                fw.t1_next - PWM_PERIOD_TCY,  # the last start time of a period without a Timer1 tick
                (volts if volts < VOLTS_LIMIT else VOLTS_LIMIT) << 16,  # svm clamps it there too
                dphase,
                fw.phase_adv,
                fw.ref_override if fw.ref_override_on else None,
                fw._adc_every,
                self._duty_cache,
            )
        else:
            self._ctx = None
        d = _tuple_new(Drive, (seq, a, b, c) + tail)
        if (
            not running
            and not fw.booting
            and not fw.reference
            and self._period_tcy == PWM_PERIOD_TCY
            and fw.t % PWM_PERIOD_TCY == 0
            and not fw.s2_wait_release
            and fw.act_key == fw.pend_key
            and fw.ref_speed == (fw.ref_override if fw.ref_override_on else ((fw.pot_code & 0x3FF) - 512) << 6)
        ):
            # Stopped, registers settled, RefSpeed = the pot's: while halls, S2 and the pot stay
            # as they are, a period only advances time and the Drive differs only in seq.
            self._idle = (fw.hall, fw.pot_code, {seq: d}, (a, b, c) + tail)
        else:
            self._idle = None
        return d

    def step(self, sensors: Sensors) -> Drive:
        """Lockstep: exactly one agreed period with these sensors.

        Plain 50 µs periods (see `_finish`) run inline here: the ADC ISR when due, one PWM ISR,
        one cached SVM lookup, a Drive from the cached tail. A stopped motor with nothing changing
        only advances time and reuses its Drives (one per seq). Everything else goes through
        `_step_events`. All paths give the reference path's Drive exactly
        (tests/test_an1017_fastpath.py compares every Drive over randomised streams).
        A Sensors repeating the last one's seq (a duplicated frame) gets the last Drive again and
        the firmware does not step: a board answers a repeat the same way (issue 16, item 8).
        """
        last = self._last_drive
        if last is not None and sensors[0] == last[0]:
            return last
        ctx = self._ctx
        if ctx is not None:
            hall, t_last, vkey, dphase, adv, ovr, adc_every, cache = ctx
            seq, inputs, _, _, adc = sensors
            fw = self.fw
            t = fw.t
            if (inputs & 0x2F) == hall and t <= t_last:  # halls unchanged, S2 up, FLTA quiet
                tail = self._tail
                if adc:
                    pot = adc[0]
                    if pot != fw.pot_code:
                        fw.pot_code = pot
                        if adc_every and ovr is None:  # appnote: the ADC ISR runs at every boundary
                            ref = ((pot & 0x3FF) - 512) << 6
                            if ref != fw.ref_speed:
                                fw.ref_speed = ref
                                tel = tail[6]
                                tail = self._tail = tail[:6] + ((ref, tel[1], tel[2]),)
                # (appnote, pot unchanged: RefSpeed is already this pot's value — see _finish)
                if not adc_every and t % 16_000 == 0:  # v11: the ADC ISR at every 16th boundary
                    ref = (((fw.pot_code & 0x3FF) - 512) << 6) if ovr is None else ovr
                    if ref != fw.ref_speed:
                        fw.ref_speed = ref
                        tel = tail[6]
                        tail = self._tail = tail[:6] + ((ref, tel[1], tel[2]),)
                fw.act_key = fw.pend_key  # PWM ISR: last period's registers take effect ...
                phase = (fw.phase + dphase) & 0xFFFF  # ... and it writes the next ones,
                fw.phase = phase
                pend = fw.pend_key = vkey | ((phase + adv) & 0xFFFF)
                fw.t = t + 1000
                self._last_seq = seq
                d = self._last_drive = _tuple_new(Drive, (seq,) + cache[pend] + tail)  # which the Drive carries
                return d
        idle = self._idle
        if idle is not None:
            hall, pot, drives, body = idle
            seq, inputs, _, _, adc = sensors
            if (inputs & 15) == hall and (not adc or adc[0] == pot):
                self.fw.t += PWM_PERIOD_TCY
                self._last_seq = seq
                d = drives.get(seq)
                if d is None:
                    if len(drives) >= 4096:
                        drives.clear()
                    d = drives[seq] = _tuple_new(Drive, (seq,) + body)
                self._last_drive = d
                return d
        d = self._last_drive = self._step_events(sensors)
        return d

    def _step_events(self, sensors: Any) -> Drive:
        """A period with a Timer1 tick or a timed hall edge after its PWM boundary, or the general path."""
        fw = self.fw
        inputs = sensors.inputs
        adc = sensors.adc
        seq = sensors.seq
        self._last_seq = seq
        t = fw.t
        t1 = fw.t1_next
        ctx = self._ctx
        if ctx is not None and not inputs & (INPUT_S2 | INPUT_FAULT) and t1 > t:
            new_hall = inputs & 7
            edge_at = -1
            if new_hall != fw.hall:
                edge = sensors.edge_time_100ns
                if edge != EDGE_NONE and edge != 0:  # an edge at the boundary precedes the PWM ISR
                    edge_at = t + min(edge << 1, PWM_PERIOD_TCY - 1)
                else:
                    edge_at = t  # → the general path below
            if edge_at != t:
                # the plain period's ADC and PWM ISRs (An1017Firmware._pwm_run for n = 1)
                _, _, vkey, dphase, adv, ovr, adc_every, _ = ctx
                if adc:
                    fw.pot_code = adc[0]
                fw.s2_level = False
                if adc_every or t % 16_000 == 0:
                    fw.ref_speed = (((fw.pot_code & 0x3FF) - 512) << 6) if ovr is None else ovr
                fw.act_key = fw.pend_key
                phase = (fw.phase + dphase) & 0xFFFF
                fw.phase = phase
                fw.pend_key = vkey | ((phase + adv) & 0xFFFF)
                t_end = t + PWM_PERIOD_TCY
                # the later events in the dsPIC's order: by time, Timer1 first on a tie
                if t1 < t_end and (edge_at < 0 or t1 <= edge_at):
                    fw.t1_next = t1 + TIMER1_PERIOD_TCY
                    fw._timer1()
                    if edge_at >= 0:
                        fw._apply_hall(new_hall, edge_at)
                elif edge_at >= 0:
                    fw._apply_hall(new_hall, edge_at)
                    if t1 < t_end and fw.running:
                        fw.t1_next = t1 + TIMER1_PERIOD_TCY
                        fw._timer1()
                fw.t = t_end
                return self._finish(seq)
        edge = sensors.edge_time_100ns
        fw.run(self._period_tcy, inputs, None if edge == EDGE_NONE else edge << 1, adc[0] if adc else None)
        return self._finish(seq)

    def advance(self, duration_us: float, sensors: Any) -> Drive:
        """Real time: any span of wall time (sub-Tcy remainders carry over)."""
        total = duration_us * TCY_PER_US + self._frac_tcy
        tcy = int(total)
        self._frac_tcy = total - tcy
        edge = sensors.edge_time_100ns
        adc = sensors.adc
        if tcy > 0:
            self.fw.run(tcy, sensors.inputs, None if edge == EDGE_NONE else edge << 1, adc[0] if adc else None)
        self._last_seq = sensors.seq
        return self._finish(sensors.seq)

    def watchdog_trip(self) -> Drive:
        """Sensors stopped arriving: StopMotor, state FAULT, fault WATCHDOG."""
        self.watchdog_trips += 1
        self._last_drive = None
        self.last_error = int(ErrorCode.WATCHDOG)  # Status.last_error speaks ErrorCode; FAULT_WATCHDOG is for Drive.fault
        self.fw.press_stop(STATE_FAULT, FAULT_WATCHDOG)
        return self._finish(self._last_seq)

    def status(self) -> Status:
        """The target's own counters (the server adds link counters)."""
        return Status(0, 0, 0, 0, 0, 0, self.watchdog_trips & 0xFFFF, self.last_error)

    @property
    def time_us(self) -> float:
        """Virtual time since power-on, µs."""
        return self.fw.t / TCY_PER_US


if _an1017core is not None:

    class _CFirmware(_an1017core.Core):
        """An1017Firmware whose state is the C struct of `_an1017core.Core`.

        The host-command methods are An1017Firmware's own (they only read and write attributes,
        which are the struct's members here); `run` is the compiled one, plus `step` (one lockstep
        period → Drive) and `finish` (the Drive of the current state) used by _CAn1017Target.
        """

        __init__ = An1017Firmware.__init__
        press_start = An1017Firmware.press_start
        press_stop = An1017Firmware.press_stop
        set_gains = An1017Firmware.set_gains
        declared_gains = An1017Firmware.declared_gains
        _coefficients = An1017Firmware._coefficients
        duties = An1017Firmware.duties

    class _CAn1017Target(An1017Target):
        """An1017Target on the compiled firmware: `step` is the C method of `fw` itself.

        Parameter writes, hello, start/stop, watchdog and status are the Python ones; their
        effects land in the C struct through its members (gains through `pending_gains`, taken
        at the next Timer1 ISR as in the Python model). The lockstep period and the last seq
        live in the struct, behind `_period_tcy` and `_last_seq`.
        """

        backend = "c"

        def __init__(self, options: An1017Options = An1017Options(), *, reference: bool = False,
                     backend: str | None = None) -> None:
            super().__init__(options, reference=reference, backend=backend)
            self.step = self.fw.step  # type: ignore[method-assign]  # no Python frame per period

        @property
        def _period_tcy(self) -> int:  # type: ignore[override]
            return self.fw.period_tcy

        @_period_tcy.setter
        def _period_tcy(self, value: int) -> None:
            self.fw.period_tcy = value

        @property
        def _last_drive(self) -> Drive | None:  # type: ignore[override]
            return self.fw.last_drive

        @_last_drive.setter
        def _last_drive(self, value: Drive | None) -> None:
            if value is None:
                self.fw.last_drive = None  # the C step keeps the others itself

        @property
        def _last_seq(self) -> int:  # type: ignore[override]
            return self.fw.last_seq

        @_last_seq.setter
        def _last_seq(self, value: int) -> None:
            self.fw.last_seq = value

        def _finish(self, seq: int) -> Drive:
            return self.fw.finish(seq)

else:  # pragma: no cover
    _CFirmware = _CAn1017Target = None  # type: ignore[assignment,misc]


def constraint_name(number: int) -> str:
    """Human name of a gain constraint number (1, 2, 3)."""
    return GAIN_CONSTRAINT_NAMES[number]

