"""Physics checks of the scalar plant against hand-derived values and the AN1017 tables."""

from __future__ import annotations

import dataclasses
import math

import pytest

from hilbench.plant import HallParams, LoadProfile, MotorParams, Plant, PlantParams

DT = 50e-6
PHI = (0.0, -2.0 * math.pi / 3.0, 2.0 * math.pi / 3.0)


def hurst(**motor_changes) -> PlantParams:
    p = PlantParams.hurst()
    return dataclasses.replace(p, motor=dataclasses.replace(p.motor, **motor_changes))


def q_duties(theta: float, vq: float, vbus: float = 24.0):
    return tuple(0.5 + vq * math.cos(theta + math.pi / 2 + ph) / vbus for ph in PHI)


def test_psi_from_ke_hand_value():
    m = MotorParams.from_ke(rs_ohm=1, l_h=1e-3, ke_v_per_krpm=7.32, pole_pairs=5, j_kgm2=1e-5)
    # 7.32 V line-line peak at 1000 rpm: phase peak 7.32/sqrt(3) at we = 5*104.72 rad/s
    assert m.psi_wb == pytest.approx(7.32 / math.sqrt(3) / (5 * 1000 * 2 * math.pi / 60), rel=1e-12)
    assert m.psi_wb == pytest.approx(8.0715e-3, rel=1e-4)


def test_steady_no_load_speed_is_analytic():
    params = hurst()
    m = params.motor
    plant = Plant(params)
    vq = 12.0
    for _ in range(8000):
        plant.step(*q_duties(plant.theta_e, vq), 1, DT)
    r, l, psi, p, b = m.rs_ohm, m.ld_h, m.psi_wb, m.pole_pairs, m.b_nms_per_rad

    # Voltage held in the stator frame over a period while the rotor turns by we*DT: its
    # rotor-frame average is vq*sinc(x)*e^{-jx}, x = we*DT/2 (the ripple averages out: linear).
    def residual(wm: float) -> float:
        we = p * wm
        x = 0.5 * we * DT
        g = math.sin(x) / x if x else 1.0
        vd_eff, vq_eff = vq * g * math.sin(x), vq * g * math.cos(x)
        iq = b * wm / (1.5 * p * psi)  # torque balances viscous friction
        i_d = (vd_eff + we * l * iq) / r  # vd = R id - we L iq
        return vq_eff - (r * iq + we * l * i_d + we * psi)  # vq = R iq + we (L id + psi)

    lo, hi = 1.0, vq / (p * psi) * 1.1
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if residual(lo) * residual(mid) <= 0:
            hi = mid
        else:
            lo = mid
    assert plant.w_m == pytest.approx(0.5 * (lo + hi), rel=1e-6)


def test_locked_rotor_current_is_v_over_r():
    plant = Plant(hurst())
    plant.load = LoadProfile("locked")
    duties = (0.6, 0.45, 0.45)
    for _ in range(600):  # 30 ms = 34 electrical time constants
        plant.step(*duties, 1, DT)
    mean = sum(duties) / 3
    for i_x, d in zip(plant.i_abc, duties):
        assert i_x == pytest.approx(24.0 * (d - mean) / 2.54, rel=1e-9, abs=1e-12)
    assert plant.w_m == 0.0 and plant.theta_e == 0.0


@pytest.mark.parametrize("order, sign", [((0, 1, 2), 1), ((0, 2, 1), -1)])
def test_phase_order_sets_direction(order, sign):
    plant = Plant(hurst())
    f_hz, v = 5.0, 3.0
    for k in range(20000):  # 1 s of a 5 Hz electrical field
        ang = 2 * math.pi * f_hz * k * DT
        d = [0.5 + v * math.cos(ang + ph) / 24.0 for ph in PHI]
        plant.step(d[order[0]], d[order[1]], d[order[2]], 1, DT)
    # synchronous: one mechanical turn per p electrical turns -> 1 turn per second
    assert plant.theta_m_total * sign == pytest.approx(2 * math.pi * f_hz / 5, abs=0.3)


