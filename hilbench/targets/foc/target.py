"""`FocTarget`: the F2812 FOC firmware behind the Target interface (hilbench/targets/base.py).

Exchange timing (docs/foc.md "Exchange"): the agreed period is 50 µs, half a PWM period. The
exchange at an even half (k = 0, 2, …) is timer 1's underflow: the ISR runs on that exchange's
Sensors and writes new compare values, which the Event Manager loads at the period match 50 µs
later. So the Drive of an underflow half carries the compare values of the *previous* ISR and
the Drive of the following half the new ones; the plant integrates each half with its own
duties. A period of n·50 µs runs n halves and reports their mean duty (an approximation).

Duties are high-side on-times in T1 counts, 0..7500 (`pwm_period_counts` = 7500 = T1PR).
Encoder: Sensors.encoder is the 16-bit x4 count; T2 follows its differences. Index: bit
`INPUT_INDEX` of Sensors.inputs (protocol v2; 0x40 until then) says a pulse passed since the
last exchange; the CAP3 ISR then runs at the exchange.

Every protocol message this target builds is built in this module's `_hello`, `_drive` and
`_param_*` helpers, so the move to protocol v2 (u16 duties, IQ24 parameters, adc_bits, telemetry
ids) is a local edit.
"""

from __future__ import annotations

from typing import Any

from hilbench.errors import ConfigError
from hilbench.targets.kit import ParamSpec, ParamTable, RepeatAnswer, core_field, realtime_core_of, served_mode
from hilbench.protocol import (
    PROTOCOL_VERSION,
    Access,
    AdcRole,
    Drive,
    ErrorCode,
    HostHello,
    Input,
    ParamInfo,
    ParamSetResult,
    ParamType,
    ParamValue,
    Sensors,
    Status,
    TargetHello,
)
from hilbench.targets.foc import TELEMETRY_SPEC
from hilbench.targets.foc.firmware import (
    FAULT_WATCHDOG,
    HALF_PERIOD_US,
    STATE_ALIGN,
    STATE_FAULT,
    STATE_RUN,
    FocFirmware,
    FocOptions,
    firmware_config,
)
from hilbench.targets.foc.iqmath import iq_to_iq15
from hilbench.targets.foc.svpwm import T1PR

FIRMWARE_NAME = "F2812FOC"
FIRMWARE_VERSION = 0x0100
PWM_FREQ_HZ = 10_000
ADC_BITS = 12
#: the most half periods one exchange may span (C core: foc_run_halves sums T1 counts in 32 bits; 28.6 s)
HALVES_MAX = 572_662
INPUT_S2 = int(Input.S2)
INPUT_INDEX = int(getattr(Input, "INDEX", 0x40))  # protocol v2's bit; 0x40 is free in v1
PTYPE_INT, PTYPE_BOOL = int(ParamType.INT), int(ParamType.BOOL)
#: IQ24 parameters: ParamType.IQ24 in protocol v2 (value / 2^24); until then INT carrying the raw IQ24
PTYPE_IQ24 = int(getattr(ParamType, "IQ24", ParamType.INT))
ACCESS_RW = int(Access.RW)
OUTPUT_OFF, OUTPUT_PWM = 0, 1
ADC_ROLES = (int(AdcRole.IA), int(AdcRole.IB), int(AdcRole.VBUS))


if Drive._fields[1:4] != ("duty_a", "duty_b", "duty_c") or len(Drive._fields) != 11:
    # _drive and the C core build Drives positionally: a changed message must not go unnoticed
    raise ConfigError(f"foc: Drive fields changed to {Drive._fields}; update target.py and _core.c")


#: (key of FocFirmware.telemetry_q15, id) in Drive order; the table lives in the package's profile
TELEMETRY: tuple[tuple[str, int], ...] = tuple((key, tid) for key, tid, *_ in TELEMETRY_SPEC)
TELEMETRY_IDS = tuple(i for _, i in TELEMETRY)
TELEMETRY_KEYS = tuple(k for k, _ in TELEMETRY)

