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
3. Convert to dsPIC program words: the MSP430 instructions kept, one 24-bit word each, then by the
   rules of docs/board.md 3a (from the dsPIC30F's instruction forms, DS70157): c, operand forms the
   dsPIC needs two or three instructions for; a, runs of one-bit shifts (one SL/ASR/LSR); b, the
   32-bit carry and compare idioms through the status register (ADDC/SUBB, CP+CPB+BRA); d, a move
   folded into a three-operand ALU op. Constants and the
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
    code: tuple[tuple[str, tuple[Ins, ...]], ...] = ()  # each kept code section's instructions


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


@dataclass(frozen=True)
class Ins:
    """One MSP430 instruction as llvm-objdump prints it; ``relocated``: its operands (0 source,
    1 destination) whose extension word the linker fills in (a symbol's address, unknown here)."""
    op: str
    args: tuple[str, ...]
    relocated: frozenset[int] = frozenset()


_HAS_EXTENSION = re.compile(r"^(#|&|-?\d+\()")


def _relocated_operands(args: tuple[str, ...], at: int, offs: list[int]) -> frozenset[int]:
    """Which operands the relocations at ``offs`` fill in: the source's extension word is at +2, the
    destination's after it. A small literal (#0, #1, #2, #4, #8, #-1) has no extension word unless it
    is relocated (the linker's value is unknown, objdump prints #0)."""
    has = [bool(_HAS_EXTENSION.match(a)) for a in args]
    small = [bool(re.fullmatch(r"#(0|1|2|4|8|-1)", a)) for a in args]
    if len(args) == 1:
        return frozenset({0} if at + 2 in offs and has[0] else ())
    if len(args) != 2 or not offs:
        return frozenset()
    if len(offs) >= 2:
        return frozenset(i for i in (0, 1) if has[i])
    if not has[0]:
        return frozenset({1} if has[1] else ())
    if has[0] and not small[0]:
        return frozenset({0} if at + 2 in offs else {1})
    # a small literal source: it is the relocated one only if the destination has no extension word
    return frozenset({1} if has[1] else {0})


def _instructions(obj: Path) -> dict[str, list[Ins]]:
    listing: dict[str, list[Ins]] = {}
    section, address, relocs = "", 0, []
    rows: list[tuple[int, str, tuple[str, ...], list[int]]] = []

    def flush() -> None:
        for at, op, args, offs in rows:
            listing.setdefault(section, []).append(Ins(op, args, _relocated_operands(args, at, offs)))
        rows.clear()

    for line in _run(["llvm-objdump", "-d", "-r", "--no-show-raw-insn", str(obj)]).splitlines():
        head = re.match(r"Disassembly of section (\S+):", line)
        reloc = re.match(r"^\s+([0-9a-f]+):\s+R_MSP430", line)
        insn = re.match(r"^\s+([0-9a-f]+):\s+(\S+)\s*(.*)$", line)
        if head:
            flush()
            section = head.group(1)
            listing.setdefault(section, [])
        elif reloc and rows:
            rows[-1][3].append(int(reloc.group(1), 16))
        elif insn:
            args = tuple(a.strip() for a in insn.group(3).split(",")) if insn.group(3).strip() else ()
            rows.append((int(insn.group(1), 16), insn.group(2), args, []))
    flush()
    return listing


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
    words, code = [], []
    for obj, sec in seen:
        sizes, _syms, _refs, ins = info[obj]
        kind = "." + sec.split(".")[1]
        if kind in totals:
            totals[kind] += sizes.get(sec, 0)
        totals["ins"] += len(ins.get(sec, ()))
        if kind == ".text":
            code.append((sec, tuple(ins.get(sec, ()))))
            words.append((convert(ins.get(sec, ())).words, sec))
        elif kind in (".rodata", ".data"):
            words.append(((sizes.get(sec, 0) + 1) // 2, sec))
    return Kept(totals["ins"], totals[".text"], totals[".rodata"], totals[".data"], totals[".bss"],
                tuple(sorted(h for h in helpers if h.startswith("__") or h.startswith("mem"))),
                tuple(sorted(sec for _obj, sec in seen)), tuple(sorted(words, reverse=True)), tuple(sorted(code)))


# ---- step 3: MSP430 instructions to dsPIC words (docs/board.md section 3a, "The conversion") ----
# dsPIC30F instruction forms (DS70157, the 16-bit MCU and DSC programmer's reference manual):
#   MOV Ws,Wd (both any register or register-indirect mode: Wn, [Wn], [Wn++], [Wn--]...),
#   MOV [Ws+Slit10],Wnd and MOV Wns,[Wd+Slit10] (an offset on one side only), MOV f,Wn / MOV Wn,f,
#   MOV #lit16,Wn; ALU ops: op Wb,Ws,Wd (Ws, Wd register or register-indirect, never an offset),
#   op #lit10,Wn, op Wb,#lit5,Wd, op f{,WREG} (the file register with W0); CP Wb,Ws / CP Wb,#lit5 /
#   CP f / CP0; BSET/BCLR/BTG/BTST f or Ws with a bit number; SL/ASR/LSR Wb,#lit4,Wnd (any count);
#   ADDC/SUBB/CPB (the carry in); RCALL, BRA cc, PUSH/POP Ws or f: one word each.
# Assumed: all RAM and SFRs of the dsPIC30F2010 (0x0000-0x0BFF) are near data (below 8 KB), so an
# MSP430 absolute address is a file register f; calls are RCALL (4K words are within its range).
_REG = re.compile(r"^r\d+$")
_INDEXED = re.compile(r"^(-?\d+)\((r\d+)\)$")
_ALU = {"add", "addc", "sub", "subc", "and", "bis", "bic", "xor"}
_ONE_OPERAND = {"clr", "inc", "incd", "dec", "decd", "inv", "rra", "rrc", "swpb", "sxt", "tst"}


def _kind(arg: str, relocated: bool) -> str:
    """R register, C constant, K a linker-filled constant (an address), D register-indirect ([Wn]),
    X register + offset within Slit10, XL an offset beyond it or a symbol's address, A absolute (f)."""
    if _REG.match(arg):
        return "R"
    if arg.startswith("#"):
        return "K" if relocated else "C"
    if arg.startswith("&"):
        return "A"
    if arg.startswith("@"):
        return "D"
    m = _INDEXED.match(arg)
    if m:
        offset = int(m.group(1))
        return "XL" if relocated or not -512 <= offset <= 511 else ("D" if offset == 0 else "X")
    return "R"


def _value(arg: str, byte: bool) -> int:
    return int(arg[1:]) & (0xFF if byte else 0xFFFF)


def _single_bit(v: int) -> bool:
    return v != 0 and v & (v - 1) == 0


def _literal_fits(op: str, v: int, byte: bool) -> bool:
    """Whether op #v,Wn is one dsPIC instruction: a 10-bit literal, or a bit set/clear/toggle, ZE, COM."""
    full = 0xFF if byte else 0xFFFF
    if op in ("add", "sub", "addc", "subc"):
        return v <= 1023 or full + 1 - v <= 1023  # a negative literal: the other of ADD/SUB
    if op == "and":
        return v <= 1023 or _single_bit(full & ~v) or v == 0xFF or v == full
    if op == "bis":
        return v <= 1023 or _single_bit(v)
    if op == "bic":
        return _single_bit(v) or (full & ~v) <= 1023
    if op == "xor":
        return v <= 1023 or _single_bit(v) or v == full
    if op == "cmp":
        return v <= 31  # CP Wb,#lit5
    if op == "bit":
        return _single_bit(v)  # BTST
    return False


def form_words(ins: Ins) -> int:
    """dsPIC words of one MSP430 instruction by its operand forms (rule c): 1 where a dsPIC form above
    does it, 2 where the operand needs its own MOV (an offset on both sides, a literal to memory, a
    file register into a W other than W0), 3 for a read-modify-write of [Wn+offset]."""
    base, byte = ins.op.split(".")[0], ins.op.endswith(".b")
    kinds = [_kind(a, i in ins.relocated) for i, a in enumerate(ins.args)]
    extra = sum(1 for k in kinds if k == "XL")  # the address computed into a W first
    kinds = ["X" if k == "XL" else k for k in kinds]
    if len(kinds) == 1:
        (k,) = kinds
        if base in ("push", "call", "br"):
            return (2 if k in ("X", "C") and base == "push" else 2 if k == "X" else 1) + extra
        if base in _ONE_OPERAND:
            if k in ("R", "D"):
                return 1 + extra
            if k == "A":
                return (2 if base in ("swpb", "sxt") else 1) + extra
            return (2 if base in ("tst", "clr") else 3) + extra
        return 1 + extra
    if len(kinds) != 2:
        return 1
    (src, dst), arg = kinds, ins.args[0]
    literal = src == "C" and _literal_fits(base, _value(arg, byte), byte)
    if base == "mov":
        if dst == "R" or src == "R":
            return 1 + extra
        if src == "D" and dst == "D":
            return 1 + extra
        if src == "C" and _value(arg, byte) == 0 and dst in ("A", "D"):
            return 1 + extra  # CLR f / CLR [Wn]
        return 2 + extra
    if base in ("cmp", "bit"):
        if dst == "R":
            return (1 if src in ("R", "D") or literal else 2) + extra
        if dst in ("A", "D"):
            return (1 if (src == "C" and base == "bit" and literal) or (src == "R" and dst == "D") else 2) + extra
        return (2 if src == "R" or literal else 3) + extra
    if base in _ALU:
        if dst == "R":
            return (1 if src in ("R", "D") or literal else 2) + extra
        if dst in ("A", "D"):
            v = _value(arg, byte) if src == "C" else 0
            bitwise = src == "C" and (_single_bit(v) if base in ("bis", "bic", "xor") else
                                      base == "and" and _single_bit((0xFF if byte else 0xFFFF) & ~v))  # BSET/BCLR/BTG
            small = src == "C" and base in ("add", "sub") and _value(arg, byte) in (1, 2)  # INC/INC2/DEC f
            if bitwise or small or (src == "R" and dst == "D"):
                return 1 + extra
            return (2 if src in ("R", "C", "K") else 3) + extra
        return (3 if src in ("R", "C", "K") else 4) + extra
    return 1 + extra


def _is(ins: Ins, op: str, *args: str) -> bool:
    return ins.op == op and (not args or ins.args == args)


def shift_runs(code: tuple[Ins, ...] | list[Ins]) -> list[tuple[int, int, int]]:
    """Rule a: runs of one-bit shifts of one register, as (start, length, dsPIC words): n x `rra Rn`
    (ASR Wb,#n,Wd), `clrc; rrc Rn` + n-1 x `rra Rn` (LSR #n), n x `add Rn, Rn` (SL #n): one word;
    byte-mode runs (`add.b`, `rra.b`) two (SL/ASR #n is word-only: the shift, then ZE)."""
    runs, i = [], 0
    while i < len(code):
        ins, length = code[i], 0
        if _is(ins, "clrc") and i + 1 < len(code) and code[i + 1].op == "rrc" and _REG.match(code[i + 1].args[0]):
            reg, length = code[i + 1].args[0], 2
            while i + length < len(code) and _is(code[i + length], "rra", reg):
                length += 1
            words = 1
        elif ins.op in ("rra", "rra.b", "add", "add.b") and all(_REG.match(a) for a in ins.args) and \
                len(set(ins.args)) == 1:
            while i + length < len(code) and code[i + length] == ins:
                length += 1
            words = 2 if ins.op.endswith(".b") else 1
        if length and length > words:
            runs.append((i, length, words))
            i += length
        else:
            i += 1
    return runs


_FLAGS = {"add", "addc", "sub", "subc", "and", "xor", "cmp", "bit", "tst", "rra", "rrc", "inc", "incd", "dec",
          "decd", "inv", "sxt"}


def _sets_flags(ins: Ins) -> bool:
    return ins.op.split(".")[0] in _FLAGS or ins.op.startswith("j") or ins.op in ("call", "ret", "br")


def carry_chains(code: tuple[Ins, ...] | list[Ins], window: int = 8) -> list[tuple[int, ...]]:
    """Rule b: clang-msp430's carry (or borrow) of a 32-bit add (sub) through the status register:
    `cmp Ra, Rb` next to an `add`/`sub` of Ra or Rb; the status register read (`mov r2, Rt` then
    `bic Rt, Ru` with `mov #1, Ru`, or `bic r2, Ru` with `mov #1, Ru`, or `and #1` of the read); the
    bit added to (subtracted from) the high word by `add Ru, Rh` (`sub Ru, Rh`). The dsPIC adds the
    high words with ADDC (SUBB), which takes the carry from the low ADD (SUB): the compare, the read,
    the mask and the add of the bit are not needed. Returns each chain's instruction indices."""
    chains = []
    for r, ins in enumerate(code):
        reads = ins.args[:1] == ("r2",) and ins.op in ("mov", "bic", "and")
        if not reads:
            continue
        f = r - 1
        while f >= 0 and not _sets_flags(code[f]):
            f -= 1
        if f < 0 or code[f].op != "cmp":
            continue
        low = [n for n in code[max(0, f - 4):f + 9] if n.op in ("add", "sub") and n.args == code[f].args or
               n.op == "add" and n.args[1] in code[f].args]
        if not low and not (code[f].op == "cmp" and _consumed_by_sub(code, r, window)):
            continue
        chain = _carry_bit(code, f, r, window)
        if chain:  # without the low add/sub beside it the compare is the low CP of CP + CPB: kept
            chains.append(chain if low else tuple(i for i in chain if i != f))
    return chains


def _consumed_by_sub(code, r: int, window: int) -> bool:
    """Whether the bit read at r is subtracted from a high word (a borrow: the compare is a 32-bit
    subtraction's or compare's low half, the dsPIC's CP, then SUBB/CPB)."""
    chain = _carry_bit(code, r - 1, r, window)
    return bool(chain) and code[chain[-1]].op == "sub"


def _carry_bit(code, f: int, r: int, window: int) -> tuple[int, ...]:
    """The indices of the chain from the compare f and the read r to the add of the bit, or ()."""
    read = code[r]
    used = [f, r]
    bit = read.args[1]
    if read.op == "mov":  # the bit still to be masked out of the copy of SR
        for m in range(r + 1, min(len(code), r + window)):
            if code[m].op == "bic" and code[m].args[0] == bit:
                bit = code[m].args[1]
                used.append(m)
                break
            if code[m].op == "and" and code[m].args == ("#1", bit):
                used.append(m)
                break
        else:
            return ()
    if code[used[-1]].op == "bic":
        ones = [m for m in range(max(0, f - window), used[-1]) if code[m].op == "mov" and code[m].args == ("#1", bit)]
        if not ones:
            return ()
        used.append(ones[-1])
    for m in range(used[-1 if code[used[-1]].op != "mov" else -2] + 1, min(len(code), r + 2 * window)):
        if code[m].op in ("add", "sub") and bit in code[m].args and all(_REG.match(a) for a in code[m].args) and \
                (code[m].op == "add" or code[m].args[0] == bit):
            return tuple(sorted(used + [m]))
        if bit in code[m].args:
            return ()
    return ()


_BOOL_OPS = {"mov", "clr", "bic", "bis", "and", "inv", "rra", "bit", "tst", "cmp", "xor"}


def _boolean_work(ins: Ins) -> bool:
    """An instruction of clang's 32-bit compare expansion: the compares, SR reads, bit masks on
    registers and the jumps inside it (a load from memory is not, and stays counted)."""
    if ins.op.startswith("j"):
        return True
    return ins.op in _BOOL_OPS and all(_REG.match(a) or re.fullmatch(r"#(0|1|-1)", a) for a in ins.args)


def _tested_bit(code, e: int) -> bool:
    """Whether the jump at e tests a register's bit (`bit #1, Rx` / `tst Rx`, non-flag moves between)."""
    p = e - 1
    while p >= 0 and not _sets_flags(code[p]):
        p -= 1
    return p >= 0 and code[p].op in ("bit", "tst") and _boolean_work(code[p])


def compares32(code: tuple[Ins, ...] | list[Ins], window: int = 4) -> list[tuple[int, ...]]:
    """Rule b, compares: clang-msp430 compares two 32-bit values as `cmp lo; mov r2, Rt` (the low
    words' flags kept), `cmp hi` twice (a signed or unsigned jump, and jeq to choose which flags
    hold), then masks of the kept flags and `bit #1, Rx` / `tst Rx` and a conditional jump. The dsPIC
    does it in three words: CP lo, CPB hi, BRA cc. Returns the indices of each expansion's
    instructions (from the low compare to that jump, register-only ones); each becomes 3 words."""
    found, i = [], 0
    while i < len(code):
        ins = code[i]
        twin = next((j for j in range(i + 1, min(len(code), i + window + 1)) if code[j].op == "cmp" and
                     ins.op == "cmp" and code[j].args in (ins.args, ins.args[::-1])), None)
        if ins.op != "cmp" or twin is None:
            i += 1
            continue
        low = next((k for k in range(i - 1, max(-1, i - window - 1), -1) if code[k].op in ("cmp", "tst") and
                    code[k].args not in (ins.args, ins.args[::-1]) and k + 1 < len(code) and code[k + 1].args[:1] == ("r2",)), None)
        end = next((e for e in range(twin + 1, min(len(code), twin + 3 * window)) if code[e].op in ("jeq", "jne")
                    and _tested_bit(code, e)), None)
        if low is None or end is None:
            i += 1
            continue
        found.append(tuple(k for k in range(low, end + 1) if _boolean_work(code[k])))
        i = end + 1
    return found


def three_operand(code: tuple[Ins, ...] | list[Ins]) -> list[int]:
    """Rule d: `mov Ra, Rd` then `op Rb, Rd` (or `op #k, Rd`, k < 32) is one dsPIC instruction,
    op Ra,Rb,Rd (op Wb,#lit5,Wd): the dsPIC's ALU writes a third register. Word ops only (an MSP430
    byte op clears the high byte, a dsPIC one keeps it). Returns the indices of the movs folded."""
    folded = []
    for i in range(len(code) - 1):
        a, b = code[i], code[i + 1]
        if a.op != "mov" or not all(_REG.match(x) for x in a.args) or a.args[0] in ("r1", "r2") or \
                b.op not in ("add", "sub", "and", "bis", "xor") or len(b.args) != 2 or b.args[1] != a.args[1]:
            continue
        src = b.args[0]
        small = src.startswith("#") and 0 not in b.relocated and (int(src[1:]) & 0xFFFF <= 31 or
                                                                   (b.op in ("add", "sub") and -int(src[1:]) & 0xFFFF <= 31))
        if _REG.match(src) or small:
            folded.append(i)
    return folded


@dataclass(frozen=True)
class Converted:
    """dsPIC words of a code section, and what each rule of the conversion changed."""
    instructions: int
    forms_added: int  # rule c: words beyond one per instruction
    shifts_saved: int  # rule a
    carries_saved: int  # rule b, 32-bit add/sub
    compares_saved: int = 0  # rule b, 32-bit compares
    moves_saved: int = 0  # rule d, three-operand ALU

    @property
    def words(self) -> int:
        return self.instructions + self.forms_added - self.shifts_saved - self.carries_saved - self.compares_saved - \
            self.moves_saved


def convert(code: tuple[Ins, ...] | list[Ins]) -> Converted:
    cost = [form_words(ins) for ins in code]
    shifts = shift_runs(code)
    in_runs = {i for start, n, _w in shifts for i in range(start, start + n)}
    shifts_saved = sum(sum(cost[start:start + n]) - words for start, n, words in shifts)
    chains = [c for c in carry_chains(code) if not in_runs.intersection(c)]
    carried = {i for c in chains for i in c}
    compares = [c for c in compares32(code) if not (in_runs | carried).intersection(c)]
    compared = sum(sum(cost[i] for i in c) - 3 for c in compares)
    taken = in_runs | carried | {i for c in compares for i in c}
    moves = [i for i in three_operand(code) if not taken.intersection((i, i + 1))]
    return Converted(len(code), sum(cost) - len(code), shifts_saved, sum(cost[i] for i in carried), compared,
                     sum(cost[i] for i in moves))


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


def conversion(k: Kept) -> Converted:
    """Step 3's rules summed over the kept code sections."""
    parts = [convert(code) for _sec, code in k.code]
    return Converted(sum(p.instructions for p in parts), sum(p.forms_added for p in parts),
                     sum(p.shifts_saved for p in parts), sum(p.carries_saved for p in parts),
                     sum(p.compares_saved for p in parts), sum(p.moves_saved for p in parts))


def conversion_steps(c: Converted) -> str:
    """Each rule's words and the running total, in the order docs/board.md's rule table gives them."""
    steps = [("rule c (operand forms the dsPIC needs two or three instructions for)", c.forms_added),
             ("rule a (runs of one-bit shifts)", -c.shifts_saved),
             ("rule b (32-bit add/sub carry through SR -> ADDC/SUBB)", -c.carries_saved),
             ("rule b (32-bit compares -> CP, CPB, BRA)", -c.compares_saved),
             ("rule d (three-operand ALU: mov + op -> op Wb,Ws,Wd)", -c.moves_saved)]
    total, out = c.instructions, [f"{c.instructions} instructions at one word each"]
    for what, delta in steps:
        total += delta
        out.append(f"{what} {delta:+d} -> {total}")
    return "; ".join(out) + " code words"


def dspic_words(k: Kept, allowance: dict[str, int] = ALLOWANCE_WORDS) -> int:
    return conversion(k).words + (k.const_bytes + 1) // 2 + (k.data_bytes + 1) // 2 + sum(allowance.values())


def grouped(n: float) -> str:
    return f"{n:,.0f}".replace(",", " ")


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="30F2010", choices=sorted(DEVICES))
    parser.add_argument("--handlers", type=int, default=5, help="the build's interrupt handlers (their context code)")
    parser.add_argument("--all", action="store_true", help="list every kept section at -O1, not only the largest")
    args, rest = parser.parse_known_args(argv)
    if rest.count("--") != 2:
        parser.error("give -- CFLAGS... -- SOURCES...")
    split = rest.index("--", 1)
    cflags, sources = rest[1:split], rest[split + 1:]
    flash_bytes, ram_bytes = DEVICES[args.device]
    allowance = allowance_words(args.handlers)
    print(f"dsPIC{args.device} size estimate (no XC16 here): clang --target=msp430, function/data sections, "
          f"-O1 inlining only functions declared inline (as XC16 -O1), "
          f"kept = reachable from main and the interrupt handlers; dsPIC words = MSP430 instructions converted "
          f"by rules a-d (docs/board.md 3a) + "
          f"constants and data initialisers / 2 + {sum(allowance.values())} words allowance; bytes = words x 3")
    for what, words in allowance.items():
        print(f"  allowance {words:4d} words: {what}")
    with tempfile.TemporaryDirectory() as tmp:
        for level in ("-Os", "-O1"):
            k = kept(compile_objects(cflags, sources, level, Path(tmp)))
            words = dspic_words(k, allowance)
            c = conversion(k)
            print(f"  {level}: {k.instructions} instructions ({k.code_bytes} B msp430 code), constants {k.const_bytes} B, "
                  f"data {k.data_bytes} B, bss {k.bss_bytes} B, library calls {', '.join(k.helpers) or 'none'} "
                  f"-> {words} words = {words * 3} B")
            print(f"    conversion {level}: " + conversion_steps(c))
    shown = k.words if args.all else k.words[:LARGEST]
    print(f"  {'kept' if args.all else 'largest'} at -O1 (dsPIC words): " +
          ", ".join(f"{sec.split('.', 2)[2]} {n}" for n, sec in shown))
    print(f"static RAM (msp430, 2-byte alignment as on the dsPIC): {k.data_bytes + k.bss_bytes} B of "
          f"{ram_bytes} B; stack bound: tests/test_firmware_dspic.py")
    percent = 100.0 * words * 3 / flash_bytes
    print(f"flash estimate: {grouped(words * 3)} of {grouped(flash_bytes)} bytes = {percent:.1f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
