"""PNG plots of a recording (the `plot` extra: matplotlib).

One figure per question an engineer asks of a run: did the speed follow the reference, what did
the currents do, what did the firmware command, did the halls and sectors sequence right, how
did the link keep time.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from hilbench.bench.recorder import RecordingData
from hilbench.errors import ConfigError, HilbenchError


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


#: above this many points in view a trace is drawn as its min/max envelope per bucket
MAX_POINTS = 2000
#: the link plot's log axis starts here (µs): a period answered early is drawn at it
LINK_FLOOR_US = 0.1
#: more hall edges than this in view: the halls are drawn as their edge rate, not as steps
MAX_HALL_EDGES = 400


def parse_window(text: str | None) -> tuple[float, float] | None:
    """`--window T0:T1` (simulated seconds) as (t0, t1)."""
    if text is None:
        return None
    try:
        t0, t1 = (float(x) for x in text.split(":"))
    except ValueError:
        raise ConfigError(f"--window {text!r}: expected T0:T1 in seconds, e.g. 1.0:1.05") from None
    if not t1 > t0:
        raise ConfigError(f"--window {text!r}: T1 must be after T0")
    return t0, t1


def _events(data: RecordingData) -> list[tuple[float, str]]:
    """The recording's events as (t_s, text): "t=1.234500 text" lines."""
    from hilbench.bench.display import parse_event

    return [parsed for parsed in (parse_event(text) for text in data.events) if parsed is not None]


