"""Speed-step tests: one definition used by `hilbench step`, the control socket, sweeps and the API.

A step test starts the motor with the reference at ``from_rpm``, holds ``settle_s`` so the loop
settles, steps the reference to ``to_rpm`` and keeps ``after_s`` seconds. The metrics are computed
on the plant's speed from the step on, against the reference the firmware actually gets (the
profile's `effective_rpm`: a pot quantises it), so a perfect loop scores zero steady-state error.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from hilbench.bench.metrics import StepMetrics, step_metrics
from hilbench.bench.recorder import MemoryRecorder
from hilbench.bench.scenario import Event
from hilbench.config import clipped
from hilbench.errors import ConfigError
from hilbench.limits import is_finite_number, shown
from hilbench.protocol import State
from hilbench.targets.profile import TargetProfile

if TYPE_CHECKING:
    from hilbench.bench.assembly import BenchParts

STATE_STALLED = int(State.STALLED)


def step_scenario(
    from_rpm: float, to_rpm: float, step_at_s: float, duration_s: float, press_at_s: float = 0.0
) -> tuple[Event, ...]:
    """The step test as session events: reference, start button, step, end."""
    if not 0.0 <= press_at_s < step_at_s < duration_s:
        raise ConfigError(
            f"step test: need 0 <= press_at_s < step_at_s < duration_s (got {press_at_s}, {step_at_s}, {duration_s})"
        )
    return (
        Event(at_s=0.0, ref_rpm=float(from_rpm)),
        Event(at_s=press_at_s, press="s2"),
        Event(at_s=step_at_s, ref_rpm=float(to_rpm)),
        Event(at_s=duration_s, end=True),
    )


@dataclass(frozen=True)
class StepTest:
    """The shape of a step test (rpm and seconds)."""

    from_rpm: float
    to_rpm: float
    settle_s: float = 1.0
    after_s: float = 1.0

    def __post_init__(self) -> None:
        for name in ("from_rpm", "to_rpm", "settle_s", "after_s"):
            value = getattr(self, name)
            if not is_finite_number(value) or abs(value) > 1e7:
                raise ConfigError(f"step: {name}={shown(value)}: expected a finite number (|x| <= 1e7)")
        if self.from_rpm == self.to_rpm:
            raise ConfigError(f"step: --from and --to are both {self.from_rpm:g} rpm; a step needs two speeds")
        if not (self.settle_s > 0.02 and self.after_s > 0):
            raise ConfigError("step: settle and after times must be positive (settle > 20 ms)")

    @property
    def duration_s(self) -> float:
        return self.settle_s + self.after_s

    def events(self) -> tuple[Event, ...]:
        """Reference at from_rpm, S2, step at settle_s, end. From standstill, S2 comes with the step."""
        if self.from_rpm == 0:
            return (
                Event(at_s=0.0, ref_rpm=0.0),
                Event(at_s=self.settle_s, ref_rpm=self.to_rpm),
                Event(at_s=self.settle_s, press="s2"),
                Event(at_s=self.duration_s, end=True),
            )
        return step_scenario(self.from_rpm, self.to_rpm, self.settle_s, self.duration_s)

    def quantised_rpm(self, profile: TargetProfile, rpm: float) -> float:
        """The reference the firmware gets for ``rpm``."""
        return profile.reference.effective_rpm(rpm) if profile.reference is not None else rpm


@dataclass
class StepResult:
    """One parameter set's step response and its figures."""

    label: str
    gains: dict[str, float]
    metrics: StepMetrics
    t_s: np.ndarray = field(repr=False)  # from the step, s
    speed_rpm: np.ndarray = field(repr=False)
    ref_rpm: float = 0.0
    stalled: bool = False  # the firmware stopped on its stall protection (metrics not meaningful)
    #: the reference the firmware itself reports after the step (its telemetry; a firmware may ramp
    #: it after an alignment), None when it reports none
    firmware_ref_rpm: np.ndarray | None = field(default=None, repr=False)


def require_speed_loop(profile: TargetProfile, where: str) -> None:
    """A step test needs a target with a speed loop and a reference input."""
    if not profile.has("speed_loop") or profile.reference is None:
        raise ConfigError(f"{where}: target {profile.name!r} has no speed loop to step "
                          "(its profile declares no speed_loop capability or reference input)")


