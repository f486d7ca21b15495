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
reason for a check that reads one. A recording that cannot be read (damaged, beyond the reader's
bound, gone) is never a SKIP: each check that reads it fails naming the file and why, and
`raise_if_failed` raises that RecordingError (exit code 6). The CLI exits with
`CheckFailed.exit_code` (9) when a check fails on its figure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, Iterator, Literal, Mapping, Sequence

import numpy as np

from hilbench.bench.chunk_scans import FirstNonzero, RunningPeak, SettleScan, WindowScan
from hilbench.bench.column_chunks import ArrayChunks, ColumnChunks
from hilbench.fieldspec import spec
from hilbench.errors import CheckFailed, HilbenchError, RecordingError

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
    unreadable: bool = False  # its recording could not be read: fails, and is a RecordingError (exit 6)

    def line(self) -> str:
        verdict = "SKIP" if self.skipped else "PASS" if self.passed else "FAIL"
        return f"check {self.name}: {verdict} {self.figure}"

    def as_dict(self) -> dict[str, object]:
        return {"name": self.name, "kind": self.kind, "passed": self.passed, "skipped": self.skipped,
                "figure": self.figure, "value": self.value, "bound": self.bound}


#: a run's recorded signals: whole arrays (a run that kept its rows) or a recording read in chunks
SignalsSource = Callable[[], "Mapping[str, np.ndarray] | ColumnChunks"]

#: kinds judged on the summary alone; the others read the recorded signals
SUMMARY_KINDS = ("speed_error", "overruns")


def run_checks(entries: Sequence[CheckEntry], summary: "Summary", signals: SignalsSource,
               absent: Mapping[str, str] | None = None) -> list[CheckResult]:
    """Judge every run kind of ``entries`` on a finished run; ``signals`` is read only if needed,
    and then only the columns a check reads, a chunk of rows at a time (memory bounded however
    long the run). ``signals`` raises a RecordingError for a recording it cannot read (every check
    reading it fails with it) and any other HilbenchError when nothing was recorded (they say
    SKIP). ``absent``: columns this kind of run cannot record, each with the reason (a check
    reading one says SKIP with it; any other missing column is the check's failure or a bug,
    never a SKIP)."""
    cache: dict[str, _Signals | Exception] = {}

    def columns() -> _Signals:
        if "s" not in cache:
            try:
                source = signals()
            except RecordingError as exc:  # a recording that is there but cannot be read: an error, not a SKIP
                cache["s"] = _Unreadable(exc)
            except HilbenchError as exc:  # nothing recorded: `hilbench run` without --record keeps no rows
                cache["s"] = _NoRows(str(exc))
            else:
                cache["s"] = _Signals(source if isinstance(source, ColumnChunks) else ArrayChunks(source), absent or {})
        got = cache["s"]
        if isinstance(got, Exception):
            raise got
        return got

    def judge(entry: CheckEntry) -> CheckResult | _Pending:
        if not _for_firmware(entry, summary.firmware):
            return _other_firmware(entry, summary.firmware)
        try:
            return _judge_run(entry, summary, columns)
        except _Absent as exc:
            return CheckResult(entry.label, entry.kind, True, f"not judged: {exc}", skipped=True)
        except _NoRows:
            return CheckResult(entry.label, entry.kind, True, "not judged: no rows were kept "
                               "(record the run, --record run.npz, to judge the signals)", skipped=True)
        except _Unreadable as exc:
            return _unreadable(entry, exc.error)

    judged = [entry for entry in entries if entry.kind in RUN_KINDS]
    outcomes = [judge(entry) for entry in judged]
    pending = [outcome for outcome in outcomes if isinstance(outcome, _Pending)]
    if pending:  # one pass over the rows for every check that reads them (a CSV is parsed once)
        try:
            for chunk in columns().chunks(*dict.fromkeys(name for p in pending for name in p.names)):
                for p in pending:
                    p.offer(chunk)
        except RecordingError as exc:  # damaged on the way (a row out of order, a file cut short)
            return [_unreadable(e, exc) if isinstance(o, _Pending) else o for e, o in zip(judged, outcomes)]
    return [outcome.finish() if isinstance(outcome, _Pending) else outcome for outcome in outcomes]


def _unreadable(entry: CheckEntry, error: RecordingError) -> CheckResult:
    """A check whose recording cannot be read: failed, naming the file and why (never a SKIP)."""
    return CheckResult(entry.label, entry.kind, False, f"cannot be judged: {error}", unreadable=True)


class _NoRows(Exception):
    """The run kept no rows to judge signals on."""


