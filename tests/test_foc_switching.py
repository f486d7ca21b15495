"""The FOC servo's closed loop on the switching inverter next to the averaged one (docs/foc.md,
"The inverter edge by edge"); `python -m pytest -s` prints the table.

What physics says, not what either model printed: without a dead time the bridge's ripple averages
out and the ADC samples the period's mean, so the two plants give the same loop; at rated load the
current keeps its sign through every edge but near its zero crossings, so the dead band acts the
same in both; at light load the bridge's dead band has a dead zone (a diode current that reaches
zero stays there until the switch turns on), so torque follows a commanded voltage late: the
load-step dip grows beyond the dead-time-free one and the current gets flat spots at zero, which the
averaged sign term, switching the full error at any nonzero current, does not have.
"""

from __future__ import annotations

import numpy as np
import pytest

from _foc_bench import IndexPlant, servo_params, speed_events, thd
from hilbench.bench.scenario import Event
from hilbench.bench.session import Session, SessionOptions
from hilbench.targets.foc.target import FocTarget

pytestmark = pytest.mark.slow
DT = 50e-6


def run(events, *, model: str, dead: bool, dead_term: str = "sign"):
    plant = IndexPlant(servo_params(dead_time_enabled=dead, model=model, average_dead_time=dead_term), seed=0, substeps=1)
    speeds, currents = [], []
    target = FocTarget()
    inner = target.step

    def step(sensors):  # type: ignore[no-untyped-def]
        speeds.append(plant.speed_rpm)
        currents.append(plant.i_a)
        return inner(sensors)

    target.step = step  # type: ignore[method-assign]
    Session(target, plant, events, SessionOptions(period_us=50, observe_every_periods=10 ** 9)).run()
    return speeds, currents


def thd_at_400(load_nm: float, **kw) -> float:
    ev = [Event(at_s=0.0, press="s2"), Event(at_s=0.2, load_nm=load_nm),
          Event(at_s=0.25, params=(("ref_rpm", 400.0),)), Event(at_s=2.0, end=True)]
    _, i_a = run(ev, **kw)
    return thd(np.array(i_a[round(1.4 / DT):round(2.0 / DT)]), DT, 20.0)


def dip_and_overshoot(**kw) -> tuple[float, float]:
    ev = speed_events((0.2, 1000.0), (1.5, 400.0), end_s=4.2, loads=((2.7, 0.05),))
    speed, _ = run(ev, **kw)
    overshoot = (max(speed[round(0.2 / DT):round(1.5 / DT)]) - 1000.0) / 10.0
    dip = 400.0 - min(speed[round(2.7 / DT):])
    return dip, overshoot


@pytest.fixture(scope="module")
def figures():
    out = {}
    for model, term in (("average", "sign"), ("switching", "sign"), ("average", "edges")):
        name = model if term == "sign" else "average-edges"
        for dead in (False, True):
            if name == "average-edges" and not dead:
                continue
            for load in (0.05, 0.637):
                out[name, "thd", load, dead] = thd_at_400(load, model=model, dead=dead, dead_term=term)
            out[name, "dip", dead], out[name, "overshoot", dead] = dip_and_overshoot(model=model, dead=dead,
                                                                                     dead_term=term)
    print()
    for key, value in sorted(out.items(), key=str):
        print(key, f"{value * 100:.2f} %" if key[1] == "thd" else f"{value:.2f}")
    return out


def test_without_dead_time_the_switching_loop_is_the_averaged_one(figures):
    for load in (0.05, 0.637):
        assert figures["switching", "thd", load, False] < 0.01 and figures["average", "thd", load, False] < 0.01
    assert abs(figures["switching", "dip", False] - figures["average", "dip", False]) < 5.0
    assert abs(figures["switching", "overshoot", False] - figures["average", "overshoot", False]) < 0.3


def test_at_rated_load_the_dead_band_distorts_both_alike(figures):
    sw, av = figures["switching", "thd", 0.637, True], figures["average", "thd", 0.637, True]
    assert 0.02 < sw and abs(sw - av) < 0.01


def test_at_light_load_the_bridges_dead_zone_shows(figures):
    # the clamp's flat spots: more distortion than the sign term gives
    assert figures["switching", "thd", 0.05, True] > figures["average", "thd", 0.05, True] + 0.02
    # torque follows late: the dip is deeper than without a dead time; the sign term's is shallower
    assert figures["switching", "dip", True] > figures["switching", "dip", False] + 10.0
    assert figures["average", "dip", True] < figures["average", "dip", False]
    # the "edges" term has the dead zone's mean effect
    assert abs(figures["average-edges", "dip", True] - figures["switching", "dip", True]) < 0.1 * figures["switching", "dip", True]
