"""The compiled FOC firmware (_core.c) against the Python model: every Drive, bit for bit."""

from __future__ import annotations

import random

import pytest

from _foc_bench import IndexPlant, servo_params, speed_events
from hilbench.bench.scenario import Event
from hilbench.bench.session import Session, SessionOptions
from hilbench.protocol import HostHello, Sensors
from hilbench.targets.foc.firmware import FocOptions
from hilbench.targets.foc.iqmath import iq
from hilbench.targets.foc.target import INPUT_INDEX, PARAM_IDS, FocTarget, available_backends

pytestmark = pytest.mark.skipif("c" not in available_backends(), reason="the FOC C core is not built")


class Recording:
    """A target that keeps every Drive it returns (the session sees the target unchanged)."""

    def __init__(self, target: FocTarget) -> None:
        self.target = target
        self.firmware_name = target.firmware_name
        self.drives: list = []

    def __getattr__(self, name: str):
        return getattr(self.target, name)

    def step(self, sensors):
        d = self.target.step(sensors)
        self.drives.append(d)
        return d


def closed_loop(backend: str, options: FocOptions, period_us: int, dead_time: bool) -> list:
    events = speed_events((0.2, 1000.0), (0.7, 400.0), (1.4, -400.0), end_s=1.8, loads=((1.0, 0.05),))
    events.append(Event(at_s=1.2, params=(("iq_kp", float(iq(0.5))), ("spd_out_max", float(iq(0.3))))))
    rec = Recording(FocTarget(options, backend=backend))
    plant = IndexPlant(servo_params(dead_time_enabled=dead_time), seed=0, substeps=1)
    Session(rec, plant, events, SessionOptions(period_us=period_us, observe_every_periods=10 ** 9)).run()
    return rec.drives


@pytest.mark.parametrize("options,period_us,dead_time", [
    (FocOptions(), 50, True),
    (FocOptions(pi_form="pi_clamp", align_current_a=0.0, speed_fr="v4.3"), 50, False),
    (FocOptions(speed_ramp_rpm_per_s=0.0, learn_index=False, calibrated_angle=-1250), 100, True),
])
def test_closed_loop_drives_identical(options, period_us, dead_time):
    py = closed_loop("python", options, period_us, dead_time)
    c = closed_loop("c", options, period_us, dead_time)
    assert len(py) == len(c) > 10_000
    for k, (a, b) in enumerate(zip(py, c)):
        assert a == b, f"exchange {k}: python {a} != c {b}"


def test_random_streams_identical():
    rng = random.Random(17)
    targets = [FocTarget(FocOptions(align_s=0.002), backend=b) for b in ("python", "c")]
    for t in targets:
        t.hello(HostHello(0, 1, 50, 0, 100))
    enc = 0
    for k in range(30_000):
        enc = (enc + rng.randint(-12, 12)) & 0xFFFF
        inputs = (8 if rng.random() < 0.002 else 0) | (INPUT_INDEX if rng.random() < 0.01 else 0)
        adc = (rng.randint(0, 4095), rng.randint(0, 4095), rng.randint(3000, 3300))
        s = Sensors(k & 0xFF, inputs, 0xFFFF, enc, adc)
        if k % 5000 == 2500:
            pairs = ((PARAM_IDS["ref_rpm"], rng.randint(-3000, 3000)), (PARAM_IDS["id_kp"], iq(rng.random())))
            assert [t.set_params(pairs) for t in targets][0] == targets[1].set_params(pairs)
        if k % 7000 == 3000:
            for t in targets:
                t.start()
        if k % 3 == 0:
            dur = rng.choice((0.0, 20.0, 50.0, 75.0, 130.0))
            out = [t.advance(dur, s) for t in targets]
        else:
            out = [t.step(s) for t in targets]
        assert out[0] == out[1], f"exchange {k}"
    assert targets[0].watchdog_trip() == targets[1].watchdog_trip()
    py, c = targets[0].fw, targets[1].fw
    assert (py.qep.t2cnt, py.qep.calibrated_angle, py.speed.speed, py.pid_iq.ui) == \
        (c.qep.t2cnt, c.qep.calibrated_angle, c.speed.speed, c.iq_ui)
