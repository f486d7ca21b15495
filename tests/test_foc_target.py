"""FocTarget through the Target interface: handshake, exchange halves, parameters, QEP wiring."""

import math

import pytest

from hilbench.errors import ConfigError
from hilbench.protocol import HostHello, Sensors
from hilbench.targets import make_target
from hilbench.targets.foc import make_foc_target
from hilbench.targets.base import Target
from hilbench.targets.foc.firmware import STATE_ALIGN, STATE_FAULT, STATE_RUN, STATE_STOPPED, FocOptions, adc_to_iq
from hilbench.targets.foc.iqmath import ONE, iq
from hilbench.targets.foc.target import INPUT_INDEX, PARAM_IDS, PARAMS, FocTarget

BACKEND = None  # the default backend (C when built); the module is also run on python below
MID = (2048, 2048, 3185)  # zero currents, 311 V on a 400 V full-scale divider


def hello(t, period_us=50):
    return t.hello(HostHello(0, 1, period_us, 0, 100))


def sensors(seq, inputs=0, enc=0, adc=MID):
    return Sensors(seq, inputs, 0xFFFF, enc, adc)


def test_factory_interface_and_hello():
    t = make_target("foc")
    assert isinstance(t, Target) and t.firmware_name == "F2812FOC"
    h = hello(t)
    assert h.pwm_period_counts == 7500 and h.pwm_freq_hz == 10_000 and h.n_params == len(PARAMS)
    assert h.adc_roles == (4, 5, 3)
    with pytest.raises(ConfigError):
        hello(FocTarget(), 75)
    with pytest.raises(ConfigError):
        make_foc_target(no_such_option=1)
    with pytest.raises(ConfigError):
        make_target("foc", FocOptions(pi_form="pid"))  # type: ignore[arg-type]
    assert make_foc_target(pi_form="pi_clamp", backend="python").fw.pid_spd.__class__.__name__ == "PiClamp"


def test_adc_reading():
    assert adc_to_iq(2048) == 0
    assert adc_to_iq(0) == -ONE
    assert adc_to_iq(4095) == 2047 * ONE // 2048
    assert adc_to_iq(2048 + 410) == 410 * ONE // 2048  # 1.0 A on 409.6 codes/A = 0.2 pu of 5 A


def alignment_duties():
    """Min-max SVPWM duty counts of the alignment vector 0.03 pu on the alpha axis (independent)."""
    m = 0.03
    v = [m / math.sqrt(3), -m / (2 * math.sqrt(3)), -m / (2 * math.sqrt(3))]
    mid = (max(v) + min(v)) / 2
    return [7500 * (0.5 + (x - mid)) for x in v]


def test_compare_values_apply_from_the_next_period_match():
    t = FocTarget(FocOptions(align_current_a=0.0), backend=BACKEND)  # PMSM3_1's fixed alignment voltage
    hello(t)
    t.start()
    d0 = t.step(sensors(0))  # underflow: the ISR writes CMPR; the pins still follow the old values
    assert (d0.duty_a, d0.duty_b, d0.duty_c) == (0, 0, 0) and d0.output_mode == 1 and d0.state == STATE_ALIGN
    d1 = t.step(sensors(1))  # period match: the new values are loaded
    for got, want in zip((d1.duty_a, d1.duty_b, d1.duty_c), alignment_duties()):
        assert abs(got - want) <= 1.001
    d2 = t.step(sensors(2))
    assert d2[1:4] == d1[1:4]


def test_a_100us_exchange_reports_the_mean_of_both_halves():
    t = FocTarget(FocOptions(align_current_a=0.0), backend=BACKEND)
    hello(t, 100)
    t.start()
    d = t.step(sensors(0))
    for got, want in zip((d.duty_a, d.duty_b, d.duty_c), alignment_duties()):
        assert abs(got - want / 2) <= 1  # first half: the old (all-off) compares, second: the new


