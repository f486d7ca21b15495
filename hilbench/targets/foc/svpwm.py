"""The seed's simplified SVPWM, literally (seed eq. 1–7, Table 1, Table 2), in IQ24.

Inputs are Uα, Uβ in per unit of the largest phase voltage of the linear range, Udc/√3 (the
SVGEN convention), so the seed's normalisation √3/Udc·(Uα + jUβ) (eq. 1) is the identity and
eq. 2 reads

    Ux = Uβ,   Uy = (√3·Uα − Uβ)/2,   Uz = (−√3·Uα − Uβ)/2.

Sector code P = [Ux>0] + 2[Uy>0] + 4[Uz>0] (eq. 3), Table 1 maps P → N; sectors 1/4, 2/5, 3/6
share compare values (Table 2, in units of T_PWM/4). CMPRx ≤ 0 is set to 0 (the seed's
over-modulation rule); nothing else is clamped.

Compare values are T1 counts: T1PR = 7500 (150 MHz, continuous up/down, 10 kHz), T_PWM = 2·T1PR,
so T_PWM/4 = 3750 and CMPRx = _IQmpyI32int(value, 3750) (floor). With active-high outputs the
pin is high while T1CNT > CMPRx, so the high-side duty of each half period is
(T1PR − CMPRx)/T1PR; a CMPR above T1PR never matches (duty 0) and CMPR = 0 is high throughout.
"""

from __future__ import annotations

from hilbench.targets.foc.iqmath import ONE, iq, iq_mpy, wrap32

__all__ = ["T1PR", "T_PWM_QUARTER", "P_TO_SECTOR", "svpwm", "duty_counts"]

T1PR = 7500
T_PWM_QUARTER = T1PR // 2  # T_PWM/4 = 2*T1PR/4
HALF_SQRT3 = iq(0.8660254)  # _IQ(0.8660254) = 14 529 495
HALF = iq(0.5)
#: seed Table 1: P -> N (P = 0 and 7 only for a zero vector)
P_TO_SECTOR = {3: 1, 1: 2, 5: 3, 4: 4, 6: 5, 2: 6}


def svpwm(u_alpha: int, u_beta: int) -> tuple[int, int, int, int]:
    """(sector N, CMPR1, CMPR2, CMPR3) for Uα, Uβ (IQ24, pu of Udc/√3); N = 0 for a zero vector."""
    a = iq_mpy(HALF_SQRT3, u_alpha)
    h = iq_mpy(HALF, u_beta)
    ux = u_beta
    uy = wrap32(a - h)
    uz = wrap32(-a - h)
    p = (ux > 0) + 2 * (uy > 0) + 4 * (uz > 0)
    n = P_TO_SECTOR.get(p, 0)
    case = (n - 1) % 3 if n else -1
    if case == 0:  # N = 1, 4
        v1, v2, v3 = ONE - uy - ux, ONE + uy - ux, ONE + uy + ux
    elif case == 1:  # N = 2, 5
        v1, v2, v3 = ONE - uy + uz, ONE + uy + uz, ONE - uy - uz
    elif case == 2:  # N = 3, 6
        v1, v2, v3 = ONE + ux + uz, ONE - ux - uz, ONE + ux - uz
    else:
        v1 = v2 = v3 = ONE
    c1 = (wrap32(v1) * T_PWM_QUARTER) >> 24
    c2 = (wrap32(v2) * T_PWM_QUARTER) >> 24
    c3 = (wrap32(v3) * T_PWM_QUARTER) >> 24
    return n, (c1 if c1 > 0 else 0), (c2 if c2 > 0 else 0), (c3 if c3 > 0 else 0)


def duty_counts(cmpr: int) -> int:
    """High-side on-time of one half period in T1 counts (0..T1PR) for a compare value ≥ 0."""
    return T1PR - cmpr if cmpr < T1PR else 0
