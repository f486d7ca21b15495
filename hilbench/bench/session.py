"""The bench session: handshake, the per-period exchange, the plant's period, and the parts around them.

Period k (docs/design.md, timing contract): sample the plant at t_k, send Sensors(seq=k), get
Drive(seq=k), and the plant integrates its period with that Drive (its actuation delay is the
plant's). Around that hot path each concern is a part (hilbench.bench.parts) that says the next
period it acts in: the scenario (references, load, buttons, bus, faults), live tuning with its
guard and the control socket, the history sample with the observer and the display stream, the
bus capacitor. `_loop` runs the periods between in a tight loop (`_tight_runner`) up to the
next period any part is due in, and the due parts there; sensor faults filter the Sensors while
one is in force (hilbench.bench.faults); real time paces each exchange (`RealtimePacing`). The
session knows no terminal and no firmware: what it needs of the target comes from the target's
profile and its HELLO.
"""

from __future__ import annotations

import gc
import math
import os
import struct
import time
from typing import TYPE_CHECKING, Any, Callable, Generator, Iterable, Protocol

from hilbench.bench import segments as segmentation
from hilbench.bench.clock import CpuLatencyRequest
from hilbench.bench.columns import BENCH_COLUMNS, session_row
from hilbench.bench.control import COMMANDS, ControlRequest
from hilbench.bench.faults import SensorFaults, SensorSpec
from hilbench.bench.history import SpeedHistory
from hilbench.bench.livetuning import GuardSettings, LiveTuning
from hilbench.bench.pacing import RealtimePacing, SessionAborted
from hilbench.bench.parts import BusPart, HistoryPart, LivePart, ScenarioPart, Schedule
from hilbench.bench.recorder import MARKER_EVENT, MARKER_FAULT, MARKER_PARAM, Recorder, fields_struct
from hilbench.bench.sensing import hall_edges, with_index_marks
from hilbench.bench.scenario import PERIOD_TOLERANCE, Event, ScenarioPlayer, first_period_at
from hilbench.bench.settings import SessionOptions
from hilbench.bench.streamstats import StreamingPercentiles
from hilbench.bench.summary import Segment, Snapshot, Summary
from hilbench.errors import (BenchLimitError, ConfigError, HilbenchError, LinkError, ProtocolError, RecordingError,
                             SimulationError, TargetError)
from hilbench.plant.model import RPM_PER_RAD_S, PlantOutput
from hilbench.plant.period import Period
from hilbench.protocol import (
    MAX_EDGES,
    PROTOCOL_VERSION,
    Drive,
    HostHello,
    Input,
    Mode,
    OutputMode,
    Sensors,
    TargetHello,
    TargetInfo,
    check_target_hello,
)
from hilbench.targets.base import Target
from hilbench.targets.profile import ParamReference, PotReference, TargetProfile
from hilbench.targets.describe import describe as describe_firmware, described_profile
from hilbench.targets.registry import profile_for_firmware, registered_for_firmware

if TYPE_CHECKING:
    from hilbench.bench.display import DisplayStream

try:  # the lockstep span in C (optional, built with the C cores)
    from hilbench.bench import _span
except ImportError:  # pragma: no cover - no compiler at install time
    _span = None  # type: ignore[assignment]

INPUT_INDEX = int(Input.INDEX)
INPUT_FAULT = int(Input.FAULT)
HALL_MASK = int(Input.HALL_A | Input.HALL_B | Input.HALL_C)
OUTPUT_OFF = int(OutputMode.OFF)
#: the Drive's fields as the tight loop unpacks them into variables of these names (one unpack of
#: the tuple; an attribute read each would cost more than the period's arithmetic)
DRIVE_FIELDS = ("seq", "duty_a", "duty_b", "duty_c", "output_mode", "state", "sector", "direction_ccw",
                "required_ccw", "fault", "telemetry")
if Drive._fields != DRIVE_FIELDS:  # the unpack below names every field: a changed message must not pass
    raise ProtocolError(f"session: Drive fields changed to {Drive._fields}; update DRIVE_FIELDS and the loop")

START_PRESS_S = segmentation.START_PRESS_S  # presses this soon after a reference are starts, not stops
#: speed samples kept for the dashboard and `ctl step` (the newest; ~8 s at the default 1 ms)
HISTORY_SAMPLES = 8192
#: messages kept for the dashboard
MAX_MESSAGES = 64


class PlantLike(Protocol):
    """What the session uses of a plant (hilbench.plant.model.Plant)."""

    hall_bits: int
    last_edge_s: float | None
    pot_fraction: float
    vbus_v: float
    w_m: float
    i_bus: float
    t_s: float
    speed_rpm: float
    i_abc: tuple[float, float, float]
    fault_input: bool  # the board's overcurrent comparator, latched (drives the target's FAULT input)
    outputs: tuple[PlantOutput, ...]  # what it records every period (append_state)
    load: Any

    def set_period(self, period_us: int, actuation_delay_periods: int = 0, duty_full_scale: float = 1.0) -> None: ...
    def advance(self, duty_a: float, duty_b: float, duty_c: float, output_mode: int,
                state_to: bytearray | None = None, /) -> float | None: ...
    def step(self, duty_a: float, duty_b: float, duty_c: float, output_mode: int, dt_s: float,
             state_to: bytearray | None = None, /) -> float | None: ...
    def sense(self, roles: tuple[int, ...]) -> tuple[int, bool, bool, int, tuple[int, ...]]: ...
    def edges(self) -> tuple[tuple[float, int], ...]: ...  # every hall edge of the last advance
    def index_marks(self) -> tuple[float, ...]: ...  # every encoder index mark of the last advance


