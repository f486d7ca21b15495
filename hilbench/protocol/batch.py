"""SensorsBatch records and BatchDigest digests (twin-speculative lockstep; PROTOCOL.md, "Batches").

A batch carries the Sensors of consecutive periods as records of what changed since the period
before, so a period in which only the hall edges or nothing changed costs one byte or less:

    0x80 | n, n < 64               n + 1 periods as the one before, without edges (a run)
    0xC0 | c2 c1 c0                a period whose only change is ADC channels 0..2 by 2-bit codes
                                   (0 none, 1 +1, 2 +2, 3 -1; channel 0 in the low bits): noise
    h (bit 7 clear), then in order:
      0x01 inputs   u8
      0x02 encoder  a value, from the prediction: the encoder's last change again (a period without
                    this record, a run's or a tiny one's included, moves it by that step)
      0x20 ADC      u8 count, then every channel's code as u16 (the first period; a count change)
      0x04 0x08 0x10  ADC channels 0, 1, 2 changed: a signed 4-bit change each (-7..7), two a byte,
                    the lower nibble first; a nibble -8 says the code follows as u16 after the nibbles
      0x40 edges    u8 count (1..), then each edge as in Sensors: time u16 (100 ns), lines u8
    a value: one byte d != 0x80, the change as a signed byte (-127..127); or 0x80, then the value u16

The decoder state (inputs, encoder, ADC codes) starts at zero with the first batch after a
handshake or a per-period Sensors, and carries over from batch to batch. The digest is the CRC-32
(zlib's) of the batch's Drives, each as its message (type . seq . payload, seq = period mod 256),
one after the other. Records of a period never straddle two batches.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

from hilbench.errors import ProtocolError
from hilbench.protocol.messages import MAX_BATCH_BYTES, Drive, Sensors, pack_drive

REC_RUN = 0x80
REC_TINY = 0xC0
_TINY_CODES = {1: 1, 2: 2, -1: 3}
REC_INPUTS = 0x01
REC_ENCODER = 0x02
REC_ADC0 = 0x04  # channels 0, 1, 2: 0x04, 0x08, 0x10
REC_ADC_ALL = 0x20
REC_EDGES = 0x40
MAX_RUN = 64
MAX_BATCH_PERIODS = 255
#: the records every runtime build takes (its receive buffer holds a 22-byte ParamSet): a first batch's
#: size; BatchDigest.room says what the target takes after it
MIN_BATCH_BYTES = 17


def _value(old: int, new: int) -> bytes:
    d = (new - old) & 0xFFFF
    if d <= 127:
        return bytes((d,))
    if d >= 0xFFFF - 126:
        return bytes((d - 0xFF00,))
    return bytes((0x80, new & 0xFF, new >> 8))


@dataclass
class BatchState:
    """What the records describe changes against: the last period's inputs, encoder and ADC codes."""

    inputs: int = 0
    encoder: int = 0
    adc: tuple[int, ...] = ()
    enc_step: int = 0  # the encoder's last change (u16): the prediction of the next
    ignore_encoder: bool = False  # a target without an encoder: its count is sent as 0 (never a record)

    def saved(self) -> tuple[int, int, tuple[int, ...], int]:
        return self.inputs, self.encoder, self.adc, self.enc_step

    def restore(self, saved: tuple[int, int, tuple[int, ...], int]) -> None:
        self.inputs, self.encoder, self.adc, self.enc_step = saved

    def record(self, s: Sensors) -> bytes:
        """One period's record (b"" for a period as the one before, without edges); advances."""
        encoder = 0 if self.ignore_encoder else s.encoder
        adc = s.adc
        old = self.adc
        if (s.inputs == self.inputs and not s.edges and len(adc) == len(old) <= 3
                and encoder == (self.encoder + self.enc_step) & 0xFFFF):
            quick = self._adc_only(adc, old)  # the common period: ADC noise only
            if quick is not None:
                self.encoder = encoder
                return quick
        return self._record(s, encoder, tuple(adc))

    def _adc_only(self, adc: tuple[int, ...], old: tuple[int, ...]) -> bytes | None:
        """b"" (no change) or the 1-byte record of a period whose only change is ADC noise of -1..+2
        on channels 0..2; None when the changes need a full record."""
        tiny = REC_TINY
        for i in range(len(adc)):
            d = adc[i] - old[i]
            if d:
                code = _TINY_CODES.get(d)
                if code is None:
                    return None
                tiny |= code << (2 * i)
        if tiny == REC_TINY:
            return b""
        self.adc = tuple(adc)
        return bytes((tiny,))

    def _record(self, s: Sensors, encoder: int, adc: tuple[int, ...]) -> bytes:
        h = 0
        body = bytearray()
        if s.inputs != self.inputs:
            h |= REC_INPUTS
            body.append(s.inputs)
        predicted = (self.encoder + self.enc_step) & 0xFFFF
        if encoder != predicted:
            h |= REC_ENCODER
            body += _value(predicted, encoder)
            self.enc_step = (encoder - self.encoder) & 0xFFFF
        if len(adc) != len(self.adc) or (len(adc) > 3 and adc[3:] != self.adc[3:]):
            h |= REC_ADC_ALL
            body.append(len(adc))
            for code in adc:
                body += code.to_bytes(2, "little")
        else:
            nibbles: list[int] = []
            tail = bytearray()
            for i in range(min(3, len(adc))):
                if adc[i] != self.adc[i]:
                    h |= REC_ADC0 << i
                    d = adc[i] - self.adc[i]
                    if -7 <= d <= 7:
                        nibbles.append(d & 0xF)
                    else:
                        nibbles.append(8)
                        tail += adc[i].to_bytes(2, "little")
            for j in range(0, len(nibbles), 2):
                body.append(nibbles[j] | ((nibbles[j + 1] << 4) if j + 1 < len(nibbles) else 0))
            body += tail
        if h & ~(REC_ADC0 * 7) == 0 and h and not s.edges:  # only small ADC changes: one byte if it can
            tiny = REC_TINY
            for i in range(3):
                if h & (REC_ADC0 << i):
                    code = _TINY_CODES.get(adc[i] - self.adc[i])
                    if code is None:
                        break
                    tiny |= code << (2 * i)
            else:
                self.adc, self.encoder = adc, encoder
                return bytes((tiny,))
        if s.edges:
            h |= REC_EDGES
            body.append(len(s.edges))
            for t, lines in s.edges:
                body += t.to_bytes(2, "little") + bytes((lines,))
        self.inputs, self.encoder, self.adc = s.inputs, encoder, adc
        return bytes((h,)) + bytes(body) if h else b""


