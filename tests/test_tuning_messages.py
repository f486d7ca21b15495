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
