"""AN1017's space-vector modulation (Bowling's SVM.c) in exact integer arithmetic.

Facts §1: 172-entry 0–60° sine table, sectors chosen by the VECTOR boundaries of a 16-bit angle,
t1/t2 scaled by volts then by the PWM period, centred zero vectors. Every value matches the
chip's 32-bit intermediate / unsigned 16-bit result arithmetic.
"""

from __future__ import annotations

import math

PTPER = 499
TPWM = PTPER << 1  # 998: the full PWM period in duty-register units (LSB = Tcy/2)
VOLTS_LIMIT = 28300  # "equivalent to 0.866, which is sqrt(3)/2"
SIXTY_DEG = 0x2AAA
VECTORS = (0x0000, 0x2AAA, 0x5555, 0x8000, 0xAAAA, 0xD555)

# round(32767·sin(i·60°/171)), i = 0..171 (index 171 is never reached by the algorithm).
SINE_TABLE: tuple[int, ...] = tuple(
    int(math.floor(32767.0 * math.sin(math.radians(i * 60.0 / 171.0)) + 0.5)) for i in range(172)
)


def svm_sector(angle_u16: int) -> int:
    """Sector 1..6 of a 16-bit angle, by the firmware's `angle < VECTORk` tests in order."""
    a = angle_u16 & 0xFFFF
    if a < 0x2AAA:
        return 1
    if a < 0x5555:
        return 2
    if a < 0x8000:
        return 3
    if a < 0xAAAA:
        return 4
    if a < 0xD555:
        return 5
    return 6


def svm(volts: int, angle_u16: int) -> tuple[int, int, int]:
    """Duty registers (PDC1, PDC2, PDC3) for amplitude `volts` (Q15, ≥ 0) at `angle_u16`.

    The firmware model calls it at every PWM ISR; the compiled core has its own copy, checked
    against this one at every angle (tests/test_svm.py).
    """
    if volts > VOLTS_LIMIT:
        volts = VOLTS_LIMIT
    a = angle_u16 & 0xFFFF
    sector = svm_sector(a)
    angle2 = (a - VECTORS[sector - 1]) & 0xFFFF
    angle1 = (SIXTY_DEG - angle2) & 0xFFFF
    t1 = SINE_TABLE[(angle1 >> 6) & 0xFF]
    t2 = SINE_TABLE[(angle2 >> 6) & 0xFF]
    t1 = ((t1 * volts) >> 15) & 0xFFFF
    t1 = ((t1 * TPWM) >> 15) & 0xFFFF
    t2 = ((t2 * volts) >> 15) & 0xFFFF
    t2 = ((t2 * TPWM) >> 15) & 0xFFFF
    h = ((TPWM - t1 - t2) & 0xFFFF) >> 1
    if sector == 1:
        return (t1 + t2 + h) & 0xFFFF, (t2 + h) & 0xFFFF, h
    if sector == 2:
        return (t1 + h) & 0xFFFF, (t1 + t2 + h) & 0xFFFF, h
    if sector == 3:
        return h, (t1 + t2 + h) & 0xFFFF, (t2 + h) & 0xFFFF
    if sector == 4:
        return h, (t1 + h) & 0xFFFF, (t1 + t2 + h) & 0xFFFF
    if sector == 5:
        return (t2 + h) & 0xFFFF, h, (t1 + t2 + h) & 0xFFFF
    return (t1 + t2 + h) & 0xFFFF, h, (t1 + h) & 0xFFFF
