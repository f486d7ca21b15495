"""PNG plots of a recording (the `plot` extra: matplotlib).

One figure per question an engineer asks of a run: did the speed follow the reference, what did
the currents do, what did the firmware command, did the halls and sectors sequence right, how
did the link keep time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from hilbench.bench.column_chunks import ArrayChunks, ColumnChunks
from hilbench.bench.recorder import RecordingData
from hilbench.bench.recording_head import RecordingHead
from hilbench.config import clipped
from hilbench.errors import ConfigError, HilbenchError
from hilbench.ui.plot_data import MAX_POINTS, Rate, RecordingView, Trace, view, whole_trace


class PlotUnavailable(HilbenchError):
    """matplotlib is not installed."""

    exit_code = 2
    kind = "plot"


def _pyplot():  # type: ignore[no-untyped-def]
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise PlotUnavailable("plots need matplotlib: pip install 'hilbench[plot]'") from None
    return plt


#: the link plot's log axis starts here (µs): a period answered early is drawn at it
LINK_FLOOR_US = 0.1
#: more hall edges than this in view: the halls are drawn as their edge rate, not as steps
MAX_HALL_EDGES = 400


@dataclass(frozen=True)
class Plots:
    """The PNGs written (iterates as their paths), and each standard figure the recording's columns
    could not draw, as "what (no column, ...)": a monitor-mode or custom-firmware layout may lack the
    plant's currents or the duties, and its plots must still be drawn and say so."""

    paths: tuple[Path, ...]
    left_out: tuple[str, ...] = ()

    def __iter__(self) -> Iterator[Path]:
        return iter(self.paths)

    def __len__(self) -> int:
        return len(self.paths)

    def note(self) -> str | None:
        """One line naming what was left out, or None when every figure was drawn in full."""
        return "plots left out: " + "; ".join(self.left_out) if self.left_out else None


def parse_window(text: str | None) -> tuple[float, float] | None:
    """`--window T0:T1` (simulated seconds) as (t0, t1)."""
    if text is None:
        return None
    shown = clipped(repr(text), 60)
    try:
        t0, t1 = (float(x) for x in text.split(":"))
    except ValueError:
        raise ConfigError(f"--window {shown}: expected T0:T1 in seconds, e.g. 1.0:1.05") from None
    if not (math.isfinite(t0) and math.isfinite(t1)):
        raise ConfigError(f"--window {shown}: T0 and T1 must be finite numbers of seconds")
    if not t1 > t0:
        raise ConfigError(f"--window {shown}: T1 must be after T0")
    return t0, t1


def _events(events: Sequence[str]) -> list[tuple[float, str]]:
    """The recording's events as (t_s, text): "t=1.234500 text" lines."""
    from hilbench.bench.display import parse_event

    return [parsed for parsed in (parse_event(text) for text in events) if parsed is not None]


def _trace(ax, t: np.ndarray, y: np.ndarray, label: str, style: dict, offset: float = 0.0,  # type: ignore[no-untyped-def]
           digital: bool = False) -> None:
    """A line of arrays in memory, decimated as `_draw` draws it."""
    _draw(ax, whole_trace(t, y), label, style, offset, digital)


def _draw(ax, trace: Trace, label: str, style: dict, offset: float = 0.0,  # type: ignore[no-untyped-def]
          digital: bool = False) -> None:
    """A line, or its min/max envelope per bucket when there are more points than pixels: a 20 kHz
    current over seconds shows its true extent, not a blob of overdrawn lines or aliasing. A
    digital trace (halls, sector) is drawn in steps, and decimated as its band only."""
    t, lo, hi = trace.t_s, trace.lo, trace.hi
    if hi is None:
        if digital:
            ax.step(t, lo + offset, where="post", label=label, **style)
        else:
            ax.plot(t, lo + offset, label=label, **style)
        return
    colour = style.get("color")
    if digital:
        band = ax.fill_between(t, lo + offset, hi + offset, step="post", color=colour, alpha=0.85, lw=0.6, label=label)
        band.set_edgecolor(band.get_facecolor())
        return
    (line,) = ax.plot(t, (lo + hi) / 2 + offset, label=label, lw=style.get("lw", 0.8) * 0.6,
                      ls=style.get("ls", "-"), color=colour, alpha=0.9)
    ax.fill_between(t, lo + offset, hi + offset, step="post", color=line.get_color(), alpha=0.35, lw=0)