#: the columns `analyse` reads (a sweep converts only these of every step test's rows), and the
#: firmware's reported reference when the layout has it (the step plot's reference)
ANALYSED_COLUMNS = ("t_s", "speed_rpm", "ia_a", "ib_a", "state")
FIRMWARE_REF_COLUMN = "ref_speed_rpm"


def analyse(columns: dict[str, np.ndarray], test: StepTest, profile: TargetProfile, label: str,
            gains: dict[str, float], period_s: float) -> StepResult:
    """Metrics of a recorded step test.

    A row's plant values are those at the end of its period, so they are placed at t_s + period;
    the step happens at the start of the first period whose t_s reaches ``settle_s``.
    """
    t_start = columns["t_s"]
    t = t_start + period_s
    speed = columns["speed_rpm"]
    y0 = test.quantised_rpm(profile, test.from_rpm)
    y_ref = test.quantised_rpm(profile, test.to_rpm)
    stepped = np.flatnonzero(t_start >= test.settle_s)
    t_step = float(t_start[stepped[0]]) if stepped.size else test.settle_s
    i_alpha = columns["ia_a"]
    i_beta = (columns["ia_a"] + 2.0 * columns["ib_a"]) / np.sqrt(3.0)
    currents = np.hypot(i_alpha, i_beta)  # the phase-current amplitude |i_dq|
    metrics = step_metrics(t, speed, y0=y0, y_final_ref=y_ref, current_a=currents, t_step_s=t_step)
    after = t >= t_step
    stalled = bool(columns["state"].size and columns["state"][-1] == STATE_STALLED)
    reported = columns.get("ref_speed_rpm")
    firmware_ref = reported[after] if reported is not None and np.isfinite(reported[after]).all() else None
    return StepResult(label, gains, metrics, t[after] - t_step, speed[after], y_ref, stalled, firmware_ref)


def run_step(
    build: Callable[[tuple[Event, ...], MemoryRecorder], "BenchParts"],
    test: StepTest,
    gains: dict[str, float],
    label: str | None = None,
) -> StepResult:
    """Run one step test on a bench ``build`` assembles (`assembly.build_bench`) and analyse it."""
    recorder = MemoryRecorder()
    parts = build(test.events(), recorder)
    try:
        session = parts.session
        session.handshake()
        require_speed_loop(session.profile, "step")
        if gains:
            session.set_params(gains, 0.0, guard=False)
        session.run()
    finally:
        parts.close()
    name = label or ("/".join(f"{v:.4g}" for v in gains.values()) or "firmware defaults")
    names = ANALYSED_COLUMNS + ((FIRMWARE_REF_COLUMN,) if FIRMWARE_REF_COLUMN in recorder.rows.layout.column_names else ())
    return analyse(recorder.columns(names), test, session.profile, name, gains, session.period.s)


def parse_gain_sets(words: Sequence[str], names: Sequence[str]) -> list[dict[str, float]]:
    """`--gains 0.1,0.01,0` → [{"kp": 0.1, "ki": 0.01, "kd": 0.0}] for names (kp, ki, kd); fewer
    values leave the rest. `--gains kp=0.1,ki=0.01` names them."""
    sets: list[dict[str, float]] = []
    for word in words:
        parts = [p.strip() for p in word.split(",")]
        try:
            if all("=" in p for p in parts):
                pairs = [(k.strip(), float(v)) for k, v in (p.split("=", 1) for p in parts)]
                named: dict[str, float] = {}
                for name, value in pairs:
                    if name in named:  # (kp=0.1,kp=0.2: which one was meant?)
                        raise ConfigError(f"--gains {clipped(repr(word), 60)}: {name[:40]} given twice")
                    named[name] = value
                sets.append(named)
                continue
            values = [float(p) for p in parts]
        except ValueError:
            raise ConfigError(f"--gains {clipped(repr(word), 60)}: not numbers (e.g. 0.1,0.01,0 or kp=0.1,ki=0.01)") from None
        if not 1 <= len(values) <= len(names):
            raise ConfigError(f"--gains {clipped(repr(word), 60)}: expected up to {len(names)} comma-separated values ({','.join(names)})")
        sets.append(dict(zip(names, values)))
    return sets


def result_row(result: StepResult) -> dict[str, Any]:
    """A flat row for tables and CSV."""
    m = result.metrics
    return {"label": result.label, **result.gains, **{k: v for k, v in m.as_dict().items()}}
