"""Links: framed messages over a serial port, a virtual serial pair (pty), loop:// or an fd.

    link = open_link("pty", timeout_s=0.5)      # link.peer_path: the tty the far end opens
    link.send(msg); reply = link.recv()         # LinkTimeout / LinkClosed name the link
    link.stats                                  # frames, bytes, CRC errors, resyncs, gaps ...
"""

from hilbench.link.faulty import FaultCounts, FaultyLink
from hilbench.link.link import DEFAULT_BAUD, DEFAULT_TIMEOUT_S, Link, LinkStats, open_link
from hilbench.link.pty import PtyPair, open_pty_pair

__all__ = [
    "DEFAULT_BAUD",
    "DEFAULT_TIMEOUT_S",
    "FaultCounts",
    "FaultyLink",
    "Link",
    "LinkStats",
    "PtyPair",
    "open_link",
    "open_pty_pair",
]
