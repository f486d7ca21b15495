"""`hilbench run --mode monitor` and `hilbench step --mode monitor`: a monitor session (the plant is
the real motor, hilbench.bench.monitor) from a config, and a step test on the firmware's measured speed.

They print nothing. The board is a port (a serial device, a pty, a pyserial URL); the recording is
closed and the board's motor stopped whatever happens.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from hilbench.version import __version__
from hilbench.bench import settings
from hilbench.bench.assembly import configured_profile
from hilbench.bench.bench import Signals
from hilbench.bench.column_chunks import AliasChunks, ArrayChunks, ColumnChunks, recording_chunks
from hilbench.bench.launcher import open_target
from hilbench.bench.metrics import step_metrics
from hilbench.bench.monitor import MonitorOptions, MonitorSession, monitor_options
from hilbench.bench.recorder import MemoryRecorder, Recorder
from hilbench.bench.scenario import Event
from hilbench.bench.summary import Snapshot, Summary
from hilbench.config import BenchConfig
from hilbench.errors import ConfigError
from hilbench.plant.period import Period
from hilbench.protocol import PROTOCOL_VERSION, SCHEMA_FINGERPRINT, State

if TYPE_CHECKING:
    from hilbench.bench.steptest import StepResult, StepTest


#: monitor mode's least request timeout and retry interval (wall seconds)
MONITOR_TIMEOUT_S = 5.0
MONITOR_RETRY_S = 0.5


def _options(cfg: BenchConfig, duration_s: float | None) -> MonitorOptions:
    return monitor_options(cfg.link.period_us, cfg.link.watchdog_ms, duration_s,
                           max(cfg.link.timeout_ms / 1000.0, MONITOR_TIMEOUT_S))


def _metadata(cfg: BenchConfig, session: MonitorSession) -> dict[str, Any]:
    assert session.hello is not None
    return {
        "hilbench_version": __version__, "protocol_version": PROTOCOL_VERSION,
        "schema_fingerprint": f"0x{SCHEMA_FINGERPRINT:08x}", "seed": 0, "target": cfg.link.target,
        "target_hello": session.hello._asdict(), "params": session.param_values(), "config_source": cfg.source,
        "config": settings.config_metadata(cfg), "period_us": cfg.link.period_us, "mode": "monitor",
        "predicted_duties": False,
    }


def run_monitor_session(
    cfg: BenchConfig,
    events: tuple[Event, ...],
    *,
    record: str | Path | None = None,
    keep_rows: bool = False,
    duration_s: float | None = None,
    control: Any = None,
    gains: dict[str, float] | None = None,
    on_ready: Callable[[MonitorSession], None] | None = None,
    observer: Callable[[Snapshot], None] | None = None,
) -> tuple[Summary, ColumnChunks | None]:
    """One monitor session on the configured board: handshake, ``gains`` written, the events played
    at the board's time; the summary and (recorded or kept) the signals, to read in chunks (a
    recording is not read here: a check reads only its columns, a chunk at a time)."""
    # a request's answer waits behind the stream's Drives, and a frame sent again while the board
    # sends is one it loses (it holds one received frame): patient timeouts and retries
    handle = open_target(cfg.link.target, mode="realtime", timeout_s=max(cfg.link.timeout_ms / 1000.0, MONITOR_TIMEOUT_S),
                         watchdog_ms=cfg.link.watchdog_ms, retry_s=max(cfg.link.retry_ms / 1000.0, MONITOR_RETRY_S))
    try:
        target = handle.target
        if not hasattr(target, "stray_sink"):
            raise ConfigError(f"monitor mode: target {cfg.link.target!r} is not a board on a link; give its port "
                              "(a serial device, a pty, serial:/dev/ttyUSB0?baud=250000)")
        tuning = cfg.tuning
        from hilbench.bench.livetuning import GuardSettings

        guard = GuardSettings(tuning.guard, tuning.guard_window_s, tuning.guard_oscillation_rpm, tuning.guard_swings,
                              tuning.guard_current_a)
        session = MonitorSession(target, events, _options(cfg, duration_s), profile=configured_profile(cfg),
                                 control=control, guard=guard, target_label=cfg.link.target,  # type: ignore[arg-type]
                                 observer=observer)
        if on_ready is not None:
            on_ready(session)

        def make_recorder(ready: MonitorSession) -> Recorder | MemoryRecorder | None:
            if record is not None:
                return Recorder(Path(record), _metadata(cfg, ready),
                                flush_rows=max(1, round(Period(cfg.link.period_us).per_s)))
            return MemoryRecorder(_metadata(cfg, ready)) if keep_rows else None

        summary = session.run(make_recorder, gains)
        recorder = session.recorder
    finally:
        handle.close()
    signals: ColumnChunks | None = None
    if isinstance(recorder, MemoryRecorder):
        signals = ArrayChunks(recorder.columns(), {n: u for n, u, _ in recorder.rows.layout.column_specs})
    elif record is not None:
        signals = recording_chunks(record)
    return summary, signals


def run_monitor(cfg: BenchConfig, *, record: str | Path | None = None, control: Any = None,
                on_ready: Callable[[MonitorSession], None] | None = None,
                observer: Callable[[Snapshot], None] | None = None) -> Summary:
    """`hilbench run --mode monitor`: the config's scenario on the board; its [[check]] tables judged
    on the recording (without --record, as a HIL run, the signal checks say SKIP: no rows are kept
    in memory, which grew with the run)."""
    summary, signals = run_monitor_session(cfg, settings.scenario_events(cfg), record=record,
                                           keep_rows=False, duration_s=cfg.run.duration_s,  # as a HIL run: no rows kept in memory
                                           control=control, on_ready=on_ready, observer=observer)
    if cfg.check:
        from hilbench.bench.checks import run_checks

        def columns() -> ColumnChunks:
            """The recorded signals, the firmware's measured speed standing for the plant's speed
            (`speed_rpm`: there is no other in monitor mode)."""
            if signals is None:  # the signal checks say SKIP (memory stays flat however long the run)
                raise ConfigError("monitor: nothing recorded")
            speed = settings.configured_target_profile(cfg).speed_column
            if speed is None or speed not in signals.names:
                return signals
            return AliasChunks(signals, {"speed_rpm": speed})

        from hilbench.plant.model import OUTPUTS

        no_plant = {out.column: "a monitor-mode run records no plant (the plant is the real motor)" for out in OUTPUTS}
        summary.checks = run_checks(cfg.check, summary, columns, absent=no_plant)
    return summary


def monitor_step(cfg: BenchConfig, test: "StepTest", gains: dict[str, float] | None = None,
                 record: str | Path | None = None, warn: Callable[[str], None] | None = None) -> "StepResult":
    """`hilbench step --mode monitor`: the step test on the board's motor, its figures from the
    firmware's measured speed (the telemetry column the profile names), from the step's row on;
    ``warn`` gets the session's warnings (e.g. a Stop the stream never confirmed)."""
    summary, kept = run_monitor_session(cfg, test.events(), record=record, keep_rows=record is None,
                                        duration_s=test.duration_s, gains=gains)
    for warning in summary.warnings:
        if warn is not None:
            warn(warning)
    assert kept is not None
    signals = Signals(kept.whole(), kept.units)  # a step test's few seconds
    profile = configured_profile(cfg) or settings.configured_target_profile(cfg)
    column = profile.speed_column
    if column is None or column not in signals:
        raise ConfigError(f"step --mode monitor: target {profile.name!r} streams no measured speed "
                          f"(columns: {', '.join(signals)})")
    return analyse_measured(signals, test, profile, column, gains or {})


