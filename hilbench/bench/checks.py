"""Pass/fail checks in a bench config: `[[check]]` tables, judged on a run's summary and recording.

A run that goes wrong still completes: a motor that runs away at -218 895 rpm or a config that
misses its reference by 59 % ends "completed". Checks turn those into a failure with a figure:

    [[check]]
    kind = "speed_error"      # steady-state error of every held reference (the summary's segments)
    max_pct = 2.0
    min_hold_s = 0.8          # segments held shorter than this are not judged

Run kinds (judged by `hilbench run` and `hilbench.testing.assert_config_checks`):

==================  ==========================================================================
speed_error         max_pct: |mean plant speed - reference| / |reference| over the last 30 % of
                    each held reference (segment; ``segment = N`` picks one, 1-based)
settling_time       max_s, band_pct (default 5): time from the reference change until the speed
                    stays within band_pct of the reference for the rest of the segment
peak_current        max_a: largest |ia|, |ib|, |ic| over the window
speed_limit         max_rpm: largest |speed_rpm| over the window (a runaway)
signal              signal, min and/or max: any recorded column stays within over the window
no_fault            the run did not end on a fault and the firmware's fault column stayed 0
overruns            max (count) and/or max_pct (% of periods): real-time overruns
==================  ==========================================================================

Step kinds (judged by `hilbench step` on every gain set's response; `run` ignores them):
step_rise_time (max_s), step_settling_time (max_s), step_overshoot (max_pct), step_error
(max_pct: |steady-state error| in % of the step), step_peak_current (max_a).

Any check may name the firmware its bounds were written for (``firmware = "NAME"``, the name in
the target's HELLO): a run of another firmware skips it (SKIP, "not judged").

Every result is one line: the check, PASS/FAIL and its figure against the bound. A check that
cannot be judged fails and says why (no such column, no samples in its window, a `segment = N`
the run does not have); the segment kinds over every segment say SKIP ("not judged", passing) when
no segment was held `min_hold_s` (a short run is not a failed one; the other kinds still look at
it), and so do the signal kinds of a run that kept no rows; `no_fault` without rows is judged from
the fault code the live history saw (`Summary.fault_first_s`). A run that cannot have a column (a
monitor-mode run records no plant: `absent` names such columns with the reason) says SKIP with that
reason for a check that reads one. The CLI exits with `CheckFailed.exit_code` (9) when one fails.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, Iterator, Literal, Mapping, Sequence

import numpy as np

from hilbench.fieldspec import spec
from hilbench.errors import CheckFailed, HilbenchError

if TYPE_CHECKING:
    from hilbench.bench.steptest import StepResult
    from hilbench.bench.summary import Segment, Summary

RUN_KINDS = ("speed_error", "settling_time", "peak_current", "speed_limit", "signal", "no_fault", "overruns")
STEP_KINDS = ("step_rise_time", "step_settling_time", "step_overshoot", "step_error", "step_peak_current")
CheckKind = Literal[
    "speed_error", "settling_time", "peak_current", "speed_limit", "signal", "no_fault", "overruns",
    "step_rise_time", "step_settling_time", "step_overshoot", "step_error", "step_peak_current",
]
assert CheckKind.__args__ == RUN_KINDS + STEP_KINDS  # type: ignore[attr-defined]

#: the bound keys each kind needs (at least one of them) and the others it may take
_NEEDS: dict[str, tuple[str, ...]] = {
    "speed_error": ("max_pct",), "settling_time": ("max_s",), "peak_current": ("max_a",),
    "speed_limit": ("max_rpm",), "signal": ("min", "max"), "no_fault": (), "overruns": ("max", "max_pct"),
    "step_rise_time": ("max_s",), "step_settling_time": ("max_s",), "step_overshoot": ("max_pct",),
    "step_error": ("max_pct",), "step_peak_current": ("max_a",),
}
_TAKES: dict[str, tuple[str, ...]] = {
    "speed_error": ("max_pct", "segment", "min_hold_s"),
    "settling_time": ("max_s", "band_pct", "segment", "min_hold_s"),
    "peak_current": ("max_a", "from_s", "to_s"),
    "speed_limit": ("max_rpm", "from_s", "to_s"),
    "signal": ("signal", "min", "max", "from_s", "to_s"),
    "no_fault": ("from_s", "to_s"),
    "overruns": ("max", "max_pct"),
}
_OPTIONAL_KEYS = ("max_pct", "max_s", "max_a", "max_rpm", "min", "max", "signal", "segment", "min_hold_s",
                  "band_pct", "from_s", "to_s")


@dataclass(frozen=True)
class CheckEntry:
    """[[check]]: one pass/fail criterion of a run (or of `hilbench step`); see the module doc."""

    kind: CheckKind = field(metadata=spec(doc="what is judged (hilbench.bench.checks)"))
    name: str = field(default="", metadata=spec(doc="label in the summary (default: the kind)"))
    max_pct: float | None = field(default=None, metadata=spec(unit="%", ge=0, le=1e6))
    max_s: float | None = field(default=None, metadata=spec(unit="s", gt=0, le=86400))
    max_a: float | None = field(default=None, metadata=spec(unit="A", gt=0, le=1e6))
    max_rpm: float | None = field(default=None, metadata=spec(unit="rpm", gt=0, le=1e7))
    min: float | None = field(default=None, metadata=spec(doc="signal: lowest allowed value"))
    max: float | None = field(default=None, metadata=spec(doc="signal: highest allowed value; overruns: count"))
    signal: str | None = field(default=None, metadata=spec(doc="signal: a recorded column, e.g. ia_a"))
    segment: int | None = field(default=None, metadata=spec(ge=1, le=100000, doc="only this held reference (1-based)"))
    min_hold_s: float = field(default=0.0, metadata=spec(unit="s", ge=0, le=86400, doc="judge segments held at least this long"))
    band_pct: float = field(default=5.0, metadata=spec(unit="%", gt=0, le=100))
    from_s: float = field(default=0.0, metadata=spec(unit="s", ge=0))
    to_s: float | None = field(default=None, metadata=spec(unit="s", gt=0))
    firmware: str | None = field(default=None, metadata=spec(doc="judge only runs of this firmware (the name in its HELLO)"))

    def check(self) -> list[tuple[str, str]]:
        bad: list[tuple[str, str]] = []
        needs = _NEEDS[self.kind]
        if needs and all(getattr(self, key) is None for key in needs):
            bad.append((needs[0], f"kind {self.kind!r} needs {' or '.join(needs)}"))
        takes = _TAKES.get(self.kind, needs)
        for key in _OPTIONAL_KEYS:
            default = CheckEntry.__dataclass_fields__[key].default
            if key not in takes and getattr(self, key) != default:
                bad.append((key, f"not used by kind {self.kind!r} (it takes {', '.join(takes) or 'no keys'})"))
        if self.kind == "signal" and not self.signal:
            bad.append(("signal", "kind 'signal' needs signal = COLUMN (e.g. \"ia_a\")"))
        if self.to_s is not None and self.to_s <= self.from_s:
            bad.append(("to_s", f"must be after from_s ({self.from_s:g} s)"))
        return bad

    @property
    def label(self) -> str:
        return self.name or self.kind


@dataclass(frozen=True)
class CheckResult:
    """One check's verdict: its figure against its bound, as one line."""

    name: str
    kind: str
    passed: bool
    figure: str  # e.g. "worst -0.87 % (segment 1, +1500 rpm) <= 2 %"
    value: float | None = None
    bound: float | None = None
    skipped: bool = False  # not judged (no rows, another firmware, no held segment): passes, says SKIP

    def line(self) -> str:
        verdict = "SKIP" if self.skipped else "PASS" if self.passed else "FAIL"
        return f"check {self.name}: {verdict} {self.figure}"

    def as_dict(self) -> dict[str, object]:
        return {"name": self.name, "kind": self.kind, "passed": self.passed, "skipped": self.skipped,
                "figure": self.figure, "value": self.value, "bound": self.bound}


