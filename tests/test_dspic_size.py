"""Issue 24: the dsPIC30F2010 build's flash estimate without XC16 (`make size` in the port's folder,
size_estimate.py: clang --target=msp430 objects, --gc-sections' reachability, one 24-bit word per
MSP430 instruction, constants at 2 bytes a word, stated allowances; docs/board.md "Does it fit")."""

from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from _firmware import require_tool
from hilbench.targets.sil import FIRMWARE_DIR, RUNTIME_SOURCES

REPO = Path(__file__).resolve().parents[1]
from test_firmware_dspic import DEFS

PORT = FIRMWARE_DIR / "ports" / "dspic30f2010"
LAST_LINE = re.compile(r"^flash estimate: ([\d ]+) of ([\d ]+) bytes = ([\d.]+) %$")
FLASH_LIMIT_PERCENT = 85.0


def _tools() -> None:
    for tool in ("clang", "llvm-objdump", "llvm-readelf"):
        require_tool(tool, "the dsPIC flash estimate (apt: clang llvm)")
    require_tool("make", "the dsPIC Makefile (apt: make)")


def _estimator():
    spec = importlib.util.spec_from_file_location("size_estimate", PORT / "size_estimate.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["size_estimate"] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def _make_size(device: str, *extra: str) -> tuple[str, float]:
    done = subprocess.run(["make", "-s", "-C", str(PORT), "size", f"DEVICE={device}", *extra], capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    last = done.stdout.strip().splitlines()[-1]
    match = LAST_LINE.match(last)
    assert match, last
    estimate, flash = (int(match.group(i).replace(" ", "")) for i in (1, 2))
    assert abs(100.0 * estimate / flash - float(match.group(3))) < 0.05
    return done.stdout, float(match.group(3))


def test_reachability_keeps_what_a_gc_linker_keeps(tmp_path: Path) -> None:
    """A hand-made case: main calls used() through a pointer in data and reads a const table, an ISR
    calls isr_helper(); unused() and its string are dropped; a library call is listed, not counted."""
    _tools()
    source = tmp_path / "case.c"
    source.write_text(
        "static const char text[] = \"never referenced from a root\";\n"
        "__attribute__((noinline)) int used(int x) { return x + 1; }\n"
        "__attribute__((noinline)) int unused(int x) { return text[x] + 2; }\n"
        "int (*volatile pick)(int) = used;\n"
        "static const int ramp[4] = {1, 2, 3, 5};\n"
        "volatile long v;\n"
        "volatile unsigned char which;\n"
        "__attribute__((noinline)) void isr_helper(void) { v = v * v; }\n"
        "void _T1Interrupt(void) { isr_helper(); }\n"
        "int main(void) { return pick(ramp[which & 3u]); }\n")
    est = _estimator()
    objects = est.compile_objects([], [str(source)], "-O1", tmp_path)
    kept = est.kept(objects)
    out = subprocess.run(["llvm-objdump", "-d", "--no-show-raw-insn", str(objects[0])], capture_output=True,
                         text=True, check=True, timeout=60).stdout
    bodies = re.split(r"\n(?=Disassembly of section)", out)
    want = sum(len(re.findall(r"^\s+[0-9a-f]+:\s+\S", b, re.M)) for b in bodies
               if re.search(r"section \.text\.(used|isr_helper|_T1Interrupt|main):", b))
    assert kept.instructions == want
    assert kept.helpers == ("__mspabi_mpyl",)
    assert kept.const_bytes == 8  # ramp; the string only unused() reads is dropped
    assert kept.data_bytes == 2  # pick, a 16-bit pointer
    assert kept.bss_bytes == 5  # v and which


def test_size_estimate_of_the_dspic_builds(capsys) -> None:
    """`make size` prints the method and a last line with the estimate. The 48 KB dsPIC30F4012 (the
    pin-compatible part) has room; whether the 12 KB dsPIC30F2010 does is the next test's."""
    _tools()
    text, percent = _make_size("30F4012")
    with capsys.disabled():
        print("\n" + text)
    assert percent <= FLASH_LIMIT_PERCENT


def test_host_only_code_is_not_kept() -> None:
    """The host's side of the protocol (unpacking TargetHello, Drive, ParamInfo...) is compiled into
    the objects but nothing on the target reaches it: the estimate (and XC16's --gc-sections) drops it."""
    _tools()
    est = _estimator()
    sources = [str(PORT / "main.c"), str(FIRMWARE_DIR / "an1017.c"), *(str(s) for s in RUNTIME_SOURCES)]
    with tempfile.TemporaryDirectory() as tmp:
        kept = est.kept(est.compile_objects(list(DEFS), sources, "-O1", Path(tmp)))
    assert ".text.on_sensors" in kept.sections and ".text.an1017_isr_timer1" in kept.sections
    host_side = re.compile(r"\.text\.hbp_(unpack_(target_hello|drive|param_info)|pack_sensors)")
    kept_host_code = [s for s in kept.sections if host_side.match(s)]
    assert not kept_host_code, kept_host_code


@pytest.mark.xfail(strict=True, reason="issue 24: by the estimate the dsPIC30F2010 build does not fit its 12 KB "
                                       "(112.3 % at -O1, 108.1 % at -Os); docs/board.md 'Does it fit'")
def test_dspic30f2010_build_fits_with_15_percent_margin(capsys) -> None:
    _tools()
    text, percent = _make_size("30F2010")
    with capsys.disabled():
        print("\n" + text)
    assert percent <= FLASH_LIMIT_PERCENT


LEVEL_LINE = re.compile(r"^  (-O1|-Os): (\d+) instructions .*constants (\d+) B, data \d+ B, bss (\d+) B, "
                        r".*-> (\d+) words = (\d+) B$")


def _grouped(n: int) -> str:
    return f"{n:,}".replace(",", " ")


def test_board_guide_quotes_what_make_size_prints() -> None:
    """docs/board.md section 3a's table and static RAM figure are the ones `make size` prints (so the
    guide cannot keep an old estimate), and the RAM is within the 222 bytes of before protocol 3
    (issue 27: the dsPIC30F2010 build's RAM does not grow)."""
    _tools()
    text, _percent = _make_size("30F2010")
    guide = (REPO / "docs" / "board.md").read_text()
    levels = {m.group(1): m for m in map(LEVEL_LINE.match, text.splitlines()) if m}
    assert set(levels) == {"-O1", "-Os"}, text
    for level, m in levels.items():
        instructions, constants, bss, words, flash = (int(m.group(i)) for i in range(2, 7))
        assert flash == 3 * words
        row = re.search(rf"^\|[^|\n]*`{level}`[^|\n]*\| (.+) \|$", guide, re.M)
        assert row, f"docs/board.md has no table row for {level}"
        cells = [c.strip().strip("*") for c in row.group(1).split("|")]
        assert cells == [_grouped(instructions), f"{constants} B", _grouped(words), _grouped(flash),
                         f"{100.0 * flash / 12288:.1f} %", f"{100.0 * flash / 49152:.1f} %"], (level, cells)
        assert bss <= 222, f"static RAM {bss} B at {level}: more than the 222 B of before protocol 3"
        assert f"Static RAM (msp430, 2-byte aligned): {bss} bytes of 512" in guide


def test_board_guide_quotes_the_real_motor_builds_estimate() -> None:
    """docs/board.md section 13a's figures for `make size MODE=motor` (the real-motor build, halls,
    pot and the monitor stream instead of the lockstep scheduler) are the ones it prints."""
    _tools()
    guide = (REPO / "docs" / "board.md").read_text()
    for device, flash in (("30F2010", 12288), ("30F4012", 49152)):
        text, percent = _make_size(device, "MODE=motor")
        estimate = int(LAST_LINE.match(text.strip().splitlines()[-1]).group(1).replace(" ", ""))
        assert f"{estimate:,}".replace(",", " ") in guide and f"{percent:.1f} %" in guide, (device, estimate, percent)
        ram = re.search(r"static RAM \(msp430[^)]*\): (\d+) B of", text)
        assert ram and f"static RAM: {ram.group(1)} of 512 bytes" in guide, text
        assert "8 handlers x 16 words" in text, text  # CN, IC7 and IC8 beside the HIL build's five
