"""AN1017 firmware model: seed tables, PID, timing, state machine, parameters, the default backend == the reference.

Expected values come from the seed document (Tables 6, 8, 9, Table 7 formulas), the facts file
and hand arithmetic in the comments — never from the model's own output.
"""

from __future__ import annotations

from _firmware import one_edge
import pytest

from hilbench.targets.an1017.target import (
    PARAM_KD,
    PARAM_KI,
    PARAM_KP,
    PARAM_REF_OVR,
    PARAM_REF_OVR_ON,
    PARAM_STALL_MS,
    PARAMS,
    An1017Target,
)
from hilbench.targets.an1017.firmware import (
    MAXPERIOD,
    MINPERIOD,
    MINPERIOD_DIVF,
    PHASE_VALUES,
    SECTOR_TABLE,
    An1017Firmware,
    An1017Options,
    check_gain_constraints,
    speed_control,
)
from hilbench.targets.an1017.fixedpoint import divf

from hilbench.protocol import HostHello, Sensors, decode_frame, encode_frame

EDGE_NONE = 0xFFFF
S2 = 0x08
OFF, PWM, LOW_SIDE = 0, 1, 2
STOPPED, BOOTSTRAP, RUNNING, STALLED, FAULT = 0, 1, 2, 3, 4
# CW order of hall states (C B A) from Table 8: sector 0..5 = 100, 110, 010, 011, 001, 101
HALL_OF_SECTOR = (0b100, 0b110, 0b010, 0b011, 0b001, 0b101)


def sensors(seq: int, hall: int, edge: int = EDGE_NONE, pot: int = 512, s2: bool = False) -> Sensors:
    return Sensors(seq & 0xFF, hall | (S2 if s2 else 0), one_edge(edge, hall), 0, (pot, 0, 0))


# ---- Table 6 / MINPERIOD ---------------------------------------------------------------------
@pytest.mark.parametrize(
    "actual, past, period, speed",
    [(0x0000, 0xFEC7, 0x0139, 0x7F97), (0x2000, 0x1D8E, 0x0272, 0x3FCB), (0x4000, 0xC5EE, 0x7A12, 0x0147)],
)
@pytest.mark.parametrize("ccw", [False, True])
def test_table6_measured_speed(actual, past, period, speed, ccw):
    fw = An1017Firmware()
    fw.running = True
    fw.actual_capture, fw.past_capture = actual, past
    fw.cur_ccw = ccw
    fw._timer1()
    assert fw.period == period
    assert fw.measured_speed == (-speed if ccw else speed)


def test_minperiod_consistency():
    # (20 MHz/64)·60 / (6000 rpm · 10 poles) = 312.5 → MINPERIOD 313 clamps Period, 312 is the divf numerator
    assert (20_000_000 / 64) * 60 / (6000 * 10) == 312.5
    assert MINPERIOD == 313 and MINPERIOD_DIVF == 312 and MAXPERIOD == 31250
    assert divf(MINPERIOD_DIVF, MINPERIOD) == 0x7F97  # < 0x7FFF: never overflows
    fw = An1017Firmware()
    fw.running = True
    fw.actual_capture, fw.past_capture = 100, 0  # faster than 6000 rpm → clamped
    fw._timer1()
    assert fw.period == 313 and fw.phase_inc == 512000 // 313 == 1635
    fw.actual_capture, fw.past_capture = 40000, 0  # slower than 60 rpm → clamped
    fw._timer1()
    assert fw.period == 31250 and fw.measured_speed == 0x0147 and fw.phase_inc == 16


# ---- Table 8 / Table 9 -----------------------------------------------------------------------
def test_table8_sector_from_halls():
    table8 = {0b001: 4, 0b010: 2, 0b011: 3, 0b100: 0, 0b101: 5, 0b110: 1}
    for hall, sector in table8.items():
        assert SECTOR_TABLE[hall] == sector
    assert SECTOR_TABLE[0] == -1 and SECTOR_TABLE[7] == -1
    t = An1017Target()
    for hall in range(8):
        d = t.step(sensors(hall, hall))
        assert d.sector == table8.get(hall, 7)


