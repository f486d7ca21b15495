"""A lossy line: 1 % of the bytes corrupted both ways, and the protocol must survive it."""

from hilbench.testing import link_survives


def test_a_link_with_1_percent_corrupted_bytes_survives():
    report = link_survives(corrupt_byte_rate=0.01, periods=1000, seed=7, timeout_s=0.005)
    assert report.mismatches == 0, "a corrupted Drive was accepted"
    assert report.good + report.lost == report.periods and report.good > 0.5 * report.periods
    assert report.corrupted_frames_rx > 0 and report.corrupted_frames_tx > 0  # the line was lossy
    assert report.frame_errors > 0  # and the host counted the bad frames it threw away