SignalsSource = Callable[[], Mapping[str, np.ndarray]]

#: kinds judged on the summary alone; the others read the recorded signals
SUMMARY_KINDS = ("speed_error", "overruns")


def run_checks(entries: Sequence[CheckEntry], summary: "Summary", signals: SignalsSource,
               absent: Mapping[str, str] | None = None) -> list[CheckResult]:
    """Judge every run kind of ``entries`` on a finished run; ``signals`` is read only if needed.
    ``absent``: columns this kind of run cannot record, each with the reason (a check reading one
    says SKIP with it; any other missing column is the check's failure or a bug, never a SKIP)."""
    cache: dict[str, Mapping[str, np.ndarray]] = {}

    def columns() -> Mapping[str, np.ndarray]:
        if "s" not in cache:
            try:
                cache["s"] = signals()
            except HilbenchError as exc:  # nothing recorded: `hilbench run` without --record keeps no rows
                raise _NoRows(str(exc)) from None
            if absent:
                cache["s"] = _WithAbsent(cache["s"], absent)
        return cache["s"]

    def judge(entry: CheckEntry) -> CheckResult:
        if not _for_firmware(entry, summary.firmware):
            return _other_firmware(entry, summary.firmware)
        try:
            return _judge_run(entry, summary, columns)
        except _Absent as exc:
            return CheckResult(entry.label, entry.kind, True, f"not judged: {exc}", skipped=True)
        except _NoRows:
            return CheckResult(entry.label, entry.kind, True, "not judged: no rows were kept "
                               "(record the run, --record run.npz, to judge the signals)", skipped=True)

    return [judge(entry) for entry in entries if entry.kind in RUN_KINDS]


