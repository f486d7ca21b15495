"""The C library is correct with a 16-bit int: built with avr-gcc (int is 16 bits on AVR) and the strict
flags, the library alone and the loopback example as a whole AVR firmware, whose static RAM is read
back with avr-nm.

Needs the apt packages gcc-avr and avr-libc; skips without them, fails under HILBENCH_REQUIRE_TOOLS=1.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from c_build import FIRMWARE_DIR, LIBRARY_SOURCES, STRICT_FLAGS

AN1017_PROFILE = ("-DHBP_MAX_ADC=3u", "-DHBP_MAX_TELEMETRY=3u", "-DHBP_MAX_EDGES=3u", "-DHBP_MAX_BATCH=17u")  # the dsPIC build's
MCUS = ("atmega328p", "atmega2560")
RAM_BUDGET = 128  # bytes of static RAM for the library in the AN1017 profile (issue 10)


@pytest.fixture(scope="module")
def avr_gcc() -> str:
    path = shutil.which("avr-gcc")
    if path is None or shutil.which("avr-nm") is None:
        if os.environ.get("HILBENCH_REQUIRE_TOOLS") == "1":
            pytest.fail("avr-gcc/avr-nm are required (HILBENCH_REQUIRE_TOOLS=1): apt-get install gcc-avr avr-libc")
        pytest.skip("avr-gcc not installed (apt-get install gcc-avr avr-libc)")
    return path


def _avr(avr_gcc: str, mcu: str, sources: list[Path], out: Path, *flags: str) -> Path:
    cmd = [avr_gcc, *STRICT_FLAGS, f"-mmcu={mcu}", "-Os", f"-I{FIRMWARE_DIR}", *flags, *map(str, sources),
           "-o", str(out)]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, f"avr-gcc failed ({' '.join(cmd)}):\n{result.stdout}{result.stderr}"
    return out


def _static_symbols(elf: Path) -> dict[str, int]:
    """Symbols in RAM (.data/.bss: nm types b B d D) -> size in bytes."""
    out = subprocess.run(["avr-nm", "-S", str(elf)], capture_output=True, text=True, timeout=30, check=True).stdout
    sizes = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 4 and parts[2] in "bBdD":
            sizes[parts[3]] = int(parts[1], 16)
    return sizes


@pytest.mark.parametrize("mcu", MCUS)
def test_library_compiles_warning_free_with_a_16_bit_int(avr_gcc: str, mcu: str, tmp_path: Path) -> None:
    for flags in ((), AN1017_PROFILE):
        for src in LIBRARY_SOURCES:
            obj = _avr(avr_gcc, mcu, [src], tmp_path / f"{src.stem}.o", *flags, "-c")
            assert _static_symbols(obj) == {}, "the library keeps no static data of its own"


@pytest.mark.parametrize("mcu", MCUS)
def test_loopback_firmware_builds_and_fits_the_ram_budget(avr_gcc: str, mcu: str, tmp_path: Path) -> None:
    elf = _avr(avr_gcc, mcu, [FIRMWARE_DIR / "examples" / "avr_loopback.c", *LIBRARY_SOURCES],
               tmp_path / "loopback.elf", *AN1017_PROFILE)
    sym = _static_symbols(elf)
    # hbp_rx_t on AVR (no padding): 23 buffer + 10 state + CRC 2 + 5 u16 counters + 1 last_error = 46 bytes
    assert sym["loopback_rx"] == 46
    library = sym["loopback_rx"] + sym["param_values"]  # the receiver + the firmware's three int32 values
    print(f"{mcu}: static RAM of the protocol library (AN1017 profile) {library} B = hbp_rx_t "
          f"{sym['loopback_rx']} + 3 int32 values {sym['param_values']} (budget {RAM_BUDGET}); named static "
          f"symbols of the whole loopback firmware {sum(sym.values())} B (its const tables sit in RAM on an AVR "
          f"without PROGMEM)")
    assert sym["param_values"] == 12
    assert library <= RAM_BUDGET
