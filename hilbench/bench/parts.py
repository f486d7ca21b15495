"""The session's parts, each acting only in the periods it asks for, and the schedule that runs them.

A part says the first period from k on it acts in (`due_at(k)`; inf: none until something changes
its state) and acts there (`run(k)`). Before a period's exchange: the scenario (events, ramps, the
buttons' release, a fault's end) and the live part (the guard's look, `ctl step`, the control
socket). After it: the history sample (speed history, segments, the observer, the display, the
overspeed limit) and the bus capacitor. The session runs the periods between in a tight loop;
nothing a part changes is cached across a part's call, so no part can miss another's change.
When the session's C span runs the periods, it takes the history samples itself and the part
takes them in bulk when the span returns (`HistoryPart.take`): the part is then due only where it
has more to do (the display, the observer, the recorder's flush).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Iterable, Protocol, Sequence

import numpy as np

from hilbench.bench.recorder import MARKER_EVENT
from hilbench.bench.scenario import Event, Ramp, ScenarioPlayer
from hilbench.bench.summary import Snapshot, percentiles
from hilbench.errors import ParamError
from hilbench.plant.model import RPM_PER_RAD_S
from hilbench.protocol import Drive, Input

if TYPE_CHECKING:
    from hilbench.bench.control import ControlRequest
    from hilbench.bench.session import ControlSource, Session

INPUT_S2 = int(Input.S2)
INPUT_S3 = int(Input.S3)
#: how long a button press is held (the firmware debounces and acts on the edge)
BUTTON_HOLD_S = 0.002
CTL_STEP_HOLD_S = 1.0
CTL_STEP_AFTER_S = 1.0
STEP_REPLY_KEYS = ("rise_time_s", "overshoot_pct", "settling_time_s", "ss_error", "ss_error_pct", "ss_ripple", "iae", "itae")
#: the unit of each figure of a `ctl step` reply (the speed in rpm)
STEP_REPLY_UNITS = {"rise_time_s": "s", "overshoot_pct": "%", "settling_time_s": "s", "ss_error": "rpm",
                    "ss_error_pct": "%", "ss_ripple": "rpm", "iae": "rpm*s", "itae": "rpm*s^2"}


class Part(Protocol):
    """One concern of the session, acting only in the periods it asks for."""

    def due_at(self, k: int) -> float:
        """The first period from k on this part acts in (inf: none until its state changes)."""

    def run(self, k: int) -> None:
        """Act in period k."""


class Schedule:
    """The parts that act before a period's exchange and those that act after it, in order."""

    def __init__(self, before: Sequence[Part], after: Sequence[Part], ended: Callable[[], bool]) -> None:
        self.before = tuple(before)
        self.after = tuple(after)
        self._ended = ended

    def next_before(self, k: int) -> float:
        """The first period from k on a part acts in before its exchange."""
        due = math.inf
        for part in self.before:
            at = part.due_at(k)
            if at < due:
                due = at
        return due

    def next_after(self, k: int) -> float:
        """The first period from k on a part acts in after its exchange."""
        due = math.inf
        for part in self.after:
            at = part.due_at(k)
            if at < due:
                due = at
        return due

    def run_before(self, k: int) -> bool:
        """The parts due in period k, before its exchange; True when one of them ended the run."""
        for part in self.before:
            if part.due_at(k) <= k:
                part.run(k)
                if self._ended():
                    return True
        return False

    def run_after(self, k: int) -> None:
        """The parts due in period k (as `plan` found them), after its exchange and the plant's period."""
        for part in self.after:
            if part.due_at(k) <= k:
                part.run(k)


