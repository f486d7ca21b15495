"""One bench run from a config, and step tests: what `hilbench run` and `hilbench step` call.

They print nothing. Whatever happens — a fault, Ctrl-C, a bad parameter — the recording is closed
and any process the run started is reaped (the `Bench` owns them).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

from hilbench.bench import settings
from hilbench.bench.assembly import build_bench
from hilbench.bench.bench import Bench
from hilbench.bench.session import Session, Snapshot, Summary
from hilbench.bench.settings import load_config
from hilbench.config import BenchConfig, Override, clipped
from hilbench.errors import ConfigError, LinkError
from hilbench.targets.profile import TargetProfile

if TYPE_CHECKING:
    from hilbench.bench.control import ControlServer
    from hilbench.bench.steptest import StepResult, StepTest


@dataclass(frozen=True)
class RunRequest:
    """What the user asked for on top of the config file."""

    config_path: str | None = None
    overrides: tuple[str | Override, ...] = ()  # `--set` words, a gains file's values
    target: str | None = None
    mode: str | None = None
    duration_s: float | None = None
    record: str | None = None
    scenario: str | None = None  # a file of [[scenario]] tables replacing the config's


def load_run_config(request: RunRequest) -> BenchConfig:
    """The config with the command line's choices folded in as overrides (validated together)."""
    overrides: list[str | Override] = list(request.overrides)
    if request.target is not None:  # (a TOML string whatever the spec holds)
        overrides.append(Override(f"link.target={json.dumps(request.target)}", "--target"))
    if request.mode is not None:
        overrides.append(Override(f'run.mode="{request.mode}"', "--mode"))
    if request.duration_s is not None:
        overrides.append(Override(f"run.duration_s={request.duration_s!r}", "--duration"))
    return load_config(request.config_path, overrides, scenario_path=request.scenario)


def settings_profile(cfg: BenchConfig) -> TargetProfile:
    """The configured target's profile (the default target's for a port with no [link] firmware)."""
    return settings.configured_target_profile(cfg)


def in_process(cfg: BenchConfig) -> BenchConfig:
    """The same config on the configured target's in-process model (sweeps run there)."""
    profile = settings_profile(cfg)
    return cfg.replace(link=dataclasses.replace(cfg.link, target=f"inprocess:{profile.name}", firmware=None))


def run_bench(
    cfg: BenchConfig,
    *,
    record: str | Path | None = None,
    observer: Callable[[Snapshot], None] | None = None,
    control: "ControlServer | None" = None,
    on_ready: Callable[[Session], None] | None = None,
    warn: Callable[[str], None] | None = None,
) -> Summary:
    """Run the bench described by ``cfg`` with its scenario; raises HilbenchError kinds on faults.
    ``warn`` gets the warnings (impossible-looking settings, real time over a network) before the run."""
    from hilbench.bench.feasibility import check_run, hall_sector_s, overrun_warning

    warnings = check_run(cfg)  # impossible settings raise here, before anything is opened
    _say(warn, warnings)  # (now: opening the target may take long, a delay fault holding its handshake)
    bench = Bench(cfg, record=record, scenario=True, observer=observer, control=control, keep_rows=False)
    with bench:
        warnings += bench.warnings
        _say(warn, bench.warnings)
        session = bench.session
        assert session is not None
        if on_ready is not None:
            on_ready(session)
        try:
            bench.run()
        except LinkError as exc:
            raise LinkError(
                f"{exc}{bench.child_status()}; last good period {session.periods_done - 1}"
                + (f"; recording {record} closed with a fault marker" if record is not None else "")
            ) from None
        summary = bench.close()
        assert summary is not None
        if cfg.check:  # the config's pass/fail criteria, on what was recorded
            from hilbench.bench.checks import run_checks

            summary.checks = run_checks(cfg.check, summary, bench.signal_chunks)
    assert summary is not None
    held = overrun_warning(summary.periods, summary.overruns, stall_periods=summary.longest_stall_periods,
                           stall_at_s=summary.longest_stall_at_s, period_us=cfg.link.period_us,
                           sector_s=hall_sector_s(cfg))
    summary.warnings = warnings + summary.warnings + [w for w in [held] if w]  # (the run's own: a refused set)
    return summary


def _say(warn: Callable[[str], None] | None, warnings: Sequence[str]) -> None:
    for text in warnings:
        if warn is not None:
            warn(text)


def check_overrides(words: Sequence[str]) -> tuple[str, ...]:
    """`--set KEY=VALUE` words, each checked for its shape (values are validated with the config)."""
    for word in words:
        if word.split("=", 1)[0].strip() in ("scenario", "adc") and "=" in word:
            continue  # a whole array of tables: scenario=[{at_s = 0.0, ref_rpm = 1000.0}, ...]
        if "=" not in word or "." not in word.split("=", 1)[0]:
            raise ConfigError(f"--set {clipped(repr(word), 80)}: expected TABLE.KEY=VALUE, e.g. motor.rs_ohm=2.6 or "
                              "target.kp=0.2")
    return tuple(words)


def run_step_tests(
    cfg: BenchConfig,
    test: "StepTest",
    gain_sets: Sequence[dict[str, float]],
    progress: Callable[[int, int], None] | None = None,
) -> list["StepResult"]:
    """One step test per parameter set on the configured target (a fresh bench each)."""
    from hilbench.bench.steptest import run_step

    options = dataclasses.replace(settings.session_options(cfg), duration_s=test.duration_s,
                                  history_every_periods=1_000_000)
    results = []
    sets = list(gain_sets) or [{}]
    for index, gains in enumerate(sets):
        results.append(run_step(lambda events, recorder: build_bench(cfg, events=events, options=options,
                                                                    recorder=recorder), test, gains))
        if progress is not None:
            progress(index + 1, len(sets))
    return results
