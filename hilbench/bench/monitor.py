"""Monitor mode: the plant is the real motor. The board runs on its own sensors and timers, streams
a Drive every agreed period (HostHello mode MONITOR), and takes checked parameter writes.

No plant model: the session records the board's stream as the same rows as a HIL run (the bench's
columns and the telemetry columns of the target's profile; the plant's columns are absent), so
`report` and the scope read a real-motor run as they read a simulated one and two runs overlay. A
row's time is the board's own: the stream's seq counts agreed periods of the board's clock (a slot
the board could not send is a seq skipped, a frame lost on the wire a row missing: both counted).
The scenario acts at the board's time: a reference through the profile's `monitor_reference` (the
board's pot is not the bench's), S2 as the Start command, parameter writes. The control socket's
`get`, `set`, `ref`, `start`, `press s2`, `guard` and `stop` act as in a HIL run, and the guard
watches new gains on the firmware's measured speed. Any frame to the board feeds its watchdog: the
session sends a StatusRequest every quarter of the watchdog time, so a host that dies leaves the
motor stopped within the watchdog time. The session knows no terminal and no firmware by name.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, Iterable

from hilbench.bench import segments as segmentation
from hilbench.bench.columns import session_row
from hilbench.bench.control import COMMANDS, ControlRequest
from hilbench.bench.history import SpeedHistory
from hilbench.bench.livetuning import GuardSettings, LiveTuning, raw_per_unit
from hilbench.bench.recorder import MARKER_EVENT, MARKER_FAULT, MARKER_PARAM, MemoryRecorder, Recorder, fields_struct
from hilbench.bench.scenario import Event
from hilbench.bench.summary import Snapshot, Summary
from hilbench.errors import ConfigError, HilbenchError, LinkError, LinkTimeout, TargetError
from hilbench.plant.period import Period
from hilbench.protocol import Drive, Mode, OutputMode, ParamSetResult, Start, State, Status, StatusRequest, Stop, TargetHello
from hilbench.protocol.messages import Message
from hilbench.targets.profile import ParamReference, TargetProfile
from hilbench.targets.registry import profile_for_firmware

if TYPE_CHECKING:
    from hilbench.bench.display import DisplayStream
    from hilbench.bench.session import ControlSource
    from hilbench.targets.remote import RemoteTarget

MODE_MONITOR = int(Mode.MONITOR)
STATE_FAULT = int(State.FAULT)
#: the wall time the session waits for the first streamed Drive before it says the board is silent
FIRST_DRIVE_S = 5.0
#: a Stop is sent again when this many streamed Drives after it still show the outputs on (at most
#: STOP_ATTEMPTS times)
STOP_SEEN_DRIVES = 10
STOP_ATTEMPTS = 5
#: a Start or Stop not seen taken in the stream this long after (the board's clock) is sent again
COMMAND_SEEN_S = 0.05
#: a live view's sample every this many rows, and the samples it keeps (as a HIL session's)
OBSERVE_EVERY_ROWS = 10
HISTORY_SAMPLES = 8192
#: the stream's shortest period (a Drive's wire time at 250 kbaud is ~0.9 ms)
MIN_PERIOD_US = 1000
#: a reference ramp is written as steps this far apart on the board's clock (each a checked write)
RAMP_WRITE_S = 0.02
#: after a frame that has no answer (Start, Stop, a keep-alive), the Drives streamed before the next
#: frame goes out: the board holds one received frame and drops one arriving before its main loop
#: took the last (a Drive sent after one it was busy sending means its loop ran in between)
TAKEN_AFTER_DRIVES = 2


def _running(drive: Drive) -> bool:
    """Whether the board's motor runs (S2 stops it then; a Stop is taken when it no longer does)."""
    return int(drive.state) not in (int(State.STOPPED), STATE_FAULT, int(State.STALLED))


