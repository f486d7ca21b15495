"""AN1017 built for the motor (issue 11, finding 2, firmware side).

The note's speed scale is a build constant of a 10-pole motor at 6000 rpm; here pole pairs and the
maximum speed are `[target]` options. Hand-derived references: Period counts TMR3 ticks (3.2 µs)
between two hall-B edges, half an electrical revolution, so p pole pairs at n rpm give
Period = 60/(2·3.2e-6·p·n) = 9 375 000/(p·n); MINPERIOD rounds that up at the maximum speed, MAXPERIOD
is the 60 rpm period (kept ≤ 32767, a positive DIVF divisor), MeasuredSpeed = DIVF(MINPERIOD − 1,
Period), so one Q15 step is 9 375 000/(p·(MINPERIOD − 1)·32768) rpm.
"""

from __future__ import annotations

from _firmware import one_edge
import pytest

from hilbench.bench.bench import Bench
from hilbench.errors import ConfigError
from hilbench.targets.an1017 import PROFILE, An1017Settings
from hilbench.targets.an1017.firmware import An1017Firmware, An1017Options, build_periods, rpm_per_speed_q15
from hilbench.targets.an1017.target import An1017Target, available_backends
from hilbench.targets.profile import MotorBuild
from _an1017_streams import first_difference, play, random_script

# the accelerators checked against the Python reference (the Python backend is that reference)
ACCELERATORS = [b for b in available_backends() if b != "python"]


def test_the_notes_build_is_the_default():
    # "#define MINPERIOD 313 // For 6000 max rpm and 10 poles motor", MAXPERIOD 31250 (60 rpm)
    assert build_periods(5, 6000) == (313, 31250)
    assert rpm_per_speed_q15(5, 6000) == pytest.approx(1_875_000 / (312 * 32768), rel=1e-15)
    fw = An1017Firmware()
    assert (fw.min_period, fw.max_period) == (313, 31250)
    assert PROFILE.configured(An1017Settings()) is PROFILE
    assert PROFILE.built_for(An1017Settings()) == MotorBuild(pole_pairs=5, max_speed_rpm=6000.0)


def test_other_builds_by_hand():
    # 4 pole pairs, 6000 rpm: 9 375 000/24 000 = 390.625 -> 391; 60 rpm: 39 062 -> 32767
    assert build_periods(4, 6000) == (391, 32767)
    # 4 pole pairs, 3000 rpm: 781.25 -> 782; one Q15 step = 9 375 000/(4·781·32768) rpm
    assert build_periods(4, 3000) == (782, 32767)
    assert rpm_per_speed_q15(4, 3000) == pytest.approx(9_375_000 / (4 * 781 * 32768), rel=1e-12)
    # 3 pole pairs (the 200 W servo), 3000 rpm: 1041.67 -> 1042; 60 rpm: 52 083 -> 32767
    assert build_periods(3, 3000) == (1042, 32767)
    with pytest.raises(ConfigError, match="pole_pairs"):
        An1017Options(pole_pairs=0)
    with pytest.raises(ConfigError, match="max_speed_rpm"):
        An1017Options(max_speed_rpm=50)


def test_profile_follows_the_build():
    settings = An1017Settings(pole_pairs=4, max_speed_rpm=3000)
    profile = PROFILE.configured(settings)
    step = 9_375_000 / (4 * 781 * 32768)  # rpm per Q15 step (above)
    # 1500 rpm: RefSpeed = 1500/step = 16 380 Q15 = 255.9 pot counts of 64 -> code 512 + 256
    assert profile.reference.code_for_rpm(1500.0) == 768
    assert profile.reference.rpm_for_code(768) == pytest.approx(256 * 64 * step)
    assert {c.column: c.scale for c in profile.telemetry}["measured_speed_rpm"] == pytest.approx(step)
    assert profile.built_for(settings) == MotorBuild(pole_pairs=4, max_speed_rpm=3000.0)
    assert An1017Target(An1017Options(pole_pairs=4, max_speed_rpm=3000)).fw.min_period == 782


