"""PNG plots of a recording (the `plot` extra: matplotlib).

One figure per question an engineer asks of a run: did the speed follow the reference, what did
the currents do, what did the firmware command, did the halls and sectors sequence right, how
did the link keep time.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hilbench.bench.recorder import RecordingData
from hilbench.errors import HilbenchError


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


def _line_figure(plt, t, columns, series, ylabel: str, title: str):  # type: ignore[no-untyped-def]
    """One axis of lines against time: (column, label, line style) per series."""
    fig, ax = plt.subplots(figsize=(10, 4.5))
    for name, label, style in series:
        ax.plot(t, columns[name], label=label, **style)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    return fig


def plot_recording(data: RecordingData, out_dir: Path, stem: str | None = None) -> list[Path]:
    """Write the standard plots of a recording into ``out_dir``; returns their paths."""
    plt = _pyplot()
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = stem or data.path.name.split(".")[0]
    c = data.columns
    t = c["t_s"]
    written: list[Path] = []

    def save(fig, name: str) -> None:  # type: ignore[no-untyped-def]
        path = out_dir / f"{stem}_{name}.png"
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)

    speeds = [("ref_speed_rpm", "reference (firmware)", {"lw": 1.2, "color": "k", "ls": "--"}),
              ("speed_rpm", "speed (plant)", {"lw": 1.0})]
    if "measured_speed_rpm" in c and not np.all(np.isnan(c["measured_speed_rpm"])):
        speeds.append(("measured_speed_rpm", "speed (firmware measured)", {"lw": 0.8, "alpha": 0.8}))
    save(_line_figure(plt, t, c, speeds, "speed [rpm]", "speed vs reference"), "speed")
    from hilbench.bench.recorder import COLUMN_NAMES

    own = [name for name in c if name not in COLUMN_NAMES]  # the target's own telemetry columns
    if own:
        lines = [(name, f"{name} [{data.units.get(name, '')}]", {"lw": 0.8}) for name in own]
        save(_line_figure(plt, t, c, lines, "value", "target telemetry"), "telemetry")
    currents = [(name, label, {"lw": 0.6}) for name, label in (("ia_a", "i_a"), ("ib_a", "i_b"), ("ic_a", "i_c"))]
    currents.append(("ibus_a", "i_bus", {"lw": 0.8, "color": "k"}))
    save(_line_figure(plt, t, c, currents, "current [A]", "phase and bus currents"), "currents")
    duties = [(name, name, {"lw": 0.6}) for name in ("duty_a", "duty_b", "duty_c")]
    save(_line_figure(plt, t, c, duties, "duty [counts]", "PWM duties from the target"), "duties")

    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(10, 5), sharex=True)
    ax1.step(t, c["hall"], where="post", lw=0.8)
    ax1.set_ylabel("hall CBA")
    ax2.step(t, c["sector"], where="post", lw=0.8, color="C1")
    ax2.set_ylabel("sector")
    ax2.set_xlabel("time [s]")
    ax1.set_title("hall state and firmware sector")
    save(fig, "hall")

    timing = [("rtt_us", "round trip [µs]", {"lw": 0.5}), ("lateness_us", "lateness [µs]", {"lw": 0.5})]
    fig = _line_figure(plt, t, c, timing, "µs", "link timing (real-time runs; zero in lockstep)")
    fig.axes[0].set_yscale("symlog")
    save(fig, "link")
    return written


def plot_overlay(curves: list[tuple[str, np.ndarray, np.ndarray]], reference: tuple[np.ndarray, np.ndarray] | None, path: Path, title: str) -> Path:
    """Several speed responses on one axis (step comparisons)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(10, 4.5))
    if reference is not None:
        ax.plot(reference[0], reference[1], color="k", ls="--", lw=1.0, label="reference")
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