def _trace(ax, t: np.ndarray, y: np.ndarray, label: str, style: dict, offset: float = 0.0,  # type: ignore[no-untyped-def]
           digital: bool = False) -> None:
    """A line, or its min/max envelope per bucket when there are more points than pixels: a 20 kHz
    current over seconds shows its true extent, not a blob of overdrawn lines or aliasing. A
    digital trace (halls, sector) is drawn in steps, and decimated as its band only."""
    from hilbench.bench.display import envelope

    if len(t) <= 2 * MAX_POINTS:
        if digital:
            ax.step(t, y + offset, where="post", label=label, **style)
        else:
            ax.plot(t, y + offset, label=label, **style)
        return
    bucket = -(-len(t) // MAX_POINTS)
    lo, hi = envelope(np.asarray(y, dtype=np.float64), bucket)
    tb = t[::bucket]
    colour = style.get("color")
    if digital:
        band = ax.fill_between(tb, lo + offset, hi + offset, step="post", color=colour, alpha=0.85, lw=0.6, label=label)
        band.set_edgecolor(band.get_facecolor())
        return
    (line,) = ax.plot(tb, (lo + hi) / 2 + offset, label=label, lw=style.get("lw", 0.8) * 0.6,
                      ls=style.get("ls", "-"), color=colour, alpha=0.9)
    ax.fill_between(tb, lo + offset, hi + offset, step="post", color=line.get_color(), alpha=0.35, lw=0)


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


def _line_figure(plt, t, columns, series, ylabel: str, title: str, events=(), label_events=True):  # type: ignore[no-untyped-def]
    """One axis of traces against time: (column, label, line style) per series."""
    fig, ax = plt.subplots(figsize=(10, 4.5))
    for name, label, style in series:
        if name in columns:  # a target may not record every base column
            _trace(ax, t, columns[name], label, style)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    if len(t):
        _mark_events(ax, list(events), float(t[0]), float(t[-1]), label_events)
    ax.legend(loc="best")
    return fig


def _lanes_figure(plt, t, columns, series, title: str, events=()):  # type: ignore[no-untyped-def]
    """One lane per trace, sharing the time axis: three phases decimated over a whole run overlap
    into one block on a single axis; in lanes of their own each keeps its colour and its extent."""
    shown = [(name, label, unit, style) for name, label, unit, style in series if name in columns]
    fig, axes = plt.subplots(len(shown), 1, figsize=(10, 1.3 + 1.25 * len(shown)), sharex=True, squeeze=False)
    for ax, (name, label, unit, style) in zip(axes[:, 0], shown):
        _trace(ax, t, columns[name], label, style)
        ax.set_ylabel(f"{label}\n[{unit}]", fontsize=8)
        ax.grid(alpha=0.3)
        if len(t):
            _mark_events(ax, list(events), float(t[0]), float(t[-1]))
    axes[0, 0].set_title(title)
    axes[-1, 0].set_xlabel("time [s]")
    return fig


def plot_recording(data: RecordingData, out_dir: Path, stem: str | None = None,
                   window: tuple[float, float] | None = None) -> list[Path]:
    """Write the standard plots of a recording into ``out_dir``; returns their paths. ``window``:
    only simulated seconds t0..t1 (every period drawn when it is short enough)."""
    plt = _pyplot()
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = stem or data.path.name.split(".")[0]
    c = _in_window(data.columns, window)
    written: list[Path] = []
    for fig, name in _standard_figures(plt, c, data.units, _events(data)):
        path = out_dir / f"{stem}_{name}.png"
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written


def _in_window(columns: dict[str, np.ndarray], window: tuple[float, float] | None) -> dict[str, np.ndarray]:
    """The rows of simulated seconds t0..t1 (all of them without a window); ConfigError if none."""
    t = columns["t_s"]
    if window is None:
        return columns
    keep = (t >= window[0]) & (t <= window[1])
    if not keep.any():
        raise ConfigError(f"plot window {window[0]:g}..{window[1]:g} s: the recording spans "
                          f"{t[0]:g}..{t[-1]:g} s" if len(t) else "plot window: the recording is empty")
    return {name: values[keep] for name, values in columns.items()}


def _standard_figures(plt, c, units, events):  # type: ignore[no-untyped-def]
    """(figure, name) of each standard plot the columns allow, made one at a time."""
    t = c["t_s"]
    speeds = [("ref_speed_rpm", "reference (firmware)", {"lw": 1.2, "color": "k", "ls": "--"}),
              ("speed_rpm", "speed (plant)", {"lw": 1.0})]
    if "measured_speed_rpm" in c and not np.all(np.isnan(c["measured_speed_rpm"])):
        speeds.append(("measured_speed_rpm", "speed (firmware measured)", {"lw": 0.8, "alpha": 0.8}))
    yield _line_figure(plt, t, c, speeds, "speed [rpm]", "speed vs reference", events), "speed"
    from hilbench.bench.recorder import COLUMN_NAMES
    from hilbench.plant.model import OUTPUTS

    bench_columns = set(COLUMN_NAMES) | {out.column for out in OUTPUTS}  # the bench's and the plant's
    own = [name for name in c if name not in bench_columns]  # the target's own telemetry columns
    if own:
        lines = [(name, f"{name} [{units.get(name, '')}]", {"lw": 0.8}) for name in own]
        yield _line_figure(plt, t, c, lines, "value", "target telemetry", events, False), "telemetry"
    currents = [(name, label, "A", {"lw": 0.6, "color": f"C{k}"})
                for k, (name, label) in enumerate((("ia_a", "i_a"), ("ib_a", "i_b"), ("ic_a", "i_c")))]
    currents.append(("ibus_a", "i_bus", "A", {"lw": 0.8, "color": "k"}))
    if any(name in c for name, *_ in currents):  # (a monitor-mode recording has no plant currents)
        yield _lanes_figure(plt, t, c, currents, "phase and bus currents", events), "currents"
    duties = [(name, name, "counts", {"lw": 0.6, "color": f"C{k}"}) for k, name in enumerate(("duty_a", "duty_b", "duty_c"))]
    yield _lanes_figure(plt, t, c, duties, "PWM duties from the target", events), "duties"
    if "hall" in c and "sector" in c:
        yield _hall_figure(plt, t, c, events), "hall"
    if "rtt_us" in c and "lateness_us" in c and (np.any(np.nan_to_num(c["rtt_us"]) != 0)
                                                 or np.any(np.nan_to_num(c["lateness_us"]) != 0)):
        # a log axis of what is positive: a period answered early (lateness < 0) is on time, drawn at the floor
        floor = LINK_FLOOR_US
        timing_c = {"rtt_us": np.maximum(c["rtt_us"], floor), "lateness_us": np.maximum(c["lateness_us"], floor)}
        timing = [("rtt_us", "round trip [µs]", {"lw": 0.5}),
                  ("lateness_us", f"lateness [µs] (early or on time: at {floor:g})", {"lw": 0.5})]
        fig = _line_figure(plt, t, timing_c, timing, "µs", "link timing (real time)", events, False)  # real time only
        fig.axes[0].set_yscale("log")
        fig.axes[0].set_ylim(bottom=floor * 0.8)
        yield fig, "link"


def _hall_figure(plt, t, c, events):  # type: ignore[no-untyped-def]
    """Halls as three digital traces (bit 0 = A), the firmware's sector below."""
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(10, 5), sharex=True, gridspec_kw={"height_ratios": [3, 2]})
    hall = np.clip(np.nan_to_num(c["hall"], nan=0.0, posinf=0.0, neginf=0.0), 0, 7).astype(np.int64)
    edges = np.flatnonzero(np.diff(hall) != 0) + 1
    if len(edges) > MAX_HALL_EDGES:  # steps would be a solid bar: the edge rate, and invalid codes
        _hall_rate(ax1, t, edges, hall)
    else:
        for bit, name in enumerate(("A", "B", "C")):
            _trace(ax1, t, ((hall >> bit) & 1).astype(np.float64) * 0.8, f"hall {name}", {"lw": 0.8, "color": f"C{bit}"},
                   offset=1.2 * bit, digital=True)
        ax1.set_yticks([0.4, 1.6, 2.8], ["A", "B", "C"])
        ax1.set_ylabel("hall")
    sector = np.nan_to_num(c["sector"], nan=7.0).astype(np.int64)
    changes = np.flatnonzero(np.diff(sector) != 0) + 1
    if len(changes) > MAX_HALL_EDGES:  # as dense as the halls: its rate, and the out-of-sequence jumps
        _sector_rate(ax2, t, changes, sector)
    else:
        _trace(ax2, t, c["sector"], "sector", {"lw": 0.8, "color": "C3"}, digital=True)
        ax2.set_ylabel("sector")
    ax2.set_xlabel("time [s]")
    ax1.set_title("hall signals and firmware sector")
    if len(t):
        for ax in (ax1, ax2):
            _mark_events(ax, events, float(t[0]), float(t[-1]))
    return fig


