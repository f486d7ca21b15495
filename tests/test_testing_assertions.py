"""The plugin's assertions judge what they are given: a NaN band passed every run (third audit:
`assert_settles(band=nan)` passed a motor standing still against 1500 rpm)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hilbench.testing import assert_settles

STILL = {"t_s": np.linspace(0.0, 1.0, 11), "speed_rpm": np.zeros(11)}


@pytest.mark.parametrize(("reference", "band"), [(1500.0, math.nan), (1500.0, -1.0), (math.nan, 10.0),
                                                 (1500.0, math.inf), (1500.0, 10**400), (1500.0, "5")])
def test_a_band_or_reference_that_judges_nothing_is_refused(reference: object, band: object) -> None:
    with pytest.raises(ValueError, match="assert_settles: reference=.*finite numbers, band >= 0"):
        assert_settles(STILL, "speed_rpm", reference, band=band, by_s=0.5)  # type: ignore[arg-type]


def test_a_motor_standing_still_does_not_settle_at_1500_rpm_and_one_there_does() -> None:
    with pytest.raises(AssertionError, match="speed_rpm not within 1500 ± 10"):
        assert_settles(STILL, "speed_rpm", 1500.0, band=10.0, by_s=0.5)
    assert assert_settles(STILL, "speed_rpm", 0.0, band=np.float64(0.0), by_s=0.5) == 0.0
    with pytest.raises(AssertionError, match="worst nan"):
        assert_settles({**STILL, "speed_rpm": np.full(11, np.nan)}, "speed_rpm", 0.0, band=10.0, by_s=0.5)
