"""Issue 12, the dsPIC30F2010 port: compiles warning-free, and its RAM fits the chip's 512 bytes.

XC16 cannot be installed here, so the port (ports/dspic30f2010/main.c with the core, the bridge
and the C library) is compiled with host gcc, strict flags, against hostcheck/xc.h, a register
header written for this test.

RAM figure = static + a computed stack bound:
- static: the RAM objects (.bss/.data, not const: XC16 keeps const data in program memory) of the
  host build. No RAM object holds a pointer and x86-64 aligns uint32_t to 4 bytes where the dsPIC
  aligns to 2, so this is an upper bound of the dsPIC's figure.
- stack: the deepest call path of the same sources built for a 16-bit-int, 16-bit-pointer target
  (avr-gcc: -fstack-usage frame sizes, call edges from the disassembly, the one indirect call
  hbp_param_set -> check_gains added by hand), with the dsPIC's larger costs added: +2 bytes per
  call (its return address is 4 bytes, the AVR's 2) and +24 bytes per interrupt level (PC, SR and
  IPL pushed by the hardware: 4; W0-W7 saved by the compiler for an ISR that calls functions: 16;
  RCOUNT and one spare word: 4). On main's stack sits one ISR: PWM, Timer1, Timer2, FLTA and
  UART1 RX share priority 4, so they never nest. In lockstep PWM and Timer1 interrupts are off
  (the firmware's timers are gated); in real time Sensors frames do not go through the bridge's
  on_sensors/an1017_run (the ISRs run the firmware): the bound is the larger of the two modes.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

from _firmware import require_tool
from c_build import STRICT_FLAGS
from hilbench.targets.sil import FIRMWARE_DIR, PROTOCOL_DIR

PORT = FIRMWARE_DIR / "ports" / "dspic30f2010"
SOURCES = (PORT / "main.c", FIRMWARE_DIR / "an1017.c", FIRMWARE_DIR / "an1017_bridge.c", PROTOCOL_DIR / "hbp.c",
           PROTOCOL_DIR / "hbp_messages.c")
DEFS = ("-DHBP_MAX_ADC=3u", "-DHBP_MAX_TELEMETRY=3u", f"-I{PORT / 'hostcheck'}", f"-I{FIRMWARE_DIR}",
        f"-I{PROTOCOL_DIR}")
DSPIC30F2010_RAM_BYTES = 512
ISRS = ("_PWMInterrupt", "_T1Interrupt", "_T2Interrupt", "_FLTAInterrupt", "_U1RXInterrupt")
DSPIC_EXTRA_PER_CALL = 2
DSPIC_ISR_CONTEXT = 24
LOCKSTEP_ISRS = ("_T2Interrupt", "_FLTAInterrupt", "_U1RXInterrupt")
MARGIN_BYTES = 32


@pytest.mark.parametrize("options", [(), ("-DHIL_DRIVE_BRIDGE", "-DHIL_LOCAL_POT"),
                                     ("-DAN1017_VARIANT=AN1017_VARIANT_V11",)], ids=["default", "options", "v11"])
def test_dspic_port_compiles_warning_free(gcc: str, tmp_path: Path, options: tuple[str, ...]) -> None:
    for source in SOURCES:
        result = subprocess.run([gcc, *STRICT_FLAGS, "-Os", *DEFS, *options, "-c", str(source), "-o",
                                 str(tmp_path / (source.stem + ".o"))], capture_output=True, text=True, timeout=120)
        assert result.returncode == 0, result.stderr


def static_ram_bytes(gcc: str, tmp_path: Path) -> dict[str, int]:
    """RAM objects (.bss/.data) of the host build and their sizes."""
    objects = []
    for source in SOURCES:
        obj = tmp_path / (source.stem + ".o")
        subprocess.run([gcc, *STRICT_FLAGS, "-Os", "-fno-pic", "-fno-pie", *DEFS, "-c", str(source), "-o", str(obj)],
                       check=True, capture_output=True, timeout=120)
        objects.append(str(obj))
    out = subprocess.run(["nm", "-S", *objects], capture_output=True, text=True, check=True, timeout=30).stdout
    sizes = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 4 and parts[2] in "bBdD":
            sizes[parts[3]] = int(parts[1], 16)
    return sizes


def stack_bound_bytes(tmp_path: Path) -> tuple[int, dict[str, tuple[int, list[str]]]]:
    avr_gcc = require_tool("avr-gcc", "the computed stack bound of the dsPIC port (apt: gcc-avr avr-libc)")
    elf = tmp_path / "dspic_port_16bit.elf"
    build = tmp_path / "su"
    build.mkdir()
    cmd = [avr_gcc, "-mmcu=atmega328p", "-std=c99", "-Os", "-fstack-usage", *DEFS, *(str(s) for s in SOURCES),
           str(PORT / "hostcheck" / "sfr.c"), "-o", str(elf)]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=180, cwd=build)
    assert result.returncode == 0, result.stderr
    frames: dict[str, int] = {}
    for su in build.glob("*.su"):
        for line in su.read_text().splitlines():
            where, size, _kind = line.split("\t")
            frames[where.rsplit(":", 1)[1]] = max(frames.get(where.rsplit(":", 1)[1], 0), int(size))
    disasm = subprocess.run(["avr-objdump", "-d", str(elf)], capture_output=True, text=True, check=True,
                            timeout=60).stdout
    calls: dict[str, set[str]] = {}
    current = None
    for line in disasm.splitlines():
        head = re.match(r"^[0-9a-f]+ <([^>]+)>:$", line)
        if head:
            current = head.group(1)
            continue
        call = re.search(r"\t(r?call|jmp|rjmp)\t.*<([^>+]+)>$", line)
        if current and call and call.group(2) != current and call.group(2) in frames:
            calls.setdefault(current, set()).add(call.group(2))
    calls.setdefault("hbp_param_set", set()).add("check_gains")  # the constraint callback (icall)

    def deepest(fn: str, seen: tuple[str, ...] = (), skip: str = "") -> tuple[int, list[str]]:
        assert fn not in seen, f"recursion through {fn}"
        best, path = 0, []
        for callee in calls.get(fn, ()):
            if callee == skip:
                continue
            depth, sub = deepest(callee, seen + (fn,), skip)
            depth += 2 + DSPIC_EXTRA_PER_CALL  # the return address, dsPIC-sized
            if depth > best:
                best, path = depth, sub
        return frames.get(fn, 0) + best, [fn, *path]

    paths = {fn: deepest(fn) for fn in ("main", *ISRS)}
    paths["main (real time)"] = deepest("main", skip="on_sensors")
    lockstep = paths["main"][0] + max(paths[f][0] for f in LOCKSTEP_ISRS) + DSPIC_ISR_CONTEXT
    realtime = paths["main (real time)"][0] + max(paths[f][0] for f in ISRS) + DSPIC_ISR_CONTEXT
    return max(lockstep, realtime), paths


def test_dspic_port_ram_fits_512_bytes(gcc: str, tmp_path: Path, capsys) -> None:
    sizes = static_ram_bytes(gcc, tmp_path)
    assert set(sizes) == {"bridge", "tcy_high", "rt_boot_pending", "realtime_on"}, sizes
    static = sum(sizes.values())
    stack, paths = stack_bound_bytes(tmp_path)
    assert "an1017_bridge_handle" in paths["main"][1], paths["main"]  # the analysis found the frame path
    with capsys.disabled():
        print(f"\ndsPIC30F2010 RAM: static {static} B ({', '.join(f'{k} {v}' for k, v in sorted(sizes.items()))}) "
              f"+ stack bound {stack} B = {static + stack} of {DSPIC30F2010_RAM_BYTES} B (margin {MARGIN_BYTES} B "
              f"required); deepest main path {' > '.join(paths['main'][1])}")
    assert static + stack <= DSPIC30F2010_RAM_BYTES - MARGIN_BYTES