class _NoRows(Exception):
    """The run kept no rows to judge signals on."""


class _Absent(Exception):
    """A check reads a column this kind of run cannot record."""


class _WithAbsent(Mapping[str, np.ndarray]):
    """A run's signals; reading (or asking for) a column ``absent`` names raises `_Absent` with its reason."""

    def __init__(self, signals: Mapping[str, np.ndarray], absent: Mapping[str, str]) -> None:
        self._signals = signals
        self._absent = absent

    def _refuse(self, name: object) -> None:
        if isinstance(name, str) and name in self._absent and name not in self._signals:
            raise _Absent(f"no column {name!r}: {self._absent[name]}")

    def __getitem__(self, name: str) -> np.ndarray:
        self._refuse(name)
        return self._signals[name]

    def __contains__(self, name: object) -> bool:
        self._refuse(name)
        return name in self._signals

    def __iter__(self) -> Iterator[str]:
        return iter(self._signals)

    def __len__(self) -> int:
        return len(self._signals)


def _for_firmware(entry: CheckEntry, firmware: str) -> bool:
    return entry.firmware is None or entry.firmware.strip().upper() == firmware.strip().upper()


def _other_firmware(entry: CheckEntry, firmware: str) -> CheckResult:
    """Bounds written for one firmware say nothing about another: passed, as not judged."""
    return CheckResult(entry.label, entry.kind, True, f"not judged: written for {entry.firmware}, "
                                                      f"the run's firmware is {firmware or 'unknown'}", skipped=True)


def step_checks(entries: Sequence[CheckEntry], result: "StepResult", firmware: str) -> list[CheckResult]:
    """Judge every step kind of ``entries`` on one step response of ``firmware``."""
    return [_judge_step(entry, result) if _for_firmware(entry, firmware) else _other_firmware(entry, firmware)
            for entry in entries if entry.kind in STEP_KINDS]


def raise_if_failed(results: Sequence[CheckResult], where: str = "") -> None:
    """CheckFailed (exit code 9) naming every failed check, when one failed."""
    failed = [r for r in results if not r.passed]
    if failed:
        what = "; ".join(f"{r.name}: {r.figure}" for r in failed)
        raise CheckFailed(f"{where}{len(failed)} of {len(results)} checks failed: {what}")


def checks_text(results: Sequence[CheckResult]) -> str:
    """One line per check, for the plain summary."""
    return "\n".join(r.line() for r in results)


# ---------------------------------------------------------------- run kinds
def _result(entry: CheckEntry, passed: bool, figure: str, value: float | None, bound: float | None) -> CheckResult:
    return CheckResult(entry.label, entry.kind, bool(passed), figure, value, bound)


