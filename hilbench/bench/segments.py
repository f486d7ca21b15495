"""The run's reference segments: one segmentation for the run summary and `hilbench report`.

A segment is one held speed reference, from the moment it is reached (after its ramp) until the
next reference, a stop (a press of the start/stop button after the start) or the end; its figure
is the mean plant (and firmware) speed over the last 30 % of the hold. The session tells a
`Segmenter` every reference change however it was made (scenario, ramp, `ctl ref`, `ctl step`,
the Python API) and records the same calls as ``segment:`` events; `hilbench report` replays
those events over the recorded rows, so both see the same samples and give the same numbers
(issue 16, item 10). Memory is bounded: a hold's samples are decimated beyond ``capacity``.
"""

from __future__ import annotations

import bisect
import math
import operator
import re
from dataclasses import dataclass, field
from typing import Iterable, Sequence

from hilbench.bench.summary import Segment

#: presses this soon after a reference are starts, not stops
START_PRESS_S = 0.05
#: holds shorter than this give no segment
MIN_HOLD_S = 0.05
#: the segment's figure is the mean over this last fraction of the hold
WINDOW_FRACTION = 0.3
EVENT_PREFIX = "segment:"
_EVENT = re.compile(r"^segment: (ref|press|end) at (\S+)(?: ref (\S+) ramp (\S+))?$")


@dataclass
class _Open:
    t_s: float
    hold_from_s: float
    ref_rpm: float
    stride: int = 1
    seen: int = 0
    samples: list[tuple[float, float, float]] = field(default_factory=list)


_time, _plant, _measured = operator.itemgetter(0), operator.itemgetter(1), operator.itemgetter(2)  # of a sample


