"""The session's speed history: the newest samples of (t_s, ref_rpm, plant_rpm, measured_rpm).

One float64 array used as a ring, not a deque of tuples: a 1 s run at 50 us periods takes 1000
samples, and as tuples each was a fresh object the cycle collector had to walk once (a young
generation of ~1600 objects, about 0.3-0.7 ms at the end of nearly every other run: 3-7 % of a
1 s in-process run). The C span's samples arrive as arrays (`extend`), the Python loop's one at a
time (`append`); readers (the dashboard, `ctl step`) see a sequence of 4-tuples of floats, oldest
first, as they saw the deque.
"""
from __future__ import annotations

import math
from typing import Iterator

import numpy as np

Sample = tuple[float, float, float, float]


class SpeedHistory:
    """The newest ``maxlen`` speed samples, oldest first (a bounded sequence of `Sample`)."""

    def __init__(self, maxlen: int) -> None:
        if maxlen < 1:
            raise ValueError(f"SpeedHistory: maxlen must be >= 1, got {maxlen}")
        self.maxlen = maxlen
        self._ring = np.empty((maxlen, 4))
        self._taken = 0  # samples ever appended; the newest is at (_taken - 1) % maxlen

    def __len__(self) -> int:
        return min(self._taken, self.maxlen)

    def append(self, t_s: float, ref_rpm: float, plant_rpm: float, measured_rpm: float) -> None:
        self._ring[self._taken % self.maxlen] = (t_s, ref_rpm, plant_rpm, measured_rpm)
        self._taken += 1

    def extend(self, t_s: np.ndarray, ref_rpm: float, plant_rpm: np.ndarray, measured_rpm: np.ndarray) -> None:
        """Samples in order, as equal-length arrays (one reference for them all)."""
        n = len(t_s)
        if n > self.maxlen:  # only the newest fit
            skip = n - self.maxlen
            self._taken += skip
            t_s, plant_rpm, measured_rpm, n = t_s[skip:], plant_rpm[skip:], measured_rpm[skip:], self.maxlen
        at = self._taken % self.maxlen
        first = min(n, self.maxlen - at)  # up to the ring's end, the rest from its start
        for lo, hi, dest in ((0, first, at), (first, n, 0)):
            if hi > lo:
                rows = self._ring[dest:dest + hi - lo]
                rows[:, 0] = t_s[lo:hi]
                rows[:, 1] = ref_rpm
                rows[:, 2] = plant_rpm[lo:hi]
                rows[:, 3] = measured_rpm[lo:hi]
        self._taken += n

    def _ordered(self) -> np.ndarray:
        n = len(self)
        if self._taken <= self.maxlen:
            return self._ring[:n]
        at = self._taken % self.maxlen
        return np.concatenate((self._ring[at:], self._ring[:at]))

    @staticmethod
    def _samples(rows: np.ndarray) -> list[Sample]:
        """Rows as tuples of Python floats, a NaN as `math.nan` itself (so equal histories compare
        equal, as tuples holding the one NaN object did)."""
        values = rows.tolist()
        if np.isnan(rows).any():
            values = [[math.nan if v != v else v for v in row] for row in values]
        return [tuple(row) for row in values]  # type: ignore[misc]

    def __iter__(self) -> Iterator[Sample]:
        return iter(self._samples(self._ordered()))

    def __getitem__(self, index: int) -> Sample:
        n = len(self)
        if not -n <= index < n:
            raise IndexError("SpeedHistory index out of range")
        if index < 0:
            index += n
        return self._samples(self._ordered()[index:index + 1])[0]

    def __bool__(self) -> bool:
        return self._taken > 0

    def __repr__(self) -> str:
        return f"SpeedHistory({len(self)} of {self.maxlen} samples)"


__all__ = ["Sample", "SpeedHistory"]
