"""Bench tests with pytest: the plugin (`hilbench.testing.plugin`, loaded by pytest through the
`pytest11` entry point once hilbench is installed) and the assertions a test uses.

    from hilbench.testing import assert_settles, hil_requires

    @hil_requires("speed_loop")
    def test_holds_1500_rpm(bench):             # once per --hil-target
        bench.set_reference(1500)
        bench.press("s2")
        bench.run(1.5)
        assert_settles(bench, "speed_rpm", 1500, band=30, by_s=1.0)

Names load on first use, so importing this package (pytest does, at start) costs nothing.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import pytest

#: `@hil_requires("fault_injection", firmware="AN1017")`: the marker, importable by name
hil_requires = pytest.mark.hil_requires

_LAZY = {
    "assert_settles": "hilbench.testing.assertions",
    "assert_within": "hilbench.testing.assertions",
    "assert_no_fault": "hilbench.testing.assertions",
    "assert_param": "hilbench.testing.assertions",
    "assert_step": "hilbench.testing.assertions",
    "assert_config_checks": "hilbench.testing.assertions",
    "record_metric": "hilbench.testing.assertions",
    "STEP_BOUNDS": "hilbench.testing.assertions",
    "TargetInfo": "hilbench.testing.targets",
    "bench_process": "hilbench.testing.targets",
    "describe_target": "hilbench.testing.targets",
    "target_id": "hilbench.testing.targets",
    "link_survives": "hilbench.testing.link",
    "LinkReport": "hilbench.testing.link",
    "step_response": "hilbench.testing.steps",
}

if TYPE_CHECKING:
    from hilbench.testing.assertions import (
        STEP_BOUNDS,
        assert_config_checks,
        assert_no_fault,
        assert_param,
        assert_settles,
        assert_step,
        assert_within,
        record_metric,
    )
    from hilbench.testing.link import LinkReport, link_survives
    from hilbench.testing.steps import step_response
    from hilbench.testing.targets import TargetInfo, bench_process, describe_target, target_id


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'hilbench.testing' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


__all__ = ["hil_requires", *sorted(_LAZY)]
