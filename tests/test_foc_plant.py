"""Plant additions for the FOC target: encoder A/B order and index, 12-bit ADC, both backends."""

import math

import pytest

from hilbench.plant.model import Plant, available_backends
from hilbench.plant.params import AdcChannel, EncoderParams, InverterParams, MotorParams, PlantParams

BACKENDS = available_backends()


def servo(reverse=False, index_counts=1234, bits=12):
    motor = MotorParams(rs_ohm=5.4, ld_h=6.64e-3, lq_h=6.64e-3, psi_wb=0.08336, pole_pairs=3, j_kgm2=3.8e-5)
    adc = (AdcChannel("ia", 409.6, 2048.0, 0.0, bits), AdcChannel("ib", 409.6, 2048.0, 0.0, bits))
    return PlantParams(motor=motor, encoder=EncoderParams(lines=2500, reverse=reverse, index_counts=index_counts),
                       adc=adc, inverter=InverterParams(vbus_v=311.1, pwm_freq_hz=10_000.0))


def spin(plant, rpm, periods, dt=50e-6):
    """Coast at a constant speed (no friction, no currents): returns per-period samples."""
    plant.reset(speed_rad_s=rpm * 2 * math.pi / 60)
    out = []
    for _ in range(periods):
        plant.step(0.0, 0.0, 0.0, 0, dt)
        out.append((plant.encoder_count, plant.encoder_ab, plant.encoder_index, plant.theta_m_total))
    return out


@pytest.mark.parametrize("backend", BACKENDS)
def test_forward_rotation_a_leads_b(backend):
    # 1 rpm: 10000 counts/60 s = 0.0083 counts per 50 us: every x4 state is seen
    samples = spin(Plant(servo(), backend=backend), 1.0, 60_000)
    ab = [s[1] for s in samples]
    rises_a = [k for k in range(1, len(ab)) if ab[k][0] == 1 and ab[k - 1][0] == 0]
    rises_b = [k for k in range(1, len(ab)) if ab[k][1] == 1 and ab[k - 1][1] == 0]
    assert rises_a and rises_b
    # the states run 00 -> 10 -> 11 -> 01: A rises a quarter cycle before B (A leads)
    states = [s for k, s in enumerate(ab) if k == 0 or s != ab[k - 1]]
    assert len(states) > 8
    assert all(states[i + 1] == {(0, 0): (1, 0), (1, 0): (1, 1), (1, 1): (0, 1), (0, 1): (0, 0)}[states[i]]
               for i in range(len(states) - 1))
    rev = spin(Plant(servo(reverse=True), backend=backend), 1.0, 6_000)
    rs = [s[1] for k, s in enumerate(rev) if k == 0 or s[1] != rev[k - 1][1]]
    assert all(rs[i + 1] == {(1, 0): (0, 0), (1, 1): (1, 0), (0, 1): (1, 1), (0, 0): (0, 1)}[rs[i]]
               for i in range(len(rs) - 1))  # B leads A


@pytest.mark.parametrize("backend", BACKENDS)
def test_index_once_per_turn_at_its_count(backend):
    # 600 rpm = 10 turns/s: 2 s = 20 index pulses, each where the x4 count passes 1234 (mod 10000)
    samples = spin(Plant(servo(), backend=backend), 600.0, 40_000)
    marks = [k for k, s in enumerate(samples) if s[2]]
    assert len(marks) == 20
    for k in marks:
        before = samples[k - 1][3] * 10_000 / (2 * math.pi)  # unwrapped mechanical counts
        after = samples[k][3] * 10_000 / (2 * math.pi)
        turns = math.floor((after - 1234) / 10_000)
        assert before < 1234 + turns * 10_000 <= after


@pytest.mark.parametrize("backend", BACKENDS)
def test_twelve_bit_adc(backend):
    p = Plant(servo(), backend=backend)
    p.reset()
    p.i_a = 1.0  # sensors are plain attributes (read as they are)
    assert p.adc_codes((4,))[0] == 2458  # 2048 + 409.6 -> round
    p.i_a = 100.0
    assert p.adc_codes((4,))[0] == 4095
    ten = Plant(servo(bits=10), backend=backend)
    ten.i_a = 100.0
    assert ten.adc_codes((4,))[0] == 1023
