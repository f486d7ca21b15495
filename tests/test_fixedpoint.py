"""dsPIC DSP-engine arithmetic against hand-derived values."""

from __future__ import annotations

import pytest

from hilbench.targets.an1017.fixedpoint import (
    adc_signed_fractional,
    divf,
    float_to_q15,
    lac,
    mac,
    q15_mul,
    sac,
    sat16,
    wrap16,
)


def test_sat16_clamps_to_q15():
    assert sat16(40000) == 32767
    assert sat16(-40000) == -32768
    assert sat16(-5) == -5


def test_wrap16_is_c_int_wrap():
    assert wrap16(0x8000) == -32768
    assert wrap16(57344) == -8192
    assert wrap16(-32769) == 32767


def test_fractional_multiply_truncates_and_saturates():
    assert q15_mul(16384, 16384) == 8192  # 0.5·0.5
    assert q15_mul(-32768, -32768) == 32767  # −1·−1 saturates
    # 7281·32663 = 237 819 303 → /32768 = 7257.68 → SAC truncation gives 7257 (facts §2.2)
    assert q15_mul(7281, 32663) == 7257
    assert q15_mul(7281, -32663) == -7258  # bits 31:16 = floor, not toward zero


def test_mac_saturates_accumulator_at_1_31():
    acc = lac(32000)
    acc = mac(acc, 32767, 32767)  # would exceed +1.0
    assert acc == 0x7FFFFFFF
    assert sac(acc) == 32767
    acc = mac(lac(-32000), 32767, -32767)
    assert sac(acc) == -32768


def test_sac_truncates_not_rounds():
    assert sac((100 << 16) + 0xFFFF) == 100
    assert sac(-1) == -1


def test_divf_table6_and_truncation():
    assert divf(312, 313) == 0x7F97
    assert divf(312, 626) == 0x3FCB
    assert divf(312, 31250) == 0x0147
    assert divf(-1, 3) == -10922  # trunc toward zero
    with pytest.raises(ValueError):
        divf(313, 313)


def test_conversions():
    assert float_to_q15(0.1) == 3277
    assert float_to_q15(0.01) == 328
    assert float_to_q15(-0.5) == -16384
    assert adc_signed_fractional(0) == -32768
    assert adc_signed_fractional(512) == 0
    assert adc_signed_fractional(1023) == 0x7FC0
