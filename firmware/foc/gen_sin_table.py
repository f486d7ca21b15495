"""Write foc_sin_table.c: the quarter-wave sine table of the FOC firmware (python gen_sin_table.py).

Entry k is round(sin(2*pi*k/32768) * 2^24), rounded half away from zero, for k = 0..8192: the
values hilbench/targets/foc/iqmath.py gives `_IQsinPU` of a Q15 angle (docs/foc.md, IQmath). The
other three quarters follow by symmetry, exactly (sin(pi - x) and -sin(x) give the same table
entries: tests/test_foc_firmware_c.py checks the whole turn against the Python table).
"""

from __future__ import annotations

import math
from pathlib import Path

ONE = 1 << 24
QUARTER = 8193


def sin_entry(k: int) -> int:
    x = math.sin(2.0 * math.pi * (((k << 9) & (ONE - 1)) / ONE)) * ONE
    return int(math.floor(x + 0.5)) if x >= 0 else -int(math.floor(-x + 0.5))


def render() -> str:
    values = [sin_entry(k) for k in range(QUARTER)]

    def array(name: str, part: list[int]) -> str:
        rows = [", ".join(f"{v}L" for v in part[i:i + 8]) for i in range(0, len(part), 8)]
        return f"const int32_t {name}[{len(part)}] FOC_ROM = {{\n    " + ",\n    ".join(rows) + "\n};\n"

    return (
        "/* foc_sin_table.c: round(sin(2*pi*k/32768) * 2^24), k = 0..8192 (IQ24 _IQsinPU of a Q15 angle).\n"
        " * Written by gen_sin_table.py; do not edit. In flash on every target (PROGMEM on the AVR), in two\n"
        " * arrays: no object on the AVR may exceed 32767 bytes. */\n"
        '#include "foc_blocks.h"\n\n'
        + array("foc_sin_quarter_lo", values[:4096]) + "\n" + array("foc_sin_quarter_hi", values[4096:])
    )


if __name__ == "__main__":
    Path(__file__).with_name("foc_sin_table.c").write_text(render())
