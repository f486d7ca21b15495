"""A transport held to the wire time of a UART at a given baud (a spec's ``?wire_baud=N``).

A SIL target or an emulator on a pty answers in microseconds; a board behind a UART cannot: each
byte takes 10 bits of wire time (start, 8 data, stop) in each direction, and the two directions
are independent (full duplex). ThrottledTransport makes any transport behave like that wire:

- **send**: the bytes go onto the wire when it is free (after the bytes sent before them) and
  reach the far end when their last bit has gone. A write returns at once, as a write into an
  operating system's serial buffer does (it waits only while more than TX_BUFFER_BYTES are queued);
  the bytes are handed to the far end at their wire time by the next read or write, whose waits
  wake for it.
- **receive**: bytes the far end wrote are delivered no earlier than their wire time: they start
  on the wire when they were written or when the bytes before them have gone, whichever is later.

Every wait is on a deadline through the inner transport's own read (which also collects what
arrives meanwhile), so a clock and an inner transport given by a test make the arithmetic
checkable without wall time. Times are taken when the host next touches the link: while it is
busy elsewhere, bytes reach the far end and are stamped on arrival later, never earlier (a
conservative wire, never a faster one).
"""

from __future__ import annotations

import math
from collections import deque
from time import monotonic
from typing import Callable

from hilbench.link.transport import Transport

BITS_PER_BYTE = 10  # 8N1: a start bit, 8 data bits, a stop bit
TX_BUFFER_BYTES = 4096  # what a write may queue before it waits (a Linux tty's buffer is 4 KB)
#: received bytes held back for their wire time at most: a far end that writes faster than its wire
#: for long (no UART can) loses what is beyond, counted in ``rx_overrun_bytes``, as a UART overrun
#: would; memory stays bounded whatever the far end does
RX_AHEAD_BYTES = 65536


#: how long a close waits for the queued bytes' wire time; what would arrive later is dropped
CLOSE_FLUSH_S = 2.0


class ThrottledTransport(Transport):
    """``inner`` held to ``baud`` bits/s of 8N1 wire time in each direction."""

    def __init__(self, inner: Transport, baud: int, *, clock: Callable[[], float] = monotonic) -> None:
        if baud <= 0:
            raise ValueError(f"ThrottledTransport: baud must be positive, got {baud}")
        self.inner = inner
        self.baud = baud
        self.name = f"{inner.name} (wire {baud} baud)"
        self.byte_s = BITS_PER_BYTE / baud
        self._clock = clock
        self._tx_free_s = 0.0  # when the host -> target wire is free again
        self._rx_free_s = 0.0  # when the target -> host wire is free again
        self._rx: deque[tuple[float, bytes]] = deque()  # (delivery time, bytes), in order
        self._tx: deque[tuple[float, bytes]] = deque()  # (wire time of the last byte, bytes), in order
        self._tx_queued = 0
        self._rx_queued = 0
        self.wire_bytes_tx = 0
        self.wire_bytes_rx = 0
        self.rx_overrun_bytes = 0

    # -- the wire's arithmetic -------------------------------------------------------------
    def _stamp_rx(self, data: bytes) -> None:
        """Received bytes on the target -> host wire: delivered when their last bit has come."""
        room = RX_AHEAD_BYTES - self._rx_queued
        if len(data) > room:  # far ahead of the wire: what does not fit is lost (an overrun)
            self.rx_overrun_bytes += len(data) - max(room, 0)
            data = data[:max(room, 0)]
            if not data:
                return
        self._rx_queued += len(data)
        start = max(self._clock(), self._rx_free_s)
        self._rx_free_s = start + len(data) * self.byte_s
        self.wire_bytes_rx += len(data)
        self._rx.append((self._rx_free_s, data))

    def _pump(self, timeout_s: float) -> None:
        """Hand over the sent bytes whose time has come, then collect what the inner transport has
        (waiting at most timeout_s, and no longer than until the next sent bytes are due)."""
        self._deliver()
        if self._tx:
            timeout_s = min(timeout_s, self._tx[0][0] - self._clock())
        data = self.inner.read(max(timeout_s, 0.0))
        if data:
            self._stamp_rx(data)
        self._deliver()

    def _deliver(self) -> None:
        tx = self._tx
        if not tx:
            return
        now = self._clock()
        while tx and tx[0][0] <= now:
            data = tx.popleft()[1]
            self._tx_queued -= len(data)
            self.inner.write(data, 1.0)

    def _due(self) -> bytes:
        """Every received byte whose wire time has come, in order."""
        now = self._clock()
        out = bytearray()
        rx = self._rx
        while rx and rx[0][0] <= now:
            out += rx.popleft()[1]
        self._rx_queued -= len(out)
        return bytes(out)

    # -- Transport ----------------------------------------------------------------------------
    def read(self, timeout_s: float | None) -> bytes:
        deadline = None if timeout_s is None else self._clock() + timeout_s
        while True:
            self._pump(0.0)
            ready = self._due()
            if ready:
                return ready
            now = self._clock()
            if deadline is not None and now >= deadline:
                return b""
            wait = self._rx[0][0] - now if self._rx else None
            if self._tx:
                wait = self._tx[0][0] - now if wait is None else min(wait, self._tx[0][0] - now)
            if deadline is not None:
                wait = deadline - now if wait is None else min(wait, deadline - now)
            self._pump(1.0 if wait is None else wait)

    def write(self, data: bytes, timeout_s: float) -> None:
        """Queue data for the wire (it reaches the far end at the wire time of its last byte, after
        the bytes before it); waits only while more than TX_BUFFER_BYTES are queued."""
        if not data:
            return
        start = max(self._clock(), self._tx_free_s)
        self._tx_free_s = start + len(data) * self.byte_s
        self.wire_bytes_tx += len(data)
        self._tx.append((self._tx_free_s, bytes(data)))
        self._tx_queued += len(data)
        self._deliver()
        while self._tx_queued > TX_BUFFER_BYTES:
            self._pump(self._tx[0][0] - self._clock())

    def flush(self, within_s: float = math.inf) -> None:
        """Wait until every queued byte whose wire time comes within ``within_s`` has reached the
        far end (by default every queued byte)."""
        deadline = self._clock() + within_s
        while self._tx and self._tx[0][0] <= deadline:
            self._pump(self._tx[0][0] - self._clock())

    def fileno(self) -> int | None:
        return self.inner.fileno()

    def empty_read_ends(self) -> bool:
        return self.inner.empty_read_ends()

    def _hung_up(self, why: str) -> Exception:
        return self.inner._hung_up(why)  # type: ignore[attr-defined]

    def close(self) -> None:
        """What was written still reaches the far end (a Stop before the close) when its wire time
        comes within CLOSE_FLUSH_S; later bytes, that Stop too, are dropped: at a few baud a queue
        of retries would hold the close for hours."""
        try:
            self.flush(CLOSE_FLUSH_S)
        except Exception:  # noqa: BLE001 - a far end that hung up takes nothing more
            pass
        self.inner.close()


__all__ = ["BITS_PER_BYTE", "TX_BUFFER_BYTES", "ThrottledTransport"]
