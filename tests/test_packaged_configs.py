"""Both seed systems' benches are installed with hilbench (issue 22, item 8): `hilbench run
servo_200w` and `extends = "packaged:servo_200w"` work outside the clone, where the servo config was
"cannot read"."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from conftest import BENCH_CONFIGS, REPO_ROOT
from hilbench.bench.settings import load_config
from hilbench.config import packaged_configs
from hilbench.errors import ConfigError


def test_the_packaged_configs_are_the_repository_s() -> None:
    assert packaged_configs() == ("hurst_mclv", "servo_200w")
    for name in packaged_configs():
        assert (REPO_ROOT / "hilbench" / "data" / f"{name}.toml").read_text() == (BENCH_CONFIGS / f"{name}.toml").read_text()


def test_a_packaged_config_by_name_and_by_extends(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # no bench_configs here
    servo = load_config("servo_200w")
    assert servo.source == "<packaged servo_200w.toml>" and servo.link.target == "inprocess:foc"
    assert load_config("packaged:servo_200w.toml").motor == servo.motor
    mine = tmp_path / "mine.toml"
    mine.write_text('extends = "packaged:servo_200w"\n[motor]\nrs_ohm = 6.0\n')
    assert load_config(mine).motor.rs_ohm == 6.0 and load_config(mine).link.target == "inprocess:foc"
    with pytest.raises(ConfigError, match=r"packaged:servo: no packaged config of that name .*did you mean 'servo_200w'"):
        load_config("packaged:servo")
    (tmp_path / "servo_200w").mkdir()  # a name that is something here is that thing, not the packaged one
    with pytest.raises((ConfigError, OSError)):
        load_config("servo_200w")


@pytest.mark.slow
def test_run_servo_200w_from_another_directory(tmp_path: Path) -> None:
    run = subprocess.run([sys.executable, "-m", "hilbench", "run", "servo_200w", "--no-ui", "--no-control",
                          "--duration", "0.2"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert run.returncode in (0, 9), run.stderr  # 9: a check of the config judged a 0.2 s run
    assert "target: inprocess:foc" in run.stdout and "ended: completed" in run.stdout
