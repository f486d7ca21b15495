"""The switching inverter checked by hand, and against the averaged one.

By hand: with the rotor held and no resistance or back-EMF, a phase current is the integral of
its phase voltage over L, piecewise linear, and each leg's voltage is known from the carrier: a
pulse d·T wide centred on the counter's zero or peak, the dead time delaying the edge of the switch
the current's diode does not stand in for (into the motor: the high side's turn-on; out: the low
side's). So the current at any instant, and what the ADC samples at its phase, follow from a few
lines of arithmetic here. The same model stepped in ten pieces equals it stepped whole.

Against the averaged inverter (period means over each PWM period, one electrical turn at fixed
speed, the duty sequences of tests/test_switching_spice.py): without dead time they agree within
0.2 % of the rated current however large the ripple; with dead time they agree where the ripple is
small against the current (the Hurst at rated load: within 0.3 %) and part where it is not: the
averaged bridge takes the dead band's sign from the current at the period's start, while in the
bridge each edge has its own current, ripple included, and a diode current that reaches zero in
the dead time stays there (the servo at light load: the ripple crosses zero in most PWM periods,
and the fundamental differs by about 10 %); and a leg held at 0 or 100 % duty does not switch, so
it has no dead time, which the averaged sign term subtracts all the same (the Hurst over-modulated:
6 %). `average_dead_time = "edges"` takes the sign at each edge and drops the term of a leg that
does not switch: within 0.5 % there.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from _spice import BridgeCase, fundamental, pwm_period_means, run_plant, steady_duties
from test_switching_spice import HURST, HURST_RATED_A, SERVO_RATED_A, hurst_case, servo_case

from hilbench.plant import LoadProfile, MotorParams, Plant, PlantParams
from hilbench.plant.params import AdcChannel, InverterParams, PwmTiming

L_H = 2.0e-3
VBUS = 24.0
F_PWM = 20e3
T = 1.0 / F_PWM


def held_rotor_plant(centre: str, dead_s: float, i0: tuple[float, float], sample: float = 0.0) -> Plant:
    """A rotor that cannot turn, no resistance, no magnet: the phases are pure inductances."""
    motor = MotorParams(rs_ohm=0.0, ld_h=L_H, lq_h=L_H, psi_wb=0.0, pole_pairs=2, j_kgm2=1.0)
    inv = InverterParams(vbus_v=VBUS, pwm_freq_hz=F_PWM, dead_time_s=dead_s, dead_time_enabled=dead_s > 0,
                         model="switching")
    adc = (AdcChannel("ia", 100.0, 2048.0, bits=12), AdcChannel("ib", 100.0, 2048.0, bits=12))
    plant = Plant(PlantParams(motor=motor, inverter=inv, adc=adc, pwm=PwmTiming(centre, sample)))  # type: ignore[arg-type]
    plant.load = LoadProfile("locked")
    plant.i_d, plant.i_q = i0
    plant._sense()
    return plant


def high_intervals(centre: str, d: float, periods: int) -> list[tuple[float, float]]:
    """The leg's ideal high-side intervals over `periods` PWM periods from the counter's zero (the
    leg low before t = 0)."""
    if centre == "peak":
        return [((n + (1 - d) / 2) * T, (n + (1 + d) / 2) * T) for n in range(periods)]
    out = [(0.0, d * T / 2)]
    out += [((n - d / 2) * T, (n + d / 2) * T) for n in range(1, periods)]
    return out + [((periods - d / 2) * T, periods * T)]


def with_dead_time(intervals, current_sign: int, td: float):
    """A current into the motor holds a switching leg low through every dead time (the low diode),
    so its high intervals start Td late; a current out of it holds it high (the high diode), so
    they end Td late."""
    if current_sign > 0:
        return [(a + td, b) for a, b in intervals if a + td < b]
    return [(a, b + td) for a, b in intervals]


def expected_currents(i0, intervals_abc, t: float) -> np.ndarray:
    """i_x(t) = i_x(0) + (1/L) * integral of (v_x - mean v) over [0, t]."""
    on = np.array([sum(max(0.0, min(b, t) - a) for a, b in iv) for iv in intervals_abc]) * VBUS
    return np.asarray(i0) + (on - on.mean()) / L_H


@pytest.mark.parametrize("centre", ["zero", "peak"])
@pytest.mark.parametrize("dead_s", [0.0, 1.5e-6])
def test_phase_currents_follow_the_carrier_and_the_dead_time_by_hand(centre, dead_s):
    i_ab = (4.0, 2.0)  # i_a = 4 A, i_b, i_c = -2 +- 3.46 A (signs +, +, -): far from zero all along
    i_d, i_q = i_ab[0], (i_ab[0] + 2 * i_ab[1]) / math.sqrt(3)
    plant = held_rotor_plant(centre, dead_s, (i_d, i_q))
    i0 = plant.i_abc
    signs = [1 if x > 0 else -1 for x in i0]
    duties = (0.62, 0.35, 0.51)
    intervals = [with_dead_time(high_intervals(centre, d, 2), s, dead_s) for d, s in zip(duties, signs)]
    pieces = 50
    worst = ripple = 0.0
    for n in range(2 * pieces):  # two PWM periods, 1 us at a time
        plant.step(*duties, 1, T / pieces)
        want = expected_currents(i0, intervals, (n + 1) * T / pieces)
        worst = max(worst, float(np.abs(np.array(plant.i_abc) - want).max()))
        ripple = max(ripple, float(np.abs(want - np.asarray(i0)).max()))
    assert worst < 1e-9
    assert ripple > 0.02  # the check is not trivially flat


@pytest.mark.parametrize("backend", ["python", "c"])
def test_the_overcurrent_comparator_sees_the_ripple_peak(backend):
    """The board's comparator watches the current all the time, not at the period's end: with the
    pulses on the peak, phase c's current (-6 A at the start) swings to -6.011 A at mid-period by
    hand and back to -5.990 A, so a 6.0 A comparator trips inside a period it ends below, and one
    at 6.02 A never does."""
    from conftest import require_c_plant
    from hilbench.plant.params import ProtectionParams

    if backend == "c" and not require_c_plant():
        pytest.skip("C plant core not built")
    i_d, i_q = 4.0, 8.0 / math.sqrt(3)
    duties = (0.62, 0.35, 0.51)
    intervals = [high_intervals("peak", d, 1) for d in duties]
    tripped = {}
    for oc in (6.0, 6.02):
        base = held_rotor_plant("peak", 0.0, (i_d, i_q)).params
        params = dataclasses.replace(base, protection=ProtectionParams(oc, False, 0.0, 0.0, 0.0))
        plant = Plant(params, backend=backend)
        plant.load = LoadProfile("locked")
        plant.i_d, plant.i_q = i_d, i_q
        plant._sense()
        i0 = plant.i_abc
        peak = max(float(np.abs(expected_currents(i0, intervals, t)).max()) for t in np.linspace(0.0, T, 2001))
        assert plant.fault_input is False and max(abs(x) for x in i0) <= oc
        plant.step(*duties, 1, T)
        assert max(abs(x) for x in plant.i_abc) < 6.0 < peak < 6.02  # the end is below, the peak between
        tripped[oc] = plant.fault_input
    assert tripped == {6.0: True, 6.02: False}


@pytest.mark.parametrize("centre", ["zero", "peak"])
def test_the_adc_samples_the_current_at_its_phase(centre):
    """A sampling phase of 0.3: the ADC holds the phase currents of 0.3 T into the period, while
    the recorded currents are the period's end; a phase of 0 samples at the period's boundary."""
    i_d, i_q = 4.0, 8.0 / math.sqrt(3)
    duties = (0.7, 0.3, 0.5)
    inside = held_rotor_plant(centre, 0.0, (i_d, i_q), sample=0.3)
    at_zero = held_rotor_plant(centre, 0.0, (i_d, i_q), sample=0.0)
    i0 = inside.i_abc
    intervals = [high_intervals(centre, d, 1) for d in duties]
    for plant in (inside, at_zero):
        plant.step(*duties, 1, T)
    sampled = expected_currents(i0, intervals, 0.3 * T)
    end = expected_currents(i0, intervals, T)
    assert inside.adc_codes((4, 5)) == tuple(round(2048 + 100 * x) for x in sampled[:2])
    assert at_zero.adc_codes((4, 5)) == tuple(round(2048 + 100 * x) for x in end[:2])
    assert np.allclose(inside.i_abc, end, atol=1e-9) and abs(sampled[0] - end[0]) > 0.05


def test_a_period_in_pieces_equals_the_period_whole():
    """The bridge depends on absolute time only: ten 5 us steps are one 50 us step, to the RK4
    steps' own error (the intervals differ), over 100 PWM periods at 0.5 A with a 3.2 us dead band."""
    case = servo_case(0.5, 3.2e-6)
    whole = run_plant(case, points=1)[1]
    pieces = run_plant(case, points=10)[1][::10]
    assert np.abs(whole - pieces).max() < 1e-8


