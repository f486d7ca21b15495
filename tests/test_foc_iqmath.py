"""IQmath (GLOBAL_Q 24) primitives against hand-computed values."""

import math

import pytest

from hilbench.targets.foc import iqmath as m


def test_iq_truncates_toward_zero():
    assert m.iq(0.8660254) == 14_529_495  # 14 529 495.46...
    assert m.iq(0.57735026918963) == 9_686_330  # 9 686 330.8 -> truncated, round() would give ...331
    assert m.iq(-0.3) == -5_033_164  # -5 033 164.8 -> toward zero
    assert m.iq(1.0) == 16_777_216
    assert m.iqn(1 / 66.6667, 21) == int(2 ** 21 / 66.6667)
    with pytest.raises(ValueError):
        m.iq(128.0)


def test_iq_mpy_floor_shift():
    half = 8_388_608
    assert m.iq_mpy(half, 3) == 1  # 1.5 -> 1
    assert m.iq_mpy(half, -3) == -2  # -1.5 -> floor -2 (not truncation)
    assert m.iq_mpy(-half, 3) == -2
    assert m.iq_mpy(m.iq(0.5), m.iq(0.5)) == m.iq(0.25)
    # _IQmpy(_IQ(0.5), x) == x >> 1, but _IQmpy(_IQ(-0.5), x) != -(x >> 1) for odd x
    assert m.iq_mpy(m.iq(0.5), 7) == 3 and m.iq_mpy(m.iq(-0.5), 7) == -4 and -(7 >> 1) == -3
    assert m.iq_rmpy(half, 3) == 2  # rounding variant: 1.5 -> 2


def test_iq_mpy_wraps_instead_of_saturating():
    # 100 * 2 = 200 does not fit Q24 (max 127.99...): 200 * 2^24 - 2^32 = -939 524 096 (-56.0)
    assert m.iq_mpy(m.iq(100), m.iq(2)) == 200 * 2 ** 24 - 2 ** 32 == -939_524_096
    assert m.wrap32(2 ** 31) == -(2 ** 31)
    assert m.wrap32(-(2 ** 31) - 1) == 2 ** 31 - 1


def test_sat_and_conversions():
    assert m.iq_sat(m.iq(1.5), m.iq(1), m.iq(-1)) == m.ONE
    assert m.iq_sat(m.iq(-1.5), m.iq(1), m.iq(-1)) == -m.ONE
    assert m.iq_sat(5, 10, -10) == 5
    assert m.iq_to_iq15(511) == 0 and m.iq_to_iq15(512) == 1
    assert m.iq_to_iq15(-1) == -1 and m.iq_to_iq15(-512) == -1 and m.iq_to_iq15(-513) == -2
    assert m.iq15_to_iq(1) == 512 and m.iq15_to_iq(-32768) == -m.ONE
    assert m.iq_to_iq21(-1) == -1 and m.iq21_to_iq(3) == 24
    assert m.iq_mpy_i32int(m.iq(0.5), 7501) == 3750  # floor(3750.5)
    assert m.iq_mpy_i32int(m.iq(-0.5), 7501) == -3751


def test_sin_cos_pu():
    assert m.sin_pu(0) == 0
    assert m.sin_pu(m.iq(0.25)) == m.ONE
    assert m.cos_pu(m.iq(0.5)) == -m.ONE
    assert m.sin_pu(m.iq(0.75)) == -m.ONE
    assert m.sin_pu_q15(4096) == 11_863_283  # sin 45 deg * 2^24 = 11 863 283.2
    assert m.cos_pu_q15(4096) == 11_863_283
    assert m.sin_pu(m.iq(1.25)) == m.ONE  # periodic


def test_sin_table_error_within_half_lsb_and_cos_consistent():
    worst = 0.0
    for k in range(0, 32768, 7):
        exact = math.sin(2 * math.pi * k / 32768) * 2 ** 24
        worst = max(worst, abs(m.sin_pu_q15(k) - exact))
        assert m.cos_pu_q15(k) == m.cos_pu(k << 9)
        assert m.sin_pu_q15(k) == m.sin_pu(k << 9)
    assert worst <= 0.5 + 1e-6
