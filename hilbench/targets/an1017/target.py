"""The AN1017 firmware model behind the Target interface (docs/design.md, hilbench/targets/base.py).

The firmware itself lives in `hilbench.targets.an1017.firmware` (plain ints, Tcy time); this module translates
protocol messages to its inputs and its state to Drive, and owns the declared parameter table.

Drive semantics (the timing contract, docs/design.md "Timing"): `duty_a..c` are the duty
registers the PWM ISR wrote during the step's span, i.e. what PDC1..3 hold for the next PWM
period (PWMCON2.IUE = 0 latches them at the next boundary). The plant applies them in that next
period, so the chip's one-period register latency is there once and no more. PDC values above 1000
(only produced by the firmware's volts = −1 start-up transient in CCW) mean 100 % and are
reported as 1000.

Two backends with identical outputs: "python", the readable reference (An1017Firmware, every ISR
as the firmware runs it), and "c", its one accelerator: the board firmware firmware/an1017/an1017.c
compiled into this process behind a thin glue (hilbench/targets/an1017/_core.c, an optional
extension; its state is exposed under An1017Firmware's attribute names); tests/test_an1017_core.py
compares every Drive of the two.
"c" is chosen when the extension is built unless HILBENCH_AN1017_BACKEND=python (or
backend="python") asks otherwise; `reference=True` means the Python reference (it cannot be
combined with backend="c"). `target.backend` says which one runs.
"""

from __future__ import annotations

import os
from typing import Any, Mapping

from hilbench.errors import ConfigError, ParamError
from hilbench.targets.kit import ParamSpec, ParamTable, RepeatAnswer, core_field, realtime_core_of, served_mode
from hilbench.targets.an1017.firmware import (
    GAIN_CONSTRAINT_NAMES,
    STATE_FAULT,
    FAULT_WATCHDOG,
    SECTOR_INVALID,
    SECTOR_TABLE,
    TCY_PER_US,
    An1017Firmware,
    An1017Options,
    build_periods,
    check_gain_constraints,
    max_phase_advance_from_deg,
)

from hilbench.protocol import (
    PROTOCOL_VERSION,
    SCHEMA_FINGERPRINT,
    Access,
    AdcRole,
    Drive,
    ErrorCode,
    HostHello,
    ParamInfo,
    ParamSetResult,
    ParamType,
    ParamValue,
    Result,
    Sensors,
    Status,
    TargetHello,
    TargetInfo,
    TelemetryId,
    TelemetryInfo,
)
from hilbench.protocol import DUTY_NEXT_PERIOD, INPUT_FAULT, INPUT_HALL_A, INPUT_HALL_B, INPUT_HALL_C, INPUT_S2, MAX_EDGES, REPORT_WRITTEN
from hilbench.targets.an1017.firmware import PERIOD_X_RPM_X_POLE_PAIRS

# plain ints of the protocol constants (IntEnum members are slower in the per-period path)
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
_tuple_new = tuple.__new__  # Drive is a NamedTuple: this skips its Python-level __new__ (~3x cheaper)
if Drive._fields[1:4] != ("duty_a", "duty_b", "duty_c") or len(Drive._fields) != 11:
    # _finish builds Drives from positional tuples: a changed message must not go unnoticed
    raise ConfigError(f"an1017: Drive fields changed to {Drive._fields}; update the tuple layout in an1017.py")
if Sensors._fields != ("seq", "inputs", "edges", "encoder", "adc"):
    raise ConfigError(f"an1017: Sensors fields changed to {Sensors._fields}; update the unpacking in step()")



def edges_tcy(edges: Any) -> "tuple[tuple[int, int], ...] | None":
    """Sensors.edges (time in 100 ns, lines) as the firmware's (offset in Tcy, hall bits); None for none."""
    return tuple((t << 1, lines) for t, lines in edges) if edges else None