def turn(case: BridgeCase, model: str) -> tuple[np.ndarray, complex]:
    """PWM-period means over the case's turn and the fundamental of phase a's."""
    means = pwm_period_means(case, model=model, points=1 if model != "switching" else 50)
    tc = (np.arange(len(means)) + 0.5) / case.pwm_freq_hz
    return means, fundamental(tc, means[:, 0], case.we_rad_s / (2 * math.pi))


def zero_crossing_share(case: BridgeCase) -> float:
    """The share of PWM periods in which a phase current of the switching model changes sign (the
    ripple reaching across zero): where the current at an edge need not have the start's sign."""
    per = round(1.0 / (case.pwm_freq_hz * case.period_s)) * 20
    i = run_plant(case, points=20)[1]
    n = (len(i) - 1) // per
    seg = i[: n * per + 1]
    crossings = 0
    for k in range(n):
        s = np.sign(seg[k * per:(k + 1) * per + 1])
        crossings += bool(np.any(s.min(axis=0) != s.max(axis=0)))
    return crossings / n


def over_modulated_hurst() -> BridgeCase:
    """The Hurst at 2400 rpm and rated current: the voltage it needs is above the linear range,
    the SVPWM duties clip at 0 and 1 for part of each turn."""
    comp = 4 / math.pi * 0.8e-6 * 2e4 * 24.0
    duties = steady_duties(**HURST, speed_rpm=2400.0, vbus_v=24.0, period_s=50e-6, n_periods=100, counts=1000,
                           i_q_a=1.64, theta0_rad=0.3, dead_comp_v=comp)
    return BridgeCase(**HURST, speed_rpm=2400.0, vbus_v=24.0, pwm_freq_hz=2e4, dead_s=0.8e-6, pulse_centre="zero",
                      period_s=50e-6, counts=1000, duties=duties, theta0_rad=0.3, i0_dq=(0.0, 1.64))


