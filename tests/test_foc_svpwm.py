"""The seed's simplified SVPWM against the standard min-max (centred) SVPWM and the seed's tables."""

import math

from hilbench.targets.foc.iqmath import iq
from hilbench.targets.foc.svpwm import T1PR, duty_counts, svpwm


def minmax_cmpr(m: float, ang: float) -> list[float]:
    """Standard centred SVPWM: d_x = 1/2 + (v_x - (max+min)/2)/Udc; CMPR = T1PR (1 - d_x).

    |U| = m * Udc/sqrt(3); amplitude-invariant inverse Clarke gives the phase voltages."""
    udc = 1.0
    va_ = m * udc / math.sqrt(3) * math.cos(ang)
    vb_ = m * udc / math.sqrt(3) * math.sin(ang)
    v = [va_, -0.5 * va_ + math.sqrt(3) / 2 * vb_, -0.5 * va_ - math.sqrt(3) / 2 * vb_]
    mid = (max(v) + min(v)) / 2
    return [T1PR * (1 - (0.5 + (x - mid) / udc)) for x in v]


def test_equals_minmax_within_one_count_in_the_linear_range():
    worst = 0.0
    for k in range(3600):
        ang = 2 * math.pi * k / 3600
        for m in (0.0, 0.05, 0.2, 0.5, 0.8, 0.95, 1.0):
            _, c1, c2, c3 = svpwm(iq(m * math.cos(ang)), iq(m * math.sin(ang)))
            ref = minmax_cmpr(m, ang)
            for got, want in zip((c1, c2, c3), ref):
                worst = max(worst, abs(got - want))
    # the integer floor loses < 1 count; the truncated IQ constants add ~1e-4 count
    assert worst < 1.001, worst


def test_sector_numbers_follow_table_1():
    # sector N spans (N-1)*60 .. N*60 degrees (seed Fig. 2/3: sector 1 from V4 and V6)
    for n in range(1, 7):
        ang = math.radians(60 * (n - 1) + 30)
        assert svpwm(iq(0.5 * math.cos(ang)), iq(0.5 * math.sin(ang)))[0] == n
        for off in (-25, 25):
            ang = math.radians(60 * (n - 1) + 30 + off)
            assert svpwm(iq(0.9 * math.cos(ang)), iq(0.9 * math.sin(ang)))[0] == n


def test_overmodulation_follows_the_seed_clamp_literally():
    # 30 deg, |U| = 1.2: Ux = 0.6, Uy = (sqrt3 * 1.0392 - 0.6)/2 = 0.6, N = 1:
    # CMPR1 = 3750 (1 - 1.2) < 0 -> 0, CMPR2 = 3750 (1 + 0.6 - 0.6) = 3750, CMPR3 = 3750 * 2.2 = 8250
    ang = math.radians(30)
    n, c1, c2, c3 = svpwm(iq(1.2 * math.cos(ang)), iq(1.2 * math.sin(ang)))
    assert n == 1 and c1 == 0 and abs(c2 - 3750) <= 1 and abs(c3 - 8250) <= 1
    assert duty_counts(c1) == T1PR and duty_counts(c3) == 0
    # Beyond the linear range the clamp clips each phase's duty at 100 % (CMPR <= 0 -> 0) and a
    # CMPR above T1PR never matches (0 %): that is the min-max duty clipped to [0, 1] per phase,
    # with no rescaling of the vector, so the applied vector is distorted (not a scaled circle).
    worst = 0.0
    for m in (1.05, 1.1, 1.2, 1.5):
        for k in range(720):
            a = 2 * math.pi * k / 720
            _, *c = svpwm(iq(m * math.cos(a)), iq(m * math.sin(a)))
            for got, want in zip(c, minmax_cmpr(m, a)):
                assert got >= 0
                worst = max(worst, abs(duty_counts(got) - min(T1PR, max(0.0, T1PR - want))))
    assert worst < 1.001


def test_zero_vector_is_fifty_percent():
    assert svpwm(0, 0) == (0, 3750, 3750, 3750)
