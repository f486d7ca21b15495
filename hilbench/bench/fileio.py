"""Positioned writes that finish: a recording's journal, side files and archive members are written
with `pwrite` at their place, so a failed write leaves no buffered bytes behind to land later; and a
write held together with the note that it was done (`interrupts_held`)."""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import threading
from typing import Iterator


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


__all__ = ["interrupts_held", "pwrite_all"]
