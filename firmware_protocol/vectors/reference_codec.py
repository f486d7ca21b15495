"""An independent CRC, COBS and framing (protocol 3), written from their definitions, bit by bit and
byte by byte.

The golden vectors (make_vectors.py) and the Python tests check the codec against this, never
against the codec itself.
"""

from __future__ import annotations


def crc16(data: bytes) -> int:
    """Bitwise CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no final xor."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def cobs(raw: bytes) -> bytes:
    """Byte-by-byte COBS encoder (frames shorter than 254 bytes)."""
    out = bytearray([0])
    code_at = 0
    for b in raw:
        if b == 0:
            out[code_at] = len(out) - code_at
            code_at = len(out)
            out.append(0)
        else:
            out.append(b)
    out[code_at] = len(out) - code_at
    return bytes(out)


def check_bytes(crc: int) -> bytes:
    """PROTOCOL.md: T0 = 1 c15..c9, T1 = 1 c8..c2, T2 = 1 c1 c0 00000 (bit strings, most significant first)."""
    bits = f"{crc:016b}"
    return bytes((int("1" + bits[0:7], 2), int("1" + bits[7:14], 2), int("1" + bits[14:16] + "00000", 2)))


def wire(message: bytes, crc_flip: int = 0, lengths: tuple[int, int] | None = None) -> bytes:
    """type . seq . payload -> its bytes on the wire: COBS(L . message . L) . T . 0x00, L the frame's
    length between delimiters. crc_flip and lengths make deliberately bad frames."""
    length = len(message) + 6  # COBS adds one byte to L . message . L, then three check bytes
    first, last = lengths if lengths is not None else (length, length)
    encoded = cobs(bytes((first,)) + message + bytes((last,)))
    assert len(encoded) + 3 == length
    return encoded + check_bytes(crc16(encoded) ^ crc_flip) + b"\x00"
