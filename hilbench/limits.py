"""Size limits on everything the bench reads, and the one bounded read they go through.

Whatever a file or a peer holds, hilbench reads at most these many bytes before it refuses the
input with one line naming it: a config that ``extends = "/dev/zero"`` is refused after a MiB, not
after the machine's memory. `docs/design.md` ("Limits") lists them with the control socket's,
the scope's and the recordings' own.
"""

from __future__ import annotations

import math
import numbers
import os
import select
import stat
import time
from pathlib import Path

from hilbench.errors import HilbenchError

KIB = 1024
MIB = 1024 * KIB
GIB = 1024 * MIB

#: a config file, each file of its ``extends`` chain, a ``--scenario`` file, a ``--gains-file``
CONFIG_MAX_BYTES = 1 * MIB
#: one line of a sweep store (``--resume``), and the whole store
STORE_LINE_MAX_BYTES = 64 * KIB
STORE_MAX_BYTES = 256 * MIB
#: a recording's metadata: a CSV ``#`` line, a journal's header, an NPZ's metadata member
RECORDING_META_MAX_BYTES = 16 * MIB
#: a CSV recording's row line, and its columns
RECORDING_LINE_MAX_BYTES = 64 * KIB
RECORDING_MAX_COLUMNS = 1024
#: the column data of a recording read back (report, the scope's viewer, the plugin's plots)
RECORDING_MAX_BYTES = 16 * GIB
#: how long a bounded read of a pipe or a device waits for its next byte
READ_IDLE_TIMEOUT_S = 10.0


def size_text(n_bytes: int) -> str:
    """1048576 -> '1 MiB' (the limits read as the docs write them)."""
    for unit, size in (("GiB", GIB), ("MiB", MIB), ("KiB", KIB)):
        if n_bytes >= size and n_bytes % size == 0:
            return f"{n_bytes // size} {unit}"
    return f"{n_bytes} bytes"


def is_finite_number(value: object) -> bool:
    """A finite real number (an int, a float, numpy's; not a bool) that a float holds: JSON or TOML
    from outside may carry NaN, or an int of 400 digits that overflows every figure made from it."""
    if not isinstance(value, numbers.Real) or isinstance(value, bool):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def clipped(text: str, limit: int = 40) -> str:
    """``text`` on one line, cut to ``limit`` characters (a `--set` word may be 100 kB)."""
    text = " ".join(text.split())
    return text if len(text) <= limit else text[:limit - 3] + "..."


def shown(value: object, limit: int = 40) -> str:
    """``value``'s repr for a message, `clipped`; an int too long to print (Python refuses over 4300
    digits) by its size."""
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 128:
        return f"<an integer of {value.bit_length()} bits>"
    try:
        return clipped(repr(value), limit)
    except ValueError:  # a container holding such an int
        return f"<a {type(value).__name__}>"


def read_bounded(path: str | os.PathLike[str], limit: int, error: type[HilbenchError], what: str) -> bytes:
    """At most ``limit`` bytes of ``path``; ``error(what: ...)`` when it holds more, cannot be read,
    or (a pipe, a device) stays silent for READ_IDLE_TIMEOUT_S. A regular file's size is checked
    before anything is read; anything else is read in pieces until its end or the limit, without
    blocking (a FIFO nobody writes to reads as empty instead of hanging)."""
    try:
        fd = os.open(os.fspath(path), os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        raise error(f"{what}: cannot read: {exc.strerror or exc}") from None
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise error(f"{what}: is a directory")
        if stat.S_ISREG(st.st_mode) and st.st_size > limit:
            raise error(f"{what}: {st.st_size} bytes, more than the limit of {size_text(limit)}")
        return _read_pieces(fd, limit, error, what, regular=stat.S_ISREG(st.st_mode))
    finally:
        os.close(fd)


def _read_pieces(fd: int, limit: int, error: type[HilbenchError], what: str, *, regular: bool) -> bytes:
    parts: list[bytes] = []
    total = 0
    deadline = time.monotonic() + READ_IDLE_TIMEOUT_S
    while True:
        try:
            chunk = os.read(fd, min(1 * MIB, limit + 1 - total))
        except BlockingIOError:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not select.select([fd], [], [], remaining)[0]:
                raise error(f"{what}: nothing to read for {READ_IDLE_TIMEOUT_S:g} s") from None
            continue
        except OSError as exc:
            raise error(f"{what}: cannot read: {exc.strerror or exc}") from None
        if not chunk:
            return b"".join(parts)
        parts.append(chunk)
        total += len(chunk)
        deadline = time.monotonic() + READ_IDLE_TIMEOUT_S
        if total > limit:
            raise error(f"{what}: more than the limit of {size_text(limit)}"
                        + ("" if regular else " (not a regular file)"))


def read_text_bounded(path: str | os.PathLike[str], limit: int, error: type[HilbenchError], what: str) -> str:
    """`read_bounded` as UTF-8 text (``error`` naming the first byte that is not)."""
    raw = read_bounded(path, limit, error, what)
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{what}: not UTF-8 text (byte {exc.start})") from None


def check_path_size(path: Path, limit: int, error: type[HilbenchError], what: str) -> int:
    """The size of a regular file, ``error`` when it is not one or is larger than ``limit``."""
    try:
        st = path.stat()
    except OSError as exc:
        raise error(f"{what}: cannot read: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise error(f"{what}: not a regular file")
    if st.st_size > limit:
        raise error(f"{what}: {st.st_size} bytes, more than the limit of {size_text(limit)}")
    return st.st_size


__all__ = [
    "is_finite_number",
    "CONFIG_MAX_BYTES", "STORE_LINE_MAX_BYTES", "STORE_MAX_BYTES", "RECORDING_META_MAX_BYTES",
    "RECORDING_LINE_MAX_BYTES", "RECORDING_MAX_COLUMNS", "RECORDING_MAX_BYTES", "READ_IDLE_TIMEOUT_S",
    "check_path_size", "read_bounded", "read_text_bounded", "size_text",
]
