"""Links over TCP: the AN1017 emulator served on 127.0.0.1 and reached through socket:// and
rfc2217:// (pyserial URLs), with the same deadlines and statistics as a pty.

The reference for every Drive is the in-process AN1017 model fed the same Sensors after the same
HostHello: a link only carries bytes, so what comes back must be exactly what the model computes.
"""

from __future__ import annotations

import select
import socket
import subprocess
import sys
import threading
import time
from typing import Any

from _firmware import one_edge
import pytest
import serial
import serial.rfc2217

from hilbench.errors import ConfigError, LinkClosed, LinkError, LinkTimeout
from hilbench.link import FaultyLink, TcpListener, open_link, parse_tcp_listen
from hilbench.protocol import EDGE_NONE, INPUT_S2, MODE_LOCKSTEP, PROTOCOL_VERSION, HostHello, Sensors
from hilbench.targets import make_target
from hilbench.targets.remote import RemoteTarget
from hilbench.targets.serve import serve

from _tcp_serve import ServedInThread

PERIOD_US = 50
HALL_SEQUENCE = (0b001, 0b011, 0b010, 0b110, 0b100, 0b101)  # one electrical turn, 60 degrees a step


def sensors_script(n: int) -> list[Sensors]:
    """S2 pressed then released (start), the pot above mid-scale, halls stepping every 40 periods."""
    out = []
    for k in range(n):
        halls = HALL_SEQUENCE[(k // 40) % 6]
        buttons = INPUT_S2 if 5 <= k < 15 else 0
        edge = (k * 500) & 0xFFFF if k % 40 == 0 else EDGE_NONE
        out.append(Sensors((k + 1) & 0xFF, halls | buttons, one_edge(edge, halls), 0, (700 + (k % 7), 0, 650)))
    return out


def reference_drives(script: list[Sensors]) -> list[Any]:
    model = make_target("an1017")
    model.hello(HostHello(1, PROTOCOL_VERSION, PERIOD_US, MODE_LOCKSTEP, 0))
    return [model.step(s) for s in script]


@pytest.fixture
def served():
    s = ServedInThread()
    try:
        yield s
    finally:
        s.close()


def lockstep(link: Any, script: list[Sensors]) -> list[Any]:
    remote = RemoteTarget(link, timeout_s=2.0, retry_s=2.0)  # no retries: the frame counts below are exact
    hello = remote.handshake(PERIOD_US, MODE_LOCKSTEP, 0, attempts=3)
    assert hello.firmware_name.upper().startswith("AN1017")
    return [remote.step(s) for s in script]


def test_an1017_over_socket_url_matches_the_in_process_model(served: ServedInThread) -> None:
    script = sensors_script(600)
    link = open_link(served.url, timeout_s=2.0)
    try:
        assert link.fileno() is not None  # a raw socket: the fd fast path, like a pty
        drives = lockstep(link, script)
        stats = link.stats
    finally:
        link.close()
    assert drives == reference_drives(script)
    assert len({(d.output_mode, d.state) for d in drives}) > 1  # the script does start the drive
    assert stats.frames_tx == stats.frames_rx == 601  # HostHello + 600 Sensors, TargetHello + 600 Drives
    assert stats.frame_errors == stats.seq_gaps == stats.timeouts == 0
    served.thread.join(timeout=10)  # the host hung up: serve returns, the helper closes its side
    assert served.error is None and served.report.sensors == 600


def test_socket_link_keeps_deadlines_and_counts_timeouts(served: ServedInThread) -> None:
    link = open_link(served.url, timeout_s=0.05)
    try:
        t0 = time.monotonic()
        with pytest.raises(LinkTimeout) as info:
            link.recv()  # nothing was asked: nothing comes
        waited = time.monotonic() - t0
        assert 0.05 <= waited < 2.0
        assert served.url in str(info.value) and link.stats.timeouts == 1
    finally:
        link.close()


def test_server_hang_up_is_link_closed() -> None:
    with TcpListener() as listener:
        link = open_link(listener.url, timeout_s=1.0)
        try:
            far = listener.accept(5.0)
            far.close()
            with pytest.raises(LinkClosed):
                link.recv()
        finally:
            link.close()


def test_accept_deadline_and_stop() -> None:
    with TcpListener() as listener:
        assert listener.url == f"socket://127.0.0.1:{listener.port}" and listener.port > 0
        with pytest.raises(LinkTimeout):
            listener.accept(0.05)
        stop = threading.Event()
        stop.set()
        with pytest.raises(LinkClosed):
            listener.accept(None, stop_event=stop)


@pytest.mark.parametrize("text, expected", [
    ("tcp:0", ("127.0.0.1", 0)),
    ("tcp:5000", ("127.0.0.1", 5000)),
    ("tcp:0.0.0.0:5000", ("0.0.0.0", 5000)),
    ("tcp:[::1]:65535", ("::1", 65535)),
])
def test_parse_tcp_listen(text: str, expected: tuple[str, int]) -> None:
    assert parse_tcp_listen(text) == expected


@pytest.mark.parametrize("text", ["tcp:", "tcp:x", "tcp:65536", "tcp:-1", "socket://127.0.0.1:5", "5000"])
def test_parse_tcp_listen_refuses(text: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_tcp_listen(text)
    assert repr(text) in str(info.value)


def test_nothing_listening_is_one_line_link_error() -> None:
    with TcpListener() as listener:
        url = listener.url  # a port that was free a moment ago; nobody listens once closed
    with pytest.raises(LinkError) as info:
        open_link(url, timeout_s=0.5)
    assert url in str(info.value) and "\n" not in str(info.value)


def test_lossy_socket_spec_gives_a_seeded_faulty_link(served: ServedInThread) -> None:
    """~1 % of bytes corrupted (bit error rate 0.01/8 = 0.00125) on the host side, by spec alone:
    every Drive that arrives is still exactly the model's, and every corrupted frame costs one."""
    link = open_link(served.url + "?corrupt=0.00125&fault_seed=11", timeout_s=0.02)
    assert isinstance(link, FaultyLink) and link.seed == 11
    script = sensors_script(300)
    expected = reference_drives(script)
    try:
        # a lost frame costs retry_s then timeout_s (0.07 s, the default retry_s made it 0.12 s); no
        # Sensors is sent again within them, so the seeded injector sees the same bytes either way
        remote = RemoteTarget(link, timeout_s=0.02, retry_s=0.05)
        remote.handshake(PERIOD_US, MODE_LOCKSTEP, 0, attempts=50)
        got = lost = 0
        for s, want in zip(script, expected):
            try:
                drive = remote.step(s)
            except LinkTimeout:
                lost += 1
                continue
            # a lost Sensors desynchronises nothing here: lockstep advances one period per frame
            # the target *receives*, so compare only while none was lost
            if lost == 0:
                assert drive == want
            got += 1
        injected = link.injected
        stats = link.stats
    finally:
        link.close()
    # 300 exchanges of ~35 wire bytes at ~1 % of bytes: about 100 frames hit; every one that
    # came back corrupted was refused and counted (a flipped delimiter can merge two into one)
    assert injected.corrupted_frames_rx > 0 and injected.corrupted_frames_tx > 0
    assert 2 * stats.frame_errors >= injected.corrupted_frames_rx
    # how many periods time out also depends on this busy VM's scheduling: only require some of each
    assert got + lost == len(script) and got > 0 and lost > 0


# -- rfc2217:// through pyserial's own RFC 2217 port manager ---------------------------------
class PtySerial(serial.Serial):
    """A pty slave as a pyserial port: a pty has no modem lines, so report them idle."""

    cts = dsr = ri = cd = property(lambda self: False)  # type: ignore[assignment]

    def _update_rts_state(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass

    def _update_break_state(self) -> None:
        pass


class Rfc2217Bridge:
    """A minimal RFC 2217 server (pyserial's PortManager, as in its rfc2217_server example):
    one TCP client <-> a local serial port. Here the port is a pty slave; the emulator is served
    on the pty master in another thread."""

    def __init__(self, port: serial.Serial) -> None:
        self.port = port
        self.listener = socket.create_server(("127.0.0.1", 0), backlog=1)
        self.url = f"rfc2217://127.0.0.1:{self.listener.getsockname()[1]}"
        self.alive = threading.Event()
        self.alive.set()
        self.conn: socket.socket | None = None
        self._lock = threading.Lock()
        self.thread = threading.Thread(target=self._accept, daemon=True)
        self.thread.start()
        self.reader: threading.Thread | None = None

    def write(self, data: bytes) -> None:  # PortManager's connection interface
        with self._lock:
            assert self.conn is not None
            self.conn.sendall(data)

    def _accept(self) -> None:
        self.listener.settimeout(20)
        conn, _ = self.listener.accept()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.settimeout(0.2)
        self.conn = conn
        manager = serial.rfc2217.PortManager(self.port, self)
        self.reader = threading.Thread(target=self._serial_to_net, args=(manager,), daemon=True)
        self.reader.start()
        while self.alive.is_set():
            try:
                data = conn.recv(4096)
            except socket.timeout:
                continue
            except OSError:
                break
            if not data:
                break
            self.port.write(b"".join(manager.filter(data)))
        self.alive.clear()

    def _serial_to_net(self, manager: Any) -> None:
        while self.alive.is_set():
            try:
                data = self.port.read(self.port.in_waiting or 1)
            except serial.SerialException:
                break
            if data:
                try:
                    self.write(b"".join(manager.escape(data)))
                except OSError:
                    break

    def close(self) -> None:
        self.alive.clear()
        self.thread.join(timeout=10)
        if self.reader is not None:
            self.reader.join(timeout=10)
        if self.conn is not None:
            self.conn.close()
        self.listener.close()


def test_an1017_over_rfc2217_matches_the_in_process_model() -> None:
    pty_link = open_link("pty", timeout_s=1.0)  # the emulator's end
    slave = PtySerial(pty_link.peer_path, baudrate=250_000, timeout=0.1)
    stop = threading.Event()
    target = make_target("an1017")
    server = threading.Thread(target=serve, args=(target, pty_link), kwargs={"stop_event": stop}, daemon=True)
    server.start()
    bridge = Rfc2217Bridge(slave)
    try:
        link = open_link(bridge.url + "?timeout=5", timeout_s=2.0)
        try:
            assert link.fileno() is None  # telnet-escaped: read through pyserial, not the fd
            script = sensors_script(300)
            t0 = time.monotonic()
            with pytest.raises(LinkTimeout):
                link.recv(0.05)  # the deadline holds through pyserial's reader thread too
            assert time.monotonic() - t0 < 2.0 and link.stats.timeouts == 1
            drives = lockstep(link, script)
            stats = link.stats
        finally:
            link.close()
    finally:
        bridge.close()
        stop.set()
        server.join(timeout=10)
        slave.close()
        pty_link.close()
    assert not server.is_alive()
    assert drives == reference_drives(script)
    assert stats.frames_rx == 301 and stats.frame_errors == 0 and stats.seq_gaps == 0


# -- the helper in a separate process, as `hilbench emulate NAME --port tcp:0` would run it ----
SERVE_CHILD = """
import sys
from hilbench.link import serve_tcp_once
from hilbench.targets import make_target
from hilbench.targets.serve import serve
target = make_target(sys.argv[1])
serve_tcp_once(0, lambda link: serve(target, link), accept_timeout_s=30.0,
               announce=lambda url: print(url, flush=True))
"""


def test_an1017_served_by_a_child_process_over_tcp() -> None:
    proc = subprocess.Popen([sys.executable, "-c", SERVE_CHILD, "an1017"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True)
    try:
        assert proc.stdout is not None
        ready, _, _ = select.select([proc.stdout], [], [], 30)
        assert ready, "the child announced no URL"
        url = proc.stdout.readline().strip()
        assert url.startswith("socket://127.0.0.1:")
        script = sensors_script(200)
        link = open_link(url, timeout_s=2.0)
        try:
            drives = lockstep(link, script)
        finally:
            link.close()
        assert drives == reference_drives(script)
        assert proc.wait(timeout=10) == 0  # the host hung up: serve returned, the child exited
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=10)
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()
