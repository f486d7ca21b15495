"""The compiled AN1017 firmware core (hilbench/targets/an1017/_core.c) against the reference path.

The C backend is the board firmware (firmware/an1017/an1017.c) compiled into this process behind a
thin glue. The Python backend (`reference=True`: every PWM ISR with the full SVM) is the spec;
the C backend must give the identical Drive at every period over the seeded random streams of
tests/_an1017_streams.py (hall edges anywhere, invalid halls, reversals, stalls, S2, gain
writes accepted and refused, pot changes, watchdog, advance() spans, 50/100/250/1000 µs periods,
both variants) and in a closed loop with the scalar plant. Independent checks: the C SVM on the
facts file's reference duty vectors (§1.3) and the C DIVF on Table 6.
"""

from __future__ import annotations

import dataclasses
import random

from _firmware import one_edge
import pytest

from conftest import require_c_an1017
from hilbench.bench.settings import load_config
from hilbench.config import plant_params_from_config
from hilbench.errors import ConfigError
from hilbench.plant import Plant
from hilbench.protocol import PROTOCOL_VERSION, Drive, HostHello, Sensors
from hilbench.targets.an1017.target import An1017Target, available_backends
from hilbench.targets.an1017.firmware import An1017Firmware, An1017Options
from _an1017_streams import first_difference, play, play_with_advances, random_script

pytestmark = pytest.mark.skipif(not require_c_an1017(), reason="compiled AN1017 core not built")

S2 = 0x08
EDGE_NONE = 0xFFFF
PERIOD_S = 50e-6
# firmware state compared at the end of a stream: every variable of the Python model that the board
# firmware has too (the duty registers through duties() and pending_duties(); the next Timer1 tick
# and the end of the bootstrap only while they are pending: the firmware counts them from now)
STATE_FIELDS = tuple(
    f for f in An1017Firmware.__slots__
    if f not in ("options", "pend_duty", "act_duty", "t_frac_us", "t3_zero", "ic7_fifo", "s2_level", "t1_next",
                 "boot_end")
)


def pair(variant: str = "seed", period_us: int = 50) -> tuple[An1017Target, An1017Target]:
    opts = An1017Options(variant=variant)
    c_t, ref_t = An1017Target(opts, backend="c"), An1017Target(opts, reference=True)
    for t in (c_t, ref_t):
        t.hello(HostHello(0, PROTOCOL_VERSION, period_us, 0, 0))
        t.start()
    return c_t, ref_t


def assert_same_state(c_t: An1017Target, ref_t: An1017Target) -> None:
    for f in STATE_FIELDS:
        assert getattr(c_t.fw, f) == getattr(ref_t.fw, f), f"firmware field {f}"
    assert c_t.fw.duties() == ref_t.fw.duties()
    assert c_t.fw.pending_duties() == ref_t.fw.pending_duties()
    if ref_t.fw.running:
        assert c_t.fw.t1_next == ref_t.fw.t1_next
    if ref_t.fw.booting:
        assert c_t.fw.boot_end == ref_t.fw.boot_end


def test_backend_selection(monkeypatch):
    assert available_backends() == ("c", "python")
    monkeypatch.delenv("HILBENCH_AN1017_BACKEND", raising=False)
    assert An1017Target().backend == "c"
    assert An1017Target(reference=True).backend == "python"
    assert type(An1017Target(reference=True).fw) is An1017Firmware
    monkeypatch.setenv("HILBENCH_AN1017_BACKEND", "python")
    t = An1017Target()
    assert t.backend == "python" and type(t.fw) is An1017Firmware
    assert An1017Target(backend="c").backend == "c"  # the argument wins over the environment
    with pytest.raises(ConfigError):
        An1017Target(backend="fortran")
    with pytest.raises(ConfigError):
        An1017Target(reference=True, backend="c")


@pytest.mark.parametrize(
    "volts, angle, duties",
    [  # facts §1.3 reference duty vectors (also tests/test_svm.py)
        (0, 0x0000, (499, 499, 499)),
        (16384, 0x0000, (714, 284, 284)),
        (16384, 0x1555, (747, 499, 251)),
        (28300, 0x1555, (927, 499, 71)),
        (32767, 0x4000, (499, 927, 71)),
        (16384, 0x8000, (284, 714, 714)),
        (10000, 0xE000, (644, 354, 567)),
        (20000, 0x0AAA, (791, 361, 207)),
    ],
)
def test_c_svm_reference_vectors(volts, angle, duties):
    from hilbench.targets.an1017 import _core as _an1017core

    assert _an1017core.svm(volts, angle) == duties


@pytest.mark.parametrize("period, speed", [(0x0139, 0x7F97), (0x0272, 0x3FCB), (0x7A12, 0x0147)])
@pytest.mark.parametrize("ccw", [False, True])
def test_c_measured_speed_table6(period, speed, ccw):
    """AN1017 Table 6 through the C Timer1 ISR: Period from two captures → MeasuredSpeed."""
    t = An1017Target(backend="c")
    t.start()
    fw = t.fw
    fw.run(200_002, 0b100, None, 512)  # ChargeBootstraps ends just after 10 ms (Tcy 200 001): RunMotor
    assert fw.running and fw.t1_next == 200_001 + 20_096
    fw.past_capture, fw.actual_capture, fw.cur_ccw = 1000, (1000 + period) & 0xFFFF, ccw
    fw.run(fw.t1_next - fw.t + 1, 0b100, None, 512)  # up to and including the Timer1 tick
    assert fw.period == period
    assert fw.measured_speed == (-speed if ccw else speed)