def test_measured_speed_of_a_four_pole_pair_build():
    # 4 pole pairs at 1000 rpm: hall-B edges every 9 375 000/4000 = 2343.75 ticks -> 2343 or 2344;
    # one sector every 60/(1000·4·6) s = 2500 µs -> B edges 7500 µs apart = 2343.75 ticks
    from test_an1017 import _hall_stream
    from hilbench.protocol import Sensors

    t = An1017Target(An1017Options(pole_pairs=4))
    t.start()
    for k, (hall, edge) in enumerate(_hall_stream(1600, 2500.0, 50)):
        d = t.step(Sensors(k & 0xFF, hall, one_edge(edge, hall), 0, (900, 0, 0)))
    # MeasuredSpeed = trunc(390·32768/Period) with Period 2343 or 2344
    assert d.telemetry[1] in (390 * 32768 // 2343, 390 * 32768 // 2344)
    assert d.telemetry[1] * rpm_per_speed_q15(4, 6000) == pytest.approx(1000.0, rel=1e-3)


@pytest.mark.parametrize("backend", ACCELERATORS)
@pytest.mark.parametrize("pole_pairs,max_speed_rpm", [(4, 6000), (3, 3000)])
def test_other_builds_are_bit_exact_with_the_reference(backend, pole_pairs, max_speed_rpm):
    opts = An1017Options(pole_pairs=pole_pairs, max_speed_rpm=max_speed_rpm)
    script = random_script(11, 12_000, 50)
    got = play(An1017Target(opts, backend=backend), script)
    ref = play(An1017Target(opts, reference=True), script)
    assert got == ref, first_difference(got, ref)


@pytest.mark.parametrize("spec", ["emulator:an1017", "sil:an1017"])
def test_four_pole_pair_motor_follows_with_a_four_pole_pair_build(request, spec):
    """Acceptance: firmware pole pairs 4 on a 4-pole-pair motor follow 800 / 3000 / −2000 rpm within
    2 %, on the model (emulator process) and on the board firmware built with the defines (sil)."""
    if spec.startswith("sil:"):
        request.getfixturevalue("gcc")  # the board firmware is compiled for this host
    overrides = ["motor.pole_pairs=4", "target.pole_pairs=4"]
    with Bench(None, target=spec, overrides=overrides) as bench:
        bench.set_reference(800.0)
        bench.run(0.02)
        bench.press()
        for ref_rpm, hold_s in ((800.0, 1.5), (3000.0, 1.2), (-2000.0, 1.6)):
            bench.set_reference(ref_rpm)
            bench.run(hold_s - 0.2)
            start = len(bench.signals()["t_s"])
            bench.run(0.2)
            speed = bench.signals()["speed_rpm"][start:]
            assert speed.mean() == pytest.approx(ref_rpm, rel=0.02), (ref_rpm, speed.mean())


@pytest.mark.parametrize("pole_pairs,max_speed_rpm", [(4, 6000), (3, 3000)])
def test_board_firmware_built_for_the_motor_equals_the_model(tmp_path, gcc, pole_pairs, max_speed_rpm):
    """firmware/an1017 compiled with the build-time defines (docs/board.md) gives the Python
    model's Drive at every period of a seeded random stream."""
    from _firmware import Command, random_stream
    from hilbench.protocol import MODE_LOCKSTEP, PROTOCOL_VERSION, HostHello
    from hilbench.targets.sil import motor_defines
    from test_firmware_core_inprocess import InProcessCore, load_core_library

    lib = load_core_library(tmp_path / "liban1017.so", motor_defines(pole_pairs, max_speed_rpm))
    model = An1017Target(An1017Options(pole_pairs=pole_pairs, max_speed_rpm=max_speed_rpm))
    model.hello(HostHello(0, PROTOCOL_VERSION, 50, MODE_LOCKSTEP, 0))
    core = InProcessCore(lib, "seed", 50)
    compared = 0
    for item in random_stream(21, 20000, 50):
        if isinstance(item, Command):
            core.follow(item, model)
            continue
        assert core.step(item) == tuple(model.step(item)), (compared, item)
        compared += 1
    assert compared >= 20000
    assert model.fw.min_period == build_periods(pole_pairs, max_speed_rpm)[0]


# ---- FLTA (issue 11, finding 3, the firmware side) -------------------------------------------------
FAULT_BIT, S2_BIT = 0x20, 0x08  # Sensors.inputs: the over-current comparator (FLTA), the S2 button


def _with_fault_bursts(script: list[tuple], seed: int) -> list[tuple]:
    """A script whose Sensors carry the FAULT bit in seeded bursts of 1..40 periods."""
    import random

    from hilbench.protocol import Sensors

    rng = random.Random(seed)
    out, left = [], 0
    for item in script:
        if item[0] == "sensors":
            if left == 0 and rng.random() < 0.003:
                left = rng.randint(1, 40)
            if left:
                left -= 1
                s = item[1]
                item = ("sensors", Sensors(s.seq, s.inputs | FAULT_BIT, s.edges, s.encoder, s.adc))
        out.append(item)
    return out


def test_flta_stops_the_motor_latched_until_a_stop_start():
    from test_an1017 import _hall_stream
    from hilbench.protocol import Sensors

    t = An1017Target()
    stream = _hall_stream(20_000, 2000.0, 50)
    k = 0

    def step(extra: int = 0):
        nonlocal k
        hall, edge = stream[k]
        d = t.step(Sensors(k & 0xFF, hall | extra, one_edge(edge, hall), 0, (900, 0, 0)))
        k += 1
        return d

    t.start()
    for _ in range(6000):
        d = step()
    assert (d.output_mode, d.state, d.fault) == (1, 2, 0)  # PWM, RUNNING
    d = step(FAULT_BIT)
    assert (d.output_mode, d.state, d.fault) == (0, 4, 3)  # outputs off, FAULT, OVERCURRENT
    for _ in range(100):  # latched: the comparator releasing does not restart anything
        d = step()
    assert (d.output_mode, d.state, d.fault) == (0, 4, 3)
    step(S2_BIT)  # a start while the pin is still asserted is stopped again at once
    d = step(FAULT_BIT)
    assert (d.output_mode, d.state, d.fault) == (0, 4, 3)
    step(S2_BIT)  # S2 (press, release) with the pin quiet: ChargeBootstraps, then running
    d = step()
    assert (d.output_mode, d.state, d.fault) == (2, 1, 0)  # LOW_SIDE, BOOTSTRAP
    for _ in range(400):
        d = step()
    assert (d.output_mode, d.state) == (1, 2)


@pytest.mark.parametrize("backend", ACCELERATORS)
def test_flta_is_bit_exact_with_the_reference(backend):
    script = _with_fault_bursts(random_script(5, 30_000, 50), 5)
    got = play(An1017Target(backend=backend), script)
    ref = play(An1017Target(reference=True), script)
    assert got == ref, first_difference(got, ref)
    assert sum(1 for d in ref if hasattr(d, "fault") and d.fault == 3) > 10


def test_flta_board_firmware_equals_the_model(tmp_path, gcc):
    from _firmware import Command, random_stream
    from hilbench.protocol import MODE_LOCKSTEP, PROTOCOL_VERSION, HostHello, Sensors
    from test_firmware_core_inprocess import InProcessCore, load_core_library
    import random

    lib = load_core_library(tmp_path / "liban1017.so")
    model = An1017Target()
    model.hello(HostHello(0, PROTOCOL_VERSION, 50, MODE_LOCKSTEP, 0))
    core = InProcessCore(lib, "seed", 50)
    rng, left, faults = random.Random(9), 0, 0
    for item in random_stream(9, 30000, 50):
        if isinstance(item, Command):
            core.follow(item, model)
            continue
        if left == 0 and rng.random() < 0.003:
            left = rng.randint(1, 40)
        if left:
            left -= 1
            item = Sensors(item.seq, item.inputs | FAULT_BIT, item.edges, item.encoder, item.adc)
        d = tuple(model.step(item))
        assert core.step(item) == d, item
        faults += d[9] == 3
    assert faults > 10
