"""The scope's HTTP log: a malformed request is one line, at most one line per window, never a
traceback.

aiohttp logs a request it cannot parse (a request line over 8 KB, a 200 kB header, 20 000
headers, TLS bytes on the plain port) as "Error handling request" with the parser's traceback,
before any token or user check: anyone on the machine could print tracebacks on the bench
user's terminal. The scope's request handlers log through a `RateLimitedLog` instead: the first
problem of a window is one line (what, from where, the parser's one-line reason), the rest of the
window is counted and named in the next line.
"""

from __future__ import annotations

import logging
import re
import sys
import threading
import time
from typing import Callable, TextIO

#: at most one line per this many seconds (the others are counted)
WINDOW_S = 10.0


class RateLimitedLog(logging.Handler):
    """A logging handler that writes one line per record, at most one per ``window_s``."""

    def __init__(self, write: Callable[[str], None] | None = None, window_s: float = WINDOW_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__(logging.INFO)
        self._write = write or _stderr_line
        self.window_s = window_s
        self._clock = clock
        self._lock_rl = threading.Lock()
        self._next_s = float("-inf")
        self.suppressed = 0
        self.count = 0

    def emit(self, record: logging.LogRecord) -> None:
        with self._lock_rl:
            self.count += 1
            now = self._clock()
            if now < self._next_s:
                self.suppressed += 1
                return
            more, self.suppressed = self.suppressed, 0
            self._next_s = now + self.window_s
        self._write(one_line(record) + (f" ({more} more in the last {self.window_s:g} s)" if more else ""))


def one_line(record: logging.LogRecord) -> str:
    """"scope: MESSAGE: REASON" in one line: the exception's first line, no traceback."""
    try:
        text = record.getMessage()
    except (TypeError, ValueError):
        text = str(record.msg)
    text = text.replace("Error handling request", "refused a malformed HTTP request")
    if record.exc_info and record.exc_info[1] is not None:
        reason = " ".join(str(record.exc_info[1]).split())
        reason = _QUOTED.split(reason, 1)[0]  # the parser quotes what it was sent: not for a terminal
        text = f"{text}: {type(record.exc_info[1]).__name__}: {reason}"
    text = "".join(c if c.isprintable() else "?" for c in " ".join(text.split()))
    return "scope: " + (text if len(text) <= 200 else text[:197] + "...")


_QUOTED = re.compile(r":? (?:bytearray\(|b'|b\"|')")


def _stderr_line(line: str, stream: TextIO | None = None) -> None:
    out = stream or sys.stderr
    try:
        out.write(line + "\n")
        out.flush()
    except (OSError, ValueError):
        pass


def scope_logger(handler: RateLimitedLog) -> logging.Logger:
    """A logger of the scope's own (not in logging's tree: nothing propagates to the root's handlers
    or to logging.lastResort's tracebacks) that writes through ``handler``."""
    logger = logging.Logger("hilbench.scope.http", logging.INFO)
    logger.propagate = False
    logger.addHandler(handler)
    return logger


__all__ = ["RateLimitedLog", "WINDOW_S", "one_line", "scope_logger"]
