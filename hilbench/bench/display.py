"""The display stream: the session's recorded rows, decimated for a screen (a scope asks for it).

The recording stays full-rate; a scope only needs, per display bucket of ``bucket_periods``
periods, the minimum and maximum of each column (an envelope: a 20 kHz current shows its true
extent at any zoom, where plain subsampling would alias). This part is asleep until a scope asks
for the stream (a run without a recording then keeps a bounded window of rows for it,
`Session.watch_rows`, and drops it when no scope has asked for ``IDLE_AFTER_S``) (the control socket's ``stream`` command); then, every time the session calls
`due` (every ``observe_every_periods``) and at least every ``take_every_s`` of wall time or just
before the recorder flushes its buffer, it takes the raw rows appended since its last take (a
slice of ``recorder.rows.data``), turns them into envelopes with one ``reduceat`` per take and
keeps the frames in a ring. A ``stream`` request gets the frames after the one it saw, the
columns it asked for as little-endian float32 in base64, the markers and the status figures.

Markers: the recorder's events of the rows taken (scenario and script actions, parameter writes,
guard trips, ctl actions, faults: "t=... text" with its marker code), kept with the frame. Halls become three digital columns
(``hall_a``, ``hall_b``, ``hall_c``: bits 0, 1, 2 of ``hall``), exact under min/max.
"""

from __future__ import annotations

import base64
import math
import time
from collections import deque
from dataclasses import dataclass
from enum import IntEnum
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

import numpy as np

from hilbench.bench.recorder import MARKER_FAULT, MARKER_PARAM
from hilbench.errors import HilbenchError
from hilbench.protocol import Fault, State

if TYPE_CHECKING:
    from hilbench.bench.pacing import RealtimePacing
    from hilbench.protocol import Drive
    from hilbench.bench.session import Session

#: periods per display bucket at the start (0.5 ms at 20 kHz); doubled in a take with many rows
BUCKET_PERIODS = 10
#: at most this many buckets per frame (the bucket doubles until the take fits)
MAX_FRAME_BUCKETS = 600
#: a take at least this often while a scope is attached (wall time)
TAKE_EVERY_S = 0.1
#: frames kept for scopes that connect or fall behind
RING_FRAMES = 400
#: at most this many buckets (summed over frames) in one reply
MAX_REPLY_BUCKETS = 20_000
#: the stream sleeps again when no scope asked for this long (wall time)
IDLE_AFTER_S = 5.0
#: a newly attached scope gets this much history (simulated seconds) when the buffer holds it
HISTORY_S = 2.0
#: the digital columns made of ``hall`` (bit, name)
HALL_BITS = ((0, "hall_a"), (1, "hall_b"), (2, "hall_c"))


class ScopeError(HilbenchError):
    """The scope's stream could not answer (the run goes on)."""

    kind = "scope"


def envelope(values: np.ndarray, bucket: int) -> tuple[np.ndarray, np.ndarray]:
    """Min and max of each run of ``bucket`` rows (axis 0; the last bucket may be shorter)."""
    if bucket < 1:
        raise ValueError(f"envelope: bucket must be >= 1, got {bucket}")
    starts = np.arange(0, len(values), bucket)
    if not len(starts):
        shape = (0,) + values.shape[1:]
        return np.zeros(shape), np.zeros(shape)
    return np.minimum.reduceat(values, starts, axis=0), np.maximum.reduceat(values, starts, axis=0)


def b64_f32(values: np.ndarray) -> str:
    """A float array as little-endian float32 bytes in base64 (the page's Float32Array)."""
    return base64.b64encode(np.ascontiguousarray(values, dtype="<f4").tobytes()).decode("ascii")


def parse_event(text: str) -> tuple[float, str] | None:
    """A recorder event "t=1.234500 text" as (t_s, text)."""
    head, _, rest = text.partition(" ")
    if not head.startswith("t="):
        return None
    try:
        return float(head[2:]), rest
    except ValueError:
        return None


def marker_kind(text: str, marker: int) -> str:
    """What an event is, for the page's marker colours."""
    if text.startswith("guard"):
        return "guard"
    if marker == MARKER_PARAM or text.startswith("set "):
        return "param"
    if marker == MARKER_FAULT or text.startswith("fault"):
        return "fault"
    return "event"