# Seed Table 9 lists (LastSector → Sector) pairs; its labels name sector+1 "CCW". The firmware's
# hall ISRs (facts §2.3) decide the opposite way — sector index increasing is CW, the direction
# in which the PWM ISR advances Phase — and the model follows the firmware, so every label of
# the printed table is inverted here.
TABLE9_AS_PRINTED = [
    (0, 1, "CCW"), (1, 2, "CCW"), (2, 3, "CCW"), (3, 4, "CCW"), (4, 5, "CCW"), (5, 0, "CCW"),
    (0, 5, "CW"), (1, 0, "CW"), (2, 1, "CW"), (3, 2, "CW"), (4, 3, "CW"), (5, 4, "CW"),
]


@pytest.mark.parametrize("last, new, printed", TABLE9_AS_PRINTED)
def test_table9_direction_pairs(last, new, printed):
    t = An1017Target()
    t.start()
    for k in range(201):  # through the bootstrap into RUNNING at the `last` sector
        t.step(sensors(k, HALL_OF_SECTOR[last], pot=600))
    d = t.step(sensors(201, HALL_OF_SECTOR[new], edge=100, pot=600))
    assert d.sector == new
    firmware_ccw = printed == "CW"  # inverted label, see above
    assert d.direction_ccw is firmware_ccw


# ---- PID (Table 7) ---------------------------------------------------------------------------
def test_pid_hand_computed_sequence_seed_coefficients():
    c0, c1, c2 = 3277 + 328 + 0, -3277 - 0, 0  # seed: Kp+Ki+Kd, -Kp-2Kd, Kd
    # step 1: e0 = 10000; acc = 2·10000·3605 = 72 100 000 → >>16 = 1100
    co, e0 = speed_control(10000, 0, 0, 0, 0, c0, c1, c2)
    assert (co, e0) == (1100, 10000)
    # step 2: acc = 1100·65536 + 72 100 000 − 65 540 000 = 78 649 600 → 1200
    co, e0 = speed_control(10000, 0, 1100, 10000, 0, c0, c1, c2)
    assert co == 1200
    # negative error: ref −32768, meas 32663 → e saturates at −32768; acc = −2·32768·3605 → −3605
    co, e0 = speed_control(-32768, 32663, 0, 0, 0, c0, c1, c2)
    assert e0 == -32768 and co == -3605


def test_pid_saturates_after_every_mac():
    # CO = 32767, e0 = e1 = 32767, c0 = 3605, c1 = −3277:
    # after MAC 1 the accumulator clips to 0x7FFFFFFF; MAC 2 subtracts 2·32767·3277 = 214 754 918
    # → 1 932 728 729 >> 16 = 29491 (without per-MAC saturation the sum would clip to 32767)
    co, _ = speed_control(32767, 0, 32767, 32767, 0, 3605, -3277, 0)
    assert co == 29491
    co, _ = speed_control(32767, 0, 32000, 0, 0, 32000, 0, 0)
    assert co == 32767
    co, _ = speed_control(-32768, 0, -32000, 0, 0, 32000, 0, 0)
    assert co == -32768


def test_pid_coefficients_per_variant():
    seed = An1017Firmware()
    seed._coefficients()
    assert (seed.c0, seed.c1, seed.c2) == (3605, -3277, 0)
    v11 = An1017Firmware(An1017Options(variant="v11"))
    v11._coefficients()
    assert (v11.c0, v11.c1, v11.c2) == (3605, -328, 0)


def test_variant_resolution():
    seed = An1017Options().resolved()
    assert seed.adc_every_pwm_period and seed.pid_c1_textbook and not seed.phase_advance
    assert seed.stall_timeout_ms == 100
    v11 = An1017Options(variant="v11").resolved()
    assert not v11.adc_every_pwm_period and not v11.pid_c1_textbook and v11.phase_advance
    assert v11.stall_timeout_ms == 1000


