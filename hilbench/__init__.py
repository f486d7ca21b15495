"""hilbench: a hardware-in-the-loop serial bridge and bench for PMSM motor-control firmware.

The public API (docs/api.md)::

    import hilbench

    cfg = hilbench.load_config(None, ["link.period_us=100"])    # the packaged default + overrides
    with hilbench.Bench(cfg) as bench:                         # or Bench(target="inprocess:an1017")
        bench.set_reference(1500)
        bench.press("s2")
        bench.run(1.0)                                         # or run(until=lambda b: ..., timeout_s=5)
        signals = bench.signals()                              # arrays with units, one row per period
    result = hilbench.step_test(from_rpm=1000, to_rpm=2000, params={"kp": 0.2})

Names are loaded on first use, so `import hilbench` is cheap and import order never matters.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hilbench.errors import (
    ConfigError,
    HilbenchError,
    LinkError,
    ParamError,
    ProtocolError,
    RecordingError,
    BenchLimitError,
    TargetError,
)

from hilbench.version import __version__

_LAZY = {
    "Bench": "hilbench.bench.bench",
    "Signals": "hilbench.bench.bench",
    "Summary": "hilbench.bench.summary",
    "load_config": "hilbench.bench.settings",
    "BenchConfig": "hilbench.config",
    "read_recording": "hilbench.bench.recorder",
    "RecordingData": "hilbench.bench.recorder",
    "ControlClient": "hilbench.bench.control",
    "StepTest": "hilbench.bench.steptest",
    "StepResult": "hilbench.bench.steptest",
    "step_test": "hilbench.bench.api",
    "sweep": "hilbench.bench.api",
    "Tolerances": "hilbench.bench.sweep",
    "TargetProfile": "hilbench.targets.profile",
    "TelemetryColumn": "hilbench.targets.profile",
    "PotReference": "hilbench.targets.profile",
    "ParamReference": "hilbench.targets.profile",
    "known_targets": "hilbench.targets.registry",
    "get_profile": "hilbench.targets.registry",
}

if TYPE_CHECKING:
    from hilbench.bench.api import step_test, sweep
    from hilbench.bench.bench import Bench, Signals
    from hilbench.bench.control import ControlClient
    from hilbench.bench.recorder import RecordingData, read_recording
    from hilbench.bench.steptest import StepResult, StepTest
    from hilbench.bench.summary import Summary
    from hilbench.bench.sweep import Tolerances
    from hilbench.bench.settings import load_config
    from hilbench.config import BenchConfig
    from hilbench.targets.profile import ParamReference, PotReference, TargetProfile, TelemetryColumn
    from hilbench.targets.registry import get_profile, known_targets


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'hilbench' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)


__all__ = [
    "Bench",
    "BenchConfig",
    "ConfigError",
    "ControlClient",
    "HilbenchError",
    "LinkError",
    "ParamError",
    "ParamReference",
    "PotReference",
    "ProtocolError",
    "RecordingData",
    "RecordingError",
    "BenchLimitError",
    "Signals",
    "StepResult",
    "StepTest",
    "Summary",
    "TargetError",
    "TargetProfile",
    "TelemetryColumn",
    "Tolerances",
    "__version__",
    "get_profile",
    "known_targets",
    "load_config",
    "read_recording",
    "step_test",
    "sweep",
]
