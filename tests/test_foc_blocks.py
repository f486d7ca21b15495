"""DMC blocks (CLARKE, PARK, IPARK, PID_REG3, clamping PI, SPEED_FR, QEP) on hand-made cases."""

import math

from hilbench.targets.foc import blocks as b
from hilbench.targets.foc.iqmath import ONE, iq


def test_clarke():
    assert b.INV_SQRT3 == 9_686_330
    assert b.clarke(iq(0.5), iq(-0.25)) == (iq(0.5), 0)  # As + 2 Bs = 0
    assert b.clarke(0, iq(0.5)) == (0, 9_686_330)  # beta = 1/sqrt(3)
    # balanced currents at 90 deg: ia = 0, ib = sin(-120+90)... = -(-0.866): beta = (0 + 2*0.866)/sqrt3 = 1
    alpha, beta = b.clarke(0, iq(math.sqrt(3) / 2))
    assert alpha == 0 and abs(beta - ONE) <= 2


def test_park_ipark():
    s, c = b.sin_cos(iq(0.25))
    assert (s, c) == (ONE, 0)
    assert b.park(ONE, 0, s, c) == (0, -ONE)
    s, c = b.sin_cos(4096 << 9)  # 45 deg
    assert s == c == 11_863_283
    assert b.park(ONE, 0, s, c) == (11_863_283, -11_863_283)
    for k in range(0, 32768, 1001):
        s, c = b.sin_cos(k << 9)
        d, q = b.park(iq(0.3), iq(-0.7), s, c)
        a2, b2 = b.ipark(d, q, s, c)
        assert abs(a2 - iq(0.3)) <= 3 and abs(b2 - iq(-0.7)) <= 3


def test_pid_reg3_back_calculation():
    pid = b.PidReg3(kp=ONE, ki=iq(0.5), kc=iq(0.5), out_max=ONE, out_min=-ONE)
    pid.ref, pid.fdb = iq(0.8), 0  # err = 13 421 772
    assert pid.calc() == ONE
    assert pid.up == 13_421_772 and pid.ui == 6_710_886 and pid.out_presat == 20_132_658
    assert pid.sat_err == ONE - 20_132_658 == -3_355_442
    pid.calc()  # Ui = 6 710 886 + 6 710 886 + floor(-3 355 442 / 2)
    assert pid.ui == 6_710_886 + 6_710_886 - 1_677_721 == 11_744_051
    assert pid.out == ONE and pid.sat_err == ONE - (13_421_772 + 11_744_051)


def test_pid_reg3_linear_integral_is_kp_times_ki():
    pid = b.PidReg3(kp=iq(0.5), ki=iq(0.1), kc=0, out_max=ONE, out_min=-ONE)
    pid.ref, pid.fdb = iq(0.01), 0  # err 167 772, Up = 83 886, Ki*Up = 8 388 (floor of 8 388.6)
    for n in range(1, 6):
        pid.calc()
        assert pid.ui == 8_388 * n and pid.out == 83_886 + 8_388 * n


def test_pi_clamp_conditional_integration():
    pi = b.PiClamp(kp=ONE, ki=iq(0.5), kc=0, out_max=ONE, out_min=-ONE)
    pi.ref, pi.fdb = iq(0.8), 0
    assert pi.calc() == ONE and pi.ui == 6_710_886 and pi.v1 == 20_132_658
    pi.calc()  # last Out != v1: the integrator holds
    assert pi.ui == 6_710_886
    pi.ref = iq(0.1)  # up = 1 677 721
    assert pi.calc() == 1_677_721 + 6_710_886  # still held (last call saturated)
    pi.calc()  # now Out == v1: integrates Ki*up = 838 860
    assert pi.ui == 6_710_886 + 838_860