def _window(entry: CheckEntry, t: np.ndarray) -> tuple[np.ndarray, str]:
    end = entry.to_s if entry.to_s is not None else math.inf
    mask = (t >= entry.from_s) & (t <= end)
    last = float(t[-1]) if t.size else 0.0
    return mask, f"{entry.from_s:.3f}-{min(end, last):.3f} s"


#: how a run can end before its scenario: the last held reference was cut short, not completed
STOPPED_EARLY = ("stopped by ctl", "interrupted")


def _segments(entry: CheckEntry, summary: "Summary") -> tuple[list[tuple[int, "Segment"]], str]:
    """The held references a check judges: those it names, held long enough, and not the last one of
    a run the user stopped early (its hold was cut short, not completed)."""
    cut = len(summary.segments) if summary.end_reason in STOPPED_EARLY else 0
    chosen = [(n, s) for n, s in enumerate(summary.segments, 1)
              if (entry.segment is None or n == entry.segment) and s.t_end_s - s.t_start_s >= entry.min_hold_s
              and n != cut]
    if chosen:
        return chosen, ""
    what = f"segment {entry.segment}" if entry.segment is not None else "held speed reference"
    hold = f" held at least {entry.min_hold_s:g} s" if entry.min_hold_s else ""
    return [], f"no {what}{hold} ({len(summary.segments)} segments in the run)"


def _unjudged(entry: CheckEntry, why: str, bound: float | None) -> CheckResult:
    """No segment to judge: a check asking for a given segment fails; one over every segment
    passes with the reason (a short run, or one with no reference, is not a failed run)."""
    if entry.segment is not None:
        return _result(entry, False, why, None, bound)
    return CheckResult(entry.label, entry.kind, True, f"not judged: {why}", None, bound, skipped=True)


Columns = Callable[[], Mapping[str, np.ndarray]]


def _judge_run(entry: CheckEntry, summary: "Summary", columns: Columns) -> CheckResult:
    """One run kind's verdict (`_RUN_JUDGES`)."""
    return _RUN_JUDGES[entry.kind](entry, summary, columns)


def _speed_error(entry: CheckEntry, summary: "Summary", columns: Columns) -> CheckResult:
    """The worst steady-state error of the held references judged."""
    chosen, why = _segments(entry, summary)
    if not chosen:
        return _unjudged(entry, why, entry.max_pct)
    n, worst = max(chosen, key=lambda ns: abs(ns[1].error_pct) if not math.isnan(ns[1].error_pct) else math.inf)
    err = worst.error_pct
    bound = float(entry.max_pct or 0.0)
    ok = not math.isnan(err) and abs(err) <= bound
    return _result(entry, ok, f"worst {err:+.2f} % (segment {n}, {worst.ref_rpm:+.0f} rpm, "
                              f"{worst.t_start_s:.2f}-{worst.t_end_s:.2f} s) {'<=' if ok else '>'} {bound:g} %",
                   abs(err), bound)


def _settle_time(t: np.ndarray, speed: np.ndarray, seg: "Segment", band: float) -> float:
    """From a segment's start until the speed stays within ``band`` of its reference to its end
    (inf: outside the band at the end)."""
    mask = (t >= seg.t_start_s) & (t < seg.t_end_s)
    tt, yy = t[mask], speed[mask]
    outside = np.flatnonzero(np.abs(yy - seg.ref_rpm) > band * abs(seg.ref_rpm))
    if outside.size == 0:
        return 0.0
    if outside[-1] == yy.size - 1:
        return math.inf  # still outside at the segment's end
    return float(tt[outside[-1] + 1] - seg.t_start_s)