def hall_from_windows(theta_deg: float) -> int:
    """an1017_facts.md §2.5: A=1 on [30,210), B=1 on [270,90), C=1 on [150,330)."""
    t = theta_deg % 360
    a = 30 <= t < 210
    b = t >= 270 or t < 90
    c = 150 <= t < 330
    return int(a) | int(b) << 1 | int(c) << 2


TABLE8 = {0b001: 4, 0b010: 2, 0b011: 3, 0b100: 0, 0b101: 5, 0b110: 1}  # CBA -> sector


@pytest.mark.parametrize("direction", [1, -1])
def test_halls_follow_table8_with_exact_edge_times(direction):
    params = hurst(b_nms_per_rad=0.0)
    plant = Plant(params)
    wm = 100.0 * direction  # back-EMF 7 V line-line: below the bus, coasts at constant speed
    theta0 = math.radians(1.0)
    plant.reset(theta_e=theta0, speed_rad_s=wm)
    we = 5 * wm
    seq, edges = [plant.hall_bits], []
    for k in range(400):
        t_start = k * DT
        plant.step(0.5, 0.5, 0.5, 0, DT)
        th_deg = math.degrees(theta0 + we * (t_start + DT))
        assert plant.hall_bits == hall_from_windows(th_deg)
        if plant.last_edge_s is not None:
            seq.append(plant.hall_bits)
            edges.append(t_start + plant.last_edge_s)
    sectors = [TABLE8[h] for h in seq]
    assert all((b - a) % 6 == (1 if direction > 0 else 5) for a, b in zip(sectors, sectors[1:]))
    assert len(edges) >= 6
    # edges every 60 deg electrical at 30 + k*60 deg, exact times from the constant speed
    for t_edge in edges:
        th = math.degrees(theta0 + we * t_edge)
        assert (th - 30.0) / 60.0 == pytest.approx(round((th - 30.0) / 60.0), abs=1e-9 * abs(we) * 180 / math.pi / 60)
    period = math.radians(60) / abs(we)
    for a, b in zip(edges, edges[1:]):
        assert b - a == pytest.approx(period, abs=1e-9)


def test_hall_offset_moves_edges():
    params = dataclasses.replace(hurst(), hall=HallParams(offset_deg=10.0))
    plant = Plant(params)
    plant.reset(theta_e=math.radians(35.0))  # A rises at 40 deg now, so A is still 0
    assert plant.hall_bits & 1 == 0


def test_encoder_counts_four_times_lines_per_turn():
    params = hurst(b_nms_per_rad=0.0)
    plant = Plant(params)
    wm = 50.0
    plant.reset(theta_e=0.123, speed_rad_s=wm)
    c0 = plant.encoder_count
    n = 1000
    dt = (2 * math.pi / wm) / n
    for _ in range(n * 40):  # 40 mechanical turns
        plant.step(0.5, 0.5, 0.5, 0, dt)
    assert plant.encoder_count == (c0 + 40 * 4 * 500) % 65536
    plant.reset(theta_e=0.123, speed_rad_s=-wm)
    for _ in range(n):
        plant.step(0.5, 0.5, 0.5, 0, dt)
    assert plant.encoder_count == (c0 - 2000) % 65536


def spin_up(plant: Plant, vq: float = 12.0, n: int = 2000) -> None:
    for _ in range(n):
        plant.step(*q_duties(plant.theta_e, vq), 1, DT)


def test_off_mode_currents_decay_to_exact_zero_and_rotor_coasts():
    plant = Plant(hurst())
    spin_up(plant)
    plant.load_torque_nm = 0.02
    spin_up(plant, n=200)  # loaded: substantial current
    assert abs(plant.i_q) > 0.2
    w_before = plant.w_m
    zero_at = None
    for k in range(400):
        plant.step(0.9, 0.1, 0.5, 0, DT)  # duties are ignored with the outputs off
        assert all(math.isfinite(x) for x in plant.i_abc)
        if zero_at is None and plant.i_d == 0.0 and plant.i_q == 0.0:
            zero_at = k
        if zero_at is not None:
            assert plant.i_abc == (0.0, 0.0, 0.0)
    assert zero_at is not None and zero_at < 40  # decays against the bus within 2 ms
    assert 0 < plant.w_m < w_before  # coasting, slowed by friction and load


