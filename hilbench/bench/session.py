"""The bench session: handshake, the per-period exchange, plant integration and its parts.

Period k (docs/design.md, timing contract): sample the plant at t_k, send Sensors(seq=k), get
Drive(seq=k), integrate the plant over [t_k, t_k + Ts) with the duties of the Drive received
``actuation_delay_periods`` periods earlier. Around that hot path, each concern is its own part,
called only in the periods it asked for: the scenario (`ScenarioPlayer`: references, load,
buttons, bus), sensor faults (`SensorFaults`), live tuning and its guard (`LiveTuning`), the
control socket's commands, real-time pacing (`RealtimePacing`), the recorder (a `SessionRow`) and
the observer (a `Snapshot` every ``observe_every_periods``). The session knows no terminal and no
firmware: what it needs of the target comes from the target's profile and its HELLO.
"""

from __future__ import annotations

import dataclasses
import gc
import math
import struct
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Literal, Protocol

from hilbench.bench.clock import CpuLatencyRequest
from hilbench.bench.columns import BENCH_COLUMNS, RPM_PER_RAD_S, session_row
from hilbench.bench.faults import SensorFaults
from hilbench.bench.livetuning import GuardSettings, LiveTuning
from hilbench.bench.pacing import RealtimePacing, SessionAborted
from hilbench.bench.recorder import MARKER_EVENT, MARKER_FAULT, MARKER_PARAM, Recorder, fields_struct
from hilbench.bench.sensing import hall_edges, with_index_marks
from hilbench.bench.scenario import PERIOD_TOLERANCE, Event, Ramp, ScenarioPlayer, first_period_at
from hilbench.bench import segments as segmentation
from hilbench.bench.streamstats import StreamingPercentiles
from hilbench.bench.summary import Segment, Snapshot, Summary, percentiles
from hilbench.plant.model import PlantOutput
from hilbench.errors import BenchLimitError, HilbenchError, LinkError, ParamError, ProtocolError, SimulationError, TargetError
from hilbench.protocol import (
    PROTOCOL_VERSION,
    HostHello,
    Input,
    OutputMode,
    MAX_EDGES,
    Sensors,
    TargetHello,
    TargetInfo,
    check_target_hello,
)
from hilbench.targets.base import Target
from hilbench.targets.profile import ParamReference, PotReference, TargetProfile
from hilbench.targets.describe import describe as describe_firmware, described_profile
from hilbench.targets.registry import profile_for_firmware, registered_for_firmware

INPUT_S2 = int(Input.S2)
INPUT_S3 = int(Input.S3)
INPUT_INDEX = int(Input.INDEX)
INPUT_FAULT = int(Input.FAULT)
OUTPUT_OFF = int(OutputMode.OFF)

START_PRESS_S = segmentation.START_PRESS_S  # presses this soon after a reference are starts, not stops
#: speed samples kept for the dashboard and `ctl step` (the newest; ~8 s at the default 1 ms)
HISTORY_SAMPLES = 8192
#: messages kept for the dashboard
MAX_MESSAGES = 64
CTL_STEP_HOLD_S = 1.0
CTL_STEP_AFTER_S = 1.0
STEP_REPLY_KEYS = ("rise_time_s", "overshoot_pct", "settling_time_s", "ss_error", "ss_error_pct", "ss_ripple", "iae", "itae")

#: how long a button press is held (the firmware debounces and acts on the edge)
BUTTON_HOLD_S = 0.002


class PlantLike(Protocol):
    """What the session uses of a plant (hilbench.plant.model.Plant)."""

    hall_bits: int
    last_edge_s: float | None
    encoder_count: int
    pot_fraction: float
    vbus_v: float
    w_m: float
    t_s: float
    fault_input: bool  # the board's overcurrent comparator, latched (drives the target's FAULT input)
    outputs: tuple[PlantOutput, ...]  # what it records every period (append_state)

    def set_period(self, period_us: int, actuation_delay_periods: int = 0) -> None: ...
    def advance(self, duty_a: float, duty_b: float, duty_c: float, output_mode: int,
                state_to: bytearray | None = None, /) -> float | None: ...
    def step(self, duty_a: float, duty_b: float, duty_c: float, output_mode: int, dt_s: float,
             state_to: bytearray | None = None, /) -> float | None: ...
    def edges(self) -> tuple[tuple[float, int], ...]: ...  # every hall edge of the last advance
    def index_marks(self) -> tuple[float, ...]: ...  # every encoder index mark of the last advance
    def adc_codes(self, roles: tuple[int, ...]) -> tuple[int, ...]: ...
    def sense(self, roles: tuple[int, ...]) -> tuple[int, bool, bool, int, tuple[int, ...]]: ...
    def append_state(self, buf: bytearray) -> None: ...


class ControlRequest(Protocol):
    """One request from the control socket (hilbench.bench.control)."""

    cmd: str
    args: dict[str, Any]

    def reply(self, ok: bool, text: str, data: dict[str, Any] | None = None) -> None: ...


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
    overspeed_rpm: float = 0.0  # bench limit ([protection] overspeed_rpm): the run ends with a fault; 0: none
    bus_capacitance_f: float = 0.0  # the bus capacitor regeneration charges ([protection]); 0: a stiff bus
    overvoltage_v: float = 0.0  # bench limit on the bus voltage; 0: none


