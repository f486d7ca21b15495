"""A lossy line: 1 % of the bytes corrupted both ways, and the protocol must survive it."""

from hilbench.testing import link_survives


def test_a_link_with_1_percent_corrupted_bytes_survives():
    report = link_survives(corrupt_byte_rate=0.01, periods=1000, seed=7)
    assert report.corrupted_frames_rx > 0 and report.corrupted_frames_tx > 0  # the line was lossy
    assert report.mismatches == 0, "a corrupted Drive was accepted"
    assert (report.good, report.lost) == (report.periods, 0), "an exchange was lost despite retries"
    assert report.retries > 0 and report.frame_errors > 0  # lost frames were sent again, bad ones counted
