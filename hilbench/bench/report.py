"""Summaries of a recording, for `hilbench report` (data only; the CLI prints)."""

from __future__ import annotations

import re
from typing import Any, Callable, Iterator

import numpy as np

from hilbench.bench import segments as segmentation
from hilbench.bench.chunk_quantiles import spread
from hilbench.bench.column_chunks import ArrayChunks, ColumnChunks
from hilbench.bench.recording_head import RecordingHead
from hilbench.bench.recorder import MARKER_FAULT, MARKER_SKIPPED, RecordingData
from hilbench.plant.period import Period

#: fault rows a report names (the first ones); the rest are counted: a recording full of faults
#: would otherwise list every row
MAX_FAULT_ROWS = 1000

_EVENT_TIME = re.compile(r"^t=([0-9.]+) (.*)$")
_REF = re.compile(r"^ref (-?[0-9.]+) rpm")


def timed_events(data: RecordingData) -> list[tuple[float, str]]:
    """Events that carry a time (scenario actions, parameter changes)."""
    return _timed_events(data.events)


def _timed_events(events: tuple[str, ...]) -> list[tuple[float, str]]:
    out: list[tuple[float, str]] = []
    for text in events:
        match = _EVENT_TIME.match(text)
        if match and not segmentation.is_segment_event(match.group(2)):
            out.append((float(match.group(1)), match.group(2)))
    return out


def reference_segments(data: RecordingData) -> list[dict[str, float]]:
    """Each reference hold: mean plant and firmware speed over its last 30 % — the run summary's
    own segmentation (hilbench.bench.segments) replayed over the recorded rows."""
    return _segments(_head(data), ArrayChunks(data.columns, data.units))


def _segments(head: RecordingHead, source: ColumnChunks) -> list[dict[str, float]]:
    """`reference_segments` from the rows a chunk at a time (the Segmenter keeps 4096 samples a hold)."""
    period_us = head.metadata.get("period_us")
    if "speed_rpm" not in source.names or not isinstance(period_us, int) or period_us <= 0:
        return []
    period_s = Period(period_us).s
    every = int(head.metadata.get("history_every_periods", 20) or 20)
    firmware = "measured_speed_rpm" in source.names  # the target's own speed, where it reports one
    replaying = segmentation.Replay(head.events, period_s, every)
    t_last: float | None = None
    for chunk in source.chunks(["speed_rpm", *(["measured_speed_rpm"] if firmware else [])]):
        t = chunk["t_s"]
        if not len(t):
            continue
        t_last = float(t[-1])
        k = np.rint(t / period_s)
        sampled = np.flatnonzero(np.remainder(k, every) == 0)  # the rows replay samples (its own test, exactly)
        measured = chunk["measured_speed_rpm"][sampled] if firmware else np.full(len(sampled), np.nan)
        replaying.rows(t[sampled], chunk["speed_rpm"][sampled], measured)
    if t_last is None:
        return []
    end_s = (round(t_last / period_s) + 1) * period_s  # a killed run: its last row
    return [{
        "from_s": round(seg.t_start_s, 4), "to_s": round(seg.t_end_s, 4), "ref_rpm": seg.ref_rpm,
        "plant_rpm": round(seg.plant_rpm, 2), "firmware_rpm": round(seg.measured_rpm, 2),
        "error_pct": round(seg.error_pct, 3),
    } for seg in replaying.finish(end_s)]


#: the notes a closing run writes last (session._close, Bench.close)
_END_NOTES = ("end:", "interrupted at period", "fault at period", "aborted")


def how_it_ended(data: RecordingData) -> str:
    """The run's own end note, or — for a killed or truncated recording — that it was cut short
    and where (the last event is not how it ended: issue 16, item 9)."""
    t_last = float(data.columns["t_s"][-1]) if data.n_rows else None
    return _ended(_head(data), data.n_rows, t_last)


def _ended(head: RecordingHead, n_rows: int, t_last_s: float | None) -> str:
    end = head.metadata.get("end")
    if isinstance(end, str) and end:
        return end
    for text in reversed(head.events):
        if text.startswith(_END_NOTES):
            return text
    if n_rows and t_last_s is not None:
        return f"cut short (no end note: killed or truncated) after t={t_last_s:.6f} s, {n_rows} rows"
    return "cut short (no end note and no rows: killed or truncated before the first row)"


def summarise(data: RecordingData) -> dict[str, Any]:
    """The facts of a recording held in memory as plain data."""
    return summarise_chunks(_head(data), ArrayChunks(data.columns, data.units))


def _head(data: RecordingData) -> RecordingHead:
    return RecordingHead(data.path, data.metadata, data.events, data.units, data.formats)


class _Extremes:
    """One pass: rows, first and last time, the first MAX_FAULT_ROWS fault rows and how many there
    are, the largest magnitudes (a NaN wins, as np.max)."""

    def __init__(self, names: tuple[str, ...]) -> None:
        self.rows = 0
        self.t_first_s = self.t_last_s = 0.0
        self.fault_rows: list[int] = []
        self.faults = 0
        self.has_seq = "seq" in names
        self.peaks: dict[str, float] = {}

    def offer(self, chunk: dict[str, np.ndarray]) -> None:
        t = chunk["t_s"]
        if not len(t):
            return
        if not self.rows:
            self.t_first_s = t[0]
        self.t_last_s = t[-1]
        faults = np.flatnonzero(chunk["marker"] == MARKER_FAULT)
        self.faults += len(faults)
        faults = faults[:max(0, MAX_FAULT_ROWS - len(self.fault_rows))]
        self.fault_rows += [int(chunk["seq"][i]) if self.has_seq else int(i) + self.rows for i in faults]
        self.rows += len(t)
        for name, values in chunk.items():
            if name not in ("t_s", "marker", "seq"):
                peak = np.max(np.abs(values))
                self.peaks[name] = peak if name not in self.peaks else np.maximum(self.peaks[name], peak)


