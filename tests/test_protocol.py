"""Wire protocol (Python codec): round trips, frame sizes, hand-derived bytes, robustness to bad input.

Expectations come from the CRC-16/CCITT-FALSE catalogue check value, the COBS examples of Cheshire &
Baker, an independent bitwise CRC and COBS written here, and the layout fixed in docs/design.md.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hilbench.errors import DecodeError, ProtocolError
from hilbench.protocol import (
    PROTOCOL_VERSION,
    Drive,
    ErrorReport,
    FrameDecoder,
    HostHello,
    ParamDescribe,
    ParamGet,
    ParamInfo,
    ParamSet,
    ParamSetResult,
    ParamValue,
    Sensors,
    Start,
    Status,
    StatusRequest,
    Stop,
    TargetDescribe,
    TargetHello,
    TargetInfo,
    TelemetryDescribe,
    TelemetryInfo,
    decode_frame,
    encode_frame,
)
from hilbench.protocol.framing import cobs_decode, cobs_encode, crc16
from reference_codec import crc16 as ref_crc, wire as ref_wire  # independent

REPO = Path(__file__).resolve().parent.parent

u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFFFFFF)
i16 = st.integers(-0x8000, 0x7FFF)
i32 = st.integers(-0x80000000, 0x7FFFFFFF)
name = st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7E), max_size=16)
unit = st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7E), max_size=8)
edges = st.lists(st.tuples(u16, u8), max_size=16).map(tuple)

MESSAGES = st.one_of(
    st.builds(HostHello, u8, u8, u16, u8, u16, u32),
    st.builds(TargetHello, u8, u8, u32, u16, u16, u32, u8, u8, name,
              st.lists(u8, max_size=8).map(tuple), st.lists(u8, max_size=8).map(tuple)),
    st.builds(Sensors, u8, u8, edges, u16, st.lists(u16, max_size=8).map(tuple)).filter(
        lambda m: 2 * len(m.adc) + 3 * len(m.edges) <= 56),  # 62 bytes a message
    st.builds(Drive, u8, u16, u16, u16,
              st.integers(0, 3), st.integers(0, 7), st.integers(0, 7), st.booleans(), st.booleans(),
              st.integers(0, 63),
              st.lists(i16, max_size=8).map(tuple)),
    st.builds(ParamDescribe, u8, u8),
    st.builds(ParamInfo, u8, u8, u8, u8, i32, i32, i32, name, unit).filter(
        lambda m: len(m.name) + len(m.unit) <= 42),
    st.builds(ParamGet, u8, u8),
    st.builds(ParamValue, u8, u8, u8, i32),
    st.builds(ParamSet, u8, st.lists(st.tuples(u8, i32), max_size=4).map(tuple)),
    st.builds(ParamSetResult, u8, u8, u8, u8),
    st.builds(Start, u8),
    st.builds(Stop, u8),
    st.builds(StatusRequest, u8),
    st.builds(Status, u8, u16, u16, u16, u16, u16, u16, u8),
    st.builds(ErrorReport, u8, u8, u8, u32),
    st.builds(TelemetryDescribe, u8, u8),
    st.builds(TelemetryInfo, u8, u8, u8, u8, i32, i32, name, unit),
    st.builds(TargetDescribe, u8),
    st.builds(TargetInfo, u8, u8, u8, u8, u16, u8),
)


def test_crc_check_value() -> None:
    assert crc16(b"123456789") == 0x29B1
    assert ref_crc(b"123456789") == 0x29B1


@pytest.mark.parametrize(
    ("raw", "enc"),
    [
        (b"\x00", b"\x01\x01"),
        (b"\x00\x00", b"\x01\x01\x01"),
        (b"\x11\x22\x00\x33", b"\x03\x11\x22\x02\x33"),
        (b"\x11\x22\x33\x44", b"\x05\x11\x22\x33\x44"),
        (b"\x11\x00\x00\x00", b"\x02\x11\x01\x01\x01"),
    ],
)
def test_cobs_examples(raw: bytes, enc: bytes) -> None:
    assert cobs_encode(raw) == enc
    assert cobs_decode(enc) == raw


def test_sensors_bytes_by_hand() -> None:
    msg = Sensors(seq=5, inputs=0x0B, edges=((1234, 3), (4000, 1)), encoder=0xFFFF, adc=(512, 0, 1023))
    # wire order: inputs u8, encoder u16, adc (u8 count, u16 each), edges (u16 time, u8 lines) to the end
    raw = bytes([0x10, 5, 0x0B, 0xFF, 0xFF, 3, 0x00, 0x02, 0x00, 0x00, 0xFF, 0x03,
                 0xD2, 0x04, 3, 0xA0, 0x0F, 1])
    assert encode_frame(msg) == ref_wire(raw)
    assert len(encode_frame(msg)) == 18 + 7
    assert len(encode_frame(msg._replace(edges=()))) == 12 + 7


def test_drive_bit_layout_by_hand() -> None:
    msg = Drive(seq=200, duty_a=7500, duty_b=2, duty_c=0xFFFF, output_mode=1, state=2, sector=5,
                direction_ccw=True, required_ccw=False, fault=4, telemetry=(-1, 2, -32768))
    # duties u16 LE; flags u16: mode 0-1, state 2-4, sector 5-7, ccw 8, required 9, fault 10-15
    flags = 1 | 2 << 2 | 5 << 5 | 1 << 8 | 4 << 10
    assert flags == 0x11A9
    raw = bytes([0x11, 200, 0x4C, 0x1D, 0x02, 0x00, 0xFF, 0xFF, 0xA9, 0x11, 0xFF, 0xFF, 0x02, 0x00, 0x00, 0x80])
    assert encode_frame(msg) == ref_wire(raw)
    assert len(encode_frame(msg)) == 16 + 7


def test_frame_layout_by_hand() -> None:
    """Start(seq=1): COBS(L 30 01 L) . T0 T1 T2 . 00 with L = 8, the CRC-16/CCITT-FALSE of the four
    COBS bytes computed bit by bit, seven bits a check byte with the top bit set."""
    cobs = bytes([0x05, 0x08, 0x30, 0x01, 0x08])
    crc = ref_crc(cobs)
    t = (0x80 | crc >> 9, 0x80 | (crc >> 2) & 0x7F, 0x80 | (crc & 3) << 5)
    assert encode_frame(Start(1)) == cobs + bytes(t) + b"\x00"
    assert len(encode_frame(Start(1))) == 9


def test_an1017_profile_fits_the_budget() -> None:
    """1 kHz full duplex at 250 000 baud: 25 bytes per period per direction. A Sensors with one hall edge
    and a Drive with three telemetry values take 22 and 23 (92 %); a period without an edge 19."""
    sensors = encode_frame(Sensors(0xFF, 0xFF, ((0xFFFF, 7),), 0xFFFF, (1023, 1023, 1023)))
    drive = encode_frame(Drive(0xFF, 1000, 1000, 1000, 3, 7, 7, True, True, 63, (-1, -1, -1)))
    assert len(sensors) == 22
    assert len(drive) == 23
    assert max(len(sensors), len(drive)) <= 250_000 / 10 / 1000


@settings(max_examples=1500, suppress_health_check=[HealthCheck.too_slow])
@given(MESSAGES)
def test_round_trip(msg) -> None:
    wire = encode_frame(msg)
    assert wire[-1] == 0 and 0 not in wire[:-1]
    assert len(wire) <= 62 + 7
    assert decode_frame(wire[:-1]) == msg
    decoder = FrameDecoder()
    assert decoder.feed(wire) == [msg]
    assert decoder.counters["frames"] == 1


def test_round_trip_gives_bools_and_tuples() -> None:
    d = decode_frame(encode_frame(Drive(1, 0, 0, 0, 0, 0, 0, True, False, 0, (5,)))[:-1])
    assert d.direction_ccw is True and d.required_ccw is False and d.telemetry == (5,)


@pytest.mark.parametrize(
    "msg",
    [
        Drive(0, 0x10000, 0, 0, 0, 0, 0, False, False, 0, ()),
        Drive(0, -1, 0, 0, 0, 0, 0, False, False, 0, ()),
        Drive(0, 0, 0, 0, 4, 0, 0, False, False, 0, ()),
        Drive(0, 0, 0, 0, 0, 0, 0, False, False, 64, ()),
        Drive(0, 0, 0, 0, 0, 8, 0, False, False, 0, ()),
        Drive(0, 0, 0, 0, 0, 0, 0, False, False, 0, (0,) * 9),
        Sensors(256, 0, (), 0, ()),
        Sensors(0, 0, (), 0x10000, ()),
        Sensors(0, 0, (), 0, (-1,)),
        Sensors(0, 0, ((0x10000, 0),), 0, ()),
        Sensors(0, 0, ((0, 256),), 0, ()),
        Sensors(0, 0, ((0, 0),) * 17, 0, ()),
        Sensors(0, 0, ((0, 0),) * 16, 0, (0,) * 5),  # 64 bytes: more than a frame holds
        ParamSet(0, ((0, 0),) * 5),
        ParamSet(0, ((0, 2**31),)),
        ParamInfo(0, 0, 0, 0, 0, 0, 0, "x" * 17),
        ParamInfo(0, 0, 0, 0, 0, 0, 0, "x", "u" * 9),
        ParamValue(0, 0, 0, -2**31 - 1),
        HostHello(0, 2, 1000, 0, 0, 2**32),
        TargetHello(0, 1, 0, 1, 1, 1, 0, 10, "caf\u00e9", (), ()),
        TelemetryInfo(0, 0, 0, 0, 2**31, 1, "x", ""),
        ("not", "a", "message"),
    ],
)
def test_unencodable_messages_raise_protocol_error(msg) -> None:
    with pytest.raises(ProtocolError):
        encode_frame(msg)


@settings(max_examples=800)
@given(st.binary(max_size=80))
def test_garbage_raises_only_decode_error(data: bytes) -> None:
    try:
        decode_frame(data)
    except DecodeError:
        pass


@settings(max_examples=500, suppress_health_check=[HealthCheck.too_slow])
@given(MESSAGES, st.data())
def test_truncation_and_bit_flips_are_rejected(msg, data) -> None:
    body = encode_frame(msg)[:-1]
    cut = data.draw(st.integers(0, len(body) - 1))
    try:
        assert decode_frame(body[:cut]) != msg
    except DecodeError:
        pass
    bits = data.draw(st.lists(st.integers(0, 8 * len(body) - 1), min_size=1, max_size=2, unique=True))
    flipped = bytearray(body)
    for bit in bits:
        flipped[bit // 8] ^= 1 << (bit % 8)
    decoder = FrameDecoder()
    got = decoder.feed(bytes(flipped) + b"\x00")
    assert got == []  # a 1- or 2-bit error is never accepted
    assert sum(decoder.counters[k] for k in ("crc_errors", "cobs_errors", "length_errors",
                                             "unknown_type", "oversized")) >= 1


@settings(max_examples=400, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=200), MESSAGES, st.lists(st.integers(1, 40), max_size=8))
def test_decoder_survives_garbage_and_finds_the_next_frame(garbage: bytes, msg, splits) -> None:
    stream = garbage + b"\x00" + encode_frame(msg)
    decoder = FrameDecoder()
    got = []
    pos = 0
    for size in splits:
        got += decoder.feed(stream[pos:pos + size])
        pos += size
    got += decoder.feed(stream[pos:])
    assert got and got[-1] == msg


def _largest_frame() -> bytes:
    msg = TargetHello(0xA5, PROTOCOL_VERSION, 0xFFFFFFFF, 0xFFFF, 1000, 20000, 3, 12, "W" * 16, tuple(range(8)),
                      tuple(range(10, 18)))
    return encode_frame(msg)


def test_every_1_and_2_bit_error_in_the_longest_checked_span_fails_the_crc() -> None:
    """CRC level: the longest span the check covers (65 COBS bytes), every single and double bit error."""
    body = bytes((i * 37 + 11) & 0xFF for i in range(65))
    crc = crc16(body)
    frame = bytearray(body + bytes((crc >> 8, crc & 0xFF)))
    nbits = len(frame) * 8
    from binascii import crc_hqx

    def ok(f: bytearray) -> bool:
        return crc_hqx(bytes(f[:-2]), 0xFFFF) == f[-2] << 8 | f[-1]

    assert ok(frame)
    for a in range(nbits):
        frame[a // 8] ^= 1 << (a % 8)
        assert not ok(frame)
        for b in range(a + 1, nbits):
            frame[b // 8] ^= 1 << (b % 8)
            assert not ok(frame), (a, b)
            frame[b // 8] ^= 1 << (b % 8)
        frame[a // 8] ^= 1 << (a % 8)


@pytest.mark.slow
def test_every_1_and_2_bit_error_on_the_wire_of_the_largest_message_is_rejected() -> None:
    """Wire level: flips in the COBS bytes of the largest message, through the stream decoder."""
    wire = _largest_frame()
    body = bytearray(wire[:-1])
    nbits = len(body) * 8
    decoder = FrameDecoder()
    for a in range(nbits):
        body[a // 8] ^= 1 << (a % 8)
        assert decoder.feed(bytes(body) + b"\x00") == [], a
        for b in range(a + 1, nbits):
            body[b // 8] ^= 1 << (b % 8)
            assert decoder.feed(bytes(body) + b"\x00") == [], (a, b)
            body[b // 8] ^= 1 << (b % 8)
        body[a // 8] ^= 1 << (a % 8)
    assert decoder.counters["frames"] == 0
    assert decoder.feed(wire) != []


def test_decoder_counts_each_kind_of_error() -> None:
    good = encode_frame(Start(1))
    bad_crc = ref_wire(bytes([0x30, 1]), crc_flip=1)
    unknown = ref_wire(bytes([0x7E, 1]))
    bad_len = ref_wire(bytes([0x30, 1, 0x55]))  # Start carries no payload
    bad_frame_len = ref_wire(bytes([0x30, 1]), lengths=(8, 9))  # the trailing length disagrees

    bad_cobs = bytes([0x09, 0x0A, 0x30, 0x01, 0x0A])
    from hilbench.protocol.framing import check_bytes
    bad_cobs = bad_cobs + check_bytes(ref_crc(bad_cobs)) + b"\x00"
    oversized = b"\x01" * 200 + b"\x00"
    decoder = FrameDecoder()
    got = []
    for chunk in (good, bad_crc, good, unknown, bad_len, bad_frame_len, bad_cobs, b"\x00\x00", oversized[:100],
                  oversized[100:], good):
        got += decoder.feed(chunk)
    assert got == [Start(1)] * 3
    c = decoder.counters
    assert (c["frames"], c["crc_errors"], c["unknown_type"], c["length_errors"], c["cobs_errors"], c["oversized"]) == (
        3, 1, 1, 2, 1, 1)
    assert c["resyncs"] == 2
    assert c["garbage_bytes"] == (len(bad_crc) + len(unknown) + len(bad_len) + len(bad_frame_len) + len(bad_cobs)
                                  + 200)


def test_decoder_never_raises_on_odd_input() -> None:
    decoder = FrameDecoder()
    assert decoder.feed(b"") == []
    assert decoder.feed(bytearray(b"\x03\x00")) == []
    assert decoder.feed(memoryview(b"\xff" * 70)) == []


def test_generated_files_are_fresh() -> None:
    result = subprocess.run([sys.executable, str(REPO / "firmware_protocol" / "generate.py"), "--check"],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
