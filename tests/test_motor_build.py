"""The bench refuses a plant the firmware is not built for (issue 11, finding 2)."""

from __future__ import annotations

from pathlib import Path

import pytest

import hilbench
from conftest import run_cli

REPO = Path(__file__).resolve().parent.parent


def _four_pole_pair_config(tmp_path: Path, extra: str = "") -> Path:
    text = (REPO / "bench_configs" / "hurst_mclv.toml").read_text().replace("pole_pairs = 5", "pole_pairs = 4")
    assert "pole_pairs = 4" in text
    path = tmp_path / "four_pp.toml"
    path.write_text(text + '\n[link]\ntarget = "inprocess:an1017"\n' + extra)
    return path


def test_cli_refuses_a_four_pole_pair_motor_on_an1017_in_one_line(tmp_path: Path) -> None:
    result = run_cli("run", str(_four_pole_pair_config(tmp_path)), timeout=120)
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, result.stderr
    assert "4 pole pairs" in lines[0] and "built for 5" in lines[0], lines[0]
    assert "Traceback" not in result.stderr


def test_the_api_refuses_it_too_and_the_config_may_allow_it(tmp_path: Path) -> None:
    with pytest.raises(hilbench.ConfigError, match="4 pole pairs.*built for 5"):
        with hilbench.Bench(_four_pole_pair_config(tmp_path)):
            pass
    allowed = _four_pole_pair_config(tmp_path, "allow_pole_pair_mismatch = true\n")
    with hilbench.Bench(allowed) as bench:
        bench.run(0.01)


def test_a_profile_without_a_build_is_not_checked(tmp_path: Path) -> None:
    text = (REPO / "bench_configs" / "hurst_mclv.toml").read_text().replace("pole_pairs = 5", "pole_pairs = 4")
    path = tmp_path / "loop.toml"
    path.write_text(text + '\n[link]\ntarget = "inprocess:loopback"\n')
    cfg = hilbench.load_config(path)
    profile = hilbench.get_profile("loopback")
    assert profile.built_for(cfg.target) is None
    from hilbench.bench.settings import check_motor_build

    check_motor_build(cfg, profile)  # no build stated: nothing to refuse
