"""Bench.set_params takes keywords or one mapping; anything else is one ConfigError, never a silent
write of nothing (a dict passed positionally used to become the guard flag: an empty set the
firmware refused as a bad request)."""

from __future__ import annotations

import pytest

import hilbench
from hilbench.errors import ConfigError


def test_a_mapping_and_keywords_write_the_same() -> None:
    with hilbench.Bench(target="inprocess:an1017") as bench:
        bench.set_params({"kp": 0.2}, guard=False)
        assert bench.get_params()["kp"] == pytest.approx(0.2, abs=1 / 32768)
        bench.set_params(kp=0.3, guard=False)
        assert bench.get_params()["kp"] == pytest.approx(0.3, abs=1 / 32768)


@pytest.mark.parametrize("call", [
    lambda b: b.set_params(),
    lambda b: b.set_params([("kp", 0.1)]),
    lambda b: b.set_params(kp="fast"),
    lambda b: b.set_params({"kp": None}),
])
def test_a_wrong_call_is_one_config_error(call) -> None:  # type: ignore[no-untyped-def]
    with hilbench.Bench(target="inprocess:an1017") as bench:
        with pytest.raises(ConfigError, match="set_params"):
            call(bench)
