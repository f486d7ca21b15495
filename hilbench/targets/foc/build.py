"""How the FOC firmware (firmware/foc) is built for a given `[target]` table: its settings as
compiler defines.

The in-process core takes the settings at run time (`firmware_config`); every other build (SIL,
the simulated MCUs, a board) compiles them in: firmware/foc/foc_config.h holds the servo build's
values, and `config_defines(options)` overrides each one that differs, so any `[target]` table
builds the same firmware everywhere.
"""

from __future__ import annotations

from pathlib import Path

from hilbench.targets.foc.firmware import FocOptions, firmware_config

REPO = Path(__file__).resolve().parents[3]
FIRMWARE_DIR = REPO / "firmware" / "foc"
#: the firmware's portable sources (every build compiles these three)
SOURCES = (FIRMWARE_DIR / "foc.c", FIRMWARE_DIR / "foc_blocks.c", FIRMWARE_DIR / "foc_sin_table.c")
HEADERS = (FIRMWARE_DIR / "foc.h", FIRMWARE_DIR / "foc_blocks.h", FIRMWARE_DIR / "foc_config.h",
           FIRMWARE_DIR / "iq24.h")


def _literal(value: int) -> str:
    """A C constant of a 32-bit long (parenthesised when negative, so it survives any context)."""
    if value == -(1 << 31):
        return "(-2147483647L-1L)"
    return f"({value}L)" if value < 0 else f"{value}L"


def config_defines(options: FocOptions = FocOptions()) -> tuple[str, ...]:
    """-DFOC_CFG_* for every setting that differs from the servo build (none for FocOptions())."""
    default = firmware_config(FocOptions())
    values = firmware_config(options)
    return tuple(f"-DFOC_CFG_{key.upper()}={_literal(value)}" for key, value in values.items()
                 if value != default[key])


__all__ = ["FIRMWARE_DIR", "HEADERS", "SOURCES", "config_defines"]