@pytest.mark.parametrize("name, case, rated_a", [
    ("servo rated", servo_case(1.697, 0.0), SERVO_RATED_A), ("servo light", servo_case(0.133, 0.0), SERVO_RATED_A),
    ("hurst rated", hurst_case(1.64, 0.0), HURST_RATED_A), ("hurst light", hurst_case(0.15, 0.0), HURST_RATED_A),
])
def test_without_dead_time_the_averaged_bridge_is_the_switching_ones_period_mean(name, case, rated_a):
    sw, f_sw = turn(case, "switching")
    av, f_av = turn(case, "average")
    rms = math.sqrt(np.mean((sw - av) ** 2))
    print(f"{name}, no dead time: PWM-period means differ by {rms / rated_a * 100:.3f} % of rated (rms), "
          f"fundamental {abs(f_av - f_sw) / rated_a * 100:.3f} % of rated")
    assert rms < 0.002 * rated_a
    assert abs(f_av - f_sw) < 0.002 * rated_a


def test_with_dead_time_they_agree_where_the_ripple_is_small_and_part_where_it_is_not():
    small = hurst_case(1.64, 0.8e-6)  # ripple ~50 mA p-p on 1.64 A
    large = servo_case(0.133, 3.2e-6)  # ripple ~190 mA p-p on ~0.22 A
    report = {}
    for name, case, rated in (("small", small, HURST_RATED_A), ("large", large, SERVO_RATED_A)):
        sw, f_sw = turn(case, "switching")
        for model in ("average", "average-edges"):
            av, f_av = turn(case, model)
            report[name, model] = (math.sqrt(np.mean((sw - av) ** 2)) / rated, abs(f_av - f_sw) / abs(f_sw))
        report[name, "crossings"] = zero_crossing_share(case)
    for name in ("small", "large"):
        print(f"ripple {name} against the current: a phase current crosses zero within "
              f"{report[name, 'crossings'] * 100:.0f} % of the PWM periods; averaged bridge against the switching one: "
              + ", ".join(f"{m} {report[name, m][0] * 100:.2f} % of rated (rms of the period means), fundamental "
                          f"{report[name, m][1] * 100:.2f} %" for m in ("average", "average-edges")))
    # ripple small against the current: the current keeps its sign through almost every PWM period
    assert report["small", "crossings"] < 0.1
    assert report["small", "average"][0] < 0.003 and report["small", "average"][1] < 0.003
    # comparable: the ripple reaches across zero in most PWM periods, the sign at the period's start
    # is not the one at the edges, the clamp holds currents at zero; the models part
    assert report["large", "crossings"] > 0.5
    assert report["large", "average"][1] > 0.05


