"""A seeded fault injector around any link: drop, corrupt bits, duplicate, delay, go silent.

Faults are drawn from seeded generators, one per stream (tx bytes, rx bytes, tx frames), so the
same seed and the same bytes give the same faults however the reads happen to be chunked.
Bit corruption acts on the wire bytes (delimiters included) in both directions by default;
drop, duplicate, delay and silence act on the frames this end sends.
"""

from __future__ import annotations

import math
import random
import time
from dataclasses import dataclass, field

from hilbench.link.link import Link, LinkStats
from hilbench.protocol import encode_frame
from hilbench.protocol.messages import Message


@dataclass
class FaultCounts:
    """What the injector did (mutable counters, read them after a run)."""

    corrupted_bits_tx: int = 0
    corrupted_bytes_tx: int = 0
    corrupted_frames_tx: int = 0
    corrupted_bits_rx: int = 0
    corrupted_bytes_rx: int = 0
    corrupted_frames_rx: int = 0
    dropped: int = 0
    duplicated: int = 0
    delayed: int = 0
    silenced: int = 0


@dataclass
class _BitStream:
    """Where the next bit flip falls in one byte stream, and which frame it is in."""

    rng: random.Random
    log_keep: float  # log(1 - p), or 0.0 when p == 0
    skip_bits: int = -1
    frame_index: int = 0
    last_frame: int = -1
    last_byte_global: int = -1
    bytes_seen: int = 0
    counts: dict[str, int] = field(default_factory=lambda: {"bits": 0, "bytes": 0, "frames": 0})

    def gap(self) -> int:
        """Bits left untouched before the next flip (geometric with success probability p)."""
        u = 1.0 - self.rng.random()  # (0, 1]
        return int(math.log(u) / self.log_keep)

    def corrupt(self, data: bytes) -> bytes:
        if self.log_keep == 0.0 or not data:
            return data
        if self.skip_bits < 0:
            self.skip_bits = self.gap()
        n_bits = len(data) * 8
        pos = self.skip_bits
        if pos >= n_bits:
            self.skip_bits = pos - n_bits
            self.frame_index += data.count(0)
            self.bytes_seen += len(data)
            return data
        buf = bytearray(data)
        counts = self.counts
        while pos < n_bits:
            i = pos >> 3
            frame = self.frame_index + data.count(0, 0, i)  # a delimiter belongs to the frame it ends
            if frame != self.last_frame:
                self.last_frame = frame
                counts["frames"] += 1
            if self.bytes_seen + i != self.last_byte_global:
                self.last_byte_global = self.bytes_seen + i
                counts["bytes"] += 1
            buf[i] ^= 1 << (pos & 7)
            counts["bits"] += 1
            pos += 1 + self.gap()
        self.skip_bits = pos - n_bits
        self.frame_index += data.count(0)
        self.bytes_seen += len(data)
        return bytes(buf)


def _log_keep(rate: float, what: str) -> float:
    if not 0.0 <= rate < 1.0:
        raise ValueError(f"FaultyLink: {what} must be in [0, 1), got {rate}")
    return math.log1p(-rate) if rate > 0 else 0.0


class FaultyLink:
    """The Link interface with seeded faults injected; `injected` counts them."""

    def __init__(self, link: Link, seed: int, *, corrupt_bit_rate: float = 0.0, drop_rate: float = 0.0,
                 duplicate_rate: float = 0.0, delay_s: float = 0.0, delay_rate: float = 1.0,
                 silent_after: int | None = None, corrupt_direction: str = "both") -> None:
        if corrupt_direction not in ("rx", "tx", "both"):
            raise ValueError(f"FaultyLink: corrupt_direction must be rx, tx or both, got {corrupt_direction!r}")
        for what, rate in (("drop_rate", drop_rate), ("duplicate_rate", duplicate_rate)):
            _log_keep(rate, what)
        if not 0.0 <= delay_rate <= 1.0:
            raise ValueError(f"FaultyLink: delay_rate must be in [0, 1], got {delay_rate}")
        self.inner = link
        self.name = f"{link.name} (faulty, seed {seed})"
        self.peer_path = link.peer_path
        self.seed = seed
        self.drop_rate = drop_rate
        self.duplicate_rate = duplicate_rate
        self.delay_s = delay_s
        self.delay_rate = delay_rate
        self.silent_after = silent_after
        keep = _log_keep(corrupt_bit_rate, "corrupt_bit_rate")
        self._tx_bits = _BitStream(random.Random(f"{seed}:tx-bits"), keep if corrupt_direction != "rx" else 0.0)
        self._rx_bits = _BitStream(random.Random(f"{seed}:rx-bits"), keep if corrupt_direction != "tx" else 0.0)
        self._frames_rng = random.Random(f"{seed}:tx-frames")
        self._sent = 0
        self._counts = FaultCounts()
        if self._rx_bits.log_keep:
            link.rx_filter = self._rx_bits.corrupt

    @property
    def injected(self) -> FaultCounts:
        c = self._counts
        c.corrupted_bits_tx = self._tx_bits.counts["bits"]
        c.corrupted_bytes_tx = self._tx_bits.counts["bytes"]
        c.corrupted_frames_tx = self._tx_bits.counts["frames"]
        c.corrupted_bits_rx = self._rx_bits.counts["bits"]
        c.corrupted_bytes_rx = self._rx_bits.counts["bytes"]
        c.corrupted_frames_rx = self._rx_bits.counts["frames"]
        return c

    @property
    def timeout_s(self) -> float:
        return self.inner.timeout_s

    @property
    def stats(self) -> LinkStats:
        return self.inner.stats

    def send(self, msg: Message) -> None:
        """Send msg, unless the dice say drop it; maybe late, maybe twice, maybe bit-flipped."""
        self._sent += 1
        if self.silent_after is not None and self._sent > self.silent_after:
            self._counts.silenced += 1
            return
        rng = self._frames_rng
        # draw every decision for every frame so one knob never shifts another's sequence
        drop = rng.random() < self.drop_rate
        dup = rng.random() < self.duplicate_rate
        delay = self.delay_s > 0 and rng.random() < self.delay_rate
        if drop:
            self._counts.dropped += 1
            return
        if delay:
            self._counts.delayed += 1
            time.sleep(self.delay_s)  # a late far end, not a synchronisation
        data = encode_frame(msg)
        copies = 2 if dup else 1
        if dup:
            self._counts.duplicated += 1
        for _ in range(copies):
            self.inner.send_bytes(self._tx_bits.corrupt(data))

    def recv(self, timeout_s: float | None = None) -> Message:
        return self.inner.recv(timeout_s)

    def recv_or_none(self, timeout_s: float | None) -> Message | None:
        return self.inner.recv_or_none(timeout_s)

    def poll(self) -> list[Message]:
        return self.inner.poll()

    def reset_sequence(self) -> None:
        self.inner.reset_sequence()

    def fileno(self) -> int | None:
        return self.inner.fileno()

    @property
    def closed(self) -> bool:
        return self.inner.closed

    def close(self) -> None:
        self.inner.close()

    def __enter__(self) -> "FaultyLink":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
