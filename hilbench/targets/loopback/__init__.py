"""The protocol's loopback target: a deterministic mapping of Sensors to Drive, for link tests.

It has no motor control, so it declares no speed loop: `step` and `sweep` refuse it.
"""

from __future__ import annotations

from hilbench.protocol import TelemetryId
from hilbench.targets.profile import TargetProfile, TelemetryColumn


def _make(options: object) -> object:
    from hilbench.targets.loopback.target import LoopbackTarget

    return LoopbackTarget()


PROFILE = TargetProfile(
    name="loopback",
    firmware_name="loopback",
    make=_make,
    description="the protocol's loopback target (echoes the encoder, edge time and seq)",
    telemetry=(
        TelemetryColumn(int(TelemetryId.ECHO_ENCODER), "echo_encoder", "", 1.0, "%d"),
        TelemetryColumn(int(TelemetryId.ECHO_EDGE), "echo_edge_100ns", "100 ns", 1.0, "%d"),
        TelemetryColumn(int(TelemetryId.ECHO_SEQ), "echo_seq", "", 1.0, "%d"),
    ),
    capabilities=frozenset({"realtime", "tuning", "link_check"}),
)

__all__ = ["PROFILE"]
