"""What the plots of a recording draw, computed from its rows a chunk at a time.

A trace with more rows in view than 2 * MAX_POINTS is drawn as the min/max envelope of runs of
``bucket`` rows (one per pixel column or so, so peaks stay visible); this module forms those
envelopes chunk by chunk (a partial bucket carried to the next chunk), so a 600 s recording is
plotted in the memory of one chunk and the envelopes, and the figures are those the whole arrays
gave. Two passes: the rows in view (count, first and last time), then every trace.

Hall edges and sector changes are counted and binned as they come; the ticks of invalid hall codes
and out-of-sequence sector changes are kept one per 1/MAX_POINTS of the span once there are more
than MAX_TICKS of them (their count stays exact).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from hilbench.bench.column_chunks import ColumnChunks
from hilbench.bench.display import envelope
from hilbench.errors import ConfigError

#: above this many points in view a trace is drawn as its min/max envelope per bucket
MAX_POINTS = 2000
#: more ticks than this: one kept per 1/MAX_POINTS of the span
MAX_TICKS = 4 * MAX_POINTS


@dataclass(frozen=True)
class Trace:
    """A trace as drawn: every row (``hi`` None) or the envelope ``lo``..``hi`` of buckets starting at ``t_s``."""

    t_s: np.ndarray
    lo: np.ndarray
    hi: np.ndarray | None = None


def whole_trace(t_s: np.ndarray, y: np.ndarray) -> Trace:
    """A trace of arrays in memory, decimated as `TraceBuilder` decimates chunks."""
    builder = TraceBuilder(len(t_s))
    builder.add(t_s, np.asarray(y, dtype=np.float64))
    return builder.trace()


class TraceBuilder:
    """One trace of ``n_rows`` rows, fed in order, chunk by chunk; ``bucket`` rows an envelope point
    (default: every row up to 2 * MAX_POINTS rows, else MAX_POINTS points)."""

    def __init__(self, n_rows: int, bucket: int | None = None) -> None:
        if bucket is None:
            bucket = 1 if n_rows <= 2 * MAX_POINTS else -(-n_rows // MAX_POINTS)
        self.bucket = max(1, bucket)
        self._t: list[np.ndarray] = []
        self._lo: list[np.ndarray] = []
        self._hi: list[np.ndarray] = []
        self._rest_t = np.zeros(0)
        self._rest_y = np.zeros(0)

    def add(self, t_s: np.ndarray, y: np.ndarray) -> None:
        if self.bucket == 1:
            self._t.append(np.array(t_s))
            self._lo.append(np.array(y, dtype=np.float64))
            return
        t_s = np.concatenate([self._rest_t, t_s])
        y = np.concatenate([self._rest_y, np.asarray(y, dtype=np.float64)])
        full = len(y) // self.bucket * self.bucket
        self._reduce(t_s[:full], y[:full])
        self._rest_t, self._rest_y = t_s[full:].copy(), y[full:].copy()

    def _reduce(self, t_s: np.ndarray, y: np.ndarray) -> None:
        if len(y):
            lo, hi = envelope(y, self.bucket)
            self._t.append(t_s[::self.bucket].copy())
            self._lo.append(lo)
            self._hi.append(hi)

    def trace(self) -> Trace:
        if self.bucket == 1:
            return Trace(_joined(self._t), _joined(self._lo))
        self._reduce(self._rest_t, self._rest_y)
        self._rest_t, self._rest_y = np.zeros(0), np.zeros(0)
        return Trace(_joined(self._t), _joined(self._lo), _joined(self._hi))


def _joined(parts: list[np.ndarray]) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(0)


@dataclass
class Ticks:
    """Times to mark (invalid codes, out-of-sequence changes), bounded; ``count`` exact."""

    t0_s: float
    span_s: float
    count: int = 0
    times: list[float] = field(default_factory=list)
    _bins: dict[int, float] | None = None

    def add(self, t_s: np.ndarray) -> None:
        self.count += len(t_s)
        if self._bins is None:
            self.times.extend(t_s.tolist())
            if len(self.times) <= MAX_TICKS:
                return
            t_s, self.times, self._bins = np.asarray(self.times), [], {}
        bins = np.floor((t_s - self.t0_s) / self.span_s * MAX_POINTS).astype(np.int64)
        for b, t in zip(bins.tolist(), t_s.tolist()):
            self._bins.setdefault(b, t)

    def array(self) -> np.ndarray:
        return np.asarray(self.times if self._bins is None else sorted(self._bins.values()))


@dataclass
class Rate:
    """Edges (hall) or changes (sector) of a whole-number trace: their count, binned over ~200 bins, and ticks."""

    bins: np.ndarray
    ticks: Ticks
    count: int = 0
    counts: np.ndarray = field(default_factory=lambda: np.zeros(200, dtype=np.int64))
    last: int | None = None


@dataclass
class RecordingView:
    """The rows of a recording in view, as the figures draw them."""

    n_rows: int
    t_first_s: float
    t_last_s: float
    traces: dict[str, Trace]
    has_values: dict[str, bool]  # a column with a number that is not NaN ...
    nonzero: dict[str, bool]  # ... with one that is neither 0 nor NaN
    hall: Rate | None = None
    sector: Rate | None = None


def _rows_in_view(source: ColumnChunks, window: tuple[float, float] | None) -> tuple[int, float, float]:
    """How many rows are in view, the first and last time of them (pass 1: t_s only)."""
    n, first, last, whole_first, whole_last = 0, 0.0, 0.0, None, 0.0
    for chunk in source.chunks([]):
        t = chunk["t_s"]
        if not len(t):
            continue
        whole_first = t[0] if whole_first is None else whole_first
        whole_last = t[-1]
        if window is not None:
            t = t[(t >= window[0]) & (t <= window[1])]
        if len(t):
            first = t[0] if not n else first
            last = t[-1]
            n += len(t)
    if window is not None and not n:
        raise ConfigError(f"plot window {window[0]:g}..{window[1]:g} s: the recording spans "
                          f"{whole_first:g}..{whole_last:g} s" if whole_first is not None else
                          "plot window: the recording is empty")
    return n, float(first), float(last)


def _hall_codes(values: np.ndarray) -> np.ndarray:
    return np.clip(np.nan_to_num(values, nan=0.0, posinf=0.0, neginf=0.0), 0, 7).astype(np.int64)


def _sector_codes(values: np.ndarray) -> np.ndarray:
    return np.nan_to_num(values, nan=7.0).astype(np.int64)


def view(source: ColumnChunks, columns: Sequence[str], window: tuple[float, float] | None = None,
         link_floor_us: float = 0.1) -> RecordingView:
    """The traces of ``columns`` (those the recording has) in view; with hall and sector, their
    bit traces (hall_a, hall_b, hall_c) and rates; rtt_us and lateness_us floored at ``link_floor_us``."""
    names = [name for name in dict.fromkeys(columns) if name in source.names and name != "t_s"]
    n, t_first, t_last = _rows_in_view(source, window)
    builders = {name: TraceBuilder(n) for name in names}
    hall_sector = "hall" in names and "sector" in names
    if hall_sector:
        builders.update({f"hall_{x}": TraceBuilder(n) for x in "abc"})
    result = RecordingView(n, t_first, t_last, {}, dict.fromkeys(names, False), dict.fromkeys(names, False))
    if hall_sector:
        bins = np.linspace(t_first, t_last, 201)
        span = float(t_last - t_first) or 1.0
        result.hall, result.sector = Rate(bins, Ticks(t_first, span)), Rate(bins, Ticks(t_first, span))
    for chunk in source.chunks(names):
        t = chunk["t_s"]
        if window is not None:
            keep = (t >= window[0]) & (t <= window[1])
            chunk = {name: values[keep] for name, values in chunk.items()}
            t = chunk["t_s"]
        if not len(t):
            continue
        for name in names:
            y = chunk[name]
            result.has_values[name] = result.has_values[name] or not bool(np.all(np.isnan(y)))
            result.nonzero[name] = result.nonzero[name] or bool(np.any(np.nan_to_num(y) != 0))
            if name in ("rtt_us", "lateness_us"):  # a log axis: what is early or on time at the floor
                y = np.maximum(y, link_floor_us)
            builders[name].add(t, y)
        if hall_sector:
            _hall_chunk(result, builders, t, chunk["hall"], chunk["sector"])
    result.traces = {name: builder.trace() for name, builder in builders.items()}
    return result


def _hall_chunk(result: RecordingView, builders: dict[str, TraceBuilder], t: np.ndarray, hall_values: np.ndarray,
                sector_values: np.ndarray) -> None:
    hall = _hall_codes(hall_values)
    for bit, x in enumerate("abc"):
        builders[f"hall_{x}"].add(t, ((hall >> bit) & 1).astype(np.float64) * 0.8)
    assert result.hall is not None and result.sector is not None
    result.hall.ticks.add(t[(hall == 0) | (hall == 7)])
    _changes(result.hall, hall, t)
    sector = _sector_codes(sector_values)
    changes, previous = _changes(result.sector, sector, t)
    before, after = previous[changes], sector[changes]
    jump = ((after - before) % 6 != 1) & ((before - after) % 6 != 1) | (after > 5) | (before > 5)
    result.sector.ticks.add(t[changes[jump]])


def _changes(rate: Rate, codes: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rows of this chunk whose code differs from the row before (across the chunk's cut),
    counted and binned into ``rate``; and each row's previous code."""
    previous = np.concatenate([[rate.last if rate.last is not None else codes[0]], codes[:-1]])
    changes = np.flatnonzero(codes != previous)
    rate.last = int(codes[-1])
    rate.count += len(changes)
    rate.counts += np.histogram(t[changes], bins=rate.bins)[0]
    return changes, previous


__all__ = ["MAX_POINTS", "MAX_TICKS", "Rate", "RecordingView", "Ticks", "Trace", "TraceBuilder", "view", "whole_trace"]