class ControlSource(Protocol):
    """Where control requests come from (hilbench.bench.control.ControlServer)."""

    def poll(self) -> list[ControlRequest]: ...


class Session:
    """One bench run over a target and a plant."""

    c_span = True  # the periods between events in C when plant and target have C steps (`_c_span`)

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
        control: ControlSource | None = None,
        link_stats: Callable[[], dict[str, int]] | None = None,
        target_label: str = "target",
        guard: GuardSettings = GuardSettings(),
    ) -> None:
        self.target = target
        self.plant = plant
        self.options = options
        self.period = Period(options.period_us)
        self.recorder = recorder
        self.observer = observer
        self.link_stats = link_stats or (lambda: {})
        self.target_label = target_label
        self.expected_profile = profile
        self.profile: TargetProfile = profile or profile_for_firmware("")
        self.hello: TargetHello | None = None
        self.predicting = False  # lockstep with the duties predicted over each period (HostHello mode PREDICT)
        self.target_info: TargetInfo | None = None  # TargetDescribe's answer (None: the target has none)
        self.tuning = LiveTuning(target, self.profile, target_label, guard)
        self.tuning.on_change = self._on_param_change
        self.faults = SensorFaults()
        self.messages: list[str] = []
        #: (t_s, ref_rpm, plant_rpm, measured_rpm): the newest HISTORY_SAMPLES (memory stays flat)
        self.history = SpeedHistory(HISTORY_SAMPLES)
        self.segmenter = segmentation.Segmenter()
        self.on_params: Callable[[dict[str, float]], None] | None = None
        self.periods_done = 0
        self.ref_rpm = 0.0  # the reference the host asks for now
        self.drive: Drive | None = None  # the last Drive
        self.pacing: RealtimePacing | None = None
        #: real time: called once, with the run's time, when overruns say other work takes the run's CPU
        #: (the bench raises the run to SCHED_FIFO then: [link] realtime_fifo = "contended"); set before
        #: `begin`, which hands it to the pacing
        self.on_contended: Callable[[float], None] | None = None
        self.lockstep_rtts = StreamingPercentiles()
        self.telemetry_index: dict[str, tuple[int, float]] = {}
        self.duration_s = 0.0
        self.display: Any = None  # the scope's display stream (hilbench.bench.display), made by `stream`
        self.scenario = ScenarioPart(self, events)
        self.live = LivePart(self, control)
        self.sampler = HistoryPart(self, self.live)
        after = [self.sampler] + ([BusPart(self, self.scenario)]
                                  if options.bus_capacitance_f > 0.0 or options.overvoltage_v > 0.0 else [])
        self._schedule = Schedule([self.scenario, self.live], after, lambda: self.ended)
        self._end_reason: str | None = None
        self._closed = False
        self._qos: CpuLatencyRequest | None = None
        self._trip_noted = False  # the overcurrent comparator's trip is an event once per latch
        self._edge_s: float | None = None
        self._hall_before = 0
        self._next_k = 0
        self._rows_changed = False  # watch_rows changed the row writer: the tight loop is made again
        self._span_samples: bytearray | None = None  # the C span's history samples (None: no C span runs)
        self._span_hand_over_at: Callable[[], int] | None = None  # the recorder's, when the C span hands its rows over

    @property
    def player(self) -> ScenarioPlayer:
        """The scenario's player (its events and ramps)."""
        return self.scenario.player

    @property
    def control(self) -> ControlSource | None:
        return self.live.control

    @property
    def hall_bits_sent(self) -> int:
        """The plant's halls of the last period's Sensors (before any sensor fault's filter)."""
        return self._hall_before

    # ------------------------------------------------------------------ handshake
    def handshake(self) -> TargetHello:
        """Agree period and mode; learn the target's profile, telemetry and parameters."""
        mode = 0 if self.options.mode == "lockstep" else 1
        # the watchdog in both modes: a host killed turns the target's outputs off. In lockstep a
        # trip leaves the firmware's state alone (its time stands still while the host is away:
        # the runtime's and the emulators' lockstep watchdog, at least 1 s), so a host that pauses
        # on a loaded machine changes no recording (tests/test_lockstep_pause.py)
        host = HostHello(0, PROTOCOL_VERSION, self.options.period_us, mode, self.options.watchdog_ms)
        hello = self.target.hello(host)
        check_target_hello(hello, where=self.target_label)  # protocol version, schema fingerprint, declarations
        self.predicting = False
        # a target on a link (a firmware on the C runtime can predict; `serve` refuses for a Python one);
        # an in-process target never predicts, so one that ignores the mode is not taken at its word
        if mode == int(Mode.LOCKSTEP) and self.options.predict_duties and getattr(self.target, "link", None) is not None \
                and hello.pwm_freq_hz * self.options.period_us >= 2_000_000:  # periods of 2 PWM periods or more
            hello = self._hello_predicting(host) or hello
        self.hello = hello
        found = registered_for_firmware(hello.firmware_name)
        if found is None:  # no module knows it: the firmware's own description (protocol 3)
            description = describe_firmware(self.target, hello, self.target_label)
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
            self.telemetry_index[column.column] = (index, column.scale)
        self.faults.spec = SensorSpec(adc_full_scale=(1 << hello.adc_bits) - 1)
        self._refuse_unknown_set_names()  # here, before the bench opens a recording for a run that cannot be
        return hello

    def _hello_predicting(self, host: HostHello) -> TargetHello | None:
        """HostHello mode PREDICT: lockstep whose Drives carry the mean duties the firmware is predicted
        to have over the next period (firmware/runtime/hrt_link.c), so that a period of many PWM periods
        does not hold the duties of its start for all of it. A target that refuses (a Python model, a
        build without room for the copy of the state) gets the plain lockstep HostHello again: None."""
        try:
            hello = self.target.hello(host._replace(mode=int(Mode.PREDICT)))
        except (TargetError, ConfigError):  # a refusal; a link error is no answer and ends the run
            hello = self.target.hello(host)  # as agreed before the refusal, whatever the target did with it
            check_target_hello(hello, where=self.target_label)
            return None
        check_target_hello(hello, where=self.target_label)
        self.predicting = True
        return hello

    def target_max_edges(self) -> int:
        """The input edges one Sensors may carry: the target's TargetInfo.max_edges, else the protocol's."""
        info = self.target_info
        return min(int(info.max_edges), MAX_EDGES) if info is not None and info.max_edges else MAX_EDGES

    def too_many_edges(self, k: int, n: int) -> None:
        """Period k has more input edges than the target takes in one Sensors: a bench limit."""
        period_us, most = self.options.period_us, self.target_max_edges()
        raise BenchLimitError(
            f"{self.target_label}: period {k} has {n} input edges (hall and index), the target takes at most "
            f"{most} a period (its TargetInfo.max_edges); use a shorter link.period_us (at most "
            f"{max(1, period_us * most // (n + 1))} us at this speed) or a firmware built with a "
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
        self.tuning.set(values, self.now_s if t_s is None else t_s, guard=guard)

    def _on_param_change(self, t_s: float, text: str, values: dict[str, float]) -> None:
        if self.on_params is not None:
            self.on_params(values)
        self.message(f"{t_s:.3f} s: {text}")
        if self.recorder is not None:
            self.recorder.event(f"t={t_s:.6f} {text}", MARKER_PARAM)

    # ------------------------------------------------------------------ what the bench does
    @property
    def now_s(self) -> float:
        """The start of the period the bench is in (the plant's clock: one time base)."""
        return self.period.t_s(self.periods_done)

    def set_reference(self, rpm: float) -> None:
        """The speed reference, by the way the target's profile says it reaches the firmware."""
        self.ref_rpm = rpm
        self.tuning.reference_changed(self.now_s)  # gains on probation are watched from here
        reference = self.profile.reference
        if isinstance(reference, PotReference):
            self.plant.pot_fraction = reference.pot_fraction(rpm)
        elif isinstance(reference, ParamReference):
            self.tuning.set({reference.param: reference.value(rpm)}, self.now_s, guard=False)

    def reference_now(self, rpm: float, t_s: float, note: str) -> None:
        """A reference from the control socket: any reference ramp ends, a segment starts, noted."""
        self.player.ramps.pop("ref_rpm", None)
        self.set_reference(rpm)
        self.segment("ref", t_s, rpm)
        self.note(t_s, note)

    def set_load(self, kind: str, value: float) -> None:
        """A load profile from here on: constant N*m, linear/quadratic coefficient, or locked."""
        from hilbench.plant.params import LoadProfile

        if kind in ("linear", "quadratic"):
            self.plant.load = LoadProfile(kind, coeff=value)  # type: ignore[arg-type]
        else:
            self.plant.load = LoadProfile(kind, torque_nm=value)  # type: ignore[arg-type]

    def press(self, button: str, t_s: float) -> None:
        """Hold a button (s2 start/stop, s3) for `parts.BUTTON_HOLD_S`."""
        self.scenario.press(button, t_s)
        self.scenario.wake(self.periods_done)  # its release is due

    def send_start(self, t_s: float) -> None:
        """The target's Start command (`ctl start`)."""
        self.target.start()

    def apply_now(self, event: Event) -> None:
        """An event from a script or a test at the current period (recorded like a scenario event)."""
        self.scenario.apply(event, event.at_s)
        self.scenario.wake(self.periods_done)  # ramps, the button's release

    def scenario_end(self, t_s: float) -> None:
        """The scenario's end event: the run ends, unless a duration was asked for."""
        if self.options.duration_s is None:
            self._end_reason = "scenario end"
        else:  # --duration wins: the state is held after the scenario's last event
            self.note(t_s, f"scenario end: held until the duration ({self.options.duration_s:g} s)")

    def stop_run(self, t_s: float, reason: str, note: str) -> None:
        """End the run at this period (`ctl stop`)."""
        self._end_reason = reason
        self.segment("end", t_s)
        self.note(t_s, note)

    def watch_rows(self, on: bool) -> None:
        """Rows for the scope in a run that records none: a `WindowRecorder` (bounded, never saved)
        while a scope watches, nothing again when it stops. Between periods only (the parts' thread);
        the tight loop picks the new row writer up before its next periods."""
        from hilbench.bench.recorder import WindowRecorder

        window = isinstance(self.recorder, WindowRecorder)
        if on and self.recorder is None and self.hello is not None:
            self.recorder = WindowRecorder(max(1, round(self.period.per_s)))  # type: ignore[assignment]
        elif not on and window:
            self.recorder = None
        else:
            return
        if hasattr(self, "summary"):  # begun: the loop's row writer follows
            self._record = self._row_writer()
            self._rows_changed = True

    def display_stream(self) -> "DisplayStream":
        """The scope's display stream, made on the first request."""
        if self.display is None:
            from hilbench.bench.display import DisplayStream

            self.display = DisplayStream(self)
        return self.display

    def _refuse_unknown_set_names(self) -> None:
        """A scenario `set` of a parameter the target did not declare (a typo) is refused at the
        handshake, as a gains file's is: in the run it could only be refused, the run going on; and
        before the recording opens, which would be left with its header only."""
        declared = self.tuning.ids
        for event in self.player.events:
            unknown = [name for name, _ in event.params if name not in declared]
            if unknown:
                raise ConfigError(f"[[scenario]] at_s = {event.at_s:g}: set {unknown[0][:40]!r}: {self.target_label} "
                                  f"declares no such parameter (it has {', '.join(sorted(declared)) or 'none'})")

    # ------------------------------------------------------------------ notes
    def message(self, text: str) -> None:
        self.messages.append(text)
        if len(self.messages) > 2 * MAX_MESSAGES:
            del self.messages[:-MAX_MESSAGES]

    def note(self, t_s: float, text: str) -> None:
        self.message(f"{t_s:.3f} s: {text}")
        if self.recorder is not None:
            self.recorder.event(f"t={t_s:.6f} {text}", MARKER_EVENT)

    def segment(self, kind: str, t_s: float, ref_rpm: float = 0.0, ramp_s: float = 0.0) -> None:
        """Tell the segmentation (and the recording, for `report`) of a reference change, a press, the end."""
        text = self.segmenter.tell(kind, t_s, ref_rpm, ramp_s)
        if self.recorder is not None:
            self.recorder.event(text)

    # ------------------------------------------------------------------ control socket
    def handle_control(self, request: ControlRequest, t_s: float) -> None:
        """Answer one control-socket request: its command in `control.COMMANDS` acts on the session."""
        command = COMMANDS.get(request.cmd)
        try:
            if command is None:
                request.reply(False, f"command {request.cmd!r} is not available in this session")
            else:
                command.act(self, request, t_s)
        except HilbenchError as exc:
            request.reply(False, str(exc))
        except (ValueError, TypeError, ArithmeticError, KeyError) as exc:  # a request must never end the run
            if not getattr(request, "replied", False):
                request.reply(False, f"{request.cmd}: refused ({type(exc).__name__}: {str(exc)[:80]})")

    # ------------------------------------------------------------------ the run
    def run(self) -> Summary:
        """Handshake if needed, then run periods until the duration or the scenario ends."""
        self.begin()
        self.advance(self.planned_periods)
        return self.end()

    def begin(self) -> None:
        """Get ready to run: handshake if needed, the recorder's layout, the plant's period, pacing
        and the CPU request. Then `advance` runs periods, as many calls as wanted, and `end` closes."""
        options = self.options
        if self.hello is None:
            self.handshake()
        assert self.hello is not None
        summary = Summary(self.target_label, options.mode, options.period_us, firmware=self.hello.firmware_name,
                          predicted_duties=self.predicting)
        summary.recording = str(self.recorder.path) if self.recorder is not None else None
        self.summary = summary
        duration = options.duration_s if options.duration_s is not None else self.player.end_s
        self.planned_periods = max(1, self.period.count(5.0 if duration is None else duration))
        self.duration_s = self.period.t_s(self.planned_periods)
        if options.mode == "realtime":
            self._begin_realtime(summary)
        self.lockstep_rtts = StreamingPercentiles()
        self.scenario.start(self.plant.vbus_v)
        self._wall_start = time.perf_counter()
        missing = (-1, 0.0)  # (telemetry index, scale) of the firmware's measured speed and reference
        self.sampler.start((self.telemetry_index.get(self.profile.speed_column or "", missing),
                            self.telemetry_index.get("ref_speed_rpm", missing)), self._wall_start)
        self._record = self._row_writer()
        self.plant.set_period(options.period_us, options.actuation_delay_periods, self.hello.pwm_period_counts)
        self._next_k = 0
        self._edge_s = self.plant.last_edge_s
        self._hall_before = self.plant.hall_bits  # the plant's halls at the last Sensors (before a period's edges)
        self.drive = None

    def _begin_realtime(self, summary: Summary) -> None:
        """Pacing and, when asked for, the CPU wake-up latency request (released by `end`)."""
        options = self.options
        self.pacing = RealtimePacing(
            options.period_us, label=self.target_label,
            abort_after=options.max_consecutive_overruns if options.overrun_policy == "abort" else None,
            on_contended=self.on_contended,
        )
        if not options.cpu_latency_qos:
            summary.cpu_latency = "not requested ([link] cpu_latency_qos = false)"
            return
        self._qos = CpuLatencyRequest()
        self._qos.__enter__()  # released by end(), however the run ends
        summary.cpu_latency = self._qos.status

    @property
    def samples_in_c(self) -> bool:
        """Whether the next periods run in the C span, which takes their history samples itself
        (a sensor fault in force sends them to the Python loop)."""
        return self._span_samples is not None and not self.faults.on

    @property
    def rows_in_c(self) -> bool:
        """Whether the next periods run in the C span and it hands the recorder's chunks over itself
        (`Recorder.span_rows`): no part need end the span for the recorder's writes."""
        return self._span_hand_over_at is not None and self.samples_in_c and self._span_hand_over_at() > 0

    @property
    def ended(self) -> bool:
        """The scenario's end, `ctl stop` or a fault ended the run."""
        return self._end_reason is not None

    def advance(self, n_periods: int) -> bool:
        """Run up to ``n_periods`` more periods; False once the run has ended. A fault or Ctrl-C
        closes the run (recording with a fault marker) and propagates."""
        if self.ended:
            return False
        expect_rows = getattr(self.recorder, "expect_rows", None)
        if expect_rows is not None and self._next_k == 0 and n_periods == self.planned_periods and self.pacing is None:
            # the whole planned run in one call: its NPZ archive written as it goes (lockstep only: in real
            # time the writer's thread would share the CPU the run is pinned to)
            expect_rows(n_periods)
        gc_was_enabled = gc.isenabled()
        gc.disable()  # no collector pauses inside periods (recorded rows are plain numbers)
        try:
            self.periods_done = self._loop_checked(self._next_k, self._next_k + n_periods)
            self._next_k = self.periods_done
        except KeyboardInterrupt:
            self.summary.end_reason = "interrupted"
            try:
                self._stop_target()  # (a second Ctrl-C while the target is asked: the recording still closes)
            finally:
                self._close(f"interrupted at period {self.periods_done}")
            raise
        except (LinkError, TargetError, SessionAborted, SimulationError, BenchLimitError) as exc:
            self._fault(f"fault at period {self.periods_done}: {exc}", str(exc))
            raise
        except Exception as exc:  # anything else (a bug, an observer's own error) left a period half done:
            self._fault(f"error at period {self.periods_done}: {type(exc).__name__}: {exc}",
                        f"{type(exc).__name__}: {exc}")  # the run cannot go on; what was recorded is kept
            raise
        finally:
            if gc_was_enabled:
                gc.enable()
        return not self.ended

    def _loop_checked(self, k_from: int, k_to: int) -> int:
        """`_loop`, with an arithmetic error of a plant that left the physical reported as a diverged
        simulation."""
        try:
            return self._loop(k_from, k_to)
        except (ValueError, OverflowError, ZeroDivisionError, struct.error, ProtocolError):
            diverged = self._divergence()
            if diverged is None:
                raise
            raise SimulationError(diverged) from None

    def _loop(self, k_from: int, k_to: int) -> int:
        """Periods k_from..k_to-1: plain periods run tight up to the next period any part is due in;
        there the parts due act before and after its exchange. Returns the next period (the one the
        run ended in, when a part ended it)."""
        schedule = self._schedule
        run = self._periods_runner()
        k = k_from
        if self.pacing is not None:
            self.pacing.start_at(k_from)
        while k < k_to:
            self.periods_done = k  # a part's fault, or the end, is at this period
            before_k = schedule.next_before(k)
            if before_k <= k:
                if schedule.run_before(k):
                    return k
                before_k = schedule.next_before(k + 1)
            if self._rows_changed:  # a scope started or stopped watching a run without a recording
                self._rows_changed = False
                run = self._periods_runner()
            after_k = schedule.next_after(k)  # (the history part's periods depend on the runner: after it)
            stop = after_k + 1
            if before_k < stop:
                stop = before_k
            k = run((k, k_to if k_to < stop else int(stop)))
            if after_k == k - 1:
                self.periods_done = after_k
                schedule.run_after(after_k)
        return k

    def _periods_runner(self) -> Callable[[tuple[int, int]], int]:
        """What runs the periods [k, stop) between the parts': the tight loop (`_tight_runner`), or
        its readable form period by period (`_periods_one_by_one`, for tests); returns `stop`."""
        self._span_samples = None
        self._span_hand_over_at = None
        if getattr(self, "_readable_periods", False):
            return lambda span: self._periods_one_by_one(*span)
        return self._tight_runner()

    def _tight_runner(self) -> Callable[[tuple[int, int]], int]:
        """`_periods_one_by_one` with `_sensors` and `_period` inlined (a period is ~2 µs in
        process, a call 0.1 µs; tests/test_session_loop.py checks both give the same recording).
        The loop's locals live in a generator's frame, bound once (default arguments) and resumed
        at each due period: ``send((k, stop))`` runs [k, stop) and gives back ``stop``."""
        pack, pack_telemetry, extend, rows = self._record or (None, None, None, None)
        session, faults, hello = self, self.faults, self.hello
        assert hello is not None

        def periods(sense: Callable[[tuple[int, ...]], tuple[int, bool, bool, int, tuple[int, ...]]] = self.plant.sense,
                    advance: Callable[..., float | None] = self.plant.advance, step: Callable[[Sensors], Drive] = self.target.step,
                    pacing: RealtimePacing | None = self.pacing, roles: tuple[int, ...] = tuple(hello.adc_roles),
                    edge_limit: int = self.options.period_us * 10 - 1, read_index: bool = self.profile.has("encoder"),
                    plant_edges: Callable[[], tuple[tuple[float, int], ...]] = self.plant.edges,
                    plant_marks: Callable[[], tuple[float, ...]] = self.plant.index_marks,
                    max_edges: int = self.target_max_edges(),
                    new: Callable[..., Sensors] = tuple.__new__, pack: Callable[..., bytes] | None = pack,
                    pack_telemetry: Callable[..., bytes] | None = pack_telemetry,
                    extend: Callable[[bytes], None] | None = extend, rows: bytearray | None = rows,
                    host_ref: bool = self._record_host_ref, rtts: StreamingPercentiles = self.lockstep_rtts,
                    perf: Callable[[], float] = time.perf_counter,
                    span: Any = self._c_span(rows), samples: bytearray | None = self._span_samples,
                    sampler: HistoryPart = self.sampler,
                    hand_over_at: Callable[[], int] | None = self._span_hand_over_at,
                    span_stopped: Callable[[], None] | None = getattr(self.recorder, "span_stopped", None),
                    ) -> Generator[int, tuple[int, int], None]:
            k, stop = yield 0
            edge_s, drive, hall_before = session._edge_s, session.drive, session._hall_before
            rtt, late, marker = 0.0, 0.0, 0  # lockstep: no wall-clock figures in the row
            in_span = False
            while True:
                buttons, filtering = session.scenario.buttons, faults.on  # the parts may have changed them
                try:
                    while k < stop:
                        py_stop = stop
                        if span is not None and not filtering:  # the periods in C (hilbench/bench/_span.c)
                            in_span = True
                            k = span.run(k, stop, buttons, session.ref_rpm, edge_s, drive, hall_before,
                                         hand_over_at() if hand_over_at is not None else 0)
                            in_span = False
                            edge_s, drive, hall_before = span.edge_s, span.drive, span.hall_before
                            if samples:  # the history samples it took (an overspeed in the last ends the run there)
                                session._edge_s, session.drive, session._hall_before = edge_s, drive, hall_before
                                k_next, k = k, span.k
                                taken = bytes(samples)
                                del samples[:]
                                sampler.take(taken)
                                k = k_next
                            if k >= stop:
                                break
                            py_stop = k + 1  # a comparator trip or too many edges: its period here, then C again
                        for k in range(k, py_stop):
                            hall, tripped, index, count, adc = sense(roles)  # the plant's sensors after the last period
                            inputs = hall | buttons
                            if edge_s is None:  # a period without a hall edge (most): nothing more to do
                                edges = ()
                            else:  # every hall edge of the period, timed
                                edges = hall_edges(plant_edges(), edge_limit)
                                if len(edges) > max_edges:
                                    session.too_many_edges(k, len(edges))
                            if index and read_index:  # the encoder's index marks passed: among the edges
                                inputs |= INPUT_INDEX
                                edges = with_index_marks(edges, plant_marks(), edge_limit, hall_before)
                                if len(edges) > max_edges:
                                    session.too_many_edges(k, len(edges))
                            hall_before = hall
                            if tripped:  # the board's overcurrent comparator drives FAULT
                                inputs |= INPUT_FAULT
                                session._comparator(k)
                            sensors = new(Sensors, (k & 0xFF, inputs, edges, count, adc))
                            if filtering:  # a sensor fault is in force: the target gets what it leaves
                                sensors = faults.filter(sensors)
                                hall, filtering = sensors[1] & HALL_MASK, faults.on
                            if pacing is not None:  # real time: the period's wall-clock slot, or the Drive held
                                drive = pacing.exchange(k, sensors, drive, step)
                                rtt, late, marker = pacing.rtt, pacing.late, pacing.marker
                            elif k & 63:
                                drive = step(sensors)
                            else:  # lockstep: a sample of round-trip times, not every period's
                                sent = perf()
                                drive = step(sensors)
                                rtts.append(perf() - sent)
                            _seq, duty_a, duty_b, duty_c, output_mode, state, sector, _ccw, _req, fault, telemetry = drive
                            if tripped and output_mode == OUTPUT_OFF:  # the firmware's stop re-arms the comparator
                                session._comparator_cleared()
                            if rows is not None:  # raw values in their own types (columns.session_row)
                                if host_ref:
                                    extend(pack(k, hall, sector, duty_a, duty_b, duty_c, output_mode, state, fault, rtt,
                                                late, marker, session.ref_rpm))
                                else:
                                    extend(pack(k, hall, sector, duty_a, duty_b, duty_c, output_mode, state, fault, rtt,
                                                late, marker))
                                extend(pack_telemetry(*telemetry))  # a call on the tuple itself: cheaper than a `*` among positionals
                            edge_s = advance(duty_a, duty_b, duty_c, output_mode, rows)  # the plant's period; it appends its outputs
                            if pacing is not None:
                                pacing.finished(k)
                        if samples is not None and not filtering and not k % sampler.every:
                            session._edge_s, session.drive, session._hall_before = edge_s, drive, hall_before
                            sampler.sample(k)  # a period C left to Python, at a history period: its sample now
                        k = py_stop
                except BaseException:
                    if in_span:  # where the C span stopped, and what it left
                        k, edge_s, drive, hall_before = span.k, span.edge_s, span.drive, span.hall_before
                        in_span = False
                        if span_stopped is not None:  # rows an interrupted hand-over took leave the buffer
                            span_stopped()
                        if samples:  # the samples of the periods before it, as the Python loop took them
                            taken = bytes(samples)
                            del samples[:]
                            session._edge_s, session.drive, session._hall_before = edge_s, drive, hall_before
                            sampler.take(taken)
                    session.periods_done = k
                    raise
                finally:
                    session._edge_s, session.drive, session._hall_before = edge_s, drive, hall_before
                k, stop = yield stop

        runner = periods()
        next(runner)
        return runner.send

    def _c_span(self, rows: bytearray | None, *, sampled: bool = True) -> Any:
        """The C span runner (hilbench/bench/_span.c: `_tight_runner`'s periods without Python per
        period, and their history samples unless not ``sampled``) when plant and target both have a
        C step and the session runs lockstep; else None. `c_span = False` (or
        HILBENCH_SESSION_SPAN=python) keeps the Python loop."""
        if _span is None or not self.c_span or self.pacing is not None or os.environ.get("HILBENCH_SESSION_SPAN") == "python":
            return None
        plant_api, target_core = getattr(self.plant, "span_api", None), getattr(self.target, "span_core", None)
        papi = plant_api() if plant_api is not None else None
        core = target_core() if target_core is not None else None
        if papi is None or core is None or self.target.step != core[1].step:  # a wrapper in front of the step: its own
            return None
        hello = self.hello
        assert hello is not None
        sampler = self.sampler
        (i_meas, _), (i_ref, _) = sampler.speed_telemetry
        samples = bytearray()
        span_rows = getattr(self.recorder, "span_rows", None) if rows is not None else None
        span = _span.Span(plant=self.plant, plant_api=papi, core=core[1], target_api=core[0], roles=tuple(hello.adc_roles),
                          edge_limit=self.options.period_us * 10 - 1, read_index=self.profile.has("encoder"), rows=rows,
                          n_telemetry=len(hello.telemetry_ids), host_ref=self._record_host_ref,
                          rtt_append=self.lockstep_rtts.append, max_edges=self.target_max_edges(),
                          sample_every=sampler.every, samples=samples if sampled else None, meas_index=i_meas,
                          ref_index=i_ref, overspeed_rpm=sampler.overspeed_rpm, rpm_per_rad_s=RPM_PER_RAD_S,
                          hand_over=span_rows)
        if rows is not None and self.recorder is not None and span.row_bytes != self.recorder.rows.struct.size:
            return None  # a row the C span does not write (columns.OWN_FIELDS changed without _span.c)
        if sampled:
            self._span_samples = samples  # the history part takes them from here (`samples_in_c`)
        hand_over_at = getattr(self.recorder, "hand_over_at", None)
        if span_rows is not None and hand_over_at is not None:  # the recorder's chunks handed over from inside
            # the span (`rows_in_c`); not while a scope's display stream takes the rows before each flush
            self._span_hand_over_at = lambda: 0 if self.display is not None else hand_over_at()
        return span

    def _periods_one_by_one(self, k: int, stop: int) -> int:
        """Periods [k, stop), each exchanged (in its wall-clock slot in real time): the readable
        form of `_tight_runner`."""
        pacing = self.pacing
        try:
            for k in range(k, stop):
                sensors, hall, tripped = self._sensors(k)
                if pacing is None:
                    self.drive = self.target.step(sensors)
                    rtt, late, marker = 0.0, 0.0, 0
                else:
                    self.drive = pacing.exchange(k, sensors, self.drive, self.target.step)
                    rtt, late, marker = pacing.rtt, pacing.late, pacing.marker
                self._edge_s = self._period(k, hall, tripped, rtt, late, marker)
                if pacing is not None:
                    pacing.finished(k)
        except BaseException:
            self.periods_done = k
            raise
        return stop

    def _sensors(self, k: int) -> tuple[Sensors, int, bool]:
        """Period k's Sensors: the plant's sensors as the last period left them, the buttons, every
        input edge of the period with its time in 100 ns, what a sensor fault in force leaves; with the hall bits the target
        gets and whether the comparator has tripped."""
        hall, tripped, index, count, adc = self.plant.sense(tuple(self.hello.adc_roles))  # type: ignore[union-attr]
        inputs = hall | self.scenario.buttons
        if index and self.profile.has("encoder"):
            inputs |= INPUT_INDEX
        if tripped:
            inputs |= INPUT_FAULT
            self._comparator(k)
        limit = self.options.period_us * 10 - 1
        edges = () if self._edge_s is None else hall_edges(self.plant.edges(), limit)  # every hall edge, timed
        if index and self.profile.has("encoder"):
            edges = with_index_marks(edges, self.plant.index_marks(), limit, self._hall_before)
        self._hall_before = hall
        if len(edges) > self.target_max_edges():
            self.too_many_edges(k, len(edges))
        sensors = Sensors(k & 0xFF, inputs, edges, count, adc)
        if self.faults.on:
            sensors = self.faults.filter(sensors)
            hall = sensors.inputs & HALL_MASK
        return sensors, hall, tripped

    def _period(self, k: int, hall: int, tripped: bool, rtt: float, late: float, marker: int) -> float | None:
        """After period k's exchange: the comparator's re-arm, the row, the plant's period with the
        Drive; returns the period's last hall edge."""
        drive = self.drive
        assert drive is not None
        if tripped and drive.output_mode == OUTPUT_OFF:
            self._comparator_cleared()
        rows = None
        if self._record is not None:
            pack, pack_telemetry, extend, rows = self._record
            own = (k, hall, drive.sector, drive.duty_a, drive.duty_b, drive.duty_c, drive.output_mode, drive.state,
                   drive.fault, rtt, late, marker)
            extend(pack(*own, *((self.ref_rpm,) if self._record_host_ref else ())))
            extend(pack_telemetry(*drive.telemetry))
        return self.plant.advance(drive.duty_a, drive.duty_b, drive.duty_c, drive.output_mode, rows)

    def fault_seen(self, t_s: float, code: int) -> None:
        """The history saw a firmware fault code: the summary keeps the first code and the span."""
        summary = self.summary
        if summary.fault_first_s is None:
            summary.fault_code, summary.fault_first_s = int(code), t_s
        summary.fault_last_s = t_s

    def _comparator(self, k: int) -> None:
        """The overcurrent comparator's latch is set: note the trip once."""
        if not self._trip_noted:
            self._trip_noted = True
            self.note(self.period.t_s(k), "overcurrent: the board's comparator tripped, FAULT input set")

    def _comparator_cleared(self) -> None:
        """The firmware turned its outputs off (its stop): the latch clears, as a stop/start re-arms
        the MCLV's FLTA."""
        self.plant.fault_input = False
        self._trip_noted = False

    def end_on_limit(self, k: int, reason: str) -> None:
        """A bench limit ends the run (the caller's `advance` closes it with a fault marker); a plant
        that left the physical (NaN, absurd values) is a diverged simulation, not a limit."""
        diverged = self._divergence()
        if diverged is not None:
            raise SimulationError(diverged)
        t_s = self.period.t_s(k)
        self.note(t_s, reason)
        raise BenchLimitError(f"{self.target_label}: {reason} at t={t_s:.4f} s")

    def _divergence(self) -> str | None:
        """What is wrong when the plant's state left the physical (None: it did not)."""
        plant = self.plant
        try:
            state = {"speed": plant.w_m * RPM_PER_RAD_S, **{f"i{p}": i for p, i in zip("abc", plant.i_abc)}}
        except (AttributeError, ValueError, OverflowError):
            return None
        bad = {k: v for k, v in state.items() if not math.isfinite(v) or abs(v) > 1e9}
        if not bad:
            return None
        what = ", ".join(f"{k} {v:.3g}" for k, v in bad.items())
        return (f"the plant diverged at t={self.now_s:.6f} s (period {self.periods_done}: {what}); the config's "
                f"motor or load is beyond what the integrator follows at this period (try more [plant] substeps, "
                f"a larger j_kgm2 or l_h, a smaller load)")

    def _row_writer(self) -> tuple[Callable[..., bytes], Callable[..., bytes], Callable[[bytes], None], bytearray] | None:
        """The recorder's per-period pieces: the packers of the session's raw fields and of the
        telemetry, the row buffer's extend and the buffer (the plant's period appends its outputs)."""
        recorder = self.recorder
        self._record_host_ref = False
        if recorder is None:
            return None
        row = session_row(self.profile, tuple(self.hello.telemetry_ids), self.period.s, self.plant.outputs)  # type: ignore[union-attr]
        recorder.metadata["history_every_periods"] = self.options.history_every_periods  # the report's segments
        recorder.start(row.layout)
        self._record_host_ref = any(name == "host_ref_rpm" for name, _ in row.own_fields)
        return (fields_struct(row.own_fields).pack, fields_struct(row.telemetry_fields).pack, recorder.rows.extend,
                recorder.rows.data)

    # ------------------------------------------------------------------ the end
    def end(self) -> Summary:
        """Close the run: the target stops, the recording is closed, the summary is made."""
        summary = self.summary
        if not self._closed:
            if self._end_reason is not None:
                summary.end_reason = self._end_reason
            self._confirm_speculation()
            try:
                self._stop_target()
            finally:  # (a Ctrl-C while the target is asked: the recording still closes)
                self._close(f"end: {summary.end_reason} at period {self.periods_done}")
            diverged = getattr(self.target, "divergence", None)
            if diverged is not None:  # [link] on_divergence = "continue": the run went on; it ends with it
                raise diverged
        return summary

    def _fault(self, note: str, what: str) -> None:
        """A fault ended the run: the plant's switches open, the recording closes with a fault marker."""
        self.summary.end_reason = "fault"
        self.summary.fault = what
        self._end_reason = "fault"
        self._deenergise()
        self._close(note, fault=True)

    def _confirm_speculation(self) -> None:
        """Twin-speculative lockstep (hilbench.bench.speculative): the periods still in flight confirmed
        by the target before the end; a divergence or a silent link there ends the run as a fault."""
        drain = getattr(self.target, "drain", None)
        if drain is None:
            return
        try:
            drain()
        except (LinkError, TargetError) as exc:
            self._fault(f"fault at period {self.periods_done}: {exc}", str(exc))
            raise

    def _stop_target(self) -> None:
        """A clean end: the target stops its outputs (S2 as a command)."""
        try:
            self.target.stop()
        except HilbenchError:
            pass

    def _deenergise(self) -> None:
        """Open every switch of the plant's inverter: the motor coasts whatever the target does."""
        try:
            self.plant.step(0.0, 0.0, 0.0, OUTPUT_OFF, self.period.s)
        except Exception:  # noqa: BLE001 - de-energising must never mask the original fault
            pass

    def _close(self, note: str, fault: bool = False) -> None:
        self._closed = True
        if self._qos is not None:
            self._qos.__exit__(None, None, None)
        self._finish(note, fault)

    def _finish(self, note: str, fault: bool) -> None:
        if self.display is not None:  # a watching scope takes the last rows before the close writes them out
            self.display.closing()
        no_more_rows = getattr(self.recorder, "no_more_rows", None)
        if no_more_rows is not None and not fault:  # (a fault marks the last row first)
            try:
                no_more_rows()  # an archive's thread converts the last rows while the summary is made
            except RecordingError:  # the close meets it again and says it, after the summary
                pass
        summary, pacing = self.summary, self.pacing
        summary.periods = self.periods_done
        summary.sim_s = self.now_s
        summary.wall_s = time.perf_counter() - self._wall_start
        summary.rtt_us = (pacing.rtts if pacing is not None else self.lockstep_rtts).percentiles(1e6)
        if pacing is not None:
            summary.lateness_us = pacing.lateness.percentiles(1e6)
            summary.overruns = pacing.overruns
            summary.skipped_periods = pacing.skipped
            summary.longest_stall_periods = pacing.longest_stall
            summary.longest_stall_at_s = pacing.longest_stall_k * pacing.period_s
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