def _mark_events(ax, events: list[tuple[float, str]], t0: float, t1: float, label: bool = False) -> None:  # type: ignore[no-untyped-def]
    """Event markers: a dotted vertical line each (with its text on the first axis)."""
    groups: list[tuple[float, list[str]]] = []  # events closer than 1/200 of the span share a label
    for t_s, text in sorted(e for e in events if t0 <= e[0] <= t1):
        if groups and t_s - groups[-1][0] < (t1 - t0) / 200:
            groups[-1][1].append(text)
        else:
            groups.append((t_s, [text]))
    for t_s, texts in groups:
        joined = "; ".join(texts)
        colour = "tab:red" if "fault" in joined or "guard" in joined else ("tab:green" if any(x.startswith("set ") for x in texts) else "0.45")
        ax.axvline(t_s, color=colour, lw=0.7, ls=":", alpha=0.9)
        if label:
            ax.text(t_s, 0.98, " " + (joined if len(joined) <= 48 else joined[:47] + "…"), transform=ax.get_xaxis_transform(),
                    rotation=90, va="top", ha="left", fontsize=6.5, color=colour, alpha=0.9, clip_on=True)


def _line_figure(plt, v: RecordingView, traces: dict[str, Trace], series, ylabel: str, title: str,  # type: ignore[no-untyped-def]
                 events=(), label_events=True):
    """One axis of traces against time: (column, label, line style) per series."""
    fig, ax = plt.subplots(figsize=(10, 4.5))
    for name, label, style in series:
        if name in traces:  # a target may not record every base column
            _draw(ax, traces[name], label, style)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    if v.n_rows:
        _mark_events(ax, list(events), v.t_first_s, v.t_last_s, label_events)
    ax.legend(loc="best")
    return fig


def _lanes_figure(plt, v: RecordingView, series, title: str, events=()):  # type: ignore[no-untyped-def]
    """One lane per trace, sharing the time axis: three phases decimated over a whole run overlap
    into one block on a single axis; in lanes of their own each keeps its colour and its extent."""
    shown = [(name, label, unit, style) for name, label, unit, style in series if name in v.traces]
    fig, axes = plt.subplots(len(shown), 1, figsize=(10, 1.3 + 1.25 * len(shown)), sharex=True, squeeze=False)
    for ax, (name, label, unit, style) in zip(axes[:, 0], shown):
        _draw(ax, v.traces[name], label, style)
        ax.set_ylabel(f"{label}\n[{unit}]", fontsize=8)
        ax.grid(alpha=0.3)
        if v.n_rows:
            _mark_events(ax, list(events), v.t_first_s, v.t_last_s)
    axes[0, 0].set_title(title)
    axes[-1, 0].set_xlabel("time [s]")
    return fig


def plot_recording(data: RecordingData, out_dir: Path, stem: str | None = None,
                   window: tuple[float, float] | None = None) -> Plots:
    """Write the standard plots of a recording in memory into ``out_dir``."""
    head = RecordingHead(data.path, data.metadata, data.events, data.units, data.formats)
    return plot_recording_chunks(head, ArrayChunks(data.columns, data.units), out_dir, stem, window)


