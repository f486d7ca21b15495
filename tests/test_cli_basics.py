"""The command line's basic contract: help that teaches, errors without tracebacks."""

from __future__ import annotations

from conftest import run_cli


def test_help_lists_commands() -> None:
    result = run_cli("--help")
    assert result.returncode == 0
    assert "ports" in result.stdout


def test_unknown_command_is_one_line_nonzero() -> None:
    result = run_cli("no-such-command")
    assert result.returncode != 0
    assert "Traceback" not in result.stderr
