"""Opening links from target specs: one code path from the parsed spec to a Link.

    link = open_link("socket://127.0.0.1:5000?corrupt=1e-3", timeout_s=0.5)

A pty, an fd, a tty and a socket:// connection are file descriptors and share the fd fast path
(poll + one os.read). Every other pyserial URL (rfc2217://, loop://, spy://, ...) is read through
pyserial with the caller's deadline. A spec's fault keys wrap the link in a FaultyLink.
"""

from __future__ import annotations

import os
import socket

from hilbench.errors import ConfigError, LinkError
from hilbench.link.faulty import FaultyLink
from hilbench.link.link import DEFAULT_TIMEOUT_S, Link
from hilbench.link.pty import open_pty_pair
from hilbench.link.spec import (
    KIND_INPROCESS,
    PORT_DEVICE,
    PORT_FD,
    PORT_PTY,
    PORT_URL,
    FaultSpec,
    TargetSpec,
    parse_target_spec,
)
from hilbench.link.throttle import ThrottledTransport
from hilbench.link.transport import FdTransport, PtyMasterTransport, SerialUrlTransport

# URL schemes whose pyserial port is a plain socket carrying the bytes as they are (no telnet
# escaping, no logging wrapper): read through its fd like a pty
_RAW_SOCKET_SCHEMES = ("socket://",)


def open_link(spec: str | TargetSpec, *, timeout_s: float = DEFAULT_TIMEOUT_S) -> Link | FaultyLink:
    """Open the link a target spec names (parse_target_spec's grammar), wrapped in a FaultyLink
    when the spec has fault keys.

    A port spec opens that port. `pty`, and the kinds that start their far end as a process
    (emulator:, sil:, exec:), make a raw pty pair here: `link.peer_path` is the path the far end
    opens. inprocess: has no link (ConfigError). A malformed spec is a ConfigError; a port that
    cannot be opened is a LinkError naming it.
    """
    parsed = spec if isinstance(spec, TargetSpec) else parse_target_spec(spec)
    return apply_link_options(_open_plain(parsed, timeout_s), parsed)


def apply_link_options(link: Link, parsed: TargetSpec) -> Link | FaultyLink:
    """The spec's wire throttle (``wire_baud``) under the link, then its faults around it."""
    return apply_faults(throttle(link, parsed.wire_baud), parsed.faults)


def throttle(link: Link, wire_baud: int | None) -> Link:
    """link itself without a baud; else a link over the same transport held to that wire time.
    The fault injector goes around it, so a corrupted byte still takes its wire time."""
    if wire_baud is None:
        return link
    transport = ThrottledTransport(link.transport, wire_baud)
    return Link(transport, f"{link.name} (wire {wire_baud} baud)", timeout_s=link.timeout_s,
                peer_path=link.peer_path)


def apply_faults(link: Link, faults: FaultSpec | None) -> Link | FaultyLink:
    """link itself without faults; else a seeded FaultyLink with the spec's rates around it."""
    if faults is None:
        return link
    try:
        return FaultyLink(link, faults.seed, **faults.faulty_link_options())  # type: ignore[arg-type]
    except BaseException:
        link.close()
        raise


def _open_plain(spec: TargetSpec, timeout_s: float) -> Link:
    if spec.kind == KIND_INPROCESS:
        raise ConfigError(f"target spec {spec.text!r}: an in-process target has no link to open")
    if spec.spawns_process or spec.port_kind == PORT_PTY:
        return _open_pty(timeout_s)
    if spec.port_kind == PORT_FD:
        return _open_fd(spec.port, timeout_s)
    if spec.port_kind == PORT_DEVICE:
        return _open_serial(spec.port, spec.baud, spec.port, timeout_s)
    if spec.port_kind == PORT_URL:
        return _open_url(spec.port, spec.baud, timeout_s)
    raise ConfigError(f"target spec {spec.text!r}: kind {spec.kind!r} has no port")  # pragma: no cover


def _open_pty(timeout_s: float) -> Link:
    pair = open_pty_pair()
    name = f"pty:{pair.slave_path}"
    transport = PtyMasterTransport(pair.master_fd, pair.slave_fd, pair.slave_path, name)
    return Link(transport, name, timeout_s=timeout_s, peer_path=pair.slave_path)


def _open_fd(port: str, timeout_s: float) -> Link:
    fd = int(port[len("fd:"):])
    try:
        os.fstat(fd)
    except OSError as exc:
        raise LinkError(f"link {port}: file descriptor {fd} is not open: {exc.strerror}") from None
    return Link(FdTransport(fd, port), port, timeout_s=timeout_s)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _open_serial(device: str, baud: int, name: str, timeout_s: float) -> Link:
    import serial  # pyserial

    if not os.path.exists(device):
        raise LinkError(f"link {name}: no such port {device} (try `hilbench ports`)")
    try:
        port = serial.Serial(device, baudrate=baud, timeout=0, exclusive=True)
    except serial.SerialException as exc:
        text = _first_line(exc)
        if "lock" in text.lower():
            raise LinkError(f"link {name}: port {device} is busy (another program has it open)") from None
        raise LinkError(f"link {name}: cannot open port {device}: {text}") from None
    except (OSError, ValueError) as exc:
        raise LinkError(f"link {name}: cannot open port {device}: {exc}") from None
    transport = FdTransport(port.fd, name, owns_fd=False, on_close=port.close)
    return Link(transport, name, timeout_s=timeout_s)


def _open_url(url: str, baud: int, timeout_s: float) -> Link:
    """serial_for_url; a raw socket goes on the fd fast path, anything else through pyserial."""
    import serial  # pyserial

    try:
        port = serial.serial_for_url(url, baudrate=baud, timeout=0)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise LinkError(f"link {url}: cannot open: {_first_line(exc)}") from None
    try:
        if url.startswith(_RAW_SOCKET_SCHEMES):
            fd = port.fileno()
            _set_nodelay(fd)
            transport: FdTransport | SerialUrlTransport = FdTransport(fd, url, owns_fd=False, on_close=port.close)
        else:
            transport = SerialUrlTransport(port, url)
    except BaseException:
        port.close()
        raise
    return Link(transport, url, timeout_s=timeout_s)


def _set_nodelay(fd: int) -> None:
    """No Nagle on a lockstep link: each small frame goes out now, not after the peer's ACK."""
    sock = socket.socket(fileno=os.dup(fd))  # a second handle on the same connection
    try:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    finally:
        sock.close()


__all__ = ["apply_faults", "apply_link_options", "open_link", "throttle"]