@dataclass(frozen=True)
class Frame:
    """Envelopes of consecutive buckets: bucket i starts at ``t0_s + i * bucket_s``."""

    seq: int
    t0_s: float
    bucket_s: float
    n: int
    envelopes: dict[str, tuple[np.ndarray, np.ndarray]]  # column -> (mins, maxs), float32

    def as_json(self, names: Sequence[str]) -> dict[str, Any]:
        return {"seq": self.seq, "t0": self.t0_s, "dt": self.bucket_s, "n": self.n,
                "cols": {name: [b64_f32(self.envelopes[name][0]), b64_f32(self.envelopes[name][1])]
                         for name in names if name in self.envelopes}}


class DisplayStream:
    """The session's display part (see module docstring); asleep until a scope asks."""

    def __init__(self, session: "Session", *, bucket_periods: int = BUCKET_PERIODS,
                 max_frame_buckets: int = MAX_FRAME_BUCKETS, take_every_s: float = TAKE_EVERY_S,
                 clock: Callable[[], float] = time.perf_counter) -> None:
        self.session = session
        self.bucket_periods = bucket_periods
        self.max_frame_buckets = max_frame_buckets
        self.take_every_s = take_every_s
        self.clock = clock
        self.frames: deque[Frame] = deque(maxlen=RING_FRAMES)
        self.seq = 0
        self.takes = 0
        self.error: str | None = None
        self._rows: Any = None  # the recorder's row buffer taken from
        self._taken = 0  # rows of it taken, counted from the run's first (its `dropped` rows on: in the buffer)
        self._boundary: set[tuple[int, str]] = set()
        self.marks: deque[tuple[int, float, str, str]] = deque(maxlen=1000)  # (seq, t_s, kind, text)
        self._asked_at = -math.inf
        self._last_take = -math.inf
        self._layout: Any = None
        self._names: tuple[str, ...] = ()
        self._specs: dict[str, tuple[str, Any, float, float]] = {}
        self._tracked: tuple[str, ...] = ()
        self._units: dict[str, str] = {}
        self._drive: Any = None
        self._pacing: "RealtimePacing | None" = None
        self._k = 0
        self._rate = (clock(), 0, 0.0)  # (wall, k, periods/s)

    # ------------------------------------------------------------------ the session's side
    @property
    def active(self) -> bool:
        return self.clock() - self._asked_at < IDLE_AFTER_S

    def due(self, k: int, drive: "Drive | None", pacing: "RealtimePacing | None") -> None:
        """Every observe period: note the status; take new rows when a take is due or a flush comes."""
        self._drive, self._pacing, self._k = drive, pacing, k
        if self._asked_at == -math.inf or not self.active:
            if self._asked_at != -math.inf:  # no scope asks any more: a run without a recording keeps no rows
                self.session.watch_rows(False)
                self._asked_at = -math.inf
            return
        if self.flush_coming() or self.clock() - self._last_take >= self.take_every_s:
            self._take_or_sleep()

    def flush_coming(self) -> bool:
        """Whether the recorder's next `maybe_flush` writes rows out (a loop's cue to call `due` now)."""
        return _flush_coming(self.session.recorder)

    def closing(self) -> None:
        """The run ends: the rows not taken yet taken now, before the close writes them out (while a
        scope watches)."""
        if self._asked_at != -math.inf and self.active:
            self._take_or_sleep()

    def _take_or_sleep(self) -> None:
        try:
            self.take()
        except Exception as exc:  # noqa: BLE001 - a scope must never end a run: it goes to sleep instead
            self.error = f"scope stream stopped: {type(exc).__name__}: {exc}"
            self._asked_at = -math.inf

    def take(self) -> None:
        """Decimate the rows appended since the last take into one frame (the tracked columns only:
        min/max of each raw field, scaled afterwards, so a take costs two reductions per column)."""
        self._last_take = self.clock()
        recorder = self.session.recorder
        if recorder is None:
            return
        rows = recorder.rows
        if rows.layout is not self._layout:
            self._learn(rows.layout)
        if rows is not self._rows:  # another recorder's buffer (a scope's window, or none): from its start
            self._rows, self._taken = rows, rows.dropped
        size = rows.struct.size
        data = rows.data
        # the rows not taken yet: those the buffer still holds (a flush may have let some go untaken;
        # counted from the run's start, so a buffer refilled to the same length is not mistaken for one
        # with nothing new)
        row_from, row_to = max(self._taken - rows.dropped, 0), len(data) // size  # (a row may be half-appended)
        if row_to <= row_from:
            return
        # a view, not a copy: this runs on the session's thread, so the buffer cannot grow while
        # the view lives, and the view is gone when this returns
        raw = np.frombuffer(data, dtype=rows.layout.dtype, count=row_to - row_from, offset=row_from * size)
        try:
            self._taken = rows.dropped + row_to
            self.seq += 1
            self._take_events(recorder, row_from, row_to)
            bucket = self.bucket_periods
            while len(raw) > bucket * self.max_frame_buckets:
                bucket *= 2
            starts = np.arange(0, len(raw), bucket)
            envelopes = {name: self._envelope(raw, name, starts) for name in self._tracked}
            t_field, t_scale = self._specs["t_s"][1], self._specs["t_s"][2]
            t0_s = float(raw[t_field][0]) * t_scale
        finally:
            del raw
        self.takes += 1
        self.frames.append(Frame(self.seq, t0_s, bucket * self.session.period.s, len(starts), envelopes))

    def _envelope(self, raw: np.ndarray, name: str, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        kind, source, scale, modulo = self._specs[name]
        if kind == "bit":
            values = (raw["hall"] >> source) & 1
        elif modulo:
            values = np.mod(raw[source] * scale, modulo)
        else:
            values = np.ascontiguousarray(raw[source])  # one strided pass; reduceat is ~9x faster on it
        lo, hi = np.minimum.reduceat(values, starts), np.maximum.reduceat(values, starts)
        if kind == "field" and not modulo and scale != 1.0:
            lo, hi = (lo * scale, hi * scale) if scale >= 0 else (hi * scale, lo * scale)
        return lo.astype(np.float32), hi.astype(np.float32)

    def _take_events(self, recorder: Any, row_from: int, row_to: int) -> None:
        """The recorder's events at the rows taken (its pending list: a file recorder empties it
        when it flushes, and we take before that)."""
        events = getattr(recorder, "events", None)
        if events is None:
            events = getattr(recorder, "_events", ())
        boundary = set()  # events noted at the next row to come: taken now, skipped next time
        for index, text, marker in events:
            if row_from <= index <= row_to and (index, text) not in self._boundary:
                if index == row_to:
                    boundary.add((index, text))
                parsed = parse_event(text)
                if parsed is not None and math.isfinite(parsed[0]):
                    self.marks.append((self.seq, parsed[0], marker_kind(parsed[1], marker), parsed[1]))
        self._boundary = boundary

    def _learn(self, layout: Any) -> None:
        self._layout = layout
        self._rows = None  # (a new layout: the buffer was emptied) taken from its start
        names = list(layout.column_names)
        units = {name: unit for name, unit, _ in layout.column_specs}
        wrap = dict(layout.wrap)
        specs: dict[str, tuple[str, Any, float, float]] = {
            name: ("field", src, scale, wrap.get(name, 0.0)) for name, _, _, src, scale in layout.columns}
        if "hall" in names:
            at = names.index("hall") + 1
            names[at:at] = [n for _, n in HALL_BITS]
            units.update({n: "bit" for _, n in HALL_BITS})
            specs.update({n: ("bit", bit, 1.0, 0.0) for bit, n in HALL_BITS})
        self._names = tuple(names)
        self._units = units
        self._specs = specs
        self._tracked = tuple(n for n in self._tracked if n in specs)
        self.frames.clear()

    def _track(self, columns: Sequence[str]) -> None:
        """Decimate these columns from now on, and again the history the buffer still holds."""
        new = [c for c in columns if c in self._specs and c not in self._tracked]
        if new:
            self._tracked += tuple(new)
            self._rewind()

    def _rewind(self) -> None:
        recorder = self.session.recorder
        if recorder is None:
            return
        rows = recorder.rows
        self._rows = rows
        self._taken = rows.dropped + max(0, len(rows) - int(HISTORY_S / self.session.period.s))
        self.frames.clear()

    # ------------------------------------------------------------------ a scope's request
    def request(self, since: int, columns: Sequence[str], t_s: float) -> dict[str, Any]:
        """The reply to ``stream``: frames after ``since`` (-1: a new scope; meta and history).
        Raises ScopeError (a refusal the session answers with) rather than anything that would end the run."""
        try:  # every number in the reply is finite by construction (the reply line refuses NaN)
            return self._request(since, columns, t_s)
        except Exception as exc:  # noqa: BLE001
            raise ScopeError(f"scope stream: {type(exc).__name__}: {exc}") from None

    def _request(self, since: int, columns: Sequence[str], t_s: float) -> dict[str, Any]:
        first = self._asked_at == -math.inf or not self.active
        self._asked_at = self.clock()
        self.session.watch_rows(True)  # a run without a recording: rows for the scope while it watches
        recorder = self.session.recorder
        if recorder is not None and recorder.rows.layout is not self._layout:
            self._learn(recorder.rows.layout)
        if first:  # wake up: history from what the buffer still holds
            self._tracked = ()
            self._rewind()
        self._track(columns)
        self.take()
        names = [c for c in columns if c in self._tracked]
        frames = [f for f in self.frames if f.seq > since]
        total, chosen = 0, []
        for frame in reversed(frames):  # the newest first, up to the reply's budget
            total += frame.n
            if total > MAX_REPLY_BUCKETS and chosen:
                break
            chosen.append(frame)
        chosen.reverse()
        out: dict[str, Any] = {
            "seq": self.seq, "frames": [f.as_json(names) for f in chosen],
            "status": self.status(t_s), "markers": [[t, kind, text] for seq, t, kind, text in self.marks if seq > since],
        }
        if since < 0:
            out["meta"] = self.meta()
        return out

    def meta(self) -> dict[str, Any]:
        """What the page needs once: columns with units, parameters with ranges, the run."""
        from hilbench.bench.livetuning import raw_per_unit

        session = self.session
        tuning = session.tuning
        params = {}
        for name, info in tuning.info.items():
            scale = raw_per_unit(info.ptype)
            params[name] = {"min": info.min_value / scale, "max": info.max_value / scale,
                            "writable": bool(info.access), "integer": scale == 1.0}
        return {
            "columns": [[name, self._units.get(name, "")] for name in self._names],
            "params": params, "tunable": list(session.profile.tunable),
            "period_s": session.period.s, "mode": session.options.mode,
            "target": session.target_label,
            "firmware": session.hello.firmware_name if session.hello is not None else "",
            "live": True,
        }

    def status(self, t_s: float) -> dict[str, Any]:
        """State, fault, reference, parameters and the link figures now."""
        from hilbench.bench.summary import percentiles

        session, drive, pacing = self.session, self._drive, self._pacing
        now = self.clock()
        wall, k0, rate = self._rate
        if now - wall >= 0.5:
            rate = (self._k - k0) / (now - wall)
            self._rate = (now, self._k, rate)
        rtts = pacing.rtts if pacing is not None else session.lockstep_rtts
        stats = percentiles([r * 1e6 for r in rtts[-256:]]) if rtts else {}
        try:
            params = session.param_values()
        except Exception:  # noqa: BLE001 - a status must not fail on a target that stopped answering
            params = {}
        return {
            "t_s": _num(t_s), "state": None if drive is None else int(drive.state),
            "fault": None if drive is None else int(drive.fault),
            "state_name": None if drive is None else _name(State, drive.state),
            "fault_name": None if drive is None else _name(Fault, drive.fault),
            "ref_rpm": _num(session.ref_rpm), "params": _finite(params),
            "guard": bool(session.tuning.guard.enabled), "periods_per_s": _num(rate),
            "rtt_p50_us": _num(stats.get("p50")), "rtt_p99_us": _num(stats.get("p99")),
            "overruns": pacing.overruns if pacing is not None else 0,
            "link": {k: v for k, v in session.link_stats().items() if isinstance(v, (int, float))},
            "ended": session.ended,
        }


def _flush_coming(recorder: Any) -> bool:
    """Whether the recorder's next `maybe_flush` writes rows out (a full chunk, a planned run's
    last one before the close, a CSV's rows for its thread: `Recorder.rows_to_write`)."""
    if recorder is None:
        return False
    rows_to_write = getattr(recorder, "rows_to_write", None)
    if rows_to_write is not None:
        return bool(rows_to_write() <= 0)
    return len(recorder.rows) >= getattr(recorder, "flush_rows", math.inf)


def _name(kind: type[IntEnum], code: int) -> str:
    """A protocol state's or fault's name ("4" for a code the schema does not name)."""
    try:
        return kind(code).name
    except ValueError:
        return str(int(code))


def _num(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def _finite(values: Mapping[str, float]) -> dict[str, float | None]:
    return {k: _num(v) for k, v in values.items()}


__all__ = ["BUCKET_PERIODS", "DisplayStream", "Frame", "envelope", "b64_f32", "marker_kind", "parse_event"]