class _Unreadable(Exception):
    """The run's recording is there but cannot be read (``error`` says which and why)."""

    def __init__(self, error: RecordingError) -> None:
        super().__init__(str(error))
        self.error = error


class _Absent(Exception):
    """A check reads a column this kind of run cannot record."""


class _Signals:
    """A run's signals for the checks: asking for a column ``absent`` names raises `_Absent` with
    its reason; reading gives the columns asked for, a chunk of rows at a time."""

    def __init__(self, source: ColumnChunks, absent: Mapping[str, str]) -> None:
        self._source = source
        self._absent = absent

    def _refuse(self, name: str) -> None:
        if name in self._absent and name not in self._source.names:
            raise _Absent(f"no column {name!r}: {self._absent[name]}")

    def has(self, name: str) -> bool:
        self._refuse(name)
        return name in self._source.names

    def reads(self, *names: str) -> tuple[str, ...]:
        """``names``, each refused if the run cannot have it."""
        for name in names:
            self._refuse(name)
        return names

    def chunks(self, *names: str) -> Iterator[dict[str, np.ndarray]]:
        """t_s and ``names`` chunk by chunk (KeyError: a column the run does not have)."""
        return self._source.chunks(self.reads(*names))


@dataclass(frozen=True)
class _Pending:
    """A check that reads rows: the columns it reads, what it does with each chunk of them (t_s
    with them, in row order), and its verdict after the last."""

    names: tuple[str, ...]
    offer: Callable[[dict[str, np.ndarray]], None]
    finish: Callable[[], CheckResult]


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
    """CheckFailed (exit code 9) naming every failed check, when one failed; RecordingError (exit
    code 6) naming the file and why, when a check could not read its recording."""
    unreadable = [r for r in results if r.unreadable]
    if unreadable:
        raise RecordingError(f"{where}{len(unreadable)} of {len(results)} checks {unreadable[0].figure}")
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


def _scan(entry: CheckEntry) -> WindowScan:
    return WindowScan(entry.from_s, entry.to_s)


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


Columns = Callable[[], "_Signals"]


def _judge_run(entry: CheckEntry, summary: "Summary", columns: Columns) -> CheckResult | _Pending:
    """One run kind's verdict (`_RUN_JUDGES`), or what it reads of the rows to reach it."""
    return _RUN_JUDGES[entry.kind](entry, summary, columns)


def _speed_error(entry: CheckEntry, summary: "Summary", columns: Columns) -> CheckResult | _Pending:
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


def _settling_time(entry: CheckEntry, summary: "Summary", columns: Columns) -> CheckResult | _Pending:
    """The slowest settling into the band of the held references judged."""
    chosen, why = _segments(entry, summary)
    if not chosen:
        return _unjudged(entry, why, entry.max_s)
    names = columns().reads("speed_rpm")
    band = entry.band_pct / 100.0
    scans = [(n, SettleScan(seg, band)) for n, seg in chosen]

    def offer(chunk: dict[str, np.ndarray]) -> None:
        for _, scan in scans:
            scan.offer(chunk["t_s"], chunk["speed_rpm"])

    def finish() -> CheckResult:
        worst_n, worst_s, worst_seg = 0, -1.0, chosen[0][1]
        for n, scan in scans:
            if scan.settle_s > worst_s:
                worst_n, worst_s, worst_seg = n, scan.settle_s, scan.segment
        bound = float(entry.max_s or 0.0)
        ok = worst_s <= bound
        shown = "never (outside the band at the segment's end)" if math.isinf(worst_s) else f"{worst_s:.3f} s"
        return _result(entry, ok, f"slowest {shown} to stay within {entry.band_pct:g} % (segment {worst_n}, "
                                  f"{worst_seg.ref_rpm:+.0f} rpm from {worst_seg.t_start_s:.2f} s) "
                                  f"{'<=' if ok else '>'} {bound:g} s", worst_s, bound)

    return _Pending(names, offer, finish)


def _peak_current(entry: CheckEntry, summary: "Summary", columns: Columns) -> CheckResult | _Pending:
    names = columns().reads("ia_a", "ib_a", "ic_a")
    window, peak = _scan(entry), RunningPeak()

    def offer(c: dict[str, np.ndarray]) -> None:
        mask = window.mask(c["t_s"])
        stacked = np.abs(np.stack([c["ia_a"][mask], c["ib_a"][mask], c["ic_a"][mask]]))
        values = stacked.max(axis=0) if stacked.size else stacked
        peak.offer(values, values, c["t_s"][mask])

    return _Pending(names, offer, lambda: _max_abs(entry, "|ia|,|ib|,|ic|", peak, float(entry.max_a or 0.0), "A",
                                                   window.text))