def plot_recording_chunks(head: RecordingHead, source: ColumnChunks, out_dir: Path, stem: str | None = None,
                          window: tuple[float, float] | None = None) -> Plots:
    """Write the standard plots of a recording into ``out_dir``, its rows read a chunk at a time:
    each figure the columns allow, and what they did not. ``window``: only simulated seconds t0..t1
    (every period drawn when it is short enough)."""
    plt = _pyplot()
    stem = stem or head.path.name.split(".")[0]
    v = view(source, _plotted_columns(source.names), window, LINK_FLOOR_US)
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    left_out: list[str] = []
    for fig, name in _standard_figures(plt, v, source.names, head.units, _events(head.events), left_out):
        path = out_dir / f"{stem}_{name}.png"
        fig.tight_layout()
        save_png(fig, path)
        plt.close(fig)
        written.append(path)
    return Plots(tuple(written), tuple(left_out))


#: the formats a plot file's suffix may ask for (none: PNG)
PLOT_FORMATS = ("png", "pdf", "svg")


def save_png(fig, path: Path) -> None:  # type: ignore[no-untyped-def]
    """The figure at ``path`` in the format its suffix names (PLOT_FORMATS; PNG without one), drawn
    first and written in one piece (`open_output`: never onto a running session's recording, even
    through a symlink; a FIFO takes it as a file does)."""
    import io

    from hilbench.bench.outputs import open_output

    image = io.BytesIO()
    suffix = path.suffix[1:].lower()
    fig.savefig(image, format=suffix if suffix in PLOT_FORMATS else "png", dpi=110)
    with open_output(path, binary=True) as handle:
        handle.write(image.getvalue())


_SPEEDS = ("ref_speed_rpm", "speed_rpm", "measured_speed_rpm")
_CURRENTS = ("ia_a", "ib_a", "ic_a", "ibus_a")
_DUTIES = ("duty_a", "duty_b", "duty_c")


def _own_columns(names: Sequence[str]) -> list[str]:
    """The target's own telemetry columns (not the bench's nor the plant's)."""
    from hilbench.bench.recorder import COLUMN_NAMES
    from hilbench.plant.model import OUTPUTS

    bench_columns = set(COLUMN_NAMES) | {out.column for out in OUTPUTS}
    return [name for name in names if name not in bench_columns]


def _plotted_columns(names: Sequence[str]) -> list[str]:
    return [*_SPEEDS, *_own_columns(names), *_CURRENTS, *_DUTIES, "hall", "sector", "rtt_us", "lateness_us"]


def _missing(what: str, wanted: Sequence[str], names: Sequence[str]) -> str | None:
    """"what (no a, b)" for the columns of ``wanted`` the recording lacks; None when it has them all."""
    lacking = [name for name in wanted if name not in names]
    return f"{what} (no {', '.join(lacking)})" if lacking else None


