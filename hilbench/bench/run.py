"""One bench run from a config: connect the target, build the plant, record, run, clean up.

Used by `hilbench run` and by tests; it prints nothing. Whatever happens — a fault, Ctrl-C, a
bad parameter — the recording is closed and any process the run started is reaped.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

from hilbench import __version__
from hilbench.bench import settings
from hilbench.bench.launcher import TargetHandle, open_target
from hilbench.bench.cpus import CpuPinning
from hilbench.bench.recorder import Recorder
from hilbench.bench.session import Session, SessionOptions, Snapshot, Summary
from hilbench.config import BenchConfig, load_config, plant_params_from_config
from hilbench.errors import ConfigError, LinkError
from hilbench.protocol import PROTOCOL_VERSION
from hilbench.targets.profile import TargetProfile

if TYPE_CHECKING:
    from hilbench.bench.steptest import StepResult, StepTest


@dataclass(frozen=True)
class RunRequest:
    """What the user asked for on top of the config file."""

    config_path: str | None = None
    overrides: tuple[str, ...] = ()
    target: str | None = None
    mode: str | None = None
    duration_s: float | None = None
    record: str | None = None


def load_run_config(request: RunRequest) -> BenchConfig:
    """The config with the command line's choices folded in as overrides (validated together)."""
    overrides = list(request.overrides)
    if request.target is not None:
        overrides.append(f'link.target="{request.target}"')
    if request.mode is not None:
        overrides.append(f'run.mode="{request.mode}"')
    if request.duration_s is not None:
        overrides.append(f"run.duration_s={request.duration_s!r}")
    return load_config(request.config_path, overrides)


def effective_seed(cfg: BenchConfig) -> int:
    """[run] seed when given, else [plant] seed."""
    return cfg.run.seed if cfg.run.seed is not None else cfg.plant.seed


def configured_profile(cfg: BenchConfig) -> TargetProfile | None:
    """The profile the config names (by its target spec, or [link] firmware for a port), else None:
    a board's profile is then found by the firmware name in its HELLO."""
    if settings.target_name(cfg.link.target) is None and cfg.link.firmware is None:
        return None
    return settings.target_profile(cfg.link)


def settings_profile(cfg: BenchConfig) -> TargetProfile:
    """The configured target's profile (the default target's for a port with no [link] firmware)."""
    return settings.target_profile(cfg.link)


def in_process(cfg: BenchConfig) -> BenchConfig:
    """The same config on the configured target's in-process model (sweeps run there)."""
    profile = settings_profile(cfg)
    return cfg.replace(link=dataclasses.replace(cfg.link, target=f"inprocess:{profile.name}", firmware=None))


def connect(cfg: BenchConfig, options: SessionOptions) -> TargetHandle:
    """Open the configured target (spawning the emulator if asked)."""
    return open_target(
        cfg.link.target,
        profile=configured_profile(cfg),
        options=cfg.target,
        mode=options.mode,
        timeout_s=options.timeout_s,
        watchdog_ms=options.watchdog_ms,
    )


def run_bench(
    cfg: BenchConfig,
    *,
    record: str | Path | None = None,
    observer: Callable[[Snapshot], None] | None = None,
    control: Any = None,
    on_ready: Callable[[Session], None] | None = None,
) -> Summary:
    """Run the bench described by ``cfg``; raises HilbenchError kinds on faults."""
    from hilbench.plant.model import Plant

    options = dataclasses.replace(settings.session_options(cfg), seed=effective_seed(cfg))
    events = settings.scenario_events(cfg)
    plant = Plant(plant_params_from_config(cfg), seed=options.seed, substeps=cfg.plant.substeps)
    handle = connect(cfg, options)
    recorder: Recorder | None = None
    try:
        session = Session(
            handle.target, plant, events, options, profile=configured_profile(cfg), observer=observer, control=control,
            link_stats=handle.link_stats, target_label=handle.label, guard=settings.guard_settings(cfg),
        )
        try:
            hello = session.handshake()
        except LinkError as exc:
            raise LinkError(f"{handle.label}: handshake failed: {exc}{handle.child_status()}") from None
        if hasattr(handle.target, "timeout_s"):
            handle.target.timeout_s = options.timeout_s  # the first answer may wait for the process to start
        initial = settings.initial_params(cfg)
        if initial:
            session.set_params(initial, 0.0, guard=False)
        if record is not None:
            metadata = {
                "hilbench_version": __version__,
                "protocol_version": PROTOCOL_VERSION,
                "seed": options.seed,
                "target": cfg.link.target,
                "target_hello": hello._asdict(),
                "params": session.param_values(),
                "config_source": cfg.source,
                "config": settings.config_metadata(cfg),
                "period_us": options.period_us,
                "mode": options.mode,
            }
            recorder = Recorder(Path(record), metadata, flush_rows=max(1, round(1e6 / options.period_us)))
            session.recorder = recorder
        if on_ready is not None:
            on_ready(session)
        try:
            if options.mode == "realtime" and cfg.link.pin_realtime and handle.process is not None:
                with CpuPinning([handle.process.pid], cfg.link.realtime_cpu) as pinning:
                    summary = session.run()
                summary.cpus = pinning.status
                return summary
            return session.run()
        except LinkError as exc:
            raise LinkError(
                f"{exc}{handle.child_status()}; last good period {session.periods_done - 1}"
                + (f"; recording {recorder.path} closed with a fault marker" if recorder else "")
            ) from None
    finally:
        if recorder is not None and not recorder.closed:
            recorder.close("aborted")
        handle.close()


def check_overrides(words: Sequence[str]) -> tuple[str, ...]:
    """`--set KEY=VALUE` words, each checked for its shape (values are validated with the config)."""
    for word in words:
        if "=" not in word or "." not in word.split("=", 1)[0]:
            raise ConfigError(f"--set {word!r}: expected TABLE.KEY=VALUE, e.g. motor.rs_ohm=2.6 or target.kp=0.2")
    return tuple(words)


def run_step_tests(
    cfg: BenchConfig,
    test: "StepTest",
    gain_sets: Sequence[dict[str, float]],
    progress: Callable[[int, int], None] | None = None,
) -> list["StepResult"]:
    """One step test per gain set on the configured target (a fresh target and plant each)."""
    from hilbench.bench.steptest import run_step
    from hilbench.plant.model import Plant

    options = dataclasses.replace(
        settings.session_options(cfg), seed=effective_seed(cfg), duration_s=test.duration_s, history_every_periods=1_000_000
    )
    results = []
    sets = list(gain_sets) or [{}]
    for index, gains in enumerate(sets):
        handle = connect(cfg, options)
        try:
            def make(events, opts, recorder, handle=handle):  # type: ignore[no-untyped-def]
                plant = Plant(plant_params_from_config(cfg), seed=opts.seed, substeps=cfg.plant.substeps)
                return Session(handle.target, plant, events, opts, recorder=recorder, profile=configured_profile(cfg),
                               link_stats=handle.link_stats, target_label=handle.label)

            results.append(run_step(make, test, gains, options))
        finally:
            handle.close()
        if progress is not None:
            progress(index + 1, len(sets))
    return results

