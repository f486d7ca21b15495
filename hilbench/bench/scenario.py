"""Scenarios: what happens to the bench at which time — reference, load, buttons, bus, faults.

A scenario is a sorted tuple of events. Each event acts at ``at_s``; a reference or bus change
with ``ramp_s > 0`` ramps linearly from the value in force to the new one. The session asks
``ScenarioPlayer.due(t_s, period_s)`` in the period that contains the next event's time
(`plant.period.first_period_at`: integer period index, a documented tolerance for binary
round-off). The `[[scenario]]` tables are validated with the whole config (`settings.ScenarioEntry`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

from hilbench.bench.faults import FAULT_KINDS
from hilbench.plant.period import PERIOD_TOLERANCE, first_period_at

BUTTONS = ("s2", "s3")


@dataclass(frozen=True)
class Event:
    """One scenario action. Exactly one of the action fields is set."""

    at_s: float
    ref_rpm: float | None = None      # speed reference, through the pot (or override)
    pot: float | None = None          # pot position 0..1, raw
    ramp_s: float = 0.0               # ramp duration for ref_rpm / pot / vbus_v
    load_nm: float | None = None      # constant load torque from here on
    load_kind: str = "constant"       # constant N*m | linear N*m per rad/s | quadratic N*m per (rad/s)^2 | locked
    vbus_v: float | None = None
    press: str | None = None          # "s2" (start/stop) or "s3"
    fault: str | None = None          # one of faults.FAULT_KINDS
    fault_duration_s: float | None = None
    params: tuple[tuple[str, float], ...] = ()  # live parameter writes, e.g. (("kp", 0.2),)
    end: bool = False                 # end the run here

    def describe(self) -> str:
        """A short human line, used as the recording's event note."""
        if self.ref_rpm is not None:
            return f"ref {self.ref_rpm:g} rpm" + (f" ramp {self.ramp_s:g} s" if self.ramp_s else "")
        if self.pot is not None:
            return f"pot {self.pot:g}" + (f" ramp {self.ramp_s:g} s" if self.ramp_s else "")
        if self.load_nm is not None:
            return f"load {self.load_kind} {self.load_nm:g}"
        if self.vbus_v is not None:
            return f"vbus {self.vbus_v:g} V"
        if self.press is not None:
            return f"press {self.press}"
        if self.fault is not None:
            return f"fault {self.fault}" + (f" for {self.fault_duration_s:g} s" if self.fault_duration_s else "")
        if self.params:
            return "set " + " ".join(f"{k}={v:g}" for k, v in self.params)
        return "end"


LOAD_KINDS = ("constant", "linear", "quadratic", "locked")


def default_scenario() -> tuple[Event, ...]:
    """The default bench: pot ramp to 1500 rpm with S2, step to 2500, reverse to -1500, stop.

    The pot starts turning before S2 so that the firmware sees a non-zero reference at start:
    with the reference at zero the default firmware applies no voltage and its stall timer stops it
    again.

    Each reference is held about 1 s, longer than the 0.6-0.7 s the default firmware's gains need
    to settle; the reversal gets more because it brakes through zero first.
    """
    return (
        Event(at_s=0.0, ref_rpm=1500.0, ramp_s=0.3),
        Event(at_s=0.03, press="s2"),
        Event(at_s=1.2, ref_rpm=2500.0),
        Event(at_s=2.2, ref_rpm=-1500.0),
        Event(at_s=3.6, press="s2"),
        Event(at_s=3.8, end=True),
    )


@dataclass
class Ramp:
    """A linear change from v0 at t0 to v1 at t1 (reference or bus voltage)."""

    t0: float
    t1: float
    v0: float
    v1: float

    def value(self, t_s: float) -> float:
        if t_s >= self.t1:
            return self.v1
        return self.v0 + (self.v1 - self.v0) * (t_s - self.t0) / (self.t1 - self.t0)


class ScenarioPlayer:
    """Walks a scenario in time; the session applies what it yields."""

    def __init__(self, events: Iterable[Event]) -> None:
        self.events: tuple[Event, ...] = tuple(sorted(events, key=lambda e: e.at_s))
        self._index = 0
        self.next_t_s = self.events[0].at_s if self.events else float("inf")
        self.ramps: dict[str, Ramp] = {}

    def due(self, t_s: float, period_s: float | None = None) -> list[Event]:
        """Events whose time has come: with ``period_s``, every event in the period that starts at
        ``t_s`` or before (`first_period_at`: the period containing its time);
        without, every event at or before ``t_s``."""
        out: list[Event] = []
        events = self.events
        if period_s is not None:
            k = round(t_s / period_s)
            while self._index < len(events) and first_period_at(events[self._index].at_s, period_s) <= k:
                out.append(events[self._index])
                self._index += 1
            self.next_t_s = events[self._index].at_s if self._index < len(events) else float("inf")
            return out
        while self._index < len(events) and events[self._index].at_s <= t_s + 1e-12:
            out.append(events[self._index])
            self._index += 1
        self.next_t_s = events[self._index].at_s if self._index < len(events) else float("inf")
        return out

    @property
    def end_s(self) -> float | None:
        """Time of the first ``end`` event, if any."""
        for event in self.events:
            if event.end:
                return event.at_s
        return None

    def reference_at(self, t_s: float) -> float | None:
        """The speed reference in force at ``t_s`` (for step analysis), or None before any."""
        value: float | None = None
        for event in self.events:
            if event.at_s > t_s:
                break
            if event.ref_rpm is not None:
                value = event.ref_rpm
        return value


__all__ = ["BUTTONS", "Event", "FAULT_KINDS", "LOAD_KINDS", "PERIOD_TOLERANCE", "Ramp", "ScenarioPlayer",
           "default_scenario", "first_period_at"]