# ---- state machine ---------------------------------------------------------------------------
def test_s2_bootstrap_10ms_then_pwm_then_s2_stops():
    t = An1017Target()
    hall = HALL_OF_SECTOR[2]
    d = t.step(sensors(0, hall, s2=True))  # pressed: main waits for the release
    assert d.output_mode == OFF and d.state == STOPPED
    modes = [t.step(sensors(k, hall)) for k in range(1, 202)]  # released at step 1
    # 10 ms = 200 steps of 50 µs with the low sides on, then complementary PWM at 50 %
    assert all(m.output_mode == LOW_SIDE and m.state == BOOTSTRAP for m in modes[:200])
    assert modes[200].output_mode == PWM and modes[200].state == RUNNING
    assert (modes[200].duty_a, modes[200].duty_b, modes[200].duty_c) == (499, 499, 499)
    t.step(sensors(300, hall, s2=True))
    d = t.step(sensors(301, hall))
    assert d.output_mode == OFF and d.state == STOPPED


def test_watchdog_trip_turns_outputs_off():
    t = An1017Target()
    t.start()
    for k in range(250):
        t.step(sensors(k, HALL_OF_SECTOR[0], pot=700))
    d = t.watchdog_trip()
    assert d.output_mode == OFF and d.fault == 1 and d.state == FAULT
    assert t.status().watchdog_trips == 1
    d = t.step(sensors(251, HALL_OF_SECTOR[0], pot=700))
    assert d.output_mode == OFF


@pytest.mark.parametrize("variant, stop_step", [("seed", 2229), ("v11", 20316)])
def test_stall_stops_after_timeout(variant, stop_step):
    # RunMotor at 200 001 Tcy; Timer1 every 20 096 Tcy; stop at tick limit+1 (limit % 10 == 0
    # force-commutates instead): seed 101 ticks → 2 229 697 Tcy → 50 µs step 2229;
    # v1.1 1001 ticks → 20 316 097 Tcy → step 20316.
    t = An1017Target(An1017Options(variant=variant))
    t.start()
    hall = HALL_OF_SECTOR[3]
    last = None
    for k in range(stop_step + 1):
        d = t.step(sensors(k, hall, pot=800))
        if k == stop_step - 1:
            last = d
        if k == 200 + 10 * 20096 // 1000 + 1:  # just after the 10th tick: force-commutated
            assert t.fw.stall_counter == 10
    assert last.state == RUNNING and last.output_mode == PWM
    assert d.state == STALLED and d.output_mode == OFF and d.fault == 2


def test_force_commutation_resets_phase_every_10_ticks():
    fw = An1017Firmware()
    hall = HALL_OF_SECTOR[4]
    fw.hall = hall
    fw.press_start()
    fw.run(200_002, hall, None, 800)  # RunMotor at 200 001 Tcy (CW: RefSpeed > 0)
    tick10 = 200_001 + 10 * 20096  # = 400 961, between PWM boundaries 400 000 and 401 000
    fw.run(tick10 - fw.t, hall, None, 800)
    fw.phase = 12345
    fw.run(1, hall, None, 800)  # exactly the 10th Timer1 tick, no PWM boundary
    assert fw.stall_counter == 10
    assert fw.phase == PHASE_VALUES[4]


# ---- parameters ------------------------------------------------------------------------------
def test_parameter_table_and_defaults():
    t = An1017Target()
    names = {t.describe(pid).name: t.describe(pid).value for pid in PARAMS}
    assert names["kp"] == 3277 and names["ki"] == 328 and names["kd"] == 0
    assert names["stall_ms"] == 100 and names["ph_adv_on"] == 0
    assert all(len(n) <= 12 for n in names)
    assert t.get_param(99).result == 1


@pytest.mark.parametrize(
    "pairs, pid, detail",
    [
        (((PARAM_KP, 30000), (PARAM_KI, 3000)), PARAM_KP, 1),  # 33000 ≥ 32764
        (((PARAM_KP, 20000), (PARAM_KD, 7000)), PARAM_KP, 2),  # Kp + 2Kd = 34000 ≥ 32768
        (((PARAM_KI, 32764),), PARAM_KI, 1),
    ],
)
def test_gain_constraint_refusals(pairs, pid, detail):
    t = An1017Target()
    r = t.set_params(pairs)
    assert (r.result, r.param_id, r.detail) == (4, pid, detail)
    assert t.get_param(PARAM_KP).value == 3277  # nothing written


