"""The bench session: handshake, the per-period exchange, plant integration, scenario, recording.

Period k (ARCHITECTURE.md, timing contract): sample the plant at t_k, send Sensors(seq=k), get
Drive(seq=k), integrate the plant over [t_k, t_k + Ts) with the duties of the Drive received
``actuation_delay_periods`` periods earlier. The session knows no terminal: a caller-supplied
``observer`` sees snapshots, the caller prints. A board, an emulator process and an in-process
model are all a ``Target``; the session cannot tell them apart.
"""

from __future__ import annotations

import dataclasses
import gc
import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Literal

from hilbench.bench.clock import CpuLatencyRequest, Pacer
from hilbench.bench.recorder import (
    MARKER_EVENT,
    MARKER_FAULT,
    MARKER_PARAM,
    MARKER_SKIPPED,
    Recorder,
    RowLayout,
    fields_struct,
)
from hilbench.bench.scenario import Event, Ramp, ScenarioPlayer
from hilbench.errors import HilbenchError, LinkError, ParamError, TargetError
from hilbench.protocol import (
    PROTOCOL_VERSION,
    Edge,
    Fault,
    HostHello,
    Input,
    OutputMode,
    ParamType,
    Result,
    Sensors,
    State,
    TargetHello,
    TelemetryId,
    check_target_hello,
)
from hilbench.plant.model import STATE_FIELDS
from hilbench.targets.profiles import TargetProfile, profile_for

# The schema's constants as plain ints: the hot loop puts them into Sensors and compares with them.
EDGE_NONE = int(Edge.NONE)
INPUT_S2 = int(Input.S2)
INPUT_S3 = int(Input.S3)
OUTPUT_OFF = int(OutputMode.OFF)
STATE_STALLED = int(State.STALLED)
FAULT_STALL = int(Fault.STALL)
RESULT_NAMES = {
    Result.OK: "ok", Result.UNKNOWN_ID: "unknown parameter", Result.READ_ONLY: "read-only",
    Result.OUT_OF_RANGE: "out of range", Result.CONSTRAINT: "constraint", Result.BAD_REQUEST: "bad request",
}

RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)

#: the plant's step is accurate to 1e-6 at 50 us; longer periods are integrated in substeps
MAX_PLANT_STEP_US = 50

START_PRESS_S = 0.05  # presses this soon after a reference are starts, not stops (segments)
CTL_STEP_HOLD_S = 1.0
CTL_STEP_AFTER_S = 1.0
STEP_REPLY_KEYS = ("rise_time_s", "overshoot_pct", "settling_time_s", "ss_error", "ss_error_pct", "ss_ripple", "iae", "itae")

#: how long a button press is held (the firmware debounces and acts on the edge)
BUTTON_HOLD_S = 0.002


@dataclass(frozen=True)
class SessionOptions:
    """How a session runs (the [run] and [link] tables of a bench config)."""

    period_us: int = 50
    mode: Literal["lockstep", "realtime"] = "lockstep"
    duration_s: float | None = None  # None: until the scenario's end event
    actuation_delay_periods: int = 0
    timeout_s: float = 0.5
    watchdog_ms: int = 100
    overrun_policy: Literal["continue", "abort"] = "continue"
    max_consecutive_overruns: int = 10
    cpu_latency_qos: bool = True  # real time: keep idle CPUs from halting (clock.CpuLatencyRequest)
    seed: int = 0
    observe_every_periods: int = 400
    history_every_periods: int = 20


@dataclass(frozen=True)
class GuardSettings:
    """Guarded tuning: after a gain change, watch a window and restore the old gains on trouble."""

    enabled: bool = True
    window_s: float = 1.0
    oscillation_rpm: float = 150.0  # a speed-error swing beyond ±this counts
    oscillation_swings: int = 4  # this many swings across ±oscillation_rpm trip the guard
    current_limit_a: float = 3.0  # phase current peak (the MCLV six-step trip level is 3 A)


@dataclass
class _CtlStep:
    """A `ctl step` in progress: hold, step, then answer with the metrics."""

    request: Any
    from_rpm: float
    to_rpm: float
    due_s: float
    t_step_s: float | None = None


@dataclass
class Segment:
    """One held speed reference and how well the motor followed it."""

    t_start_s: float
    t_end_s: float
    ref_rpm: float
    plant_rpm: float = float("nan")
    measured_rpm: float = float("nan")

    @property
    def error_pct(self) -> float:
        if self.ref_rpm == 0:
            return float("nan")
        return 100.0 * (self.plant_rpm - self.ref_rpm) / abs(self.ref_rpm)


