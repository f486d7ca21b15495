"""The live dashboard of `hilbench run`: speed, state, duties, currents, gains, link, progress.

The session hands over a Snapshot every few hundred periods; the dashboard redraws at most
``max_fps`` times a second so that drawing never slows the loop it watches.
"""

from __future__ import annotations

import math
import time
from typing import Any

from rich.console import Console, Group
from rich.live import Live
from rich.panel import Panel
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table
from rich.text import Text

from hilbench.bench.history import SpeedHistory
from hilbench.bench.session import Session, Snapshot, Summary
from hilbench.protocol import Fault

STATE_NAMES = {0: "STOPPED", 1: "BOOTSTRAP", 2: "RUNNING", 3: "STALLED", 4: "FAULT"}
OUTPUT_NAMES = {0: "off", 1: "PWM", 2: "low-side on", 3: "?"}
FAULT_NAMES = {int(code): code.name for code in Fault}
SPARK = "▁▂▃▄▅▆▇█"
#: the summary's mode line when the Drives carried the duties predicted over each period (mode PREDICT)
_PREDICTED = ", duties predicted over each period"


def sparkline(values: list[float], width: int = 100) -> str:
    """A one-line chart of the whole series, decimated to ``width`` characters."""
    step = max(1, len(values) // width)
    picked = values[::step][-width:]
    clean = [v for v in picked if not math.isnan(v)]
    if not clean:
        return ""
    lo, hi = min(clean), max(clean)
    span = (hi - lo) or 1.0
    return "".join(" " if math.isnan(v) else SPARK[min(7, int((v - lo) / span * 7.999))] for v in picked)


def _fmt(value: float, spec: str = ".0f") -> str:
    return "—" if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, spec)