# ------------------------------------------------------------------------------------- scenario
class ScenarioPart:
    """The scenario's events, its ramps, the buttons (held BUTTON_HOLD_S) and a fault's end."""

    def __init__(self, session: "Session", events: Iterable[Event]) -> None:
        self.session = session
        self.player = ScenarioPlayer(events)
        self.buttons = 0  # the button bits the Sensors carry now
        self.release_s = math.inf
        self.supply_v = 0.0  # the bench supply's voltage (the bus rises above it only with a capacitor)
        self.next_k: float = 0

    def start(self, supply_v: float) -> None:
        self.supply_v = supply_v
        self.next_k = self.session.period.index_at(self.player.next_t_s)

    def due_at(self, k: int) -> float:
        return self.next_k

    def wake(self, k: int) -> None:
        """Look again from period k (a ramp or a button press from outside the scenario)."""
        self.next_k = min(self.next_k, k)

    def run(self, k: int) -> None:
        """Scenario events, ramps, the button release and fault expiry due in period k."""
        session, period = self.session, self.session.period
        t_s = period.t_s(k)
        held = bool(session.live.steps)  # a `ctl step` owns the reference: events wait for its end
        if not held and period.index_at(self.player.next_t_s) <= k:
            for event in self.player.due(t_s, period.s):
                self.apply(event, t_s)
            if session.ended:
                return
        if self.player.ramps and not held:
            self._tick_ramps(t_s)
        if period.index_at(self.release_s) <= k:
            self.buttons = 0
            self.release_s = math.inf
        if period.index_at(session.faults.clear_at_s) <= k:
            session.faults.apply("clear", t_s, None)
        self.next_k = period.index_at(min(math.inf if held else self.player.next_t_s, self.release_s,
                                          session.faults.clear_at_s,
                                          t_s + period.s if self.player.ramps and not held else math.inf))

    def press(self, button: str, t_s: float) -> None:
        """Hold a button (s2 start/stop, s3) for BUTTON_HOLD_S."""
        self.buttons |= INPUT_S2 if button == "s2" else INPUT_S3
        self.release_s = t_s + BUTTON_HOLD_S

    def apply(self, event: Event, t_s: float) -> None:
        """One scenario event (or a script's, `Session.apply_now`), noted in the recording."""
        session = self.session
        if event.ref_rpm is not None:
            self._reference(event, t_s)
        elif event.pot is not None:
            session.plant.pot_fraction = event.pot
        elif event.load_nm is not None:
            session.set_load(event.load_kind, event.load_nm)
        elif event.vbus_v is not None:
            self._supply(event, t_s)
        elif event.press is not None:
            self.press(event.press, t_s)
            if event.press == "s2":
                session.segment("press", t_s)
        elif event.fault is not None:
            session.faults.apply(event.fault, t_s, event.fault_duration_s, session.hall_bits_sent)
        elif event.params:
            try:
                session.tuning.set(dict(event.params), t_s)
            except ParamError as exc:  # said in the summary and the recording, the run goes on
                refused = f"scenario {event.describe()} at {t_s:.3f} s refused: {exc}"
                session.message(f"{t_s:.3f} s: {exc}")
                if session.summary is not None:
                    session.summary.warnings.append(refused)
                if session.recorder is not None:
                    session.recorder.event(f"t={t_s:.6f} refused {event.describe()}: {exc}", MARKER_EVENT)
                return
        elif event.end:
            session.scenario_end(t_s)
        if session.recorder is not None:
            session.recorder.event(f"t={t_s:.6f} {event.describe()}", MARKER_EVENT)

    def _reference(self, event: Event, t_s: float) -> None:
        assert event.ref_rpm is not None
        self.session.segment("ref", t_s, event.ref_rpm, event.ramp_s)
        if event.ramp_s > 0:
            self.player.ramps["ref_rpm"] = Ramp(t_s, t_s + event.ramp_s, self.session.ref_rpm, event.ref_rpm)
        else:
            self.player.ramps.pop("ref_rpm", None)
            self.session.set_reference(event.ref_rpm)

    def _supply(self, event: Event, t_s: float) -> None:
        assert event.vbus_v is not None
        plant = self.session.plant
        if event.ramp_s > 0:
            self.player.ramps["vbus_v"] = Ramp(t_s, t_s + event.ramp_s, plant.vbus_v, event.vbus_v)
        else:
            plant.vbus_v = self.supply_v = event.vbus_v

    def _tick_ramps(self, t_s: float) -> None:
        for kind, ramp in list(self.player.ramps.items()):
            value = ramp.value(t_s)
            if kind == "ref_rpm":
                self.session.set_reference(value)
            elif kind == "vbus_v":
                self.session.plant.vbus_v = self.supply_v = value
            if t_s >= ramp.t1:
                del self.player.ramps[kind]


