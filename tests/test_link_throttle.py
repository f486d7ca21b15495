"""The wire-time throttle (`?wire_baud=N`, hilbench.link.throttle) on a virtual clock.

Expected times are the UART's arithmetic written out here: 8N1 is 10 bits a byte, so at 250 000
baud a byte takes 40 us; the two directions are independent. No wall time is measured: the inner
transport is a script on a virtual clock that its own waits advance.
"""

from __future__ import annotations

import pytest

from hilbench.errors import ConfigError
from hilbench.link import parse_target_spec
from hilbench.link.link import Link
from hilbench.link.throttle import ThrottledTransport
from hilbench.link.transport import Transport
from hilbench.protocol import Drive, Sensors

BYTE_250K_S = 10 / 250_000  # 40 us


class VirtualWire(Transport):
    """An inner transport on a virtual clock: the far end's bytes arrive at scripted times (or, with
    `answer`, a fixed time after each of our writes); a read's wait advances the clock."""

    name = "virtual"

    def __init__(self) -> None:
        self.now = 0.0
        self.arrivals: list[tuple[float, bytes]] = []
        self.written: list[tuple[float, bytes]] = []
        self.answer: bytes | None = None

    def clock(self) -> float:
        return self.now

    def read(self, timeout_s: float | None) -> bytes:
        ready = [a for a in self.arrivals if a[0] <= self.now]
        if not ready:
            upcoming = min((t for t, _ in self.arrivals), default=None)
            limit = self.now + (timeout_s if timeout_s is not None else 1e9)
            if upcoming is None or upcoming > limit:
                self.now = limit
                return b""
            self.now = upcoming
            ready = [a for a in self.arrivals if a[0] <= self.now]
        for a in ready:
            self.arrivals.remove(a)
        return b"".join(data for _, data in ready)

    def write(self, data: bytes, timeout_s: float) -> None:
        self.written.append((self.now, data))
        if self.answer is not None and data.endswith(b"\x00"):
            self.arrivals.append((self.now, self.answer))  # the far end answers at once

    def close(self) -> None:
        pass


def _throttled(baud: int = 250_000) -> tuple[VirtualWire, ThrottledTransport]:
    wire = VirtualWire()
    return wire, ThrottledTransport(wire, baud, clock=wire.clock)


def test_a_write_reaches_the_far_end_at_the_wire_time_of_its_last_byte() -> None:
    wire, t = _throttled()
    t.write(b"x" * 19, 1.0)
    t.write(b"y" * 10, 1.0)  # queued behind the first on the same wire
    assert wire.written == [] and wire.now == 0.0  # a write returns at once, as into a tty's buffer
    assert t.read(1.0) == b""  # the wait hands each over at its time
    assert wire.written[0] == (pytest.approx(19 * BYTE_250K_S), b"x" * 19)
    assert wire.written[1] == (pytest.approx(29 * BYTE_250K_S), b"y" * 10)
    assert t.wire_bytes_tx == 29


def test_an_idle_wire_starts_a_write_when_it_is_made() -> None:
    wire, t = _throttled(1_250_000)
    wire.now = 5.0
    t.write(b"z" * 5, 1.0)
    t.flush()
    assert wire.written[0][0] == pytest.approx(5.0 + 5 * 10 / 1_250_000)


def test_a_write_waits_only_while_the_buffer_is_full() -> None:
    from hilbench.link.throttle import TX_BUFFER_BYTES

    wire, t = _throttled()
    t.write(b"a" * TX_BUFFER_BYTES, 1.0)
    assert wire.now == 0.0
    t.write(b"b" * 100, 1.0)  # 100 bytes over: it waits until the first 100 bytes' worth has gone
    assert wire.now == pytest.approx(TX_BUFFER_BYTES * BYTE_250K_S)
    assert wire.written == [(pytest.approx(TX_BUFFER_BYTES * BYTE_250K_S), b"a" * TX_BUFFER_BYTES)]