def summarise_chunks(head: RecordingHead, source: ColumnChunks) -> dict[str, Any]:
    """The facts of a recording as plain data, its rows read a chunk at a time (the memory of a
    chunk, the fault rows and the segments' samples, whatever the length). A figure may be a float
    that is not finite (an infinite speed column): JSON output goes through `json_safe` first."""
    meta = head.metadata
    hello = meta.get("target_hello") or {}
    wanted = [name for name in ("marker", "seq", "speed_rpm", "ia_a", "ib_a", "ic_a", "ibus_a") if name in source.names]
    scan = _Extremes(source.names)
    for chunk in source.chunks(wanted):
        scan.offer(chunk)
    n = scan.rows
    info: dict[str, Any] = {
        "file": str(head.path),
        "rows": n,
        "time_s": f"{scan.t_first_s:.6f} .. {scan.t_last_s:.6f}" if n else "empty",
        "target": f"{hello.get('firmware_name', '?')} via {meta.get('target', '?')}",
        "mode": meta.get("mode", "?") + (", duties predicted over each period" if meta.get("predicted_duties") else ""),
        "period_us": meta.get("period_us", "?"),
        "seed": meta.get("seed", "?"),
        "ended": _ended(head, n, float(scan.t_last_s) if n else None),
        "fault_rows": scan.fault_rows,
    }
    if scan.faults > len(scan.fault_rows):  # (only then: the summary of a few faults is as it was)
        info["fault_rows_left_out"] = scan.faults - len(scan.fault_rows)  # after the first MAX_FAULT_ROWS
    peaks = scan.peaks
    if n and "speed_rpm" in peaks:
        info["max_speed_rpm"] = round(float(peaks["speed_rpm"]), 2)
    if n and all(name in peaks for name in ("ia_a", "ib_a", "ic_a")):
        phase = np.maximum(np.maximum(peaks["ia_a"], peaks["ib_a"]), peaks["ic_a"])
        info["max_phase_current_a"] = round(float(phase), 4)
    if n and "ibus_a" in peaks:
        info["max_bus_current_a"] = round(float(peaks["ibus_a"]), 4)
    if n and meta.get("mode") == "realtime" and "rtt_us" in source.names and "lateness_us" in source.names:
        info.update(_realtime_timing(source))
    info["segments"] = [
        f"{s['from_s']:.2f}-{s['to_s']:.2f} s: ref {s['ref_rpm']:+.0f} rpm, plant {s['plant_rpm']:+.1f}, "
        f"firmware {s['firmware_rpm']:+.1f}, error {s['error_pct']:+.2f} %"
        for s in _segments(head, source)
    ]
    info["events"] = [f"{when:.4f} s {text}" for when, text in _timed_events(head.events)]
    return info


def json_safe(value: Any, depth: int = 0) -> Any:
    """``value`` (a summary) ready for `report --json`: each float that is not finite is the string
    "inf", "-inf" or "nan". JSON has no such numbers (json.dumps writes Infinity or NaN, which JSON
    parsers refuse); a string says what the table shows, where null would read as "no figure".
    Dicts, lists and tuples are walked, everything else is kept; a value nested deeper than 32
    levels (a hand-made metadata value) is a note saying so, so the walk and the dump stay shallow."""
    if isinstance(value, (float, np.floating)) and not np.isfinite(value):
        return "nan" if np.isnan(value) else "inf" if value > 0 else "-inf"
    if isinstance(value, (dict, list, tuple)) and depth >= 32:
        return "(nested too deeply to show)"
    if isinstance(value, dict):
        return {key: json_safe(item, depth + 1) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(item, depth + 1) for item in value]
    return value


def realtime_timing(data: RecordingData) -> dict[str, str | int]:
    """Lateness and round trip of a real-time recording, and the periods the host skipped."""
    return _realtime_timing(ArrayChunks(data.columns, data.units))


def _realtime_timing(source: ColumnChunks) -> dict[str, str | int]:
    """`realtime_timing` a chunk at a time: exact percentiles by radix selection (chunk_quantiles)."""
    def lateness() -> Iterator[np.ndarray]:
        return (chunk["lateness_us"] for chunk in source.chunks(["lateness_us"]))

    def rtt() -> Iterator[np.ndarray]:
        return (chunk["rtt_us"][chunk["marker"] != MARKER_SKIPPED] for chunk in source.chunks(["rtt_us", "marker"]))

    skipped = sum(int(np.sum(chunk["marker"] == MARKER_SKIPPED)) for chunk in source.chunks(["marker"]))

    def text(values: Callable[[], Iterator[np.ndarray]]) -> str:
        figures = spread(values, (50, 99))
        if not figures.count:
            return "-"
        p50, p99 = figures.percentiles
        return f"p50 {p50:.1f}, p99 {p99:.1f}, max {figures.max_value:.1f}"

    return {"lateness_us": text(lateness), "rtt_us": text(rtt), "skipped_periods": skipped}
