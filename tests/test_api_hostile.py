"""The Python API's wrong calls are one HilbenchError each, never a traceback from deep inside
(third audit: step_test(from_rpm=nan) raised ValueError in the pot's code, step_test(params=[1]) and
sweep({"kp": 0.1}) TypeError, Bench(target=5) AttributeError at open)."""

from __future__ import annotations

import math

import pytest

import hilbench
from hilbench.errors import ConfigError


@pytest.mark.parametrize(("call", "says"), [
    (lambda: hilbench.step_test(from_rpm=math.nan), "step: from_rpm=nan: expected a finite number"),
    (lambda: hilbench.step_test(to_rpm=10**5000), "step: to_rpm=<an integer of 16610 bits>"),
    (lambda: hilbench.step_test(settle_s=math.inf), "step: settle_s=inf: expected a finite number"),
    (lambda: hilbench.step_test(params=[1]), "step_test params=[1]: expected a mapping"),
    (lambda: hilbench.sweep({"kp": 0.1}), "sweep axes={'kp': 0.1}: expected a mapping of names to lists"),
    (lambda: hilbench.sweep([("kp", [0.1])]), "sweep axes=[('kp', [0.1])]: expected a mapping"),
    (lambda: hilbench.Bench(target=5), "Bench: target=5: a target spec"),
])
def test_a_wrong_call_is_one_config_error(call, says: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ConfigError) as caught:
        call()
    assert str(caught.value).startswith(says)