def test_off_mode_above_bus_brakes_through_diodes():
    plant = Plant(hurst())
    plant.reset(speed_rad_s=600.0)  # 5730 rpm: line back-EMF peak 42 V > 24 V bus
    plant.step(0.5, 0.5, 0.5, 0, DT)
    for _ in range(200):
        plant.step(0.5, 0.5, 0.5, 0, DT)
        assert all(math.isfinite(x) for x in plant.i_abc)
    assert plant.i_bus <= 0.0  # regenerating into the bus
    assert plant.w_m < 590.0  # diode current brakes much faster than friction alone
    assert max(abs(x) for x in plant.i_abc) > 0.1


def test_low_side_shorts_phases_and_brakes():
    plant = Plant(hurst())
    spin_up(plant)
    w0 = plant.w_m
    for _ in range(2000):
        plant.step(0.0, 0.0, 0.0, 2, DT)
    assert plant.w_m < 0.2 * w0


@pytest.mark.parametrize("dt, substeps, tol", [(25e-6, 1, 1e-6), (50e-6, 1, 1e-5), (50e-6, 2, 1e-6)])
def test_energy_balance_closes(dt, substeps, tol):
    """RK4 error ~ h^4: a 20 kHz period in 2 substeps closes to 1e-6 (the bench default)."""
    plant = Plant(hurst(coulomb_nm=2e-3), substeps=substeps)
    plant.track_energy = True
    plant.load = LoadProfile("step", torque_nm=0.0, step_time_s=0.05, step_torque_nm=0.015)
    n = int(round(0.1 / dt))
    for _ in range(n):
        plant.step(*q_duties(plant.theta_e, 12.0), 1, dt)
    stored = plant.magnetic_energy_j + plant.kinetic_energy_j
    out = plant.e_cu_j + plant.e_fric_j + plant.e_load_j + stored
    assert plant.e_load_j > 0 and plant.e_fric_j > 0
    assert abs(plant.e_in_j - out) <= tol * plant.e_in_j


def test_fast_path_equals_energy_path():
    a, b = Plant(hurst()), Plant(hurst())
    b.track_energy = True
    for _ in range(3000):
        a.step(*q_duties(a.theta_e, 10.0), 1, DT)
        b.step(*q_duties(b.theta_e, 10.0), 1, DT)
    assert a.w_m == pytest.approx(b.w_m, rel=1e-12)
    assert a.i_q == pytest.approx(b.i_q, rel=1e-10)
    assert a.hall_bits == b.hall_bits


def test_stiction_holds_then_breaks_away():
    plant = Plant(hurst(coulomb_nm=5e-3))
    plant.reset(theta_e=1.0)
    # q-axis torque 1.5*p*psi*iq: 0.05 A -> 3 mN*m < 5 mN*m: no motion at all
    v_small = 0.05 * 2.54
    for _ in range(2000):
        plant.step(*q_duties(1.0, v_small), 1, DT)
    assert plant.w_m == 0.0 and plant.theta_e == 1.0
    for _ in range(2000):
        plant.step(*q_duties(plant.theta_e, 2.0), 1, DT)
    assert plant.w_m > 1.0


def test_adc_codes_seeded_and_clamped():
    a, b = Plant(PlantParams.hurst(), seed=7), Plant(PlantParams.hurst(), seed=7)
    for pl in (a, b):
        pl.pot_fraction = 0.5
    roles = (1, 2, 3, 4, 5, 0)
    ca = [a.adc_codes(roles) for _ in range(5)]
    cb = [b.adc_codes(roles) for _ in range(5)]
    assert ca == cb
    assert ca[0][1] == 512 and ca[0][0] == 512  # no noise in the default channels: exact
    assert ca[0][2] == round(24.0 * 1023 / (1.6 * 24.0))
    assert ca[0][5] == 0
    a.pot_fraction = 2.0
    assert a.adc_codes((1,)) == (1023,)
