"""One pass over a recording's chunks for the [[check]] tables: the same figures as over whole arrays.

Each scan takes a recording's rows a chunk at a time (hilbench.bench.column_chunks) and keeps only
what its figure needs: the largest value so far and its time, the first fault and a count, where a
segment last left its band. No sum is formed, so nothing depends on where the chunks are cut: every
figure is the very float the whole-array evaluation gave (np.argmax's first maximum, a NaN winning
as it does there; tests/test_checks_bounded.py compares them on one recording cut many ways).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from hilbench.bench.summary import Segment


class WindowScan:
    """The rows of each chunk within [from_s, to_s], and the window as the figures print it."""

    def __init__(self, from_s: float, to_s: float | None) -> None:
        self.from_s = from_s
        self.end_s = to_s if to_s is not None else math.inf
        self.last_s = 0.0  # the recording's last time (0 without rows)

    def mask(self, t: np.ndarray) -> np.ndarray:
        """The window's rows of one chunk (chunks come in row order)."""
        if t.size:
            self.last_s = float(t[-1])
        return (t >= self.from_s) & (t <= self.end_s)

    @property
    def text(self) -> str:
        return f"{self.from_s:.3f}-{min(self.end_s, self.last_s):.3f} s"


class RunningPeak:
    """The first row of the largest ``key`` over every chunk offered (np.argmax over them all: a NaN
    key is larger than any number, the first NaN wins), with its value and time."""

    def __init__(self) -> None:
        self.found = False
        self.key = 0.0
        self.value = 0.0
        self.t_s = 0.0

    def offer(self, key: np.ndarray, value: np.ndarray, t: np.ndarray) -> None:
        if key.size == 0:
            return
        i = int(np.argmax(key))
        candidate = float(key[i])
        if not self.found or (not math.isnan(self.key) and (math.isnan(candidate) or candidate > self.key)):
            self.found, self.key, self.value, self.t_s = True, candidate, float(value[i]), float(t[i])


class FirstNonzero:
    """The first row whose code is not 0, its code and time, and how many such rows."""

    def __init__(self) -> None:
        self.count = 0
        self.code = 0.0
        self.t_s = 0.0

    def offer(self, codes: np.ndarray, t: np.ndarray) -> None:
        bad = np.flatnonzero(codes != 0)
        if bad.size and not self.count:
            self.code, self.t_s = float(codes[bad[0]]), float(t[bad[0]])
        self.count += int(bad.size)


class SettleScan:
    """From a segment's start until the speed stays within ``band`` (a fraction) of its reference to
    the segment's end: where the speed last left the band, chunk by chunk."""

    def __init__(self, segment: "Segment", band: float) -> None:
        self.segment = segment
        self.band = band
        self.left = False  # the speed was outside the band at some row of the segment
        self.pending = False  # ... at the segment's latest row so far
        self.back_s = 0.0  # the time of the row after the last one outside

    def offer(self, t: np.ndarray, speed_rpm: np.ndarray) -> None:
        seg = self.segment
        mask = (t >= seg.t_start_s) & (t < seg.t_end_s)
        tt, yy = t[mask], speed_rpm[mask]
        if tt.size == 0:
            return
        outside = np.flatnonzero(np.abs(yy - seg.ref_rpm) > self.band * abs(seg.ref_rpm))
        if outside.size:
            self.left = True
            self.pending = bool(outside[-1] == yy.size - 1)
            if not self.pending:
                self.back_s = tt[outside[-1] + 1]
        elif self.pending:
            self.pending, self.back_s = False, tt[0]

    @property
    def settle_s(self) -> float:
        """0 when never outside; inf when outside at the segment's end."""
        if not self.left:
            return 0.0
        if self.pending:
            return math.inf
        return float(self.back_s - self.segment.t_start_s)


__all__ = ["FirstNonzero", "RunningPeak", "SettleScan", "WindowScan"]