def _speed_limit(entry: CheckEntry, summary: "Summary", columns: Columns) -> CheckResult | _Pending:
    names = columns().reads("speed_rpm")
    window, peak = _scan(entry), RunningPeak()

    def offer(c: dict[str, np.ndarray]) -> None:
        mask = window.mask(c["t_s"])
        values = np.abs(c["speed_rpm"][mask])
        peak.offer(values, values, c["t_s"][mask])

    return _Pending(names, offer, lambda: _max_abs(entry, "|speed_rpm|", peak, float(entry.max_rpm or 0.0), "rpm",
                                                   window.text))


def _signal(entry: CheckEntry, summary: "Summary", columns: Columns) -> CheckResult | _Pending:
    name = entry.signal or ""
    if not columns().has(name):
        return _result(entry, False, f"no column {name!r} in the recording", None, None)
    lo = -math.inf if entry.min is None else entry.min
    hi = math.inf if entry.max is None else entry.max
    window, worst = _scan(entry), RunningPeak()

    def offer(c: dict[str, np.ndarray]) -> None:
        mask = window.mask(c["t_s"])
        values = c[name][mask]
        worst.offer(np.maximum(lo - values, values - hi), values, c["t_s"][mask])

    return _Pending((name,), offer, lambda: _within(entry, name, worst, window.text))


def _no_fault(entry: CheckEntry, summary: "Summary", columns: Columns) -> CheckResult | _Pending:
    """The run did not end on a fault and the firmware's fault column stayed 0 over the window."""
    if summary.end_reason == "fault" or summary.fault:
        return _result(entry, False, f"the run ended on a fault: {summary.fault}", 1.0, 0.0)
    try:
        names = columns().reads("fault")
    except _NoRows:
        return _no_fault_live(entry, summary)
    window, first = _scan(entry), FirstNonzero()

    def offer(c: dict[str, np.ndarray]) -> None:
        mask = window.mask(c["t_s"])
        first.offer(c["fault"][mask], c["t_s"][mask])

    def finish() -> CheckResult:
        if first.count:
            return _result(entry, False, f"firmware fault code {int(first.code)} at {first.t_s:.4f} s "
                                         f"(over {window.text}, {first.count} periods with a fault)",
                           float(first.count), 0.0)
        return _result(entry, True, f"no fault over {window.text}", 0.0, 0.0)

    return _Pending(names, offer, finish)


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


def _overruns(entry: CheckEntry, summary: "Summary", columns: Columns) -> CheckResult | _Pending:
    count, periods = summary.overruns, max(1, summary.periods)
    pct = 100.0 * count / periods
    ok = (entry.max is None or count <= entry.max) and (entry.max_pct is None or pct <= entry.max_pct)
    bounds = " and ".join(b for b in (f"{entry.max:g}" if entry.max is not None else "",
                                      f"{entry.max_pct:g} %" if entry.max_pct is not None else "") if b)
    return _result(entry, ok, f"{count} overruns ({pct:.2f} % of {summary.periods} periods) "
                              f"{'within' if ok else 'beyond'} {bounds}", float(count),
                   entry.max if entry.max is not None else entry.max_pct)


#: each run kind's judge
_RUN_JUDGES: dict[str, Callable[[CheckEntry, "Summary", Columns], CheckResult | _Pending]] = {
    "speed_error": _speed_error, "settling_time": _settling_time, "peak_current": _peak_current,
    "speed_limit": _speed_limit, "signal": _signal, "no_fault": _no_fault, "overruns": _overruns,
}
assert tuple(_RUN_JUDGES) == RUN_KINDS


def _max_abs(entry: CheckEntry, what: str, peak: RunningPeak, bound: float, unit: str, window: str) -> CheckResult:
    if not peak.found:
        return _result(entry, False, f"no samples over {window}", None, bound)
    ok = peak.value <= bound
    return _result(entry, ok, f"max {what} {peak.value:.4g} {unit} at {peak.t_s:.4f} s over {window} "
                              f"{'<=' if ok else '>'} {bound:g} {unit}", peak.value, bound)


def _within(entry: CheckEntry, name: str, worst: RunningPeak, window: str) -> CheckResult:
    if not worst.found:
        return _result(entry, False, f"no samples over {window}", None, None)
    ok = worst.key <= 0.0
    limits = f"[{'' if entry.min is None else format(entry.min, 'g')}, {'' if entry.max is None else format(entry.max, 'g')}]"
    return _result(entry, ok, f"{name} worst {worst.value:.4g} at {worst.t_s:.4f} s over {window} "
                              f"{'within' if ok else 'outside'} {limits}", worst.value, entry.max if entry.max is not None else entry.min)


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
