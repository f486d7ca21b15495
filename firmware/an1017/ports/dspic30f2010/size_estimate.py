#!/usr/bin/env python3
"""Flash and static-RAM estimate of the dsPIC30F2010 build without XC16 (docs/board.md, "Does it fit").

    python3 size_estimate.py [--device 30F2010|30F4012] -- CFLAGS... -- SOURCES...

(`make size` in this folder runs it with the Makefile's own sources and defines.) Method:
1. Compile every source of the build with `clang --target=msp430` (a 16-bit target with 16-bit
   registers and pointers, like the dsPIC), at -O1 (what XC16's free licence allows) and at -Os
   (a PRO licence), with function and data sections; hostcheck/xc.h stands in for <xc.h>. At -O1
   with clang's inliner held to functions declared `inline` (-finline-hint-functions), as XC16's
   GCC inliner is at -O1: its -finline-small-functions (inlining functions not declared inline) is
   on at -O2, -O3 and -Os only (XC16 user's guide), while clang's -O1 inlines any function under its
   cost threshold, copying e.g. the link's field writers into every reply.
2. Keep what the linker's --gc-sections would keep: the sections reachable through relocations from
   main and the interrupt handlers (no msp430 linker here, so the reachability is computed).
3. Convert to dsPIC program words: one 24-bit word per MSP430 instruction kept; constants and the
   initial values of data at 2 bytes per word (the dsPIC reads program memory through its 16-bit
   PSV window, the upper byte of each word unused); a fixed allowance for what the msp430 objects
   lack: the interrupt vector tables, start-up code, interrupt prologues, and the run-time library
   routines the objects call (32-bit multiply and divide), sized as stated in ALLOWANCE_WORDS.
4. Bytes = words x 3, the unit of the data sheet's "12 Kbytes".
Prints the method, the figures of both optimisation levels, and last the verdict line at -O1.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

#: program flash in bytes (words x 3) and RAM in bytes, DS70118 / DS70135
DEVICES = {"30F2010": (12288, 512), "30F4012": (49152, 2048)}
#: one interrupt handler's context save and restore, in words
HANDLER_WORDS = 16


def allowance_words(handlers: int = 5) -> dict[str, int]:
    """Words added for what the msp430 objects do not hold (docs/board.md explains each figure);
    ``handlers``: the build's interrupt handlers (the HIL build 5, the real-motor build 8)."""
    return {
        "reset vector + IVT + AIVT (program addresses 0x000-0x0FF)": 128,
        "C start-up (stack, PSV, .data/.bss init loop)": 48,
        f"interrupt prologue/epilogue, {handlers} handlers x {HANDLER_WORDS} words (W0-W7, RCOUNT, PSVPAG push/pop, "
        "RETFIE)": HANDLER_WORDS * handlers,
        "run-time library: 32-bit multiply, 32/32 and 32/16 divide and remainder, memset": 160,
    }


ALLOWANCE_WORDS = allowance_words()
ROOTS = re.compile(r"^(main|_\w+Interrupt)$")
#: how many of the largest kept sections `make size` names (what to cut next)
LARGEST = 16


@dataclass(frozen=True)
class Kept:
    """What --gc-sections would keep of the objects, as the msp430 compiler made them."""
    instructions: int
    code_bytes: int
    const_bytes: int
    data_bytes: int
    bss_bytes: int
    helpers: tuple[str, ...]
    sections: tuple[str, ...]
    words: tuple[tuple[int, str], ...] = ()  # dsPIC words of each kept section, largest first


def _run(argv: list[str]) -> str:
    done = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    if done.returncode != 0:
        errors = [line for line in done.stderr.splitlines() if "error" in line] or done.stderr.splitlines()[-1:]
        sys.exit(f"size_estimate: {argv[0]} failed: {errors[0] if errors else 'exit ' + str(done.returncode)}")
    return done.stdout


def _sections(obj: Path) -> tuple[dict[str, int], dict[str, str]]:
    """Section sizes, and each defined symbol's section (index -> name resolved)."""
    names, sizes = {}, {}
    for line in _run(["llvm-readelf", "-S", "-W", str(obj)]).splitlines():
        m = re.match(r"\s*\[\s*(\d+)\]\s+(\S+)\s+\S+\s+[0-9a-f]+\s+[0-9a-f]+\s+([0-9a-f]+)", line)
        if m:
            names[m.group(1)] = m.group(2)
            sizes[m.group(2)] = int(m.group(3), 16)
    symbols = {}
    for line in _run(["llvm-readelf", "-s", "-W", str(obj)]).splitlines():
        p = line.split()
        if len(p) == 8 and p[0].endswith(":") and p[6] in names and p[3] in ("FUNC", "OBJECT", "NOTYPE"):
            symbols[p[7]] = names[p[6]]
    return sizes, symbols


def _relocations(obj: Path) -> dict[str, set[str]]:
    refs: dict[str, set[str]] = {}
    current = None
    for line in _run(["llvm-objdump", "-r", str(obj)]).splitlines():
        head = re.match(r"RELOCATION RECORDS FOR \[(.*)\]:", line)
        if head:
            current = refs.setdefault(head.group(1), set())
            continue
        p = line.split()
        if current is not None and len(p) == 3 and re.fullmatch(r"[0-9a-f]+", p[0]):
            current.add(re.sub(r"[+-]0x[0-9a-f]+$", "", p[2]))
    return refs


