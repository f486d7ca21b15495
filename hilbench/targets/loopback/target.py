"""The loopback target: a documented, deterministic Sensors -> Drive mapping for end-to-end tests.

The same mapping is written in C (firmware_protocol/examples/loopback_core.c) and documented
in firmware_protocol/PROTOCOL.md, so a test can assert every field of every Drive exactly:

- duty_a/b/c = adc[0]/adc[1]/adc[2] (0 when the channel is absent);
- output PWM and state RUNNING after Start or a rising S2 input, else OFF and STOPPED (Stop or
  another rising S2 stops);
- sector from the hall bits C B A by AN1017 Table 8 (001->4, 010->2, 011->3, 100->0, 101->5,
  110->1, 000/111 -> 7 invalid); direction_ccw = S3 input; required_ccw False; fault 0;
- telemetry = (encoder as int16, the first edge's time (100 ns) as int16, -1 without one, seq).
Parameters: 0 "kp" Q15 RW [0, 32767] = 3277, 1 "ki" Q15 RW [0, 32767] = 328, 2 "version" INT
RO = 1; constraint 1: kp + ki <= 32767 (else CONSTRAINT, param_id 0, detail 1).
"""

from __future__ import annotations

from typing import Final, Mapping

from hilbench.targets.kit import ParamSpec, ParamTable, RepeatAnswer, served_mode
from hilbench.protocol import (
    ACCESS_RO,
    ACCESS_RW,
    ADC_IBUS,
    ADC_POT,
    ADC_VBUS,
    FAULT_NONE,
    FAULT_WATCHDOG,
    INPUT_S2,
    INPUT_S3,
    OUTPUT_OFF,
    OUTPUT_PWM,
    PROTOCOL_VERSION,
    SCHEMA_FINGERPRINT,
    PTYPE_INT,
    PTYPE_Q15,
    STATE_RUNNING,
    STATE_STOPPED,
    TELEMETRY_ECHO_EDGE,
    TELEMETRY_ECHO_ENCODER,
    TELEMETRY_ECHO_SEQ,
    Drive,
    ErrorCode,
    HostHello,
    ParamInfo,
    ParamSetResult,
    ParamValue,
    Sensors,
    Status,
    TargetHello,
    TargetInfo,
    TelemetryInfo,
)
from hilbench.protocol import DUTY_IMMEDIATE, INPUT_HALL_A, INPUT_HALL_B, INPUT_HALL_C, MAX_EDGES, REPORT_WRITTEN

FIRMWARE_NAME: Final = "loopback"
FIRMWARE_VERSION: Final = 1
PWM_PERIOD_COUNTS: Final = 1000
PWM_FREQ_HZ: Final = 20_000
ADC_ROLES: Final = (int(ADC_POT), int(ADC_IBUS), int(ADC_VBUS))
TELEMETRY_IDS: Final = (int(TELEMETRY_ECHO_ENCODER), int(TELEMETRY_ECHO_EDGE), int(TELEMETRY_ECHO_SEQ))

PARAM_KP: Final = 0
PARAM_KI: Final = 1
PARAM_VERSION: Final = 2
PARAM_SPECS: Final = (
    ParamSpec(PARAM_KP, "kp", int(PTYPE_Q15), int(ACCESS_RW), 0, 32767),
    ParamSpec(PARAM_KI, "ki", int(PTYPE_Q15), int(ACCESS_RW), 0, 32767),
    ParamSpec(PARAM_VERSION, "version", int(PTYPE_INT), int(ACCESS_RO), 1, 1),
)
DEFAULTS: Final = {PARAM_KP: 3277, PARAM_KI: 328, PARAM_VERSION: 1}
#: id: (name, ptype, access, min, max, default), the table above as plain tuples
PARAMS: Final = {spec.param_id: (spec.name, spec.ptype, spec.access, spec.min_value, spec.max_value,
                                 DEFAULTS[spec.param_id]) for spec in PARAM_SPECS}
CONSTRAINT_KP_PLUS_KI: Final = 1
MAX_SET_PAIRS: Final = 4

# AN1017 Table 8: hall bits C B A (bit2 C, bit1 B, bit0 A) -> sector, 7 = invalid
SECTOR_OF_HALLS: Final = (7, 4, 2, 3, 0, 5, 1, 7)


def _kp_plus_ki(values: Mapping[int, int], written: tuple[int, ...]) -> tuple[int, int] | None:
    """kp + ki <= 32767, named by kp (as PROTOCOL.md and the C target)."""
    return (PARAM_KP, CONSTRAINT_KP_PLUS_KI) if values[PARAM_KP] + values[PARAM_KI] > 32767 else None


def _int16(value: int) -> int:
    """A u16 read as two's complement int16."""
    value &= 0xFFFF
    return value - 0x10000 if value & 0x8000 else value