def _standard_figures(plt, v: RecordingView, names: Sequence[str], units, events,  # type: ignore[no-untyped-def]
                      left_out: list[str]):
    """(figure, name) of each standard plot the columns allow, made one at a time; a figure whose
    columns are all missing is left out, and a lane missing from one that is drawn, named in ``left_out``."""
    c = v.traces
    speeds = [("ref_speed_rpm", "reference (firmware)", {"lw": 1.2, "color": "k", "ls": "--"}),
              ("speed_rpm", "speed (plant)", {"lw": 1.0})]
    if "measured_speed_rpm" in c and v.has_values["measured_speed_rpm"]:
        speeds.append(("measured_speed_rpm", "speed (firmware measured)", {"lw": 0.8, "alpha": 0.8}))
    if any(name in c for name, *_ in speeds):
        yield _line_figure(plt, v, c, speeds, "speed [rpm]", "speed vs reference", events), "speed"
    else:
        left_out.append(_missing("speed", _SPEEDS, names) or "speed")
    own = [name for name in _own_columns(names) if name != "t_s"]
    if own:
        lines = [(name, f"{name} [{units.get(name, '')}]", {"lw": 0.8}) for name in own]
        yield _line_figure(plt, v, c, lines, "value", "target telemetry", events, False), "telemetry"
    currents = [(name, label, "A", {"lw": 0.6, "color": f"C{k}"})
                for k, (name, label) in enumerate((("ia_a", "i_a"), ("ib_a", "i_b"), ("ic_a", "i_c")))]
    currents.append(("ibus_a", "i_bus", "A", {"lw": 0.8, "color": "k"}))
    duties = [(name, name, "counts", {"lw": 0.6, "color": f"C{k}"}) for k, name in enumerate(_DUTIES)]
    for what, lanes, title in (("currents", currents, "phase and bus currents"),
                               ("duties", duties, "PWM duties from the target")):
        missing = _missing(what, [name for name, *_ in lanes], names)
        if missing is not None:
            left_out.append(missing)
        if any(name in c for name, *_ in lanes):  # (a monitor-mode recording has no plant currents)
            yield _lanes_figure(plt, v, lanes, title, events), what
    if v.hall is not None:
        yield _hall_figure(plt, v, events), "hall"
    else:
        left_out.append(_missing("hall", ("hall", "sector"), names) or "hall")
    link = _missing("link", ("rtt_us", "lateness_us"), names)
    if link is not None:
        left_out.append(link)
    elif v.nonzero["rtt_us"] or v.nonzero["lateness_us"]:
        # a log axis of what is positive: a period answered early (lateness < 0) is on time, drawn at the floor
        floor = LINK_FLOOR_US
        timing = [("rtt_us", "round trip [µs]", {"lw": 0.5}),
                  ("lateness_us", f"lateness [µs] (early or on time: at {floor:g})", {"lw": 0.5})]
        fig = _line_figure(plt, v, c, timing, "µs", "link timing (real time)", events, False)  # real time only
        fig.axes[0].set_yscale("log")
        fig.axes[0].set_ylim(bottom=floor * 0.8)
        yield fig, "link"


def _hall_figure(plt, v: RecordingView, events):  # type: ignore[no-untyped-def]
    """Halls as three digital traces (bit 0 = A), the firmware's sector below."""
    assert v.hall is not None and v.sector is not None
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(10, 5), sharex=True, gridspec_kw={"height_ratios": [3, 2]})
    if v.hall.count > MAX_HALL_EDGES:  # steps would be a solid bar: the edge rate, and invalid codes
        _rate(ax1, v, v.hall, "hall edges", "C0", "invalid hall code ({count} periods)")
        ax1.text(0.01, 0.97, f"{v.hall.count} edges: too many to draw as steps (report --window T0:T1 shows them)",
                 transform=ax1.transAxes, va="top", fontsize=7, color="0.35")
    else:
        for bit, name in enumerate(("A", "B", "C")):
            _draw(ax1, v.traces[f"hall_{name.lower()}"], f"hall {name}", {"lw": 0.8, "color": f"C{bit}"},
                  offset=1.2 * bit, digital=True)
        ax1.set_yticks([0.4, 1.6, 2.8], ["A", "B", "C"])
        ax1.set_ylabel("hall")
    if v.sector.count > MAX_HALL_EDGES:  # as dense as the halls: its rate, and the out-of-sequence jumps
        _rate(ax2, v, v.sector, "sector changes", "C3", "out-of-sequence changes ({count})")
    else:
        _draw(ax2, v.traces["sector"], "sector", {"lw": 0.8, "color": "C3"}, digital=True)
        ax2.set_ylabel("sector")
    ax2.set_xlabel("time [s]")
    ax1.set_title("hall signals and firmware sector")
    if v.n_rows:
        for ax in (ax1, ax2):
            _mark_events(ax, events, v.t_first_s, v.t_last_s)
    return fig


def _rate(ax, v: RecordingView, rate: Rate, what: str, colour: str, ticks_label: str) -> None:  # type: ignore[no-untyped-def]
    """Too many hall edges or sector changes to draw as steps: ``what`` per second over ~200 bins
    (6 hall edges an electrical revolution), and each of ``rate``'s ticks (a period with an invalid
    hall code, 0 or 7; a sector change not to a neighbour) as a red one, labelled ``ticks_label``
    with its {count}."""
    span = float(v.t_last_s - v.t_first_s) or 1.0
    ax.step(rate.bins[:-1], rate.counts / (span / 200), where="post", color=colour, lw=0.9, label=f"{what} per second")
    if rate.ticks.count:
        ticks = rate.ticks.array()
        ax.plot(ticks, np.zeros(ticks.size), "|", color="tab:red", ms=8, label=ticks_label.format(count=rate.ticks.count))
    ax.set_ylabel(f"{what} / s")
    ax.legend(loc="upper right", fontsize=7)


