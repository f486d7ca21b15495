"""Links: every spec kind, pty raw mode and permissions, bulk reads, hang-up, stats, FaultyLink."""

from __future__ import annotations

import dataclasses
import fcntl
import math
import os
import socket
import stat
import termios

import pytest

from hilbench.errors import ConfigError, LinkClosed, LinkError, LinkTimeout
from hilbench.link import FaultyLink, Link, open_link, parse_target_spec
from hilbench.protocol import Drive, HostHello, Sensors, encode_frame


def _sensors(seq: int) -> Sensors:
    return Sensors(seq, 0x05, ((1234, 0x05),), 40000, (100, 200, 300))


@pytest.fixture
def pty_pair():
    host = open_link("pty", timeout_s=1.0)
    far = open_link(host.peer_path, timeout_s=1.0)
    try:
        yield host, far
    finally:
        far.close()
        host.close()


def test_pty_slave_is_raw_and_owner_only() -> None:
    link = open_link("pty", timeout_s=0.5)
    try:
        path = link.peer_path
        assert path is not None and path.startswith("/dev/")
        assert link.name == f"pty:{path}"
        mode = os.stat(path).st_mode
        assert stat.S_ISCHR(mode)
        assert stat.S_IMODE(mode) == 0o600
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        try:
            iflag, oflag, cflag, lflag, *_ , cc = termios.tcgetattr(fd)
            assert not lflag & (termios.ECHO | termios.ICANON | termios.ISIG)
            assert not oflag & termios.OPOST
            assert not iflag & (termios.ICRNL | termios.IXON)
            assert cflag & termios.CSIZE == termios.CS8
        finally:
            os.close(fd)
    finally:
        link.close()


def test_pty_round_trip_both_ways(pty_pair) -> None:
    host, far = pty_pair
    msg = _sensors(7)
    host.send(msg)
    assert far.recv() == msg
    reply = HostHello(3, 1, 1000, 0, 100)
    far.send(reply)
    assert host.recv() == reply


def test_serial_spec_with_baud_opens_a_tty() -> None:
    host = open_link("pty", timeout_s=0.5)
    link = open_link(f"serial:{host.peer_path}?baud=115200", timeout_s=0.5)
    try:
        link.send(_sensors(1))
        assert host.recv() == _sensors(1)
    finally:
        link.close()
        host.close()


def test_loop_url_echoes_frames() -> None:
    link = open_link("loop://", timeout_s=0.5)
    try:
        msgs = [_sensors(k) for k in range(5)]
        for m in msgs:
            link.send(m)
        assert [link.recv() for _ in msgs] == msgs
        assert link.stats.frames_rx == 5 and link.stats.frames_tx == 5
    finally:
        link.close()


def test_fd_spec_over_a_socketpair() -> None:
    a, b = socket.socketpair()
    link = open_link(f"fd:{a.detach()}", timeout_s=0.5)
    try:
        frame = encode_frame(_sensors(9))
        b.sendall(frame)
        assert link.recv() == _sensors(9)
        link.send(_sensors(10))
        assert b.recv(100) == encode_frame(_sensors(10))
    finally:
        link.close()
        b.close()


def test_missing_port_is_one_line_naming_it() -> None:
    with pytest.raises(LinkError) as info:
        open_link("serial:/dev/ttyNOPE_hilbench?baud=250000")
    text = str(info.value)
    assert "/dev/ttyNOPE_hilbench" in text and "\n" not in text


def test_busy_port_is_refused(pty_pair) -> None:
    host, _far = pty_pair  # _far holds an exclusive lock on the slave
    with pytest.raises(LinkError) as info:
        open_link(host.peer_path, timeout_s=0.5)
    assert host.peer_path in str(info.value) and "busy" in str(info.value)


@pytest.mark.parametrize("spec", ["bogus", "fd:x", "serial:", "serial:/dev/x?speed=3", "pty?baud=9600",
                                  "loop://?drop=2"])
def test_malformed_specs_are_config_errors(spec: str) -> None:
    with pytest.raises(ConfigError):
        open_link(spec)