def _hall_rate(ax, t, edges, hall) -> None:  # type: ignore[no-untyped-def]
    """Too many hall edges to draw as steps: edges per second over ~200 bins (6 an electrical
    revolution), and every period with an invalid code (0 or 7) as a red tick."""
    span = float(t[-1] - t[0]) or 1.0
    bins = np.linspace(float(t[0]), float(t[-1]), 201)
    counts, _ = np.histogram(t[edges], bins=bins)
    ax.step(bins[:-1], counts / (span / 200), where="post", color="C0", lw=0.9, label="hall edges per second")
    bad = np.flatnonzero((hall == 0) | (hall == 7))
    if bad.size:
        ax.plot(t[bad], np.zeros(bad.size), "|", color="tab:red", ms=8, label=f"invalid hall code ({bad.size} periods)")
    ax.set_ylabel("hall edges / s")
    ax.legend(loc="upper right", fontsize=7)
    ax.text(0.01, 0.97, f"{len(edges)} edges: too many to draw as steps (report --window T0:T1 shows them)",
            transform=ax.transAxes, va="top", fontsize=7, color="0.35")


def _sector_rate(ax, t, changes, sector) -> None:  # type: ignore[no-untyped-def]
    """Too many sector changes to draw as steps: changes per second, and every change that is not
    to a neighbouring sector (a skipped or invalid one, 7) as a red tick."""
    span = float(t[-1] - t[0]) or 1.0
    bins = np.linspace(float(t[0]), float(t[-1]), 201)
    counts, _ = np.histogram(t[changes], bins=bins)
    ax.step(bins[:-1], counts / (span / 200), where="post", color="C3", lw=0.9, label="sector changes per second")
    before, after = sector[changes - 1], sector[changes]
    jump = ((after - before) % 6 != 1) & ((before - after) % 6 != 1) | (after > 5) | (before > 5)
    if jump.any():
        ax.plot(t[changes[jump]], np.zeros(int(jump.sum())), "|", color="tab:red", ms=8,
                label=f"out-of-sequence changes ({int(jump.sum())})")
    ax.set_ylabel("sector changes / s")
    ax.legend(loc="upper right", fontsize=7)


def plot_speed_overlay(recordings: Sequence[RecordingData], out_dir: Path,
                       window: tuple[float, float] | None = None) -> Path:
    """The speed of several recordings on one time axis (a HIL run and a real-motor run of the same
    scenario): each one's measured speed (the firmware's; a HIL run's plant speed too) and the first
    one's reference. The recordings share the column names and units, whatever their mode."""
    curves: list[tuple[str, np.ndarray, np.ndarray]] = []
    reference: tuple[np.ndarray, np.ndarray] | None = None
    for data in recordings:
        c = _in_window(data.columns, window)
        mode = str(data.metadata.get("mode", "")) or "run"
        name = f"{data.path.name} ({mode})"
        for column, what in (("measured_speed_rpm", "firmware measured"), ("speed_rpm", "plant")):
            if column in c and not np.all(np.isnan(c[column])):
                curves.append((f"{name}: {what}", c["t_s"], c[column]))
        if reference is None and "ref_speed_rpm" in c:
            reference = (c["t_s"], c["ref_speed_rpm"])
    stem = recordings[0].path.name.split(".")[0]
    return plot_overlay(curves, reference, out_dir / f"{stem}_overlay_speed.png",
                        "speed: " + " vs ".join(d.path.name for d in recordings), "reference (firmware, first)")


def plot_overlay(curves: list[tuple[str, np.ndarray, np.ndarray]], reference: tuple[np.ndarray, np.ndarray] | None, path: Path, title: str,
                 reference_label: str = "reference") -> Path:
    """Several speed responses on one axis (step comparisons)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(10, 4.5))
    if reference is not None:
        ax.plot(reference[0], reference[1], color="k", ls="--", lw=1.0, label=reference_label)
    for label, t, y in curves:
        ax.plot(t, y, lw=1.0, label=label)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("speed [rpm]")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