def test_a_leg_that_does_not_switch_has_no_dead_time():
    """Over-modulated, the duties clip at 0 and 1: those legs do not switch and have no dead band;
    the averaged sign term subtracts it all the same, the "edges" term does not."""
    case = over_modulated_hurst()
    clipped = np.mean([any(d in (0.0, 1.0) for d in duties) for duties in case.duties])
    _, f_sw = turn(case, "switching")
    _, f_sign = turn(case, "average")
    _, f_edges = turn(case, "average-edges")
    sign_err, edges_err = abs(f_sign - f_sw) / abs(f_sw), abs(f_edges - f_sw) / abs(f_sw)
    print(f"over-modulated Hurst: {clipped * 100:.0f} % of periods with a leg at 0 or 100 %; fundamental off by "
          f"{sign_err * 100:.2f} % (sign), {edges_err * 100:.2f} % (edges)")
    assert clipped > 0.2
    assert sign_err > 0.03
    assert edges_err < 0.005


@pytest.mark.parametrize("config, target, centre", [
    (None, "inprocess:an1017", "zero"), ("bench_configs/servo_200w.toml", "inprocess:foc", "peak")])
def test_a_bench_gives_the_plant_its_targets_pwm_timing(config, target, centre):
    """`[inverter] model = "switching"` in a config: the plant switches with the carrier its target's
    profile declares (the dsPIC's pulses on the counter's zero, the F2812's on its peak)."""
    import hilbench
    from conftest import REPO_ROOT

    path = None if config is None else REPO_ROOT / config
    with hilbench.Bench(path, target=target, overrides=("inverter.model=switching",)) as bench:
        plant = bench.session.plant
        assert plant.params.inverter.model == "switching" and plant._bridge.switching
        assert plant.params.pwm.pulse_centre == centre
        bench.run(0.02)
        assert np.all(np.isfinite(bench.signals()["ia_a"]))