# declared parameters (the board firmware's table, firmware/an1017)
PARAM_KP, PARAM_KI, PARAM_KD = 0, 1, 2
PARAM_PH_ADV_ON, PARAM_PH_ADV_DEG = 3, 4
PARAM_REF_OVR_ON, PARAM_REF_OVR = 5, 6
PARAM_STALL_MS = 7
PARAM_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(PARAM_KP, "kp", PTYPE_Q15, ACCESS_RW, 0, 32767),
    ParamSpec(PARAM_KI, "ki", PTYPE_Q15, ACCESS_RW, 0, 32767),
    ParamSpec(PARAM_KD, "kd", PTYPE_Q15, ACCESS_RW, 0, 32767),
    ParamSpec(PARAM_PH_ADV_ON, "ph_adv_on", PTYPE_BOOL, ACCESS_RW, 0, 1),
    ParamSpec(PARAM_PH_ADV_DEG, "ph_adv_deg", PTYPE_INT, ACCESS_RW, 0, 60, "deg"),
    ParamSpec(PARAM_REF_OVR_ON, "ref_ovr_on", PTYPE_BOOL, ACCESS_RW, 0, 1),
    ParamSpec(PARAM_REF_OVR, "ref_override", PTYPE_Q15, ACCESS_RW, -32768, 32767),
    ParamSpec(PARAM_STALL_MS, "stall_ms", PTYPE_INT, ACCESS_RW, 10, 30000, "ms"),
)
#: id → (name, ptype, access, min, max), the table above as plain tuples
PARAMS: dict[int, tuple[str, int, int, int, int]] = {
    spec.param_id: (spec.name, spec.ptype, spec.access, spec.min_value, spec.max_value) for spec in PARAM_SPECS
}
GAIN_PARAMS = (PARAM_KP, PARAM_KI, PARAM_KD)
#: the gains each of the application note's constraints involves (the written one is named)
CONSTRAINT_GAINS = {1: (PARAM_KP, PARAM_KI, PARAM_KD), 2: (PARAM_KP, PARAM_KD), 3: (PARAM_KD,)}
#: the firmware's self-description (an1017.c's hrt_firmware; tests/test_firmware_sil.py compares them)
INPUTS_READ = INPUT_HALL_A | INPUT_HALL_B | INPUT_HALL_C | INPUT_S2 | INPUT_FAULT
TELEMETRY_DECL = (("ref_speed", "rpm"), ("measured_speed", "rpm"), ("control_output", "q15"))

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
    _an1017core.init(Drive)


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


