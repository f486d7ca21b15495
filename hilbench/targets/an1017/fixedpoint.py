"""dsPIC30F DSP-engine arithmetic on plain Python ints, so firmware models match the chip bit for bit.

Q15 (1.15 signed fractional) values are ints in [-32768, 32767]. The accumulator model keeps
its value as an int scaled like the chip's 40-bit accumulator (bit 31..16 = the Q15 word);
"SATA" normal saturation clamps it to the 1.31 range after every operation, which is what
the dsPIC does with CORCON.SATA = 1 and ACCSAT = 0.
"""

from __future__ import annotations

Q15_MAX = 32767
Q15_MIN = -32768
ACC_SAT_MAX = 0x7FFFFFFF  # 1.31 normal saturation (ACCSAT = 0)
ACC_SAT_MIN = -0x80000000
ACC40_MAX = (1 << 39) - 1
ACC40_MIN = -(1 << 39)


def sat16(x: int) -> int:
    """Clamp to the signed 16-bit (Q15) range."""
    if x > Q15_MAX:
        return Q15_MAX
    if x < Q15_MIN:
        return Q15_MIN
    return x


def wrap16(x: int) -> int:
    """Two's-complement wrap to a signed 16-bit int (what a C `int` on the dsPIC holds)."""
    x &= 0xFFFF
    return x - 0x10000 if x & 0x8000 else x


def u16(x: int) -> int:
    """Wrap to an unsigned 16-bit int (C `unsigned int` on the dsPIC)."""
    return x & 0xFFFF


def sata(acc: int) -> int:
    """Accumulator normal saturation (SATA = 1, ACCSAT = 0): clamp to 1.31."""
    if acc > ACC_SAT_MAX:
        return ACC_SAT_MAX
    if acc < ACC_SAT_MIN:
        return ACC_SAT_MIN
    return acc


def wrap40(acc: int) -> int:
    """Accumulator without saturation: wraps at 40 bits."""
    acc &= (1 << 40) - 1
    return acc - (1 << 40) if acc & (1 << 39) else acc


def lac(q15: int) -> int:
    """LAC: load a Q15 word into accumulator bits 31:16 (sign-extended)."""
    return q15 << 16


def frac_product(a_q15: int, b_q15: int) -> int:
    """Fractional multiply into accumulator scale: (a·b) << 1, as MPY/MAC do in fractional mode."""
    return (a_q15 * b_q15) << 1


def mac(acc: int, a_q15: int, b_q15: int, saturate: bool = True) -> int:
    """MAC: acc += a·b (fractional); with SATA the result saturates to 1.31 after the add."""
    acc += (a_q15 * b_q15) << 1
    return sata(acc) if saturate else wrap40(acc)


def sac(acc: int) -> int:
    """SAC (no rounding): bits 31:16 of the accumulator with data-write saturation (SATDW = 1)."""
    return sat16(acc >> 16)


def q15_mul(a_q15: int, b_q15: int) -> int:
    """MPY then SAC: truncating fractional product, saturated (−1·−1 → 32767)."""
    return sat16((a_q15 * b_q15 * 2) >> 16)


def divf(num_q15: int, den_q15: int) -> int:
    """DIVF (REPEAT #17): 1.15 quotient trunc(num·32768/den), truncated toward zero.

    The chip requires |num| < |den|; outside that the quotient is undefined, so refuse it.
    """
    if den_q15 == 0 or abs(num_q15) >= abs(den_q15):
        raise ValueError(f"divf({num_q15}, {den_q15}): needs |dividend| < |divisor|")
    q = abs(num_q15) * 32768 // abs(den_q15)
    return -q if (num_q15 < 0) != (den_q15 < 0) else q


def float_to_q15(x: float) -> int:
    """SFloat_To_SFrac16 of the firmware: positive → int(32767·x + 0.5), negative → int(32768·x − 0.5)."""
    if x < 0.0:
        return sat16(int(32768.0 * x - 0.5))
    return sat16(int(32767.0 * x + 0.5))


def q15_to_float(q: int) -> float:
    """A Q15 word as a float fraction (q / 32768)."""
    return q / 32768.0


def adc_signed_fractional(code_10bit: int) -> int:
    """10-bit ADC code in FORM = 11 (signed fractional): (code − 512) << 6."""
    return ((code_10bit & 0x3FF) - 512) << 6
