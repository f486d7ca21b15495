"""`hilbench step --plot` (issue 22, item 12): the FOC firmware ramps its reference after its
alignment, so the plot's reference is the one the firmware reports, and each curve is named by its
parameters (the legend said "0.3")."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

from hilbench.cli import cli


@pytest.mark.slow
def test_the_foc_step_plot_shows_the_firmware_s_reference_and_names(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import hilbench.ui.plots as plots

    seen: dict[str, Any] = {}

    def capture(curves, reference, path, title, reference_label="reference"):  # type: ignore[no-untyped-def]
        seen.update(curves=curves, reference=reference, label=reference_label)
        return path

    monkeypatch.setattr(plots, "plot_overlay", capture)
    result = CliRunner().invoke(cli, ["step", "servo_200w", "--from", "500", "--to", "1000",
                                      "--gains", "spd_kp=0.3", "--plot", str(tmp_path / "s.png")])
    assert result.exit_code in (0, 9), result.output
    (label, t, speed), = seen["curves"]
    assert label.startswith("spd_kp=0.3")
    t_ref, ref = seen["reference"]
    assert seen["label"] == "reference (firmware)" and len(ref) == len(t_ref) == len(t)
    ref = np.asarray(ref)
    assert ref[0] < 0.9 * 1000 and ref[-1] == pytest.approx(1000, rel=0.02)  # a ramp, not the ideal step