def _settling_time(entry: CheckEntry, summary: "Summary", columns: Columns) -> CheckResult:
    """The slowest settling into the band of the held references judged."""
    chosen, why = _segments(entry, summary)
    if not chosen:
        return _unjudged(entry, why, entry.max_s)
    c = columns()
    band = entry.band_pct / 100.0
    worst_n, worst_s, worst_seg = 0, -1.0, chosen[0][1]
    for n, seg in chosen:
        settle = _settle_time(c["t_s"], c["speed_rpm"], seg, band)
        if settle > worst_s:
            worst_n, worst_s, worst_seg = n, settle, seg
    bound = float(entry.max_s or 0.0)
    ok = worst_s <= bound
    shown = "never (outside the band at the segment's end)" if math.isinf(worst_s) else f"{worst_s:.3f} s"
    return _result(entry, ok, f"slowest {shown} to stay within {entry.band_pct:g} % (segment {worst_n}, "
                              f"{worst_seg.ref_rpm:+.0f} rpm from {worst_seg.t_start_s:.2f} s) "
                              f"{'<=' if ok else '>'} {bound:g} s", worst_s, bound)


def _peak_current(entry: CheckEntry, summary: "Summary", columns: Columns) -> CheckResult:
    c = columns()
    mask, window = _window(entry, c["t_s"])
    stacked = np.abs(np.stack([c["ia_a"][mask], c["ib_a"][mask], c["ic_a"][mask]]))
    return _max_abs(entry, "|ia|,|ib|,|ic|", stacked.max(axis=0) if stacked.size else stacked,
                    c["t_s"][mask], float(entry.max_a or 0.0), "A", window)


def _speed_limit(entry: CheckEntry, summary: "Summary", columns: Columns) -> CheckResult:
    c = columns()
    mask, window = _window(entry, c["t_s"])
    return _max_abs(entry, "|speed_rpm|", np.abs(c["speed_rpm"][mask]), c["t_s"][mask],
                    float(entry.max_rpm or 0.0), "rpm", window)


def _signal(entry: CheckEntry, summary: "Summary", columns: Columns) -> CheckResult:
    c = columns()
    mask, window = _window(entry, c["t_s"])
    name = entry.signal or ""
    if name not in c:
        return _result(entry, False, f"no column {name!r} in the recording", None, None)
    return _within(entry, name, c[name][mask], c["t_s"][mask], window)


def _no_fault(entry: CheckEntry, summary: "Summary", columns: Columns) -> CheckResult:
    """The run did not end on a fault and the firmware's fault column stayed 0 over the window."""
    if summary.end_reason == "fault" or summary.fault:
        return _result(entry, False, f"the run ended on a fault: {summary.fault}", 1.0, 0.0)
    try:
        c = columns()
    except _NoRows:
        return _no_fault_live(entry, summary)
    mask, window = _window(entry, c["t_s"])
    codes = c["fault"][mask]
    bad = np.flatnonzero(codes != 0)
    if bad.size:
        i = int(bad[0])
        return _result(entry, False, f"firmware fault code {int(codes[i])} at {float(c['t_s'][mask][i]):.4f} s "
                                     f"(over {window}, {bad.size} periods with a fault)", float(bad.size), 0.0)
    return _result(entry, True, f"no fault over {window}", 0.0, 0.0)


def _no_fault_live(entry: CheckEntry, summary: "Summary") -> CheckResult:
    """No rows kept: the fault code as the live history saw it (every history period; a firmware
    fault latches until a restart, so none is missed), over the check's window."""
    end = entry.to_s if entry.to_s is not None else math.inf
    window = f"{entry.from_s:.3f}-{min(end, summary.sim_s):.3f} s"
    first, last = summary.fault_first_s, summary.fault_last_s
    if first is not None and last is not None and first <= end and last >= entry.from_s:
        return _result(entry, False, f"firmware fault code {summary.fault_code} at {max(first, entry.from_s):.4f} s "
                                     f"(seen live over {window}; no rows kept)", 1.0, 0.0)
    return _result(entry, True, f"no fault seen live over {window} (no rows kept)", 0.0, 0.0)


def _overruns(entry: CheckEntry, summary: "Summary", columns: Columns) -> CheckResult:
    count, periods = summary.overruns, max(1, summary.periods)
    pct = 100.0 * count / periods
    ok = (entry.max is None or count <= entry.max) and (entry.max_pct is None or pct <= entry.max_pct)
    bounds = " and ".join(b for b in (f"{entry.max:g}" if entry.max is not None else "",
                                      f"{entry.max_pct:g} %" if entry.max_pct is not None else "") if b)
    return _result(entry, ok, f"{count} overruns ({pct:.2f} % of {summary.periods} periods) "
                              f"{'within' if ok else 'beyond'} {bounds}", float(count),
                   entry.max if entry.max is not None else entry.max_pct)