def analyse_measured(signals: Any, test: "StepTest", profile: Any, column: str, gains: dict[str, float],
                     monitor: bool = True) -> "StepResult":
    """Step figures on the firmware's measured speed ``column`` (a HIL run's recording or a monitor
    one: the same analysis, so the two compare), against the reference as the firmware gets it (monitor:
    the profile's monitor reference; else its reference, a pot's quantum). The step is at the first
    row at or after settle_s."""
    from hilbench.bench.steptest import StepResult

    t = np.asarray(signals["t_s"], dtype=float)
    y = np.asarray(signals[column], dtype=float)
    reference = profile.monitor_reference if monitor else profile.reference
    y0 = reference.effective_rpm(test.from_rpm) if reference is not None else test.from_rpm
    y_ref = reference.effective_rpm(test.to_rpm) if reference is not None else test.to_rpm
    stepped = np.flatnonzero(t >= test.settle_s)
    t_step = float(t[stepped[0]]) if stepped.size else test.settle_s
    metrics = step_metrics(t, y, y0=y0, y_final_ref=y_ref, t_step_s=t_step)
    after = t >= t_step
    label = "/".join(f"{v:.4g}" for v in gains.values()) or "firmware defaults"
    state = np.asarray(signals["state"]) if "state" in signals else np.zeros(0)
    stalled = bool(state.size and int(state[-1]) == int(State.STALLED))
    return StepResult(label, dict(gains), metrics, t[after] - t_step, y[after], y_ref, stalled)


__all__ = ["analyse_measured", "monitor_step", "run_monitor", "run_monitor_session"]