def test_received_bytes_are_delivered_no_earlier_than_their_wire_time() -> None:
    wire, t = _throttled()
    wire.arrivals = [(1.0, b"a" * 23), (1.0, b"b" * 2)]
    assert t.read(0.5) == b""  # nothing written yet at 0.5 s
    assert wire.now == pytest.approx(0.5)
    data = t.read(2.0)
    assert data == b"a" * 23 + b"b" * 2  # written together: one chunk of 25 bytes on the wire
    assert wire.now == pytest.approx(1.0 + 25 * BYTE_250K_S)


def test_back_to_back_chunks_queue_on_the_return_wire() -> None:
    wire, t = _throttled()
    wire.arrivals = [(0.0, b"a" * 10)]
    assert t.read(1.0) == b"a" * 10
    assert wire.now == pytest.approx(10 * BYTE_250K_S)
    wire.arrivals = [(wire.now, b"b" * 10)]  # written the instant the first was delivered
    assert t.read(1.0) == b"b" * 10
    assert wire.now == pytest.approx(20 * BYTE_250K_S)


def test_a_read_returns_empty_at_its_deadline_while_bytes_are_still_on_the_wire() -> None:
    wire, t = _throttled(9600)
    wire.arrivals = [(0.0, b"q" * 96)]  # 0.1 s on the wire
    assert t.read(0.05) == b""
    assert wire.now == pytest.approx(0.05)
    assert t.read(1.0) == b"q" * 96
    assert wire.now == pytest.approx(0.1)


def test_the_two_directions_are_independent_full_duplex() -> None:
    wire, t = _throttled()
    wire.arrivals = [(0.0, b"r" * 50)]  # the far end sends while we send
    t.write(b"w" * 50, 1.0)
    assert t.read(1.0) == b"r" * 50  # delivered at 50 byte times, not 100
    assert wire.now == pytest.approx(50 * BYTE_250K_S)
    assert wire.written[0][0] == pytest.approx(50 * BYTE_250K_S)


def test_per_period_lockstep_behind_250_kbaud_is_held_to_the_wire_rate() -> None:
    """The issue's bound: a Sensors and its Drive one after the other, 10 bits a byte: at most
    250000 / (10 * (19 + 23)) = 595 exchanges a second with protocol 3's frames (the issue's 676
    counted protocol 2's 17 + 20 bytes), however fast the far end answers."""
    wire, t = _throttled()
    drive = Drive(seq=0, duty_a=1, duty_b=2, duty_c=3, output_mode=1, state=2, sector=1,
                  direction_ccw=False, required_ccw=False, fault=0, telemetry=(1, 2, 3))
    from hilbench.protocol import encode_frame

    wire.answer = encode_frame(drive)
    link = Link(t, "virtual", timeout_s=1.0)
    sensors = Sensors(seq=0, inputs=1, edges=(), encoder=0, adc=(512, 0, 0))
    assert len(encode_frame(sensors)) == 19 and len(wire.answer) == 23
    n = 100
    for k in range(n):
        link.send(sensors._replace(seq=k))
        assert type(link.recv(1.0)) is Drive
    rate = n / wire.now
    assert rate == pytest.approx(250_000 / (10 * 42))
    assert rate <= 676


def test_wire_baud_is_a_key_of_every_spec_with_a_link() -> None:
    assert parse_target_spec("sil:an1017?wire_baud=250000").wire_baud == 250_000
    assert parse_target_spec("pty?wire_baud=9600").wire_baud == 9600
    assert parse_target_spec("socket://127.0.0.1:5000?wire_baud=1250000&baud=9600").wire_baud == 1_250_000
    assert parse_target_spec("sil:an1017").wire_baud is None
    spec = parse_target_spec("emulator:an1017?wire_baud=250000&drop=0.1")
    assert spec.wire_baud == 250_000 and spec.faults is not None and spec.faults.drop_rate == 0.1
    assert parse_target_spec("simavr:an1017?twin=auto").twin == "auto"
    assert parse_target_spec("/dev/ttyUSB0?baud=250000&twin=off").twin == "off"


