"""Issue 23 (the suite under load): lockstep is the host's clock, so a host that pauses between
periods (a loaded machine, a script between two `run` calls) must not change the recording. A
firmware build whose watchdog stopped the firmware tripped 1.3 s into a suite run beside two
CPU-bound processes and its recording differed. Now the watchdog runs in lockstep too (issues 24,
27: a host killed turns the outputs off), but a lockstep trip leaves the firmware's state alone:
the pause below trips it, and the recording is still the model's."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

import hilbench
from _firmware import require_tool
from hilbench.bench.recorder import read_recording

#: longer than the firmware runtime's lockstep watchdog floor (HRT_LOCKSTEP_WATCHDOG_MIN_MS = 1000)
PAUSE_S = 1.5


def _record(target: str, path: Path, pause_s: float) -> int:
    """Record 0.05 s, pause, 0.05 s more; the target's watchdog trips (its Status), when it has one."""
    with hilbench.Bench(target=target, record=path) as bench:
        bench.set_reference(1000)
        bench.press("s2")
        bench.run(0.05)
        threading.Event().wait(pause_s)  # the host pauses: the stimulus, not a wait for anything
        bench.run(0.05)
        remote = bench._parts.handle.target  # type: ignore[union-attr]  # noqa: SLF001 - the firmware's own counters
        return int(remote.status().watchdog_trips) if hasattr(remote, "status") else 0


@pytest.mark.slow
def test_a_host_pausing_in_lockstep_changes_nothing(tmp_path: Path) -> None:
    require_tool("gcc", "the SIL build of the AN1017 firmware")
    assert _record("sil:an1017", tmp_path / "paused.npz", PAUSE_S) >= 1  # the watchdog tripped in the pause
    _record("inprocess:an1017", tmp_path / "model.npz", 0.0)
    paused, model = read_recording(tmp_path / "paused.npz"), read_recording(tmp_path / "model.npz")
    for name, column in model.columns.items():
        if name not in ("rtt_us", "lateness_us"):
            np.testing.assert_array_equal(paused.columns[name], column, err_msg=name)
