"""Messages <-> wire bytes: encode_frame, decode_frame and the streaming FrameDecoder.

encode_frame/decode_frame run once per message in the 20 kHz lockstep hot path, so they use the
generated precompiled struct tables and COBS by bytes.split/join, with one dict lookup each.
"""

from __future__ import annotations

import struct
from binascii import crc_hqx

from hilbench.errors import DecodeError, ProtocolError
from hilbench.protocol.framing import (
    MAX_ENCODED_BYTES,
    MIN_FRAME_BYTES,
    CobsError,
    CrcError,
    LengthError,
    OversizedError,
    UnknownTypeError,
)
from hilbench.protocol.messages import PACKERS, UNPACKERS, Message

_CODE = tuple(bytes((i,)) for i in range(256))

COUNTER_NAMES = (
    "frames",
    "crc_errors",
    "cobs_errors",
    "length_errors",
    "unknown_type",
    "oversized",
    "garbage_bytes",
    "resyncs",
)


def encode_frame(msg: Message) -> bytes:
    """One message -> its complete wire bytes, 0x00 delimiter included (ProtocolError if unencodable)."""
    try:
        body = PACKERS[type(msg)](msg)
    except KeyError:
        raise ProtocolError(f"encode: {type(msg).__name__} is not a protocol message") from None
    except (struct.error, TypeError, ValueError, OverflowError, IndexError, AttributeError) as exc:
        raise ProtocolError(f"encode {type(msg).__name__}: {exc}") from None
    crc = crc_hqx(body, 0xFFFF)
    code = _CODE
    return b"".join([code[len(p) + 1] + p for p in (body + code[crc & 0xFF] + code[crc >> 8]).split(b"\x00")]) + b"\x00"


def decode_frame(body: bytes) -> Message:
    """One COBS frame without its delimiter -> message; raises a DecodeError subclass naming the fault."""
    n = len(body)
    if n > MAX_ENCODED_BYTES:
        raise OversizedError(f"frame of {n} encoded bytes exceeds {MAX_ENCODED_BYTES}")
    if n == 0 or 0 in body:
        raise CobsError("COBS: empty frame" if n == 0 else "COBS: zero byte inside a frame")
    i = 0
    parts = []
    while True:
        code = body[i]
        j = i + code
        if j > n:
            raise CobsError(f"COBS: block at offset {i} runs {j - n} bytes past the frame end")
        parts.append(body[i + 1:j])
        if j == n:
            break
        i = j
    raw = parts[0] if len(parts) == 1 else b"\x00".join(parts)
    if len(raw) < MIN_FRAME_BYTES:
        raise LengthError(f"frame of {len(raw)} bytes is shorter than {MIN_FRAME_BYTES}")
    frame = raw[:-2]
    if crc_hqx(frame, 0xFFFF) != raw[-2] | raw[-1] << 8:
        raise CrcError(f"CRC mismatch in a {len(raw)}-byte frame (type {raw[0]:#04x})")
    unpack = UNPACKERS.get(frame[0])
    if unpack is None:
        raise UnknownTypeError(f"unknown frame type {frame[0]:#04x}")
    return unpack(frame)


class FrameDecoder:
    """Splits a byte stream at 0x00 delimiters into messages; never raises, counts every bad frame.

    After any bad frame (or a run of bytes longer than the largest frame) it drops input up to the
    next 0x00 and starts again there; `resyncs` counts good frames that followed bad input.
    """

    __slots__ = ("_buf", "_discarding", "_bad_since_good", "counters", "last_error")

    def __init__(self) -> None:
        self._buf = b""
        self._discarding = False
        self._bad_since_good = False
        self.counters: dict[str, int] = dict.fromkeys(COUNTER_NAMES, 0)
        self.last_error: str | None = None

    def reset(self) -> None:
        """Forget a partial frame (counters are kept)."""
        self._buf = b""
        self._discarding = False

    def feed(self, data: bytes) -> list[Message]:
        """Add received bytes; return the messages completed by them, in order."""
        out: list[Message] = []
        try:
            chunks = (self._buf + data).split(b"\x00") if self._buf else bytes(data).split(b"\x00")
            self._buf = b""
            tail = chunks.pop()
            counters = self.counters
            for chunk in chunks:
                if self._discarding:
                    # the rest of an oversized run, already counted
                    counters["garbage_bytes"] += len(chunk)
                    self._discarding = False
                    continue
                if not chunk:
                    continue  # idle delimiters between frames are allowed
                try:
                    msg = decode_frame(chunk)
                except DecodeError as exc:
                    counters[getattr(exc, "counter", "length_errors")] += 1
                    counters["garbage_bytes"] += len(chunk) + 1
                    self._bad_since_good = True
                    self.last_error = str(exc)
                    continue
                counters["frames"] += 1
                if self._bad_since_good:
                    counters["resyncs"] += 1
                    self._bad_since_good = False
                out.append(msg)
            if self._discarding:
                counters["garbage_bytes"] += len(tail)
            elif len(tail) > MAX_ENCODED_BYTES:
                counters["oversized"] += 1
                counters["garbage_bytes"] += len(tail)
                self._discarding = True
                self._bad_since_good = True
                self.last_error = f"more than {MAX_ENCODED_BYTES} bytes without a delimiter"
            else:
                self._buf = tail
        except Exception as exc:  # noqa: BLE001 - a decoder bug must not take the link down
            self._buf = b""
            self._discarding = True
            self._bad_since_good = True
            self.counters["length_errors"] += 1
            self.last_error = f"internal decoder error: {exc!r}"
        return out


__all__ = ["encode_frame", "decode_frame", "FrameDecoder", "COUNTER_NAMES"]
