"""The protocol's loopback target: a deterministic mapping of Sensors to Drive, for link tests.

It has no motor control, so it declares no speed loop: `step` and `sweep` refuse it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hilbench.protocol import TelemetryId
from hilbench.targets.profile import TargetProfile, TelemetryColumn

if TYPE_CHECKING:
    from hilbench.targets.base import Target


def _make(options: None) -> "Target":
    from hilbench.targets.loopback.target import LoopbackTarget

    return LoopbackTarget()


PROFILE: TargetProfile[None] = TargetProfile(
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
