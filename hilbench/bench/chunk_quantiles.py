"""Exact percentiles of a column read a chunk at a time: np.percentile's figures in bounded memory.

np.percentile (method "linear") sorts every value; here each value needed (the order statistics
either side of each percentile's index) is found by a radix selection over the float64 keys: four
passes over the column, each counting 16 more bits of the keys that share the bits found so far
(65 536 counters), so the memory is one chunk and the counters whatever the length. The
interpolation between the two order statistics is NumPy's own formula (index (n - 1) * q / 100,
lerp from the nearer end), so the figures are the very floats np.percentile gives
(tests/test_report_bounded.py compares them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Iterator, Sequence

import numpy as np

#: bits of the key counted per pass (4 passes for 64 bits)
RADIX_BITS = 16
_SIGN = np.uint64(1 << 63)

Values = Callable[[], Iterator[np.ndarray]]  # a new pass over the column's chunks, in any order


@dataclass(frozen=True)
class Spread:
    """How many values, the percentiles asked (NaN if any value is NaN, as np.percentile) and the maximum."""

    count: int
    percentiles: tuple[float, ...]
    max_value: float


def _keys(values: np.ndarray) -> np.ndarray:
    """Unsigned keys in the order of the floats (-0.0 as 0.0: they are equal to a sort)."""
    bits = (np.asarray(values, dtype=np.float64) + 0.0).view(np.uint64)
    return np.where(bits & _SIGN, ~bits, bits | _SIGN)


def _value(key: int) -> float:
    bits = np.uint64(key)
    bits = bits & ~_SIGN if bits & _SIGN else ~bits
    return float(np.array([bits], dtype=np.uint64).view(np.float64)[0])


def spread(values: Values, percents: Sequence[float]) -> Spread:
    """The percentiles ``percents`` (0..100) and the maximum of the column ``values`` gives."""
    count, nans, top = 0, 0, -math.inf
    for chunk in values():
        count += chunk.size
        nans += int(np.count_nonzero(np.isnan(chunk)))
        if chunk.size and not nans:
            top = max(top, float(np.max(chunk)))
    if not count:
        return Spread(0, tuple(math.nan for _ in percents), math.nan)
    if nans:
        return Spread(count, tuple(math.nan for _ in percents), math.nan)
    fractions = [np.float64(p) / 100 for p in percents]
    index = [(count - 1) * q for q in fractions]
    below = [int(math.floor(x)) for x in index]
    ranks = sorted({r for b in below for r in (b, min(b + 1, count - 1))})
    found = dict(zip(ranks, _select(values, ranks)))
    out = []
    for x, b in zip(index, below):
        a, c = np.float64(found[b]), np.float64(found[min(b + 1, count - 1)])
        gamma = np.float64(x - b)
        out.append(float(c - (c - a) * (1 - gamma) if gamma >= 0.5 else a + (c - a) * gamma))
    return Spread(count, tuple(out), top)


def _select(values: Values, ranks: Sequence[int]) -> list[float]:
    """The values at ``ranks`` (0: the smallest) of the sorted column, by radix selection."""
    prefix = [0] * len(ranks)  # the key bits found so far, per rank
    left = list(ranks)  # the rank among the keys that share the prefix
    for shift in range(64 - RADIX_BITS, -1, -RADIX_BITS):
        high = np.uint64(shift + RADIX_BITS)
        counts = [np.zeros(1 << RADIX_BITS, dtype=np.int64) for _ in ranks]
        for chunk in values():
            keys = _keys(chunk)
            digits = ((keys >> np.uint64(shift)) & np.uint64((1 << RADIX_BITS) - 1)).astype(np.intp)
            above = keys >> high if shift + RADIX_BITS < 64 else np.zeros_like(keys)
            for n, p in enumerate(prefix):
                same = above == np.uint64(p >> (shift + RADIX_BITS)) if shift + RADIX_BITS < 64 else slice(None)
                counts[n] += np.bincount(digits[same], minlength=1 << RADIX_BITS)
        for n in range(len(ranks)):
            cumulative = np.cumsum(counts[n])
            digit = int(np.searchsorted(cumulative, left[n], side="right"))
            left[n] -= int(cumulative[digit - 1]) if digit else 0
            prefix[n] |= digit << shift
    return [_value(p) for p in prefix]


__all__ = ["RADIX_BITS", "Spread", "spread"]