@dataclass(frozen=True)
class MonitorOptions:
    """A monitor session's settings (from the config's [link] and [run] tables)."""

    period_us: int = 2000  # the stream's period on the board's clock
    watchdog_ms: int = 500
    duration_s: float | None = None  # the board's seconds; None: the scenario's end
    timeout_s: float = 2.0  # no Drive for this long (wall): the link is lost
    poll_control_s: float = 0.05
    mode: str = "monitor"  # (what the scope's page shows as the run's mode)


@dataclass
class MonitorStats:
    """What the stream did: rows, the seqs the board skipped and the frames lost between."""

    rows: int = 0
    gaps: int = 0
    missing_periods: int = 0
    statuses: int = 0
    strays: int = 0
    last_status: Status | None = None
    wall_start: float = field(default_factory=time.monotonic)


class MonitorSession:
    """One monitor-mode run over a board that streams (a `RemoteTarget` on its link)."""

    def __init__(self, target: "RemoteTarget", events: Iterable[Event], options: MonitorOptions = MonitorOptions(), *,
                 profile: TargetProfile | None = None, recorder: Recorder | MemoryRecorder | None = None,
                 control: "ControlSource | None" = None, guard: GuardSettings = GuardSettings(), target_label: str = "board",
                 observer: Callable[[Snapshot], None] | None = None) -> None:
        self.target = target
        self.options = options
        self.events = sorted(events, key=lambda e: e.at_s)
        self.expected_profile = profile
        self.profile: TargetProfile = profile or profile_for_firmware("")
        self.recorder = recorder
        self.control = control
        self.observer = observer
        self.target_label = target_label
        self.tuning = LiveTuning(target, self.profile, target_label, guard)
        self.tuning.on_change = self._on_param_change
        self.live: None = None  # `ctl step` needs the HIL session's history: refused here (see COMMANDS use)
        self.hello: TargetHello | None = None
        self.drive: Drive | None = None
        self.ref_rpm = 0.0
        self.t_s = 0.0
        self.messages: list[str] = []
        self.stats = MonitorStats()
        self.summary: Summary | None = None
        self._k = -1  # the unwrapped seq of the last row
        self._pack: Callable[..., bytes] | None = None
        self._tele_pack: Callable[..., bytes] | None = None
        self._speed_index = -1
        self._speed_scale = 0.0
        self._end_reason: str | None = None
        self._next_event = 0
        self._duration_s = 0.0
        self._inbox: list[Drive] = []
        self._drives_rx = 0  # Drives received from the link (the inbox's included)
        self._unanswered_at: int | None = None  # _drives_rx when a frame with no answer went out
        self._sent_board_s = 0.0  # the board's time at the last frame sent to it (any feeds its watchdog)
        self._pending: type[Start] | type[Stop] | None = None  # a Start or Stop (no reply) not yet seen taken
        self._pending_s = 0.0  # the board's time it went (or of the first row after it)
        self._pending_rx = 0  # _drives_rx when it went out
        self._ramp: tuple[float, float, float, float] | None = None  # (t0, from, to, duration): a reference ramp
        self._ramp_written = 0.0
        #: the held references and how the motor followed them, on the firmware's measured speed (the
        #: only speed there is: it stands for the plant's in the segments and the [[check]] verdicts)
        self.segmenter = segmentation.Segmenter()
        #: (t_s, ref_rpm, speed_rpm, measured_rpm) for a live view: the measured speed in both (no plant)
        self.history = SpeedHistory(HISTORY_SAMPLES)
        self.on_params: Callable[[dict[str, float]], None] | None = None  # a live view follows the writes
        self._observed_at = (time.perf_counter(), 0)
        self.period = Period(options.period_us)  # the stream's period (the scope's time base)
        self.display: "DisplayStream | None" = None  # the scope's stream, made when a scope asks
        self.lockstep_rtts: list[float] = []  # (a HIL session's figure: none here)
        self._values: dict[str, float] | None = None  # the parameters now (param_values)

    # ------------------------------------------------------------------ handshake
    def handshake(self) -> TargetHello:
        """HostHello mode MONITOR: the board agrees to stream every period_us; its profile, params."""
        try:
            hello = self.target.handshake(self.options.period_us, MODE_MONITOR, self.options.watchdog_ms)
        except TargetError as exc:
            raise TargetError(f"{exc} (monitor mode needs a real-motor build of the firmware, e.g. make MODE=motor; "
                              "a HIL build refuses it)") from None
        self.hello = hello
        if self.expected_profile is None or self.expected_profile.firmware_name.strip().upper() != hello.firmware_name.strip().upper():
            self.profile = profile_for_firmware(hello.firmware_name)
            self.tuning.profile = self.profile
        self.tuning.declare(hello.n_params)
        self.target.stray_sink = self._stray
        ids = tuple(hello.telemetry_ids)
        for index, tid in enumerate(ids):
            column = self.profile.telemetry_column(tid)
            if column.column == self.profile.speed_column:
                self._speed_index, self._speed_scale = index, column.scale
        row = session_row(self.profile, ids, self.options.period_us / 1e6, plant_outputs=(), halls=False)
        self._row = row
        self._pack = fields_struct(row.own_fields).pack
        self._tele_pack = fields_struct(row.telemetry_fields).pack
        self._host_ref = any(name == "host_ref_rpm" for name, _ in row.own_fields)
        if self.recorder is not None:
            self.recorder.start(row.layout)
        return hello

    # ------------------------------------------------------------------ what a control command uses
    def param_values(self) -> dict[str, float]:
        """The parameters as read once after the handshake and written since (every write is this
        session's, checked and answered): no round trips on a link the stream already fills."""
        if self._values is None:
            self._values = self.tuning.values() if self.hello is not None else {}
        return dict(self._values)

    def set_params(self, values: dict[str, float], t_s: float | None = None, *, guard: bool = True) -> None:
        self._sent_board_s = self.t_s
        self.tuning.set(values, self.t_s if t_s is None else t_s, guard=guard)

    def set_reference(self, rpm: float) -> None:
        """The reference through the profile's monitor reference (a parameter, with its enable)."""
        reference = self.profile.monitor_reference
        if reference is None and isinstance(self.profile.reference, ParamReference):
            reference = self.profile.reference
        if reference is None:
            raise ConfigError(f"monitor: target {self.profile.name!r} declares no parameter the host can set its "
                              "speed reference with (profile monitor_reference); use the board's own pot")
        values = {reference.param: reference.value(rpm)}
        if reference.enable is not None:
            values = {reference.enable: 1.0, **values}
        self.ref_rpm = rpm
        self.tuning.reference_changed(self.t_s)
        self._sent_board_s = self.t_s
        self.tuning.set(values, self.t_s, guard=False)

    def reference_now(self, rpm: float, t_s: float, note: str) -> None:
        self.set_reference(rpm)
        self.segment("ref", t_s, rpm)
        self.note(t_s, note)

    def stop_run(self, t_s: float, reason: str, note: str) -> None:
        self._end_reason = reason
        self.note(t_s, note)

    def press(self, button: str, t_s: float) -> None:
        """S2 as the Start command while stopped, Stop while running (the board's own S2 acts too)."""
        if button != "s2":
            raise ConfigError(f"monitor: press {button}: only s2 (Start/Stop) reaches the board")
        self._sent_board_s = self.t_s
        self._send_command(Stop if self.drive is not None and _running(self.drive) else Start, t_s)

    def send_start(self, t_s: float) -> None:
        """The Start command (`ctl start`), sent again while the stream does not show it taken."""
        self._sent_board_s = self.t_s
        self._send_command(Start, t_s)

    def _send_command(self, kind: type[Start] | type[Stop], t_s: float) -> None:
        """A Start or Stop: when its probe goes unanswered (a board busy sending) it still went
        (`RemoteTarget._command`), and `_check_command` sends it again while the stream does not
        show it taken, so the run goes on with a note. Judged on the Drives received after it."""
        self._pending, self._pending_s = kind, self.t_s
        try:
            self.target.start() if kind is Start else self.target.stop()
        except LinkTimeout as exc:
            self.note(t_s, str(exc))
        self._pending_rx = self._drives_rx

    def _check_command(self) -> None:
        """A Start or Stop has no answer: when the stream does not show it taken a while after it
        (COMMAND_SEEN_S of rows), the frame was lost (the board was busy sending): send it again."""
        drive, kind = self.drive, self._pending
        if kind is None or drive is None:
            return
        if self._drives_rx - len(self._inbox) <= self._pending_rx:  # rows still of Drives from before it
            self._pending_s = self.t_s  # (parked while its probe waited): the wait counts from after
            return
        if (int(drive.state) != int(State.STOPPED)) if kind is Start else not _running(drive):  # taken
            self._pending = None  # (a Start that ends in a fault was taken: sent again, it would restart)
        elif self.t_s - self._pending_s >= COMMAND_SEEN_S:
            self._sent_board_s = self.t_s
            self._send_command(kind, self.t_s)

    def segment(self, kind: str, t_s: float, ref_rpm: float = 0.0, ramp_s: float = 0.0) -> None:
        """A reference change, a press or the end, for the segments (and `report`, as events)."""
        text = self.segmenter.tell(kind, t_s, ref_rpm, ramp_s)
        if self.recorder is not None:
            self.recorder.event(text)

    def set_load(self, kind: str, value: float) -> None:
        raise ConfigError("monitor: the load is the real motor's (no plant to load)")

    def note(self, t_s: float, text: str) -> None:
        self.messages.append(f"{t_s:.3f} s: {text}")
        del self.messages[:-64]
        if self.recorder is not None:
            self.recorder.event(f"t={t_s:.6f} {text}", MARKER_EVENT)

    # ------------------------------------------------------------------ the scope's display stream
    def display_stream(self) -> "DisplayStream":
        """The scope's display stream (hilbench.bench.display), made on the first request: it reads
        the rows as they are recorded, as in a HIL run."""
        if self.display is None:
            from hilbench.bench.display import DisplayStream

            self.display = DisplayStream(self)  # type: ignore[arg-type]
        return self.display

    def watch_rows(self, on: bool) -> None:
        """Rows for the scope in a run that records none: a bounded window while a scope watches."""
        from hilbench.bench.recorder import WindowRecorder

        if on and self.recorder is None and self.hello is not None:
            window = WindowRecorder(max(1, round(self.period.per_s)))
            window.start(self._row.layout)
            self.recorder = window  # type: ignore[assignment]
        elif not on and isinstance(self.recorder, WindowRecorder):
            self.recorder = None

    def link_stats(self) -> dict[str, int]:
        stats = self.stats
        return {"rows": stats.rows, "missing_periods": stats.missing_periods, "status_replies": stats.statuses}

    @property
    def ended(self) -> bool:
        return self._end_reason is not None

    def _on_param_change(self, t_s: float, text: str, values: dict[str, float]) -> None:
        if self._values is not None:  # as the board holds them (its fixed-point value of each)
            self._values.update({name: self.tuning.encode(name, value)[1] / raw_per_unit(self.tuning.info[name].ptype)
                                 for name, value in values.items()})
        if self.on_params is not None:
            self.on_params(values)
        self.messages.append(f"{t_s:.3f} s: {text}")
        if self.recorder is not None:
            self.recorder.event(f"t={t_s:.6f} {text}", MARKER_PARAM)

    # ------------------------------------------------------------------ the stream
    def _stray(self, msg: Message) -> None:
        if type(msg) is Drive:
            self._drives_rx += 1
            self._inbox.append(msg)
        elif type(msg) is Status:
            self.stats.statuses += 1
            self.stats.last_status = msg
        elif type(msg) is not ParamSetResult:
            self.stats.strays += 1

    def _receive(self, timeout_s: float) -> Message | None:
        """The next frame from the board (None within ``timeout_s``); Drives are counted."""
        msg = self.target.link.recv_or_none(timeout_s)
        if type(msg) is Drive:
            self._drives_rx += 1
        return msg

    def _before_send(self, msg: Message) -> None:
        """Ahead of every frame to the board (the target's send gate): while the last frame with no
        answer may still sit in the board's one-frame buffer, wait for TAKEN_AFTER_DRIVES streamed
        Drives (kept for their rows). Else a ParamSet right after a Start was dropped (the board's
        `overruns`) and waited out its retry (0.5 s of wall, ~0.1 s of a simulated board's time): the
        reference came late and a restarted motor stalled (tests/test_board_guide.py, section 13)."""
        if self._unanswered_at is not None:
            deadline = time.monotonic() + self.options.timeout_s
            while self._drives_rx < self._unanswered_at + TAKEN_AFTER_DRIVES and time.monotonic() < deadline:
                self._hold(min(0.02, max(0.0, deadline - time.monotonic())))
            self._unanswered_at = None
        if type(msg) in (Start, Stop):
            self._drain_ready()
            self._unanswered_at = self._drives_rx

    def _drain_ready(self) -> None:
        """Take every frame already here (Drives kept for their rows): the Drives counted after an
        unanswered frame are then the board's since it was sent, not ones a lagging host had not
        read yet (a loaded host counted those, sent its next frame too soon, and the board dropped it)."""
        while self._hold(0.0):
            pass

    def _hold(self, timeout_s: float) -> bool:
        """One frame taken outside the row loop: a Drive kept in the inbox for its row, anything else
        as a stray; False when none came within ``timeout_s``."""
        frame = self._receive(timeout_s)
        if frame is None:
            return False
        if type(frame) is Drive:
            self._inbox.append(frame)
        else:
            self._stray(frame)
        return True

    def _keep_alive(self) -> None:
        """A StatusRequest whose answer is not waited for (a stray Status): it feeds the watchdog."""
        msg = StatusRequest(0)
        self._before_send(msg)
        self._drain_ready()
        sent_at = self._drives_rx
        self.target.link.send(msg)
        self._unanswered_at = sent_at

    def run(self, make_recorder: Callable[["MonitorSession"], Recorder | MemoryRecorder | None] | None = None,
            gains: dict[str, float] | None = None) -> Summary:
        """Handshake, ``make_recorder``'s recorder (it gets the session after the handshake), the
        ``gains`` written, then rows until the duration (the board's time) or the scenario's end.
        One call: the board's watchdog counts from the handshake, so nothing slow comes between."""
        if self.hello is None:
            self.handshake()
        assert self.hello is not None
        self.target.gate_sends(self._before_send)
        if make_recorder is not None:
            self.recorder = make_recorder(self)
            if self.recorder is not None:
                self.recorder.start(self._row.layout)
        self._stray(self.target.status())  # the watchdog counts from the handshake: fed now, and
        # answered before anything else goes out (a second frame while the board sends is lost)
        self._sent_board_s = 0.0
        if gains:
            self.set_params(gains, 0.0, guard=False)
        options = self.options
        duration = options.duration_s
        if duration is None:
            ends = [e.at_s for e in self.events if e.end]
            duration = min(ends) if ends else 5.0
        self._duration_s = duration
        summary = Summary(self.target_label, "monitor", options.period_us, firmware=self.hello.firmware_name)
        self.summary = summary
        link = self.target.link
        keepalive_s = options.watchdog_ms / 4000.0
        next_control = time.monotonic()
        last_drive_wall = time.monotonic()
        self._fire_events(0.0)
        try:
            while self._end_reason is None:
                now = time.monotonic()
                if self.t_s - self._sent_board_s >= keepalive_s:
                    # nothing else went out for a quarter of the watchdog on the board's clock (the
                    # one its watchdog counts; a simulated board may run slower than the wall): feed
                    # it. Never more often: the board holds one received frame, and a second one
                    # arriving while it sends its stream is lost (counted in its Status)
                    self._keep_alive()
                    self._sent_board_s = self.t_s
                    self._check_command()
                if self.control is not None and now >= next_control:
                    for request in self.control.poll():
                        self._handle_control(request)
                    next_control = now + options.poll_control_s
                msg = self._inbox.pop(0) if self._inbox else self._receive(0.02)
                if msg is None:
                    limit = FIRST_DRIVE_S if self._k < 0 else options.timeout_s
                    if time.monotonic() - last_drive_wall > limit:
                        raise LinkError(f"link {link.name}: no Drive streamed for {limit:g} s in monitor mode "
                                        "(is the board built for it? make MODE=motor)")
                    continue
                if type(msg) is not Drive:
                    self._stray(msg)
                    continue
                last_drive_wall = time.monotonic()
                self._row_of(msg)
                if self.t_s >= duration:
                    self._end_reason = "completed"
        finally:
            self._end(summary)
        return summary

    def _row_of(self, drive: Drive) -> None:
        """The Drive as a row at the board's time; the scenario's events due by then; the guard."""
        if self._k < 0:
            k = 0
        else:
            step = (drive.seq - self._k) & 0xFF
            if step == 0:
                return  # the same slot again (the watchdog's Drive repeats the last seq)
            if step > 1:
                self.stats.gaps += 1
                self.stats.missing_periods += step - 1
            k = self._k + step
        self._k = k
        self.t_s = k * self.options.period_us / 1e6
        self.drive = drive
        self.stats.rows += 1
        self._fire_events(self.t_s)
        if self._ramp is not None and self.t_s - self._ramp_written >= RAMP_WRITE_S:
            t0, start, end, ramp_s = self._ramp
            done = min(1.0, (self.t_s - t0) / ramp_s)
            self.set_reference(start + (end - start) * done)
            self._ramp_written = self.t_s
            if done >= 1.0:
                self._ramp = None
        tele = drive.telemetry
        if self.recorder is not None:
            own = [k, int(drive.sector), int(drive.duty_a), int(drive.duty_b), int(drive.duty_c),
                   int(drive.output_mode), int(drive.state), int(drive.fault), math.nan, math.nan,
                   MARKER_FAULT if drive.fault else 0]
            if self._host_ref:
                own.append(self.ref_rpm)
            n = len(self._row.telemetry_fields)
            values = tuple(tele[:n]) + (0,) * (n - len(tele))
            assert self._pack is not None and self._tele_pack is not None  # set with the row layout at the start
            self.recorder.rows.extend(self._pack(*own) + self._tele_pack(*values))
        if self.display is not None and (k % OBSERVE_EVERY_ROWS == 0 or self.display.flush_coming()):
            self.display.due(k, drive, None)  # the scope takes its rows before a flush empties the buffer
        if self.recorder is not None:
            self.recorder.maybe_flush()
        speed = tele[self._speed_index] * self._speed_scale if 0 <= self._speed_index < len(tele) else math.nan
        if math.isfinite(speed):
            self.segmenter.sample(self.t_s, speed, speed)
        if k % OBSERVE_EVERY_ROWS == 0:
            self.history.append(self.t_s, self.ref_rpm, speed, speed)
            if self.observer is not None:
                self.observer(self._snapshot(k, drive, speed))
        if self.t_s < self.tuning.watching and math.isfinite(speed):
            note = self.tuning.guard_check(self.t_s, self.ref_rpm, speed, 0.0, drive.state, drive.fault, False)
            if note is not None:
                self.note(self.t_s, note)

    def _snapshot(self, k: int, drive: Drive, speed: float) -> Snapshot:
        """What a live view shows (the dashboard's Snapshot): the motor's speed is the measured one,
        the plant's currents are not known (NaN)."""
        now = time.perf_counter()
        last_wall, last_k = self._observed_at
        self._observed_at = (now, k)
        telemetry = {self.profile.telemetry_column(tid).column: value * self.profile.telemetry_column(tid).scale
                     for tid, value in zip(self.hello.telemetry_ids if self.hello else (), drive.telemetry)}
        nan = math.nan
        return Snapshot(
            t_s=self.t_s, duration_s=self._duration_s, period=k, ref_rpm=self.ref_rpm, speed_rpm=speed,
            measured_rpm=speed, state=drive.state, sector=drive.sector, direction_ccw=bool(drive.direction_ccw),
            output_mode=drive.output_mode, duties=(drive.duty_a, drive.duty_b, drive.duty_c), i_abc=(nan, nan, nan),
            i_bus=nan, telemetry=telemetry, periods_per_s=(k - last_k) / max(now - last_wall, 1e-9),
            rtt_p50_us=nan, rtt_p99_us=nan,
            link={"rows": self.stats.rows, "missing_periods": self.stats.missing_periods}, overruns=0,
            messages=self.messages[-4:], history=copy.copy(self.history), fault=drive.fault)

    def _fire_events(self, t_s: float) -> None:
        while self._next_event < len(self.events) and self.events[self._next_event].at_s <= t_s + 1e-12:
            event = self.events[self._next_event]
            self._next_event += 1
            if event.end:
                self._end_reason = "completed"
            elif event.ref_rpm is not None and event.ramp_s > 0.0:  # written every RAMP_WRITE_S on the way
                self._ramp = (t_s, self.ref_rpm, event.ref_rpm, event.ramp_s)
                self._ramp_written = -math.inf
                self.segment("ref", t_s, event.ref_rpm, event.ramp_s)
            elif event.ref_rpm is not None:
                self._ramp = None
                self.set_reference(event.ref_rpm)
                self.segment("ref", t_s, event.ref_rpm)
            elif event.press == "s2":
                self.press(event.press, t_s)
                self.segment("press", t_s)
            elif event.params:
                self._sent_board_s = self.t_s
                self.tuning.set(dict(event.params), t_s)  # noted by the tuning's change note
                continue
            else:
                self.note(t_s, f"{event.describe()}: not applicable in monitor mode (no plant), skipped")
                continue
            self.note(t_s, event.describe())

    def _handle_control(self, request: ControlRequest) -> None:
        command = COMMANDS.get(request.cmd)
        try:
            if command is None or request.cmd in ("step", "load"):
                request.reply(False, f"command {request.cmd!r} is not available in monitor mode"
                              + ("; run `hilbench step --mode monitor`" if request.cmd == "step" else ""))
            else:
                command.act(self, request, self.t_s)
        except HilbenchError as exc:
            request.reply(False, str(exc))
        except (ValueError, TypeError, ArithmeticError, KeyError) as exc:
            if not request.replied:
                request.reply(False, f"{request.cmd}: refused ({type(exc).__name__}: {str(exc)[:80]})")

    def _stop_confirmed(self) -> bool:
        """Stop, until the stream says the outputs are off: a Stop has no answer and the board loses
        a frame that arrives while it sends (a lost one would leave the motor to the watchdog, and
        the watchdog's fault to the next session). False: no Drive said so after STOP_ATTEMPTS Stops."""
        for _ in range(STOP_ATTEMPTS):
            try:
                self.target.stop()
            except LinkTimeout:  # its probe went unanswered; the Stop went anyway: the stream tells
                pass
            seen = 0
            deadline = time.monotonic() + 2.0
            while seen < STOP_SEEN_DRIVES and time.monotonic() < deadline:
                msg = self._inbox.pop(0) if self._inbox else self._receive(0.05)
                if type(msg) is Drive:
                    seen += 1
                    if int(msg.output_mode) == int(OutputMode.OFF) and int(msg.state) != int(State.RUNNING):
                        return True
        return False

    def _end(self, summary: Summary) -> None:
        """Stop the motor (the board's outputs off), close the recording; the summary's figures."""
        try:
            stopped, why = self._stop_confirmed(), "no streamed Drive showed the outputs off"
        except (HilbenchError, OSError) as exc:
            stopped, why = False, str(exc)
        if not stopped:
            summary.warnings.append(f"Stop not confirmed after {STOP_ATTEMPTS} Stops ({why}): the board's watchdog "
                                    f"turns its outputs off {self.options.watchdog_ms} ms after the last frame; "
                                    "check that the motor stopped")
        self.target.gate_sends(None)
        self.target.stray_sink = None
        stats = self.stats
        summary.periods = self._k + 1
        summary.sim_s = self.t_s
        summary.wall_s = time.monotonic() - stats.wall_start
        summary.end_reason = self._end_reason or "interrupted"
        summary.params = self.param_values()
        summary.segments = self.segmenter.finish(self.t_s)
        summary.link = {"rows": stats.rows, "stream_gaps": stats.gaps, "missing_periods": stats.missing_periods,
                        "status_replies": stats.statuses, "stray_frames": stats.strays}
        link_stats = getattr(self.target.link, "stats", None)
        if link_stats is not None:
            summary.link.update(frames_rx=link_stats.frames_rx, frame_errors=link_stats.frame_errors,
                                garbage_bytes=link_stats.garbage_bytes)
        if stats.last_status is not None:  # the board's own counters: what it received, its watchdog
            summary.link.update(board_rx_errors=stats.last_status.rx_errors, board_overruns=stats.last_status.overruns,
                                board_watchdog_trips=stats.last_status.watchdog_trips)
        if self.drive is not None and self.drive.fault:
            summary.fault_code = int(self.drive.fault)
        if self.recorder is not None:
            summary.recording = str(getattr(self.recorder, "path", "")) or None
            self.recorder.event(segmentation.end_event(self.t_s))
            if self.display is not None:  # a watching scope takes the last rows before the close writes them out
                self.display.closing()
            self.recorder.close(f"end: {summary.end_reason} at period {summary.periods}")
            summary.rows_recorded = int(getattr(self.recorder, "rows_written", stats.rows))