class Segmenter:
    """Reference changes, stops and speed samples in; `Segment`s out, in bounded memory. Samples come
    in time order (every caller's are a period count's), so a hold's window is a slice of them."""

    def __init__(self, capacity: int = 4096) -> None:
        self.capacity = capacity
        self.segments: list[Segment] = []
        self._open: _Open | None = None

    def reference(self, t_s: float, ref_rpm: float, ramp_s: float = 0.0) -> None:
        """A new reference at t_s, held from t_s + ramp_s (the same reference again changes nothing)."""
        current = self._open
        if current is not None and current.ref_rpm == ref_rpm and ramp_s == 0.0 and t_s >= current.hold_from_s:
            return
        self._close(t_s)
        self._open = _Open(t_s, t_s + ramp_s, ref_rpm)

    def press(self, t_s: float) -> None:
        """The start/stop button: a stop unless it comes right after the reference (a start)."""
        current = self._open
        if current is not None and t_s > current.hold_from_s + START_PRESS_S:
            self._close(t_s)

    def end(self, t_s: float) -> None:
        self._close(t_s)

    def tell(self, kind: str, t_s: float, ref_rpm: float = 0.0, ramp_s: float = 0.0) -> str:
        """A reference change ("ref"), a press ("press") or the end (anything else); the recording's
        note of it (what `report` replays)."""
        if kind == "ref":
            self.reference(t_s, ref_rpm, ramp_s)
            return reference_event(t_s, ref_rpm, ramp_s)
        if kind == "press":
            self.press(t_s)
            return press_event(t_s)
        self.end(t_s)
        return end_event(t_s)

    def sample(self, t_s: float, plant_rpm: float, measured_rpm: float) -> None:
        current = self._open
        if current is None or t_s < current.hold_from_s:
            return
        current.seen += 1
        if (current.seen - 1) % current.stride:
            return
        current.samples.append((t_s, plant_rpm, measured_rpm))
        if len(current.samples) >= self.capacity:  # keep every other one: half the rate from now on
            del current.samples[1::2]
            current.stride *= 2

    def sample_many(self, t_s: Sequence[float], plant_rpm: Sequence[float], measured_rpm: Sequence[float]) -> None:
        """`sample` for each of these samples in turn (times ascending), a slice at a time."""
        current = self._open
        if current is None:
            return
        n = len(t_s)
        i = bisect.bisect_left(t_s, current.hold_from_s)  # those before the hold: not seen
        while i < n:
            first = i + (-current.seen) % current.stride  # the next one kept
            if first >= n:
                current.seen += n - i
                return
            room = self.capacity - len(current.samples)
            end = min(n, first + room * current.stride)
            stop = first + ((end - first - 1) // current.stride) * current.stride + 1  # after the last one kept
            step = current.stride
            current.samples.extend(zip(t_s[first:stop:step], plant_rpm[first:stop:step], measured_rpm[first:stop:step]))
            current.seen += stop - i
            i = stop
            if len(current.samples) >= self.capacity:  # keep every other one: half the rate from now on
                del current.samples[1::2]
                current.stride *= 2

    def finish(self, t_s: float) -> list[Segment]:
        """Close the open hold at t_s; every segment of the run."""
        self._close(t_s)
        return list(self.segments)

    def _close(self, end_s: float) -> None:
        current, self._open = self._open, None
        if current is None:
            return
        start = current.hold_from_s
        if end_s - start <= MIN_HOLD_S or current.ref_rpm == 0:
            return
        window_start = end_s - WINDOW_FRACTION * (end_s - start)
        samples = current.samples  # in time order: the window is a slice of them
        window = samples[bisect.bisect_left(samples, window_start, key=_time):bisect.bisect_left(samples, end_s, key=_time)]
        if not window:
            return
        plant = sum(map(_plant, window)) / len(window)
        measured = [m for m in map(_measured, window) if m == m]  # (NaN: not reported)
        self.segments.append(Segment(current.t_s, end_s, float(current.ref_rpm), plant,
                                     sum(measured) / len(measured) if measured else math.nan))


def reference_event(t_s: float, ref_rpm: float, ramp_s: float = 0.0) -> str:
    """The recording's note of a reference change (exact values: the report replays it)."""
    return f"{EVENT_PREFIX} ref at {t_s!r} ref {float(ref_rpm)!r} ramp {float(ramp_s)!r}"


def press_event(t_s: float) -> str:
    return f"{EVENT_PREFIX} press at {t_s!r}"


def end_event(t_s: float) -> str:
    return f"{EVENT_PREFIX} end at {t_s!r}"


def is_segment_event(text: str) -> bool:
    return text.startswith(EVENT_PREFIX)


def parse_segment_event(text: str) -> tuple[float, str, float, float] | None:
    """A ``segment:`` event as (time, kind, ref, ramp); None for other events; ValueError for one
    whose numbers are not finite (no session writes that: a damaged recording)."""
    match = _EVENT.match(text)
    if not match:
        return None
    kind, when, ref, ramp = match.groups()
    numbers = (float(when), float(ref or 0.0), float(ramp or 0.0))
    if not all(math.isfinite(x) for x in numbers):
        raise ValueError(f"segment event {text[:60]!r}: a number that is not finite")
    return numbers[0], kind, numbers[1], numbers[2]


def replay(events: Iterable[str], t_s: Sequence[float], plant_rpm: Sequence[float], measured_rpm: Sequence[float],
           period_s: float, every_periods: int, end_s: float) -> list[Segment]:
    """The segments of a recording: its ``segment:`` events over the rows the session sampled
    (every ``every_periods``-th period, at k * period_s, as the session's own history)."""
    replaying = Replay(events, period_s, every_periods)
    replaying.rows(t_s, plant_rpm, measured_rpm)
    return replaying.finish(end_s)


class Replay:
    """`replay` a chunk of rows at a time (rows in order): the same segments, in the Segmenter's
    bounded memory however long the recording."""

    def __init__(self, events: Iterable[str], period_s: float, every_periods: int) -> None:
        self._calls = [call for call in map(parse_segment_event, events) if call is not None]
        self._next = 0
        self._period_s = period_s
        self._every = every_periods
        self._segmenter = Segmenter()

    def rows(self, t_s: Sequence[float], plant_rpm: Sequence[float], measured_rpm: Sequence[float]) -> None:
        """The next rows of the recording."""
        calls, period_s, every, segmenter = self._calls, self._period_s, self._every, self._segmenter
        i = self._next
        for row in range(len(t_s)):
            k = round(t_s[row] / period_s)
            if k % every:
                continue
            t = k * period_s
            while i < len(calls) and _period_of(calls[i][0], period_s) <= k:  # by period, as the session ran them
                _apply(segmenter, calls[i])
                i += 1
            segmenter.sample(t, float(plant_rpm[row]), float(measured_rpm[row]))
        self._next = i

    def finish(self, end_s: float) -> list[Segment]:
        """The events after the last row, then every segment, the open one closed at ``end_s``."""
        for call in self._calls[self._next:]:
            _apply(self._segmenter, call)
        self._next = len(self._calls)
        return self._segmenter.finish(end_s)


def _period_of(t_s: float, period_s: float) -> float:
    """The period an event at ``t_s`` fell in (rounded, as the session ran it); ±inf for a time no
    period index holds (a damaged recording's 1e308 s)."""
    q = t_s / period_s
    return round(q) if math.isfinite(q) else math.copysign(math.inf, q)


def _apply(segmenter: Segmenter, call: tuple[float, str, float, float]) -> None:
    when, kind, ref, ramp = call
    if kind == "ref":
        segmenter.reference(when, ref, ramp)
    elif kind == "press":
        segmenter.press(when)
    else:
        segmenter.end(when)


__all__ = ["Replay", "Segmenter", "replay", "reference_event", "press_event", "end_event", "is_segment_event", "parse_segment_event",
           "START_PRESS_S"]