def test_check_gain_constraints_pure_function():
    assert check_gain_constraints(3277, 328, 0) is None
    assert check_gain_constraints(32000, 500, 264) == 1  # sum 32764 is not < 0.9999
    assert check_gain_constraints(32000, 0, 400) == 2  # −32000 − 800 = −32800 < −32768
    assert check_gain_constraints(-32768, 0, 32764) == 3  # only Kd < 0.9999 breaks


def test_out_of_range_and_unknown_refused_atomically():
    t = An1017Target()
    r = t.set_params(((PARAM_KI, 100), (PARAM_STALL_MS, 5)))
    assert (r.result, r.param_id) == (3, PARAM_STALL_MS)
    assert t.get_param(PARAM_KI).value == 328
    assert t.set_params(((42, 1),)).result == 1


def test_gain_change_is_atomic_at_timer1_boundary():
    t = An1017Target()
    t.start()
    hall = HALL_OF_SECTOR[0]
    for k in range(201):
        t.step(sensors(k, hall, pot=700))
    assert t.set_params(((PARAM_KP, 6000), (PARAM_KI, 1000), (PARAM_KD, 100))).result == 0
    assert t.get_param(PARAM_KP).value == 6000  # declared value at once
    assert (t.fw.kp, t.fw.c0) == (3277, 3605)  # firmware still on the old set
    t1_next = t.fw.t1_next
    k = 201
    while t.fw.t + 1000 <= t1_next:  # (t.fw re-read after each step: it is brought up to date)
        t.step(sensors(k, hall, pot=700))
        k += 1
        assert t.fw.c0 == 3605
    t.step(sensors(k, hall, pot=700))  # this step contains the Timer1 tick
    fw = t.fw
    assert (fw.kp, fw.ki, fw.kd) == (6000, 1000, 100)
    assert (fw.c0, fw.c1, fw.c2) == (7100, -6200, 100)


def test_reference_override_replaces_pot():
    t = An1017Target()
    assert t.set_params(((PARAM_REF_OVR_ON, 1), (PARAM_REF_OVR, -12345))).result == 0
    d = t.step(sensors(0, HALL_OF_SECTOR[0], pot=1000))
    assert d.telemetry[0] == -12345
    t.set_params(((PARAM_REF_OVR_ON, 0),))
    d = t.step(sensors(1, HALL_OF_SECTOR[0], pot=1000))
    assert d.telemetry[0] == (1000 - 512) * 64


def test_adc_rate_per_variant():
    # seed: every PWM period; v1.1: every 16th (SEVOPS 1:16) → a pot change shows up within 16 periods
    seed, v11 = An1017Target(), An1017Target(An1017Options(variant="v11"))
    seen_seed, seen_v11 = [], []
    for k in range(40):
        pot = 512 if k < 3 else 800
        seen_seed.append(seed.step(sensors(k, 4, pot=pot)).telemetry[0])
        seen_v11.append(v11.step(sensors(k, 4, pot=pot)).telemetry[0])
    assert seen_seed[3] == (800 - 512) * 64
    assert seen_v11[3:16] == [0] * 13 and seen_v11[16] == (800 - 512) * 64


# ---- scripted hall stream --------------------------------------------------------------------
def _hall_stream(n_steps: int, sector_us: float, step_us: int, ccw: bool = False, offset_us: float = 17.3):
    """(hall, edge_100ns) per step for a rotor stepping one sector every sector_us."""
    out = []
    idx = 0
    next_edge = offset_us
    for k in range(n_steps):
        t0, t1 = k * step_us, (k + 1) * step_us
        edge = EDGE_NONE
        while t0 <= next_edge < t1:
            idx += 1
            edge = int(round((next_edge - t0) * 10))
            next_edge += sector_us
        sector = (-idx) % 6 if ccw else idx % 6
        out.append((HALL_OF_SECTOR[sector], edge))
    return out


