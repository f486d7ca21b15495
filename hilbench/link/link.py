"""Framed links: messages over a byte transport, with deadlines and statistics.

The link knows frames, not meanings: it encodes and decodes with hilbench.protocol, reads in
bulk and splits frames in memory, and counts what went across and what went wrong. The one
piece of meaning it keeps is which message types carry a running sequence number (Sensors,
Drive), so it can count sequence gaps.
"""

from __future__ import annotations

import os
import termios
from time import monotonic
from collections import deque
from dataclasses import asdict, dataclass
from typing import Any, Callable, Iterable

from hilbench.errors import DecodeError, LinkError, LinkTimeout
from hilbench.link.transport import _HANGUP_ERRNOS, _READ_CHUNK, FdTransport, Transport
from hilbench.protocol import Drive, FrameDecoder, Sensors, decode_frame, encode_frame
from hilbench.protocol.messages import Message

DEFAULT_TIMEOUT_S = 1.0
_UNSEQUENCED = object()  # _next_seq.get default: a message type without a running seq
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
    """Messages over a transport: send(msg), recv(timeout_s) -> msg, stats, close().

    On a file descriptor (pty, tty, socket) send and recv talk to the fd directly: one os.write
    per frame; poll (the timeout) then one os.read of all that is waiting; and when those bytes
    are exactly one frame on a clean stream, decode_frame on it without the streaming decoder.
    Anything else (partial frames, several frames, bad bytes, an rx_filter) goes through the
    FrameDecoder, which counts every fault.
    """

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
        self._pending: deque[Message] = deque()
        self._sequenced = frozenset(sequenced_types)
        # the seq each sequenced type should carry next (None: not seen yet); other types absent
        self._next_seq: dict[type, int | None] = dict.fromkeys(self._sequenced)
        self._rx_filter: Callable[[bytes], bytes] | None = None
        self.frames_tx = 0
        self.bytes_tx = 0
        self.bytes_rx = 0
        self.timeouts = 0
        self.seq_gaps = 0
        self.fast_frames = 0  # good frames decoded on the fast path (the decoder never saw them)
        self._clean = True  # the decoder holds no partial frame and owes no resync count
        self._blocking = False  # the fd is O_NONBLOCK except while recv_or_none(None) is in use
        self._closed = False
        # direct fd access for FdTransport; -1 = go through the transport
        fd = transport.fileno() if isinstance(transport, FdTransport) else None
        self._fd_w = -1 if fd is None else fd
        self._fd_r = -1
        self._poll_fd: Callable[[float | None], list[Any]] | None = None
        if fd is not None:
            self._poll_fd = transport._poll.poll  # type: ignore[attr-defined]
            self._update_fast_read()

    def _update_fast_read(self) -> None:
        """Read the fd directly unless an rx_filter is set or a pty master still holds its slave."""
        transport = self.transport
        if (self._fd_w < 0 or self._rx_filter is not None or self._closed
                or getattr(transport, "slave_fd", None) is not None):
            self._fd_r = -1
        else:
            self._fd_r = self._fd_w

    @property
    def rx_filter(self) -> Callable[[bytes], bytes] | None:
        """A function applied to received bytes before decoding (the fault injector's)."""
        return self._rx_filter

    @rx_filter.setter
    def rx_filter(self, value: Callable[[bytes], bytes] | None) -> None:
        self._rx_filter = value
        self._update_fast_read()

    # -- sending -------------------------------------------------------------------------
    def send(self, msg: Message) -> None:
        """Encode one message and write all of its bytes (LinkTimeout if the far end stalls)."""
        data = encode_frame(msg)
        fd = self._fd_w
        if fd >= 0:
            try:
                n = os.write(fd, data)
            except BlockingIOError:
                n = 0
            except OSError:
                n = 0  # the transport names the error (hang-up, closed) on the retry below
            if n != len(data):
                self._write(data[n:], self.timeout_s)
        else:
            self._write(data, self.timeout_s)
        self.frames_tx += 1
        self.bytes_tx += len(data)

    def send_bytes(self, data: bytes, frames: int = 1) -> None:
        """Write ready-made wire bytes (used by the fault injector) and count them."""
        self._write(data, self.timeout_s)
        self.frames_tx += frames
        self.bytes_tx += len(data)

    # -- receiving -----------------------------------------------------------------------
    def recv(self, timeout_s: float | None = None) -> Message:
        """The next good frame's message; LinkTimeout after timeout_s, LinkClosed on hang-up."""
        if self._pending:
            return self._pending.popleft()
        timeout = self.timeout_s if timeout_s is None else timeout_s
        fd = self._fd_r
        if fd >= 0:
            # the hot path: wait, read what is waiting, and it is usually exactly one frame
            t0 = monotonic()
            msg = self._read_ready(fd, timeout)
            if msg is not None:
                return msg
            remaining = t0 + timeout - monotonic()
            msg = self._wait(remaining, timeout) if remaining > 0 else None
        else:
            msg = self._wait(timeout, timeout)
        if msg is None:
            self.timeouts += 1
            raise LinkTimeout(
                f"link {self.name}: no frame for {timeout * 1000:.0f} ms "
                f"(after {self.stats.frames_rx} frames received)"
            )
        return msg

    def recv_or_none(self, timeout_s: float | None) -> Message | None:
        """Like recv, but None when nothing arrives in timeout_s (not counted as a timeout).

        For servers that wake up periodically to check a stop flag or a watchdog. timeout_s None
        waits as long as it takes (LinkClosed on hang-up): on an fd that is one blocking os.read
        per frame with no poll; the fd then stays blocking, so writes wait for the far end
        without a deadline, until a call with a timeout makes it non-blocking again.
        """
        if self._pending:
            return self._pending.popleft()
        fd = self._fd_r
        if timeout_s is None:
            return self._recv_forever()
        if self._blocking:
            self._set_blocking(False)
        if fd >= 0:
            t0 = monotonic()
            return self._took(self._read_once(fd, timeout_s), t0 + timeout_s, timeout_s)
        return self._wait(timeout_s, timeout_s)

    def _read_once(self, fd: int, timeout_s: float) -> bytes | None:
        """One poll and one read: what arrived (b"": end of file, or a raw tty's empty read), or None
        (nothing, or a read error the transport names on the next read); a hang-up's error raises."""
        if not self._poll_fd(timeout_s * 1000.0 if timeout_s > 0 else 0):
            return None
        try:
            return os.read(fd, _READ_CHUNK)
        except OSError as exc:  # BlockingIOError included: nothing after all
            if exc.errno in _HANGUP_ERRNOS:  # (said now: with no time left no later read would)
                raise self.transport._hung_up(os.strerror(exc.errno or 0)) from None  # type: ignore[attr-defined]
            return None

    def _took(self, data: bytes | None, deadline: float, timeout_s: float) -> Message | None:
        """recv_or_none's end after one poll and read (`_read_once`'s answer): the frame they brought,
        else the wait through the transport up to ``deadline``. hilbench/targets/_remotestep.c, the
        C form of RemoteTarget.step, hands what it read here whenever it is not one good Drive."""
        if data is not None and self._data_or_eof(data):
            msg = self._take_read(data)
            if msg is not None:
                return msg
        remaining = deadline - monotonic()
        return self._wait(remaining, timeout_s) if remaining > 0 else None

    def _read_ready(self, fd: int, timeout_s: float) -> Message | None:
        """One poll and one read: the frame that arrived, or None (nothing yet, or part of one).

        Another read error returns None: the caller's wait reads again through the transport, which
        names it. End of file and a hang-up's error raise the hang-up."""
        data = self._read_once(fd, timeout_s)
        if data is None or not self._data_or_eof(data):
            return None
        return self._take_read(data)

    def _data_or_eof(self, data: bytes) -> bool:
        """True for bytes; 0 bytes raise the hang-up where they are the far end's end of file (the
        transport's `empty_read_ends`: not on a raw tty that still answers as one), else False."""
        if data:
            return True
        if self.transport.empty_read_ends():
            raise self.transport._hung_up("end of file")  # type: ignore[attr-defined]
        return False

    def _take_read(self, data: bytes) -> Message | None:
        """What one read brought: the frame itself when it is exactly one good frame (the fast
        path, no streaming decoder), else the first frame the streaming decoder makes of it."""
        if data[-1] == 0 and self._clean:
            try:
                msg = decode_frame(data[:-1])  # raises when a 0x00 inside means more frames
            except DecodeError:
                pass
            else:
                self.bytes_rx += len(data)
                self.fast_frames += 1
                kind = type(msg)
                expect = self._next_seq.get(kind, _UNSEQUENCED)
                if expect is not _UNSEQUENCED:
                    seq = msg.seq
                    if expect is not None and seq != expect:
                        self.seq_gaps += 1
                    self._next_seq[kind] = (seq + 1) & 0xFF
                return msg
        return self._take_first(data)

    def _recv_forever(self) -> Message:
        """The next frame, however long it takes: blocking reads, no poll (the lockstep server)."""
        fd = self._fd_r
        if fd < 0:
            while True:
                msg = self._wait(1.0, 1.0)
                if msg is not None:
                    return msg
        if not self._blocking:
            self._set_blocking(True)
        while True:
            try:
                data = os.read(fd, _READ_CHUNK)
            except OSError as exc:
                self._set_blocking(False)
                self._read(0)  # the transport names a hang-up
                raise LinkError(f"link {self.name}: read failed: {exc.strerror}") from None
            if not data:
                self._set_blocking(False)
                raise self.transport._hung_up("end of file")  # type: ignore[attr-defined]
            msg = self._take_read(data)
            if msg is not None:
                return msg

    def _set_blocking(self, blocking: bool) -> None:
        fd = self._fd_w
        if fd >= 0:
            if blocking and os.isatty(fd):
                # pyserial opens ttys with VMIN=0, VTIME=0, where a blocking read returns b""
                # at once; VMIN=1 makes it wait for a byte (O_NONBLOCK reads ignore VMIN)
                attrs = termios.tcgetattr(fd)
                if attrs[6][termios.VMIN] != 1 or attrs[6][termios.VTIME] != 0:
                    attrs[6][termios.VMIN], attrs[6][termios.VTIME] = 1, 0
                    termios.tcsetattr(fd, termios.TCSANOW, attrs)
            os.set_blocking(fd, blocking)
        self._blocking = blocking

    def _wait(self, remaining: float, timeout: float) -> Message | None:
        """The general receive loop through the transport: the first frame, or None at the deadline."""
        deadline = monotonic() + remaining
        read = self._read
        while True:
            data = read(remaining)
            if data:
                msg = self._take_first(data)
                if msg is not None:
                    self._update_fast_read()  # a pty master may just have released its slave
                    return msg
            remaining = deadline - monotonic()
            if remaining <= 0:
                return None

    def _take_first(self, data: bytes) -> Message | None:
        frames = self._take(data)
        if not frames:
            return None
        if len(frames) > 1:
            self._pending.extend(frames[1:])
        return frames[0]

    def poll(self) -> list[Message]:
        """Every good frame already waiting, without blocking."""
        out = list(self._pending)
        self._pending.clear()
        data = self._read(0)
        while data:
            out.extend(self._take(data))
            data = self._read(0)
        return out

    def _check_seq(self, kind: type, seq: int) -> None:
        expect = self._next_seq[kind]
        if expect is not None and seq != expect:
            self.seq_gaps += 1
        self._next_seq[kind] = (seq + 1) & 0xFF

    def _take(self, data: bytes) -> list[Message]:
        """Feed the streaming decoder (it counts every fault) and note whether it is left clean."""
        self.bytes_rx += len(data)
        if self._rx_filter is not None:
            data = self._rx_filter(data)
        errors_before = self._decoder_errors()
        frames = self._feed(data)
        # clean: no partial frame held (data ended on a delimiter), and no resync still owed
        # (no bad frame in this feed, and any earlier bad input was followed by a good frame)
        self._clean = (bool(data) and data[-1] == 0 and self._decoder_errors() == errors_before
                       and (self._clean or bool(frames)))
        if frames and self._sequenced:
            sequenced = self._sequenced
            for msg in frames:
                kind = type(msg)
                if kind in sequenced:
                    self._check_seq(kind, msg.seq)
        return frames

    def _decoder_errors(self) -> int:
        d = self._decoder
        return (sum(_decoder_counter(d, key) for key in _DECODER_ERROR_KEYS)
                + _decoder_counter(d, "garbage_bytes"))

    def reset_sequence(self) -> None:
        """Forget the last sequence numbers (a new session starts counting again)."""
        self._next_seq = dict.fromkeys(self._sequenced)

    # -- bookkeeping ---------------------------------------------------------------------
    @property
    def stats(self) -> LinkStats:
        d = self._decoder
        return LinkStats(
            frames_tx=self.frames_tx,
            frames_rx=_decoder_counter(d, "frames") + self.fast_frames,
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
            self._fd_r = self._fd_w = -1
            self.transport.close()

    def __enter__(self) -> "Link":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Link({self.name!r})"
