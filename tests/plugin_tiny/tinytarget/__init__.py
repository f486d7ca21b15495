"""A tiny open-loop V/f drive as a hilbench target, packaged the way an outside package would be.

It is found only through its ``hilbench.targets`` entry point (tests/plugin_tiny on PYTHONPATH
holds the module and its dist-info), and it uses only hilbench's public names: a profile, a
Target-shaped class speaking the protocol's messages. Its reference is a parameter (no pot), and
it reports two target-defined telemetry ids (0x80 electrical angle, 0x81 modulation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from hilbench.fieldspec import spec
from hilbench.protocol import (
    PROTOCOL_VERSION,
    SCHEMA_FINGERPRINT,
    Drive,
    ParamInfo,
    ParamSetResult,
    ParamValue,
    Sensors,
    Status,
    TargetHello,
    TelemetryId,
)
from hilbench.targets import ParamReference, TargetProfile, TelemetryColumn

TELEMETRY_ANGLE = 0x80
TELEMETRY_MODULATION = 0x81
PWM_COUNTS = 1000
# id -> (name, ptype INT, access RW, min, max, default)
PARAMS = {
    0: ("speed_ref", 1, 1, -6000, 6000, 0),
    1: ("v_per_krpm", 1, 1, 0, 100, 36),  # % of full modulation per 1000 rpm
    2: ("accel_rpm_s", 1, 1, 1, 20000, 4000),
}


@dataclass(frozen=True)
class TinyOptions:
    """[target] for tiny: the motor it drives and its voltage boost."""

    pole_pairs: int = field(default=5, metadata=spec(ge=1, le=64, doc="motor pole pairs"))
    boost_pct: float = field(default=4.0, metadata=spec(ge=0, le=50, doc="modulation at zero speed, %"))


class TinyTarget:
    """A rotating voltage vector at the (rate-limited) reference frequency, amplitude ∝ speed."""

    firmware_name = "TINY"

    def __init__(self, options: TinyOptions) -> None:
        self.options = options
        self.values = {pid: p[5] for pid, p in PARAMS.items()}
        self.running = False
        self.speed_rpm = 0.0
        self.theta = 0.0
        self.period_s = 50e-6
        self.last_seq = -1
        self.last_drive: Drive | None = None

    def hello(self, host: object) -> TargetHello:
        self.period_s = getattr(host, "period_us") * 1e-6
        return TargetHello(getattr(host, "seq"), PROTOCOL_VERSION, SCHEMA_FINGERPRINT, 1, PWM_COUNTS, 20000,
                           len(PARAMS), 10, "TINY", (),
                           (int(TelemetryId.REF_SPEED), TELEMETRY_ANGLE, TELEMETRY_MODULATION))

    def describe(self, param_id: int) -> ParamInfo:
        name, ptype, access, lo, hi, _ = PARAMS[param_id]
        return ParamInfo(0, param_id, ptype, access, lo, hi, self.values[param_id], name)

    def get_param(self, param_id: int) -> ParamValue:
        return ParamValue(0, param_id, 0 if param_id in PARAMS else 1, self.values.get(param_id, 0))

    def set_params(self, pairs: tuple[tuple[int, int], ...]) -> ParamSetResult:
        for pid, value in pairs:
            if pid not in PARAMS:
                return ParamSetResult(0, 1, pid, 0)
            if not PARAMS[pid][3] <= value <= PARAMS[pid][4]:
                return ParamSetResult(0, 3, pid, 0)
        for pid, value in pairs:
            self.values[pid] = value
        return ParamSetResult(0, 0, pairs[-1][0], 0)

    def start(self) -> None:
        self.running = True

    def stop(self) -> None:
        self.running = False

    def step(self, sensors: Sensors) -> Drive:
        if sensors.seq == self.last_seq and self.last_drive is not None:
            return self.last_drive  # a repeated frame is answered, not acted on twice
        if sensors.inputs & 0x08 and not getattr(self, "_s2", False):
            self.running = not self.running
        self._s2 = bool(sensors.inputs & 0x08)
        ref = float(self.values[0]) if self.running else 0.0
        limit = self.values[2] * self.period_s
        self.speed_rpm += max(-limit, min(limit, ref - self.speed_rpm))
        w_e = self.speed_rpm / 60.0 * 2.0 * math.pi * self.options.pole_pairs
        self.theta = (self.theta + w_e * self.period_s) % (2.0 * math.pi)
        m = min(1.0, (self.options.boost_pct + self.values[1] * abs(self.speed_rpm) / 1000.0) / 100.0)
        lead = math.pi / 2 if self.speed_rpm >= 0 else -math.pi / 2  # the voltage leads the rotor by ~90°
        duties = [round(PWM_COUNTS / 2 * (1 + m * math.cos(self.theta + lead - k * 2 * math.pi / 3))) for k in range(3)]
        mode = 1 if self.running else 0
        telemetry = (round(self.speed_rpm), round(math.degrees(self.theta) * 10), round(m * 1000))
        drive = Drive(sensors.seq, *duties, mode, 2 if self.running else 0, 0, self.speed_rpm < 0, ref < 0, 0, telemetry)
        self.last_seq, self.last_drive = sensors.seq, drive
        return drive

    def advance(self, duration_us: float, sensors: Sensors) -> Drive:
        self.period_s = duration_us * 1e-6
        return self.step(sensors)

    def watchdog_trip(self) -> Drive:
        self.running = False
        return Drive(0, 0, 0, 0, 0, 4, 7, False, False, 1, (0, 0, 0))

    def status(self) -> Status:
        return Status(0, 0, 0, 0, 0, 0, 0, 0)


PROFILE = TargetProfile(
    name="tiny",
    firmware_name="TINY",
    make=lambda options: TinyTarget(options if isinstance(options, TinyOptions) else TinyOptions()),
    description="a tiny open-loop V/f drive (a plug-in test target)",
    options_type=TinyOptions,
    tunable=("v_per_krpm", "accel_rpm_s"),
    reference=ParamReference("speed_ref", 1.0),
    telemetry=(
        TelemetryColumn(int(TelemetryId.REF_SPEED), "ref_speed_rpm", "rpm", 1.0, "%d"),
        TelemetryColumn(TELEMETRY_ANGLE, "tiny_angle_deg", "deg", 0.1, "%.1f"),
        TelemetryColumn(TELEMETRY_MODULATION, "tiny_modulation", "", 0.001, "%.3f"),
    ),
    capabilities=frozenset({"speed_loop", "tuning"}),
    sweep_defaults=(("v_per_krpm", "30:40:3"),),
)
