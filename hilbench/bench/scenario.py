"""Scenarios: what happens to the bench at which time — reference, load, buttons, bus, faults.

A scenario is a sorted tuple of events. Each event acts at ``at_s``; a reference or bus change
with ``ramp_s > 0`` ramps linearly from the value in force to the new one. The session asks
``ScenarioPlayer.due(t_s, period_s)`` in the period that contains the next event's time
(`first_period_at`: integer period index, a documented tolerance for binary round-off).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable, Literal, Mapping

from hilbench.errors import ConfigError

FaultKind = Literal[
    "hall_a_high",
    "hall_a_low",
    "hall_b_high",
    "hall_b_low",
    "hall_c_high",
    "hall_c_low",
    "hall_missing_edge",
    "encoder_glitch",
    "clear",
]
FAULT_KINDS: tuple[str, ...] = FaultKind.__args__  # type: ignore[attr-defined]
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
    fault: str | None = None          # a FaultKind
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


_ACTION_KEYS = ("ref_rpm", "pot", "load_nm", "vbus_v", "press", "fault", "params", "end")
_ALLOWED_KEYS = set(_ACTION_KEYS) | {"at_s", "ramp_s", "load_kind", "fault_duration_s"}
LOAD_KINDS = ("constant", "linear", "quadratic", "locked")


def event_from_mapping(raw: Mapping[str, Any], where: str) -> tuple[Event | None, list[str]]:
    """Validate one ``[[scenario]]`` table; returns the event or the list of problems."""
    import difflib

    problems: list[str] = []
    for key in raw:
        if key not in _ALLOWED_KEYS:
            close = difflib.get_close_matches(key, sorted(_ALLOWED_KEYS), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            problems.append(f"{where} {key}: unknown key{hint}")
    actions = [key for key in _ACTION_KEYS if key in raw]
    if len(actions) != 1:
        problems.append(f"{where}: needs exactly one of {', '.join(_ACTION_KEYS)} (found {actions or 'none'})")
    at_s = raw.get("at_s")
    if not isinstance(at_s, (int, float)) or isinstance(at_s, bool) or at_s < 0:
        problems.append(f"{where} at_s: must be a number of seconds >= 0 (got {at_s!r})")
    for key in ("ref_rpm", "pot", "load_nm", "vbus_v", "ramp_s", "fault_duration_s"):
        if key in raw and (not isinstance(raw[key], (int, float)) or isinstance(raw[key], bool)):
            problems.append(f"{where} {key}: must be a number (got {raw[key]!r})")
    if isinstance(raw.get("pot"), (int, float)) and not 0.0 <= raw["pot"] <= 1.0:
        problems.append(f"{where} pot: must be within 0..1 (got {raw['pot']!r})")
    if isinstance(raw.get("vbus_v"), (int, float)) and not 0.0 <= raw["vbus_v"] <= 1000.0:
        problems.append(f"{where} vbus_v: must be within 0..1000 V (got {raw['vbus_v']!r})")
    if isinstance(raw.get("ramp_s"), (int, float)) and raw["ramp_s"] < 0:
        problems.append(f"{where} ramp_s: must be >= 0")
    if "press" in raw and raw["press"] not in BUTTONS:
        problems.append(f"{where} press: must be one of {', '.join(BUTTONS)} (got {raw['press']!r})")
    if "fault" in raw and raw["fault"] not in FAULT_KINDS:
        close = difflib.get_close_matches(str(raw["fault"]), FAULT_KINDS, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        problems.append(f"{where} fault: unknown fault {raw['fault']!r}{hint}; known: {', '.join(FAULT_KINDS)}")
    if "load_kind" in raw and raw["load_kind"] not in LOAD_KINDS:
        problems.append(f"{where} load_kind: must be one of {', '.join(LOAD_KINDS)}")
    params: tuple[tuple[str, float], ...] = ()
    if "params" in raw:
        if not isinstance(raw["params"], Mapping) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in raw["params"].values()
        ):
            problems.append(f"{where} params: must be a table of name = number")
        else:
            params = tuple((str(k), float(v)) for k, v in raw["params"].items())
    if "end" in raw and raw["end"] is not True:
        problems.append(f"{where} end: must be true")
    if problems:
        return None, problems
    fields = {k: v for k, v in raw.items() if k not in ("params",)}
    for key in ("ref_rpm", "pot", "load_nm", "vbus_v", "ramp_s", "fault_duration_s", "at_s"):
        if key in fields:
            fields[key] = float(fields[key])
    return Event(params=params, **fields), []


def scenario_from_list(raw_events: Iterable[Mapping[str, Any]], where: str) -> tuple[Event, ...]:
    """Validate a whole ``[[scenario]]`` list; raises one ConfigError with every problem."""
    events: list[Event] = []
    problems: list[str] = []
    for index, raw in enumerate(raw_events):
        event, errs = event_from_mapping(raw, f"{where} [[scenario]] #{index + 1}")
        problems.extend(errs)
        if event is not None:
            events.append(event)
    if problems:
        raise ConfigError("; ".join(problems))
    return tuple(sorted(events, key=lambda e: e.at_s))


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


#: a time within this fraction of a period of a period boundary is on the boundary (2.2 s is not
#: representable in binary: 2.2 / 50e-6 = 43999.99999999999; it belongs to period 44 000)
PERIOD_TOLERANCE = 1e-6


def first_period_at(t_s: float, period_s: float) -> float:
    """The period that contains time ``t_s``: period k covers [k * period_s, (k + 1) * period_s),
    so an event at t_s fires in period floor(t_s / period_s), a time within PERIOD_TOLERANCE of a
    period of a boundary counting as on it. inf beyond any run (t_s / period_s >= 2^50)."""
    if t_s == math.inf or not t_s / period_s < 2.0**50:
        return math.inf
    q = t_s / period_s
    k = math.floor(q)
    if q - k > 1.0 - PERIOD_TOLERANCE:  # just below a boundary by float round-off: on it
        k += 1
    return max(0, k)


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
        ``t_s`` or before (hilbench.bench.session.first_period_at: the period containing its time);
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
