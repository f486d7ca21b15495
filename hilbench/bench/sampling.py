"""Where a sweep puts its points: a grid, seeded random or Latin-hypercube samples, and a refinement
that zooms around the best point so far (a best point at a grid's edge is followed out of it, within
the parameters' own ranges).

All seeded: the same ranges, counts and seed give the same points on any machine.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from hilbench.errors import ConfigError

Point = tuple[tuple[str, float], ...]


@dataclass(frozen=True)
class Axis:
    """One swept parameter: its range and how many values a grid takes from it."""

    name: str
    low: float
    high: float
    count: int = 1

    def values(self) -> tuple[float, ...]:
        if self.count == 1:
            return (self.low,)
        return tuple(float(x) for x in np.linspace(self.low, self.high, self.count))


def grid(axes: Sequence[Axis]) -> list[Point]:
    """Every combination, the first axis slowest."""
    return [tuple(zip((a.name for a in axes), values)) for values in itertools.product(*(a.values() for a in axes))]


def random_points(axes: Sequence[Axis], n: int, seed: int) -> list[Point]:
    """``n`` uniform samples of the box."""
    rng = np.random.Generator(np.random.PCG64(seed))
    u = rng.random((n, len(axes)))
    return [_scale(axes, row) for row in u]


def latin_hypercube(axes: Sequence[Axis], n: int, seed: int) -> list[Point]:
    """``n`` samples with each axis cut into n strata, one sample per stratum (McKay et al. 1979)."""
    rng = np.random.Generator(np.random.PCG64(seed))
    u = np.empty((n, len(axes)))
    for j in range(len(axes)):
        u[:, j] = (rng.permutation(n) + rng.random(n)) / n
    return [_scale(axes, row) for row in u]


def _scale(axes: Sequence[Axis], row: np.ndarray) -> Point:
    return tuple((a.name, float(a.low + (a.high - a.low) * x)) for a, x in zip(axes, row))


def zoom(axes: Sequence[Axis], best: Point, shrink: float, limits: Sequence[tuple[float, float]]) -> list[Axis]:
    """The axes of the next refinement round: ``shrink`` times as wide, centred on ``best``, kept
    inside ``limits`` (a centre at an edge moves the window out to the limit)."""
    if not 0.0 < shrink < 1.0:
        raise ConfigError(f"refine: shrink {shrink} must be between 0 and 1")
    out = []
    for axis, (_, centre), (lo_limit, hi_limit) in zip(axes, best, limits):
        half = (axis.high - axis.low) * shrink / 2.0
        low, high = max(lo_limit, centre - half), min(hi_limit, centre + half)
        out.append(Axis(axis.name, low, high, axis.count))
    return out


__all__ = ["Axis", "Point", "grid", "latin_hypercube", "random_points", "zoom"]