def test_fd_not_open_is_a_link_error() -> None:
    with pytest.raises(LinkError) as info:
        open_link("fd:987654")
    assert "987654" in str(info.value)


def test_inprocess_has_no_link() -> None:
    with pytest.raises(ConfigError):
        open_link("inprocess:an1017")


def test_open_link_takes_a_parsed_spec() -> None:
    link = open_link(parse_target_spec("loop://"), timeout_s=0.5)
    try:
        link.send(_sensors(3))
        assert link.recv() == _sensors(3)
    finally:
        link.close()


@pytest.mark.parametrize("spec", ["emulator:an1017", "sil:an1017", "exec:/bin/cat"])
def test_process_kinds_open_a_pty_for_their_far_end(spec: str) -> None:
    host = open_link(spec, timeout_s=0.5)
    try:
        assert isinstance(host, Link) and host.peer_path is not None and host.peer_path.startswith("/dev/")
        far = open_link(host.peer_path, timeout_s=0.5)
        try:
            far.send(_sensors(4))
            assert host.recv() == _sensors(4)
        finally:
            far.close()
    finally:
        host.close()


def test_spy_url_reads_a_tty_through_pyserial_with_deadlines(tmp_path) -> None:
    """spy:// wraps a tty in pyserial's logger: read through pyserial, same frames, same deadlines."""
    host = open_link("pty", timeout_s=0.5)
    log = tmp_path / "spy.txt"
    link = open_link(f"spy://{host.peer_path}?file={log}", timeout_s=0.05)
    try:
        assert link.fileno() is None
        with pytest.raises(LinkTimeout):
            link.recv()
        assert link.stats.timeouts == 1
        for k in range(20):
            host.send(_sensors(k))
        assert [link.recv(1.0).seq for _ in range(20)] == list(range(20))
        link.send(_sensors(99))
        assert host.recv() == _sensors(99)
        assert link.stats.frames_rx == 20 and link.stats.frames_tx == 1
    finally:
        link.close()
        host.close()
    assert "RX" in log.read_text() or "read" in log.read_text()


def test_reads_are_bulk(pty_pair, monkeypatch) -> None:
    """Three frames written at once arrive with one read: all bytes are in after the first recv."""
    host, far = pty_pair
    far_fd = far.fileno()
    reads: list[int] = []
    real_read = os.read

    def counting_read(fd: int, n: int) -> bytes:
        data = real_read(fd, n)
        if fd == far_fd:
            reads.append(len(data))
        return data

    monkeypatch.setattr(os, "read", counting_read)
    wire = b"".join(encode_frame(_sensors(k)) for k in range(3))
    host.send_bytes(wire, frames=3)
    assert far.recv() == _sensors(0)
    assert far.stats.bytes_rx == len(wire)
    assert far.recv() == _sensors(1) and far.recv() == _sensors(2)
    assert reads == [len(wire)]


def test_timeout_is_counted_and_names_the_link(pty_pair) -> None:
    host, _ = pty_pair
    with pytest.raises(LinkTimeout) as info:
        host.recv(timeout_s=0.05)
    assert host.name in str(info.value)
    assert host.stats.timeouts == 1
    assert host.recv_or_none(0.01) is None
    assert host.stats.timeouts == 1


def test_far_end_hang_up_is_link_closed(pty_pair) -> None:
    host, far = pty_pair
    far.send(_sensors(1))
    assert host.recv() == _sensors(1)  # the far end has spoken: our slave copy is released
    far.close()
    with pytest.raises(LinkClosed) as info:
        host.recv(timeout_s=1.0)
    assert host.name in str(info.value)


def test_near_end_hang_up_seen_by_far_end(pty_pair) -> None:
    host, far = pty_pair
    host.send(_sensors(1))
    assert far.recv() == _sensors(1)
    host.close()
    with pytest.raises(LinkClosed):
        far.recv(timeout_s=1.0)


