"""Positioned writes that finish: a recording's journal, side files and archive members are written
with `pwrite` at their place, so a failed write leaves no buffered bytes behind to land later; and a
write held together with the note that it was done (`interrupts_held`)."""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import signal
import stat
import threading
import time
from pathlib import Path
from typing import IO, Iterator


def pwrite_all(fd: int, data: memoryview, offset: int) -> None:
    """All of ``data`` written at ``offset`` (pwrite until done; nothing written is an error, not a
    loop without end)."""
    while len(data):
        n = os.pwrite(fd, data, offset)
        if n <= 0:
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        data, offset = data[n:], offset + n


@contextlib.contextmanager
def interrupts_held() -> Iterator[None]:
    """SIGINT held back while the block runs (the main thread's, whose handler Python set), so that
    its KeyboardInterrupt comes after the block, never between a write and the note that it was done
    (a later flush would write it again). Not a signal mask: another thread would take the signal
    and the main thread raise all the same. For short blocks: a Ctrl-C waits for them."""
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is None:
        yield
        return
    caught: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if caught:  # now, to the handler it was meant for
            signal.raise_signal(signal.SIGINT)


#: how long `open_held` waits for a FIFO's reader to open it (a consumer started just after the run)
FIFO_READER_WAIT_S = 10.0


def open_held(path: Path | str, *, binary: bool = False, read_too: bool = False,
              reader_wait_s: float | None = None) -> IO:
    """``path`` opened for writing from its start and, a regular file, held (an exclusive ``flock``)
    while it stays open: refused *before* anything is truncated when another holder has it (a
    second session recording to the same path, a `ctl save` onto a recording being written). A FIFO
    with no reader within ``reader_wait_s`` (default FIFO_READER_WAIT_S) is refused (ENXIO), not
    waited on for ever. Raises an OSError naming the file, its strerror the reason in words."""
    wait_s = FIFO_READER_WAIT_S if reader_wait_s is None else reader_wait_s
    for _ in range(8):  # (a holder may remove the file between our open and our lock: open again)
        fd = _open_waiting_for_reader(path, (os.O_RDWR if read_too else os.O_WRONLY) | os.O_CREAT | os.O_NONBLOCK
                                      | os.O_CLOEXEC, wait_s)
        try:
            if stat.S_ISREG(os.fstat(fd).st_mode):  # (a device or FIFO has nothing to truncate)
                _hold(fd, path)
                if not _names(path, fd):
                    os.close(fd)
                    continue
                os.ftruncate(fd, 0)
            os.set_blocking(fd, True)
        except BaseException:
            os.close(fd)
            raise
        break
    else:
        raise OSError(errno.EBUSY, "it is removed and made again as it is opened", str(path))
    if binary:  # (the file object owns fd from here, closing it if this fails)
        return open(fd, "w+b" if read_too else "wb")
    return open(fd, "w", encoding="utf-8", newline="\n")


def _open_waiting_for_reader(path: Path | str, flags: int, wait_s: float) -> int:
    """os.open; a FIFO's reader may be a moment behind its writer: polled for, up to ``wait_s``."""
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return os.open(path, flags, 0o666)
        except OSError as exc:
            if exc.errno != errno.ENXIO or not _is_fifo(path):  # (a socket or a device gives it too)
                raise
            if time.monotonic() >= deadline:
                raise OSError(errno.ENXIO, f"a FIFO with no reader within {wait_s:g} s", str(path)) from None
            time.sleep(0.01)


def file_identity(path: Path | str) -> tuple[int, int] | None:
    """(device, inode) of the file at ``path`` after symlinks (one file by any name); None when there
    is none."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino


def _names(path: Path | str, fd: int) -> bool:
    """Whether ``path`` still names the file open on ``fd`` (not removed, or replaced, since)."""
    held = os.fstat(fd)
    return file_identity(path) == (held.st_dev, held.st_ino)


#: why a held file is refused (its strerror)
HELD_REASON = "another process is writing it: a running session's recording?"
#: how long `_hold` tries again while a lock is taken: `held_elsewhere`'s probe holds one for a moment
HOLD_RETRY_S = 0.05


def _hold(fd: int, path: Path | str) -> None:
    """An exclusive flock on ``fd``, or the OSError saying another holder has one (a probe's shared
    lock of a moment is waited out, HOLD_RETRY_S). A filesystem without locks (an NFS mount with no
    lock daemon: ENOLCK) writes unheld, as before there were any."""
    deadline = time.monotonic() + HOLD_RETRY_S
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return
        except BlockingIOError:
            if time.monotonic() >= deadline:
                raise OSError(errno.EBUSY, HELD_REASON, str(path)) from None
            time.sleep(0.002)
        except OSError:
            return


def held_elsewhere(path: Path | str) -> bool:
    """Whether ``path`` is held as `open_held` holds it (a running session's journal) by any other
    open of it, in this process too (flock locks an open file, not a process: the session's own
    `ctl save` sees its recording held);
    False when there is no such file, it is not a regular file or it cannot be read."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):  # (not even opened: a FIFO's writer would take us for its reader)
            return False
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return False
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return False
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:  # (a filesystem without locks: nothing is held there)
        return False
    finally:
        os.close(fd)
    return False


def _is_fifo(path: Path | str) -> bool:
    try:
        return stat.S_ISFIFO(os.stat(path).st_mode)
    except OSError:
        return False


__all__ = ["HELD_REASON", "file_identity", "held_elsewhere", "interrupts_held", "open_held", "pwrite_all"]
