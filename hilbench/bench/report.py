"""Summaries of a recording, for `hilbench report` (data only; the CLI prints)."""

from __future__ import annotations

import re
from typing import Any

import numpy as np

from hilbench.bench import segments as segmentation
from hilbench.bench.recorder import MARKER_FAULT, MARKER_SKIPPED, RecordingData
from hilbench.plant.period import Period

_EVENT_TIME = re.compile(r"^t=([0-9.]+) (.*)$")
_REF = re.compile(r"^ref (-?[0-9.]+) rpm")


def timed_events(data: RecordingData) -> list[tuple[float, str]]:
    """Events that carry a time (scenario actions, parameter changes)."""
    out: list[tuple[float, str]] = []
    for text in data.events:
        match = _EVENT_TIME.match(text)
        if match and not segmentation.is_segment_event(match.group(2)):
            out.append((float(match.group(1)), match.group(2)))
    return out


def reference_segments(data: RecordingData) -> list[dict[str, float]]:
    """Each reference hold: mean plant and firmware speed over its last 30 % — the run summary's
    own segmentation (hilbench.bench.segments) replayed over the recorded rows."""
    c = data.columns
    t = c["t_s"]
    period_us = data.metadata.get("period_us")
    if len(t) == 0 or "speed_rpm" not in c or not isinstance(period_us, int) or period_us <= 0:
        return []
    period_s = Period(period_us).s
    every = int(data.metadata.get("history_every_periods", 20) or 20)
    firmware = c.get("measured_speed_rpm")  # the target's own speed, where it reports one
    measured = firmware if firmware is not None else np.full(len(t), np.nan)
    end_s = (round(float(t[-1]) / period_s) + 1) * period_s  # a killed run: its last row
    segments: list[dict[str, float]] = []
    for seg in segmentation.replay(data.events, t, c["speed_rpm"], measured, period_s, every, end_s):
        segments.append({
            "from_s": round(seg.t_start_s, 4), "to_s": round(seg.t_end_s, 4), "ref_rpm": seg.ref_rpm,
            "plant_rpm": round(seg.plant_rpm, 2), "firmware_rpm": round(seg.measured_rpm, 2),
            "error_pct": round(seg.error_pct, 3),
        })
    return segments


#: the notes a closing run writes last (session._close, Bench.close)
_END_NOTES = ("end:", "interrupted at period", "fault at period", "aborted")


def how_it_ended(data: RecordingData) -> str:
    """The run's own end note, or — for a killed or truncated recording — that it was cut short
    and where (the last event is not how it ended: issue 16, item 9)."""
    end = data.metadata.get("end")
    if isinstance(end, str) and end:
        return end
    for text in reversed(data.events):
        if text.startswith(_END_NOTES):
            return text
    if data.n_rows:
        t_last = float(data.columns["t_s"][-1])
        return f"cut short (no end note: killed or truncated) after t={t_last:.6f} s, {data.n_rows} rows"
    return "cut short (no end note and no rows: killed or truncated before the first row)"


def summarise(data: RecordingData) -> dict[str, Any]:
    """The facts of a recording as plain data."""
    c = data.columns
    n = data.n_rows
    meta = data.metadata
    hello = meta.get("target_hello") or {}
    faults = np.flatnonzero(c["marker"] == MARKER_FAULT) if n else np.array([], dtype=int)
    info: dict[str, Any] = {
        "file": str(data.path),
        "rows": n,
        "time_s": f"{c['t_s'][0]:.6f} .. {c['t_s'][-1]:.6f}" if n else "empty",
        "target": f"{hello.get('firmware_name', '?')} via {meta.get('target', '?')}",
        "mode": meta.get("mode", "?") + (", duties predicted over each period" if meta.get("predicted_duties") else ""),
        "period_us": meta.get("period_us", "?"),
        "seed": meta.get("seed", "?"),
        "ended": how_it_ended(data),
        "fault_rows": [int(c["seq"][i]) if "seq" in c else int(i) for i in faults],
    }
    if n and "speed_rpm" in c:
        info["max_speed_rpm"] = round(float(np.max(np.abs(c["speed_rpm"]))), 2)
    if n and all(name in c for name in ("ia_a", "ib_a", "ic_a")):
        info["max_phase_current_a"] = round(float(np.max(np.abs(np.stack([c["ia_a"], c["ib_a"], c["ic_a"]])))), 4)
    if n and "ibus_a" in c:
        info["max_bus_current_a"] = round(float(np.max(np.abs(c["ibus_a"]))), 4)
    if n and meta.get("mode") == "realtime" and "rtt_us" in c and "lateness_us" in c:
        info.update(realtime_timing(data))
    info["segments"] = [
        f"{s['from_s']:.2f}-{s['to_s']:.2f} s: ref {s['ref_rpm']:+.0f} rpm, plant {s['plant_rpm']:+.1f}, "
        f"firmware {s['firmware_rpm']:+.1f}, error {s['error_pct']:+.2f} %"
        for s in reference_segments(data)
    ]
    info["events"] = [f"{when:.4f} s {text}" for when, text in timed_events(data)]
    return info


def realtime_timing(data: RecordingData) -> dict[str, str | int]:
    """Lateness and round trip of a real-time recording, and the periods the host skipped."""
    c = data.columns
    skipped = c["marker"] == MARKER_SKIPPED
    rtt = c["rtt_us"][~skipped]

    def spread(values: np.ndarray) -> str:
        if not len(values):
            return "-"
        p50, p99 = np.percentile(values, [50, 99])
        return f"p50 {p50:.1f}, p99 {p99:.1f}, max {np.max(values):.1f}"

    return {"lateness_us": spread(c["lateness_us"]), "rtt_us": spread(rtt), "skipped_periods": int(np.sum(skipped))}
