"""The AN1017 speed loop: a 1000 -> 2000 rpm step within limits, with its default gains."""

from hilbench.testing import assert_no_fault, assert_step, hil_requires, step_response


@hil_requires("speed_loop", firmware="AN1017")
def test_step_1000_to_2000_rpm_within_limits(bench):
    # measured with the firmware's gains (kp 0.1, ki 0.01): rise 0.33 s, no overshoot,
    # settled (2 %) 0.71 s after the step, 1.2 % short of the reference, 0.61 A peak
    result = step_response(bench, 1000, 2000, settle_s=0.5, after_s=1.0)
    assert_step(result, max_rise_time_s=0.45, max_overshoot_pct=2.0, max_settling_time_s=0.9,
                max_ss_error_pct=2.0, max_peak_current_a=1.0)
    assert_no_fault(bench)
