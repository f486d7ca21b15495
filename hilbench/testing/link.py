"""A lossy link a test can demand survival of: lockstep round trips through a seeded fault
injector (`hilbench.link.FaultyLink`) against the protocol's loopback target in its own process.

"Survives" means what the protocol promises on a noisy line: no corrupted Drive is ever
accepted (the loopback target's answer is a known function of the Sensors, so every accepted one
is checked), each lost exchange costs only its own period (the link recovers on the next frame
delimiter), and the errors are counted on both ends.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LinkReport:
    """What a lossy link test saw."""

    periods: int
    good: int  # exchanges with a correct Drive
    lost: int  # exchanges with no Drive in time (a corrupted frame either way)
    mismatches: int  # accepted Drives that were wrong: must be 0
    corrupted_frames_tx: int  # frames the injector damaged, host -> target
    corrupted_frames_rx: int  # ... target -> host
    frame_errors: int  # bad frames the host's link counted
    target_rx_errors: int  # bad frames the target counted (its Status)
    rtt_p50_us: float


def bit_rate_for_byte_rate(byte_rate: float) -> float:
    """The bit error rate that damages ``byte_rate`` of bytes: 1 - (1 - p_byte)^(1/8)."""
    if not 0.0 <= byte_rate < 1.0:
        raise ValueError(f"byte_rate must be in [0, 1), got {byte_rate}")
    return 1.0 - (1.0 - byte_rate) ** (1.0 / 8.0)


def link_survives(*, corrupt_byte_rate: float = 0.01, periods: int = 2000, seed: int = 0,
                  timeout_s: float = 0.02) -> LinkReport:
    """Run ``periods`` lockstep exchanges with the loopback target (`hilbench emulate loopback`
    on a pty, reaped after) through a FaultyLink damaging ``corrupt_byte_rate`` of the bytes both
    ways; returns the counts (it raises LinkError only when 20 exchanges in a row are lost)."""
    from hilbench.bench.linktest import run_link_test
    from hilbench.link import FaultyLink

    injectors: list[FaultyLink] = []

    def wrap(link: object) -> FaultyLink:
        faulty = FaultyLink(link, seed, corrupt_bit_rate=bit_rate_for_byte_rate(corrupt_byte_rate))  # type: ignore[arg-type]
        injectors.append(faulty)
        return faulty

    result = run_link_test("loopback", periods=periods, timeout_s=timeout_s, link_wrapper=wrap)
    injected = injectors[0].injected
    from hilbench.testing.assertions import record_metric

    for name, value in (("good", result.good), ("lost", result.timeouts), ("mismatches", result.mismatches),
                        ("frame_errors", int(result.link.get("frame_errors", 0)))):
        record_metric(f"link.{name}", value)
    return LinkReport(
        periods=result.periods, good=result.good, lost=result.timeouts, mismatches=result.mismatches,
        corrupted_frames_tx=injected.corrupted_frames_tx, corrupted_frames_rx=injected.corrupted_frames_rx,
        frame_errors=int(result.link.get("frame_errors", 0)),
        target_rx_errors=int(result.target_status.get("rx_errors", 0)), rtt_p50_us=result.rtt_p50_us,
    )


__all__ = ["LinkReport", "bit_rate_for_byte_rate", "link_survives"]
