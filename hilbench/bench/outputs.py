"""The files the bench writes besides its recording (a saved fragment, a step's or a sweep's CSV, a
plot): never onto a recording a running session writes, by any of its names, never waiting for
ever on a FIFO, and every failure an OSError that names the file."""

from __future__ import annotations

import contextlib
import errno
from pathlib import Path
from typing import IO, Iterator

from hilbench.bench.fileio import HELD_REASON, open_held
from hilbench.bench.recorder import held_by_a_running_session


@contextlib.contextmanager
def open_output(path: Path | str, *, binary: bool = False, reader_wait_s: float | None = None) -> Iterator[IO]:
    """``path`` opened for writing from its start (`open_held`: held while open; a FIFO's reader
    waited for ``reader_wait_s``), refused first when it is a running session's recording file.
    An OSError raised by the block's writes (a full disk) gets the file's name."""
    if held_by_a_running_session(path):
        raise OSError(errno.EBUSY, HELD_REASON, str(path))
    try:
        with open_held(path, binary=binary, reader_wait_s=reader_wait_s) as handle:
            yield handle
    except OSError as exc:
        if exc.filename is None:
            raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from None
        raise


__all__ = ["open_output"]
