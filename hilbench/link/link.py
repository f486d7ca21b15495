"""Framed links: messages over a byte transport, with deadlines and statistics.

The link knows frames, not meanings: it encodes and decodes with hilbench.protocol, reads in
bulk and splits frames in memory, and counts what went across and what went wrong. The one
piece of meaning it keeps is which message types carry a running sequence number (Sensors,
Drive), so it can count sequence gaps.
"""

from __future__ import annotations

import os
import stat
import time
from collections import deque
from dataclasses import asdict, dataclass
from typing import Any, Callable, Iterable
from urllib.parse import parse_qs, urlsplit

from hilbench.errors import LinkError, LinkTimeout
from hilbench.link.pty import open_pty_pair
from hilbench.link.transport import FdTransport, PtyMasterTransport, SerialUrlTransport, Transport
from hilbench.protocol import Drive, FrameDecoder, Sensors, encode_frame

DEFAULT_BAUD = 250_000
DEFAULT_TIMEOUT_S = 1.0
_DECODER_ERROR_KEYS = ("crc_errors", "cobs_errors", "length_errors", "unknown_type", "oversized")


@dataclass(frozen=True)
class LinkStats:
    """A snapshot of one link's counters (frames and bytes each way, and every error kind)."""

    frames_tx: int = 0
    frames_rx: int = 0
    bytes_tx: int = 0
    bytes_rx: int = 0
    crc_errors: int = 0
    cobs_errors: int = 0
    length_errors: int = 0
    unknown_type: int = 0
    oversized: int = 0
    garbage_bytes: int = 0
    resyncs: int = 0
    timeouts: int = 0
    seq_gaps: int = 0

    @property
    def frame_errors(self) -> int:
        """Bad frames of every kind the decoder rejected."""
        return self.crc_errors + self.cobs_errors + self.length_errors + self.unknown_type + self.oversized

    def as_dict(self) -> dict[str, int]:
        out = asdict(self)
        out["frame_errors"] = self.frame_errors
        return out


def _decoder_counter(decoder: Any, key: str) -> int:
    counters = decoder.counters
    if isinstance(counters, dict):
        return int(counters.get(key, 0))
    return int(getattr(counters, key, 0))


class Link:
    """Messages over a transport: send(msg), recv(timeout_s) -> msg, stats, close()."""

    def __init__(self, transport: Transport, name: str, *, timeout_s: float = DEFAULT_TIMEOUT_S,
                 peer_path: str | None = None,
                 sequenced_types: Iterable[type] = (Sensors, Drive)) -> None:
        self.name = name
        self.timeout_s = timeout_s
        self.peer_path = peer_path
        self.transport = transport
        self._read = transport.read
        self._write = transport.write
        self._decoder = FrameDecoder()
        self._feed = self._decoder.feed
        self._pending: deque[Any] = deque()
        self._sequenced = frozenset(sequenced_types)
        self._last_seq: dict[type, int] = {}
        self.rx_filter: Callable[[bytes], bytes] | None = None
        self.frames_tx = 0
        self.bytes_tx = 0
        self.bytes_rx = 0
        self.timeouts = 0
        self.seq_gaps = 0
        self._closed = False

    # -- sending -------------------------------------------------------------------------
    def send(self, msg: Any) -> None:
        """Encode one message and write all of its bytes (LinkTimeout if the far end stalls)."""
        data = encode_frame(msg)
        self._write(data, self.timeout_s)
        self.frames_tx += 1
        self.bytes_tx += len(data)

    def send_bytes(self, data: bytes, frames: int = 1) -> None:
        """Write ready-made wire bytes (used by the fault injector) and count them."""
        self._write(data, self.timeout_s)
        self.frames_tx += frames
        self.bytes_tx += len(data)

    # -- receiving -----------------------------------------------------------------------
    def recv(self, timeout_s: float | None = None) -> Any:
        """The next good frame's message; LinkTimeout after timeout_s, LinkClosed on hang-up."""
        pending = self._pending
        if pending:
            return pending.popleft()
        timeout = self.timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + timeout
        remaining = timeout
        while True:
            data = self._read(remaining)
            if data:
                frames = self._take(data)
                if frames:
                    if len(frames) > 1:
                        pending.extend(frames[1:])
                    return frames[0]
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self.timeouts += 1
                raise LinkTimeout(
                    f"link {self.name}: no frame for {timeout * 1000:.0f} ms "
                    f"(after {self.stats.frames_rx} frames received)"
                )

    def recv_or_none(self, timeout_s: float) -> Any | None:
        """Like recv, but None when nothing arrives in timeout_s (not counted as a timeout).

        For servers that wake up periodically to check a stop flag or a watchdog.
        """
        pending = self._pending
        if pending:
            return pending.popleft()
        deadline = time.monotonic() + timeout_s
        remaining = timeout_s
        while True:
            data = self._read(remaining)
            if data:
                frames = self._take(data)
                if frames:
                    if len(frames) > 1:
                        pending.extend(frames[1:])
                    return frames[0]
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None

    def poll(self) -> list[Any]:
        """Every good frame already waiting, without blocking."""
        out = list(self._pending)
        self._pending.clear()
        data = self._read(0)
        while data:
            out.extend(self._take(data))
            data = self._read(0)
        return out

    def _take(self, data: bytes) -> list[Any]:
        self.bytes_rx += len(data)
        if self.rx_filter is not None:
            data = self.rx_filter(data)
        frames = self._feed(data)
        if frames and self._sequenced:
            sequenced = self._sequenced
            last = self._last_seq
            for msg in frames:
                kind = type(msg)
                if kind in sequenced:
                    prev = last.get(kind)
                    if prev is not None and msg.seq != ((prev + 1) & 0xFF):
                        self.seq_gaps += 1
                    last[kind] = msg.seq
        return frames

    def reset_sequence(self) -> None:
        """Forget the last sequence numbers (a new session starts counting again)."""
        self._last_seq.clear()

    # -- bookkeeping ---------------------------------------------------------------------
    @property
    def stats(self) -> LinkStats:
        d = self._decoder
        return LinkStats(
            frames_tx=self.frames_tx,
            frames_rx=_decoder_counter(d, "frames"),
            bytes_tx=self.bytes_tx,
            bytes_rx=self.bytes_rx,
            crc_errors=_decoder_counter(d, "crc_errors"),
            cobs_errors=_decoder_counter(d, "cobs_errors"),
            length_errors=_decoder_counter(d, "length_errors"),
            unknown_type=_decoder_counter(d, "unknown_type"),
            oversized=_decoder_counter(d, "oversized"),
            garbage_bytes=_decoder_counter(d, "garbage_bytes"),
            resyncs=_decoder_counter(d, "resyncs"),
            timeouts=self.timeouts,
            seq_gaps=self.seq_gaps,
        )

    def fileno(self) -> int | None:
        return self.transport.fileno()

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.transport.close()

    def __enter__(self) -> "Link":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Link({self.name!r})"


