"""COBS framing and CRC-16/CCITT-FALSE: the byte layer under the messages.

A frame on the wire is COBS(type . seq . payload . crc16_be) followed by one 0x00. The CRC goes high
byte first, so frame and CRC read MSB first are one codeword of the polynomial division: every
burst of up to 16 bits is detected (a CRC sent low byte first is not, PROTOCOL.md). COBS removes
every 0x00 from the frame, so the next 0x00 is always a frame boundary: a receiver that lost its
place resynchronises there. Decoded frames are at most MAX_FRAME_BYTES (64), so COBS never needs a
0xFF block and adds exactly one byte.
"""

from __future__ import annotations

from binascii import crc_hqx

from hilbench.errors import DecodeError

MAX_FRAME_BYTES = 64
MAX_ENCODED_BYTES = MAX_FRAME_BYTES + 1  # COBS body without the delimiter
MIN_FRAME_BYTES = 4  # type, seq, crc16

_CODE = tuple(bytes((i,)) for i in range(256))

# COBS_CODE[k]: the code byte that opens a block of k data bytes (k + 1); frames stay < 254 bytes.
COBS_CODE = tuple(bytes((k + 1,)) for k in range(254))


def _crc_pre() -> tuple[int, ...]:
    """CRC_PRE: check a COBS-decoded frame's CRC in one crc_hqx call, without slicing.

    The decoder's buffer is code . frame . crc_hi . crc_lo. CRC_PRE[code] is the register value
    from which the code byte steps to 0xFFFF (the CCITT-FALSE init), so crc_hqx(buf, CRC_PRE[code])
    is the CRC register after frame . hi . lo. Feeding a register c the two bytes hi . lo leaves
    F(c ^ (hi << 8 | lo)) with F(x) = x * X^16 mod P, linear and a bijection (P(0) = 1), so the
    result is 0 exactly when c == hi << 8 | lo: the CRC sent matches.
    """
    table = [crc_hqx(bytes((k,)), 0) for k in range(256)]  # one-byte step: s -> s << 8 ^ T[s >> 8 ^ b]
    k_ff = next(k for k, t in enumerate(table) if t & 0xFF == 0xFF)  # the low byte of T is a bijection
    return tuple(((k_ff ^ b) << 8) | (0xFF ^ (table[k_ff] >> 8)) for b in range(256))


CRC_PRE = _crc_pre()


class CobsError(DecodeError):
    """The bytes between two delimiters are not valid COBS."""

    counter = "cobs_errors"


class CrcError(DecodeError):
    """The frame's CRC does not match its contents."""

    counter = "crc_errors"


class LengthError(DecodeError):
    """The frame or its payload has a length (or content) its message type does not allow."""

    counter = "length_errors"


class UnknownTypeError(DecodeError):
    """The frame's type byte names no message of this protocol version."""

    counter = "unknown_type"


class OversizedError(DecodeError):
    """More bytes than the largest frame arrived before a delimiter."""

    counter = "oversized"


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no xorout)."""
    return crc_hqx(data, 0xFFFF)


def cobs_encode(raw: bytes) -> bytes:
    """COBS-encode a frame of at most 253 bytes (no delimiter added)."""
    code = COBS_CODE
    return b"".join([code[len(p)] + p for p in raw.split(b"\x00")])


def cobs_join(parts: list[bytes]) -> bytes:
    """raw.split(b"\\0") of a frame < 254 bytes -> its COBS encoding plus the 0x00 delimiter.

    Below 254 bytes every block is one split part, so a code byte in front of each part is all
    COBS does; the generated encoders inline the one-zero case and call this for the rest.
    """
    code = COBS_CODE
    if len(parts) == 1:
        raw = parts[0]
        return b"".join((code[len(raw)], raw, b"\x00"))
    out: list[bytes] = []
    for part in parts:
        out += (code[len(part)], part)
    out.append(b"\x00")
    return b"".join(out)


def cobs_decode(enc: bytes) -> bytes:
    """Undo COBS on one frame body (delimiter removed); CobsError if it is not valid COBS."""
    n = len(enc)
    if n == 0:
        raise CobsError("COBS: empty frame")
    if 0 in enc:
        raise CobsError("COBS: zero byte inside a frame")
    i = 0
    parts = []
    while True:
        code = enc[i]
        if code == 0:
            raise CobsError(f"COBS: zero byte at offset {i}")
        j = i + code
        if j > n:
            raise CobsError(f"COBS: block at offset {i} runs {j - n} bytes past the frame end")
        parts.append(enc[i + 1:j])
        if j == n:
            break
        i = j
    return parts[0] if len(parts) == 1 else b"\x00".join(parts)


def frame_bytes(body: bytes) -> bytes:
    """type . seq . payload -> complete wire bytes (CRC appended, COBS, 0x00 delimiter)."""
    crc = crc_hqx(body, 0xFFFF)
    return cobs_join((body + _CODE[crc >> 8] + _CODE[crc & 0xFF]).split(b"\x00"))


def unframe(enc: bytes) -> bytes:
    """One COBS frame body (no delimiter) -> type . seq . payload, CRC checked and stripped."""
    if len(enc) > MAX_ENCODED_BYTES:
        raise OversizedError(f"frame of {len(enc)} encoded bytes exceeds {MAX_ENCODED_BYTES}")
    raw = cobs_decode(enc)
    n = len(raw)
    if n < MIN_FRAME_BYTES:
        raise LengthError(f"frame of {n} bytes is shorter than {MIN_FRAME_BYTES}")
    body = raw[:-2]
    if crc_hqx(body, 0xFFFF) != raw[-2] << 8 | raw[-1]:
        raise CrcError(f"CRC mismatch in a {n}-byte frame (type {raw[0]:#04x})")
    return body


__all__ = [
    "MAX_FRAME_BYTES",
    "MAX_ENCODED_BYTES",
    "CobsError",
    "CrcError",
    "LengthError",
    "UnknownTypeError",
    "OversizedError",
    "COBS_CODE",
    "CRC_PRE",
    "crc16",
    "cobs_encode",
    "cobs_join",
    "cobs_decode",
    "frame_bytes",
    "unframe",
]
