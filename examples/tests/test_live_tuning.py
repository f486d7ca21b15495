"""Guarded live tuning: a gain set that makes the speed oscillate is reverted by the bench's guard."""

from hilbench.testing import assert_param, assert_settles, hil_requires


@hil_requires("tuning", "speed_loop", firmware="AN1017")
def test_a_bad_live_gain_change_is_reverted(bench):
    bench.set_reference(1500)
    bench.press("s2")
    bench.run(1.0)
    kp, ki = bench.get_params()["kp"], bench.get_params()["ki"]
    bench.set_params(kp=0.3, ki=0.6)  # allowed by the firmware's rules, but it oscillates
    bench.run(1.5)
    assert any("guard" in event and "restored" in event for event in bench.events), bench.events[-3:]
    assert_param(bench, "kp", kp)
    assert_param(bench, "ki", ki)
    assert_settles(bench, "speed_rpm", 1500, band=75, by_s=2.3)
