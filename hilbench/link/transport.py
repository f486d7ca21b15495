"""Byte transports under a link: a file descriptor (pty, tty, pipe, socket) or pyserial's loop://.

Every read is bulk: wait (poll) until something is readable, then take all that is waiting in
one call. pyserial's read_until reads one byte per system call and is 4x slower on a pty.
"""

from __future__ import annotations

import errno
import fcntl
import math
import os
import select
import time
from typing import Any, Callable

from hilbench.errors import LinkClosed, LinkError, LinkTimeout

_READ_CHUNK = 65536
_HANGUP_ERRNOS = (errno.EIO, errno.ENXIO, errno.ENODEV, errno.EBADF, errno.EPIPE, errno.ECONNRESET)


def _poll_ms(timeout_s: float | None) -> int | None:
    """poll() takes whole milliseconds; round up so a deadline is never cut short."""
    if timeout_s is None:
        return None
    if timeout_s <= 0:
        return 0
    return math.ceil(timeout_s * 1000.0)


class Transport:
    """What a Link needs from the bytes underneath."""

    name: str

    def read(self, timeout_s: float | None) -> bytes:  # pragma: no cover - interface
        """Everything waiting (b'' after timeout_s); LinkClosed when the far end hung up."""
        raise NotImplementedError

    def write(self, data: bytes, timeout_s: float) -> None:  # pragma: no cover - interface
        """All of data, or LinkTimeout when the far end does not drain it in timeout_s."""
        raise NotImplementedError

    def fileno(self) -> int | None:
        return None

    def empty_read_ends(self) -> bool:
        """Whether a read of 0 bytes after a poll said "readable" is the far end's end of file (a
        pipe, a socket), as here; not on a raw tty that still answers as one (`FdTransport`)."""
        return True

    def close(self) -> None:  # pragma: no cover - interface
        raise NotImplementedError


class FdTransport(Transport):
    """A non-blocking file descriptor read with poll + one os.read of what is waiting."""

    def __init__(self, fd: int, name: str, *, on_close: Callable[[], None] | None = None,
                 owns_fd: bool = True) -> None:
        self.name = name
        self.fd = fd
        self._owns_fd = owns_fd
        self._on_close = on_close
        flags = fcntl.fcntl(fd, fcntl.F_GETFL)
        fcntl.fcntl(fd, fcntl.F_SETFL, flags | os.O_NONBLOCK)
        self._poll = select.poll()
        self._poll.register(fd, select.POLLIN | select.POLLPRI)
        self._closed = False
        self._tty = os.isatty(fd)

    def fileno(self) -> int | None:
        return self.fd

    def empty_read_ends(self) -> bool:
        """A raw tty (VMIN 0) reads 0 bytes when another reader of the pty took what a poll woke us
        for: no end while it still answers as a tty (a hung-up one fails isatty, its tcgetattr)."""
        return not self._tty or not os.isatty(self.fd)

    def _hung_up(self, why: str) -> LinkClosed:
        return LinkClosed(f"link {self.name}: the far end hung up ({why})")

    def read(self, timeout_s: float | None) -> bytes:
        if self._closed:
            raise LinkClosed(f"link {self.name}: closed")
        try:
            events = self._poll.poll(_poll_ms(timeout_s))
        except InterruptedError:  # pragma: no cover - PEP 475 retries for us
            return b""
        if not events:
            return b""
        try:
            data = os.read(self.fd, _READ_CHUNK)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno in _HANGUP_ERRNOS:
                raise self._hung_up(os.strerror(exc.errno or 0)) from None
            raise LinkError(f"link {self.name}: read failed: {exc.strerror}") from None
        if not data:
            if any(ev & select.POLLHUP for _, ev in events) or self.empty_read_ends():
                raise self._hung_up("end of file")
        return data

    def write(self, data: bytes, timeout_s: float) -> None:
        if self._closed:
            raise LinkClosed(f"link {self.name}: closed")
        view = memoryview(data)
        deadline: float | None = None
        while view:
            try:
                n = os.write(self.fd, view)
            except BlockingIOError:
                n = 0
            except OSError as exc:
                if exc.errno in _HANGUP_ERRNOS:
                    raise self._hung_up(os.strerror(exc.errno or 0)) from None
                raise LinkError(f"link {self.name}: write failed: {exc.strerror}") from None
            view = view[n:]
            if not view:
                return
            now = time.monotonic()
            if deadline is None:
                deadline = now + timeout_s
            remaining = deadline - now
            if remaining <= 0:
                raise LinkTimeout(
                    f"link {self.name}: the far end did not take {len(view)} bytes in {timeout_s * 1000:.0f} ms"
                )
            poller = select.poll()
            poller.register(self.fd, select.POLLOUT)
            poller.poll(_poll_ms(remaining))

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self._owns_fd:
            try:
                os.close(self.fd)
            except OSError:
                pass
        if self._on_close is not None:
            self._on_close()


