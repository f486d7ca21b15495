"""Links: framed messages over a serial port, a virtual serial pair (pty), a socket, any pyserial URL.

    spec = parse_target_spec("socket://127.0.0.1:5000?corrupt=1e-4")   # ConfigError if malformed
    link = open_link(spec, timeout_s=0.5)       # or open_link("pty"): link.peer_path for the far end
    link.send(msg); reply = link.recv()         # LinkTimeout / LinkClosed name the link
    link.stats                                  # frames, bytes, CRC errors, resyncs, gaps ...
"""

from hilbench.link.faulty import FaultCounts, FaultyLink
from hilbench.link.link import DEFAULT_TIMEOUT_S, Link, LinkStats
from hilbench.link.ports import apply_faults, open_link
from hilbench.link.pty import PtyPair, open_pty_pair
from hilbench.link.spec import DEFAULT_BAUD, FaultSpec, TargetSpec, describe_spec_forms, parse_target_spec
from hilbench.link.tcp import TcpListener, parse_tcp_listen, serve_tcp_once
from hilbench.link.throttle import ThrottledTransport

__all__ = [
    "DEFAULT_BAUD",
    "DEFAULT_TIMEOUT_S",
    "FaultCounts",
    "FaultSpec",
    "FaultyLink",
    "Link",
    "LinkStats",
    "PtyPair",
    "TargetSpec",
    "TcpListener",
    "ThrottledTransport",
    "apply_faults",
    "describe_spec_forms",
    "open_link",
    "open_pty_pair",
    "parse_target_spec",
    "parse_tcp_listen",
    "serve_tcp_once",
]
