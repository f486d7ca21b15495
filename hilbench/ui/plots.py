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

    fig, ax = plt.subplots(figsize=(10, 4.5))
    ax.plot(t, c["ref_speed_rpm"], label="reference (firmware)", lw=1.2, color="k", ls="--")
    ax.plot(t, c["speed_rpm"], label="speed (plant)", lw=1.0)
    if not np.all(np.isnan(c["measured_speed_rpm"])):
        ax.plot(t, c["measured_speed_rpm"], label="speed (firmware measured)", lw=0.8, alpha=0.8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("speed [rpm]")
    ax.set_title("speed vs reference")
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    save(fig, "speed")

    fig, ax = plt.subplots(figsize=(10, 4.5))
    for name, label in (("ia_a", "i_a"), ("ib_a", "i_b"), ("ic_a", "i_c")):
        ax.plot(t, c[name], lw=0.6, label=label)
    ax.plot(t, c["ibus_a"], lw=0.8, color="k", label="i_bus")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("current [A]")
    ax.set_title("phase and bus currents")
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    save(fig, "currents")

    fig, ax = plt.subplots(figsize=(10, 4.5))
    for name in ("duty_a", "duty_b", "duty_c"):
        ax.plot(t, c[name], lw=0.6, label=name)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("duty [counts]")
    ax.set_title("PWM duties from the target")
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    save(fig, "duties")

    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(10, 5), sharex=True)
    ax1.step(t, c["hall"], where="post", lw=0.8)
    ax1.set_ylabel("hall CBA")
    ax2.step(t, c["sector"], where="post", lw=0.8, color="C1")
    ax2.set_ylabel("sector")
    ax2.set_xlabel("time [s]")
    ax1.set_title("hall state and firmware sector")
    save(fig, "hall")

    fig, ax = plt.subplots(figsize=(10, 4.5))
    ax.plot(t, c["rtt_us"], lw=0.5, label="round trip [µs]")
    ax.plot(t, c["lateness_us"], lw=0.5, label="lateness [µs]")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("µs")
    ax.set_yscale("symlog")
    ax.set_title("link timing (real-time runs; zero in lockstep)")
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
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
