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

from typing import Final

from hilbench.errors import ParamError
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
    RESULT_BAD_REQUEST,
    RESULT_CONSTRAINT,
    RESULT_OK,
    RESULT_OUT_OF_RANGE,
    RESULT_READ_ONLY,
    RESULT_UNKNOWN_ID,
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
# id: (name, ptype, access, min, max, default)
PARAMS: Final = {
    PARAM_KP: ("kp", int(PTYPE_Q15), int(ACCESS_RW), 0, 32767, 3277),
    PARAM_KI: ("ki", int(PTYPE_Q15), int(ACCESS_RW), 0, 32767, 328),
    PARAM_VERSION: ("version", int(PTYPE_INT), int(ACCESS_RO), 1, 1, 1),
}
CONSTRAINT_KP_PLUS_KI: Final = 1
MAX_SET_PAIRS: Final = 4

# AN1017 Table 8: hall bits C B A (bit2 C, bit1 B, bit0 A) -> sector, 7 = invalid
SECTOR_OF_HALLS: Final = (7, 4, 2, 3, 0, 5, 1, 7)


def _int16(value: int) -> int:
    """A u16 read as two's complement int16."""
    value &= 0xFFFF
    return value - 0x10000 if value & 0x8000 else value


class LoopbackTarget:
    """Target with the documented loopback mapping; every output is a pure function of inputs."""

    firmware_name = FIRMWARE_NAME

    def __init__(self) -> None:
        self.values = {pid: spec[5] for pid, spec in PARAMS.items()}
        self.running = False
        self._s2_prev = False
        self.watchdog_trips = 0
        self.last_error = 0
        self._last_sensors: Sensors | None = None
        self._last_drive: Drive | None = None

    def hello(self, host: HostHello) -> TargetHello:
        """A handshake starts a session stopped."""
        self.running = False
        self._last_drive = None
        return TargetHello(host.seq, PROTOCOL_VERSION, SCHEMA_FINGERPRINT, FIRMWARE_VERSION, PWM_PERIOD_COUNTS,
                           PWM_FREQ_HZ, len(PARAMS), 10, FIRMWARE_NAME, ADC_ROLES, TELEMETRY_IDS)  # 10-bit ADC

    def describe_target(self) -> TargetInfo:
        """As the C loopback: duties at once and as written, halls and the buttons, no encoder."""
        return TargetInfo(0, DUTY_IMMEDIATE, REPORT_WRITTEN,
                          INPUT_HALL_A | INPUT_HALL_B | INPUT_HALL_C | INPUT_S2 | INPUT_S3, 0, MAX_EDGES)

    def describe(self, param_id: int) -> ParamInfo:
        spec = PARAMS.get(param_id)
        if spec is None:
            raise ParamError(f"loopback describe: unknown param id {param_id}")
        name, ptype, access, lo, hi, _ = spec
        return ParamInfo(0, param_id, ptype, access, lo, hi, self.values[param_id], name)

    def get_param(self, param_id: int) -> ParamValue:
        if param_id not in PARAMS:
            return ParamValue(0, param_id, RESULT_UNKNOWN_ID, 0)
        return ParamValue(0, param_id, RESULT_OK, self.values[param_id])

    def set_params(self, pairs: tuple[tuple[int, int], ...]) -> ParamSetResult:
        """All or nothing: every id, access and range first, then the kp + ki constraint."""
        if not pairs or len(pairs) > MAX_SET_PAIRS:
            return ParamSetResult(0, RESULT_BAD_REQUEST, 0, 0)
        new = dict(self.values)
        for pid, value in pairs:
            spec = PARAMS.get(pid)
            if spec is None:
                return ParamSetResult(0, RESULT_UNKNOWN_ID, pid, 0)
            _, _, access, lo, hi, _ = spec
            if access != ACCESS_RW:
                return ParamSetResult(0, RESULT_READ_ONLY, pid, 0)
            if not lo <= value <= hi:
                return ParamSetResult(0, RESULT_OUT_OF_RANGE, pid, 0)
            new[pid] = value
        if new[PARAM_KP] + new[PARAM_KI] > 32767:
            return ParamSetResult(0, RESULT_CONSTRAINT, PARAM_KP, CONSTRAINT_KP_PLUS_KI)  # as PROTOCOL.md and the C target
        self.values = new
        return ParamSetResult(0, RESULT_OK, 0, 0)

    def start(self) -> None:
        self.running = True
        self._last_drive = None

    def stop(self) -> None:
        self.running = False
        self._last_drive = None

    def step(self, sensors: Sensors) -> Drive:
        """One period; a repeated seq (a duplicated frame) gets the last Drive, with no step."""
        last = self._last_drive
        if last is not None and sensors.seq == last.seq:
            return last
        self._last_drive = drive = self._map(sensors)
        return drive

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
        self._last_drive = None
        self.watchdog_trips += 1
        self.last_error = int(ErrorCode.WATCHDOG)
        seq = self._last_sensors.seq if self._last_sensors is not None else 0
        return Drive(seq, 0, 0, 0, OUTPUT_OFF, STATE_STOPPED, 7, False, False, FAULT_WATCHDOG, (0, 0, seq))

    def status(self) -> Status:
        return Status(0, 0, 0, 0, 0, 0, self.watchdog_trips & 0xFFFF, self.last_error)