@dataclass
class Summary:
    """What a run did, for the CLI's table, --json and the tests."""

    target: str
    mode: str
    period_us: int
    periods: int = 0
    sim_s: float = 0.0
    wall_s: float = 0.0
    end_reason: str = "completed"
    fault: str | None = None
    segments: list[Segment] = field(default_factory=list)
    rtt_us: dict[str, float] = field(default_factory=dict)
    lateness_us: dict[str, float] = field(default_factory=dict)
    overruns: int = 0
    #: overruns in which the host was a whole period late, so no exchange took place (Drive held)
    skipped_periods: int = 0
    #: real time: whether idle CPUs were kept awake (the PM QoS request), or why not
    cpu_latency: str = ""
    #: real time: which CPU the host loop and the emulator process shared (set by bench.run)
    cpus: str = ""
    link: dict[str, int] = field(default_factory=dict)
    params: dict[str, float] = field(default_factory=dict)
    recording: str | None = None
    rows_recorded: int = 0

    @property
    def realtime_factor(self) -> float:
        return self.sim_s / self.wall_s if self.wall_s > 0 else float("inf")

    def as_dict(self) -> dict[str, Any]:
        return {
            "target": self.target,
            "mode": self.mode,
            "period_us": self.period_us,
            "periods": self.periods,
            "sim_s": self.sim_s,
            "wall_s": self.wall_s,
            "realtime_factor": self.realtime_factor,
            "end_reason": self.end_reason,
            "fault": self.fault,
            "segments": [
                {
                    "t_start_s": s.t_start_s,
                    "t_end_s": s.t_end_s,
                    "ref_rpm": s.ref_rpm,
                    "plant_rpm": s.plant_rpm,
                    "measured_rpm": s.measured_rpm,
                    "error_pct": s.error_pct,
                }
                for s in self.segments
            ],
            "rtt_us": self.rtt_us,
            "lateness_us": self.lateness_us,
            "overruns": self.overruns,
            "skipped_periods": self.skipped_periods,
            "cpu_latency": self.cpu_latency,
            "cpus": self.cpus,
            "link": self.link,
            "params": self.params,
            "recording": self.recording,
            "rows_recorded": self.rows_recorded,
        }


@dataclass
class Snapshot:
    """What the dashboard shows; built every ``observe_every_periods`` periods."""

    t_s: float
    duration_s: float
    period: int
    ref_rpm: float
    speed_rpm: float
    measured_rpm: float
    state: int
    sector: int
    direction_ccw: bool
    output_mode: int
    duties: tuple[int, int, int]
    i_abc: tuple[float, float, float]
    i_bus: float
    control_output_q15: int
    periods_per_s: float
    rtt_p50_us: float
    rtt_p99_us: float
    link: dict[str, int]
    overruns: int
    messages: list[str]
    history: list[tuple[float, float, float, float]]


class SessionAborted(HilbenchError):
    """The session stopped on a fault; the recording is closed with a fault marker."""


def _percentiles(values: list[float]) -> dict[str, float]:
    if not values:
        return {}
    ordered = sorted(values)
    n = len(ordered)

    def pick(q: float) -> float:
        return ordered[min(n - 1, int(q * (n - 1) + 0.5))]

    return {"p50": pick(0.5), "p99": pick(0.99), "max": ordered[-1], "n": float(n)}


