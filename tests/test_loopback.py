"""The Python loopback target: every field against the mapping written in the issue and PROTOCOL.md."""

from __future__ import annotations

import pytest

from hilbench.errors import ConfigError, ParamError
from hilbench.protocol import PROTOCOL_VERSION, Drive, HostHello, Sensors
from hilbench.targets import make_target
from hilbench.targets.base import Target
from hilbench.targets.loopback.target import LoopbackTarget

# AN1017 Table 8 (C B A -> sector) as printed in the seed summary; 000 and 111 are invalid (7)
TABLE_8 = {0b001: 4, 0b010: 2, 0b011: 3, 0b100: 0, 0b101: 5, 0b110: 1, 0b000: 7, 0b111: 7}
S2, S3 = 0x08, 0x10


def test_make_target_builds_loopback_and_rejects_unknown() -> None:
    t = make_target("loopback")
    assert isinstance(t, LoopbackTarget) and isinstance(t, Target)
    with pytest.raises(ConfigError) as info:
        make_target("nope")
    assert "loopback" in str(info.value) and "an1017" in str(info.value)


def test_hello_declares_the_documented_profile() -> None:
    h = LoopbackTarget().hello(HostHello(9, PROTOCOL_VERSION, 1000, 0, 0))
    assert h.seq == 9
    assert h.protocol_version == PROTOCOL_VERSION
    assert h.firmware_name == "loopback" and h.firmware_version == 1
    assert h.pwm_period_counts == 1000 and h.pwm_freq_hz == 20000
    assert h.n_params == 3
    assert h.adc_roles == (1, 2, 3)  # POT, IBUS, VBUS
    assert h.telemetry_ids == (10, 11, 12)  # ECHO_ENCODER, ECHO_EDGE, ECHO_SEQ


@pytest.mark.parametrize("halls,sector", sorted(TABLE_8.items()))
def test_sector_follows_table_8(halls: int, sector: int) -> None:
    assert LoopbackTarget().step(Sensors(0, halls, (), 0, ())).sector == sector


def test_step_maps_every_field_exactly() -> None:
    t = LoopbackTarget()
    d = t.step(Sensors(77, 0b011 | S3, ((0x8001, 3), (0x9000, 2)), 0xFFFF, (1023, 5, 600)))
    assert d == Drive(77, 1023, 5, 600, 0, 0, 3, True, False, 0, (-1, -32767, 77))  # the first edge's time
    d = t.step(Sensors(78, 0b100, ((0x7FFF, 4),), 0x8000, (9,)))
    assert d == Drive(78, 9, 0, 0, 0, 0, 0, False, False, 0, (-32768, 32767, 78))
    d = t.step(Sensors(79, 0b100, (), 0x8000, (9,)))
    assert d.telemetry == (-32768, -1, 79)  # no edge


def test_start_stop_and_s2_edges() -> None:
    t = LoopbackTarget()
    s = Sensors(0, 1, (), 0, (1, 2, 3))
    assert (t.step(s).output_mode, t.step(s).state) == (0, 0)  # OFF, STOPPED
    t.start()
    assert (t.step(s).output_mode, t.step(s).state) == (1, 2)  # PWM, RUNNING
    t.stop()
    assert t.step(s).state == 0
    pressed = s._replace(inputs=1 | S2)
    # one seq per period (a repeated seq is a duplicated frame: answered again, no step)
    assert t.step(pressed._replace(seq=1)).state == 2  # rising S2 starts
    assert t.step(pressed._replace(seq=2)).state == 2  # held: no new edge
    assert t.step(s._replace(seq=3)).state == 2  # released
    assert t.step(pressed._replace(seq=4)).state == 0  # the next press stops


def test_hello_starts_stopped() -> None:
    t = LoopbackTarget()
    t.start()
    t.hello(HostHello(0, PROTOCOL_VERSION, 1000, 0, 0))
    assert t.step(Sensors(0, 1, (), 0, ())).state == 0


def test_params_describe_and_get() -> None:
    t = LoopbackTarget()
    kp, ki, ver = (t.describe(i) for i in range(3))
    assert (kp.name, kp.ptype, kp.access, kp.min_value, kp.max_value, kp.value) == ("kp", 0, 1, 0, 32767, 3277)
    assert (ki.name, ki.ptype, ki.access, ki.min_value, ki.max_value, ki.value) == ("ki", 0, 1, 0, 32767, 328)
    assert (ver.name, ver.ptype, ver.access, ver.value) == ("version", 1, 0, 1)
    with pytest.raises(ParamError):
        t.describe(3)
    assert t.get_param(1).value == 328 and t.get_param(1).result == 0
    assert t.get_param(42).result == 1  # UNKNOWN_ID


def test_set_params_each_result_code_and_atomicity() -> None:
    t = LoopbackTarget()
    ok = t.set_params(((0, 1000), (1, 2000)))
    assert ok.result == 0
    assert (t.get_param(0).value, t.get_param(1).value) == (1000, 2000)
    assert t.set_params(((0, 5), (9, 1))).result == 1 and t.set_params(((0, 5), (9, 1))).param_id == 9
    bad_ro = t.set_params(((2, 1),))
    assert (bad_ro.result, bad_ro.param_id) == (2, 2)
    bad_range = t.set_params(((1, -1),))
    assert (bad_range.result, bad_range.param_id) == (3, 1)
    bad_constraint = t.set_params(((0, 30000), (1, 2768)))  # 32768 > 32767
    assert (bad_constraint.result, bad_constraint.param_id, bad_constraint.detail) == (4, 0, 1)
    edge = t.set_params(((0, 30000), (1, 2767)))  # exactly 32767 is allowed
    assert edge.result == 0
    assert t.set_params(()).result == 5  # BAD_REQUEST
    assert t.set_params(tuple((0, 1) for _ in range(5))).result == 5
    # failed writes changed nothing
    assert (t.get_param(0).value, t.get_param(1).value) == (30000, 2767)


def test_watchdog_trip_turns_outputs_off() -> None:
    t = LoopbackTarget()
    t.start()
    t.step(Sensors(5, 1, (), 0, (1, 2, 3)))
    d = t.watchdog_trip()
    assert (d.output_mode, d.state, d.fault) == (0, 0, 1)  # OFF, STOPPED, WATCHDOG
    assert t.status().watchdog_trips == 1
    assert t.step(Sensors(6, 1, (), 0, ())).state == 0  # stays stopped
