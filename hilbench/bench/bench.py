"""A bench opened on any target, for Python scripts, tests and the CLI alike.

    import hilbench
    with hilbench.Bench(target="inprocess:NAME") as bench:   # NAME: `hilbench targets`
        bench.set_reference(1500)
        bench.press("s2")
        bench.run(1.0)
        speed = bench.signals()["speed_rpm"]

The bench owns what it opened (an emulator process, a link, a recording) and closes all of it on
exit, whatever happened. Everything goes through the session's own paths: parameter writes are
checked and guarded as `hilbench ctl set` is, references reach the firmware as its profile says,
and every action is an event in the recording.
"""

from __future__ import annotations

import dataclasses
import json
import math
import numbers
import os
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator, Mapping, Sequence

import numpy as np

from hilbench.version import __version__
from hilbench.bench import settings
from hilbench.bench.cpus import CpuPinning, FifoPriority
from hilbench.bench.assembly import BenchParts, build_bench, configured_profile, connect
from hilbench.bench.column_chunks import ArrayChunks, ColumnChunks, recording_chunks
from hilbench.bench.recorder import MemoryRecorder, Recorder, read_recording
from hilbench.bench.scenario import LOAD_KINDS, Event
from hilbench.bench.session import ControlSource, PlantLike, Session, Snapshot, Summary
from hilbench.bench.settings import load_config
from hilbench.config import BenchConfig
from hilbench.errors import ConfigError, LinkError
from hilbench.limits import is_finite_number, shown
from hilbench.plant.period import Period
from hilbench.protocol import PROTOCOL_VERSION, SCHEMA_FINGERPRINT, TargetHello
from hilbench.targets.base import Target
from hilbench.targets.profile import TargetProfile

#: how often `run(until=...)` looks at its condition
CONDITION_EVERY_S = 0.001


@dataclass(frozen=True)
class Signals(Mapping[str, np.ndarray]):
    """Everything recorded so far: one float64 array per column, with its unit."""

    columns: Mapping[str, np.ndarray]
    units: Mapping[str, str]

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.columns[name]
        except KeyError:
            raise KeyError(f"no column {name!r} (recorded: {', '.join(self.columns)})") from None

    def __iter__(self) -> Iterator[str]:
        return iter(self.columns)

    def __len__(self) -> int:
        return len(self.columns)

    def unit(self, name: str) -> str:
        return self.units.get(name, "")


def as_config(config: BenchConfig | str | os.PathLike[str] | None, target: str | None,
               overrides: Sequence[str]) -> BenchConfig:
    if isinstance(config, BenchConfig):
        if not target and not overrides:
            return config
        raise ConfigError("Bench: give target= and overrides= with a config path, not with a loaded BenchConfig")
    extra = list(overrides) + ([f"link.target={json.dumps(target)}"] if target else [])  # a TOML string, escaped
    return load_config(config, extra)


#: what a closed Bench says to a call that would run or change it
CLOSED = "Bench: closed (its run has ended, its results stay readable; a Bench runs once: open a new one)"


