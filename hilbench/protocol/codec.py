"""Messages <-> wire bytes: encode_frame, decode_frame and the streaming FrameDecoder.

These run once per message in the 20 kHz lockstep hot path (host: encode Sensors, decode Drive;
target: the reverse), so the work is done by code generated from the schema into
hilbench.protocol.messages: encode_frame (Sensors and Drive inline, the rest by a dict of
straight-line encoders) and decode_body (COBS undone in place, one crc_hqx call checked against a
table, Sensors and Drive inline, the rest through a tuple indexed by the type byte).
"""

from __future__ import annotations

from hilbench.errors import DecodeError
from hilbench.protocol.framing import (
    MAX_ENCODED_BYTES,
    CobsError,
    OversizedError,
)
from hilbench.protocol.messages import Message, decode_body, encode_frame

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


def decode_frame(body: bytes) -> Message:
    """One COBS frame without its delimiter -> message; raises a DecodeError subclass naming the fault."""
    n = len(body)
    if n > MAX_ENCODED_BYTES:
        raise OversizedError(f"frame of {n} encoded bytes exceeds {MAX_ENCODED_BYTES}")
    if n == 0 or 0 in body:
        raise CobsError("COBS: empty frame" if n == 0 else "COBS: zero byte inside a frame")
    return decode_body(body, n)


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
        if type(data) is bytes and not self._buf and not self._discarding:
            # Lockstep: a read usually returns exactly one whole frame: no split, no list of chunks.
            body = data[:-1]
            n = len(body)
            if 0 < n <= MAX_ENCODED_BYTES and data[-1] == 0 and 0 not in body:
                try:
                    msg = decode_body(body, n)
                except Exception:  # noqa: BLE001 - bad frame: the general path below counts it
                    pass
                else:
                    self.counters["frames"] += 1
                    if self._bad_since_good:
                        self.counters["resyncs"] += 1
                        self._bad_since_good = False
                    return [msg]
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