@dataclass
class _CtlStep:
    """A `ctl step` in progress: hold, step, then answer with the metrics."""

    request: ControlRequest
    from_rpm: float
    to_rpm: float
    due_s: float
    t_step_s: float | None = None


class Session:
    """One bench run over a target and a plant."""

    def __init__(
        self,
        target: Target,
        plant: PlantLike,
        events: Iterable[Event],
        options: SessionOptions = SessionOptions(),
        *,
        profile: TargetProfile | None = None,
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
        self.expected_profile = profile
        self.profile: TargetProfile = profile or profile_for_firmware("")
        self.hello: TargetHello | None = None
        self.target_info: TargetInfo | None = None  # TargetDescribe's answer (None: the target has none)
        self.tuning = LiveTuning(target, self.profile, target_label, guard)
        self.tuning.on_change = self._on_param_change
        self.faults = SensorFaults()
        self.messages: list[str] = []
        #: (t_s, ref_rpm, plant_rpm, measured_rpm): the newest HISTORY_SAMPLES (memory stays flat)
        self.history: deque[tuple[float, float, float, float]] = deque(maxlen=HISTORY_SAMPLES)
        self.segmenter = segmentation.Segmenter()
        self.on_params: Callable[[dict[str, float]], None] | None = None
        self.periods_done = 0
        self._buttons = 0
        self._button_release_s = math.inf
        self._ref_rpm = 0.0
        self._end_reason: str | None = None
        self._pending_steps: list[_CtlStep] = []
        self._period_s = options.period_us * 1e-6
        self._duration_s = 0.0
        self._scenario_k: float = 0
        self._obs_last = (0.0, 0)
        self._lockstep_rtts = StreamingPercentiles()
        self._tele_index: dict[str, tuple[int, float]] = {}
        self._closed = False
        self._record_host_ref = False
        self._qos: CpuLatencyRequest | None = None
        self._pacing: RealtimePacing | None = None
        self._trip_noted = False  # the overcurrent comparator's trip is an event once per latch
        self._supply_v = 0.0  # the bench supply's voltage (the bus rises above it only with a capacitor): begin()
        self.display: Any = None  # the scope's display stream (hilbench.scope.stream), made by `stream`

    # ------------------------------------------------------------------ handshake
    def handshake(self) -> TargetHello:
        """Agree period and mode; learn the target's profile, telemetry and parameters."""
        mode = 0 if self.options.mode == "lockstep" else 1
        host = HostHello(0, PROTOCOL_VERSION, self.options.period_us, mode, self.options.watchdog_ms)
        hello = self.target.hello(host)
        check_target_hello(hello, where=self.target_label)  # protocol version and schema fingerprint
        self.hello = hello
        found = registered_for_firmware(hello.firmware_name)
        if found is None:  # no module knows it: the firmware's own description (protocol 3)
            description = describe_firmware(self.target, hello)
            self.target_info = description.target
            reserved = frozenset(BENCH_COLUMNS) | {out.column for out in self.plant.outputs}
            found = described_profile(profile_for_firmware(hello.firmware_name), description, reserved)
        else:
            describe = getattr(self.target, "describe_target", None)
            self.target_info = describe() if describe is not None else None
        expected = self.expected_profile
        if expected is not None and found.firmware_name.upper() != expected.firmware_name.upper():
            raise TargetError(f"{self.target_label}: the target says it runs {hello.firmware_name!r}, "
                              f"the config expects {expected.firmware_name!r} (target {expected.name})")
        self.profile = expected or found
        self.tuning.profile = self.profile
        self.tuning.declare(hello.n_params)
        for index, tid in enumerate(hello.telemetry_ids):
            column = self.profile.telemetry_column(tid)
            self._tele_index[column.column] = (index, column.scale)
        missing = (-1, 0.0)  # (telemetry index, scale) of the firmware's measured speed and reference
        self._overspeed_rpm = self.options.overspeed_rpm if self.options.overspeed_rpm > 0 else math.inf
        self._speed_telemetry = (self._tele_index.get(self.profile.speed_column or "", missing),
                                 self._tele_index.get("ref_speed_rpm", missing))
        return hello

    def target_max_edges(self) -> int:
        """The input edges one Sensors may carry: the target's TargetInfo.max_edges, else the protocol's."""
        info = self.target_info
        return min(int(info.max_edges), MAX_EDGES) if info is not None and info.max_edges else MAX_EDGES

    def _too_many_edges(self, k: int, n: int) -> None:
        period_us = self.options.period_us
        raise BenchLimitError(
            f"{self.target_label}: period {k} has {n} input edges (hall and index), the target takes at most "
            f"{self._max_edges} a period (its TargetInfo.max_edges); use a shorter link.period_us (at most "
            f"{max(1, period_us * self._max_edges // (n + 1))} us at this speed) or a firmware built with a "
            f"larger HBP_MAX_EDGES")

    # ------------------------------------------------------------------ parameters
    @property
    def param_ids(self) -> dict[str, int]:
        return self.tuning.ids

    def param_values(self) -> dict[str, float]:
        """Every declared parameter, Q15 ones as fractions."""
        return self.tuning.values()

    def encode_param(self, name: str, value: float) -> tuple[int, int]:
        """Host-side check of one parameter write; returns (id, raw) or raises ParamError."""
        return self.tuning.encode(name, value)

    def set_params(self, values: dict[str, float], t_s: float | None = None, *, guard: bool = True) -> None:
        """Write a parameter set atomically (checked here first, then by the target; guarded)."""
        self.tuning.set(values, self.plant.t_s if t_s is None else t_s, guard=guard)

    def _message(self, text: str) -> None:
        self.messages.append(text)
        if len(self.messages) > 2 * MAX_MESSAGES:
            del self.messages[:-MAX_MESSAGES]

    def _segment(self, kind: str, t_s: float, ref_rpm: float = 0.0, ramp_s: float = 0.0) -> None:
        """Tell the segmentation (and the recording, for `report`) of a reference change, a press, the end."""
        if kind == "ref":
            self.segmenter.reference(t_s, ref_rpm, ramp_s)
            text = segmentation.reference_event(t_s, ref_rpm, ramp_s)
        elif kind == "press":
            self.segmenter.press(t_s)
            text = segmentation.press_event(t_s)
        else:
            self.segmenter.end(t_s)
            text = segmentation.end_event(t_s)
        if self.recorder is not None:
            self.recorder.event(text)

    def _on_param_change(self, t_s: float, text: str, values: dict[str, float]) -> None:
        self._scenario_k = min(self._scenario_k, self.periods_done)  # the write arms the guard: the parts look again
        if self.on_params is not None:
            self.on_params(values)
        self._message(f"{t_s:.3f} s: {text}")
        if self.recorder is not None:
            self.recorder.event(f"t={t_s:.6f} {text}", MARKER_PARAM)

    # ------------------------------------------------------------------ what the bench does
    def set_reference(self, rpm: float) -> None:
        """The speed reference, by the way the target's profile says it reaches the firmware."""
        self._ref_rpm = rpm
        reference = self.profile.reference
        if isinstance(reference, PotReference):
            self.plant.pot_fraction = reference.pot_fraction(rpm)
        elif isinstance(reference, ParamReference):
            self.tuning.set({reference.param: reference.value(rpm)}, self.plant.t_s, guard=False)

    def set_load(self, kind: str, value: float) -> None:
        """A load profile from here on: constant N*m, linear/quadratic coefficient, or locked."""
        from hilbench.plant.params import LoadProfile

        if kind in ("linear", "quadratic"):
            self.plant.load = LoadProfile(kind, coeff=value)  # type: ignore[arg-type, attr-defined]
        else:
            self.plant.load = LoadProfile(kind, torque_nm=value)  # type: ignore[arg-type, attr-defined]

    def press(self, button: str, t_s: float) -> None:
        """Hold a button (s2 start/stop, s3) for BUTTON_HOLD_S."""
        self._buttons |= INPUT_S2 if button == "s2" else INPUT_S3
        self._button_release_s = t_s + BUTTON_HOLD_S

    def _apply(self, event: Event, t_s: float) -> None:
        """One scenario event."""
        plant = self.plant
        if event.ref_rpm is not None:
            self._segment("ref", t_s, event.ref_rpm, event.ramp_s)
            if event.ramp_s > 0:
                self.player.ramps["ref_rpm"] = Ramp(t_s, t_s + event.ramp_s, self._ref_rpm, event.ref_rpm)
            else:
                self.player.ramps.pop("ref_rpm", None)
                self.set_reference(event.ref_rpm)
        elif event.pot is not None:
            plant.pot_fraction = event.pot
        elif event.load_nm is not None:
            self.set_load(event.load_kind, event.load_nm)
        elif event.vbus_v is not None:
            if event.ramp_s > 0:
                self.player.ramps["vbus_v"] = Ramp(t_s, t_s + event.ramp_s, plant.vbus_v, event.vbus_v)
            else:
                plant.vbus_v = self._supply_v = event.vbus_v
        elif event.press is not None:
            self.press(event.press, t_s)
            if event.press == "s2":
                self._segment("press", t_s)
        elif event.fault is not None:
            self.faults.apply(event.fault, t_s, event.fault_duration_s)
        elif event.params:
            try:
                self.tuning.set(dict(event.params), t_s)
            except ParamError as exc:
                self._message(f"{t_s:.3f} s: {exc}")
        elif event.end:
            if self.options.duration_s is None:
                self._end_reason = "scenario end"
            else:  # --duration wins: the state is held after the scenario's last event
                self._note(t_s, f"scenario end: held until the duration ({self.options.duration_s:g} s)")
        if self.recorder is not None:
            self.recorder.event(f"t={t_s:.6f} {event.describe()}", MARKER_EVENT)

    def apply_now(self, event: Event) -> None:
        """An event from a script or a test at the current period (recorded like a scenario event)."""
        self._apply(event, event.at_s)
        self._scenario_k = min(self._scenario_k, self.periods_done)  # ramps, the button's release

    def _tick_ramps(self, t_s: float) -> None:
        for kind, ramp in list(self.player.ramps.items()):
            value = ramp.value(t_s)
            if kind == "ref_rpm":
                self.set_reference(value)
            elif kind == "vbus_v":
                self.plant.vbus_v = self._supply_v = value
            if t_s >= ramp.t1:
                del self.player.ramps[kind]

    # ------------------------------------------------------------------ the parts' periods
    def _scenario_due(self, k: int) -> None:
        """Scenario events, ramps, the button release and fault expiry due in period k."""
        t_s, period_s = k * self._period_s, self._period_s
        if first_period_at(self.player.next_t_s, period_s) <= k:
            for event in self.player.due(t_s, period_s):
                self._apply(event, t_s)
            if self._end_reason is not None:
                return
        if self.player.ramps:
            self._tick_ramps(t_s)
        if first_period_at(self._button_release_s, period_s) <= k:
            self._buttons = 0
            self._button_release_s = math.inf
        if first_period_at(self.faults.clear_at_s, period_s) <= k:
            self.faults.apply("clear", t_s, None)
        self._scenario_k = first_period_at(min(
            self.player.next_t_s, self._button_release_s, self.faults.clear_at_s,
            t_s + period_s if self.player.ramps else math.inf), period_s)

    def _live_wanted(self, k: int) -> bool:
        """Whether the live part has work in the history periods from k on: a control socket, a
        `ctl step` in progress or a guard watching (the loop skips the call otherwise)."""
        return self.control is not None or bool(self._pending_steps) or k * self._period_s < self.tuning.watching

    def _live_due(self, k: int, drive: Any, guard_ref_rpm: float) -> None:
        """Every history period: the guard's look, `ctl step` progress, the control socket."""
        t_s = k * self._period_s
        if t_s < self.tuning.watching:  # live changes act from this period on: noted at its time
            peak = max(abs(i) for i in self.plant.i_abc)  # type: ignore[attr-defined]
            note = self.tuning.guard_check(t_s, guard_ref_rpm, self.plant.speed_rpm,  # type: ignore[attr-defined]
                                           peak, drive.state, drive.fault)
            if note is not None:
                self._note(t_s, note)
        if self._pending_steps:
            self._advance_steps(t_s)
        if self.control is not None and k % self.options.observe_every_periods == 0:
            for request in self.control.poll():
                self.handle_control(request, t_s)
            if self._end_reason is not None:
                return
            self._scenario_k = min(self._scenario_k, k + 1)  # a ctl ref may start a ramp

    # ------------------------------------------------------------------ the loop
    def run(self) -> Summary:
        """Handshake if needed, then run periods until the duration or the scenario ends."""
        self.begin()
        self.advance(self.planned_periods)
        return self.end()

    def begin(self) -> None:
        """Get ready to run: handshake if needed, the recorder's layout, pacing and the CPU request.
        Then `advance` runs periods, as many calls as wanted, and `end` closes the run."""
        options = self.options
        if self.hello is None:
            self.handshake()
        assert self.hello is not None
        summary = Summary(self.target_label, options.mode, options.period_us, firmware=self.hello.firmware_name)
        summary.recording = str(self.recorder.path) if self.recorder is not None else None
        self.summary = summary
        duration = options.duration_s if options.duration_s is not None else self.player.end_s
        self.planned_periods = max(1, round((5.0 if duration is None else duration) / self._period_s))
        self._duration_s = self.planned_periods * self._period_s
        realtime = options.mode == "realtime"
        self._pacing = RealtimePacing(
            options.period_us, label=self.target_label,
            abort_after=options.max_consecutive_overruns if options.overrun_policy == "abort" else None,
        ) if realtime else None
        self._qos = CpuLatencyRequest() if realtime and options.cpu_latency_qos else None
        if realtime and self._qos is None:
            summary.cpu_latency = "not requested ([link] cpu_latency_qos = false)"
        if self._qos is not None:
            self._qos.__enter__()  # released by end(), however the run ends
            summary.cpu_latency = self._qos.status
        self._lockstep_rtts = StreamingPercentiles()
        self._supply_v = self.plant.vbus_v
        self._scenario_k = first_period_at(self.player.next_t_s, self._period_s)
        self.faults.last_hall = self.plant.hall_bits
        self._wall_start = time.perf_counter()
        self._obs_last = (self._wall_start, 0)
        self._record = self._row_writer()
        self.plant.set_period(options.period_us, options.actuation_delay_periods)  # the plant's chunks and delay
        self._next_k = 0
        self._edge_s = self.plant.last_edge_s
        self._hall_before = self.plant.hall_bits  # the halls the target saw last (before a period's edges)
        self._max_edges = self.target_max_edges()
        self._drive: Any = None
        self._guard_ref = 0.0

    @property
    def ended(self) -> bool:
        """The scenario's end, `ctl stop` or a fault ended the run."""
        return self._end_reason is not None

    def advance(self, n_periods: int) -> bool:
        """Run up to ``n_periods`` more periods; False once the run has ended. A fault or Ctrl-C
        closes the run (recording with a fault marker) and propagates."""
        if self.ended:
            return False
        summary = self.summary
        gc_was_enabled = gc.isenabled()
        gc.disable()  # no collector pauses inside periods (recorded rows are plain numbers)
        try:
            try:
                self.periods_done = self._loop(self._next_k, self._next_k + n_periods, self._pacing)
            except (ValueError, OverflowError, ZeroDivisionError, struct.error, ProtocolError):
                diverged = self._divergence()
                if diverged is None:
                    raise
                raise SimulationError(diverged) from None
            self._next_k = self.periods_done
        except KeyboardInterrupt:
            summary.end_reason = "interrupted"
            self._stop_target()
            self._close(f"interrupted at period {self.periods_done}")
            raise
        except (LinkError, TargetError, SessionAborted, SimulationError, BenchLimitError) as exc:
            summary.end_reason = "fault"
            summary.fault = str(exc)
            self._end_reason = "fault"
            self._deenergise()
            self._close(f"fault at period {self.periods_done}: {exc}", fault=True)
            raise
        except Exception as exc:  # anything else (a bug, an observer's own error) left a period half done:
            summary.end_reason = "fault"  # the run cannot go on from there; what was recorded is kept
            summary.fault = f"{type(exc).__name__}: {exc}"
            self._end_reason = "fault"
            self._deenergise()
            self._close(f"error at period {self.periods_done}: {summary.fault}", fault=True)
            raise
        finally:
            if gc_was_enabled:
                gc.enable()
        return not self.ended

    def _divergence(self) -> str | None:
        """What is wrong when the plant's state left the physical (None: it did not)."""
        plant = self.plant
        try:
            state = {"speed": plant.w_m * RPM_PER_RAD_S, **{f"i{p}": i for p, i in zip("abc", plant.i_abc)}}  # type: ignore[attr-defined]
        except (AttributeError, ValueError, OverflowError):
            return None
        bad = {k: v for k, v in state.items() if not math.isfinite(v) or abs(v) > 1e9}
        if not bad:
            return None
        t_s = self.periods_done * self._period_s
        what = ", ".join(f"{k} {v:.3g}" for k, v in bad.items())
        return (f"the plant diverged at t={t_s:.6f} s (period {self.periods_done}: {what}); the config's motor "
                f"or load is beyond what the integrator follows at this period (try more [plant] substeps, "
                f"a larger j_kgm2 or l_h, a smaller load)")

    def end(self) -> Summary:
        """Close the run: the target stops, the recording is closed, the summary is made."""
        summary = self.summary
        if not self._closed:
            if self._end_reason is not None:
                summary.end_reason = self._end_reason
            self._stop_target()
            self._close(f"end: {summary.end_reason} at period {self.periods_done}")
        return summary

    def _close(self, note: str, fault: bool = False) -> None:
        self._closed = True
        if self._qos is not None:
            self._qos.__exit__(None, None, None)
        self._finish(self.summary, self._wall_start, self._pacing, note, fault=fault)

    def _loop(self, k_from: int, k_to: int, pacing: RealtimePacing | None) -> int:
        """Periods k_from..k_to-1: the parts run in the periods they are due; returns the next period.
        The hot path keeps its state in locals (a period is ~2 µs in process)."""
        plant, target_step, faults, history_every = self.plant, self.target.step, self.faults, self.options.history_every_periods
        plant_sense = plant.sense
        roles, edge_limit, new_sensors = tuple(self.hello.adc_roles), self.options.period_us * 10 - 1, tuple.__new__  # type: ignore[union-attr]
        plant_advance, scale = plant.advance, 1.0 / self.hello.pwm_period_counts  # type: ignore[union-attr]
        plant_edges, plant_marks, max_edges, hall_before = plant.edges, plant.index_marks, self._max_edges, self._hall_before
        pack, pack_telemetry, extend, rows = self._record or (None, None, None, None)
        host_ref = self._record_host_ref
        perf, rtts, rtt, late, marker = time.perf_counter, self._lockstep_rtts, 0.0, 0.0, 0
        edge_s, drive, guard_ref, sensor_faults, k = self._edge_s, self._drive, self._guard_ref, self.faults.active, k_from
        due_k = self._scenario_k  # the next period the scenario part asked for
        buttons, encoder_offset = self._buttons, faults.encoder_offset  # both change only when a part is due
        live = self._live_wanted(k_from)  # changes only when a part is due
        sample_k = -(-k_from // history_every) * history_every  # the next history period
        read_index = self.profile.has("encoder")  # the encoder's index mark drives INPUT_INDEX
        capacitor = self.options.bus_capacitance_f > 0.0 or self.options.overvoltage_v > 0.0
        if pacing is not None:
            pacing.start_at(k_from)
        try:
            for k in range(k_from, k_to):
                if k >= due_k:
                    self._scenario_due(k)
                    due_k, sensor_faults, buttons, encoder_offset = self._scenario_k, faults.active, self._buttons, faults.encoder_offset
                    live = self._live_wanted(k)
                    if self._end_reason is not None:
                        return k
                sample = k >= sample_k  # a history period (1 ms at 20 kHz): a compare, not a modulo
                if sample and live and drive is not None:
                    self._live_due(k, drive, guard_ref)
                    due_k, buttons, live = self._scenario_k, self._buttons, self._live_wanted(k)  # a ctl command may start a ramp
                    if self._end_reason is not None:
                        return k
                hall, tripped, index, count, adc = plant_sense(roles)  # the plant's sensors after the last period
                edges = () if edge_s is None else hall_edges(plant_edges(), edge_limit)  # every hall edge, timed
                if sensor_faults:
                    hall, edges = faults.filter(hall, edges)
                    sensor_faults = faults.active
                inputs = hall | buttons
                if read_index and index:
                    inputs |= INPUT_INDEX
                    edges = with_index_marks(edges, plant_marks(), edge_limit, hall_before)
                hall_before = hall
                if len(edges) > max_edges:
                    self._too_many_edges(k, len(edges))
                if tripped:  # the board's overcurrent comparator drives FAULT
                    inputs |= INPUT_FAULT
                    self._comparator(k)
                sensors = new_sensors(Sensors, (k & 0xFF, inputs, edges, (count + encoder_offset) & 0xFFFF, adc))
                if pacing is not None:
                    drive = pacing.exchange(k, sensors, drive, target_step)
                    rtt, late, marker = pacing.rtt, pacing.late, pacing.marker
                elif k & 63:
                    drive = target_step(sensors)
                else:  # lockstep: a sample of round-trip times, not every period's
                    sent = perf()
                    drive = target_step(sensors)
                    rtts.append(perf() - sent)
                _, da, db, dc, mode, state, sector, _, _, fault, tele = drive
                if tripped and mode == OUTPUT_OFF:  # the firmware's stop re-arms the comparator
                    self._comparator_cleared()
                if pack is not None:  # raw values in their own types (columns.session_row); the plant appends its state
                    if host_ref:
                        extend(pack(k, hall, sector, da, db, dc, mode, state, fault, rtt, late, marker, self._ref_rpm))
                    else:
                        extend(pack(k, hall, sector, da, db, dc, mode, state, fault, rtt, late, marker))
                    extend(pack_telemetry(*tele))  # a call on the tuple itself: cheaper than a `*` among positionals
                edge_s = plant_advance(da * scale, db * scale, dc * scale, mode, rows)  # it appends its outputs to the row
                if pacing is not None:
                    pacing.finished(k)
                if sample:
                    sample_k += history_every
                    guard_ref = self._sample(k, drive, pacing)
                    due_k = self._scenario_k  # the observer may have acted (a write, a press, apply_now)
                if capacitor:
                    self._bus(k)
        finally:
            self.periods_done = k
            self._edge_s, self._drive, self._guard_ref, self._hall_before = edge_s, drive, guard_ref, hall_before
        return k_to

    def _comparator(self, k: int) -> None:
        """The overcurrent comparator's latch is set: note the trip once."""
        if not self._trip_noted:
            self._trip_noted = True
            self._note(k * self._period_s, "overcurrent: the board's comparator tripped, FAULT input set")

    def _comparator_cleared(self) -> None:
        """The firmware turned its outputs off (its stop): the latch clears, as a stop/start re-arms
        the MCLV's FLTA."""
        self.plant.fault_input = False
        self._trip_noted = False

    def _bus(self, k: int) -> None:
        """The bus capacitor over period k: the supply only sources, so the bus rises above it while
        the bridge returns energy (the period's mean bus current is negative), and falls back to it as
        the bridge draws again; then the over-voltage limit."""
        plant, options = self.plant, self.options
        if options.bus_capacitance_f > 0.0:
            charged = plant.vbus_v - plant.i_bus * self._period_s / options.bus_capacitance_f  # type: ignore[attr-defined]
            plant.vbus_v = charged if charged > self._supply_v else self._supply_v
        if 0.0 < options.overvoltage_v < plant.vbus_v:
            self._end_on_limit(k, f"over-voltage: the bus is at {plant.vbus_v:.1f} V, beyond the {options.overvoltage_v:g} V "
                                  f"limit ([protection] overvoltage_v)")

    def _end_on_limit(self, k: int, reason: str) -> None:
        """A bench limit ends the run (the caller's `advance` closes it with a fault marker); a plant
        that left the physical (NaN, absurd values) is a diverged simulation, not a limit."""
        diverged = self._divergence()
        if diverged is not None:
            raise SimulationError(diverged)
        self._note(k * self._period_s, reason)
        raise BenchLimitError(f"{self.target_label}: {reason} at t={k * self._period_s:.4f} s")

    def _row_writer(self) -> tuple[Callable[..., bytes], Callable[..., bytes], Callable[[bytes], None], bytearray] | None:
        """The recorder's per-period pieces: the packers of the session's raw fields and of the
        telemetry, the row buffer's extend and the buffer (the plant's step appends its own state)."""
        recorder = self.recorder
        if recorder is None:
            return None
        row = session_row(self.profile, tuple(self.hello.telemetry_ids), self._period_s, self.plant.outputs)  # type: ignore[union-attr]
        recorder.metadata["history_every_periods"] = self.options.history_every_periods  # the report's segments
        recorder.start(row.layout)
        self._record_host_ref = any(name == "host_ref_rpm" for name, _ in row.own_fields)
        return (fields_struct(row.own_fields).pack, fields_struct(row.telemetry_fields).pack, recorder.rows.extend,
                recorder.rows.data)

    def _sample(self, k: int, drive: Any, pacing: RealtimePacing | None) -> float:
        """Every history period: the overspeed limit, the speed history, a flush, the observer.
        Returns the reference the guard compares with (the firmware's own when it reports one)."""
        tele = drive[10]
        (i_meas, s_meas), (i_ref, s_ref) = self._speed_telemetry
        meas = tele[i_meas] * s_meas if i_meas >= 0 else math.nan
        guard_ref = tele[i_ref] * s_ref if i_ref >= 0 else self._ref_rpm
        t_s, plant_rpm = k * self._period_s, self.plant.w_m * RPM_PER_RAD_S
        self.history.append((t_s, self._ref_rpm, plant_rpm, meas))
        self.segmenter.sample(t_s, plant_rpm, meas)
        if k % self.options.observe_every_periods == 0 and k:
            if self.display is not None:  # the scope takes its rows before a flush empties the buffer
                self.display.due(k, drive, pacing)
            if self.recorder is not None:
                self.recorder.maybe_flush()
            if self.observer is not None:
                self.observer(self._snapshot(k, drive, meas, pacing))
        if not -self._overspeed_rpm <= plant_rpm <= self._overspeed_rpm:
            self._end_on_limit(k, f"overspeed: the plant turns at {plant_rpm:.0f} rpm, beyond the "
                                  f"{self.options.overspeed_rpm:g} rpm limit ([protection] overspeed_rpm)")
        return guard_ref

    def _stop_target(self) -> None:
        """A clean end: the target stops its outputs (S2 as a command)."""
        try:
            self.target.stop()
        except HilbenchError:
            pass

    def _deenergise(self) -> None:
        """Open every switch of the plant's inverter: the motor coasts whatever the target does."""
        try:
            self.plant.step(0.0, 0.0, 0.0, OUTPUT_OFF, self._period_s)
        except Exception:  # noqa: BLE001 - de-energising must never mask the original fault
            pass

    # ------------------------------------------------------------------ control socket
    def handle_control(self, request: ControlRequest, t_s: float) -> None:
        """Answer one control-socket request (see hilbench.bench.control)."""
        cmd, args = request.cmd, request.args
        try:
            if cmd == "get":
                request.reply(True, "ok", {"params": self.param_values(), "t_s": t_s, "ref_rpm": self._ref_rpm,
                                           "tunable": list(self.profile.tunable)})
            elif cmd == "set":
                self.tuning.set({str(k): float(v) for k, v in args["params"].items()}, t_s)
                request.reply(True, f"applied at t={t_s:.4f} s", {"params": self.param_values()})
            elif cmd == "ref":
                self.player.ramps.pop("ref_rpm", None)
                self.set_reference(float(args["rpm"]))
                self._segment("ref", t_s, float(args["rpm"]))
                self._note(t_s, f"ref {args['rpm']} rpm (ctl)")
                request.reply(True, f"reference {args['rpm']} rpm at t={t_s:.4f} s")
            elif cmd == "step":
                self._start_ctl_step(request, float(args["from_rpm"]), float(args["to_rpm"]), t_s)
            elif cmd == "stop":
                self._end_reason = "stopped by ctl"
                self._segment("end", t_s)
                self._note(t_s, "stop (ctl)")
                request.reply(True, f"run ends at t={t_s:.4f} s")
            elif cmd == "save":  # a raw-socket client's save; `hilbench ctl save` writes where the user is
                from hilbench.bench.tuning import saved_fragment

                data = {"params": self.param_values(), "t_s": t_s, "ref_rpm": self._ref_rpm,
                        "tunable": list(self.profile.tunable)}
                try:
                    with open(str(args["file"]), "w", encoding="utf-8") as handle:
                        handle.write(saved_fragment(data))
                except OSError as exc:
                    request.reply(False, f"save {args['file']}: {exc.strerror or exc}")
                else:
                    request.reply(True, f"wrote {args['file']}", data)
            elif cmd == "start":
                self.target.start()
                self._note(t_s, "start (ctl)")
                request.reply(True, f"start command sent at t={t_s:.4f} s")
            elif cmd == "press":
                button = str(args["button"])
                self.press(button, t_s)
                self._scenario_k = min(self._scenario_k, self.periods_done)  # its release is due
                if button == "s2":
                    self._segment("press", t_s)
                self._note(t_s, f"press {button} (ctl)")
                request.reply(True, f"{button} pressed at t={t_s:.4f} s")
            elif cmd == "guard":
                self.tuning.guard = dataclasses.replace(self.tuning.guard, enabled=bool(args["on"]))
                state = "on" if self.tuning.guard.enabled else "off"
                self._note(t_s, f"guard {state} (ctl)")
                request.reply(True, f"guarded tuning {state}")
            elif cmd == "stream":  # a scope's decimated view (hilbench.scope)
                if self.display is None:
                    from hilbench.scope.stream import DisplayStream

                    self.display = DisplayStream(self)
                request.reply(True, "stream", self.display.request(int(args["since"]), args["columns"], t_s))
            elif cmd == "load":
                self.set_load("constant", float(args["nm"]))
                self._note(t_s, f"load {args['nm']} N*m (ctl)")
                request.reply(True, f"load {args['nm']} N*m at t={t_s:.4f} s")
            else:
                request.reply(False, f"command {cmd!r} is not available in this session")
        except HilbenchError as exc:
            request.reply(False, str(exc))
        except (ValueError, TypeError, ArithmeticError, KeyError) as exc:  # a request must never end the run
            if not getattr(request, "replied", False):
                request.reply(False, f"{cmd}: refused ({type(exc).__name__}: {str(exc)[:80]})")

    def _start_ctl_step(self, request: ControlRequest, from_rpm: float, to_rpm: float, t_s: float) -> None:
        """`ctl step A B`: reference A now, B after a 1 s hold; reply with the metrics 1 s later."""
        self.player.ramps.pop("ref_rpm", None)
        self.set_reference(from_rpm)
        self._segment("ref", t_s, from_rpm)
        self._note(t_s, f"step {from_rpm:g} -> {to_rpm:g} rpm (ctl): hold {from_rpm:g}")
        self._pending_steps.append(_CtlStep(request, from_rpm, to_rpm, t_s + CTL_STEP_HOLD_S))

    def _advance_steps(self, t_s: float) -> None:
        for step in list(self._pending_steps):
            if t_s < step.due_s:
                continue
            if step.t_step_s is None:  # the hold is over: step now
                self.set_reference(step.to_rpm)
                self._segment("ref", t_s, step.to_rpm)
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
        reference = self.profile.reference
        ref = reference.effective_rpm(to_rpm) if reference is not None else to_rpm
        after = [(tt, v) for tt, v in zip(t, y) if tt >= t_step]
        metrics = step_metrics([a for a, _ in after], [b for _, b in after], y0=sum(before) / len(before),
                               y_final_ref=ref, t_step_s=t_step)
        return {k: v for k, v in metrics.as_dict().items() if k in STEP_REPLY_KEYS}

    def _note(self, t_s: float, text: str) -> None:
        self._message(f"{t_s:.3f} s: {text}")
        if self.recorder is not None:
            self.recorder.event(f"t={t_s:.6f} {text}", MARKER_EVENT)

    # ------------------------------------------------------------------ reports
    def _snapshot(self, k: int, drive: Any, meas: float, pacing: RealtimePacing | None) -> Snapshot:
        rtts = pacing.rtts if pacing is not None else self._lockstep_rtts
        stats = percentiles([r * 1e6 for r in rtts.recent])
        now = time.perf_counter()
        last_wall, last_k = self._obs_last
        rate = (k - last_k) / max(now - last_wall, 1e-9)
        self._obs_last = (now, k)
        ia, ib, ic = self.plant.i_abc  # type: ignore[attr-defined]
        telemetry = {name: drive[10][index] * scale for name, (index, scale) in self._tele_index.items()}
        return Snapshot(
            t_s=k * self._period_s, duration_s=self._duration_s, period=k, ref_rpm=self._ref_rpm,
            speed_rpm=self.plant.speed_rpm, measured_rpm=meas, state=drive.state, sector=drive.sector,  # type: ignore[attr-defined]
            direction_ccw=bool(drive.direction_ccw), output_mode=drive.output_mode,
            duties=(drive.duty_a, drive.duty_b, drive.duty_c), i_abc=(ia, ib, ic), i_bus=self.plant.i_bus,  # type: ignore[attr-defined]
            telemetry=telemetry, periods_per_s=rate, rtt_p50_us=stats.get("p50", math.nan),
            rtt_p99_us=stats.get("p99", math.nan), link=self.link_stats(),
            overruns=pacing.overruns if pacing is not None else 0, messages=self.messages[-4:],
            history=self.history,  # the dashboard decimates it to its width
        )

    def _finish(self, summary: Summary, wall_start: float, pacing: RealtimePacing | None, note: str,
                fault: bool = False) -> None:
        summary.periods = self.periods_done
        summary.sim_s = self.periods_done * self._period_s
        summary.wall_s = time.perf_counter() - wall_start
        rtts = pacing.rtts if pacing is not None else self._lockstep_rtts
        summary.rtt_us = rtts.percentiles(1e6)
        if pacing is not None:
            summary.lateness_us = pacing.lateness.percentiles(1e6)
            summary.overruns = pacing.overruns
            summary.skipped_periods = pacing.skipped
        summary.link = self.link_stats()
        if self.recorder is not None:
            self.recorder.event(segmentation.end_event(summary.sim_s))
        summary.segments = self.segmenter.finish(summary.sim_s)
        try:
            summary.params = self.param_values() if not fault else {}
        except HilbenchError:
            summary.params = {}
        if self.recorder is not None:
            if fault:
                self.recorder.mark_last(MARKER_FAULT)
            self.recorder.close(note)
            summary.rows_recorded = self.recorder.rows_written


__all__ = [
    "GuardSettings",
    "Segment",
    "Session",
    "SessionAborted",
    "SessionOptions",
    "Snapshot",
    "Summary",
    "first_period_at",
    "PERIOD_TOLERANCE",
]
