"""TI IQmath semantics for GLOBAL_Q = 24 on a C28x, as plain Python ints.

Why a module of its own: every block of the F2812 firmware computes with these primitives, and
a faithful emulator must get their rounding, wrap-around and saturation exactly right
(docs/foc.md, "IQmath"; source: IQmathLib.h v1.5c and the C28x IQmath user guide).

- `_iq` is a 32-bit `long`: sums and products wrap modulo 2^32 (two's complement), nothing
  saturates unless a saturating function is called.
- `_IQ(x)` is the C cast `(long)(x * 2^24)`: truncation toward zero, not rounding.
- `_IQmpy(a, b)` is the 64-bit product shifted right by 24 (arithmetic shift = floor), low 32
  bits kept: no rounding, no saturation.
- `_IQsat(a, pos, neg)` clamps. `_IQmpyI32int(a, n)` is the integer part of a·n (floor).
- Q conversions are shifts (`_IQtoIQ15(a) = a >> 9`, `_IQ15toIQ(a) = a << 9`, ...), right shifts
  arithmetic (floor toward −∞).
- `_IQsinPU/_IQcosPU` (1.0 = one turn): the C28x boot-ROM routine is closed; this model computes
  round(sin(2π·θ)·2^24) in float64. Against the exact value the error is ≤ 0.5 LSB (plus the
  float64 error, < 1e-9 LSB); against a real C28x it is estimated at a few LSB (the ROM table is
  Q30 with interpolation; not verifiable here). The firmware only ever asks for angles that are
  Q15 values shifted to Q24 (the QEP's ElecTheta), so `sin_pu_q15`/`cos_pu_q15` answer from a
  32 768-entry table with exactly the same values.
"""

from __future__ import annotations

import math

GLOBAL_Q = 24
ONE = 1 << GLOBAL_Q  # _IQ(1.0)
_MASK32 = 0xFFFFFFFF
_SIGN32 = 0x80000000
IQ_MAX = 0x7FFFFFFF
IQ_MIN = -0x80000000

__all__ = [
    "GLOBAL_Q", "ONE", "IQ_MAX", "IQ_MIN", "wrap32", "iq", "iqn", "iq_mpy", "iq_rmpy", "iq_sat",
    "iq_mpy_i32int", "iq_to_iq15", "iq15_to_iq", "iq_to_iq21", "iq21_to_iq", "iq_to_float",
    "sin_pu", "cos_pu", "sin_pu_q15", "cos_pu_q15", "SIN_Q15_TABLE",
]


def wrap32(x: int) -> int:
    """A C28x `long`: x modulo 2^32 as a signed 32-bit value."""
    return ((x + _SIGN32) & _MASK32) - _SIGN32


def iqn(x: float, q: int) -> int:
    """`_IQn(x)`: (long)(x · 2^q), truncating toward zero like the C cast.

    Out-of-range values are undefined behaviour in C; here they raise ValueError."""
    v = int(x * (1 << q))  # int() truncates toward zero
    if not IQ_MIN <= v <= IQ_MAX:
        raise ValueError(f"_IQ{q}({x!r}) does not fit a 32-bit long")
    return v


def iq(x: float) -> int:
    """`_IQ(x)` in GLOBAL_Q = 24: truncation toward zero (e.g. _IQ(0.8660254) = 14 529 495)."""
    return iqn(x, GLOBAL_Q)


def iq_mpy(a: int, b: int) -> int:
    """`_IQmpy(a, b)`: (a·b) >> 24 (floor), low 32 bits kept (wraps, never saturates)."""
    return wrap32((a * b) >> GLOBAL_Q)


def iq_rmpy(a: int, b: int) -> int:
    """`_IQrmpy(a, b)`: as `_IQmpy` with rounding (adds 2^23 before the shift)."""
    return wrap32((a * b + (1 << (GLOBAL_Q - 1))) >> GLOBAL_Q)


def iq_sat(a: int, pos: int, neg: int) -> int:
    """`_IQsat(a, pos, neg)`: clamp to [neg, pos]."""
    return pos if a > pos else neg if a < neg else a


def iq_mpy_i32int(a: int, n: int) -> int:
    """`_IQmpyI32int(a, n)`: integer part (floor) of an IQ times a long integer."""
    return wrap32((a * n) >> GLOBAL_Q)


def iq_to_iq15(a: int) -> int:
    """`_IQtoIQ15(a)` = a >> 9 (floor)."""
    return a >> 9


def iq15_to_iq(a: int) -> int:
    """`_IQ15toIQ(a)` = a << 9 (wraps)."""
    return wrap32(a << 9)


def iq_to_iq21(a: int) -> int:
    """`_IQtoIQ21(a)` = a >> 3 (floor)."""
    return a >> 3


def iq21_to_iq(a: int) -> int:
    """`_IQ21toIQ(a)` = a << 3 (wraps)."""
    return wrap32(a << 3)


def iq_to_float(a: int, q: int = GLOBAL_Q) -> float:
    """`_IQtoF(a)` for display and tests."""
    return a / float(1 << q)


def _round_half_away(x: float) -> int:
    return int(math.floor(x + 0.5)) if x >= 0 else -int(math.floor(-x + 0.5))


def sin_pu(angle: int) -> int:
    """`_IQsinPU(angle)`: round(sin(2π·angle/2^24)·2^24); angle in turns (periodic)."""
    turns = (angle & (ONE - 1)) / ONE
    return _round_half_away(math.sin(2.0 * math.pi * turns) * ONE)


def cos_pu(angle: int) -> int:
    """`_IQcosPU(angle)`: round(cos(2π·angle/2^24)·2^24)."""
    turns = (angle & (ONE - 1)) / ONE
    return _round_half_away(math.cos(2.0 * math.pi * turns) * ONE)


#: sin_pu of every Q15 angle (index = angle in Q15 turns, 0..32767)
SIN_Q15_TABLE: tuple[int, ...] = tuple(sin_pu(k << 9) for k in range(1 << 15))


def sin_pu_q15(angle_q15: int) -> int:
    """`_IQsinPU(_IQ15toIQ(angle_q15))` from the table (identical values, list-index cost)."""
    return SIN_Q15_TABLE[angle_q15 & 0x7FFF]


def cos_pu_q15(angle_q15: int) -> int:
    """`_IQcosPU(_IQ15toIQ(angle_q15))`: sin a quarter turn (8192 in Q15) later."""
    return SIN_Q15_TABLE[(angle_q15 + 8192) & 0x7FFF]