class RecordTooLarge(ProtocolError):
    """One period's record is larger than any batch the target takes (it goes as a per-period Sensors)."""


@dataclass
class BatchBuilder:
    """Records of consecutive periods until a batch is full (MAX_BATCH_BYTES, or `max_periods`)."""

    state: BatchState = field(default_factory=BatchState)
    max_periods: int = MAX_BATCH_PERIODS
    max_bytes: int = MAX_BATCH_BYTES
    records: bytearray = field(default_factory=bytearray)
    count: int = 0
    _run_at: int = -1  # index of the run byte the next unchanged period may extend (-1: none)

    def add(self, s: Sensors) -> bool:
        """Add one period's Sensors; False (nothing changed) when it does not fit this batch."""
        if self.count >= self.max_periods:
            return False
        saved = self.state.saved()
        rec = self.state.record(s)
        if not rec:
            at = self._run_at
            if at >= 0 and (self.records[at] & 0x3F) < MAX_RUN - 1:
                self.records[at] += 1
            elif len(self.records) < self.max_bytes:
                self._run_at = len(self.records)
                self.records.append(REC_RUN)
            else:
                self.state.restore(saved)
                return False
        elif len(self.records) + len(rec) <= self.max_bytes:  # (a tiny record is no run to extend)
            self.records += rec
            self._run_at = -1
        else:
            self.state.restore(saved)
            if len(rec) > self.max_bytes:
                raise RecordTooLarge(f"SensorsBatch: one period's record of {len(rec)} bytes does not fit "
                                     f"a batch ({self.max_bytes} bytes)")
            return False
        self.count += 1
        return True

    def take(self) -> tuple[int, bytes]:
        """(count, records) of the batch so far; the builder starts an empty batch (state kept)."""
        out = (self.count, bytes(self.records))
        self.records = bytearray()
        self.count = 0
        self._run_at = -1
        return out


