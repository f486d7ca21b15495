"""Message gaps a new user met (issue 22, item 10): an override key without its unit gets a "did you
mean", and `ctl save` to a folder that does not exist is a file error (exit 1), not a target error."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from hilbench.bench.settings import load_config
from hilbench.cli import cli
from hilbench.errors import ConfigError


def test_an_override_key_without_its_unit_gets_a_did_you_mean() -> None:
    with pytest.raises(ConfigError) as info:
        load_config(None, ["motor.rs=2"])
    assert str(info.value) == "--set motor.rs [motor] rs: unknown key (did you mean 'rs_ohm'?)"


def test_ctl_save_into_a_missing_folder_is_a_file_error(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from _scope_session import running_session

    target = tmp_path / "no" / "such" / "g.toml"
    with running_session() as path:
        result = CliRunner().invoke(cli, ["ctl", "--socket", str(path), "save", str(target)])
    assert result.exit_code == 1, result.output
    assert f"hilbench: file error: {target}: No such file or directory" in result.output
    assert "target error" not in result.output


def test_ctl_get_in_a_terminal_is_a_table_and_json_when_piped() -> None:
    from hilbench.cli import ctl_text

    reply = {"ok": True, "message": "ok", "data": {"params": {"kp": 0.100006103515625, "stall_ms": 100.0},
                                                   "tunable": ["kp"], "ref_rpm": 1500.0, "t_s": 1.25,
                                                   "guard_trips": ["guard: overcurrent: …; restored kp=0.1"]}}
    assert ctl_text("get", reply).splitlines() == [
        "kp        0.100006   (tunable)", "stall_ms  100", "reference 1500 rpm at t=1.250 s",
        "guard: overcurrent: …; restored kp=0.1"]
    assert ctl_text("ref", {"ok": True, "message": "reference 1500 rpm at t=1.0000 s"}) == "reference 1500 rpm at t=1.0000 s"


def test_a_target_table_written_for_another_firmware_is_named_once() -> None:
    """The servo config's [target] (the FOC firmware's options) with --target inprocess:an1017 listed
    nine "unknown key" lines; now one line names the target it belongs to. Typos still get theirs."""
    from conftest import BENCH_CONFIGS

    with pytest.raises(ConfigError) as info:
        load_config(BENCH_CONFIGS / "servo_200w.toml", ['link.target="inprocess:an1017"'])
    text = str(info.value)
    assert "[target]: align_current_a, align_s, cur_ki, cur_kp, … (9 keys): these are the foc target's options" in text
    assert "unknown key" not in text
    with pytest.raises(ConfigError) as info:
        load_config(None, ["target.kpp=0.1", "target.kii=0.1"])
    assert "[target] kpp: unknown key (did you mean 'kp'?)" in str(info.value)
