"""The exchange period: the one place where period indices, microseconds and seconds convert.

Period k covers [k * s, (k + 1) * s). The plant advances by whole periods (`Plant.advance`), each
integrated in chunks of at most `MAX_STEP_US` (its step is accurate to 1e-6 at 50 us), so the
plant's clock and the bench's period index are one time base: after k periods ``plant.t_s`` is
``Period.t_s(k)`` exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

#: the longest step the plant integrates at once; a longer period runs in equal chunks
MAX_STEP_US = 50
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


@dataclass(frozen=True)
class Period:
    """One exchange period of ``us`` microseconds."""

    us: int
    s: float = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if isinstance(self.us, bool) or not isinstance(self.us, int) or self.us <= 0:
            raise ValueError(f"Period: {self.us!r} us is not a positive whole number of microseconds")
        object.__setattr__(self, "s", self.us * 1e-6)

    def t_s(self, k: int) -> float:
        """The start of period k, s."""
        return k * self.s

    def index_at(self, t_s: float) -> float:
        """The period containing time ``t_s`` (`first_period_at`; inf beyond any run)."""
        return first_period_at(t_s, self.s)

    def count(self, seconds: float) -> int:
        """How many whole periods ``seconds`` is, to the nearest."""
        return round(seconds / self.s)

    @property
    def per_s(self) -> float:
        """Periods (exchanges) per second."""
        return 1e6 / self.us

    @property
    def chunks(self) -> int:
        """How many equal steps the plant integrates this period in (each at most MAX_STEP_US)."""
        return max(1, math.ceil(self.us / MAX_STEP_US))

    @property
    def chunk_s(self) -> float:
        """The length of one of those steps, s."""
        return self.s / self.chunks


__all__ = ["MAX_STEP_US", "PERIOD_TOLERANCE", "Period", "first_period_at"]
