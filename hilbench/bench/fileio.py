"""Positioned writes that finish: a recording's journal, side files and archive members are written
with `pwrite` at their place, so a failed write leaves no buffered bytes behind to land later."""

from __future__ import annotations

import errno
import os


def pwrite_all(fd: int, data: memoryview, offset: int) -> None:
    """All of ``data`` written at ``offset`` (pwrite until done; nothing written is an error, not a
    loop without end)."""
    while len(data):
        n = os.pwrite(fd, data, offset)
        if n <= 0:
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        data, offset = data[n:], offset + n


__all__ = ["pwrite_all"]