def chart_rows(values: list[float], width: int, rows: int) -> list[str]:
    """A chart ``rows`` characters high of the whole series (eighth blocks), top row first."""
    if rows <= 1:
        return [sparkline(values, width)]
    step = max(1, len(values) // width)
    picked = values[::step][-width:]
    clean = [v for v in picked if not math.isnan(v)]
    if not clean:
        return [""] * rows
    lo, hi = min(clean), max(clean)
    span = (hi - lo) or 1.0
    levels = [0 if math.isnan(v) else 1 + int((v - lo) / span * (rows * 8 - 1)) for v in picked]
    return ["".join(" " if h - r * 8 <= 0 else "█" if h - r * 8 >= 8 else SPARK[h - r * 8 - 1] for h in levels)
            for r in range(rows - 1, -1, -1)]


#: below this many terminal rows the dashboard is compact (gains on one line, a one-row chart)
COMPACT_BELOW_ROWS = 32


def render_snapshot(snap: Snapshot, params: dict[str, float], target_label: str, width: int = 100,
                    chart_height: int = 1, compact: bool = False) -> Group:
    """The panels one frame of the dashboard shows (``width``: the terminal's columns; ``chart_height``:
    rows of the speed chart; ``compact``: a small terminal, gains on one line)."""
    outputs_off = snap.output_mode == 0
    motor = Table.grid(padding=(0, 2))
    motor.add_column(style="bold")
    motor.add_column(justify="right")
    motor.add_row("reference", f"{_fmt(snap.ref_rpm)} rpm")
    held = " (held)" if outputs_off else ""
    if compact:
        motor.add_row("speed plant/fw", f"{_fmt(snap.speed_rpm)} / {_fmt(snap.measured_rpm)} rpm{held}")
    else:
        motor.add_row("speed (plant)", f"{_fmt(snap.speed_rpm)} rpm")
        # a stopped firmware keeps its last MeasuredSpeed and duties: show that they do not apply now
        motor.add_row("speed (firmware)", f"{_fmt(snap.measured_rpm)} rpm{held}")
    state = STATE_NAMES.get(snap.state, str(snap.state))
    if snap.fault:  # by name, as the firmware's fault codes say (protocol Fault)
        state += f" ({FAULT_NAMES.get(snap.fault, f'fault {snap.fault}')})"
    style = "bold red" if snap.fault or state.startswith(("FAULT", "STALLED")) else "green" if state == "RUNNING" else ""
    motor.add_row("state", Text(f"{state}, outputs {OUTPUT_NAMES.get(snap.output_mode, '?')}", style=style))
    if not compact:
        motor.add_row("sector / dir", f"{snap.sector} / {'CCW' if snap.direction_ccw else 'CW'}")
    motor.add_row("duties", "— (outputs off)" if outputs_off else " ".join(str(d) for d in snap.duties))
    motor.add_row("i a/b/c", " ".join(f"{i:+.2f}" for i in snap.i_abc) + " A")
    if not compact:
        motor.add_row("i bus", f"{snap.i_bus:+.3f} A")
        for name, value in snap.telemetry.items():  # the target's own telemetry, as its profile names it
            if name not in ("measured_speed_rpm", "ref_speed_rpm"):
                motor.add_row(name.replace("_", " "), _fmt(value))

    link = Table.grid(padding=(0, 2))
    link.add_column(style="bold")
    link.add_column(justify="right")
    link.add_row("periods/s", f"{snap.periods_per_s:,.0f}")
    link.add_row("RTT p50/p99", f"{_fmt(snap.rtt_p50_us, '.0f')}/{_fmt(snap.rtt_p99_us, '.0f')} µs")
    for key in ("crc_errors", "timeouts", "resyncs", "seq_gaps"):
        if key in snap.link and (snap.link[key] or not compact):
            link.add_row(key.replace("_", " "), str(snap.link[key]))
    link.add_row("overruns", str(snap.overruns))
    if not compact:
        for name, value in params.items():
            link.add_row(name, f"{value:.5g}")

    grid = Table.grid(expand=True)
    grid.add_column(ratio=1)
    grid.add_column(ratio=1)
    grid.add_row(Panel(motor, title="motor"), Panel(link, title="link" if compact else "link & gains"))
    history = snap.history  # the session's ring: one column, not a tuple per sample
    speeds = history.column("plant_rpm") if isinstance(history, SpeedHistory) else [h[2] for h in history]
    clean = [v for v in speeds if not math.isnan(v)]
    scale = f": {min(clean):.0f} … {max(clean):.0f} rpm" if clean else ""
    title = (f"speed (plant), the last {snap.history[-1][0] - snap.history[0][0]:.1f} s{scale}"
             if snap.history else "speed (plant)")
    parts: list[Any] = [grid]
    if compact:
        if params:
            parts.append(Text("gains: " + "  ".join(f"{k} {v:.5g}" for k, v in params.items())))
        parts.append(Text(title, style="dim", no_wrap=True, overflow="ellipsis"))
        parts.append(Text(sparkline(speeds, width=max(10, width)), style="cyan", no_wrap=True, overflow="crop"))
    else:
        chart = Text("\n".join(chart_rows(speeds, max(10, width - 4), max(1, chart_height))), style="cyan")
        parts.append(Panel(chart, title=title))
    if snap.messages:
        parts.append(Text("\n".join(snap.messages[-2:]), style="yellow", no_wrap=True, overflow="ellipsis"))
    return Group(*parts)


def _two_lines(text: str, width: int) -> str:
    """A line cut to at most two terminal rows (the rest as an ellipsis)."""
    limit = max(20, 2 * width - 1)
    return text if len(text) <= limit else text[: limit - 1] + "…"


class Dashboard:
    """A rich Live view fed by the session's observer callback."""

    def __init__(self, target_label: str, duration_s: float | None, console: Console | None = None, max_fps: float = 8.0) -> None:
        self.console = console or Console(stderr=False)
        self.target_label = target_label
        self.params: dict[str, float] = {}
        self.min_interval_s = 1.0 / max_fps
        self._last = 0.0
        self.progress = Progress(
            TextColumn("[bold]simulated"),
            BarColumn(),
            TextColumn("{task.completed:.2f}/{task.total:.2f} s"),
            TimeElapsedColumn(),
            console=self.console,
        )
        self.task = self.progress.add_task("run", total=duration_s or 1.0)
        self.command_line: Any = None  # hilbench.ui.keys.CommandLine, when the terminal can type
        self.replies: list[str] = []
        self.warnings: list[str] = []  # the run's start-up warnings: kept at the top of every frame
        self.live = Live(console=self.console, refresh_per_second=max_fps, transient=False)

    def attach(self, session: Session) -> None:
        """Show the session's parameters and follow every change (ctl, scenario, guard)."""
        self.params = session.param_values()
        session.on_params = self.params.update

    def __enter__(self) -> "Dashboard":
        self.live.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self.live.__exit__(*exc)  # type: ignore[arg-type]

    def __call__(self, snap: Snapshot) -> None:
        now = time.perf_counter()
        if now - self._last < self.min_interval_s:
            return
        self._last = now
        self.progress.update(self.task, completed=snap.t_s, total=snap.duration_s)
        self.live.update(self.frame(snap))

    def frame(self, snap: Snapshot) -> Group:
        """One frame laid out for the terminal's size: the title and start-up warnings on top, the
        progress, the command line's replies and prompt at the bottom (never cropped), the panels
        between; a small terminal gets the compact panels, a tall one a taller speed chart."""
        width, height = self.console.width, self.console.height
        head: list[Any] = [Text(f"hilbench run — {self.target_label}", style="bold", no_wrap=True, overflow="ellipsis")]
        head += [Text(_two_lines(f"warning: {w}", width), style="yellow") for w in self.warnings[-2:]]
        foot: list[Any] = [self.progress]
        if self.command_line is not None and self.command_line.active:
            from hilbench.ui.keys import PROMPT_HELP

            replies = self.replies[-(1 if height < 28 else 3):]
            foot.append(Text("\n".join(_two_lines(r, width) for r in replies), style="cyan"))
            foot.append(Text(f"> {self.command_line.buffer}_" if self.command_line.buffer else PROMPT_HELP,
                             style="dim", no_wrap=True, overflow="ellipsis"))
        compact = height < COMPACT_BELOW_ROWS
        used = sum(len(self.console.render_lines(p, self.console.options.update(width=width), pad=False))
                   for p in head + foot)
        grid_rows = max(11, 4 + len(self.params)) + 2  # the taller of the motor and link panels, with borders
        chart_height = 1 if compact else max(1, min(24, height - used - grid_rows - 2 - 2 - 1))  # its border, messages
        body = render_snapshot(snap, self.params, self.target_label, width, chart_height=chart_height, compact=compact)
        return Group(*head, body, *foot)


def summary_table(summary: Summary) -> Group:
    """The end-of-run summary: how each reference was followed, link and timing figures."""
    head = Table(title=f"hilbench run — {summary.target}", show_header=False, box=None)
    head.add_row("mode", f"{summary.mode}, period {summary.period_us} µs{_PREDICTED if summary.predicted_duties else ''}")
    head.add_row("ended", summary.end_reason + (f": {summary.fault}" if summary.fault else ""))
    head.add_row("simulated", f"{summary.sim_s:.3f} s in {summary.periods:,} periods")
    head.add_row("wall", f"{summary.wall_s:.2f} s ({summary.realtime_factor:.2f}× real time)")
    if summary.rtt_us:
        head.add_row("RTT", f"p50 {summary.rtt_us['p50']:.0f} µs, p99 {summary.rtt_us['p99']:.0f} µs, max {summary.rtt_us['max']:.0f} µs")
    if summary.lateness_us:
        lat = summary.lateness_us
        head.add_row("lateness", f"p50 {lat['p50']:.1f} µs, p99 {lat['p99']:.1f} µs, max {lat['max']:.0f} µs; {_overruns_text(summary)}")
    if summary.cpu_latency:
        head.add_row("CPU wake-up", summary.cpu_latency)
    if summary.cpus:
        head.add_row("CPUs", summary.cpus)
    if summary.link:
        head.add_row("link", ", ".join(f"{k} {v}" for k, v in summary.link.items()))
    if "speculative_periods" in summary.link:
        head.add_row("speculative", _speculative_text(summary))
    if summary.params:
        head.add_row("parameters", ", ".join(f"{k} {v:.5g}" for k, v in summary.params.items()))
    if summary.recording:
        head.add_row("recording", f"{summary.recording} ({summary.rows_recorded:,} rows)")
    for warning in summary.warnings:
        head.add_row("[yellow]warning[/]", warning)
    seg = Table(title="steady state per reference (last 30 % of each hold)")
    for col in ("from [s]", "to [s]", "reference [rpm]", "plant [rpm]", "firmware [rpm]", "error [%]", "within 2 %"):
        seg.add_column(col, justify="right")
    for s in summary.segments:
        ok = abs(s.error_pct) <= 2.0
        seg.add_row(
            f"{s.t_start_s:.2f}", f"{s.t_end_s:.2f}", f"{s.ref_rpm:.0f}", f"{s.plant_rpm:.1f}",
            _fmt(s.measured_rpm, ".1f"), f"{s.error_pct:+.2f}", "[green]yes[/]" if ok else "[red]no[/]",
        )
    return Group(head, seg) if summary.segments else Group(head)


def _speculative_text(summary: Summary) -> str:
    """Twin-speculative lockstep's share of the run and its rate (hilbench.bench.speculative)."""
    link = summary.link
    if not link["speculative_periods"]:  # twin = auto, but the run went per period: say why
        if summary.predicted_duties:
            return ("off: the duties were predicted over each period (mode PREDICT, a period of 2 PWM periods "
                    "or more) and the twin does not predict; --set link.predict_duties=false to speculate")
        if link.get("speculative_alone"):
            return (f"off: every period went alone ({link['speculative_alone']}: each one's record larger than the "
                    "batches the target takes)")
        return "off: the target took no batch (one exchange a period)"
    alone = f", {link['speculative_alone']} alone" if link.get("speculative_alone") else ""
    return (f"{link['speculative_periods']} of {summary.periods} periods confirmed by the target's digests "
            f"in {link['speculative_batches']} batches ({link['speculative_resends']} resent{alone}), "
            f"{link['speculative_periods_per_s']} periods/s")


def summary_text(summary: Summary) -> str:
    """The plain summary of --no-ui: one fact per line."""
    lines = [
        f"target: {summary.target}",
        f"mode: {summary.mode}, period {summary.period_us} us{_PREDICTED if summary.predicted_duties else ''}",
        f"ended: {summary.end_reason}" + (f": {summary.fault}" if summary.fault else ""),
        f"simulated: {summary.sim_s:.3f} s, {summary.periods} periods, wall {summary.wall_s:.2f} s, "
        f"{summary.realtime_factor:.2f}x real time",
    ]
    if summary.rtt_us:
        lines.append(f"rtt_us: p50 {summary.rtt_us['p50']:.1f} p99 {summary.rtt_us['p99']:.1f} max {summary.rtt_us['max']:.1f}")
    if summary.lateness_us:
        lat = summary.lateness_us
        lines.append(f"lateness_us: p50 {lat['p50']:.1f} p99 {lat['p99']:.1f} max {lat['max']:.1f}; {_overruns_text(summary)}")
    if summary.cpu_latency:
        lines.append(f"cpu latency request: {summary.cpu_latency}")
    if summary.cpus:
        lines.append(f"cpus: {summary.cpus}")
    if summary.link:
        lines.append("link: " + ", ".join(f"{k} {v}" for k, v in summary.link.items()))
    if "speculative_periods" in summary.link:
        lines.append(f"speculative: {_speculative_text(summary)}")
    if summary.params:  # as the dashboard's table has them (issue 16, item 17)
        lines.append("parameters: " + ", ".join(f"{k} {v:.5g}" for k, v in summary.params.items()))
    for s in summary.segments:
        if summary.mode == "monitor":  # no plant: the motor's speed is what the firmware measures
            lines.append(f"ref {s.ref_rpm:+.0f} rpm [{s.t_start_s:.2f}-{s.t_end_s:.2f} s]: motor (firmware's "
                         f"measurement) {_fmt(s.measured_rpm, '+.1f')} rpm, error {s.error_pct:+.2f} %")
            continue
        lines.append(
            f"ref {s.ref_rpm:+.0f} rpm [{s.t_start_s:.2f}-{s.t_end_s:.2f} s]: plant {s.plant_rpm:+.1f} rpm, "
            f"firmware {_fmt(s.measured_rpm, '+.1f')} rpm, error {s.error_pct:+.2f} %"
        )
    if summary.recording:
        lines.append(f"recording: {summary.recording} ({summary.rows_recorded} rows)")
    lines += [f"warning: {w}" for w in summary.warnings]
    return "\n".join(lines)


def _overruns_text(summary: Summary) -> str:
    """Overruns as a count and a share of periods, with those the host skipped after a stall."""
    share = summary.overruns / max(1, summary.periods)
    skipped = f", {summary.skipped_periods} of them skipped (host stalled a whole period)" if summary.skipped_periods else ""
    return f"overruns {summary.overruns} ({share:.2%}){skipped}"