def _read_value(data: bytes, at: int, old: int) -> tuple[int, int]:
    b = data[at]
    if b != 0x80:
        return (old + (b if b < 0x80 else b - 0x100)) & 0xFFFF, at + 1
    if at + 3 > len(data):
        raise ProtocolError("SensorsBatch: a value's u16 runs past the records")
    return int.from_bytes(data[at + 1:at + 3], "little"), at + 3


def decode_records(state: BatchState, first_seq: int, count: int, records: bytes) -> list[Sensors]:
    """The Sensors a batch stands for (the reference of the C runtime's decoder); advances state.
    ProtocolError when the records are malformed or do not make exactly `count` periods."""
    out: list[Sensors] = []
    at = 0
    try:
        while at < len(records) and len(out) < count:
            h = records[at]
            at += 1
            edges: tuple[tuple[int, int], ...] = ()
            runs = 1
            if h & REC_TINY == REC_TINY:
                state.encoder = (state.encoder + state.enc_step) & 0xFFFF
                adc = list(state.adc)
                for i in range(3):
                    code = (h >> (2 * i)) & 3
                    if code:
                        if i >= len(adc):
                            raise ProtocolError(f"SensorsBatch: a change of ADC channel {i} of {len(adc)}")
                        adc[i] = (adc[i] + (-1 if code == 3 else code)) & 0xFFFF
                state.adc = tuple(adc)
            elif h & REC_RUN:
                runs = (h & 0x3F) + 1
            else:
                if h & REC_INPUTS:
                    state.inputs = records[at]
                    at += 1
                value = (state.encoder + state.enc_step) & 0xFFFF
                if h & REC_ENCODER:
                    value, at = _read_value(records, at, value)
                    state.enc_step = (value - state.encoder) & 0xFFFF
                state.encoder = value
                adc = list(state.adc)
                if h & REC_ADC_ALL:
                    n = records[at]
                    adc = [int.from_bytes(records[at + 1 + 2 * i:at + 3 + 2 * i], "little") for i in range(n)]
                    at += 1 + 2 * n
                changed = [i for i in range(3) if h & (REC_ADC0 << i)]
                tail = at + (len(changed) + 1) // 2
                for j, i in enumerate(changed):
                    if i >= len(adc):
                        raise ProtocolError(f"SensorsBatch: a change of ADC channel {i} of {len(adc)}")
                    nib = (records[at + j // 2] >> (4 * (j & 1))) & 0xF
                    if nib == 8:
                        adc[i] = int.from_bytes(records[tail:tail + 2], "little")
                        tail += 2
                    else:
                        adc[i] = (adc[i] + (nib if nib < 8 else nib - 16)) & 0xFFFF
                at = tail
                state.adc = tuple(adc)
                if h & REC_EDGES:
                    n = records[at]
                    if n == 0:
                        raise ProtocolError("SensorsBatch: an edge count of 0")
                    edges = tuple((int.from_bytes(records[at + 1 + 3 * i:at + 3 + 3 * i], "little"),
                                   records[at + 3 + 3 * i]) for i in range(n))
                    at += 1 + 3 * n
            if at > len(records) or len(out) + runs > count:
                raise ProtocolError("SensorsBatch: the records run past the frame or the count")
            for _ in range(runs):
                if h & REC_TINY == REC_RUN:  # a run: each period moves the encoder by its step
                    state.encoder = (state.encoder + state.enc_step) & 0xFFFF
                out.append(Sensors((first_seq + len(out)) & 0xFF, state.inputs, edges, state.encoder, state.adc))
    except IndexError:
        raise ProtocolError("SensorsBatch: the records end inside a period") from None
    if at != len(records) or len(out) != count:
        raise ProtocolError(f"SensorsBatch: records for {len(out)} periods, count says {count}")
    return out


def drive_digest(drives: list[Drive], crc: int = 0) -> int:
    """The CRC-32 of the Drives' messages (each with its own seq), continued from crc."""
    for d in drives:
        crc = zlib.crc32(pack_drive(d), crc)
    return crc


__all__ = [
    "BatchBuilder",
    "BatchState",
    "MAX_BATCH_PERIODS",
    "MIN_BATCH_BYTES",
    "decode_records",
    "drive_digest",
]
