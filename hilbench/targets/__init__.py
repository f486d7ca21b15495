"""Targets: one subpackage per firmware, each registering a profile; the remote proxy; serve().

`make_target(name, options)` builds a registered model in this process; `get_profile(name)` is
what the bench knows about it. Outside packages add targets through the ``hilbench.targets``
entry-point group (see `hilbench.targets.registry`).
"""

from __future__ import annotations

from hilbench.targets.profile import (
    MotorBuild,
    ParamReference,
    PotReference,
    TargetProfile,
    TelemetryColumn,
)
from hilbench.targets.registry import (
    DEFAULT_TARGET,
    get_profile,
    known_targets,
    make_target,
    profile_for_firmware,
    register,
)

__all__ = [
    "DEFAULT_TARGET",
    "MotorBuild",
    "ParamReference",
    "PotReference",
    "TargetProfile",
    "TelemetryColumn",
    "get_profile",
    "known_targets",
    "make_target",
    "profile_for_firmware",
    "register",
]
