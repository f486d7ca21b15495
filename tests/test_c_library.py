"""The C target library builds cleanly with strict flags and stays inside its RAM budget."""

from __future__ import annotations

import subprocess
from pathlib import Path

from c_build import FIRMWARE_DIR, LIBRARY_SOURCES, build_c

AN1017_PROFILE = ("-DHBP_MAX_ADC=3u", "-DHBP_MAX_TELEMETRY=3u", "-DHBP_MAX_EDGES=3u", "-DHBP_MAX_BATCH=17u")  # the dsPIC build's


def test_library_compiles_strict(gcc: str, tmp_path: Path) -> None:
    for flags in ((), AN1017_PROFILE, ("-Wsign-conversion", "-O2")):
        for src in LIBRARY_SOURCES:
            build_c([src], tmp_path / (src.stem + ".o"), extra_flags=(*flags, "-c"))


def test_static_ram_under_budget_for_an1017_profile(gcc: str, tmp_path: Path) -> None:
    exe = build_c([FIRMWARE_DIR / "tests" / "ram_usage.c", *LIBRARY_SOURCES], tmp_path / "ram",
                  extra_flags=AN1017_PROFILE)
    out = subprocess.run([str(exe)], capture_output=True, text=True, timeout=30, check=True).stdout
    sizes = dict((k, int(v)) for k, v in (line.split() for line in out.splitlines()))
    # the largest host->target message in the profile is ParamSet: type, seq, 4 x (id u8, i32) = 22,
    # then its trailing length byte
    assert sizes["HBP_RX_MAX"] == 23
    # 23 buffer + 10 state + CRC 2 + 5 u16 counters + last_error = 46 (stated in hbp.h and PROTOCOL.md);
    # 16-bit alignment pads it to 48
    assert 46 <= sizes["hbp_rx_t"] <= 48
    print(f"static RAM, AN1017 profile: hbp_rx_t {sizes['hbp_rx_t']} B + 3 int32 parameter values 12 B "
          f"= {sizes['hbp_rx_t'] + 12} B (budget 128)")
    assert sizes["hbp_rx_t"] + 3 * 4 <= 128  # plus the loopback's three parameter values
    # the library itself has no static data at all (nm: no .bss/.data symbols); -fno-pie: the const
    # layout tables hold pointers, which a position-independent build would put in .data.rel.ro
    for src in LIBRARY_SOURCES:
        obj = build_c([src], tmp_path / (src.stem + ".o"), extra_flags=(*AN1017_PROFILE, "-fno-pie", "-c"))
        nm = subprocess.run(["nm", str(obj)], capture_output=True, text=True, timeout=30, check=True).stdout
        assert not [line for line in nm.splitlines() if line.split()[-2:-1] and line.split()[-2] in "bBdD"], nm