def plot_speed_overlay(recordings: Sequence[RecordingData], out_dir: Path,
                       window: tuple[float, float] | None = None) -> Plots:
    """`plot_speed_overlay_chunks` of recordings in memory."""
    return plot_speed_overlay_chunks(
        [(RecordingHead(d.path, d.metadata, d.events, d.units, d.formats), ArrayChunks(d.columns, d.units))
         for d in recordings], out_dir, window)


def plot_speed_overlay_chunks(recordings: Sequence[tuple[RecordingHead, ColumnChunks]], out_dir: Path,
                              window: tuple[float, float] | None = None) -> Plots:
    """The speed of several recordings on one time axis (a HIL run and a real-motor run of the same
    scenario): each one's measured speed (the firmware's; a HIL run's plant speed too) and the first
    one's reference. The recordings share the column names and units, whatever their mode. Each
    read a chunk at a time; a curve of more than 2 * MAX_POINTS rows in view drawn as its envelope.
    A recording with no speed to draw is named in the result's ``left_out``."""
    curves: list[tuple[str, Trace]] = []
    reference: Trace | None = None
    left_out: list[str] = []
    for head, source in recordings:
        v = view(source, _SPEEDS, window)
        mode = str(head.metadata.get("mode", "")) or "run"
        name = f"{head.path.name} ({mode})"
        drawn = len(curves)
        for column, what in (("measured_speed_rpm", "firmware measured"), ("speed_rpm", "plant")):
            if column in v.traces and v.has_values[column]:
                curves.append((f"{name}: {what}", v.traces[column]))
        if len(curves) == drawn:
            left_out.append(f"overlay of {head.path.name} (no speed_rpm or measured_speed_rpm with values)")
        if reference is None and "ref_speed_rpm" in v.traces:
            reference = v.traces["ref_speed_rpm"]
    heads = [head for head, _ in recordings]
    stem = heads[0].path.name.split(".")[0]
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(10, 4.5))
    if reference is not None:
        _draw(ax, reference, "reference (firmware, first)", {"color": "k", "ls": "--", "lw": 1.0})
    for label, trace in curves:
        _draw(ax, trace, label, {"lw": 1.0})
    out_dir.mkdir(parents=True, exist_ok=True)  # (the --plot DIR, made as the standard plots make it)
    path = _finish_overlay(plt, fig, ax, "speed: " + " vs ".join(h.path.name for h in heads),
                           out_dir / f"{stem}_overlay_speed.png")
    return Plots((path,), tuple(left_out))


def plot_overlay(curves: list[tuple[str, np.ndarray, np.ndarray]], reference: tuple[np.ndarray, np.ndarray] | None, path: Path, title: str,
                 reference_label: str = "reference") -> Path:
    """Several speed responses on one axis (step comparisons)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(10, 4.5))
    if reference is not None:
        ax.plot(reference[0], reference[1], color="k", ls="--", lw=1.0, label=reference_label)
    for label, t, y in curves:
        ax.plot(t, y, lw=1.0, label=label)
    return _finish_overlay(plt, fig, ax, title, path)


def _finish_overlay(plt, fig, ax, title: str, path: Path) -> Path:  # type: ignore[no-untyped-def]
    ax.set_xlabel("time [s]")
    ax.set_ylabel("speed [rpm]")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:  # (nothing to draw: no empty legend and its warning)
        ax.legend(loc="best")
    fig.tight_layout()
    save_png(fig, path)  # (its folder: the caller's, checked before the work)
    plt.close(fig)
    return path
