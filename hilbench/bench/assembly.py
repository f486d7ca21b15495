"""The one place a bench is put together: a target, a plant and a session from a config.

`build_bench` connects the configured target (spawning its emulator or firmware build when the
spec asks) or takes a `Target` object, builds the plant from the config (or takes a `Plant`
object), and makes the session with the config's options, guard and profile. `Bench.open`, the
run command, step tests and sweeps all come through here, so a bench is the same bench whoever
opens it. One seed rule: `settings.effective_seed` ([run] seed, else [plant] seed) seeds the plant.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable

from hilbench.bench import settings
from hilbench.bench.launcher import TargetHandle, open_target
from hilbench.bench.recorder import MemoryRecorder, Recorder
from hilbench.bench.scenario import Event
from hilbench.bench.session import ControlSource, PlantLike, Session, SessionOptions, Snapshot
from hilbench.config import BenchConfig, plant_from_config
from hilbench.targets.base import Target
from hilbench.targets.profile import TargetProfile
from hilbench.targets.registry import profile_for_firmware


@dataclass
class BenchParts:
    """What one bench is made of; `close` releases the target (its link, its process)."""

    handle: TargetHandle
    plant: PlantLike
    session: Session
    profile: TargetProfile | None
    options: SessionOptions

    def close(self) -> None:
        self.handle.close()


def build_plant(cfg: BenchConfig, profile: TargetProfile | None = None) -> PlantLike:
    """The config's plant, seeded by the run's seed, with the PWM timing of ``profile``'s target
    (where its PWM centres its pulses and when its ADC samples; None: the default)."""
    return plant_from_config(cfg, seed=settings.effective_seed(cfg), pwm=profile.pwm_timing if profile else None)


def configured_profile(cfg: BenchConfig) -> TargetProfile | None:
    """The profile the config names (by its target spec, or [link] firmware for a port), else None:
    a board's profile is then found by the firmware name in its HELLO. Refuses a plant whose pole
    pairs differ from the firmware's build (settings.check_motor_build)."""
    if settings.target_name(cfg.link.target) is None and cfg.link.firmware is None:
        return None
    profile = settings.configured_target_profile(cfg)
    settings.check_motor_build(cfg, profile)
    return profile


def connect(cfg: BenchConfig, options: SessionOptions, profile: TargetProfile | None) -> TargetHandle:
    """Open the configured target (spawning its emulator or firmware build if the spec asks)."""
    return open_target(cfg.link.target, profile=profile, options=cfg.target, mode=options.mode,
                       timeout_s=options.timeout_s, watchdog_ms=options.watchdog_ms, retry_s=cfg.link.retry_ms / 1000.0)


def build_bench(
    cfg: BenchConfig,
    *,
    target: Target | None = None,
    plant: PlantLike | None = None,
    events: Iterable[Event] = (),
    options: SessionOptions | None = None,
    recorder: Recorder | MemoryRecorder | None = None,
    observer: Callable[[Snapshot], None] | None = None,
    control: ControlSource | None = None,
) -> BenchParts:
    """A target (``target``, or the one ``cfg`` names), a plant (``plant``, or the config's) and a
    session over them with ``options`` (default: the config's). The caller handshakes and runs;
    `BenchParts.close` releases what was opened, whatever happened. The config's plant takes its
    PWM timing from the target's profile, a ``target`` object's found by its firmware name (as the
    handshake finds it): a Target object and its spec run the same physics."""
    options = options or settings.session_options(cfg)
    profile = configured_profile(cfg) if target is None else None
    handle = connect(cfg, options, profile) if target is None else given_target(target)
    try:
        if target is None:
            handle.target = with_twin(handle.target, cfg, options, profile)
        if plant is None:
            plant = build_plant(cfg, profile if target is None else profile_for_firmware(target.firmware_name))
        session = Session(handle.target, plant, events, options, profile=profile, recorder=recorder,  # type: ignore[arg-type]
                          observer=observer, control=control, link_stats=handle.link_stats,
                          target_label=handle.label, guard=settings.guard_settings(cfg))
        _note_unconfirmed_rows(handle.target, session)
    except BaseException:
        handle.close()
        raise
    return BenchParts(handle, plant, session, profile, options)


def _note_unconfirmed_rows(target: Target, session: Session) -> None:
    """A twin-speculative run that goes on after a divergence notes, in the recording, which rows are
    the twin's without the target's confirmation (hilbench.bench.speculative)."""
    from hilbench.bench.speculative import SpeculativeTarget

    if isinstance(target, SpeculativeTarget) and target.keep_going:
        def note(first: int, resume: int) -> None:
            session.note(session.now_s, f"twin-speculative divergence: periods {first}..{resume - 1} are the twin's "
                                        f"rows, not confirmed by the target (its Drives differ among them); "
                                        f"the target's own from period {resume}")

        target.on_unconfirmed = note


def with_twin(target: Target, cfg: BenchConfig, options: SessionOptions, profile: TargetProfile | None) -> Target:
    """``target`` with its host twin ([link] twin = "auto", lockstep, a target on a link whose profile
    offers a bit-exact twin: hilbench.bench.speculative), else ``target`` itself."""
    from hilbench.bench.speculative import SpeculativeTarget
    from hilbench.targets.remote import RemoteTarget

    from hilbench.link import parse_target_spec

    spec = parse_target_spec(cfg.link.target)
    wanted = spec.twin or cfg.link.twin  # the spec's key over the config's
    if wanted != "auto" or options.mode != "lockstep" or profile is None or profile.twin is None \
            or not isinstance(target, RemoteTarget):
        return target
    make_twin = profile.twin

    def reopen() -> tuple[Target, Callable[[], None]]:
        handle = connect(cfg, options, profile)  # a fresh target: the replay that locates a divergence
        return handle.target, handle.close

    # only a far end the host starts itself comes back from a reset: a board on a port (or behind a
    # URL) is the same board in the same state when opened again, and its port is held by this run
    return SpeculativeTarget(target, make_twin(cfg.target), reopen=reopen if spec.spawns_process else None,
                             make_twin=lambda: make_twin(cfg.target),
                             period_us=options.period_us, keep_going=cfg.link.on_divergence == "continue")


def given_target(target: Target) -> TargetHandle:
    """A Target object the caller made (an in-process model, a proxy over its own link) as a
    handle; the caller keeps it, so closing the bench does not close it."""
    return TargetHandle(target, label=f"{type(target).__name__} ({target.firmware_name})")


__all__ = ["BenchParts", "build_bench", "build_plant", "configured_profile", "connect", "given_target", "with_twin"]