class Bench:
    """A target, a plant and a session, opened together; a context manager."""

    def __init__(
        self,
        config: BenchConfig | str | os.PathLike[str] | None = None,
        *,
        target: str | Target | None = None,
        plant: PlantLike | None = None,
        overrides: Sequence[str] = (),
        record: str | os.PathLike[str] | None = None,
        scenario: bool = False,
        observer: Callable[[Snapshot], None] | None = None,
        control: ControlSource | None = None,
        keep_rows: bool = True,
    ) -> None:
        """``config``: a path, a loaded config or None (the packaged default); ``target``: a target
        spec, or a `Target` object the caller made (it is not closed with the bench); ``plant``: a
        plant object instead of the config's; ``overrides``: `TABLE.KEY=VALUE` words; ``record``: a .csv/.npz path (default: kept in
        memory); ``scenario``: play the config's scenario (off: the script drives); ``keep_rows=False``
        without ``record``: keep no rows at all (a run of any length in flat memory; no signals())."""
        self._keep_rows = keep_rows
        if target is not None and not isinstance(target, str) and not callable(getattr(target, "hello", None)):
            raise ConfigError(f"Bench: target={shown(target)}: a target spec (see `hilbench targets`) "
                              "or a target object (one with hello, step, ...)")
        self._target_object = None if target is None or isinstance(target, str) else target
        self._plant_object = plant
        self.config = as_config(config, target if isinstance(target, str) else None, overrides)
        self._record_path = Path(record) if record is not None else None
        self._play_scenario = scenario
        self._observer = observer
        self._control = control
        self._parts: BenchParts | None = None
        self._scheduling: list[CpuPinning | FifoPriority] = []  # a real-time run's CPU and priority, undone at close
        self.session: Session | None = None
        self._closed = False  # the run has ended: results may be read, nothing more run or set
        self.recorder: Recorder | MemoryRecorder | None = None
        self.warnings: list[str] = []  # what the caller should tell the user before the run

    # ------------------------------------------------------------------ open and close
    def open(self) -> "Bench":
        """Connect the target, build the plant, handshake, write the configured parameters."""
        if self._closed:
            raise ConfigError(CLOSED)
        cfg = self.config
        self.warnings = settings.link_warnings(cfg) if self._target_object is None else []
        events = settings.scenario_events(cfg) if self._play_scenario else ()
        parts = self._parts = build_bench(cfg, target=self._target_object, plant=self._plant_object, events=events,
                                          observer=self._observer, control=self._control)
        session = self.session = parts.session
        handle, options = parts.handle, parts.options
        try:
            try:
                hello = session.handshake()
            except LinkError as exc:
                raise LinkError(f"{handle.label}: handshake failed: {exc}{handle.child_status()}") from None
            if hasattr(handle.target, "timeout_s"):
                handle.target.timeout_s = options.timeout_s  # type: ignore[attr-defined]
            initial = settings.initial_params(cfg)
            if initial:
                session.set_params(initial, 0.0, guard=False)
            self.recorder = self._make_recorder(hello, session, options.period_us)
            session.recorder = self.recorder
            if options.mode == "realtime":
                self._schedule_realtime(handle.process)
            session.begin()
        except BaseException:
            self.close()
            raise
        return self

    def _schedule_realtime(self, process: "subprocess.Popen[bytes] | None") -> None:
        """This thread and the target process it started on one CPU, at SCHED_FIFO (from the start, or
        once the CPU is contended), as [link] asks."""
        link = self.config.link
        pids = [process.pid] if process is not None else []
        if link.pin_realtime and pids:
            self._scheduling.append(CpuPinning(pids, link.realtime_cpu).__enter__())
        if link.realtime_priority > 0:
            fifo = FifoPriority(pids, link.realtime_priority, when=link.realtime_fifo).__enter__()
            self._scheduling.append(fifo)
            if link.realtime_fifo == "contended" and self.session is not None:
                self.session.on_contended = fifo.engage

    def _make_recorder(self, hello: TargetHello, session: Session, period_us: int) -> Recorder | MemoryRecorder | None:
        cfg = self.config
        metadata = {
            "hilbench_version": __version__,
            "protocol_version": PROTOCOL_VERSION,
            "schema_fingerprint": f"0x{SCHEMA_FINGERPRINT:08x}",
            "seed": session.options.seed,
            "target": cfg.link.target,
            "target_hello": hello._asdict(),
            "params": session.param_values(),
            "config_source": cfg.source,
            "config": settings.config_metadata(cfg),
            "period_us": period_us,
            "mode": session.options.mode,
            "predicted_duties": session.predicting,  # the Drives' duties: predicted over each period
        }
        if self._record_path is None:
            return MemoryRecorder(metadata) if self._keep_rows else None
        return Recorder(self._record_path, metadata, flush_rows=max(1, round(Period(period_us).per_s)))  # a second

    def close(self) -> Summary | None:
        """End the run (target stopped, recording closed) and release everything; idempotent."""
        summary = None
        try:
            if self.session is not None and hasattr(self.session, "summary"):
                summary = self.session.end()
                if self._scheduling:
                    summary.cpus = "; ".join(held.status for held in self._scheduling)
        finally:
            while self._scheduling:
                self._scheduling.pop().__exit__(None, None, None)
            if isinstance(self.recorder, Recorder) and not self.recorder.closed:
                self.recorder.close("aborted")
            if self._parts is not None:
                self._parts.close()
                self._parts = None
            self._closed = self.session is not None
        return summary

    @property
    def target_process(self) -> "subprocess.Popen[bytes] | None":
        """The emulator or firmware-build process this bench started (None: in process, or a port)."""
        return self._parts.handle.process if self._parts is not None else None

    def child_status(self) -> str:
        """How the emulator process this bench started is doing, for error lines ("" if none)."""
        return self._parts.handle.child_status() if self._parts is not None else ""

    def __enter__(self) -> "Bench":
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ running
    @property
    def _session(self) -> Session:
        if self.session is None:
            raise ConfigError("Bench: not open (use `with Bench(...) as bench:` or bench.open())")
        return self.session

    @property
    def _acting(self) -> Session:
        """The session, for a call that runs periods or changes the bench: refused once closed (the
        target is gone and the recording written: periods run now would be lost)."""
        if self._closed:
            raise ConfigError(CLOSED)
        return self._session

    @property
    def t_s(self) -> float:
        """Simulated time now (the start of the next period)."""
        return self._session.now_s

    def run(self, seconds: float | None = None, *, until: Callable[["Bench"], bool] | None = None,
            timeout_s: float = 60.0) -> bool:
        """Run ``seconds`` of simulated time, or until ``until(bench)`` is true (looked at every
        millisecond, at most ``timeout_s``), or the config's scenario to its end when neither is
        given. Returns False when the run has ended (scenario end, `ctl stop`)."""
        session = self._acting
        period_s = session.period.s
        if until is None:
            if seconds is None:
                return session.advance(max(0, session.planned_periods - session.periods_done))
            return session.advance(_periods(seconds, period_s, "seconds"))
        limit = session.periods_done + _periods(seconds if seconds is not None else timeout_s, period_s, "timeout_s")
        chunk = max(1, round(CONDITION_EVERY_S / period_s))
        while session.periods_done < limit:
            if until(self):
                return True
            if not session.advance(min(chunk, limit - session.periods_done)):
                return False
        return bool(until(self))

    # ------------------------------------------------------------------ steering
    def _act(self, event: Event) -> None:
        session = self._acting
        session.apply_now(dataclasses.replace(event, at_s=self.t_s))

    def press(self, button: str = "s2") -> None:
        """Press a button: s2 starts and stops the motor (as the board's S2), s3 the other."""
        if button not in ("s2", "s3"):
            raise ConfigError(f"press {button!r}: buttons are s2 and s3")
        self._act(Event(at_s=0.0, press=button))

    def set_reference(self, rpm: float, ramp_s: float = 0.0) -> None:
        """The speed reference, by the way the target takes it (a pot, a parameter)."""
        self._act(Event(at_s=0.0, ref_rpm=_finite(rpm, "rpm"), ramp_s=_finite(ramp_s, "ramp_s")))

    def set_load(self, torque_nm: float, kind: str = "constant") -> None:
        """The load from now on: constant N*m, linear/quadratic coefficient, or locked."""
        if kind not in LOAD_KINDS:
            raise ConfigError(f"set_load kind={shown(kind)}: one of {', '.join(LOAD_KINDS)}")
        self._act(Event(at_s=0.0, load_nm=_finite(torque_nm, "torque_nm"), load_kind=kind))

    def inject_fault(self, kind: str, duration_s: float | None = None) -> None:
        """A sensor fault: one of `faults.FAULT_KINDS` (hall_a_high … hall_c_low, hall_missing_edge,
        encoder_glitch, …, clear)."""
        from hilbench.bench.faults import FAULT_KINDS

        if kind not in FAULT_KINDS:
            raise ConfigError(f"inject_fault {kind!r}: one of {', '.join(FAULT_KINDS)}")
        if duration_s is not None and not (is_finite_number(duration_s) and duration_s >= 0):
            raise ConfigError(f"inject_fault duration_s={shown(duration_s)}: expected a finite number of seconds >= 0, "
                              "or None (until cleared)")
        self._act(Event(at_s=0.0, fault=kind, fault_duration_s=duration_s))

    def get_params(self) -> dict[str, float]:
        """Every declared parameter in its units (Q15 ones as fractions)."""
        return self._session.param_values()

    def set_params(self, params: Mapping[str, float] | None = None, /, *, guard: bool = True,
                   **values: float) -> None:
        """Write parameters at once, checked and guarded as `hilbench ctl set` is:
        ``bench.set_params(kp=0.1, ki=0.02)`` or ``bench.set_params({"kp": 0.1, "ki": 0.02})``."""
        if params is not None and not isinstance(params, Mapping):
            raise ConfigError(f"set_params: expected a mapping of parameter names to values, got {params!r}")
        merged = {**(params or {}), **values}
        if not merged:
            raise ConfigError("set_params: no parameter given (e.g. set_params(kp=0.1))")
        bad = [k for k, v in merged.items() if isinstance(v, bool) or not isinstance(v, numbers.Real)]
        if bad:
            raise ConfigError(f"set_params: values must be numbers, got {bad[0]}={shown(merged[bad[0]])}")
        # an int no float holds is as out of range as an infinity: the session's check refuses both
        values = {str(k): float(v) if is_finite_number(v) or not isinstance(v, numbers.Integral)
                  else (math.inf if v > 0 else -math.inf) for k, v in merged.items()}
        self._acting.set_params(values, self.t_s, guard=bool(guard))

    # ------------------------------------------------------------------ reading
    @property
    def hello(self) -> TargetHello:
        assert self._session.hello is not None
        return self._session.hello

    @property
    def profile(self) -> TargetProfile:
        return self._session.profile

    @property
    def speed_rpm(self) -> float:
        """The plant's shaft speed now."""
        return float(self._session.plant.speed_rpm)  # type: ignore[attr-defined]

    def signals(self) -> Signals:
        """Every recorded column so far as arrays (one row per period), with units."""
        recorder = self.recorder
        if isinstance(recorder, MemoryRecorder):
            columns = recorder.columns()
            units = {name: unit for name, unit, _ in recorder.rows.layout.column_specs}
            return Signals(columns, units)
        if recorder is None:
            raise ConfigError("Bench: nothing recorded yet")
        if not recorder.closed:
            recorder.flush()
        data = read_recording(recorder.path)
        return Signals(data.columns, data.units)

    def signal_chunks(self) -> ColumnChunks:
        """The recorded columns to read a chunk of rows at a time (the run's checks: memory bounded
        however long the run, where `signals` holds every column whole)."""
        recorder = self.recorder
        if isinstance(recorder, MemoryRecorder):
            return ArrayChunks(recorder.columns(), {name: unit for name, unit, _ in recorder.rows.layout.column_specs})
        if recorder is None:
            raise ConfigError("Bench: nothing recorded yet")
        if not recorder.closed:
            recorder.flush()
        return recording_chunks(recorder.path)

    @property
    def events(self) -> tuple[str, ...]:
        """The events so far, as text (`t=… what`)."""
        recorder = self.recorder
        if isinstance(recorder, MemoryRecorder):
            return tuple(text for _, text, _ in recorder.events if not text.startswith("segment:"))
        return tuple(self._session.messages)

    def summary(self) -> Summary:
        """The run's summary now (closes the run: call it at the end)."""
        summary = self.close()
        if summary is None:
            raise ConfigError("Bench: never opened")
        return summary


def _finite(value: float, what: str) -> float:
    if not is_finite_number(value):
        raise ConfigError(f"{what}={shown(value)}: expected a finite number")
    return float(value)


def _periods(seconds: float, period_s: float, what: str) -> int:
    if not is_finite_number(seconds) or not 0 <= seconds <= 1e7:
        raise ConfigError(f"run {what}={shown(seconds)}: expected 0..1e7 s")
    return round(seconds / period_s)


__all__ = ["Bench", "Signals", "configured_profile", "connect"]