@pytest.mark.parametrize("ccw", [False, True])
def test_measured_speed_follows_edge_timing(ccw):
    # one sector per 2000 µs → hall B edges every 6000 µs = 1875 TMR3 ticks of 3.2 µs
    # MeasuredSpeed = trunc(312·32768/1875) = 5452 (≈ 1000 rpm), negative for CCW
    t = An1017Target()
    t.start()
    pot = 200 if ccw else 900
    for k, (hall, edge) in enumerate(_hall_stream(1200, 2000.0, 50, ccw)):
        d = t.step(Sensors(k & 0xFF, hall, one_edge(edge, hall), 0, (pot, 0, 0)))
    assert d.telemetry[1] == (-5452 if ccw else 5452)
    assert d.direction_ccw is ccw


def _run_stream(target, stream, pot_of_step, stop_at=None):
    out = []
    for k, (hall, edge) in enumerate(stream):
        if k == 3:
            target.start()
        if stop_at is not None and k == stop_at:
            target.stop()
        out.append(target.step(Sensors(k & 0xFF, hall, one_edge(edge, hall), 0, (pot_of_step(k), 0, 0))))
    return out


@pytest.mark.parametrize("variant", ["seed", "v11"])
@pytest.mark.parametrize("step_us", [50, 1000, 250])
def test_default_backend_equals_reference_path(variant, step_us):
    opts = An1017Options(variant=variant)
    n = 30_000 // step_us * 10  # 300 ms
    stream = _hall_stream(n, 1500.0 * (1 + 0.3 * (step_us == 250)), step_us)

    def pot(k):  # forward, then reverse request (braking and reversal), then forward
        ms = k * step_us / 1000
        return 900 if ms < 120 else (150 if ms < 220 else 1000)

    got = _run_stream(An1017Target(opts), stream, pot)
    ref = _run_stream(An1017Target(opts, reference=True), stream, pot)
    assert got == ref
    assert any(d.required_ccw for d in got) and any(d.output_mode == PWM for d in got)


def test_default_backend_equals_reference_with_stall_and_invalid_halls():
    stream = [(HALL_OF_SECTOR[(k // 40) % 6] if k < 1500 else (0 if k < 1600 else 7), EDGE_NONE) for k in range(6000)]
    got = _run_stream(An1017Target(), stream, lambda k: 300)
    ref = _run_stream(An1017Target(reference=True), stream, lambda k: 300)
    assert got == ref
    assert got[-1].state == STALLED


def test_advance_real_time_matches_lockstep_for_whole_periods():
    a, b = An1017Target(), An1017Target()
    stream = _hall_stream(400, 1000.0, 50)
    a.start(), b.start()
    for k, (hall, edge) in enumerate(stream):
        s = Sensors(k & 0xFF, hall, one_edge(edge, hall), 0, (800, 0, 0))
        assert a.step(s) == b.advance(50.0, s)


def test_hello_and_drive_encode_on_the_wire():
    t = An1017Target()
    h = t.hello(HostHello(5, 1, 1000, 0, 500))
    assert (h.firmware_name, h.pwm_period_counts, h.pwm_freq_hz) == ("AN1017", 1000, 20000)
    assert h.adc_roles == (1, 2, 3) and h.telemetry_ids == (1, 2, 3) and h.n_params == len(PARAMS)
    assert decode_frame(encode_frame(h)[:-1]) == h
    t.start()
    for k, (hall, edge) in enumerate(_hall_stream(40, 1000.0, 1000, ccw=True)):
        d = t.step(Sensors(k, hall, one_edge(edge, hall), 0, (100, 0, 0)))
        assert decode_frame(encode_frame(d)[:-1]) == d
    for pid in PARAMS:
        info = t.describe(pid)
        assert decode_frame(encode_frame(info)[:-1]) == info


def test_watchdog_trip_reports_an_error_code_in_status() -> None:
    """Status.last_error speaks the protocol's ErrorCode (WATCHDOG = 9), Drive.fault its Fault."""
    from hilbench.protocol import ErrorCode, Fault, HostHello

    target = An1017Target()
    target.hello(HostHello(0, 1, 50, 1, 100))
    drive = target.watchdog_trip()
    assert drive.fault == Fault.WATCHDOG and drive.output_mode == 0
    assert target.status().last_error == ErrorCode.WATCHDOG
