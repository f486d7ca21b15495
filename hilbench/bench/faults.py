"""Injected sensor faults: a hall line stuck high or low, a missing hall edge, an encoder glitch.

The session asks `filter(hall, edges)` only while a fault is active, so a clean run pays nothing.
"""

from __future__ import annotations

import math

_HALL_BITS = {"a": 1, "b": 2, "c": 4}


class SensorFaults:
    """What the bench does to the sensor signals before they reach the target."""

    def __init__(self) -> None:
        self.force_high = 0
        self.force_low = 0
        self.missing_edge_armed = False
        self.encoder_offset = 0
        self.clear_at_s = math.inf
        self.last_hall = 0

    @property
    def active(self) -> bool:
        """Whether `filter` must see the halls this period."""
        return bool(self.force_high or self.force_low or self.missing_edge_armed)

    def apply(self, kind: str, t_s: float, duration_s: float | None) -> None:
        """Start fault ``kind`` (a scenario FaultKind; "clear" ends every fault) at ``t_s``."""
        self.force_high = self.force_low = 0
        self.missing_edge_armed = False
        self.clear_at_s = math.inf
        if kind.startswith("hall_") and kind[-4:] in ("high", "_low"):
            bit = _HALL_BITS[kind[5]]
            if kind.endswith("high"):
                self.force_high = bit
            else:
                self.force_low = bit
        elif kind == "hall_missing_edge":
            self.missing_edge_armed = True
        elif kind == "encoder_glitch":
            self.encoder_offset = (self.encoder_offset + 7) & 0xFFFF
        if duration_s:
            self.clear_at_s = t_s + duration_s

    def filter(self, hall: int, edges: tuple[tuple[int, int], ...]) -> tuple[int, tuple[tuple[int, int], ...]]:
        """The hall bits and input edges (Sensors.edges) the target gets this period: a missing edge
        keeps the halls it saw last and drops the period's edges; a forced line reads forced on
        every edge too (an edge stays, its time is what the other lines did)."""
        if self.missing_edge_armed and hall != self.last_hall:
            self.missing_edge_armed = False
            return self.last_hall, ()  # this edge never reaches the target
        self.last_hall = hall
        high, low = self.force_high, self.force_low
        if edges and (high or low):
            edges = tuple([(t, (lines | high) & ~low) for t, lines in edges])
        return (hall | high) & ~low & 0x7, edges


__all__ = ["SensorFaults"]