def monitor_options(period_us: int, watchdog_ms: int, duration_s: float | None, timeout_s: float) -> MonitorOptions:
    """The options from the config's values (a watchdog of 0 is refused: a real motor must stop when the host goes)."""
    if period_us < MIN_PERIOD_US:
        raise ConfigError(f"monitor: link.period_us={period_us} is shorter than one Drive on the wire (a Drive with "
                          f"three telemetry values is 22 bytes: 0.9 ms at 250 kbaud); the stream's period must be >= {MIN_PERIOD_US} us, e.g. 5000")
    if watchdog_ms <= 0:
        raise ConfigError("monitor: link.watchdog_ms must be > 0 (the board stops its motor when the host goes silent)")
    if watchdog_ms * 1000 < 8 * period_us:  # keep-alives every quarter of it, each waiting for 2 streamed Drives
        raise ConfigError(f"monitor: link.watchdog_ms={watchdog_ms} is less than 8 stream periods (link.period_us="
                          f"{period_us}): the keep-alives cannot reach the board before its watchdog stops the motor; "
                          f"use link.watchdog_ms >= {-(-8 * period_us // 1000)}")
    return MonitorOptions(period_us=period_us, watchdog_ms=watchdog_ms, duration_s=duration_s,
                          timeout_s=max(timeout_s, 4.0 * period_us / 1e6, 1.0))


__all__ = ["MODE_MONITOR", "MonitorOptions", "MonitorSession", "MonitorStats", "monitor_options"]
