"""Framing (protocol 3): COBS, a CRC-16 over the wire bytes, and a length at both ends.

A message is `type . seq . payload` (at most MAX_FRAME_BYTES). On the wire (PROTOCOL.md, Framing):

    B = L . message . L               L = the frame's wire length (the bytes between two 0x00s)
    E = COBS(B)                       no 0x00 inside; exactly one byte longer than B
    T = 3 check bytes                 1 c15..c9 | 1 c8..c2 | 1 c1 c0 0 0 0 0 0, c = CRC-16 over E
    wire = E . T . 0x00

The CRC (CCITT-FALSE: poly 0x1021, init 0xFFFF) covers the COBS-encoded bytes themselves, so an
error in a COBS code byte is an error in the codeword like any other; the check bytes carry 7 CRC
bits each with the top bit set (never 0x00, so they need no stuffing). A receiver checks the top
bits and the reserved zeros, the CRC, COBS, then that both length bytes equal the length it
received: a frame that lost or gained bytes at its end (a delimiter turned into data, idle filler
appended, two frames merged) has the wrong first length; a tail left after a 0x00 that an error
created in the middle of a frame has the wrong last one. PROTOCOL.md proves what this detects.
"""

from __future__ import annotations

from binascii import crc_hqx

from hilbench.errors import DecodeError

MAX_FRAME_BYTES = 62  # a message: type . seq . payload
OVERHEAD_BYTES = 7  # two lengths, the COBS code byte, three check bytes, the delimiter
MAX_WIRE_BYTES = MAX_FRAME_BYTES + OVERHEAD_BYTES - 1  # between two delimiters
MAX_ENCODED_BYTES = MAX_WIRE_BYTES  # (the older name)
MIN_WIRE_BYTES = 8  # L . type . seq . L, COBS, T

BYTE = tuple(bytes((i,)) for i in range(256))  # BYTE[i] == bytes((i,))

# COBS_CODE[k]: the code byte that opens a block of k data bytes (k + 1); frames stay < 254 bytes.
COBS_CODE = tuple(bytes((k + 1,)) for k in range(254))

def check_bytes(crc: int) -> bytes:
    """The three check bytes T of a CRC value."""
    return bytes((0x80 | crc >> 9, 0x80 | (crc >> 2) & 0x7F, 0x80 | (crc & 3) << 5))


def check_value(t0: int, t1: int, t2: int) -> int:
    """The CRC carried by three check bytes, or -1 when a top bit is clear or a reserved bit set."""
    if not (t0 & t1 & t2 & 0x80) or t2 & 0x1F:
        return -1
    return (t0 & 0x7F) << 9 | (t1 & 0x7F) << 2 | (t2 >> 5) & 3


class CobsError(DecodeError):
    """The bytes between two delimiters are not valid COBS."""

    counter = "cobs_errors"


class CrcError(DecodeError):
    """The frame's check bytes do not match its contents."""

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
        j = i + code
        if j > n:
            raise CobsError(f"COBS: block at offset {i} runs {j - n} bytes past the frame end")
        parts.append(enc[i + 1:j])
        if j == n:
            break
        i = j
    return parts[0] if len(parts) == 1 else b"\x00".join(parts)


def wire_join(parts: list[bytes]) -> bytes:
    """(L . message . L).split(b"\\0") of a frame < 254 bytes -> its wire bytes, delimiter included.

    Below 254 bytes every block is one split part, so a code byte in front of each part is all
    COBS does; the generated encoders inline the one-part case and call this for the rest."""
    code = COBS_CODE
    out: list[bytes] = []
    for part in parts:
        out += (code[len(part)], part)
    enc = b"".join(out)
    crc = crc_hqx(enc, 0xFFFF)
    return b"".join((enc, bytes((0x80 | crc >> 9, 0x80 | (crc >> 2) & 0x7F, 0x80 | (crc & 3) << 5, 0))))


def frame_bytes(message: bytes) -> bytes:
    """type . seq . payload -> complete wire bytes (lengths, COBS, check bytes, 0x00 delimiter)."""
    n = len(message)
    if not 2 <= n <= MAX_FRAME_BYTES:
        raise ValueError(f"a message of {n} bytes (2..{MAX_FRAME_BYTES})")
    length = BYTE[n + OVERHEAD_BYTES - 1]
    return wire_join((length + message + length).split(b"\x00"))


def unframe(wire: bytes) -> bytes:
    """One frame's wire bytes between delimiters -> type . seq . payload, every check made
    (LengthError, OversizedError, CrcError, CobsError)."""
    n = len(wire)
    if n > MAX_WIRE_BYTES:
        raise OversizedError(f"frame of {n} wire bytes exceeds {MAX_WIRE_BYTES}")
    if n < MIN_WIRE_BYTES:
        raise LengthError(f"frame of {n} wire bytes is shorter than {MIN_WIRE_BYTES}")
    crc = check_value(wire[n - 3], wire[n - 2], wire[n - 1])
    if crc < 0 or crc_hqx(wire[:n - 3], 0xFFFF) != crc:
        raise CrcError(f"check bytes do not match a {n}-byte frame")
    body = cobs_decode(wire[:n - 3])
    if body[0] != n or body[-1] != n:
        raise LengthError(f"a {n}-byte frame says it is {body[0]} and {body[-1]} bytes long")
    return body[1:-1]


__all__ = [
    "MAX_FRAME_BYTES",
    "MAX_ENCODED_BYTES",
    "MAX_WIRE_BYTES",
    "MIN_WIRE_BYTES",
    "OVERHEAD_BYTES",
    "CobsError",
    "CrcError",
    "LengthError",
    "UnknownTypeError",
    "OversizedError",
    "BYTE",
    "COBS_CODE",
    "check_bytes",
    "check_value",
    "crc16",
    "cobs_encode",
    "cobs_decode",
    "wire_join",
    "frame_bytes",
    "unframe",
]
