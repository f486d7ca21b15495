"""The 16-bit forms of AN1017's fractional arithmetic (firmware/an1017/q15.h, cut to fit the
dsPIC30F2010) equal the 32-bit forms they replaced (tests/q15_c/q15_before.h), operand by operand:
every second operand against every 5th first operand, and a random 2e7 MACs biased to saturation,
in CI; every operand pair and 2e8 MACs with HILBENCH_LONG_TESTS=1 (~10 s)."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent / "q15_c"


def test_the_16_bit_forms_equal_the_forms_they_replaced(gcc: str, tmp_path: Path) -> None:
    exe = tmp_path / "q15_equal"
    subprocess.run([gcc, "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-Wconversion", "-fsanitize=undefined",
                    "-fno-sanitize-recover=all", f"-I{REPO / 'firmware' / 'an1017'}", f"-I{HERE}",
                    str(HERE / "q15_equal.c"), "-o", str(exe)], check=True, capture_output=True, text=True)
    full = os.environ.get("HILBENCH_LONG_TESTS") == "1"
    done = subprocess.run([str(exe), *(["full"] if full else [])], capture_output=True, text=True, timeout=600)
    print(done.stdout)
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.count(": 0 differ") == 5, done.stdout