def test_speed_fr_constants_and_steady_speed():
    sp = b.SpeedFr(150.0, 1e-4, 30.0, 3000)
    assert (sp.k1, sp.k2, sp.k3) == (139_810_133, 16_466_823, 310_393)  # facts table, by hand
    step = iq(0.005)  # 1000 rpm: 50 Hz electrical x 100 us = 0.005 turn per ISR
    theta = 0
    raw_q21 = (sp.k1 * step) >> 24  # K1*(dtheta), Q21: 1/3 pu
    for _ in range(3000):
        theta = (theta + step) % ONE
        sp.elec_theta = theta
        sp.calc()
    assert abs(raw_q21 - (1 << 21) / 3) < 2
    # the filter's two floor()s lose < 2 Q21 LSB per call; at the fixed point that deficit is made
    # up by K3 * (raw - speed), so the steady speed sits at most 2 / (K3/2^24) Q21 LSB low
    deficit_q21 = (raw_q21 << 3) - sp.speed
    assert 0 <= deficit_q21 <= 8 * 2 * 2 ** 24 / sp.k3
    assert sp.speed_rpm in (998, 999, 1000)


def test_speed_fr_first_sample_and_wrap_window():
    sp = b.SpeedFr(150.0, 1e-4, 30.0, 3000)
    sp.old_elec_theta, sp.elec_theta = iq(0.5), iq(0.505)
    sp.calc()
    tmp = (sp.k1 * (iq(0.505) - iq(0.5))) >> 24
    assert sp.speed == ((sp.k3 * tmp) >> 24) << 3  # K2*0 + K3*Tmp, Q21 -> Q24
    before = sp.speed
    sp.elec_theta = iq(0.95)  # outside (0.1, 0.9): the raw sample is the held speed
    sp.calc()
    s21 = before >> 3
    assert sp.speed == (((sp.k2 * s21) >> 24) + ((sp.k3 * s21) >> 24)) << 3


def test_qep_counter_is_inclusive_and_directional():
    q = b.Qep(2500, 3)
    assert q.t2pr == 10_000 and q.mech_scaler == 107_374  # _IQ30(0.25/2500) = 0x1A36E
    q.count(10_000)
    assert q.t2cnt == 10_000 and q.direction == 1  # T2PR itself is a state
    q.count(1)
    assert q.t2cnt == 0  # 10 001 counts to come back: one count short per 10 000-count turn
    q.count(-1)
    assert q.t2cnt == 10_000 and q.direction == 0  # going down from 0 reloads T2PR


def test_qep_angles():
    q = b.Qep(2500, 3)
    q.t2cnt = 2500  # a quarter turn
    assert q.calc() == 24_573 and q.mech_theta == 8_191  # (107374*2500)>>15 = 8191.98
    q.t2cnt = 5000
    assert q.calc() == (3 * 16_383) & 0x7FFF == 16_381


def test_qep_negative_calibration_wraps_at_65536():
    q = b.Qep(2500, 3, calibrated_angle=-1250)
    q.t2cnt = 100  # T2CNT + Cal = -1150 -> RawTheta 64 386
    q.calc()
    assert q.raw_theta == 64_386
    assert q.mech_theta == 14_371  # (107374*64386)>>15 = 210 979, & 0x7FFF; not 28 999
    # the modular (intended) angle is 8 850 counts -> 28 999: off by 65536 mod 10000 = 5 536 counts
    assert (107_374 * 8_850) >> 15 == 28_999
    s = b.Qep(2500, 3, calibrated_angle=-1250, signed16=True)
    s.t2cnt = 100
    s.calc()
    assert s.mech_theta == 28_999  # the signed reading of the intrinsic's operand


def test_qep_index_isr():
    q = b.Qep(2500, 3)
    q.count(1234)
    q.index()
    assert (q.qep_count_index, q.t2cnt, q.index_sync_flag) == (1234, 0, 0x00F0)


def test_speed_fr_v43_unwraps_instead_of_holding():
    sp = b.SpeedFr(150.0, 1e-4, 30.0, 3000, unwrap=True)
    sp.old_elec_theta, sp.elec_theta = iq(0.998), iq(0.003)  # across the wrap: +0.005 turn
    sp.calc()
    tmp = (sp.k1 * (iq(0.003) + ONE - iq(0.998))) >> 24
    assert sp.speed == ((sp.k3 * tmp) >> 24) << 3
    sp.old_elec_theta, sp.elec_theta = iq(0.003), iq(0.998)  # backwards across it: -0.005 turn
    before = sp.speed
    sp.calc()
    tmp = (sp.k1 * (iq(0.998) - ONE - iq(0.003))) >> 24
    assert sp.speed == (((sp.k2 * (before >> 3)) >> 24) + ((sp.k3 * tmp) >> 24)) << 3
