#!/usr/bin/env python3
"""Generate the Python message module and the C message code from schema.toml.

The schema is the one definition of the wire format; both sides are produced from it so that the
host and the firmware cannot drift. `python firmware_protocol/generate.py` rewrites:

    hilbench/protocol/messages.py        NamedTuple messages, IntEnums, pack/unpack tables
    firmware_protocol/hbp_messages.h     #defines, message structs, pack/unpack prototypes
    firmware_protocol/hbp_messages.c     C99 pack/unpack of every message
    firmware_protocol/tests/hbp_test_fields.h   test-only C helpers (message union, fields by name)

`--check` writes nothing and exits 1 when any committed output differs from what it would write.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
SCHEMA = HERE / "schema.toml"
PY_OUT = REPO / "hilbench" / "protocol" / "messages.py"
H_OUT = HERE / "hbp_messages.h"
C_OUT = HERE / "hbp_messages.c"
TEST_OUT = HERE / "tests" / "hbp_test_fields.h"

SCALAR_FMT = {"u8": "B", "u16": "H", "u32": "I", "i16": "h", "i32": "i", "bool": "B", "bits8": "B", "bits16": "H",
              "bits32": "I"}
SCALAR_SIZE = {"u8": 1, "u16": 2, "u32": 4, "i16": 2, "i32": 4, "bool": 1, "bits8": 1, "bits16": 2, "bits32": 4}
ARRAY_ELEM = {"u8[]": ("B", 1), "u16[]": ("H", 2), "i16[]": ("h", 2), "pair[]": ("Bi", 5), "edge[]": ("HB", 3)}
#: arrays of (a, b) tuples: flattened on the wire
TUPLE_ARRAYS = ("pair[]", "edge[]")
C_SCALAR = {"u8": "hbp_u8", "u16": "uint16_t", "u32": "uint32_t", "i16": "int16_t", "i32": "int32_t",
            "bool": "hbp_u8"}
C_ELEM = {"u8[]": "hbp_u8", "u16[]": "uint16_t", "i16[]": "int16_t", "pair[]": "hbp_pair_t", "edge[]": "hbp_edge_t"}
RANGE = {"u8": (0, 0xFF), "u16": (0, 0xFFFF), "u32": (0, 0xFFFFFFFF), "i16": (-0x8000, 0x7FFF),
         "i32": (-0x80000000, 0x7FFFFFFF)}
BITS_WIDTH = {"bits8": 8, "bits16": 16, "bits32": 32}
# Keys that do not describe the wire (documentation, Python fast-path hints, Python defaults): left out
# of the schema fingerprint so that editing them does not make every built firmware "mismatched".
NON_WIRE_KEYS = frozenset({"doc", "hot", "hot_n", "default", "py_order"})


def _wire_content(value: object) -> object:
    """The parsed schema without NON_WIRE_KEYS, at every level."""
    if isinstance(value, dict):
        return {k: _wire_content(v) for k, v in value.items() if k not in NON_WIRE_KEYS}
    if isinstance(value, list):
        return [_wire_content(v) for v in value]
    return value


def schema_fingerprint(data: dict) -> int:
    """First 4 bytes (big-endian) of SHA-256 over the canonical JSON of the schema's wire content.

    Canonical: NON_WIRE_KEYS removed, keys sorted, separators "," and ":", ASCII only. TOML comments
    and layout never reach the parsed data, so only a change of the wire format changes the value.
    """
    canonical = json.dumps(_wire_content(data), sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return int.from_bytes(hashlib.sha256(canonical.encode("ascii")).digest()[:4], "big")


@dataclass(frozen=True)
class Field:
    name: str
    type: str
    max: str | None
    bits: tuple[tuple[str, int, str], ...]
    last: bool
    hot_n: int | None = None  # array count the Python encoder unrolls (the AN1017 profile's)
    default: str | None = None  # Python only: the NamedTuple default (a name in messages.py)

    @property
    def variable(self) -> bool:
        return self.type == "str" or self.type.endswith("[]")


@dataclass(frozen=True)
class Message:
    name: str
    type_name: str
    type_id: int
    dir: str
    fields: tuple[Field, ...]
    hot: bool = False  # sent every period: inlined into encode_frame/decode_body
    py_order: tuple[str, ...] | None = None  # the NamedTuple's field order, when not the wire's

    @property
    def snake(self) -> str:
        out = ""
        for i, ch in enumerate(self.name):
            if ch.isupper() and i:
                out += "_"
            out += ch.lower()
        return out

    def wire_names(self) -> list[str]:
        """Field names after seq in wire order, with bit fields expanded."""
        names: list[str] = []
        for f in self.fields:
            if f.bits:
                names.extend(b[0] for b in f.bits)
            else:
                names.append(f.name)
        return names

    def py_fields(self) -> list[str]:
        """Python field names after seq (the NamedTuple's order), with bit fields expanded."""
        return list(self.py_order) if self.py_order else self.wire_names()

    def reorder(self, args: list[str]) -> list[str]:
        """Expressions for ["seq"] + wire_names(), in the NamedTuple's order."""
        by_name = dict(zip(["seq"] + self.wire_names(), args))
        return [by_name[n] for n in ["seq"] + self.py_fields()]

    @property
    def fixed(self) -> tuple[Field, ...]:
        return tuple(f for f in self.fields if not f.variable)

    @property
    def fixed_len(self) -> int:
        """type + seq + all fixed-size fields (they all precede the variable ones)."""
        return 2 + sum(SCALAR_SIZE[f.type] for f in self.fixed)


def load(path: Path = SCHEMA) -> tuple[dict, list[tuple[str, str, str, list]], list[Message]]:
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    enums = [(e["name"], e["prefix"], e["doc"], e["members"]) for e in data["enum"]]
    type_ids = {m: v for (n, _, _, members) in enums if n == "MsgType" for m, v in members}
    msgs: list[Message] = []
    for m in data["message"]:
        raw = m["fields"]
        fields = []
        for i, f in enumerate(raw):
            fields.append(Field(f["name"], f["type"], f.get("max"),
                                tuple(tuple(b) for b in f.get("bits", ())), i == len(raw) - 1, f.get("hot_n"),
                                f.get("default")))
        defaults = [f.default is not None for f in fields]
        if any(defaults) and (defaults.index(True) + defaults.count(True) != len(fields)
                              or any(f.bits for f in fields if f.default)):
            raise SystemExit(f"schema.toml message {m['name']}: only the trailing plain fields may have a default")
        seen_var = False
        for f in fields:  # the codec relies on all fixed fields coming first
            if f.variable:
                seen_var = True
            elif seen_var:
                raise SystemExit(f"schema.toml message {m['name']}: fixed field {f.name} after a variable one")
        py_order = tuple(m["py_order"]) if "py_order" in m else None
        if py_order and sorted(py_order) != sorted(f.name for f in fields):
            raise SystemExit(f"schema.toml message {m['name']}: py_order must list every field once")
        msgs.append(Message(m["name"], m["type"], type_ids[m["type"]], m["dir"], tuple(fields), m.get("hot", False),
                            py_order))
    return data, enums, msgs


# ----------------------------------------------------------------------------------------------
# Python


def _py_pack_scalar_exprs(f: Field, ref: Callable[[str], str] = lambda n: f"m.{n}") -> list[str]:
    if f.type == "bool":
        return [f"(1 if {ref(f.name)} else 0)"]
    if f.bits:
        parts = []
        shift = 0
        for name, width, kind in f.bits:
            if kind == "bool":
                term = f"({1 << shift} if {ref(name)} else 0)"
            else:
                term = ref(name) if shift == 0 else f"{ref(name)} << {shift}"
            parts.append(term)
            shift += width
        return ["(" + " | ".join(parts) + ")"]
    return [ref(f.name)]


def _py_bits_check(f: Field, ref: Callable[[str], str] = lambda n: f"m.{n}") -> list[str]:
    """Range checks for bit fields (struct checks the plain scalars)."""
    lines = []
    groups: dict[int, list[str]] = {}
    for name, width, kind in f.bits:
        if kind != "bool":
            groups.setdefault(width, []).append(name)
    tests = [(f"({' | '.join(ref(n) for n in names)}) >> {width}", names, width) for width, names in groups.items()]
    if len(tests) > 1:  # one branch on the hot path; which field is wrong is found only on failure
        lines.append("    if " + " | ".join(f"({t})" for t, _, _ in tests) + ":")
        indent = "    "
    else:
        indent = ""
    for test, names, width in tests:
        lines.append(f"    {indent}if {test}:")
        lines.append(f"    {indent}    raise ProtocolError(f\"encode {{type(m).__name__}}: {'/'.join(names)} "
                     f"must be 0..{(1 << width) - 1}\")")
    return lines


def _py_unpack_scalar(f: Field, v: str) -> list[str]:
    if f.type == "bool":
        return [f"{v} != 0"]
    if f.bits:
        out = []
        shift = 0
        for _name, width, kind in f.bits:
            if kind == "bool":
                out.append(f"({v} >> {shift} & 1) != 0")
            elif shift + width == BITS_WIDTH[f.type]:  # the topmost field needs no mask
                out.append(f"{v} >> {shift}" if shift else v)
            else:
                out.append(f"{v} >> {shift} & {(1 << width) - 1}" if shift else f"{v} & {(1 << width) - 1}")
            shift += width
        return out
    return [v]


def _specialisable(m: Message) -> bool:
    """Fixed fields only, or fixed fields and one trailing numeric array: one struct per count."""
    var = [f for f in m.fields if f.variable]
    return not var or (len(var) == 1 and var[0].last and var[0].type != "str")


def _two_arrays(m: Message) -> bool:
    """Fixed fields, one counted numeric array, one trailing numeric array (Sensors): one struct per
    pair of counts."""
    var = [f for f in m.fields if f.variable]
    return (len(var) == 2 and not var[0].last and var[1].last and "str" not in (var[0].type, var[1].type)
            and var[0].type not in TUPLE_ARRAYS)


def _fast(m: Message) -> bool:
    """Whether the message gets straight-line wire encoders and decoders."""
    return _specialisable(m) or _two_arrays(m)


def _gen_python_wire(w: Callable[[str], None], data: dict, msgs: list[Message]) -> None:
    """Full-wire fast paths: encode_X(m) -> wire bytes and _decode_X(raw, n) -> message.

    The hot path (one Sensors and one Drive per period at 20 kHz) pays for every Python operation,
    so each specialisable message gets a straight-line encoder (fields unpacked once, one struct
    pack, the array count of the AN1017 profile unrolled, lengths, COBS inline for the usual frame
    without a zero, the CRC) and a decoder that unpacks the COBS-decoded buffer in place with a
    struct chosen by the message's length. Messages with strings or counted arrays reuse
    pack_X/unpack_X.
    """
    max_msg = data["max_frame_bytes"] + 1  # BY_LEN tables are indexed by the message length
    w("")
    w("# ---------------------------------------------------------------------------------------------")
    w("# Full-wire fast paths (L . message . L, COBS, check bytes, 0x00) used by hilbench.protocol.codec.")
    w("")
    for m in msgs:
        if not _specialisable(m):
            continue
        up = m.name.upper()
        var = [f for f in m.fields if f.variable]
        if var:
            f = var[0]
            _code, size = ARRAY_ELEM[f.type]
            mx = data[f.max]
            fl = m.fixed_len
            w(f"_{up}_BY_LEN = tuple(_{up}_ST[(k - {fl}) // {size}] if k >= {fl} and "
              f"(k - {fl}) % {size} == 0 and (k - {fl}) // {size} <= {mx} else None "
              f"for k in range({max_msg}))")
            if f.hot_n is not None:
                w(f"_{up}_ST{f.hot_n} = _{up}_ST[{f.hot_n}]")
    for m in msgs:
        if _two_arrays(m):
            a, b = [f for f in m.fields if f.variable]
            fixed_fmt = "<BB" + "".join(SCALAR_FMT[f.type] for f in m.fixed) + "B"
            w(f"_{m.name.upper()}_ST2 = tuple(tuple(struct.Struct({fixed_fmt!r} + {ARRAY_ELEM[a.type][0]!r} * i + "
              f"{ARRAY_ELEM[b.type][0]!r} * j) for j in range({data[b.max]} + 1)) for i in range({data[a.max]} + 1))")
            if a.hot_n is not None:
                for j in (0, 1):
                    w(f"_{m.name.upper()}_ST_{a.hot_n}_{j} = _{m.name.upper()}_ST2[{a.hot_n}][{j}]")
    for m in msgs:
        has_checks = any(f.bits for f in m.fields)
        variants = [("", True)] + ([("_unchecked", False)] if has_checks else [])
        for suffix, checked in variants:
            w("")
            w("")
            _gen_encoder(w, data, m, suffix, checked)
    for m in msgs:
        w("")
        w("")
        _gen_decoder(w, data, m)
    w("")
    w("")
    w("ENCODERS: dict[type, Callable[..., bytes]] = {")
    for m in msgs:
        w(f"    {m.name}: encode_{m.snake},")
    w("}")
    w("")
    w("# Range checks of bit fields skipped: only for messages the caller built itself (see codec).")
    w("UNCHECKED_ENCODERS: dict[type, Callable[..., bytes]] = {")
    for m in msgs:
        has_checks = any(f.bits for f in m.fields)
        w(f"    {m.name}: encode_{m.snake}{'_unchecked' if has_checks else ''},")
    w("}")
    w("")
    w("# Indexed by the frame type byte; None for a type this protocol version does not know.")
    w("_decoders: list = [None] * 256")
    for m in msgs:
        w(f"_decoders[{m.type_id:#04x}] = _decode_{m.snake}")
    w("DECODERS: tuple = tuple(_decoders)")
    w("del _decoders")
    w("_ENCODE_ERRORS = (struct.error, TypeError, ValueError, OverflowError, IndexError, AttributeError)")
    w("")
    w("")
    _gen_encode_frame(w, data, msgs)
    w("")
    w("")
    _gen_decode_body(w, data, msgs)
    w("")
    w("")


def _pack_lines(data: dict, m: Message, checks: str) -> list[str]:
    """Lines (4-space base indent) that unpack a message `m` and leave its frame in `body`.

    checks: "always", "never" or "if validate" (the bit-field range checks; struct checks the rest).
    """
    up = m.name.upper()
    out: list[str] = []
    names = ["seq"] + m.py_fields()
    out.append(f"    {_targets('x_' + n for n in names)} = m")
    ref = lambda n: f"x_{n}"  # noqa: E731
    check_lines = [line for f in m.fields if f.bits for line in _py_bits_check(f, ref)]
    if check_lines and checks == "always":
        out.extend(check_lines)
    elif check_lines and checks == "if validate":
        out.append("    if validate:")
        out.extend("    " + line for line in check_lines)
    args = [str(m.type_id), "x_seq"]
    var = [f for f in m.fields if f.variable]
    if _two_arrays(m):
        return out + _pack_two_arrays(data, m, args + [e for f in m.fixed for e in _py_pack_scalar_exprs(f, ref)])
    for f in m.fixed:
        if f.bits and var:  # the word is used by more than one pack call below: build it once
            out.append(f"    w_{f.name} = {_py_pack_scalar_exprs(f, ref)[0]}")
            args.append(f"w_{f.name}")
        else:
            args.extend(_py_pack_scalar_exprs(f, ref))
    if not var:
        out.append(f"    body = _{up}_ST.pack({', '.join(args)})")
        return out
    f = var[0]
    mx = data[f.max]
    arr = f"x_{f.name}"
    out.append(f"    n = len({arr})")
    first = "if"
    if f.hot_n is not None:
        elems = [f"e{i}" for i in range(f.hot_n)]
        flat = elems if f.type not in TUPLE_ARRAYS else [f"{e}[{k}]" for e in elems for k in (0, 1)]
        out.append(f"    if n == {f.hot_n}:")
        out.append(f"        {_targets(elems)} = {arr}")
        out.append(f"        body = _{up}_ST{f.hot_n}.pack({', '.join(args + flat)})")
        first = "elif"
    out.append(f"    {first} n <= {mx}:")
    if f.type in TUPLE_ARRAYS:
        out.append(f"        body = _{up}_ST[n].pack({', '.join(args)}, *[v for pair in {arr} for v in pair])")
    else:
        out.append(f"        body = _{up}_ST[n].pack({', '.join(args)}, *{arr})")
    out.append("    else:")
    out.append(f"        raise ProtocolError(f\"encode {m.name}: {f.name} has {{n}} entries, at most {mx}\")")
    return out


def _pack_two_arrays(data: dict, m: Message, args: list[str]) -> list[str]:
    """Lines that pack a counted array and a trailing one (the hot counts unrolled) into `body`."""
    up = m.name.upper()
    a, b = [f for f in m.fields if f.variable]
    flat_b = "[v for e in x_{0} for v in e]".format(b.name) if b.type in TUPLE_ARRAYS else f"x_{b.name}"
    out = [f"    na = len(x_{a.name})", f"    nb = len(x_{b.name})"]
    if a.hot_n is not None:
        elems = [f"e{i}" for i in range(a.hot_n)]
        out.append(f"    if na == {a.hot_n} and nb == 0:")
        out.append(f"        {_targets(elems)} = x_{a.name}")
        out.append(f"        body = _{up}_ST_{a.hot_n}_0.pack({', '.join(args + [str(a.hot_n)] + elems)})")
        out.append(f"    elif na <= {data[a.max]} and nb <= {data[b.max]}:")
    else:
        out.append(f"    if na <= {data[a.max]} and nb <= {data[b.max]}:")
    out.append(f"        body = _{up}_ST2[na][nb].pack({', '.join(args)}, na, *x_{a.name}, *{flat_b})")
    out.append("    else:")
    out.append(f"        raise ProtocolError(f\"encode {m.name}: {a.name} has {{na}} entries (at most {data[a.max]}), "
               f"{b.name} {{nb}} (at most {data[b.max]})\")")
    return out


# Lengths around the message, COBS (below 254 bytes each split part is one block behind its code
# byte; a message without a zero byte is one block), then the CRC over those bytes, as check bytes.
_WIRE_LINES = [
    "    k = len(body)",
    "    if k > MAX_FRAME_BYTES:",
    "        raise ProtocolError(f\"encode {type(m).__name__}: a message of {k} bytes exceeds {MAX_FRAME_BYTES}\")",
    "    ln = _BYTE[k + 6]",
    "    if 0 in body:",
    "        return wire_join((ln + body + ln).split(b'\\x00'))",
    "    e = b''.join((_CODE[k + 2], ln, body, ln))",
    "    c = _crc(e, 0xFFFF)",
    "    return e + _CHECK((c >> 9 | 0x80) << 24 | (c >> 2 & 0x7F | 0x80) << 16 | ((c & 3) << 5 | 0x80) << 8, 4, 'big')",
]


def _gen_encoder(w: Callable[[str], None], data: dict, m: Message, suffix: str, checked: bool) -> None:
    w(f"def encode_{m.snake}{suffix}(m: {m.name}) -> bytes:")
    if checked:
        w(f'    """{m.name} -> complete wire bytes (CRC, COBS, 0x00); ProtocolError/struct.error if unencodable."""')
    else:
        w(f'    """encode_{m.snake} without the bit-field range checks: for messages built by trusted code only."""')
    if not _fast(m):
        w(f"    return frame_bytes(pack_{m.snake}(m))")
        return
    for line in _pack_lines(data, m, "always" if checked else "never") + _WIRE_LINES:
        w(line)


def _gen_encode_frame(w: Callable[[str], None], data: dict, msgs: list[Message]) -> None:
    """encode_frame with the hot messages inlined (one Python call per frame instead of two)."""
    hot = [m for m in msgs if m.hot and _fast(m)]
    w("def encode_frame(m: Message, validate: bool = True) -> bytes:")
    w('    """One message -> its complete wire bytes, 0x00 included (ProtocolError if unencodable).')
    w("")
    w("    validate=False skips the bit-field range checks (Drive's duties, mode, state, sector), which")
    w("    would otherwise corrupt neighbouring bits silently; struct still checks every plain field.")
    w("    Only for messages the caller's own code built, never for anything that came off a wire.")
    w('    """')
    w("    t = type(m)")
    w("    try:")
    for i, m in enumerate(hot):
        w(f"        {'if' if i == 0 else 'elif'} t is {m.name}:")
        for line in _pack_lines(data, m, "if validate"):
            w("        " + line)
    w("        else:" if hot else "        if True:")
    w("            enc = (ENCODERS if validate else UNCHECKED_ENCODERS).get(t)")
    w("            if enc is None:")
    w("                raise ProtocolError(f\"encode: {t.__name__} is not a protocol message\")")
    w("            return enc(m)")
    w("        " + _WIRE_LINES[0].strip())
    w("    except _ENCODE_ERRORS as exc:")
    w("        raise ProtocolError(f\"encode {t.__name__}: {exc}\") from None")
    for line in _WIRE_LINES[1:]:
        w(line)


def _gen_decode_body(w: Callable[[str], None], data: dict, msgs: list[Message]) -> None:
    """decode_body: check bytes and CRC, COBS undone, lengths, then the hot messages inline and the
    rest by table."""
    w("def decode_body(g: bytes, n: int) -> Message:")
    w('    """One frame\'s n wire bytes between delimiters (no 0x00 in them, n <= MAX_WIRE_BYTES) -> message.')
    w("")
    w("    Raises LengthError, CrcError, CobsError or UnknownTypeError. The CRC is checked on the wire")
    w("    bytes as they are; then COBS: the code bytes after the first stand where the body's 0x00s")
    w("    were, so they are zeroed in a copy (raw[i + 1] is the body's byte i); both lengths must be n;")
    w("    the type byte picks the decoder.")
    w('    """')
    w("    if n < 8:")
    w("        raise LengthError(f\"frame of {n} wire bytes is shorter than 8\")")
    w("    m = n - 3")
    w("    t0 = g[m]")
    w("    t1 = g[n - 2]")
    w("    t2 = g[n - 1]")
    w("    if not (t0 & t1 & t2 & 0x80) or t2 & 0x1F or _crc(g[:m], 0xFFFF) != (t0 & 0x7F) << 9 | (t1 & 0x7F) << 2 | t2 >> 5 & 3:")
    w("        raise CrcError(f\"check bytes do not match a {n}-byte frame\")")
    w("    i = g[0]")
    w("    if i < m:")
    w("        raw = bytearray(g)")
    w("        while i < m:")
    w("            code = raw[i]")
    w("            raw[i] = 0")
    w("            i += code")
    w("        if i != m:")
    w("            raise CobsError(f\"COBS: last block runs {i - m} bytes past the frame end\")")
    w("    elif i == m:")
    w("        raw = g  # no 0x00 in the body: nothing to undo")
    w("    else:")
    w("        raise CobsError(f\"COBS: block at offset 0 runs {i - m} bytes past the frame end\")")
    w("    if raw[1] != n or raw[n - 4] != n:")
    w("        raise LengthError(f\"a {n}-byte frame says it is {raw[1]} and {raw[n - 4]} bytes long\")")
    w("    k = n - 6  # the message's length")
    w("    t = raw[2]")
    for i, m in enumerate(m for m in msgs if m.hot and _fast(m)):
        w(f"    {'if' if i == 0 else 'elif'} t == {m.type_id:#04x}:")
        lines = _decode_lines(data, m, inline=True)
        for line in lines:
            w("    " + line)
    w("    decode = DECODERS[t]")
    w("    if decode is None:")
    w("        raise UnknownTypeError(f\"unknown frame type {t:#04x}\")")
    w("    return decode(raw, k)")


def _targets(names: Iterable[str]) -> str:
    """Left-hand side of a tuple unpacking (a trailing comma only for one name)."""
    names = list(names)
    return ", ".join(names) + ("," if len(names) == 1 else "")


def _gen_decoder(w: Callable[[str], None], data: dict, m: Message) -> None:
    w(f"def _decode_{m.snake}(raw: bytes, k: int) -> {m.name}:")
    w(f'    """A checked frame (raw[2:2 + k] is the message: type . seq . payload) -> {m.name}."""')
    if not _fast(m):
        w(f"    return unpack_{m.snake}(bytes(raw[2:2 + k]))")
        return
    for line in _decode_lines(data, m, inline=False):
        w(line)


def _decode_lines(data: dict, m: Message, inline: bool) -> list[str]:
    """Lines (4-space indent) that turn raw (the message at raw[2:2 + k]) into a message and return it.

    inline=True (inside decode_body): a bad length is not raised here but falls through to the
    table decoder, which raises the LengthError.
    """
    up = m.name.upper()
    out: list[str] = []
    var = [f for f in m.fields if f.variable]
    fl = m.fixed_len
    args = ["v[1]"]
    idx = 2
    for f in m.fixed:
        args.extend(_py_unpack_scalar(f, f"v[{idx}]"))
        idx += 1
    if _two_arrays(m):
        a, b = var
        sa, sb = ARRAY_ELEM[a.type][1], ARRAY_ELEM[b.type][1]
        first = f"v[{idx + 1}:{idx + 1} + na]"
        second = (f"tuple(zip(v[{idx + 1} + na::2], v[{idx + 2} + na::2]))" if b.type in TUPLE_ARRAYS
                  else f"v[{idx + 1} + na:]")
        out.append(f"    na = raw[{2 + fl}] if k > {fl} else 255")
        out.append(f"    r = k - {fl + 1} - {sa} * na")
        test = f"na <= {data[a.max]} and r >= 0 and r % {sb} == 0 and r // {sb} <= {data[b.max]}"
        if inline:
            out.append(f"    if {test}:")
            out.append(f"        v = _{up}_ST2[na][r // {sb}].unpack_from(raw, 2)")
            out.append(f"        return _tnew({m.name}, ({', '.join(m.reorder(args + [first, second]))}))")
        else:
            out.append(f"    if not ({test}):")
            out.append(f"        raise LengthError(f\"{m.name}: payload of {{k - 2}} bytes does not hold {{na}} {a.name} "
                       f"and whole {b.name}\")")
            out.append(f"    v = _{up}_ST2[na][r // {sb}].unpack_from(raw, 2)")
            out.append(f"    return _tnew({m.name}, ({', '.join(m.reorder(args + [first, second]))}))")
        return out
    if not var:
        if inline:
            out.append(f"    if k == {fl}:")
            cond = len(out)
        else:
            out.append(f"    if k != {fl}:")
            out.append(f"        raise LengthError(f\"{m.name}: payload of {{k - 2}} bytes, expected {fl - 2}\")")
        out.append(f"    v = _{up}_ST.unpack_from(raw, 2)")
    else:
        f = var[0]
        _code, size = ARRAY_ELEM[f.type]
        mx = data[f.max]
        out.append(f"    st = _{up}_BY_LEN[k]")
        if inline:
            out.append("    if st is not None:")
            cond = len(out)
        else:
            out.append("    if st is None:")
            out.append(f"        raise LengthError(f\"{m.name}: payload of {{k - 2}} bytes is not {fl - 2} + {size}*n (n <= {mx})\")")
        out.append("    v = st.unpack_from(raw, 2)")
        if f.type in TUPLE_ARRAYS:
            args.append(f"tuple(zip(v[{idx}::2], v[{idx + 1}::2]))")
        else:
            args.append(f"v[{idx}:]")
    if not var and args == [f"v[{i}]" for i in range(1, idx)] and not m.py_order:
        out.append(f"    return _tnew({m.name}, v[1:])")
    else:
        for i, f in enumerate(m.fixed):
            if f.bits:  # name the bit-field word once instead of indexing v in every term
                out.append(f"    w{i + 2} = v[{i + 2}]")
                args = [a.replace(f"v[{i + 2}]", f"w{i + 2}") for a in args]
        out.append(f"    return _tnew({m.name}, ({_targets(m.reorder(args))}))")
    if inline:  # everything after the length test belongs to its if-block
        out = out[:cond] + ["    " + line for line in out[cond:]]
    return out


def gen_python(data: dict, enums: list, msgs: list[Message]) -> str:
    L: list[str] = []
    w = L.append
    w('"""Wire messages of the hilbench protocol: GENERATED by firmware_protocol/generate.py from')
    w("firmware_protocol/schema.toml. Do not edit; change the schema and re-run the generator.")
    w("")
    w("Each message is a NamedTuple whose first field is `seq`. `PACKERS[cls](msg)` gives the frame")
    w("without CRC (type . seq . payload); `UNPACKERS[type_byte](frame)` parses one (CRC already")
    w("stripped) and raises LengthError on a malformed payload. The codec's hot path uses the full-wire")
    w("fast paths instead: `ENCODERS[cls](msg)` -> wire bytes, and `DECODERS[type_byte](raw, n)` on a")
    w('COBS-decoded, CRC-checked buffer."""')
    w("")
    w("from __future__ import annotations")
    w("")
    w("import struct")
    w("from enum import IntEnum")
    w("from typing import Callable, NamedTuple, Union")
    w("")
    w("from binascii import crc_hqx as _crc")
    w("")
    w("from hilbench.errors import ProtocolError")
    w("from hilbench.protocol.framing import BYTE as _BYTE")
    w("from hilbench.protocol.framing import COBS_CODE as _CODE")
    w("from hilbench.protocol.framing import CobsError, CrcError, LengthError, UnknownTypeError, frame_bytes, wire_join")
    w("")
    w("_CHECK = int.to_bytes  # the check bytes and the delimiter as one int (PROTOCOL.md, Framing)")
    w(f"PROTOCOL_VERSION = {data['protocol_version']}")
    w("# First 4 bytes of SHA-256 over the schema's canonical wire content (generate.schema_fingerprint).")
    w(f"SCHEMA_FINGERPRINT = {schema_fingerprint(data):#010x}")
    w(f"MAX_FRAME_BYTES = {data['max_frame_bytes']}")
    w(f"MAX_NAME_CHARS = {data['max_name_chars']}")
    w(f"MAX_UNIT_CHARS = {data['max_unit_chars']}")
    w(f"MAX_EDGES = {data['max_edges']}")
    w(f"MAX_ADC = {data['max_adc']}")
    w(f"MAX_TELEMETRY = {data['max_telemetry']}")
    w(f"MAX_PARAM_PAIRS = {data['max_param_pairs']}")
    w(f"MAX_BATCH_BYTES = {data['max_batch_bytes']}")
    w("")
    w("_tnew = tuple.__new__")
    w("")
    for name, prefix, doc, members in enums:
        w("")
        w(f"class {name}(IntEnum):")
        w(f'    """{doc}."""')
        w("")
        for mname, value in members:
            w(f"    {mname} = {value:#x}" if value > 9 else f"    {mname} = {value}")
        w("")
    w("")
    for name, prefix, doc, members in enums:
        for mname, _ in members:
            w(f"{prefix}_{mname} = {name}.{mname}")
    w("")
    for m in msgs:
        w("")
        w(f"class {m.name}(NamedTuple):")
        w(f'    """{ "host -> target" if m.dir == "h2t" else "target -> host"}, frame type {m.type_id:#04x}."""')
        w("")
        w("    seq: int")
        by_name = {f.name: f for f in m.fields}
        for f in (by_name[n] for n in m.py_order) if m.py_order else m.fields:
            if f.bits:
                for bname, _w, kind in f.bits:
                    w(f"    {bname}: {'bool' if kind == 'bool' else 'int'}")
            elif f.type == "bool":
                w(f"    {f.name}: bool")
            elif f.type == "str":
                w(f"    {f.name}: str" + (f" = {f.default}" if f.default is not None else ""))
            elif f.type in TUPLE_ARRAYS:
                w(f"    {f.name}: tuple[tuple[int, int], ...]" + (f" = {f.default}" if f.default is not None else ""))
            elif f.variable:
                w(f"    {f.name}: tuple[int, ...]" + (f" = {f.default}" if f.default is not None else ""))
            elif f.default is not None:
                w(f"    {f.name}: int = {f.default}")
            else:
                w(f"    {f.name}: int")
        w("")
        w(f"    TYPE = {m.type_id:#04x}")
        w("")
    w("")
    w("Message = Union[" + ", ".join(m.name for m in msgs) + "]")
    w("")
    # structs
    for m in msgs:
        fixed_fmt = "<BB" + "".join(SCALAR_FMT[f.type] for f in m.fixed)
        var = [f for f in m.fields if f.variable]
        up = m.name.upper()
        if len(var) == 1 and var[0].last and var[0].type != "str":
            f = var[0]
            code, _size = ARRAY_ELEM[f.type]
            mx = data[f.max]
            w(f"_{up}_ST = tuple(struct.Struct({fixed_fmt!r} + {code!r} * n) for n in range({mx} + 1))")
        else:
            w(f"_{up}_ST = struct.Struct({fixed_fmt!r})")
    w("")
    # packers
    for m in msgs:
        up = m.name.upper()
        var = [f for f in m.fields if f.variable]
        w("")
        w(f"def pack_{m.snake}(m: {m.name}) -> bytes:")
        w(f'    """{m.name} -> type . seq . payload (no CRC)."""')
        for f in m.fields:
            if f.bits:
                L.extend(_py_bits_check(f))
        fixed_args = [str(m.type_id), "m.seq"]
        for f in m.fixed:
            fixed_args.extend(_py_pack_scalar_exprs(f))
        if not var:
            w(f"    return _{up}_ST.pack({', '.join(fixed_args)})")
        elif len(var) == 1 and var[0].last and var[0].type != "str":
            f = var[0]
            mx = data[f.max]
            w(f"    arr = m.{f.name}")
            w(f"    if len(arr) > {mx}:")
            w(f"        raise ProtocolError(f\"encode {m.name}: {f.name} has {{len(arr)}} entries, at most {mx}\")")
            if f.type in TUPLE_ARRAYS:
                w(f"    return _{up}_ST[len(arr)].pack({', '.join(fixed_args)}, *[v for pair in arr for v in pair])")
            else:
                w(f"    return _{up}_ST[len(arr)].pack({', '.join(fixed_args)}, *arr)")
        else:
            w(f"    parts = [_{up}_ST.pack({', '.join(fixed_args)})]")
            for f in var:
                mx = data[f.max]
                if f.type == "str":
                    w(f"    raw = _ascii(m.{f.name}, {mx}, {m.name!r}, {f.name!r})")
                else:
                    code, _size = ARRAY_ELEM[f.type]
                    w(f"    if len(m.{f.name}) > {mx}:")
                    w(f"        raise ProtocolError(f\"encode {m.name}: {f.name} has {{len(m.{f.name})}} entries, at most {mx}\")")
                    flat = f"[v for e in m.{f.name} for v in e]" if f.type in TUPLE_ARRAYS else f"m.{f.name}"
                    w(f"    raw = struct.pack('<' + {code!r} * len(m.{f.name}), *{flat})")
                if not f.last:
                    w("    parts.append(bytes((len(raw),)))" if f.type == "str" else
                      f"    parts.append(bytes((len(m.{f.name}),)))")
                w("    parts.append(raw)")
            w("    return b''.join(parts)")
        w("")
    # unpackers
    for m in msgs:
        up = m.name.upper()
        var = [f for f in m.fields if f.variable]
        w("")
        w(f"def unpack_{m.snake}(b: bytes) -> {m.name}:")
        w(f'    """type . seq . payload (no CRC) -> {m.name}; LengthError if malformed."""')
        args = ["v[1]"]
        idx = 2
        for f in m.fixed:
            args.extend(_py_unpack_scalar(f, f"v[{idx}]"))
            idx += 1
        fl = m.fixed_len
        if not var:
            w(f"    if len(b) != {fl}:")
            w(f"        raise LengthError(f\"{m.name}: payload of {{len(b) - 2}} bytes, expected {fl - 2}\")")
            w(f"    v = _{up}_ST.unpack(b)")
            if args == [f"v[{i}]" for i in range(1, idx)] and not m.py_order:
                w(f"    return _tnew({m.name}, v[1:])")
            else:
                w(f"    return _tnew({m.name}, ({', '.join(m.reorder(args))},))")
        elif len(var) == 1 and var[0].last and var[0].type != "str":
            f = var[0]
            _code, size = ARRAY_ELEM[f.type]
            mx = data[f.max]
            w(f"    n, r = divmod(len(b) - {fl}, {size})")
            w(f"    if r or n < 0 or n > {mx}:")
            w(f"        raise LengthError(f\"{m.name}: payload of {{len(b) - 2}} bytes is not {fl - 2} + {size}*n (n <= {mx})\")")
            w(f"    v = _{up}_ST[n].unpack(b)")
            if f.type in TUPLE_ARRAYS:
                args.append(f"tuple(zip(v[{idx}::2], v[{idx + 1}::2]))")
            else:
                args.append(f"v[{idx}:]")
            w(f"    return _tnew({m.name}, ({', '.join(m.reorder(args))},))")
        else:
            w(f"    if len(b) < {fl}:")
            w(f"        raise LengthError(f\"{m.name}: payload of {{len(b) - 2}} bytes, at least {fl - 2}\")")
            w(f"    v = _{up}_ST.unpack_from(b)")
            w(f"    pos = {fl}")
            for f in var:
                mx = data[f.max]
                _code, size = ARRAY_ELEM.get(f.type, ("", 1))
                if f.last:
                    w(f"    n, r = divmod(len(b) - pos, {size})")
                    w("    if r:")
                    w(f"        raise LengthError(\"{m.name}: {f.name} has a partial entry\")")
                else:
                    w("    if pos >= len(b):")
                    w(f"        raise LengthError(\"{m.name}: missing the count of {f.name}\")")
                    w("    n = b[pos]")
                    w("    pos += 1")
                    w(f"    if pos + n * {size} > len(b):")
                    w(f"        raise LengthError(f\"{m.name}: {f.name} count {{n}} runs past the frame end\")")
                w(f"    if n > {mx}:")
                w(f"        raise LengthError(f\"{m.name}: {f.name} has {{n}} entries, at most {mx}\")")
                if f.type == "str":
                    w(f"    f_{f.name} = _unascii(b[pos:pos + n], {m.name!r}, {f.name!r})")
                elif f.type == "u8[]":
                    w(f"    f_{f.name} = tuple(b[pos:pos + n])")
                elif f.type in TUPLE_ARRAYS:
                    code, size = ARRAY_ELEM[f.type]
                    w(f"    x = struct.unpack_from('<' + {code!r} * n, b, pos)")
                    w(f"    f_{f.name} = tuple(zip(x[::2], x[1::2]))")
                else:
                    code, size = ARRAY_ELEM[f.type]
                    w(f"    f_{f.name} = struct.unpack_from('<' + {code!r} * n, b, pos)")
                w(f"    pos += n * {size}")
                args.append(f"f_{f.name}")
            w(f"    return _tnew({m.name}, ({', '.join(m.reorder(args))},))")
        w("")
    w("")
    w("def _ascii(text: str, max_chars: int, msg: str, field: str) -> bytes:")
    w('    """Encode a short printable ASCII name (no NUL: names are length-delimited)."""')
    w("    try:")
    w("        raw = text.encode('ascii')")
    w("    except UnicodeEncodeError:")
    w("        raise ProtocolError(f\"encode {msg}: {field} {text!r} is not ASCII\") from None")
    w("    if len(raw) > max_chars or not all(0x20 <= c < 0x7F for c in raw):")
    w("        raise ProtocolError(f\"encode {msg}: {field} {text!r} must be at most {max_chars} printable ASCII characters\")")
    w("    return raw")
    w("")
    w("")
    w("def _unascii(raw: bytes, msg: str, field: str) -> str:")
    w('    """Decode a name; anything but printable ASCII is a malformed payload."""')
    w("    if not all(0x20 <= c < 0x7F for c in raw):")
    w("        raise LengthError(f\"{msg}: {field} is not printable ASCII\")")
    w("    return raw.decode('ascii')")
    w("")
    w("")
    _gen_python_wire(w, data, msgs)
    w("PACKERS: dict[type, Callable[..., bytes]] = {")
    for m in msgs:
        w(f"    {m.name}: pack_{m.snake},")
    w("}")
    w("")
    w("UNPACKERS: dict[int, Callable[[bytes], Message]] = {")
    for m in msgs:
        w(f"    {m.type_id:#04x}: unpack_{m.snake},")
    w("}")
    w("")
    w("MESSAGE_TYPES: dict[int, type] = {")
    for m in msgs:
        w(f"    {m.type_id:#04x}: {m.name},")
    w("}")
    w("")
    w("HOST_TO_TARGET = frozenset({" + ", ".join(m.name for m in msgs if m.dir == "h2t") + "})")
    w("TARGET_TO_HOST = frozenset({" + ", ".join(m.name for m in msgs if m.dir == "t2h") + "})")
    w("")
    names = ["PROTOCOL_VERSION", "SCHEMA_FINGERPRINT", "MAX_FRAME_BYTES", "MAX_NAME_CHARS", "MAX_UNIT_CHARS",
             "MAX_EDGES", "MAX_ADC", "MAX_TELEMETRY", "MAX_PARAM_PAIRS", "Message", "PACKERS", "UNPACKERS", "ENCODERS", "UNCHECKED_ENCODERS",
             "DECODERS", "MESSAGE_TYPES", "HOST_TO_TARGET",
             "TARGET_TO_HOST"]
    names += [e[0] for e in enums]
    names += [f"{prefix}_{mn}" for (_n, prefix, _d, members) in enums for mn, _v in members]
    names += [m.name for m in msgs]
    w("__all__ = [")
    for n in names:
        w(f"    {n!r},")
    w("]")
    w("")
    return "\n".join(L)


# ----------------------------------------------------------------------------------------------
# C


def c_max(data: dict, key: str) -> str:
    return {"max_adc": "HBP_MAX_ADC", "max_telemetry": "HBP_MAX_TELEMETRY", "max_name_chars": "HBP_MAX_NAME",
            "max_unit_chars": "HBP_MAX_UNIT", "max_param_pairs": "HBP_MAX_PARAM_PAIRS",
            "max_edges": "HBP_MAX_EDGES", "max_batch_bytes": "HBP_MAX_BATCH"}[key]


# The C codec is table-driven: each message is a const layout (hbp_messages.c) that the one packer
# and unpacker in hbp.c walk. A table entry costs a few bytes of flash where a function per message
# cost hundreds (a 16-bit MCU's flash is the limit: docs/board.md).
C_KIND = {"u8": "HBP_F_U8", "bool": "HBP_F_BOOL", "u16": "HBP_F_U16", "i16": "HBP_F_I16", "u32": "HBP_F_U32",
          "i32": "HBP_F_I32"}
C_ARRAY_KIND = {"u8[]": "HBP_F_U8", "u16[]": "HBP_F_U16", "i16[]": "HBP_F_I16", "pair[]": "HBP_F_PAIR",
                "edge[]": "HBP_F_EDGE"}
BITS_BYTES = {"bits8": 1, "bits16": 2, "bits32": 4}


def gen_header(data: dict, enums: list, msgs: list[Message]) -> str:
    L: list[str] = []
    w = L.append
    w("/* hbp_messages.h: GENERATED by firmware_protocol/generate.py from schema.toml. Do not edit. */")
    w("#ifndef HBP_MESSAGES_H")
    w("#define HBP_MESSAGES_H")
    w("")
    w("#include <stdint.h>")
    w("")
    w("/* A byte of the wire: at least 8 bits (16 on the C28x, whose char is 16 bits); only its low 8")
    w("   bits are ever used. */")
    w("typedef uint_least8_t hbp_u8;")
    w("")
    w(f"#define HBP_PROTOCOL_VERSION {data['protocol_version']}u")
    w("/* First 4 bytes of SHA-256 over schema.toml's canonical wire content (see PROTOCOL.md). The #ifndef")
    w("   exists only so that a test can build a deliberately mismatched target; never override it in a")
    w("   firmware. */")
    w("#ifndef HBP_SCHEMA_FINGERPRINT")
    w(f"#define HBP_SCHEMA_FINGERPRINT {schema_fingerprint(data):#010x}UL")
    w("#endif")
    w(f"#define HBP_MAX_FRAME {data['max_frame_bytes']}u /* a message: type, seq, payload */")
    w(f"#define HBP_MAX_NAME {data['max_name_chars']}u")
    w(f"#define HBP_MAX_UNIT {data['max_unit_chars']}u")
    w(f"#define HBP_MAX_PARAM_PAIRS {data['max_param_pairs']}u")
    w("/* Array capacities of the structs below; a firmware may lower them to its profile (-D...). */")
    for key, macro in (("max_adc", "HBP_MAX_ADC"), ("max_telemetry", "HBP_MAX_TELEMETRY"),
                       ("max_edges", "HBP_MAX_EDGES"), ("max_batch_bytes", "HBP_MAX_BATCH")):
        w(f"#ifndef {macro}")
        w(f"#define {macro} {data[key]}u")
        w("#endif")
    w("")
    for name, prefix, doc, members in enums:
        w(f"/* {doc} */")
        for mname, value in members:
            w(f"#define HBP_{prefix}_{mname} {value:#04x}u")
        w("")
    w("/* One (parameter id, value) pair of ParamSet. */")
    w("typedef struct {")
    w("    hbp_u8 id;")
    w("    int32_t value;")
    w("} hbp_pair_t;")
    w("")
    w("/* One input edge of Sensors: its time from the span's start (100 ns units) and the lines after it. */")
    w("typedef struct {")
    w("    uint16_t time_100ns;")
    w("    hbp_u8 lines;")
    w("} hbp_edge_t;")
    w("")
    w("/* A message's layout for the table-driven codec (hbp.c): one entry per wire field, in order. */")
    w("#define HBP_F_U8 1u")
    w("#define HBP_F_BOOL 2u")
    w("#define HBP_F_U16 3u")
    w("#define HBP_F_I16 4u")
    w("#define HBP_F_U32 5u")
    w("#define HBP_F_I32 6u")
    w("#define HBP_F_PAIR 7u")
    w("#define HBP_F_EDGE 8u")
    w("#define HBP_F_STR 9u   /* a NUL-terminated char array: aux = max chars */")
    w("#define HBP_F_ARRAY 10u /* aux = element kind, max = capacity, count at `count` */")
    w("#define HBP_F_BITS 11u  /* a word of aux bytes holding the next `max` HBP_F_BIT entries */")
    w("#define HBP_F_BIT 12u   /* aux = width in bits; the member is a uint8_t (width <= 8) or uint16_t */")
    w("#define HBP_F_LAST 0x80u /* (or'ed into kind) the last field: its length is the frame's rest */")
    w("typedef struct {")
    w("    hbp_u8 kind;")
    w("    hbp_u8 offset; /* of the member in the message struct */")
    w("    hbp_u8 aux;")
    w("    hbp_u8 max;")
    w("    hbp_u8 count;  /* HBP_F_ARRAY: offset of its n_ member */")
    w("} hbp_field_t;")
    w("typedef struct {")
    w("    hbp_u8 type;")
    w("    hbp_u8 n_fields;")
    w("    const hbp_field_t *fields;")
    w("} hbp_layout_t;")
    w("")
    for m in msgs:
        w(f"/* {m.name}: {'host -> target' if m.dir == 'h2t' else 'target -> host'}, type {m.type_id:#04x}, "
          f"{m.fixed_len - 2} fixed payload bytes. */")
        w(f"#define HBP_{m.type_name}_FIXED_LEN {m.fixed_len}u /* type + seq + fixed fields */")
        w("typedef struct {")
        w("    hbp_u8 seq;")
        for f in m.fields:
            if f.bits:
                for bname, width, kind in f.bits:
                    w(f"    {'hbp_u8' if width <= 8 else 'uint16_t'} {bname};{' /* 0 or 1 */' if kind == 'bool' else ''}")
            elif f.type == "str":
                w(f"    char {f.name}[{c_max(data, f.max)} + 1u]; /* NUL-terminated ASCII */")
            elif f.variable:
                w(f"    hbp_u8 n_{f.name};")
                w(f"    {C_ELEM[f.type]} {f.name}[{c_max(data, f.max)}];")
            else:
                w(f"    {C_SCALAR[f.type]} {f.name};")
        w(f"}} hbp_{m.snake}_t;")
        w(f"extern const hbp_layout_t hbp_layout_{m.snake};")
        w("")
    w("/* hbp_pack_into(layout, m, frame, cap) writes type, seq and payload to frame[0..cap) and returns the")
    w("   length, or 0 if the message does not fit (a count above its maximum, or more than cap bytes);")
    w("   hbp_pack(layout, m, frame): cap HBP_MAX_FRAME.")
    w("   hbp_unpack(layout, frame, len, m) parses such a frame of len bytes: HBP_ERROR_NONE or")
    w("   HBP_ERROR_LENGTH. (hbp.c; the layouts are in hbp_messages.c.) */")
    w("hbp_u8 hbp_pack_into(const hbp_layout_t *layout, const void *m, hbp_u8 *frame, hbp_u8 cap);")
    w("#define hbp_pack(layout, m, frame) hbp_pack_into((layout), (m), (frame), HBP_MAX_FRAME)")
    w("hbp_u8 hbp_unpack(const hbp_layout_t *layout, const hbp_u8 *frame, hbp_u8 len, void *m);")
    for m in msgs:
        w(f"#define hbp_pack_{m.snake}(m, frame) hbp_pack(&hbp_layout_{m.snake}, (const hbp_{m.snake}_t *)(m), (frame))")
        w(f"#define hbp_unpack_{m.snake}(frame, len, m) hbp_unpack(&hbp_layout_{m.snake}, (frame), (len), "
          f"(hbp_{m.snake}_t *)(m))")
    w("")
    w("/* 1 if the type byte names a message of this protocol: its bit in the mask of its group (the type's")
    w(" * high nibble). Not a switch (over the sparse types it becomes a table of one entry per value from the")
    w(" * first to the last) nor a compare per run of types (36 words of a 12 KB dsPIC's flash). */")
    w("static inline hbp_u8 hbp_type_known(hbp_u8 type)")
    w("{")
    groups: dict[int, int] = {}
    for m in msgs:
        groups[m.type_id >> 4] = groups.get(m.type_id >> 4, 0) | (1 << (m.type_id & 15))
    n_groups = max(groups) + 1
    masks = ", ".join(f"0x{groups.get(g, 0):04X}u" for g in range(n_groups))
    w(f"    static const uint16_t known[{n_groups}] = {{{masks}}};")
    w(f"    return (hbp_u8)((unsigned)type >> 4 < {n_groups}u && (((unsigned)known[type >> 4] >> (type & 15u)) & 1u) != 0u);")
    w("}")
    w("")
    w("#endif /* HBP_MESSAGES_H */")
    w("")
    return "\n".join(L)


def _c_fields(data: dict, m: Message) -> list[str]:
    """The layout entries of one message (C initialisers)."""
    st = f"hbp_{m.snake}_t"
    rows: list[str] = []
    for f in m.fields:
        last = " | HBP_F_LAST" if f.last and f.variable else ""
        if f.bits:
            rows.append(f"{{HBP_F_BITS, 0u, {BITS_BYTES[f.type]}u, {len(f.bits)}u, 0u}}")
            for bname, width, _kind in f.bits:
                rows.append(f"{{HBP_F_BIT, (hbp_u8)offsetof({st}, {bname}), {width}u, 0u, 0u}}")
        elif f.type == "str":
            rows.append(f"{{HBP_F_STR{last}, (hbp_u8)offsetof({st}, {f.name}), {c_max(data, f.max)}, 0u, 0u}}")
        elif f.variable:
            rows.append(f"{{HBP_F_ARRAY{last}, (hbp_u8)offsetof({st}, {f.name}), {C_ARRAY_KIND[f.type]}, "
                        f"{c_max(data, f.max)}, (hbp_u8)offsetof({st}, n_{f.name})}}")
        else:
            rows.append(f"{{{C_KIND[f.type]}, (hbp_u8)offsetof({st}, {f.name}), 0u, 0u, 0u}}")
    return rows


def gen_c(data: dict, enums: list, msgs: list[Message]) -> str:
    """The layouts of every message, for hbp.c's one packer and one unpacker."""
    L: list[str] = []
    w = L.append
    w("/* hbp_messages.c: GENERATED by firmware_protocol/generate.py from schema.toml. Do not edit.")
    w("   One const layout per message (its wire fields in order) for hbp_pack/hbp_unpack in hbp.c. With")
    w("   -fdata-sections and --gc-sections a build keeps only the layouts it uses. C99, no heap. */")
    w("#include <stddef.h>")
    w("")
    w('#include "hbp_messages.h"')
    w("")
    for m in msgs:
        rows = _c_fields(data, m)
        if rows:
            w(f"static const hbp_field_t fields_{m.snake}[{len(rows)}] = {{")
            for r in rows:
                w(f"    {r},")
            w("};")
        w(f"const hbp_layout_t hbp_layout_{m.snake} = {{HBP_MSG_{m.type_name}, {len(rows)}u, "
          f"{'fields_' + m.snake if rows else '0'}}};")
        w("")
    return "\n".join(L)


def gen_test_fields(data: dict, enums: list, msgs: list[Message]) -> str:
    """Test-only C helpers: a union of all messages, unpack/pack by type, field lookup by name."""
    L: list[str] = []
    w = L.append
    w("/* hbp_test_fields.h: GENERATED by firmware_protocol/generate.py. Test programs only (uses strcmp). */")
    w("#ifndef HBP_TEST_FIELDS_H")
    w("#define HBP_TEST_FIELDS_H")
    w("")
    w("#include <string.h>")
    w("")
    w('#include "hbp_messages.h"')
    w("")
    w("typedef union {")
    for m in msgs:
        w(f"    hbp_{m.snake}_t {m.snake};")
    w("} hbp_any_t;")
    w("")
    w("static const char *hbp_test_name(hbp_u8 type)")
    w("{")
    w("    switch (type) {")
    for m in msgs:
        w(f'    case HBP_MSG_{m.type_name}: return "{m.name}";')
    w("    default: return 0;")
    w("    }")
    w("}")
    w("")
    w("static hbp_u8 hbp_test_unpack(const hbp_u8 *frame, hbp_u8 len, hbp_any_t *m)")
    w("{")
    w("    switch (frame[0]) {")
    for m in msgs:
        w(f"    case HBP_MSG_{m.type_name}: return hbp_unpack_{m.snake}(frame, len, &m->{m.snake});")
    w("    default: return HBP_ERROR_UNKNOWN_TYPE;")
    w("    }")
    w("}")
    w("")
    w("static hbp_u8 hbp_test_pack(hbp_u8 type, const hbp_any_t *m, hbp_u8 *frame)")
    w("{")
    w("    switch (type) {")
    for m in msgs:
        w(f"    case HBP_MSG_{m.type_name}: return hbp_pack_{m.snake}(&m->{m.snake}, frame);")
    w("    default: return 0u;")
    w("    }")
    w("}")
    w("")
    w("/* 0: no such field; 1: scalar in *value; 2: array (*count entries, entry `index` in *value;")
    w("   pair arrays are flattened id, value, id, value...); 3: string in *str. */")
    w("static int hbp_test_field(hbp_u8 type, const hbp_any_t *m, const char *name, unsigned index,")
    w("                          long long *value, unsigned *count, const char **str)")
    w("{")
    for m in msgs:
        w(f"    if (type == HBP_MSG_{m.type_name}) {{")
        w(f"        const hbp_{m.snake}_t *x = &m->{m.snake};")
        w('        if (strcmp(name, "seq") == 0) { *value = x->seq; return 1; }')
        for f in m.fields:
            if f.bits:
                for bname, _wd, _k in f.bits:
                    w(f'        if (strcmp(name, "{bname}") == 0) {{ *value = x->{bname}; return 1; }}')
            elif f.type == "str":
                w(f'        if (strcmp(name, "{f.name}") == 0) {{ *str = x->{f.name}; return 3; }}')
            elif f.type in TUPLE_ARRAYS:
                first, second = ("id", "value") if f.type == "pair[]" else ("time_100ns", "lines")
                w(f'        if (strcmp(name, "{f.name}") == 0) {{')
                w(f"            *count = 2u * x->n_{f.name};")
                w(f"            if (index < *count) {{ *value = (index % 2u == 0u) ? x->{f.name}[index / 2u].{first} "
                  f": x->{f.name}[index / 2u].{second}; }}")
                w("            return 2;")
                w("        }")
            elif f.variable:
                w(f'        if (strcmp(name, "{f.name}") == 0) {{')
                w(f"            *count = x->n_{f.name};")
                w(f"            if (index < *count) {{ *value = x->{f.name}[index]; }}")
                w("            return 2;")
                w("        }")
            else:
                w(f'        if (strcmp(name, "{f.name}") == 0) {{ *value = x->{f.name}; return 1; }}')
        w("    }")
    w("    return 0;")
    w("}")
    w("")
    w("#endif /* HBP_TEST_FIELDS_H */")
    w("")
    return "\n".join(L)


def outputs() -> dict[Path, str]:
    data, enums, msgs = load()
    return {PY_OUT: gen_python(data, enums, msgs), H_OUT: gen_header(data, enums, msgs),
            C_OUT: gen_c(data, enums, msgs), TEST_OUT: gen_test_fields(data, enums, msgs)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if a generated file is stale")
    args = parser.parse_args(argv)
    stale = []
    for path, text in outputs().items():
        current = path.read_text(encoding="utf-8") if path.exists() else None
        if current != text:
            stale.append(path)
            if not args.check:
                path.write_text(text, encoding="utf-8")
    if args.check and stale:
        for path in stale:
            print(f"stale: {path.relative_to(REPO)} (run python firmware_protocol/generate.py)", file=sys.stderr)
        return 1
    if not args.check:
        for path in stale:
            print(f"wrote {path.relative_to(REPO)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
