"""Protocol checks: the handshake, parameters that read back, and exact loopback round trips."""

from hilbench.protocol import PROTOCOL_VERSION
from hilbench.testing import assert_param, hil_requires, link_survives


def test_the_handshake_agrees_on_the_protocol(bench, hil_target_info):
    hello = bench.hello
    assert hello.protocol_version == PROTOCOL_VERSION
    assert hello.firmware_name == hil_target_info.firmware_name
    assert hello.n_params == len(bench.get_params())


@hil_requires("tuning", firmware="AN1017")
def test_written_gains_read_back(bench):
    bench.set_params(kp=0.2, ki=0.02)
    assert_param(bench, "kp", 0.2)
    assert_param(bench, "ki", 0.02)


def test_loopback_round_trips_are_exact():
    """The protocol's loopback target in its own process: every Drive is the known answer."""
    report = link_survives(corrupt_byte_rate=0.0, periods=500)
    assert (report.good, report.lost, report.mismatches) == (500, 0, 0)