#: each run kind's judge
_RUN_JUDGES: dict[str, Callable[[CheckEntry, "Summary", Columns], CheckResult]] = {
    "speed_error": _speed_error, "settling_time": _settling_time, "peak_current": _peak_current,
    "speed_limit": _speed_limit, "signal": _signal, "no_fault": _no_fault, "overruns": _overruns,
}
assert tuple(_RUN_JUDGES) == RUN_KINDS


def _max_abs(entry: CheckEntry, what: str, values: np.ndarray, t: np.ndarray, bound: float, unit: str,
             window: str) -> CheckResult:
    if values.size == 0:
        return _result(entry, False, f"no samples over {window}", None, bound)
    i = int(np.argmax(values))
    peak = float(values[i])
    ok = peak <= bound
    return _result(entry, ok, f"max {what} {peak:.4g} {unit} at {float(t[i]):.4f} s over {window} "
                              f"{'<=' if ok else '>'} {bound:g} {unit}", peak, bound)


def _within(entry: CheckEntry, name: str, values: np.ndarray, t: np.ndarray, window: str) -> CheckResult:
    if values.size == 0:
        return _result(entry, False, f"no samples over {window}", None, None)
    lo = -math.inf if entry.min is None else entry.min
    hi = math.inf if entry.max is None else entry.max
    excess = np.maximum(lo - values, values - hi)
    i = int(np.argmax(excess))
    ok = float(excess[i]) <= 0.0
    limits = f"[{'' if entry.min is None else format(entry.min, 'g')}, {'' if entry.max is None else format(entry.max, 'g')}]"
    return _result(entry, ok, f"{name} worst {float(values[i]):.4g} at {float(t[i]):.4f} s over {window} "
                              f"{'within' if ok else 'outside'} {limits}", float(values[i]), entry.max if entry.max is not None else entry.min)


# ---------------------------------------------------------------- step kinds
def _judge_step(entry: CheckEntry, result: "StepResult") -> CheckResult:
    m = result.metrics
    where = f" ({result.label})"
    if result.stalled:
        return _result(entry, False, f"the firmware stalled during the step{where}", None, None)
    if entry.kind in ("step_rise_time", "step_settling_time"):
        value = m.rise_time_s if entry.kind == "step_rise_time" else m.settling_time_s
        bound = float(entry.max_s or 0.0)
        what = "rise 10-90 %" if entry.kind == "step_rise_time" else f"settling {m.settle_band:.0%}"
        if value is None:
            return _result(entry, False, f"{what}: never within {m.duration_s:.3f} s after the step{where} "
                                         f"> {bound:g} s", None, bound)
        ok = value <= bound
        return _result(entry, ok, f"{what} {value:.3f} s{where} {'<=' if ok else '>'} {bound:g} s", value, bound)
    if entry.kind == "step_peak_current":
        value = m.peak_current_a
        bound = float(entry.max_a or 0.0)
        if value is None:
            return _result(entry, False, f"no currents recorded{where}", None, bound)
        ok = value <= bound
        return _result(entry, ok, f"peak current {value:.3f} A{where} {'<=' if ok else '>'} {bound:g} A", value, bound)
    value = m.overshoot_pct if entry.kind == "step_overshoot" else abs(m.ss_error_pct)
    bound = float(entry.max_pct or 0.0)
    what = "overshoot" if entry.kind == "step_overshoot" else "steady-state error"
    ok = not math.isnan(value) and value <= bound
    return _result(entry, ok, f"{what} {value:.2f} %{where} {'<=' if ok else '>'} {bound:g} %", value, bound)


__all__ = [
    "CheckEntry",
    "CheckResult",
    "RUN_KINDS",
    "STEP_KINDS",
    "checks_text",
    "raise_if_failed",
    "run_checks",
    "step_checks",
]
