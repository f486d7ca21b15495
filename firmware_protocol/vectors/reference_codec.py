"""An independent CRC and COBS, written from their definitions, bit by bit and byte by byte.

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


def wire(frame: bytes) -> bytes:
    """type · seq · payload → its bytes on the wire: COBS(frame · CRC high byte first) · 0x00."""
    crc = crc16(frame)
    return cobs(frame + bytes((crc >> 8, crc & 0xFF))) + b"\x00"
