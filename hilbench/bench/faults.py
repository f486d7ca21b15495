"""Injected sensor faults: each kind a class whose `filter(sensors)` changes what the target gets.

A fault sees the whole Sensors of a period (hall bits and every other input, every timed input
edge, the encoder count, the ADC codes) and returns the ones the target gets. The session calls
`SensorFaults.filter` only while a fault is in force, so a clean run pays nothing. A new fault
starts: the passing faults end (one at a time, as on a bench with one probe), lasting damage stays
(counts an encoder lost stay lost). Adding a kind is one class here with `@fault_kind` and its test:
the scenario's ``fault = "..."``, `Bench.inject_fault` and the config's check take the names from
`FAULT_KINDS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from hilbench.protocol import Sensors

HALL_MASK = 0x7  # Sensors.inputs bits 0..2: halls A, B, C
_new_sensors = tuple.__new__  # Sensors is a NamedTuple: its Python-level __new__ is slow


@dataclass(frozen=True)
class SensorSpec:
    """What a fault needs to know of the target's inputs (from its HELLO)."""

    adc_full_scale: int = 1023


class HallTrack:
    """The hall bits the faults last saw (only while a hall fault is in force: a missing edge is
    judged against them)."""

    def __init__(self, hall_bits: int = 0) -> None:
        self.last = hall_bits


class SensorFault:
    """One injected fault: the kinds it answers to, and its filter."""

    kinds: ClassVar[tuple[str, ...]] = ()
    lasting: ClassVar[bool] = False  # stays when another fault starts or faults are cleared
    spent = False  # a one-shot fault that has acted

    def __init__(self, kind: str, spec: SensorSpec, halls: HallTrack) -> None:
        self.kind = kind
        self.spec = spec
        self.halls = halls

    def filter(self, sensors: Sensors) -> Sensors:
        raise NotImplementedError


_KINDS: dict[str, type[SensorFault]] = {}


def fault_kind(cls: type[SensorFault]) -> type[SensorFault]:
    """Register a fault class under its kinds (a decorator)."""
    for kind in cls.kinds:
        _KINDS[kind] = cls
    return cls


@fault_kind
class HallForced(SensorFault):
    """A hall line stuck high or low (hall_a_high … hall_c_low)."""

    kinds = tuple(f"hall_{line}_{level}" for line in "abc" for level in ("high", "low"))

    def __init__(self, kind: str, spec: SensorSpec, halls: HallTrack) -> None:
        super().__init__(kind, spec, halls)
        bit = 1 << "abc".index(kind[5])
        self.high, self.low = (bit, 0) if kind.endswith("high") else (0, bit)

    def filter(self, sensors: Sensors) -> Sensors:
        inputs, edges = sensors[1], sensors[2]
        self.halls.last = inputs & HALL_MASK
        high, low = self.high, self.low
        if edges:  # the line reads forced on every edge too (an edge stays: the other lines moved)
            edges = tuple([(t, (lines | high) & ~low) for t, lines in edges])
        return _new_sensors(Sensors, (sensors[0], (inputs | high) & ~low, edges, *sensors[3:]))


@fault_kind
class HallMissingEdge(SensorFault):
    """The next hall edge never reaches the target: the halls it saw last and none of the period's
    edges, for one period (then the fault is spent)."""

    kinds = ("hall_missing_edge",)

    def filter(self, sensors: Sensors) -> Sensors:
        inputs = sensors[1]
        last = self.halls.last
        if inputs & HALL_MASK != last:
            self.spent = True
            return _new_sensors(Sensors, (sensors[0], inputs & ~HALL_MASK | last, (), *sensors[3:]))
        self.halls.last = inputs & HALL_MASK
        return sensors


@fault_kind
class EncoderGlitch(SensorFault):
    """The encoder loses 7 counts at once (noise on A/B); they stay lost."""

    kinds = ("encoder_glitch",)
    lasting = True
    LOST_COUNTS = 7

    def filter(self, sensors: Sensors) -> Sensors:
        return _new_sensors(Sensors, (*sensors[:3], (sensors[3] + self.LOST_COUNTS) & 0xFFFF, sensors[4]))


@fault_kind
class AdcOffset(SensorFault):
    """Every ADC channel reads 1/32 of its full scale high (a shifted reference), clamped to it."""

    kinds = ("adc_offset",)

    def filter(self, sensors: Sensors) -> Sensors:
        top = self.spec.adc_full_scale
        shift = (top + 1) // 32
        adc = tuple(code + shift if code + shift < top else top for code in sensors[4])
        return _new_sensors(Sensors, (*sensors[:4], adc))


class SensorFaults:
    """The faults in force and when the passing ones end."""

    def __init__(self, spec: SensorSpec = SensorSpec()) -> None:
        self.spec = spec
        self.halls = HallTrack()
        self.active: list[SensorFault] = []
        self._sent_halls = 0  # the halls of the last Sensors a fault filtered
        self.clear_at_s = math.inf

    @property
    def on(self) -> bool:
        """Whether `filter` must see this period's Sensors."""
        return bool(self.active)

    def apply(self, kind: str, t_s: float, duration_s: float | None, hall_bits: int | None = None) -> None:
        """Start fault ``kind`` (one of FAULT_KINDS; "clear" ends every passing fault) at ``t_s``,
        for ``duration_s`` (None: until the next). ``hall_bits``: the plant's halls of the last Sensors
        (a missing edge is the next change from what the target got, not from the halls of the run's
        start; while a fault was in force, the halls it left)."""
        if hall_bits is not None:  # what the target got: a fault in force filtered the last Sensors
            self.halls.last = self._sent_halls if self.active else hall_bits
        self.active = [fault for fault in self.active if fault.lasting]
        self.clear_at_s = math.inf
        if kind != "clear":
            self.active.append(_KINDS[kind](kind, self.spec, self.halls))
        if duration_s:
            self.clear_at_s = t_s + duration_s

    def filter(self, sensors: Sensors) -> Sensors:
        """The Sensors the target gets this period."""
        for fault in self.active:
            sensors = fault.filter(sensors)
        self._sent_halls = sensors[1] & HALL_MASK
        if any(fault.spent for fault in self.active):
            self.active = [fault for fault in self.active if not fault.spent]
        return sensors


#: every fault kind a scenario or script may inject, and "clear"
FAULT_KINDS: tuple[str, ...] = (*_KINDS, "clear")

__all__ = ["FAULT_KINDS", "SensorFault", "SensorFaults", "SensorSpec", "fault_kind"]