def test_alignment_then_closed_loop_with_t2cnt_zeroed():
    t = FocTarget(FocOptions(align_s=0.001), backend=BACKEND)  # 10 ISRs
    hello(t)
    t.start()
    for k in range(18):
        t.step(sensors(k, enc=37))
    assert t.fw.state == STATE_ALIGN
    t.step(sensors(18, enc=37))  # the 10th ISR ends the alignment
    assert t.fw.state == STATE_RUN and t.fw.qep.t2cnt == 0


def test_s2_toggles_and_watchdog_stops():
    t = FocTarget(backend=BACKEND)
    hello(t)
    t.step(sensors(0, inputs=8))
    assert t.fw.state == STATE_ALIGN
    t.step(sensors(1, inputs=8))  # held: no new press
    assert t.fw.state == STATE_ALIGN
    t.step(sensors(2))
    t.step(sensors(3, inputs=8))
    assert t.fw.state == STATE_STOPPED
    t.start()
    d = t.watchdog_trip()
    assert d.state == STATE_FAULT and d.output_mode == 0 and d[1:4] == (0, 0, 0)


def test_parameters_round_trip_and_atomic_refusal():
    t = FocTarget(backend=BACKEND)
    hello(t)
    names = {t.describe(i).name for i in PARAMS}
    assert {"ref_rpm", "id_ref", "spd_kp", "spd_ki", "spd_kc", "iq_kp", "id_out_max"} <= names
    assert t.get_param(PARAM_IDS["spd_kp"]).value == iq(0.7)
    r = t.set_params(((PARAM_IDS["ref_rpm"], 1000), (PARAM_IDS["iq_kp"], iq(0.5))))
    assert r.result == 0
    assert t.fw.speed_ref == iq(1000 / 3000) and t.fw.gain("iq", "kp") == iq(0.5)
    r = t.set_params(((PARAM_IDS["ref_rpm"], 0), (PARAM_IDS["spd_out_max"], 2 * ONE)))
    assert r.result == 3 and t.fw.speed_ref == iq(1000 / 3000)  # nothing written
    t.set_params(((PARAM_IDS["iq_out_max"], iq(0.5)),))
    assert (t.fw.gain("iq", "out_max"), t.fw.gain("iq", "out_min")) == (iq(0.5), -iq(0.5))
    assert t.get_param(99).result == 1


def test_encoder_direction_and_index_reset():
    t = FocTarget(backend="python")  # calls the Python QEP block directly
    hello(t)
    t.step(sensors(0, enc=65530))
    for k, enc in enumerate((65535, 4, 20), start=1):  # forward across the 16-bit wrap
        t.step(sensors(k, enc=enc))
    q = t.fw.qep
    assert q.t2cnt == 26 and q.direction == 1
    t.step(sensors(4, enc=10))
    assert q.t2cnt == 16 and q.direction == 0
    q.calc()
    raw_before = q.raw_theta
    t.step(sensors(5, inputs=INPUT_INDEX, enc=10))
    assert q.t2cnt == 0 and q.qep_count_index == 16 and q.index_sync_flag == 0xF0
    q.calc()
    assert q.raw_theta == raw_before  # the first index folds T2CNT into CalibratedAngle
    t.step(sensors(6, enc=15))
    t.step(sensors(7, inputs=INPUT_INDEX, enc=15))
    assert q.t2cnt == 0 and q.calibrated_angle == 16  # later pulses only reset the counter


def test_declaration_fits_the_protocol_limits():
    t = FocTarget()
    h = hello(t)
    assert len(h.telemetry_ids) <= 8 and len(h.firmware_name) <= 12  # max_telemetry, max_name_chars
    assert all(len(t.describe(i).name) <= 12 for i in PARAMS)


@pytest.mark.skipif(not hasattr(__import__("hilbench.protocol", fromlist=["ParamType"]).ParamType, "IQ24"),
                    reason="protocol v1 carries 10-bit duties and 16-bit parameter values; v2 is needed")
def test_every_message_encodes_with_protocol_v2():
    import hilbench.protocol as proto

    t = FocTarget()
    proto.encode_frame(hello(t))
    for i in PARAMS:
        proto.encode_frame(t.describe(i))
    t.start()
    for k in range(4):
        proto.encode_frame(t.step(sensors(k)))