class PtyMasterTransport(FdTransport):
    """The master side of a pty pair we made; keeps its own slave fd until the far end speaks.

    While nobody holds the slave open, reading the master fails with EIO. Holding our copy
    until the first bytes arrive lets the far end open the path at its leisure; releasing it
    afterwards lets us see the far end hang up.
    """

    def __init__(self, master_fd: int, slave_fd: int, slave_path: str, name: str) -> None:
        super().__init__(master_fd, name)
        self.slave_fd: int | None = slave_fd
        self.slave_path = slave_path

    def release_slave(self) -> None:
        """Close our copy of the slave (the far end has it open, or we pass it on)."""
        if self.slave_fd is not None:
            try:
                os.close(self.slave_fd)
            except OSError:
                pass
            self.slave_fd = None

    def read(self, timeout_s: float | None) -> bytes:
        data = super().read(timeout_s)
        if data and self.slave_fd is not None:
            self.release_slave()
        return data

    def close(self) -> None:
        self.release_slave()
        super().close()


class SerialUrlTransport(Transport):
    """A pyserial port read through pyserial (rfc2217://, loop://, spy://, ...), with deadlines.

    What is waiting is taken in one call; otherwise one byte is awaited for at most timeout_s,
    then whatever followed it. The deadline goes into the port's `_timeout` directly: the public
    `timeout` setter reconfigures the port, which on rfc2217:// renegotiates the line settings
    with the server (50 ms sleeps) on every read, and rfc2217 refuses any write_timeout there.
    """

    def __init__(self, port: Any, name: str) -> None:
        self.name = name
        self._port = port
        self._direct = hasattr(port, "_timeout") and hasattr(port, "_write_timeout")

    def read(self, timeout_s: float | None) -> bytes:
        port = self._port
        try:
            waiting = port.in_waiting
            if waiting:
                return bytes(port.read(waiting))
            if timeout_s is not None and timeout_s <= 0:
                return b""
            if self._direct:
                port._timeout = timeout_s
            else:  # pragma: no cover
                port.timeout = timeout_s
            first = port.read(1)
            if not first:
                return b""
            waiting = port.in_waiting
            return bytes(first) + (bytes(port.read(waiting)) if waiting else b"")
        except Exception as exc:  # pyserial raises SerialException / PortNotOpenError
            raise LinkClosed(f"link {self.name}: {_first_line(exc)}") from None

    def write(self, data: bytes, timeout_s: float) -> None:
        import serial

        try:
            if self._direct:
                self._port._write_timeout = timeout_s
            else:  # pragma: no cover
                self._port.write_timeout = timeout_s
            self._port.write(data)
        except serial.SerialTimeoutException:
            raise LinkTimeout(
                f"link {self.name}: the far end did not take {len(data)} bytes in {timeout_s * 1000:.0f} ms"
            ) from None
        except Exception as exc:
            raise LinkClosed(f"link {self.name}: {_first_line(exc)}") from None

    def close(self) -> None:
        try:
            self._port.close()
        except Exception:
            pass


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