# ------------------------------------------------------------------------------------- live
@dataclass
class CtlStep:
    """A `ctl step` in progress: hold, step, then answer with the metrics."""

    request: "ControlRequest"
    from_rpm: float
    to_rpm: float
    due_s: float
    t_step_s: float | None = None


class LivePart:
    """Every history period while it has work: the guard's look after a tuning change, `ctl step`
    in progress, the control socket's requests (every observe period)."""

    def __init__(self, session: "Session", control: "ControlSource | None") -> None:
        self.session = session
        self.control = control
        self.steps: list[CtlStep] = []
        self.guard_ref_rpm = 0.0  # the reference the guard compares with (from the history sample)

    def due_at(self, k: int) -> float:
        session = self.session
        if session.drive is None or not (self.control is not None or self.steps
                                         or k * session.period.s < session.tuning.watching):
            return math.inf
        every = session.options.history_every_periods
        return -(-k // every) * every

    def run(self, k: int) -> None:
        session = self.session
        t_s = session.period.t_s(k)
        if t_s < session.tuning.watching:  # live changes act from this period on: noted at its time
            drive, plant = session.drive, session.plant
            peak = max(abs(i) for i in plant.i_abc)
            note = session.tuning.guard_check(t_s, self.guard_ref_rpm, plant.speed_rpm, peak, drive.state, drive.fault,
                                              bool(getattr(plant, "fault_input", False)))
            if note is not None:
                session.note(t_s, note)
        if self.steps:
            self._advance_steps(t_s)
        if self.control is not None and k % session.options.observe_every_periods == 0:
            for request in self.control.poll():
                session.handle_control(request, t_s)

    def start_step(self, request: "ControlRequest", from_rpm: float, to_rpm: float, t_s: float) -> None:
        """`ctl step A B`: reference A now, B after a 1 s hold; reply with the metrics 1 s later.
        The scenario's events and ramps wait until the step has answered (noted when some are due)."""
        session = self.session
        due = session.player.next_t_s
        held = (f"; scenario events due from t={due:.3f} s wait until the step ends"
                if due < t_s + CTL_STEP_HOLD_S + CTL_STEP_AFTER_S or session.player.ramps else "")
        session.reference_now(from_rpm, t_s, f"step {from_rpm:g} -> {to_rpm:g} rpm (ctl): hold {from_rpm:g}{held}")
        self.steps.append(CtlStep(request, from_rpm, to_rpm, t_s + CTL_STEP_HOLD_S))
        session.scenario.wake(session.periods_done)  # it looks again, and holds

    def _advance_steps(self, t_s: float) -> None:
        session = self.session
        for step in list(self.steps):
            if t_s < step.due_s:
                continue
            if step.t_step_s is None:  # the hold is over: step now
                session.set_reference(step.to_rpm)
                session.segment("ref", t_s, step.to_rpm)
                session.note(t_s, f"step to {step.to_rpm:g} rpm (ctl)")
                step.t_step_s = t_s
                step.due_s = t_s + CTL_STEP_AFTER_S
            else:  # the record after the step is complete: answer
                self.steps.remove(step)
                metrics = self._step_metrics(step.t_step_s, step.to_rpm)
                text = f"step {step.from_rpm:g} -> {step.to_rpm:g} rpm at t={step.t_step_s:.3f} s: {step_text(metrics)}"
                step.request.reply(True, text, {**metrics, "units": dict(STEP_REPLY_UNITS)})
                session.scenario.wake(session.periods_done)  # held scenario events go on

    def _step_metrics(self, t_step: float, to_rpm: float) -> dict[str, Any]:
        from hilbench.bench.metrics import step_metrics

        history = list(self.session.history)  # (tuples made once: read twice below)
        t = [h[0] for h in history if h[0] >= t_step - 0.05]
        y = [h[2] for h in history if h[0] >= t_step - 0.05]
        before = [v for tt, v in zip(t, y) if tt < t_step] or y[:1]
        reference = self.session.profile.reference
        ref = reference.effective_rpm(to_rpm) if reference is not None else to_rpm
        after = [(tt, v) for tt, v in zip(t, y) if tt >= t_step]
        metrics = step_metrics([a for a, _ in after], [b for _, b in after], y0=sum(before) / len(before),
                               y_final_ref=ref, t_step_s=t_step)
        return {k: v for k, v in metrics.as_dict().items() if k in STEP_REPLY_KEYS}


def step_text(metrics: dict[str, Any]) -> str:
    """A `ctl step` reply's figures in one line, with units and sensible digits."""
    def sec(v: float | None) -> str:
        return "never" if v is None else f"{v * 1e3:.1f} ms" if v < 1 else f"{v:.3f} s"

    return (f"rise {sec(metrics.get('rise_time_s'))}, overshoot {metrics.get('overshoot_pct', math.nan):.1f} %, "
            f"settling {sec(metrics.get('settling_time_s'))}, steady-state error {metrics.get('ss_error', math.nan):+.1f} rpm "
            f"({metrics.get('ss_error_pct', math.nan):+.2f} %), ripple {metrics.get('ss_ripple', math.nan):.1f} rpm, "
            f"IAE {metrics.get('iae', math.nan):.2f} rpm*s")


# ------------------------------------------------------------------------------------- after the exchange
#: a history sample as the C span takes it (hilbench/bench/_span.c's put_sample): the period, the
#: rotor's speed, the Drive's fault code, the raw telemetry of the measured speed and of the reference
#: the most history samples one C span takes before the part takes them (bounded memory: about 0.3 MB
#: while they are taken; 2048 samples are 2 s of simulated time at 50 us periods, every 20th sampled)
SPAN_SAMPLES = 2048
SAMPLE_DTYPE = np.dtype([("k", "<i8"), ("w_m", "<f8"), ("fault", "<i4"), ("meas", "<i4"), ("ref", "<i4")])


class HistoryPart:
    """Every history period: the speed history and segments, the overspeed limit, and every
    observe period the display stream, the recorder's flush and the observer's `Snapshot`.
    Periods the C span runs are sampled there and taken here in bulk (`take`); the part is then
    due only at the observe periods where something is to be done (`due_at`)."""

    def __init__(self, session: "Session", live: LivePart) -> None:
        self.session = session
        self.live = live
        self.every = session.options.history_every_periods
        self.observe_every = math.lcm(self.every, session.options.observe_every_periods)
        self.speed_telemetry = ((-1, 0.0), (-1, 0.0))  # (index, scale) of the measured speed and reference
        self.overspeed_rpm = math.inf
        self._obs_last = (0.0, 0)
        self._sampled = (-1, math.nan)  # the last sample's period and measured speed
        self._observed = -1  # the last observe period observed (once a period, whoever sampled it)

    def start(self, speed_telemetry: tuple[tuple[int, float], tuple[int, float]], wall_s: float) -> None:
        options = self.session.options
        self.speed_telemetry = speed_telemetry
        self.overspeed_rpm = options.overspeed_rpm if options.overspeed_rpm > 0 else math.inf
        self._obs_last = (wall_s, 0)

    def due_at(self, k: int) -> float:
        every = self.every
        if not self.session.samples_in_c:  # the Python loop runs the periods: every history period
            return -(-k // every) * every
        return self._observe_due(k)

    def _observe_due(self, k: int) -> float:
        """The first observe period from k on where observing does something: every one with a
        display or an observer, else the one where the recorder's next write is due (its flush, or
        a CSV's rows for its writer thread: `Recorder.rows_to_write`); at the latest the one after
        SPAN_SAMPLES samples (the span's sample buffer, and what `take` makes of it, stay that
        size however long the run: a span as long as the run held all its samples)."""
        session, every = self.session, self.observe_every
        first = max(k, 1)
        if session.display is None and session.observer is None:
            most = k + SPAN_SAMPLES * self.every
            rows_to_write = getattr(session.recorder, "rows_to_write", None)
            if rows_to_write is None or session.rows_in_c:  # no recorder, one that keeps every row in
                first = most  # memory, or the C span hands its chunks over itself
            else:  # after that period its next write is due
                first = max(first, min(k - 1 + rows_to_write(), most))
        return -(-first // every) * every

    def run(self, k: int) -> None:
        taken, meas = self._sampled
        if taken != k:  # a period the Python loop ran: its sample here
            self.sample(k)
        elif k % self.session.options.observe_every_periods == 0 and k and self._observed != k:
            # the C span's sample, taken in bulk: observed here (one C left to Python was, at its sample)
            self._observe(k, self.session.drive, meas)  # type: ignore[arg-type]

    def sample(self, k: int) -> None:
        """Period k's sample, after its plant period: the reference of `take`."""
        session = self.session
        drive = session.drive
        tele = drive.telemetry
        (i_meas, s_meas), (i_ref, s_ref) = self.speed_telemetry
        meas = tele[i_meas] * s_meas if i_meas >= 0 else math.nan
        self.live.guard_ref_rpm = tele[i_ref] * s_ref if i_ref >= 0 else session.ref_rpm  # the firmware's own when it reports one
        t_s, plant_rpm = session.period.t_s(k), session.plant.w_m * RPM_PER_RAD_S
        session.history.append(t_s, session.ref_rpm, plant_rpm, meas)
        self._sampled = (k, meas)
        if drive.fault:  # the firmware's fault as the live state shows it (no_fault without a recording)
            session.fault_seen(t_s, drive.fault)
        session.segmenter.sample(t_s, plant_rpm, meas)
        if k % session.options.observe_every_periods == 0 and k:
            self._observe(k, drive, meas)
        if not -self.overspeed_rpm <= plant_rpm <= self.overspeed_rpm:
            self._overspeed(k, plant_rpm)

    def take(self, samples: bytes) -> None:
        """The samples the C span took (`SAMPLE_DTYPE` rows, copied out of its buffer), as `sample`
        would have taken each; a sample beyond the overspeed limit is the span's last: the run ends
        at its period."""
        rows = np.frombuffer(samples, dtype=SAMPLE_DTYPE)
        if not len(rows):
            return
        session = self.session
        (i_meas, s_meas), (i_ref, s_ref) = self.speed_telemetry
        ks = rows["k"]
        t_s_array = ks * session.period.s  # float(k) * s, as Period.t_s
        plant_rpm_array = rows["w_m"] * RPM_PER_RAD_S
        meas_array = rows["meas"] * s_meas if i_meas >= 0 else np.full(len(rows), math.nan)
        last = int(rows["ref"][-1])
        self.live.guard_ref_rpm = last * s_ref if i_ref >= 0 else session.ref_rpm
        session.history.extend(t_s_array, session.ref_rpm, plant_rpm_array, meas_array)
        t_s, plant_rpm = t_s_array.tolist(), plant_rpm_array.tolist()
        meas = meas_array.tolist() if i_meas >= 0 else [math.nan] * len(rows)
        self._sampled = (int(ks[-1]), meas[-1])
        faults = np.flatnonzero(rows["fault"])
        for i in (faults[:1].tolist() + faults[-1:].tolist()):  # the first and the last: what fault_seen keeps
            session.fault_seen(t_s[i], int(rows["fault"][i]))
        session.segmenter.sample_many(t_s, plant_rpm, meas)
        rpm = plant_rpm[-1]
        if not -self.overspeed_rpm <= rpm <= self.overspeed_rpm:
            k = int(ks[-1])
            if k % session.options.observe_every_periods == 0 and k:
                self._observe(k, session.drive, meas[-1])  # type: ignore[arg-type]
            self._overspeed(k, rpm)

    def _overspeed(self, k: int, plant_rpm: float) -> None:
        session = self.session
        session.end_on_limit(k, f"overspeed: the plant turns at {plant_rpm:.0f} rpm, beyond the "
                                f"{session.options.overspeed_rpm:g} rpm limit ([protection] overspeed_rpm)")

    def _observe(self, k: int, drive: Drive, meas: float) -> None:
        session, pacing = self.session, self.session.pacing
        self._observed = k
        if session.display is not None:  # the scope takes its rows before a flush empties the buffer
            session.display.due(k, drive, pacing)
        if session.recorder is not None:
            session.recorder.maybe_flush()
        if session.observer is not None:
            session.observer(self.snapshot(k, drive, meas))

    def snapshot(self, k: int, drive: Drive, meas: float) -> Snapshot:
        import time

        session, pacing = self.session, self.session.pacing
        plant = session.plant
        rtts = pacing.rtts if pacing is not None else session.lockstep_rtts
        stats = percentiles([r * 1e6 for r in rtts.recent])
        now = time.perf_counter()
        last_wall, last_k = self._obs_last
        rate = (k - last_k) / max(now - last_wall, 1e-9)
        self._obs_last = (now, k)
        ia, ib, ic = plant.i_abc
        telemetry = {name: drive.telemetry[index] * scale for name, (index, scale) in session.telemetry_index.items()}
        return Snapshot(
            t_s=session.period.t_s(k), duration_s=session.duration_s, period=k, ref_rpm=session.ref_rpm,
            speed_rpm=plant.speed_rpm, measured_rpm=meas, state=drive.state, sector=drive.sector,
            direction_ccw=bool(drive.direction_ccw), output_mode=drive.output_mode,
            duties=(drive.duty_a, drive.duty_b, drive.duty_c), i_abc=(ia, ib, ic), i_bus=plant.i_bus,
            telemetry=telemetry, periods_per_s=rate, rtt_p50_us=stats.get("p50", math.nan),
            rtt_p99_us=stats.get("p99", math.nan), link=session.link_stats(),
            overruns=pacing.overruns if pacing is not None else 0, messages=session.messages[-4:],
            history=session.history,  # the dashboard decimates it to its width
            fault=drive.fault,
        )


class BusPart:
    """Every period, with a bus capacitor or an over-voltage limit: the supply only sources, so the
    bus rises above it while the bridge returns energy (the period's mean bus current is negative)
    and falls back to it as the bridge draws again; then the over-voltage limit."""

    def __init__(self, session: "Session", scenario: ScenarioPart) -> None:
        self.session = session
        self.scenario = scenario

    def due_at(self, k: int) -> float:
        return k

    def run(self, k: int) -> None:
        session = self.session
        plant, options = session.plant, session.options
        if options.bus_capacitance_f > 0.0:
            charged = plant.vbus_v - plant.i_bus * session.period.s / options.bus_capacitance_f
            supply = self.scenario.supply_v
            plant.vbus_v = charged if charged > supply else supply
        if 0.0 < options.overvoltage_v < plant.vbus_v:
            session.end_on_limit(k, f"over-voltage: the bus is at {plant.vbus_v:.5g} V, beyond the "
                                    f"{options.overvoltage_v:g} V limit ([protection] overvoltage_v)")


__all__ = ["SAMPLE_DTYPE", "SPAN_SAMPLES", "STEP_REPLY_UNITS", "step_text", "BUTTON_HOLD_S", "BusPart", "CtlStep", "HistoryPart", "LivePart", "Part", "ScenarioPart", "Schedule"]