@pytest.mark.parametrize("text, says", [
    ("sil:an1017?wire_baud=0", "wire_baud='0' must be a positive whole number"),
    ("sil:an1017?wire_baud=fast", "is not a whole number"),
    ("inprocess:an1017?wire_baud=250000", "an in-process target has no link"),
    ("sil:an1017?wire_bauds=250000", "did you mean 'wire_baud'"),
    ("sil:an1017?twin=on", "twin='on' must be auto or off"),
])
def test_bad_wire_baud_is_one_config_line(text: str, says: str) -> None:
    with pytest.raises(ConfigError, match=says.replace("(", r"\(")) as info:
        parse_target_spec(text)
    assert "\n" not in str(info.value)


def test_a_throttled_pty_carries_frames_to_a_real_far_end() -> None:
    """The throttle around a real pty: the bytes arrive whole and in order at the far end."""
    import os

    from hilbench.link import open_link
    from hilbench.protocol import FrameDecoder, encode_frame

    link = open_link("pty?wire_baud=1000000", timeout_s=1.0)
    try:
        far = os.open(link.peer_path, os.O_RDWR | os.O_NOCTTY)
        try:
            sensors = Sensors(seq=3, inputs=5, edges=(), encoder=0, adc=(1, 2, 3))
            link.send(sensors)
            link.transport.flush()  # no read follows to hand it over at its time: wait for it here
            got = b""
            decoder = FrameDecoder()
            frames: list[object] = []
            import select

            while not frames:
                ready, _, _ = select.select([far], [], [], 5.0)
                assert ready, "no bytes at the far end in 5 s"
                got += os.read(far, 256)
                frames = decoder.feed(got) if got.endswith(b"\x00") else []
            assert frames == [sensors]
            os.write(far, encode_frame(sensors._replace(seq=4)))
            assert link.recv(5.0) == sensors._replace(seq=4)
        finally:
            os.close(far)
    finally:
        link.close()


def test_a_far_end_far_ahead_of_its_wire_loses_the_excess_and_memory_stays_bounded() -> None:
    """A far end that writes 1 MB at once (faster than any UART): the throttle holds at most
    RX_AHEAD_BYTES for their wire time, counts the rest as an overrun, and delivers what it kept
    in order at the wire's pace."""
    from hilbench.link.throttle import RX_AHEAD_BYTES

    wire, link = _throttled()
    data = bytes(range(256)) * 4096  # 1 MiB
    wire.arrivals.append((0.0, data))
    first = link.read(0.0)
    assert first == b"" and link.rx_overrun_bytes == len(data) - RX_AHEAD_BYTES
    got = link.read(BYTE_250K_S * RX_AHEAD_BYTES + 1.0)
    assert got == data[:RX_AHEAD_BYTES]  # what was kept, in order, when its last bit has come
    assert wire.now == pytest.approx(BYTE_250K_S * RX_AHEAD_BYTES)
    wire.arrivals.append((wire.now, b"\xff" * 10))  # room again: nothing more is lost
    assert link.read(1.0) == b"\xff" * 10
    assert link.rx_overrun_bytes == len(data) - RX_AHEAD_BYTES


def test_a_close_at_a_few_baud_sends_what_is_due_soon_and_drops_the_rest() -> None:
    """Repro: `link-test 'emulator:loopback?wire_baud=1'` hung in its close, waiting out the wire
    time of every queued retry (10 s a byte at 1 baud). The close waits CLOSE_FLUSH_S at most."""
    from hilbench.link.throttle import CLOSE_FLUSH_S

    wire, t = _throttled(10)  # 1 s a byte
    t.write(b"ab", 1.0)
    t.write(b"c" * 100, 1.0)
    t.close()
    assert wire.written == [(pytest.approx(2.0), b"ab")] and wire.now <= CLOSE_FLUSH_S + 1e-9