class Session:
    """One bench run over a target and a plant."""

    def __init__(
        self,
        target: Any,
        plant: Any,
        events: Iterable[Event],
        options: SessionOptions = SessionOptions(),
        *,
        recorder: Recorder | None = None,
        observer: Callable[[Snapshot], None] | None = None,
        control: Any = None,
        link_stats: Callable[[], dict[str, int]] | None = None,
        target_label: str = "target",
        guard: GuardSettings = GuardSettings(),
    ) -> None:
        self.target = target
        self.plant = plant
        self.player = ScenarioPlayer(events)
        self.options = options
        self.recorder = recorder
        self.observer = observer
        self.control = control
        self.link_stats = link_stats or (lambda: {})
        self.target_label = target_label
        self.hello: TargetHello | None = None
        self.profile: TargetProfile = profile_for("")
        self.param_ids: dict[str, int] = {}
        self.param_info: dict[str, Any] = {}
        self.messages: list[str] = []
        self.history: list[tuple[float, float, float, float]] = []
        self.param_log: list[tuple[float, str]] = []
        self._buttons = 0
        self._button_release_s = math.inf
        self._ref_rpm = 0.0
        self._hall_force_high = 0
        self._hall_force_low = 0
        self._fault_clear_s = math.inf
        self._missing_edge_armed = False
        self._encoder_offset = 0
        self._last_hall = 0
        self._end_requested = False
        self.on_params: Callable[[dict[str, float]], None] | None = None
        self.guard = guard
        self._guard_until = -math.inf
        self._guard_prev: dict[str, float] = {}
        self._guard_sign = 0
        self._guard_swings = 0
        self.guard_trips: list[str] = []
        self._pending_steps: list[_CtlStep] = []

    # ------------------------------------------------------------------ handshake
    def handshake(self) -> TargetHello:
        """Agree period and mode; learn the target's ADC roles, telemetry and parameters."""
        mode = 0 if self.options.mode == "lockstep" else 1
        host = HostHello(0, PROTOCOL_VERSION, self.options.period_us, mode, self.options.watchdog_ms)
        hello = self.target.hello(host)
        check_target_hello(hello, where=self.target_label)  # protocol version and schema fingerprint
        self.hello = hello
        self.profile = profile_for(hello.firmware_name)
        for param_id in range(hello.n_params):
            info = self.target.describe(param_id)
            self.param_ids[info.name] = info.param_id
            self.param_info[info.name] = info
        ids = list(hello.telemetry_ids)
        self._tele_ref = ids.index(TelemetryId.REF_SPEED) if TelemetryId.REF_SPEED in ids else -1
        self._tele_meas = ids.index(TelemetryId.MEASURED_SPEED) if TelemetryId.MEASURED_SPEED in ids else -1
        self._tele_ctrl = ids.index(TelemetryId.CONTROL_OUTPUT) if TelemetryId.CONTROL_OUTPUT in ids else -1
        return hello

    # ------------------------------------------------------------------ parameters
    def param_values(self) -> dict[str, float]:
        """Every declared parameter, Q15 ones as fractions."""
        values: dict[str, float] = {}
        for name, param_id in self.param_ids.items():
            raw = self.target.get_param(param_id).value
            values[name] = raw / 32768.0 if self.param_info[name].ptype == ParamType.Q15 else float(raw)
        return values

    def encode_param(self, name: str, value: float) -> tuple[int, int]:
        """Host-side check of one parameter write; returns (id, raw) or raises ParamError."""
        if name not in self.param_ids:
            known = ", ".join(sorted(self.param_ids)) or "none"
            raise ParamError(f"{self.target_label}: unknown parameter {name!r} (declared: {known})")
        info = self.param_info[name]
        if info.access == 0:
            raise ParamError(f"{self.target_label}: parameter {name} is read-only")
        raw = round(value * 32768.0) if info.ptype == ParamType.Q15 else round(value)
        if info.ptype == ParamType.Q15 and value == 1.0:
            raw = 32767
        if not info.min_value <= raw <= info.max_value:
            lo, hi = info.min_value, info.max_value
            if info.ptype == ParamType.Q15:
                rng = f"{lo / 32768:.5f}..{hi / 32768:.5f}"
            else:
                rng = f"{lo}..{hi}"
            raise ParamError(f"{self.target_label}: {name}={value:g} is out of range {rng}")
        return info.param_id, raw

    def set_params(self, values: dict[str, float], t_s: float | None = None, *, guard: bool = True) -> None:
        """Write a parameter set atomically (checked here first, then by the target)."""
        pairs = tuple(self.encode_param(name, value) for name, value in values.items())
        if any(name in self.profile.gain_params for name in values):
            raw_now = {name: self.target.get_param(self.param_ids[name]).value
                       for name in self.profile.gain_params if name in self.param_ids}
            previous = {name: raw / 32768.0 for name, raw in raw_now.items()}
            raw_now.update({name: raw for name, (_, raw) in zip(values, pairs)})
            broken = self.profile.gain_constraint_broken(raw_now)
            if broken is not None:
                text = " ".join(f"{k}={v:g}" for k, v in values.items())
                raise ParamError(f"{self.target_label}: gains {text} break the firmware's {broken}")
        else:
            previous = {}
        result = self.target.set_params(pairs)
        if result.result != 0:
            name = next((n for n, i in self.param_ids.items() if i == result.param_id), str(result.param_id))
            reason = RESULT_NAMES.get(result.result, f"result {result.result}")
            detail = f" #{result.detail}" if result.result == Result.CONSTRAINT else ""
            raise ParamError(f"{self.target_label} refused {name}: {reason}{detail}")
        if self.on_params is not None:
            self.on_params(dict(values))
        text = "set " + " ".join(f"{k}={v:g}" for k, v in values.items())
        when = self.plant.t_s if t_s is None else t_s
        self.param_log.append((when, text))
        self.messages.append(f"{when:.3f} s: {text}")
        if self.recorder is not None:
            self.recorder.event(f"t={when:.6f} {text}", MARKER_PARAM)
        if guard and previous and self.guard.enabled:
            self._arm_guard(when, previous)

    def _arm_guard(self, t_s: float, previous: dict[str, float]) -> None:
        self._guard_until = t_s + self.guard.window_s
        self._guard_prev = previous
        self._guard_sign = 0
        self._guard_swings = 0

    def _guard_check(self, t_s: float, ref_rpm: float, state: int, fault: int) -> None:
        """One look at the motor inside the guard window (every history sample, ~1 ms)."""
        guard = self.guard
        reason = None
        peak = max(abs(i) for i in self.plant.i_abc)
        if peak > guard.current_limit_a:
            reason = f"phase current {peak:.2f} A > {guard.current_limit_a:g} A"
        elif state == STATE_STALLED or fault == FAULT_STALL:
            reason = "the firmware stalled"
        else:
            error = self.plant.speed_rpm - ref_rpm
            sign = 1 if error > guard.oscillation_rpm else (-1 if error < -guard.oscillation_rpm else 0)
            if sign and sign != self._guard_sign:
                if self._guard_sign:
                    self._guard_swings += 1
                self._guard_sign = sign
            if self._guard_swings >= guard.oscillation_swings:
                reason = f"speed error oscillates beyond ±{guard.oscillation_rpm:g} rpm"
        if reason is None:
            return
        self._guard_until = -math.inf
        restored = " ".join(f"{k}={v:g}" for k, v in self._guard_prev.items())
        try:
            self.set_params(self._guard_prev, t_s, guard=False)
            text = f"guard: {reason}; restored {restored}"
        except HilbenchError as exc:
            text = f"guard: {reason}; could not restore {restored}: {exc}"
        self.guard_trips.append(text)
        self._note(t_s, text)

    # ------------------------------------------------------------------ scenario
    def _apply(self, event: Event, t_s: float) -> None:
        plant = self.plant
        if event.ref_rpm is not None:
            target_rpm = event.ref_rpm
            if event.ramp_s > 0:
                self.player.ramps["ref_rpm"] = Ramp(t_s, t_s + event.ramp_s, self._ref_rpm, target_rpm)
            else:
                self.player.ramps.pop("ref_rpm", None)
                self._set_ref(target_rpm)
        elif event.pot is not None:
            plant.pot_fraction = event.pot
        elif event.load_nm is not None:
            self.set_load(event.load_kind, event.load_nm)
        elif event.vbus_v is not None:
            if event.ramp_s > 0:
                self.player.ramps["vbus_v"] = Ramp(t_s, t_s + event.ramp_s, plant.vbus_v, event.vbus_v)
            else:
                plant.vbus_v = event.vbus_v
        elif event.press is not None:
            self._buttons |= INPUT_S2 if event.press == "s2" else INPUT_S3
            self._button_release_s = t_s + BUTTON_HOLD_S
        elif event.fault is not None:
            self._apply_fault(event, t_s)
        elif event.params:
            try:
                self.set_params(dict(event.params), t_s)
            except ParamError as exc:
                self.messages.append(f"{t_s:.3f} s: {exc}")
        elif event.end:
            self._end_requested = True
        if self.recorder is not None:
            self.recorder.event(f"t={t_s:.6f} {event.describe()}", MARKER_EVENT)

    def set_load(self, kind: str, value: float) -> None:
        """A load profile from here on: constant N*m, linear/quadratic coefficient, or locked."""
        from hilbench.plant.params import LoadProfile

        if kind in ("linear", "quadratic"):
            self.plant.load = LoadProfile(kind, coeff=value)  # type: ignore[arg-type]
        else:
            self.plant.load = LoadProfile(kind, torque_nm=value)  # type: ignore[arg-type]

    def _set_ref(self, rpm: float) -> None:
        self._ref_rpm = rpm
        code = self.profile.pot_code_for_rpm(rpm)
        self.plant.pot_fraction = code / 1023.0

    def _apply_fault(self, event: Event, t_s: float) -> None:
        kind = event.fault or "clear"
        self._hall_force_high = self._hall_force_low = 0
        self._missing_edge_armed = False
        self._fault_clear_s = math.inf
        if kind.startswith("hall_") and kind[-4:] in ("high", "_low"):
            bit = {"a": 1, "b": 2, "c": 4}[kind[5]]
            if kind.endswith("high"):
                self._hall_force_high = bit
            else:
                self._hall_force_low = bit
        elif kind == "hall_missing_edge":
            self._missing_edge_armed = True
        elif kind == "encoder_glitch":
            self._encoder_offset = (self._encoder_offset + 7) & 0xFFFF
        if event.fault_duration_s:
            self._fault_clear_s = t_s + event.fault_duration_s

    def _tick_ramps(self, t_s: float) -> None:
        for kind, ramp in list(self.player.ramps.items()):
            value = ramp.value(t_s)
            if kind == "ref_rpm":
                self._set_ref(value)
            elif kind == "vbus_v":
                self.plant.vbus_v = value
            if t_s >= ramp.t1:
                del self.player.ramps[kind]

    # ------------------------------------------------------------------ the loop
    def run(self) -> Summary:
        """Handshake if needed, then run periods until the duration or the scenario ends."""
        options = self.options
        if self.hello is None:
            self.handshake()
        assert self.hello is not None
        summary = Summary(self.target_label, options.mode, options.period_us)
        summary.recording = str(self.recorder.path) if self.recorder is not None else None
        period_s = options.period_us * 1e-6
        duration = options.duration_s if options.duration_s is not None else self.player.end_s
        if duration is None:
            duration = 5.0
        n_periods = max(1, round(duration / period_s))
        self._duration_s = n_periods * period_s
        roles = tuple(self.hello.adc_roles)
        duty_scale = 1.0 / self.hello.pwm_period_counts
        delay = options.actuation_delay_periods
        pending: deque[Any] = deque()
        realtime = options.mode == "realtime"
        pacer = Pacer(period_s) if realtime else None
        rtts: list[float] = []
        lateness: list[float] = []
        overruns = 0
        consecutive = 0
        tele_ref, tele_meas, tele_ctrl = self._tele_ref, self._tele_meas, self._tele_ctrl
        profile = self.profile
        rpm_q15 = profile.rpm_per_speed_q15 or 0.0
        plant = self.plant
        target_step = self.target.step
        recorder = self.recorder
        if recorder is not None:
            layout, own_fields = self._row_layout(period_s)
            recorder.start(layout)
            rec_pack = fields_struct(own_fields).pack
            rec_extend = recorder.rows.extend
            rec_data, plant_state = recorder.rows.data, plant.append_state
        rec_on = recorder is not None
        observe_every = options.observe_every_periods
        history_every = options.history_every_periods
        control = self.control
        perf = time.perf_counter
        edge_limit = options.period_us * 10 - 1
        substeps = max(1, math.ceil(options.period_us / MAX_PLANT_STEP_US))
        sub_s = period_s / substeps
        edge_s = plant.last_edge_s
        wall_start = perf()
        last_obs_wall = wall_start
        last_obs_k = 0
        k = 0
        self._last_hall = plant.hall_bits
        drive = None
        last_ref = 0.0
        self.periods_done = 0
        self._period_s = period_s
        new_sensors = tuple.__new__
        next_event_k = self._first_period_at(self.player.next_t_s, period_s)
        sensor_faults = False
        late = rtt = 0.0  # lockstep: not measured, so that recordings are reproducible
        marker = 0  # events set theirs at flush; a skipped real-time period sets it here
        skipped = 0
        gc_was_enabled = gc.isenabled()
        gc.disable()  # no collector pauses inside periods (recorded rows are plain numbers)
        qos = CpuLatencyRequest() if realtime and options.cpu_latency_qos else None
        if realtime and qos is None:
            summary.cpu_latency = "not requested ([link] cpu_latency_qos = false)"
        try:
            if qos is not None:
                qos.__enter__()  # released in the finally below, however the run ends
                summary.cpu_latency = qos.status
            if pacer is not None:
                pacer.start()
            for k in range(n_periods):
                if k >= next_event_k:  # scenario events, ramps, button release, fault expiry
                    t_s = k * period_s
                    if t_s >= self.player.next_t_s:
                        for event in self.player.due(t_s):
                            self._apply(event, t_s)
                        if self._end_requested:
                            summary.end_reason = "scenario end"
                            break
                    if self.player.ramps:
                        self._tick_ramps(t_s)
                    if t_s >= self._button_release_s:
                        self._buttons = 0
                        self._button_release_s = math.inf
                    if t_s >= self._fault_clear_s:
                        self._apply_fault(Event(at_s=t_s, fault="clear"), t_s)
                    sensor_faults = bool(self._hall_force_high or self._hall_force_low or self._missing_edge_armed)
                    next_event_k = self._first_period_at(min(
                        self.player.next_t_s, self._button_release_s, self._fault_clear_s,
                        t_s + period_s if self.player.ramps else math.inf), period_s)
                if k % history_every == 0 and drive is not None:
                    t_s = k * period_s
                    # live changes act from this period on, so they are noted at its time
                    if t_s < self._guard_until:
                        self._guard_check(t_s, last_ref, drive.state, drive.fault)
                    if self._pending_steps:
                        self._advance_steps(t_s)
                    if control is not None and k % observe_every == 0:
                        self._serve_control(t_s)
                        if self._end_requested:
                            summary.end_reason = "stopped by ctl"
                            break
                        next_event_k = min(next_event_k, k + 1)  # a ctl ref may start a ramp
                # -- sample the plant
                hall = plant.hall_bits
                edge = EDGE_NONE if edge_s is None else min(int(edge_s * 1e7), edge_limit)
                if sensor_faults:
                    hall, edge = self._faulty_hall(hall, edge)
                    sensor_faults = bool(self._hall_force_high or self._hall_force_low or self._missing_edge_armed)
                sensors = new_sensors(Sensors, (
                    k & 0xFF, hall | self._buttons, edge,
                    (plant.encoder_count + self._encoder_offset) & 0xFFFF, plant.adc_codes(roles),
                ))
                # -- exchange
                if pacer is not None:
                    late = pacer.wait_for(k)
                    lateness.append(late)
                    if late >= period_s and drive is not None:
                        # the host stalled past this period's whole slot: no exchange, the Drive is
                        # held (as the board holds its PWM) and the plant keeps to the wall clock;
                        # the period counts as an overrun below
                        skipped += 1
                        rtt = 0.0
                        marker = MARKER_SKIPPED
                    else:
                        sent = perf()
                        drive = target_step(sensors)
                        rtt = perf() - sent
                        rtts.append(rtt)
                        marker = 0
                else:
                    if k & 15 == 0:
                        sent = perf()
                        drive = target_step(sensors)
                        rtts.append(perf() - sent)
                    else:
                        drive = target_step(sensors)
                _, duty_a, duty_b, duty_c, mode, state, sector, _, _, fault, tele = drive
                # -- integrate the plant over the period with this Drive (or a delayed one)
                if delay:
                    pending.append(drive)
                    applied = pending.popleft() if len(pending) > delay else None
                    if applied is None:
                        da = db = dc = 0.0
                        applied_mode = OUTPUT_OFF
                    else:
                        da, db, dc = applied[1] * duty_scale, applied[2] * duty_scale, applied[3] * duty_scale
                        applied_mode = applied[4]
                else:
                    da, db, dc = duty_a * duty_scale, duty_b * duty_scale, duty_c * duty_scale
                    applied_mode = mode
                if substeps == 1:
                    plant.step(da, db, dc, applied_mode, period_s)
                    edge_s = plant.last_edge_s
                else:  # long periods: the plant keeps its accurate step, the duties are held
                    edge_s = None
                    for i in range(substeps):
                        plant.step(da, db, dc, applied_mode, sub_s)
                        if plant.last_edge_s is not None:
                            edge_s = i * sub_s + plant.last_edge_s
                if pacer is not None:
                    finished = perf() - pacer.t0 - k * period_s
                    if finished > period_s:
                        overruns += 1
                        consecutive += 1
                        if options.overrun_policy == "abort" and consecutive >= options.max_consecutive_overruns:
                            raise SessionAborted(
                                f"{self.target_label}: {consecutive} consecutive overruns at period {k} "
                                f"(period {options.period_us} us); try a longer period or --mode lockstep"
                            )
                    else:
                        consecutive = 0
                meas_raw = tele[tele_meas] if tele_meas >= 0 else 0
                ref_raw = tele[tele_ref] if tele_ref >= 0 else self._ref_rpm
                ctrl = tele[tele_ctrl] if tele_ctrl >= 0 else 0
                if rec_on:  # raw values in their own types (see _row_layout); events set the marker
                    rec_extend(rec_pack(
                        k, hall, sector, meas_raw, ref_raw, ctrl, duty_a, duty_b, duty_c, mode, state, fault,
                        rtt, late, marker,
                    ))
                    plant_state(rec_data)  # the plant's STATE_FIELDS, appended by the plant itself
                if k % history_every == 0:
                    meas = meas_raw * rpm_q15 if tele_meas >= 0 else math.nan
                    last_ref = ref_raw * rpm_q15 if tele_ref >= 0 else ref_raw
                    self.history.append((k * period_s, self._ref_rpm, plant.w_m * RPM_PER_RAD_S, meas))
                    if k % observe_every == 0 and k:
                        if recorder is not None:
                            recorder.maybe_flush()
                        if self.observer is not None:
                            now = perf()
                            rate = (k - last_obs_k) / max(now - last_obs_wall, 1e-9)
                            last_obs_wall, last_obs_k = now, k
                            self.observer(self._snapshot(k * period_s, k, drive, meas, ctrl, rate, rtts, overruns))
            else:
                k = n_periods
            self.periods_done = k
        except KeyboardInterrupt:
            summary.end_reason = "interrupted"
            self.periods_done = k
            self._stop_target()
            self._finish(summary, wall_start, rtts, lateness, overruns, skipped, f"interrupted at period {k}")
            raise
        except (LinkError, TargetError, SessionAborted) as exc:
            self.periods_done = k
            summary.end_reason = "fault"
            summary.fault = str(exc)
            self._deenergise()
            self._finish(summary, wall_start, rtts, lateness, overruns, skipped, f"fault at period {k}: {exc}",
                         fault=True)
            raise
        finally:
            if qos is not None:
                qos.__exit__(None, None, None)
            if gc_was_enabled:
                gc.enable()
        self._stop_target()
        self._finish(summary, wall_start, rtts, lateness, overruns, skipped, f"end: {summary.end_reason} at period {k}")
        return summary

    @staticmethod
    def _first_period_at(t_s: float, period_s: float) -> float:
        """The first period k with k * period_s >= t_s (the hot loop compares k, not times)."""
        if t_s == math.inf:
            return math.inf
        k = max(0, math.ceil(t_s / period_s))
        while k > 0 and (k - 1) * period_s >= t_s:
            k -= 1
        while k * period_s < t_s:
            k += 1
        return k

    def _row_layout(self, period_s: float) -> tuple[RowLayout, tuple[tuple[str, str], ...]]:
        """The raw row of a period, and the recording's columns and units made of it; with the
        fields the session packs itself (the plant appends STATE_FIELDS after them)."""
        rpm_q15 = self.profile.rpm_per_speed_q15
        meas_scale = rpm_q15 if (self._tele_meas >= 0 and rpm_q15) else math.nan
        ref_scale = rpm_q15 if (self._tele_ref >= 0 and rpm_q15) else 1.0
        ref_code = "i" if self._tele_ref >= 0 else "d"  # the firmware's Q15, or the host's rpm
        own_fields = (
            ("k", "Q"), ("hall", "i"), ("sector", "i"), ("meas_raw", "i"), ("ref_raw", ref_code), ("ctrl_q15", "i"),
            ("duty_a", "i"), ("duty_b", "i"), ("duty_c", "i"), ("output_mode", "i"), ("state", "i"), ("fault", "i"),
            ("rtt_s", "d"), ("lateness_s", "d"), ("marker", "B"),
        )
        columns = (
            ("k", period_s), ("k", 1.0), ("hall", 1.0), ("sector", 1.0), ("theta_e_rad", 180.0 / math.pi),
            ("w_m_rad_s", RPM_PER_RAD_S), ("meas_raw", meas_scale), ("ref_raw", ref_scale), ("ctrl_q15", 1.0),
            ("ia_a", 1.0), ("ib_a", 1.0), ("ic_a", 1.0), ("ibus_a", 1.0), ("duty_a", 1.0), ("duty_b", 1.0),
            ("duty_c", 1.0), ("output_mode", 1.0), ("state", 1.0), ("fault", 1.0), ("load_nm", 1.0),
            ("rtt_s", 1e6), ("lateness_s", 1e6), ("marker", 1.0),
        )
        return RowLayout(own_fields + STATE_FIELDS, columns, wrap=(("theta_e_deg", 360.0),)), own_fields

    def _stop_target(self) -> None:
        """A clean end: the target stops its outputs (S2 as a command)."""
        try:
            self.target.stop()
        except HilbenchError:
            pass

    def _faulty_hall(self, hall: int, edge: int) -> tuple[int, int]:
        if self._missing_edge_armed and hall != self._last_hall:
            self._missing_edge_armed = False
            return self._last_hall, EDGE_NONE  # this edge never reaches the target
        self._last_hall = hall
        forced = (hall | self._hall_force_high) & ~self._hall_force_low & 0x7
        return forced, (EDGE_NONE if forced == hall and edge == EDGE_NONE else edge)

    def _deenergise(self) -> None:
        """Open every switch of the plant's inverter: the motor coasts whatever the target does."""
        try:
            self.plant.step(0.0, 0.0, 0.0, OUTPUT_OFF, self.options.period_us * 1e-6)
        except Exception:  # noqa: BLE001 - de-energising must never mask the original fault
            pass

    def _serve_control(self, t_s: float) -> None:
        for request in self.control.poll():
            self.handle_control(request, t_s)

    def handle_control(self, request: Any, t_s: float) -> None:
        """Answer one control-socket request (see hilbench.bench.control)."""
        cmd, args = request.cmd, request.args
        try:
            if cmd == "get":
                request.reply(True, "ok", {"params": self.param_values(), "t_s": t_s, "ref_rpm": self._ref_rpm})
            elif cmd == "set":
                self.set_params({str(k): float(v) for k, v in args["params"].items()}, t_s)
                request.reply(True, f"applied at t={t_s:.4f} s", {"params": self.param_values()})
            elif cmd == "ref":
                self.player.ramps.pop("ref_rpm", None)
                self._set_ref(float(args["rpm"]))
                self._note(t_s, f"ref {args['rpm']} rpm (ctl)")
                request.reply(True, f"reference {args['rpm']} rpm at t={t_s:.4f} s")
            elif cmd == "step":
                self._start_ctl_step(request, float(args["from_rpm"]), float(args["to_rpm"]), t_s)
            elif cmd == "stop":
                self._end_requested = True
                self._note(t_s, "stop (ctl)")
                request.reply(True, f"run ends at t={t_s:.4f} s")
            elif cmd == "guard":
                self.guard = dataclasses.replace(self.guard, enabled=bool(args["on"]))
                self._note(t_s, f"guard {'on' if self.guard.enabled else 'off'} (ctl)")
                request.reply(True, f"guarded tuning {'on' if self.guard.enabled else 'off'}")
            elif cmd == "load":
                self.set_load("constant", float(args["nm"]))
                self._note(t_s, f"load {args['nm']} N*m (ctl)")
                request.reply(True, f"load {args['nm']} N*m at t={t_s:.4f} s")
            else:
                request.reply(False, f"command {cmd!r} is not available in this session")
        except HilbenchError as exc:
            request.reply(False, str(exc))

    def _start_ctl_step(self, request: Any, from_rpm: float, to_rpm: float, t_s: float) -> None:
        """`ctl step A B`: reference A now, B after a 1 s hold; reply with the metrics 1 s later."""
        self.player.ramps.pop("ref_rpm", None)
        self._set_ref(from_rpm)
        self._note(t_s, f"step {from_rpm:g} -> {to_rpm:g} rpm (ctl): hold {from_rpm:g}")
        self._pending_steps.append(_CtlStep(request, from_rpm, to_rpm, t_s + CTL_STEP_HOLD_S))

    def _advance_steps(self, t_s: float) -> None:
        for step in list(self._pending_steps):
            if t_s < step.due_s:
                continue
            if step.t_step_s is None:  # the hold is over: step now
                self._set_ref(step.to_rpm)
                self._note(t_s, f"step to {step.to_rpm:g} rpm (ctl)")
                step.t_step_s = t_s
                step.due_s = t_s + CTL_STEP_AFTER_S
            else:  # the record after the step is complete: answer
                self._pending_steps.remove(step)
                metrics = self._step_metrics(step.t_step_s, step.to_rpm)
                step.request.reply(True, f"step {step.from_rpm:g} -> {step.to_rpm:g} rpm done", metrics)

    def _step_metrics(self, t_step: float, to_rpm: float) -> dict[str, Any]:
        from hilbench.bench.metrics import step_metrics

        t = [h[0] for h in self.history if h[0] >= t_step - 0.05]
        y = [h[2] for h in self.history if h[0] >= t_step - 0.05]
        before = [v for tt, v in zip(t, y) if tt < t_step] or y[:1]
        code_rpm = self.profile.pot_code_for_rpm(to_rpm)
        ref = ((code_rpm - 512) / self.profile.pot_counts_per_q15 * self.profile.rpm_per_speed_q15
               if self.profile.pot_counts_per_q15 and self.profile.rpm_per_speed_q15 else to_rpm)
        after = [(tt, v) for tt, v in zip(t, y) if tt >= t_step]
        metrics = step_metrics([a for a, _ in after], [b for _, b in after], y0=sum(before) / len(before),
                               y_final_ref=ref, t_step_s=t_step)
        return {k: v for k, v in metrics.as_dict().items() if k in STEP_REPLY_KEYS}

    def _note(self, t_s: float, text: str) -> None:
        self.messages.append(f"{t_s:.3f} s: {text}")
        if self.recorder is not None:
            self.recorder.event(f"t={t_s:.6f} {text}", MARKER_EVENT)

    def _snapshot(self, t_s, k, drive, meas, ctrl, rate, rtts, overruns) -> Snapshot:  # type: ignore[no-untyped-def]
        recent = rtts[-256:]
        stats = _percentiles([r * 1e6 for r in recent])
        ia, ib, ic = self.plant.i_abc
        return Snapshot(
            t_s=t_s,
            duration_s=self._duration_s,
            period=k,
            ref_rpm=self._ref_rpm,
            speed_rpm=self.plant.speed_rpm,
            measured_rpm=meas,
            state=drive.state,
            sector=drive.sector,
            direction_ccw=bool(drive.direction_ccw),
            output_mode=drive.output_mode,
            duties=(drive.duty_a, drive.duty_b, drive.duty_c),
            i_abc=(ia, ib, ic),
            i_bus=self.plant.i_bus,
            control_output_q15=ctrl,
            periods_per_s=rate,
            rtt_p50_us=stats.get("p50", math.nan),
            rtt_p99_us=stats.get("p99", math.nan),
            link=self.link_stats(),
            overruns=overruns,
            messages=self.messages[-4:],
            history=self.history,  # the dashboard decimates it to its width
        )

    def _finish(self, summary: Summary, wall_start: float, rtts, lateness, overruns, skipped, note, fault=False) -> None:  # type: ignore[no-untyped-def]
        period_s = self.options.period_us * 1e-6
        summary.periods = self.periods_done
        summary.sim_s = self.periods_done * period_s
        summary.wall_s = time.perf_counter() - wall_start
        summary.rtt_us = _percentiles([r * 1e6 for r in rtts])
        summary.lateness_us = _percentiles([x * 1e6 for x in lateness])
        summary.overruns = overruns
        summary.skipped_periods = skipped
        summary.link = self.link_stats()
        summary.segments = self._segments(summary.sim_s)
        try:
            summary.params = self.param_values() if not fault else {}
        except HilbenchError:
            summary.params = {}
        if self.recorder is not None:
            if fault:
                self.recorder.mark_last(MARKER_FAULT)
            self.recorder.close(note)
            summary.rows_recorded = self.recorder.rows_written

    def _segments(self, sim_s: float) -> list[Segment]:
        """Each held reference: the mean speed over the last 30 % of its hold."""
        refs = [e for e in self.player.events if e.ref_rpm is not None and e.at_s < sim_s]
        bounds = [e.at_s for e in self.player.events if e.ref_rpm is not None or e.end]
        presses = [e.at_s for e in self.player.events if e.press]
        segments: list[Segment] = []
        for event in refs:
            start = event.at_s + event.ramp_s
            # a press soon after the hold starts is the start button; a later one stops the motor
            later = sorted([b for b in bounds if b > start] + [p for p in presses if p > start + START_PRESS_S])
            end = min(later[0] if later else sim_s, sim_s)
            if end - start <= 0.05 or event.ref_rpm == 0:
                continue
            window_start = end - 0.3 * (end - start)
            samples = [(p, m) for (t, _, p, m) in self.history if window_start <= t < end]
            if not samples:
                continue
            plant_mean = sum(p for p, _ in samples) / len(samples)
            meas_values = [m for _, m in samples if not math.isnan(m)]
            meas_mean = sum(meas_values) / len(meas_values) if meas_values else math.nan
            segments.append(Segment(event.at_s, end, float(event.ref_rpm or 0.0), plant_mean, meas_mean))
        return segments