def test_stats_count_crc_errors_resyncs_and_seq_gaps(pty_pair) -> None:
    host, far = pty_pair
    good = encode_frame(_sensors(254))
    bad = bytearray(encode_frame(_sensors(255)))
    bad[3] ^= 0x10  # one flipped bit inside the frame
    wire = good + bytes(bad) + encode_frame(_sensors(0)) + encode_frame(_sensors(2))
    host.send_bytes(wire, frames=4)
    got = [far.recv(), far.recv(), far.recv()]
    assert [m.seq for m in got] == [254, 0, 2]
    stats = far.stats
    assert stats.crc_errors + stats.cobs_errors + stats.length_errors == 1
    assert stats.frame_errors == 1
    assert stats.resyncs == 1
    assert stats.seq_gaps == 2  # 254 -> 0 skips 255, 0 -> 2 skips 1; the u8 wrap itself is no gap
    assert stats.bytes_rx == len(wire)
    assert host.stats.frames_tx == 4 and host.stats.bytes_tx == len(wire)


def test_seq_wrap_is_not_a_gap(pty_pair) -> None:
    host, far = pty_pair
    for seq in (254, 255, 0, 1):
        host.send(_sensors(seq))
    for _ in range(4):
        far.recv()
    assert far.stats.seq_gaps == 0


def test_writes_to_a_stalled_far_end_time_out() -> None:
    link = open_link("pty", timeout_s=0.05)
    try:
        with pytest.raises(LinkTimeout):
            for k in range(100_000):  # nobody reads the slave: the pty buffer fills
                link.send(_sensors(k & 0xFF))
    finally:
        link.close()


# -- fault injection -----------------------------------------------------------------------
def _faulty_stream(seed: int, n: int = 400, **faults) -> tuple[bytes, object]:
    """Send n frames through a FaultyLink over loop:// and return the wire bytes that came out."""
    inner = open_link("loop://", timeout_s=0.2)
    faulty = FaultyLink(inner, seed, **faults)
    try:
        out = bytearray()
        port = inner.transport._port  # loop:// holds only a few kB: drain after every frame
        for k in range(n):
            faulty.send(_sensors(k & 0xFF))
            while port.in_waiting:
                out += port.read(port.in_waiting)
        return bytes(out), faulty.injected
    finally:
        faulty.close()


def test_faulty_link_is_deterministic_by_seed() -> None:
    faults = dict(corrupt_bit_rate=0.002, drop_rate=0.05, duplicate_rate=0.05, corrupt_direction="tx")
    a, ca = _faulty_stream(1, **faults)
    b, cb = _faulty_stream(1, **faults)
    c, _ = _faulty_stream(2, **faults)
    assert a == b and ca == cb
    assert a != c


def test_faulty_link_corruption_counts_match_the_bytes() -> None:
    """Compare the corrupted stream with the clean one bit by bit: the counts must agree."""
    clean = b"".join(encode_frame(_sensors(k & 0xFF)) for k in range(2000))
    out, counts = _faulty_stream(5, n=2000, corrupt_bit_rate=0.01 / 8, corrupt_direction="tx")
    assert len(out) == len(clean)
    flipped_bits = sum(bin(x ^ y).count("1") for x, y in zip(out, clean))
    flipped_bytes = sum(1 for x, y in zip(out, clean) if x != y)
    frames = clean.split(b"\x00")[:-1]
    start, bad_frames = 0, 0
    for f in frames:
        end = start + len(f) + 1
        bad_frames += out[start:end] != clean[start:end]
        start = end
    assert counts.corrupted_bits_tx == flipped_bits
    assert counts.corrupted_bytes_tx == flipped_bytes
    assert counts.corrupted_frames_tx == bad_frames
    # about 1 % of bytes: binomial mean n*p, well inside 6 sigma
    n_bytes, p = len(clean), 1 - (1 - 0.01 / 8) ** 8
    mean, sigma = n_bytes * p, (n_bytes * p * (1 - p)) ** 0.5
    assert abs(flipped_bytes - mean) < 6 * sigma


def test_faulty_link_drop_duplicate_silence() -> None:
    out, counts = _faulty_stream(3, n=1000, drop_rate=0.1, duplicate_rate=0.1)
    assert out.count(b"\x00") == 1000 - counts.dropped + counts.duplicated
    assert 50 < counts.dropped < 150 and 50 < counts.duplicated < 150
    out, counts = _faulty_stream(3, n=50, silent_after=20)
    assert out == b"".join(encode_frame(_sensors(k)) for k in range(20))
    assert counts.silenced == 30