def _instructions(obj: Path) -> dict[str, int]:
    counts: dict[str, int] = {}
    section = ""
    for line in _run(["llvm-objdump", "-d", "--no-show-raw-insn", str(obj)]).splitlines():
        head = re.match(r"Disassembly of section (\S+):", line)
        if head:
            section = head.group(1)
        elif re.match(r"^\s+[0-9a-f]+:\s+\S", line):
            counts[section] = counts.get(section, 0) + 1
    return counts


def kept(objects: list[Path]) -> Kept:
    """Sum what is reachable from main and the interrupt handlers, across objects."""
    info = {o: (*_sections(o), _relocations(o), _instructions(o)) for o in objects}
    globals_ = {name: (o, sec) for o, (_s, syms, _r, _i) in info.items() for name, sec in syms.items()}
    todo = [where for name, where in globals_.items() if ROOTS.match(name)]
    seen: set[tuple[Path, str]] = set()
    helpers: set[str] = set()
    while todo:
        obj, sec = todo.pop()
        if (obj, sec) in seen:
            continue
        seen.add((obj, sec))
        _sizes, syms, refs, _ins = info[obj]
        for target in refs.get(sec, ()):
            where = (obj, target) if target.startswith(".") else (
                (obj, syms[target]) if target in syms else globals_.get(target))
            if where is None:
                helpers.add(target)
            else:
                todo.append(where)
    totals = {"ins": 0, ".text": 0, ".rodata": 0, ".data": 0, ".bss": 0}
    words = []
    for obj, sec in seen:
        sizes, _syms, _refs, ins = info[obj]
        kind = "." + sec.split(".")[1]
        if kind in totals:
            totals[kind] += sizes.get(sec, 0)
        totals["ins"] += ins.get(sec, 0)
        if kind == ".text":
            words.append((ins.get(sec, 0), sec))
        elif kind in (".rodata", ".data"):
            words.append(((sizes.get(sec, 0) + 1) // 2, sec))
    return Kept(totals["ins"], totals[".text"], totals[".rodata"], totals[".data"], totals[".bss"],
                tuple(sorted(h for h in helpers if h.startswith("__") or h.startswith("mem"))),
                tuple(sorted(sec for _obj, sec in seen)), tuple(sorted(words, reverse=True)))


#: clang options per level beside the level itself (step 1 of the method: XC16 -O1's inliner)
LEVEL_OPTIONS = {"-O1": ("-finline-hint-functions",), "-Os": ()}


def compile_objects(cflags: list[str], sources: list[str], level: str, out: Path) -> list[Path]:
    objects = []
    for source in sources:
        obj = out / f"{Path(source).stem}{level}.o"
        _run(["clang", "--target=msp430", level, *LEVEL_OPTIONS.get(level, ()), "-ffunction-sections",
              "-fdata-sections", "-w", *cflags, "-c", source, "-o", str(obj)])
        objects.append(obj)
    return objects


def dspic_words(k: Kept, allowance: dict[str, int] = ALLOWANCE_WORDS) -> int:
    return k.instructions + (k.const_bytes + 1) // 2 + (k.data_bytes + 1) // 2 + sum(allowance.values())


def grouped(n: float) -> str:
    return f"{n:,.0f}".replace(",", " ")


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="30F2010", choices=sorted(DEVICES))
    parser.add_argument("--handlers", type=int, default=5, help="the build's interrupt handlers (their context code)")
    args, rest = parser.parse_known_args(argv)
    if rest.count("--") != 2:
        parser.error("give -- CFLAGS... -- SOURCES...")
    split = rest.index("--", 1)
    cflags, sources = rest[1:split], rest[split + 1:]
    flash_bytes, ram_bytes = DEVICES[args.device]
    allowance = allowance_words(args.handlers)
    print(f"dsPIC{args.device} size estimate (no XC16 here): clang --target=msp430, function/data sections, "
          f"-O1 inlining only functions declared inline (as XC16 -O1), "
          f"kept = reachable from main and the interrupt handlers; dsPIC words = MSP430 instructions + "
          f"constants and data initialisers / 2 + {sum(allowance.values())} words allowance; bytes = words x 3")
    for what, words in allowance.items():
        print(f"  allowance {words:4d} words: {what}")
    with tempfile.TemporaryDirectory() as tmp:
        for level in ("-Os", "-O1"):
            k = kept(compile_objects(cflags, sources, level, Path(tmp)))
            words = dspic_words(k, allowance)
            print(f"  {level}: {k.instructions} instructions ({k.code_bytes} B msp430 code), constants {k.const_bytes} B, "
                  f"data {k.data_bytes} B, bss {k.bss_bytes} B, library calls {', '.join(k.helpers) or 'none'} "
                  f"-> {words} words = {words * 3} B")
    print("  largest at -O1 (dsPIC words): " + ", ".join(f"{sec.split('.', 2)[2]} {n}" for n, sec in k.words[:LARGEST]))
    print(f"static RAM (msp430, 2-byte alignment as on the dsPIC): {k.data_bytes + k.bss_bytes} B of "
          f"{ram_bytes} B; stack bound: tests/test_firmware_dspic.py")
    percent = 100.0 * words * 3 / flash_bytes
    print(f"flash estimate: {grouped(words * 3)} of {grouped(flash_bytes)} bytes = {percent:.1f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
