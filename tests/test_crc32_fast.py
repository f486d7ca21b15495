"""hilbench/bench/_crc32.h: crc32_fast equals zlib.crc32 on its PCLMULQDQ path and on its portable
slice-by-8 path (-DHILBENCH_CRC32_PORTABLE), and its folding constants are the ones derived here."""

from __future__ import annotations

import ctypes
import platform
import random
import re
import subprocess
import zlib
from pathlib import Path

import pytest

HEADER_DIR = Path(__file__).resolve().parent.parent / "hilbench" / "bench"
PROJECT_FLAGS = ["-O2", "-std=c99", "-ffp-contract=off", "-fno-fast-math", "-Wall", "-Wextra", "-Werror"]
WRAPPER = """#include "_crc32.h"
uint32_t hb_test_crc(uint32_t crc, const unsigned char *p, size_t n) { return crc32_fast(crc, p, n); }
void hb_test_init(void) { crc32_init_tables(); }
int hb_test_accelerated(void) { return crc32_accelerated(); }
"""

pytestmark = pytest.mark.gcc


def xmod(e: int) -> int:
    """x^e mod P over GF(2), P = the CRC-32 polynomial (bit d = coefficient of x^d)."""
    r = 1
    for _ in range(e):
        r <<= 1
        if r >> 32:
            r ^= 0x104C11DB7
    return r


def lane(e: int) -> int:
    """x^e mod P in a 64-bit PCLMULQDQ lane's reflected order (x^d at bit 63 - d)."""
    return int(f"{xmod(e):032b}"[::-1], 2) << 32


def test_the_folding_constants_are_derived() -> None:
    text = (HEADER_DIR / "_crc32.h").read_text()
    found = {int(e): int(v, 16) for e, v in re.findall(r"#define HB_CRC32_X(\d+) (0x[0-9a-fA-F]+)ULL", text)}
    assert found == {e: lane(e) for e in (575, 511, 191, 127)}
    assert int(f"{0x104C11DB7 & 0xFFFFFFFF:032b}"[::-1], 2) == 0xEDB88320


def build(tmp_path: Path, gcc: str, *defines: str) -> ctypes.CDLL:
    source = tmp_path / "crc_wrapper.c"
    source.write_text(WRAPPER)
    out = tmp_path / f"crc{'_'.join(defines)}.so"
    cmd = [gcc, *PROJECT_FLAGS, "-fPIC", "-shared", f"-I{HEADER_DIR}", *defines, str(source), "-o", str(out)]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    lib = ctypes.CDLL(str(out))
    lib.hb_test_crc.restype = ctypes.c_uint32
    lib.hb_test_crc.argtypes = [ctypes.c_uint32, ctypes.c_void_p, ctypes.c_size_t]
    return lib


def cpu_has_pclmul() -> bool:
    if platform.machine() not in ("x86_64", "AMD64"):
        return False
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    return bool(re.search(r"\bpclmulqdq\b", flags) and re.search(r"\bsse4_1\b", flags))


@pytest.mark.parametrize("portable", [False, True], ids=["default", "portable"])
def test_crc32_fast_equals_zlib(tmp_path: Path, gcc: str, portable: bool) -> None:
    lib = build(tmp_path, gcc, *(["-DHILBENCH_CRC32_PORTABLE"] if portable else []))
    rng = random.Random(1234)
    data = bytes(rng.getrandbits(8) for _ in range(400))
    buf = ctypes.create_string_buffer(data, len(data))
    base = ctypes.addressof(buf)

    # before crc32_init_tables: the bit-at-a-time fallback, still exact
    assert lib.hb_test_crc(0, base, 300) == zlib.crc32(data[:300])
    lib.hb_test_init()
    lib.hb_test_init()  # idempotent
    expected_accel = 0 if portable else int(cpu_has_pclmul())
    assert lib.hb_test_accelerated() == expected_accel

    for offset in range(16):
        for n in range(301):
            crc = rng.getrandbits(32) if n % 3 else 0
            chunk = data[offset:offset + n]
            assert lib.hb_test_crc(crc, base + offset, n) == zlib.crc32(chunk, crc), (offset, n, crc)

    big = rng.randbytes((1 << 20) + 16)
    big_buf = ctypes.create_string_buffer(big, len(big))
    big_base = ctypes.addressof(big_buf)
    for offset, n in ((0, 1 << 20), (0, (1 << 20) + 7), (3, (1 << 20) + 7), (9, 1 << 20)):
        crc = rng.getrandbits(32)
        assert lib.hb_test_crc(crc, big_base + offset, n) == zlib.crc32(big[offset:offset + n], crc)
    for fill in (b"\x00", b"\xff"):
        for n in (1, 15, 16, 63, 64, 65, 1000, 1 << 20):
            block = fill * n
            for crc in (0, 0xFFFFFFFF):
                assert lib.hb_test_crc(crc, block, n) == zlib.crc32(block, crc), (fill, n, crc)
    # chained: a buffer in uneven pieces
    crc = 0
    for start, stop in ((0, 5), (5, 100), (100, 1 << 19), (1 << 19, (1 << 20) + 3)):
        crc = lib.hb_test_crc(crc, big_base + start, stop - start)
    assert crc == zlib.crc32(big[:(1 << 20) + 3])