@pytest.mark.parametrize("variant", ["seed", "v11"])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_c_equals_reference_random_stream_50us(variant, seed):
    script = random_script(seed, 24_000, 50)
    c_t, ref_t = pair(variant)
    got, ref = play(c_t, script), play(ref_t, script)
    assert got == ref, first_difference(got, ref)
    drives = [d for d in got if isinstance(d, tuple) and type(d) is Drive]
    assert len(drives) == 24_000 + sum(item[0] == "watchdog" for item in script)
    assert all(type(d) is Drive for d in got if isinstance(d, Drive))
    # the stream really ran the motor both ways, stopped, stalled and restarted
    assert sum(d.output_mode == 1 for d in drives) > 2000
    assert any(d.direction_ccw for d in drives) and any(not d.direction_ccw for d in drives)
    assert len({d.state for d in drives}) >= 3
    assert_same_state(c_t, ref_t)


@pytest.mark.slow
@pytest.mark.parametrize("variant", ["seed", "v11"])
@pytest.mark.parametrize("seed", range(100, 116))
def test_c_equals_reference_more_streams(variant, seed):
    """More seeds, a longer stream (4 s), a random lockstep period per seed."""
    step_us = random.Random(seed).choice((50, 50, 100, 150, 250, 500, 1000))
    script = random_script(seed, 4_000_000 // step_us, step_us)
    c_t, ref_t = pair(variant, step_us)
    got, ref = play(c_t, script), play(ref_t, script)
    assert got == ref, first_difference(got, ref)
    assert_same_state(c_t, ref_t)


@pytest.mark.parametrize("variant", ["seed", "v11"])
@pytest.mark.parametrize("step_us", [100, 250, 1000])
def test_c_equals_reference_random_stream_longer_periods(variant, step_us):
    script = random_script(10 + step_us, 1_200_000 // step_us, step_us)
    c_t, ref_t = pair(variant, step_us)
    got, ref = play(c_t, script), play(ref_t, script)
    assert got == ref, first_difference(got, ref)
    assert_same_state(c_t, ref_t)


@pytest.mark.parametrize("variant", ["seed", "v11"])
def test_c_equals_reference_with_advance_spans(variant):
    """Real-time advance() spans (not whole periods) interleaved with lockstep steps."""
    script = random_script(77, 12_000, 50)
    outs = [play_with_advances(target, script, seed=5) for target in pair(variant)]
    assert outs[0] == outs[1], first_difference(outs[0], outs[1])


def test_c_drives_encode_like_constructed_drives():
    from hilbench.protocol import decode_frame, encode_frame

    for target in pair():  # both backends build Drives without the NamedTuple's __new__
        drives = [d for d in play(target, random_script(4, 1500, 50)) if isinstance(d, tuple) and type(d) is Drive]
        assert len(drives) == 1500
        for d in drives:
            assert Drive(*d) == d and Drive._make(d) == d and len(d) == 11
            assert decode_frame(encode_frame(d)[:-1]) == d


def _pot_code(rpm: float) -> int:
    # RefSpeed = (code − 512)·64 and one Q15 step = 1 875 000/(312·32768) rpm (AN1017 Table 6)
    return 512 + round(rpm / (1_875_000 / (312 * 32768)) / 64)


@pytest.mark.parametrize("variant", ["seed", "v11"])
def test_c_equals_reference_closed_loop_default_scenario(variant):
    """2 s closed loop with the scalar plant: the default bench's actions (pot ramp to 1500 rpm,
    S2, step to 2500, reverse to −1500, S2 stop), compressed into 2 s; every Drive equal."""
    c_t, ref_t = pair(variant)
    for t in (c_t, ref_t):
        t.stop()  # started by S2 below, as on the bench
    cfg = load_config(None)
    plant = Plant(dataclasses.replace(plant_params_from_config(cfg)), seed=3)
    n = int(2.0 / PERIOD_S)
    s2_windows = ((int(0.03 / PERIOD_S), int(0.05 / PERIOD_S)), (int(1.9 / PERIOD_S), int(1.92 / PERIOD_S)))
    modes, ccw_seen, max_rpm = set(), set(), 0.0
    for k in range(n):
        t_s = k * PERIOD_S
        rpm = 1500.0 * min(1.0, t_s / 0.3) if t_s < 0.8 else (2500.0 if t_s < 1.3 else -1500.0)
        plant.pot_fraction = _pot_code(rpm) / 1023.0
        e = plant.last_edge_s
        edge = EDGE_NONE if e is None else min(int(e * 1e7), 499)
        s2 = any(a <= k < b for a, b in s2_windows)
        sensors = Sensors(k & 0xFF, plant.hall_bits | (S2 if s2 else 0), one_edge(edge, plant.hall_bits), 0,
                          plant.adc_codes((1, 2, 3)))
        d_ref = ref_t.step(sensors)
        d_c = c_t.step(sensors)
        assert d_c == d_ref, f"period {k}:\n c         {d_c}\n reference {d_ref}"
        modes.add(d_ref.output_mode)
        ccw_seen.add(d_ref.direction_ccw)
        max_rpm = max(max_rpm, abs(plant.w_m) * 60 / (2 * 3.141592653589793))
        plant.step(d_ref.duty_a / 1000, d_ref.duty_b / 1000, d_ref.duty_c / 1000, d_ref.output_mode, PERIOD_S)
    assert modes == {0, 1, 2}  # off, bootstrap (low side), PWM
    assert ccw_seen == {False, True}  # the reversal happened
    assert max_rpm > 1500.0
    assert_same_state(c_t, ref_t)
