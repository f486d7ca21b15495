"""The session's speed history: the newest samples of (t_s, ref_rpm, plant_rpm, measured_rpm).

One float64 array used as a ring, not a deque of tuples: a 1 s run at 50 us periods takes 1000
samples, and as tuples each was a fresh object the cycle collector had to walk once (a young
generation of ~1600 objects, about 0.3-0.7 ms at the end of nearly every other run: 3-7 % of a
1 s in-process run). The C span's samples arrive as arrays (`extend`), the Python loop's one at a
time (`append`); readers see a sequence of 4-tuples of floats, oldest first, as they saw the deque,
and a live view reads one column (`column`) without making a tuple per sample.

It is written and read on the session's thread (the observer, the dashboard's frame, `ctl step`);
an observer that hands it to a thread of its own passes a copy (`copy.copy`), or reads a ring that
may change under it.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Iterator, overload

import numpy as np
import numpy.typing as npt

Sample = tuple[float, float, float, float]
#: the columns, in a sample's order
COLUMNS = ("t_s", "ref_rpm", "plant_rpm", "measured_rpm")
_MEASURED = COLUMNS.index("measured_rpm")


class SpeedHistory(Sequence[Sample]):
    """The newest ``maxlen`` speed samples, oldest first."""

    def __init__(self, maxlen: int) -> None:
        if maxlen < 1:
            raise ValueError(f"SpeedHistory: maxlen must be >= 1, got {maxlen}")
        self.maxlen = maxlen
        self._ring = np.empty((maxlen, len(COLUMNS)))
        self._taken = 0  # samples ever appended; the newest is at (_taken - 1) % maxlen

    def __len__(self) -> int:
        return min(self._taken, self.maxlen)

    def append(self, t_s: float, ref_rpm: float, plant_rpm: float, measured_rpm: float) -> None:
        self._ring[self._taken % self.maxlen] = (t_s, ref_rpm, plant_rpm, measured_rpm)
        self._taken += 1

    def extend(self, t_s: npt.NDArray[np.float64], ref_rpm: float, plant_rpm: npt.NDArray[np.float64],
               measured_rpm: npt.NDArray[np.float64]) -> None:
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

    def _ordered(self) -> npt.NDArray[np.float64]:
        n = len(self)
        if self._taken <= self.maxlen:
            return self._ring[:n]
        at = self._taken % self.maxlen
        return np.concatenate((self._ring[at:], self._ring[:at]))

    def column(self, name: str) -> list[float]:
        """One column (`COLUMNS`), oldest first: what a live view plots."""
        return self._ordered()[:, COLUMNS.index(name)].tolist()

    @staticmethod
    def _samples(rows: npt.NDArray[np.float64]) -> list[Sample]:
        """Rows as tuples of Python floats, a missing measurement as `math.nan` itself (so equal
        histories compare equal, as tuples holding the one NaN object did)."""
        if not np.isnan(rows[:, _MEASURED]).any():
            return list(map(tuple, rows.tolist()))
        return [(t, ref, plant, math.nan if meas != meas else meas) for t, ref, plant, meas in rows.tolist()]

    def __iter__(self) -> Iterator[Sample]:
        return iter(self._samples(self._ordered()))

    @overload
    def __getitem__(self, index: int) -> Sample: ...

    @overload
    def __getitem__(self, index: slice) -> list[Sample]: ...

    def __getitem__(self, index: int | slice) -> Sample | list[Sample]:
        if isinstance(index, slice):
            return self._samples(self._ordered()[index])
        n = len(self)
        if not -n <= index < n:
            raise IndexError("SpeedHistory index out of range")
        slot = (self._taken - n + index % n) % self.maxlen
        return self._samples(self._ring[slot:slot + 1])[0]

    def __bool__(self) -> bool:
        return self._taken > 0

    def __copy__(self) -> SpeedHistory:
        """An independent ring (a deque's copy was)."""
        twin = SpeedHistory(self.maxlen)
        twin._ring[:] = self._ring
        twin._taken = self._taken
        return twin

    def __repr__(self) -> str:
        return f"SpeedHistory({len(self)} of {self.maxlen} samples)"


__all__ = ["COLUMNS", "Sample", "SpeedHistory"]