class LoopbackTarget:
    """Target with the documented loopback mapping; every output is a pure function of inputs."""

    firmware_name = FIRMWARE_NAME

    def __init__(self) -> None:
        self.values = dict(DEFAULTS)
        self.params = ParamTable(PARAM_SPECS, self.values.__getitem__, self._write, _kp_plus_ki)
        self.running = False
        self._s2_prev = False
        self.watchdog_trips = 0
        self.last_error = 0
        self._last_sensors: Sensors | None = None
        self._repeat = RepeatAnswer(self._map)  # a repeated seq (a duplicated frame) gets the last Drive
        self.step = self._repeat.step  # type: ignore[method-assign]

    def hello(self, host: HostHello) -> TargetHello:
        """A handshake starts a session stopped."""
        served_mode(host, "loopback")
        self.running = False
        self._repeat.forget()
        return TargetHello(host.seq, PROTOCOL_VERSION, SCHEMA_FINGERPRINT, FIRMWARE_VERSION, PWM_PERIOD_COUNTS,
                           PWM_FREQ_HZ, len(self.params), 10, FIRMWARE_NAME, ADC_ROLES, TELEMETRY_IDS)  # 10-bit ADC

    def describe_target(self) -> TargetInfo:
        """As the C loopback: duties at once and as written, halls and the buttons, no encoder."""
        return TargetInfo(0, DUTY_IMMEDIATE, REPORT_WRITTEN,
                          INPUT_HALL_A | INPUT_HALL_B | INPUT_HALL_C | INPUT_S2 | INPUT_S3, 0, MAX_EDGES)

    def describe_telemetry(self, index: int) -> TelemetryInfo | None:
        """The echoes as the C loopback names them: raw int16 values."""
        if not 0 <= index < len(TELEMETRY_IDS):
            return None
        name, unit = (("echo_encoder", "counts"), ("echo_edge", "100ns"), ("echo_seq", ""))[index]
        return TelemetryInfo(0, index, TELEMETRY_IDS[index], PTYPE_INT, 1, 1, name, unit)

    def describe(self, param_id: int) -> ParamInfo:
        return self.params.describe(param_id)

    def get_param(self, param_id: int) -> ParamValue:
        return self.params.get(param_id)

    def set_params(self, pairs: tuple[tuple[int, int], ...]) -> ParamSetResult:
        """All or nothing: every id, access and range first, then the kp + ki constraint (the kit's table)."""
        return self.params.set(pairs)

    def _write(self, values: dict[int, int], written: tuple[int, ...]) -> None:
        self.values.update(values)

    def start(self) -> None:
        self.running = True
        self._repeat.forget()

    def stop(self) -> None:
        self.running = False
        self._repeat.forget()

    def step(self, sensors: Sensors) -> Drive:
        """One period; a repeated seq (a duplicated frame) gets the last Drive, with no step."""
        return self._repeat.step(sensors)

    def _map(self, sensors: Sensors) -> Drive:
        inputs = sensors.inputs
        s2 = bool(inputs & INPUT_S2)
        if s2 and not self._s2_prev:
            self.running = not self.running
        self._s2_prev = s2
        self._last_sensors = sensors
        adc = sensors.adc
        n = len(adc)
        running = self.running
        return Drive(
            sensors.seq,
            adc[0] if n > 0 else 0,
            adc[1] if n > 1 else 0,
            adc[2] if n > 2 else 0,
            OUTPUT_PWM if running else OUTPUT_OFF,
            STATE_RUNNING if running else STATE_STOPPED,
            SECTOR_OF_HALLS[inputs & 7],
            bool(inputs & INPUT_S3),
            False,
            FAULT_NONE,
            (_int16(sensors.encoder), _int16(sensors.edges[0][0]) if sensors.edges else -1, sensors.seq),
        )

    def advance(self, duration_us: float, sensors: Sensors) -> Drive:
        """Real time: the mapping has no memory of time, so any span is one step."""
        return self.step(sensors)

    def watchdog_trip(self) -> Drive:
        """Outputs off, stopped, fault WATCHDOG; duties zero, sector invalid, telemetry zero."""
        self.running = False
        self._repeat.forget()
        self.watchdog_trips += 1
        self.last_error = int(ErrorCode.WATCHDOG)
        seq = self._last_sensors.seq if self._last_sensors is not None else 0
        return Drive(seq, 0, 0, 0, OUTPUT_OFF, STATE_STOPPED, 7, False, False, FAULT_WATCHDOG, (0, 0, seq))

    def status(self) -> Status:
        return Status(0, 0, 0, 0, 0, 0, self.watchdog_trips & 0xFFFF, self.last_error)
