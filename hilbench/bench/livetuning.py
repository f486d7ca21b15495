"""Live tuning: checked writes of a target's declared parameters, and the guard that undoes bad ones.

A write is checked here first — declared, writable, finite, inside its range, and inside the
firmware's own constraints as its profile states them — then by the target, all at once. The
guard watches the motor for a window after a change of the profile's tunable parameters and
writes the previous values back when the firmware reports a fault (an overcurrent trip of the
board's comparator among them: it cuts the current before a phase current can pass the guard's own
limit), the speed error oscillates, a phase current passes its limit or the firmware stalls. New
gains are on probation until they have met one reference change: the first one after a change
watches a window again (gains are tried by stepping the reference, often seconds after the write).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from hilbench.errors import HilbenchError, ParamError
from hilbench.protocol import Fault, ParamInfo, ParamType, Result, State, param_scale
from hilbench.targets.base import Target
from hilbench.targets.profile import TargetProfile

STATE_STALLED = int(State.STALLED)
STATE_FAULT = int(State.FAULT)
FAULT_STALL = int(Fault.STALL)
FAULT_OVERCURRENT = int(Fault.OVERCURRENT)
RESULT_NAMES = {
    Result.OK: "ok", Result.UNKNOWN_ID: "unknown parameter", Result.READ_ONLY: "read-only",
    Result.OUT_OF_RANGE: "out of range", Result.CONSTRAINT: "constraint", Result.BAD_REQUEST: "bad request",
}


def raw_per_unit(ptype: int) -> float:
    """How many raw counts one unit of a parameter is (Q15: 32768; IQ24: 2^24; integers: 1); a type
    this host does not know counts as an integer."""
    try:
        return 1.0 / param_scale(ptype)
    except ValueError:
        return 1.0


@dataclass(frozen=True)
class GuardSettings:
    """Guarded tuning: after a gain change, watch a window and restore the old gains on trouble."""

    enabled: bool = True
    window_s: float = 1.0
    oscillation_rpm: float = 150.0  # a speed-error swing beyond ±this counts
    oscillation_swings: int = 4  # this many swings across ±oscillation_rpm trip the guard
    current_limit_a: float = 3.0  # phase current peak (the MCLV six-step trip level is 3 A)


class LiveTuning:
    """The parameters a target declared, and checked, guarded writes to them."""

    def __init__(self, target: Target, profile: TargetProfile, label: str, guard: GuardSettings) -> None:
        self.target = target
        self.profile = profile
        self.label = label
        self.guard = guard
        self.ids: dict[str, int] = {}
        self.info: dict[str, ParamInfo] = {}
        self.log: list[tuple[float, str]] = []
        self.trips: list[str] = []
        self.on_change: Callable[[float, str, dict[str, float]], None] | None = None
        self.watching = -math.inf  # until when the guard watches (−inf: not armed)
        self._guard_prev: dict[str, float] = {}
        self._guard_sign = 0
        self._guard_swings = 0
        self._probation = False  # the last guarded change has not met a reference change yet

    def declare(self, n_params: int) -> None:
        """Learn every declared parameter (after the HELLO)."""
        for param_id in range(n_params):
            info = self.target.describe(param_id)
            self.ids[info.name] = info.param_id
            self.info[info.name] = info

    def values(self) -> dict[str, float]:
        """Every declared parameter in its units (Q15 ones as fractions)."""
        return {name: self.target.get_param(pid).value / raw_per_unit(self.info[name].ptype)
                for name, pid in self.ids.items()}

    def encode(self, name: str, value: float) -> tuple[int, int]:
        """Host-side check of one parameter write; returns (id, raw) or raises ParamError."""
        if name not in self.ids:
            known = ", ".join(sorted(self.ids)) or "none"
            raise ParamError(f"{self.label}: unknown parameter {name!r} (declared: {known})")
        info = self.info[name]
        if info.access == 0:
            raise ParamError(f"{self.label}: parameter {name} is read-only")
        scale = raw_per_unit(info.ptype)
        lo, hi = info.min_value, info.max_value
        rng = f"{lo / scale:.5f}..{hi / scale:.5f}" if scale != 1.0 else f"{lo}..{hi}"
        scaled = value * scale if isinstance(value, (int, float)) else math.nan
        if not math.isfinite(scaled) or abs(scaled) > 2**40:
            raise ParamError(f"{self.label}: {name}={value!r} is out of range {rng}")
        raw = 32767 if (info.ptype == ParamType.Q15 and value == 1.0) else round(scaled)
        if not lo <= raw <= hi:
            raise ParamError(f"{self.label}: {name}={value:g} is out of range {rng}")
        return info.param_id, raw

    def set(self, values: dict[str, float], t_s: float, *, guard: bool = True) -> str:
        """Write a parameter set atomically; returns the event text. Raises ParamError if refused."""
        pairs = tuple(self.encode(name, value) for name, value in values.items())
        previous = self._check_constraints(values, pairs)
        result = self.target.set_params(pairs)
        if result.result != 0:
            name = next((n for n, i in self.ids.items() if i == result.param_id), str(result.param_id))
            reason = RESULT_NAMES.get(result.result, f"result {result.result}")
            detail = f" #{result.detail}" if result.result == Result.CONSTRAINT else ""
            raise ParamError(f"{self.label} refused {name}: {reason}{detail}")
        text = "set " + " ".join(f"{k}={v:g}" for k, v in values.items())
        self.log.append((t_s, text))
        if self.on_change is not None:
            self.on_change(t_s, text, dict(values))
        if guard and previous and self.guard.enabled:
            self.watching = t_s + self.guard.window_s
            self._guard_prev = previous
            self._guard_sign = 0
            self._guard_swings = 0
            self._probation = True
        return text

    def reference_changed(self, t_s: float) -> None:
        """A new speed reference: gains on probation are watched for a window from here."""
        if self._probation and self.guard.enabled and self._guard_prev:
            self._probation = False
            self.watching = max(self.watching, t_s + self.guard.window_s)
            self._guard_sign = 0
            self._guard_swings = 0

    def _check_constraints(self, values: dict[str, float], pairs: tuple[tuple[int, int], ...]) -> dict[str, float]:
        """The firmware's constraints on the tunable set after this write; returns their values before."""
        tunable = [name for name in self.profile.tunable if name in self.ids]
        if not any(name in tunable for name in values):
            return {}
        raw_now = {name: self.target.get_param(self.ids[name]).value for name in tunable}
        previous = {name: raw / raw_per_unit(self.info[name].ptype) for name, raw in raw_now.items()}
        raw_now.update({name: raw for name, (_, raw) in zip(values, pairs)})
        broken = self.profile.check_params(raw_now) if self.profile.check_params else None
        if broken is not None:
            text = " ".join(f"{k}={v:g}" for k, v in values.items())
            raise ParamError(f"{self.label}: gains {text} break the firmware's {broken}")
        return previous

    def guard_check(self, t_s: float, ref_rpm: float, speed_rpm: float, peak_a: float, state: int,
                    fault: int, tripped: bool = False) -> str | None:
        """One look at the motor inside the guard window (``tripped``: the board's overcurrent
        comparator is latched); on trouble restores and returns the note."""
        guard = self.guard
        reason = None
        if fault == FAULT_OVERCURRENT or tripped:
            reason = f"overcurrent: the firmware faulted (fault {_fault_name(fault)}, state {_state_name(state)})" \
                if fault else "overcurrent: the board's comparator tripped"
        elif fault and fault != FAULT_STALL or state == STATE_FAULT:
            reason = f"the firmware faulted (fault {_fault_name(fault)}, state {_state_name(state)})"
        elif peak_a > guard.current_limit_a:
            reason = f"phase current {peak_a:.2f} A > {guard.current_limit_a:g} A"
        elif state == STATE_STALLED or fault == FAULT_STALL:
            reason = "the firmware stalled"
        else:
            error = speed_rpm - ref_rpm
            sign = 1 if error > guard.oscillation_rpm else (-1 if error < -guard.oscillation_rpm else 0)
            if sign and sign != self._guard_sign:
                if self._guard_sign:
                    self._guard_swings += 1
                self._guard_sign = sign
            if self._guard_swings >= guard.oscillation_swings:
                reason = f"speed error oscillates beyond ±{guard.oscillation_rpm:g} rpm"
        if reason is None:
            return None
        self.watching = -math.inf
        self._probation = False
        restored = " ".join(f"{k}={v:g}" for k, v in self._guard_prev.items())
        try:
            self.set(self._guard_prev, t_s, guard=False)
            text = f"guard: {reason}; restored {restored}"
        except HilbenchError as exc:
            text = f"guard: {reason}; could not restore {restored}: {exc}"
        self.trips.append(text)
        return text


def _fault_name(code: int) -> str:
    try:
        return Fault(code).name
    except ValueError:
        return str(code)


def _state_name(code: int) -> str:
    try:
        return State(code).name
    except ValueError:
        return str(code)


__all__ = ["GuardSettings", "LiveTuning", "raw_per_unit"]