class An1017Target:
    """AN1017 firmware as a Target: lockstep `step`, real-time `advance`, declared parameters.

    `fw` is up to date after every call and may be read freely; change it through these methods.
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
        self.fw = _c_firmware(self.options) if self.backend == "c" else An1017Firmware(options)
        self.params = ParamTable(PARAM_SPECS, self._value, self._write, self._constraint, ok_names_last=True)  # as the board's bridge
        self.period_us = PWM_PERIOD_US
        self._period_tcy = PWM_PERIOD_US * TCY_PER_US
        self.mode = 0
        self.watchdog_ms = 0
        self._last_seq = 0
        self._repeat = RepeatAnswer(self._step_new)  # a repeated seq is answered with the last Drive, no step
        self.step = self._repeat.step  # type: ignore[method-assign]
        self._frac_tcy = 0.0
        self.watchdog_trips = 0
        self.last_error = 0

    # ---- handshake and parameters ------------------------------------------------------------
    def hello(self, host: HostHello) -> TargetHello:
        """Agree the period (a whole number of 50 µs PWM periods) and the mode."""
        period_us = int(host.period_us)
        if period_us <= 0 or period_us % PWM_PERIOD_US:
            raise ConfigError(f"an1017 hello: period_us {period_us} is not a positive multiple of {PWM_PERIOD_US}")
        mode = served_mode(host, "an1017")
        self.period_us = period_us
        self._period_tcy = period_us * TCY_PER_US
        self._forget_repeat()
        self.mode = mode
        self.watchdog_ms = int(host.watchdog_ms)
        return TargetHello(
            host.seq,
            PROTOCOL_VERSION,
            SCHEMA_FINGERPRINT,
            FIRMWARE_VERSION,
            PWM_PERIOD_COUNTS,
            PWM_FREQ_HZ,
            len(self.params),
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
        return self.params.describe(param_id)

    def describe_target(self) -> TargetInfo:
        """The PWM's reload at the next period (PWMCON2.IUE = 0), the Drive's duties as written, the
        halls, S2 and FLTA read, no encoder; any number of edges in process."""
        return TargetInfo(0, DUTY_NEXT_PERIOD, REPORT_WRITTEN, INPUTS_READ, 0, MAX_EDGES)

    def describe_telemetry(self, index: int) -> TelemetryInfo | None:
        """Slot ``index`` of Drive.telemetry: the speeds in rpm (one Q15 step is 9 375 000 / (pole pairs
        x (MINPERIOD - 1) x 32768) rpm for this build), the PID's output as Q15."""
        if not 0 <= index < len(TELEMETRY_DECL):
            return None
        name, unit = TELEMETRY_DECL[index]
        if unit == "rpm":
            min_period, _ = build_periods(self.options.pole_pairs, self.options.max_speed_rpm)
            num, den = PERIOD_X_RPM_X_POLE_PAIRS, self.options.pole_pairs * (min_period - 1) * 32768
        else:
            num, den = 1, 1
        return TelemetryInfo(0, index, TELEMETRY_IDS[index], PTYPE_Q15, num, den, name, unit)

    def get_param(self, param_id: int) -> ParamValue:
        """Read one parameter; result UNKNOWN_ID for an undeclared id."""
        return self.params.get(param_id)

    def set_params(self, pairs: tuple[tuple[int, int], ...]) -> ParamSetResult:
        """All or nothing (the kit's table): ids, ranges and the application note's gain constraints
        are checked before any write."""
        return self.params.set(pairs)

    def _constraint(self, values: Mapping[int, int], written: tuple[int, ...]) -> tuple[int, int] | None:
        """The note's gain constraints, when a gain is written: (the written gain the broken one
        involves, its number)."""
        gains_touched = [pid for pid in written if pid in GAIN_PARAMS]
        if not gains_touched:
            return None
        broken = self._check_gains(values[PARAM_KP], values[PARAM_KI], values[PARAM_KD])
        if broken is None:
            return None
        offender = next((p for p in gains_touched if p in CONSTRAINT_GAINS[broken]), gains_touched[0])
        return offender, broken

    def _write(self, values: dict[int, int], written: tuple[int, ...]) -> None:
        self._apply_params(values, any(pid in GAIN_PARAMS for pid in written))

    _check_gains = staticmethod(check_gain_constraints)

    def _apply_params(self, new: dict[int, int], gains_touched: bool) -> None:
        """Write a checked, complete set of declared values (the gains only when written)."""
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

    # ---- run control -------------------------------------------------------------------------
    def start(self) -> None:
        """S2 as a command: start (ChargeBootstraps, then RunMotor) when stopped."""
        self.fw.press_start()

    def stop(self) -> None:
        """StopMotor(): all six switches off, motor coasts (also aborts a bootstrap)."""
        if self.fw.running or self.fw.booting:
            self.fw.press_stop()

    # ---- the per-period path ------------------------------------------------------------------
    def _finish(self, seq: int) -> Drive:
        """The Drive of the firmware's state now: the duty registers the PWM ISR wrote during the
        span (PDC values above 1000 reported as 1000), then mode … telemetry."""
        fw = self.fw
        a, b, c = fw.pend_duty
        if a > 1000 or b > 1000 or c > 1000:
            a, b, c = min(a, 1000), min(b, 1000), min(c, 1000)
        s = fw.sector if fw.running else SECTOR_TABLE[fw.hall] & 0xFFFF
        return _tuple_new(Drive, (
            seq, a, b, c, fw.output_mode, fw.state, 7 if s == SECTOR_INVALID else s, fw.cur_ccw, fw.req_ccw,
            fw.fault, (fw.ref_speed, fw.measured_speed, fw.control_output),
        ))

    def step(self, sensors: Sensors) -> Drive:
        """Lockstep: exactly one agreed period with these sensors (An1017Firmware.run, then the
        Drive). A Sensors repeating the last one's seq (a duplicated frame) gets the last Drive
        again and the firmware does not step (the kit's `RepeatAnswer`), as a board answers it."""
        return self._repeat.step(sensors)

    def _step_new(self, sensors: Sensors) -> Drive:
        """One new period (not a repeat)."""
        seq, inputs, edges, _, adc = sensors
        self._last_seq = seq
        self.fw.run(self._period_tcy, inputs, edges_tcy(edges) if edges else None, adc[0] if adc else None)
        return self._finish(seq)

    def _forget_repeat(self) -> None:
        self._repeat.forget()

    def advance(self, duration_us: float, sensors: Sensors) -> Drive:
        """Real time: any span of wall time (sub-Tcy remainders carry over)."""
        total = duration_us * TCY_PER_US + self._frac_tcy
        tcy = int(total)
        self._frac_tcy = total - tcy
        adc = sensors.adc
        if tcy > 0:
            self.fw.run(tcy, sensors.inputs, edges_tcy(sensors.edges), adc[0] if adc else None)
        self._last_seq = sensors.seq
        return self._finish(sensors.seq)

    def watchdog_trip(self) -> Drive:
        """Sensors stopped arriving: StopMotor, state FAULT, fault WATCHDOG."""
        self.watchdog_trips += 1
        self._forget_repeat()
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

    def _c_firmware(options: An1017Options) -> Any:
        """The board firmware firmware/an1017/an1017.c in this process (`_an1017core.Core`), built
        for these (resolved) options. Its members carry An1017Firmware's attribute names."""
        min_period, max_period = build_periods(options.pole_pairs, options.max_speed_rpm)
        return _an1017core.Core(
            variant_v11=options.variant == "v11",
            adc_every=bool(options.adc_every_pwm_period),
            c1_textbook=bool(options.pid_c1_textbook),
            phase_advance=bool(options.phase_advance),
            stall_limit=int(options.stall_timeout_ms or 100),
            phase_offset=options.phase_offset_ccw,
            max_ph_adv_deg=options.max_phase_advance_deg,
            min_period=min_period,
            max_period=max_period,
        )

    class _CAn1017Target(An1017Target):
        """An1017Target on the board firmware's C core: `step` is the C method of `fw` itself.

        Parameters go through the firmware's own an1017_param_value / an1017_check_gains /
        an1017_apply_params; hello, start/stop, watchdog and status are the Python ones. The
        lockstep period, the last seq and its Drive and real time's carried Tcy fraction live in the
        core, behind `_period_tcy`, `_last_seq` and `_frac_tcy` (the core answers a repeated seq with
        its last Drive itself).
        """

        backend = "c"

        def __init__(self, options: An1017Options = An1017Options(), *, reference: bool = False,
                     backend: str | None = None) -> None:
            super().__init__(options, reference=reference, backend=backend)
            self.step = self.fw.step  # type: ignore[method-assign]  # no Python frame per period; it answers repeats itself

        def span_core(self) -> tuple[Any, Any]:
            """The C step the session's C span runs: (hbglue.h's target capsule, the core whose
            `step` it stands for)."""
            return _an1017core.SPAN_API, self.fw

        def _value(self, param_id: int) -> int:
            if param_id not in PARAMS:
                raise ParamError(f"an1017 param {param_id}: unknown id")
            return self.fw.param_value(param_id)

        _check_gains = staticmethod(_an1017core.check_gains)

        def _apply_params(self, new: dict[int, int], gains_touched: bool) -> None:
            self.fw.apply_params(tuple(new[pid] for pid in sorted(PARAMS)), gains_touched)

        _period_tcy = core_field("period_tcy")

        def _forget_repeat(self) -> None:
            self.fw.last_drive = None  # the C step keeps its last Drive itself (firmware/an1017 glue)

        _last_seq = core_field("last_seq")

        def _finish(self, seq: int) -> Drive:
            return self.fw.finish(seq)

        _frac_tcy = core_field("frac_tcy")

        def realtime_core(self) -> tuple[Any, Any] | None:
            """The core's C advance (`fw.advance`, An1017Target.advance in C) for real time's serve loop."""
            return realtime_core_of(self, An1017Target.advance, _an1017core.SPAN_API)

else:  # pragma: no cover
    _c_firmware = _CAn1017Target = None  # type: ignore[assignment,misc]


def constraint_name(number: int) -> str:
    """Human name of a gain constraint number (1, 2, 3)."""
    return GAIN_CONSTRAINT_NAMES[number]