# -- opening links from specs -------------------------------------------------------------
def _open_serial(device: str, baud: int, name: str, timeout_s: float) -> Link:
    import serial  # pyserial

    if not os.path.exists(device):
        raise LinkError(f"link {name}: no such port {device} (try `hilbench ports`)")
    try:
        port = serial.Serial(device, baudrate=baud, timeout=0, exclusive=True)
    except serial.SerialException as exc:
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if "lock" in text.lower():
            raise LinkError(f"link {name}: port {device} is busy (another program has it open)") from None
        raise LinkError(f"link {name}: cannot open port {device}: {text}") from None
    except (OSError, ValueError) as exc:
        raise LinkError(f"link {name}: cannot open port {device}: {exc}") from None
    transport = FdTransport(port.fd, name, owns_fd=False, on_close=port.close)
    return Link(transport, name, timeout_s=timeout_s)


def _parse_baud(query: str, name: str) -> int:
    params = parse_qs(query)
    unknown = sorted(set(params) - {"baud"})
    if unknown:
        raise LinkError(f"link {name}: unknown option {unknown[0]!r} (known: baud)")
    if "baud" not in params:
        return DEFAULT_BAUD
    try:
        baud = int(params["baud"][-1])
    except ValueError:
        raise LinkError(f"link {name}: baud must be a whole number, got {params['baud'][-1]!r}") from None
    if baud <= 0:
        raise LinkError(f"link {name}: baud must be positive, got {baud}")
    return baud


def open_link(spec: str, *, timeout_s: float = DEFAULT_TIMEOUT_S) -> Link:
    """Open a link from a spec: serial:/dev/X?baud=N, /dev/X, loop://, pty, fd:N.

    `pty` makes a raw-mode pty pair and keeps the master; `link.peer_path` is the slave the far
    end opens.
    """
    spec = spec.strip()
    if spec == "pty":
        pair = open_pty_pair()
        name = f"pty:{pair.slave_path}"
        transport = PtyMasterTransport(pair.master_fd, pair.slave_fd, pair.slave_path, name)
        return Link(transport, name, timeout_s=timeout_s, peer_path=pair.slave_path)
    if spec.startswith("loop://"):
        import serial

        port = serial.serial_for_url(spec, timeout=0)
        return Link(SerialUrlTransport(port, spec), spec, timeout_s=timeout_s)
    if spec.startswith("fd:"):
        try:
            fd = int(spec[3:])
            os.fstat(fd)
        except ValueError:
            raise LinkError(f"link {spec}: fd:N needs a file descriptor number") from None
        except OSError as exc:
            raise LinkError(f"link {spec}: file descriptor {spec[3:]} is not open: {exc.strerror}") from None
        return Link(FdTransport(fd, spec), spec, timeout_s=timeout_s)
    if spec.startswith("serial:"):
        parts = urlsplit(spec[len("serial:"):])
        device = parts.path
        if not device:
            raise LinkError(f"link {spec}: serial: needs a device path, e.g. serial:/dev/ttyUSB0?baud=250000")
        return _open_serial(device, _parse_baud(parts.query, spec), spec, timeout_s)
    if spec.startswith("/"):
        device, _, query = spec.partition("?")
        return _open_serial(device, _parse_baud(query, spec), spec, timeout_s)
    raise LinkError(
        f"link {spec}: unknown link spec (use serial:/dev/ttyUSB0?baud=250000, /dev/PATH, loop://, pty or fd:N)"
    )


def is_char_device(path: str) -> bool:
    """True when path names a character device (a tty), for friendlier messages."""
    try:
        return stat.S_ISCHR(os.stat(path).st_mode)
    except OSError:
        return False
