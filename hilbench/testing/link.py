"""A lossy link a test can demand survival of: lockstep round trips through a seeded fault
injector (a target spec's fault keys: `hilbench.link.FaultyLink`) against the protocol's loopback
target in its own process.

"Survives" means what the protocol and the host promise on a noisy line: no corrupted Drive is
ever accepted (the loopback target's answer is a known function of the Sensors, so every accepted
one is checked), a lost frame costs a retry of the same Sensors, not the exchange (the target
answers a repeated seq with its Drive again), and the bad frames are counted.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LinkReport:
    """What a lossy link test saw."""

    periods: int
    good: int  # exchanges answered with the right Drive (after retries)
    lost: int  # exchanges with no Drive within the timeout, retries included
    mismatches: int  # accepted Drives that were wrong: must be 0
    retries: int  # frames the host sent again after no answer within retry_s
    corrupted_frames_tx: int  # frames the injector damaged, host -> target
    corrupted_frames_rx: int  # ... target -> host
    frame_errors: int  # bad frames the host's link counted and threw away


def bit_rate_for_byte_rate(byte_rate: float) -> float:
    """The bit error rate that damages ``byte_rate`` of bytes: 1 - (1 - p_byte)^(1/8)."""
    if not 0.0 <= byte_rate < 1.0:
        raise ValueError(f"byte_rate must be in [0, 1), got {byte_rate}")
    return 1.0 - (1.0 - byte_rate) ** (1.0 / 8.0)


def link_survives(*, corrupt_byte_rate: float = 0.01, periods: int = 2000, seed: int = 0,
                  timeout_s: float = 0.5, retry_s: float = 0.005) -> LinkReport:
    """Run ``periods`` lockstep exchanges with the loopback target in its own process over a link
    damaging ``corrupt_byte_rate`` of the bytes both ways (the spec
    ``emulator:loopback?corrupt=P&fault_seed=SEED``; the process is reaped after). The host sends
    a frame again after ``retry_s`` without its answer, as a bench does; every Drive it accepts is
    checked against the loopback's known answer."""
    from hilbench.bench.launcher import open_target
    from hilbench.bench.linktest import sensors_for_period
    from hilbench.errors import LinkTimeout
    from hilbench.protocol import MODE_LOCKSTEP
    from hilbench.targets.loopback.target import LoopbackTarget
    from hilbench.testing.assertions import record_metric

    spec = "emulator:loopback"
    if corrupt_byte_rate > 0:
        spec += f"?corrupt={bit_rate_for_byte_rate(corrupt_byte_rate)!r}&fault_seed={seed}"
    good = lost = mismatches = 0
    with open_target(spec, timeout_s=timeout_s, retry_s=retry_s) as handle:
        remote = handle.target
        remote.handshake(50, MODE_LOCKSTEP, 0, attempts=10)  # type: ignore[attr-defined]
        expected = LoopbackTarget()
        for k in range(periods):
            sensors = sensors_for_period(k)
            want = expected.step(sensors)
            try:
                drive = remote.step(sensors)
            except LinkTimeout:
                lost += 1
                continue
            if drive == want:
                good += 1
            else:
                mismatches += 1
        injected = getattr(handle.link, "injected", None)
        report = LinkReport(
            periods=periods, good=good, lost=lost, mismatches=mismatches,
            retries=int(getattr(remote, "retries", 0)),
            corrupted_frames_tx=injected.corrupted_frames_tx if injected is not None else 0,
            corrupted_frames_rx=injected.corrupted_frames_rx if injected is not None else 0,
            frame_errors=int(handle.link.stats.as_dict().get("frame_errors", 0)),
        )
    for name in ("good", "lost", "mismatches", "retries", "frame_errors"):
        record_metric(f"link.{name}", getattr(report, name))
    return report


__all__ = ["LinkReport", "bit_rate_for_byte_rate", "link_survives"]
