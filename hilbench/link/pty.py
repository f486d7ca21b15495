"""A virtual serial pair: os.openpty in raw mode, the slave readable only by its owner."""

from __future__ import annotations

import os
import tty
from typing import NamedTuple


class PtyPair(NamedTuple):
    master_fd: int
    slave_fd: int
    slave_path: str


def open_pty_pair() -> PtyPair:
    """Make a pty pair: raw mode (no echo, no line editing, 8 bit clean), slave mode 0600."""
    master_fd, slave_fd = os.openpty()
    try:
        tty.setraw(slave_fd)
        os.fchmod(slave_fd, 0o600)
        slave_path = os.ttyname(slave_fd)
    except BaseException:
        os.close(master_fd)
        os.close(slave_fd)
        raise
    return PtyPair(master_fd, slave_fd, slave_path)