def test_faulty_link_corrupts_received_bytes(pty_pair) -> None:
    host, far = pty_pair
    faulty = FaultyLink(far, 11, corrupt_bit_rate=0.05, corrupt_direction="rx")
    for k in range(200):
        host.send(_sensors(k & 0xFF))
    got = []
    while (m := faulty.recv_or_none(0.2)) is not None:
        got.append(m)
    assert all(m == _sensors(m.seq) for m in got)  # nothing corrupted is accepted
    counts = faulty.injected
    assert counts.corrupted_frames_rx > 0
    assert len(got) <= 200 - counts.corrupted_frames_rx
    assert far.stats.frame_errors > 0


def test_lossy_spec_gives_a_seeded_faulty_link_with_its_rates() -> None:
    """~1 % of bytes corrupted by spec alone (bit error rate 0.01/8): a FaultyLink with exactly
    those options, whose counts are deterministic for the seed and match the bytes bit by bit."""
    n = 2000
    clean = b"".join(encode_frame(_sensors(k & 0xFF)) for k in range(n))

    def run(spec: str) -> tuple[bytes, object]:
        link = open_link(spec, timeout_s=0.2)
        assert isinstance(link, FaultyLink)
        assert (link.seed, link._tx_bits.log_keep) == (5, math.log1p(-0.00125))
        assert link._rx_bits.log_keep == 0.0  # corrupt_dir=tx
        assert (link.drop_rate, link.duplicate_rate, link.delay_s, link.silent_after) == (0.0, 0.0, 0.0, None)
        out = bytearray()
        port = link.inner.transport._port
        try:
            for k in range(n):
                link.send(_sensors(k & 0xFF))
                while port.in_waiting:
                    out += port.read(port.in_waiting)
            return bytes(out), dataclasses.replace(link.injected)
        finally:
            link.close()

    spec = "loop://?corrupt=0.00125&corrupt_dir=tx&fault_seed=5"
    out, counts = run(spec)
    again, counts_again = run(spec)
    assert (out, counts) == (again, counts_again)
    assert counts.corrupted_bits_tx == sum(bin(x ^ y).count("1") for x, y in zip(out, clean))
    assert counts.corrupted_bytes_tx == sum(1 for x, y in zip(out, clean) if x != y)
    p = 1 - (1 - 0.00125) ** 8  # a byte is hit when any of its 8 bits is
    mean, sigma = len(clean) * p, (len(clean) * p * (1 - p)) ** 0.5
    assert abs(counts.corrupted_bytes_tx - mean) < 6 * sigma


def test_faulty_link_rejects_bad_rates() -> None:
    link = open_link("loop://")
    try:
        with pytest.raises(ValueError):
            FaultyLink(link, 0, corrupt_bit_rate=1.5)
        with pytest.raises(ValueError):
            FaultyLink(link, 0, corrupt_direction="sideways")
    finally:
        link.close()


def test_drive_round_trip_keeps_every_field(pty_pair) -> None:
    host, far = pty_pair
    d = Drive(200, 1023, 0, 512, 1, 2, 5, True, False, 0, (-32768, 32767, 200))
    far.send(d)
    assert host.recv() == d


def test_link_fd_is_nonblocking(pty_pair) -> None:
    host, _ = pty_pair
    fd = host.fileno()
    assert fd is not None
    assert fcntl.fcntl(fd, fcntl.F_GETFL) & os.O_NONBLOCK


def test_one_frame_per_read_counts_like_the_decoder(pty_pair) -> None:
    """Frames that arrive one per read (the fast path) are counted, and a bad frame arriving alone
    still counts as an error, with the resync counted at the next good frame."""
    host, far = pty_pair
    bad = bytearray(encode_frame(_sensors(2)))
    bad[4] ^= 0x01
    host.send(_sensors(1))
    assert far.recv() == _sensors(1)
    host.send_bytes(bytes(bad), frames=1)
    with pytest.raises(LinkTimeout):
        far.recv(timeout_s=0.2)  # the bad frame is not a message
    host.send(_sensors(3))
    assert far.recv() == _sensors(3)
    host.send(_sensors(4))
    assert far.recv() == _sensors(4)
    stats = far.stats
    assert stats.frames_rx == 3
    assert stats.frame_errors == 1
    assert stats.resyncs == 1
    assert stats.seq_gaps == 1  # 1 -> 3
    assert stats.bytes_rx == 3 * len(encode_frame(_sensors(1))) + len(bad)