# declared parameters; IQ24 limits as raw values
_ONE = 1 << 24
PARAM_SPECS: tuple[ParamSpec, ...] = tuple(ParamSpec(pid, name, ptype, ACCESS_RW, lo, hi, unit) for pid, (name, ptype, lo, hi, unit) in enumerate((
    ("ref_rpm", PTYPE_INT, -3000, 3000, "rpm"),
    ("id_ref", PTYPE_IQ24, -_ONE // 2, _ONE // 2, "pu"),
    ("spd_kp", PTYPE_IQ24, 0, 8 * _ONE, ""),
    ("spd_ki", PTYPE_IQ24, 0, _ONE, ""),
    ("spd_kc", PTYPE_IQ24, 0, _ONE, ""),
    ("spd_out_max", PTYPE_IQ24, 0, _ONE, "pu"),
    ("id_kp", PTYPE_IQ24, 0, 8 * _ONE, ""),
    ("id_ki", PTYPE_IQ24, 0, _ONE, ""),
    ("id_kc", PTYPE_IQ24, 0, _ONE, ""),
    ("id_out_max", PTYPE_IQ24, 0, _ONE, "pu"),
    ("iq_kp", PTYPE_IQ24, 0, 8 * _ONE, ""),
    ("iq_ki", PTYPE_IQ24, 0, _ONE, ""),
    ("iq_kc", PTYPE_IQ24, 0, _ONE, ""),
    ("iq_out_max", PTYPE_IQ24, 0, _ONE, "pu"),
    ("torque_mode", PTYPE_BOOL, 0, 1, ""),  # 1: the speed loop is bypassed, i_q follows iq_ref_set
    ("iq_ref_set", PTYPE_IQ24, -_ONE, _ONE, "pu"),
)))
#: id -> (name, ptype, min, max), the table above as plain tuples
PARAMS: dict[int, tuple[str, int, int, int]] = {
    spec.param_id: (spec.name, spec.ptype, spec.min_value, spec.max_value) for spec in PARAM_SPECS
}
PARAM_IDS = {name: pid for pid, (name, *_rest) in PARAMS.items()}
_PID_FIELDS = {"kp": "kp", "ki": "ki", "kc": "kc"}


try:
    from hilbench.targets.foc import _core
except ImportError:  # pragma: no cover - built without a C compiler
    _core = None
else:
    _core.init(Drive, INPUT_INDEX)


def available_backends() -> tuple[str, ...]:
    """The firmware-model backends usable here ("c" only when the extension is built)."""
    return ("c", "python") if _core is not None else ("python",)


def _choose_backend(backend: str | None) -> str:
    """backend argument, else HILBENCH_FOC_BACKEND, else "c" when built."""
    import os

    choice = backend or os.environ.get("HILBENCH_FOC_BACKEND", "") or ("c" if _core is not None else "python")
    if choice not in ("c", "python"):
        raise ConfigError(f"foc backend {choice!r}: expected 'c' or 'python'")
    if choice == "c" and _core is None:
        raise ConfigError("foc backend 'c': hilbench.targets.foc._core is not built (pip install . with a C compiler)")
    return choice


class FocTarget:
    """F2812 FOC firmware as a Target: lockstep `step`, real-time `advance`, declared parameters.

    Two backends with identical Drives (tests/test_foc_core.py): "c" (`_core.c`, the firmware
    state in a C struct) and "python" (`FocFirmware`, the readable model). "c" is chosen when
    built unless HILBENCH_FOC_BACKEND=python or backend="python"; `target.backend` says which."""

    firmware_name = FIRMWARE_NAME
    backend = "python"

    def __new__(cls, options: FocOptions = FocOptions(), *, backend: str | None = None) -> "FocTarget":
        if cls is FocTarget and _choose_backend(backend) == "c":
            return object.__new__(_CFocTarget)
        return object.__new__(cls)

    def __init__(self, options: FocOptions = FocOptions(), *, backend: str | None = None) -> None:
        self.options = options
        self.fw = _CFirmware(options) if self.backend == "c" else FocFirmware(options)
        self.params = ParamTable(PARAM_SPECS, self._value, self._write, ok_names_last=True)
        self._repeat = RepeatAnswer(self._step_new)  # a repeated seq (a duplicated frame) gets the last Drive
        self.step = self._repeat.step  # type: ignore[method-assign]
        self.period_us = HALF_PERIOD_US
        self._halves = 1
        self._half = 0  # 0: the next half starts at an underflow (ISR), 1: at a period match
        self._frac_us = 0.0
        self._s2_last = False
        self._last_seq = 0
        self.mode = 0
        self.watchdog_ms = 0
        self.watchdog_trips = 0
        self.last_error = 0
        self.speed_ref_rpm = 0

    # ---- messages (the one place they are built) -----------------------------------------
    def _hello(self, host: Any) -> TargetHello:
        """By field name: protocol v2 adds schema_fingerprint and adc_bits (12 here)."""
        import hilbench.protocol as proto

        values = {
            "seq": host.seq, "protocol_version": PROTOCOL_VERSION, "firmware_version": FIRMWARE_VERSION,
            "pwm_period_counts": T1PR, "pwm_freq_hz": PWM_FREQ_HZ, "n_params": len(self.params),
            "firmware_name": FIRMWARE_NAME, "adc_roles": ADC_ROLES, "telemetry_ids": TELEMETRY_IDS,
            "adc_bits": ADC_BITS, "schema_fingerprint": getattr(proto, "SCHEMA_FINGERPRINT", 0),
        }
        return TargetHello(**{name: values[name] for name in TargetHello._fields})

    def _drive(self, seq: int, duties: tuple[int, int, int]) -> Drive:
        fw = self.fw
        tel = fw.telemetry_q15()
        state = fw.state
        return Drive(seq, duties[0], duties[1], duties[2], OUTPUT_PWM if fw.outputs_on else OUTPUT_OFF,
                     state, fw.sector & 7, fw.speed.speed < 0, fw.speed_ref < 0, fw.fault,
                     tuple(tel[k] for k in TELEMETRY_KEYS))

    # ---- handshake and parameters ------------------------------------------------------------
    def hello(self, host: HostHello) -> TargetHello:
        """Agree the period: a whole number of 50 µs half PWM periods (50 µs is the faithful one)."""
        period_us = int(host.period_us)
        if period_us <= 0 or period_us % HALF_PERIOD_US:
            raise ConfigError(f"foc hello: period_us {period_us} is not a positive multiple of {HALF_PERIOD_US}")
        mode = served_mode(host, "foc")
        self.period_us = period_us
        self._halves = period_us // HALF_PERIOD_US
        self.mode = mode
        self.watchdog_ms = int(host.watchdog_ms)
        self._repeat.forget()
        return self._hello(host)

    def _value(self, pid: int) -> int:
        name = PARAMS[pid][0]
        if name == "ref_rpm":
            return self.speed_ref_rpm
        if name == "id_ref":
            return self.fw.id_ref
        if name == "torque_mode":
            return int(self.fw.torque_mode)
        if name == "iq_ref_set":
            return self.fw.iq_ref_set
        loop, field = name.split("_", 1)
        return self.fw.gain(loop, field)

    def describe(self, param_id: int) -> ParamInfo:
        return self.params.describe(param_id)

    def get_param(self, param_id: int) -> ParamValue:
        return self.params.get(param_id)

    def set_params(self, pairs: tuple[tuple[int, int], ...]) -> ParamSetResult:
        """All or nothing: ids and ranges checked before any write (the kit's table). Limits are symmetric (±max)."""
        return self.params.set(pairs)

    def _write(self, values: dict[int, int], written: tuple[int, ...]) -> None:
        fw = self.fw
        for pid in written:
            name, value = PARAMS[pid][0], values[pid]
            if name == "ref_rpm":
                self.speed_ref_rpm = int(value)
                fw.set_speed_ref_rpm(int(value))
            elif name == "id_ref":
                fw.id_ref = int(value)
            elif name == "torque_mode":
                fw.torque_mode = bool(value)
            elif name == "iq_ref_set":
                fw.iq_ref_set = int(value)
            else:
                loop, field = name.split("_", 1)
                fw.set_gain(loop, field, int(value))

    # ---- run control -------------------------------------------------------------------------
    def start(self) -> None:
        self.fw.start()

    def stop(self) -> None:
        self.fw.stop()

    def _inputs(self, inputs: int) -> None:
        s2 = bool(inputs & INPUT_S2)
        if s2 and not self._s2_last:  # S2 toggles start/stop on its press
            if self.fw.state in (STATE_ALIGN, STATE_RUN):
                self.fw.stop()
            else:
                self.fw.start()
        self._s2_last = s2

    def _run_halves(self, n: int, sensors: Sensors) -> tuple[int, int, int]:
        """n half periods from now with these sensors; the mean high-side duty over them. A negative
        count (a span back in time) or one past HALVES_MAX is refused, as the C core refuses it."""
        if not 0 <= n <= HALVES_MAX:
            raise ValueError(f"foc: {n} half periods in one exchange (0..{HALVES_MAX})")
        adc = sensors.adc
        if (n > 1 or (n == 1 and self._half == 0)) and len(adc) < 3:  # an underflow in the span reads them
            raise ValueError("foc: Sensors.adc must hold (ia, ib, vbus)")  # (before the encoder: as the C core)
        fw = self.fw
        fw.encoder(sensors.encoder, bool(sensors.inputs & INPUT_INDEX))
        sa = sb = sc = 0
        for _ in range(n):
            if self._half == 0:
                fw.underflow(adc[0], adc[1], adc[2])
                self._half = 1
            else:
                fw.period_match()
                self._half = 0
            if fw.outputs_on:
                c1, c2, c3 = fw.compare_active
                sa += T1PR - c1 if c1 < T1PR else 0
                sb += T1PR - c2 if c2 < T1PR else 0
                sc += T1PR - c3 if c3 < T1PR else 0
        if n == 1:
            return sa, sb, sc
        return (round(sa / n), round(sb / n), round(sc / n)) if n else (0, 0, 0)

    def step(self, sensors: Sensors) -> Drive:
        """Lockstep: the agreed period (see the module doc for the halves and their duties); a
        repeated seq (a duplicated frame) gets the last Drive, with no step (the kit's RepeatAnswer)."""
        return self._repeat.step(sensors)

    def _step_new(self, sensors: Sensors) -> Drive:
        self._last_seq = sensors.seq
        self._inputs(sensors.inputs)
        return self._drive(sensors.seq, self._run_halves(self._halves, sensors))

    def advance(self, duration_us: float, sensors: Sensors) -> Drive:
        """Real time: whole half periods of `duration_us` (the remainder carries over)."""
        total = duration_us + self._frac_us
        n = int(total // HALF_PERIOD_US)
        self._frac_us = total - n * HALF_PERIOD_US
        self._last_seq = sensors.seq
        self._inputs(sensors.inputs)
        duties = self._run_halves(n, sensors) if n else self._active_duties()
        return self._drive(sensors.seq, duties)

    def _active_duties(self) -> tuple[int, int, int]:
        if not self.fw.outputs_on:
            return (0, 0, 0)
        return tuple(T1PR - c if c < T1PR else 0 for c in self.fw.compare_active)  # type: ignore[return-value]

    def watchdog_trip(self) -> Drive:
        self.watchdog_trips += 1
        self._repeat.forget()
        self.last_error = int(ErrorCode.WATCHDOG)
        self.fw.stop(STATE_FAULT, FAULT_WATCHDOG)
        return self._drive(self._last_seq, (0, 0, 0))

    def status(self) -> Status:
        return Status(0, 0, 0, 0, 0, 0, self.watchdog_trips & 0xFFFF, self.last_error)

    @property
    def time_us(self) -> float:
        return self.fw.isr_count * 2 * HALF_PERIOD_US


if _core is not None:

    class _View:
        """Read-only attributes of a C firmware's block, under the Python block's names."""

        def __init__(self, fw: Any, prefix: str) -> None:
            object.__setattr__(self, "_fw", fw)
            object.__setattr__(self, "_prefix", prefix)

        def __getattr__(self, name: str) -> Any:
            return getattr(self._fw, self._prefix + name)

    class _CFirmware(_core.Core):  # type: ignore[misc,name-defined]
        """The firmware's foc_t (firmware/foc) behind FocFirmware's interface: built from the same
        integers the Python model computes (`firmware_config`); the blocks' fields are flat
        members (`spd_kp`, `qep_t2cnt`, `sp_speed`)."""

        def __init__(self, options: FocOptions) -> None:
            super().__init__(**firmware_config(options))
            self.options = options

        def gain(self, loop: str, field: str) -> int:
            return getattr(self, f"{loop}_{field}")

        def set_gain(self, loop: str, field: str, value: int) -> None:
            setattr(self, f"{loop}_{field}", int(value))
            if field == "out_max":
                setattr(self, f"{loop}_out_min", -int(value))

        outputs_on = property(lambda self: bool(self._outputs_on))
        index_learned = property(lambda self: bool(self._index_learned))
        torque_mode = property(lambda self: bool(self._torque_mode),
                               lambda self, v: setattr(self, "_torque_mode", int(bool(v))))
        compare_active = property(lambda self: (self.ca1, self.ca2, self.ca3))
        compare_shadow = property(lambda self: (self.cs1, self.cs2, self.cs3))
        qep = property(lambda self: _View(self, "qep_"))
        speed = property(lambda self: _View(self, "sp_"))

    class _CoreRepeat(RepeatAnswer):
        """The kit's answer to a repeated seq as the C step keeps it (the core's last_drive, as the AN1017
        core does): forget() clears it there."""

        __slots__ = ("core",)

        def __init__(self, core: Any) -> None:
            super().__init__(core.step)
            self.core = core

        def step(self, sensors: Sensors) -> Drive:
            return self.core.step(sensors)  # type: ignore[no-any-return]

        def forget(self) -> None:
            self.core.last_drive = None

    class _CFocTarget(FocTarget):
        """FocTarget on the compiled firmware: `step` is the C method of `fw` itself; the half
        period, S2 level and last seq live in the struct."""

        backend = "c"

        def __init__(self, options: FocOptions = FocOptions(), *, backend: str | None = None) -> None:
            super().__init__(options, backend=backend)
            self._repeat = _CoreRepeat(self.fw)  # the C step answers a repeat itself (its last_drive)
            self.step = self.fw.step  # type: ignore[method-assign]  # no Python frame per exchange

        def span_core(self) -> tuple[Any, Any]:
            """The C step the session's C span runs: (hbglue.h's target capsule, the core whose
            `step` it stands for)."""
            return _core.SPAN_API, self.fw

        def hello(self, host: HostHello) -> TargetHello:
            out = super().hello(host)
            self.fw.halves = self._halves
            return out

        _last_seq = core_field("last_seq")

        _frac_us = core_field("frac_us")

        def realtime_core(self) -> tuple[Any, Any] | None:
            """The core's C advance (`fw.advance`, this class's `advance` in C) for real time's serve loop."""
            return realtime_core_of(self, _CFocTarget.advance, _core.SPAN_API)

        def advance(self, duration_us: float, sensors: Sensors) -> Drive:
            total = duration_us + self._frac_us
            n = int(total // HALF_PERIOD_US)
            self._frac_us = total - n * HALF_PERIOD_US
            self.fw.last_seq = sensors.seq
            self.fw.inputs(sensors.inputs)
            duties = self.fw.run_halves(n, sensors) if n else self.fw.active_duties()
            return self.fw.drive(sensors.seq, *duties)

        def watchdog_trip(self) -> Drive:
            self.watchdog_trips += 1
            self._repeat.forget()
            self.last_error = int(ErrorCode.WATCHDOG)
            self.fw.stop(STATE_FAULT, FAULT_WATCHDOG)
            return self.fw.drive(self.fw.last_seq, 0, 0, 0)

else:  # pragma: no cover
    _CFirmware = _CFocTarget = None  # type: ignore[assignment,misc]


def make_foc_target(**options: Any) -> FocTarget:
    """The factory `make_target("foc", ...)` uses: FocOptions fields by name (ConfigError otherwise)."""
    import dataclasses

    backend = options.pop("backend", None)
    known = {f.name for f in dataclasses.fields(FocOptions)}
    unknown = sorted(set(options) - known)
    if unknown:
        raise ConfigError(f"target foc: unknown option {unknown[0]!r} (known: {', '.join(sorted(known))})")
    return FocTarget(FocOptions(**options), backend=backend)


__all__ = ["FocTarget", "make_foc_target", "available_backends", "FIRMWARE_NAME", "PARAMS", "PARAM_IDS", "TELEMETRY",
           "INPUT_INDEX", "ADC_BITS", "iq_to_iq15"]