def test_frame_split_across_reads_is_reassembled(pty_pair) -> None:
    host, far = pty_pair
    wire = encode_frame(_sensors(9))
    host.send_bytes(wire[:5], frames=0)
    assert far.recv_or_none(0.1) is None  # half a frame is not a message
    host.send_bytes(wire[5:] + encode_frame(_sensors(10))[:3], frames=1)
    assert far.recv() == _sensors(9)
    host.send_bytes(encode_frame(_sensors(10))[3:], frames=1)
    assert far.recv() == _sensors(10)
    host.send(_sensors(11))
    assert far.recv() == _sensors(11)
    assert far.stats.frames_rx == 3 and far.stats.frame_errors == 0 and far.stats.seq_gaps == 0


def test_recv_without_timeout_blocks_for_frames_and_sees_hang_up(pty_pair) -> None:
    """recv_or_none(None) (the lockstep server's wait): whole frames, split frames, then hang-up.
    Everything it needs is written before it is called, so it never waits on a live writer."""
    host, far = pty_pair
    wire = encode_frame(_sensors(1)) + encode_frame(_sensors(2))[:4]
    host.send_bytes(wire, frames=1)
    assert far.recv_or_none(None) == _sensors(1)
    host.send_bytes(encode_frame(_sensors(2))[4:], frames=1)
    assert far.recv_or_none(None) == _sensors(2)
    far.send(_sensors(3))  # writes still work on the now blocking fd
    assert host.recv() == _sensors(3)
    assert far.recv_or_none(0.01) is None  # a timeout again: non-blocking again
    assert not os.get_blocking(far.fileno())
    host.close()
    with pytest.raises(LinkClosed):
        far.recv_or_none(None)


def test_a_raw_ttys_empty_read_is_no_hang_up_but_a_pipes_is() -> None:
    """A raw tty (VMIN 0, VTIME 0) reads 0 bytes when nothing is waiting, as after a poll whose
    wake-up another reader of the same pty answered first; its end is EIO or POLLHUP. A pipe's 0
    bytes are its end of file."""
    import tty

    from hilbench.link.transport import FdTransport

    master, slave = os.openpty()
    tty.setraw(slave)
    attrs = termios.tcgetattr(slave)
    attrs[6][termios.VMIN], attrs[6][termios.VTIME] = 0, 0
    termios.tcsetattr(slave, termios.TCSANOW, attrs)
    link = Link(FdTransport(slave, "pty"), "pty")
    try:
        assert os.read(slave, 64) == b""  # the premise: nothing waiting reads as 0 bytes
        assert link._data_or_eof(b"") is False
        assert link.recv_or_none(0.01) is None
        os.close(master)
        master = -1
        with pytest.raises(LinkClosed):  # the far end's close, with no time left to wait: the fast path's
            link.recv_or_none(0)
        with pytest.raises(LinkClosed):  # and the transport's (EIO / POLLHUP)
            link.recv_or_none(0.5)
    finally:
        link.close()
        if master >= 0:
            os.close(master)
    master, slave = os.openpty()  # the master's side: its far end (the slave) closes, EIO
    tty.setraw(slave)
    link = Link(FdTransport(master, "ptmx"), "ptmx")
    try:
        os.close(slave)
        with pytest.raises(LinkClosed):
            link.recv_or_none(0)
    finally:
        link.close()
    r, w = os.pipe()
    pipe = Link(FdTransport(r, "pipe"), "pipe")
    try:
        os.close(w)
        with pytest.raises(LinkClosed, match="end of file"):
            pipe._data_or_eof(b"")
        with pytest.raises(LinkClosed):
            pipe.recv_or_none(0.5)
    finally:
        pipe.close()
