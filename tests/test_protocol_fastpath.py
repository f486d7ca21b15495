"""Protocol fast paths: the generated Sensors/Drive encoders and decoders, validate=False and the
one-frame FrameDecoder.feed path, each against bytes built here from the layout in PROTOCOL.md with
the independent framing of vectors/reference_codec.py (bitwise CRC, byte-by-byte COBS).
"""

from __future__ import annotations

import random
from binascii import crc_hqx

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilbench.errors import ProtocolError
from hilbench.protocol import Drive, FrameDecoder, LengthError, Sensors, decode_frame, encode_frame
from reference_codec import wire as ref_wire  # independent

# Values rich in 0x00 bytes, so frames with 0, 1, 2, 3 and more COBS blocks all occur.
U16_ZEROISH = st.one_of(st.sampled_from([0, 1, 0x100, 0xFF, 0xFF00, 0xFFFF]), st.integers(0, 0xFFFF))
I16_ZEROISH = st.one_of(st.sampled_from([0, 1, -1, 0x100, -0x100, -0x8000, 0x7FFF]), st.integers(-0x8000, 0x7FFF))
U8_ZEROISH = st.one_of(st.just(0), st.integers(0, 0xFF))

EDGES = st.lists(st.tuples(U16_ZEROISH, U8_ZEROISH), max_size=4).map(tuple)
SENSORS = st.builds(Sensors, U8_ZEROISH, U8_ZEROISH, EDGES, U16_ZEROISH,
                    st.lists(st.integers(0, 1023) | U16_ZEROISH, max_size=8).map(tuple))
DRIVE = st.builds(Drive, U8_ZEROISH, U16_ZEROISH, U16_ZEROISH, U16_ZEROISH,
                  st.integers(0, 3), st.integers(0, 7), st.integers(0, 7), st.booleans(), st.booleans(),
                  st.sampled_from([0, 1, 63]) | st.integers(0, 63),
                  st.lists(I16_ZEROISH, max_size=8).map(tuple))


def le16(v: int) -> bytes:
    return (v & 0xFFFF).to_bytes(2, "little")


def sensors_frame(m: Sensors) -> bytes:
    """type 0x10 . seq . inputs . encoder u16 . adc count u8 . adc u16 each . edges (u16 time, u8 lines) each."""
    return (bytes([0x10, m.seq, m.inputs]) + le16(m.encoder) + bytes([len(m.adc)]) + b"".join(map(le16, m.adc))
            + b"".join(le16(t) + bytes([lines]) for t, lines in m.edges))


def drive_frame(m: Drive) -> bytes:
    """type 0x11 . seq . duty_a/b/c u16 . flags u16 (mode | state<<2 | sector<<5 | ccw<<8 | req<<9 |
    fault<<10) . telemetry i16 each."""
    flags = (m.output_mode + (m.state << 2) + (m.sector << 5) + (256 if m.direction_ccw else 0)
             + (512 if m.required_ccw else 0) + (m.fault << 10))
    return (bytes([0x11, m.seq]) + le16(m.duty_a) + le16(m.duty_b) + le16(m.duty_c) + le16(flags)
            + b"".join(map(le16, m.telemetry)))


@settings(max_examples=1500)
@given(SENSORS)
def test_sensors_fast_path_bytes_and_round_trip(msg: Sensors) -> None:
    wire = ref_wire(sensors_frame(msg))
    assert encode_frame(msg) == wire
    assert encode_frame(msg, validate=False) == wire
    assert decode_frame(wire[:-1]) == msg
    assert FrameDecoder().feed(wire) == [msg]


@settings(max_examples=1500)
@given(DRIVE)
def test_drive_fast_path_bytes_and_round_trip(msg: Drive) -> None:
    wire = ref_wire(drive_frame(msg))
    assert encode_frame(msg) == wire
    assert encode_frame(msg, validate=False) == wire
    got = decode_frame(wire[:-1])
    assert got == msg
    assert type(got.direction_ccw) is bool and type(got.telemetry) is tuple


def test_the_check_accepts_exactly_the_right_crc() -> None:
    """Every possible CRC (all 65 536) in the check bytes of three frames: decoded once, at the real one."""
    from reference_codec import check_bytes

    rng = random.Random(2)
    for size in (2, 13, 60):
        message = bytes([0x42]) + bytes(rng.randrange(1, 256) for _ in range(size - 1))
        wire = ref_wire(message)
        e = wire[:-4]
        accepted = []
        for stored in range(0x10000):
            try:
                decode_frame(e + check_bytes(stored))
            except LengthError:  # (ErrorReport's own length rule: the framing passed)
                accepted.append(stored)
            except Exception:  # noqa: BLE001 - any other DecodeError: the framing refused it
                continue
            else:
                accepted.append(stored)
        assert accepted == [crc_hqx(e, 0xFFFF)]


@pytest.mark.parametrize(
    ("msg", "same_bits_as"),
    [
        # output_mode 4 spills into state's bit 0; sector 8 spills into direction_ccw (bit 8)
        (Drive(0, 0, 0, 0, 4, 0, 0, False, False, 0, (1, 2, 3)),
         Drive(0, 0, 0, 0, 0, 1, 0, False, False, 0, (1, 2, 3))),
        (Drive(0, 0, 0, 0, 0, 0, 8, False, False, 0, ()),
         Drive(0, 0, 0, 0, 0, 0, 0, True, False, 0, ())),
    ],
)
def test_validate_false_skips_only_the_bit_field_checks(msg: Drive, same_bits_as: Drive) -> None:
    with pytest.raises(ProtocolError):
        encode_frame(msg)
    # unchecked, the out-of-range value lands in its neighbour's bits: why it is for trusted code only
    assert encode_frame(msg, validate=False) == ref_wire(drive_frame(same_bits_as))


@pytest.mark.parametrize(
    "msg",
    [
        Drive(256, 0, 0, 0, 0, 0, 0, False, False, 0, (0, 0, 0)),
        Drive(0, 0x10000, 0, 0, 0, 0, 0, False, False, 0, (0, 0, 0)),
        Drive(0, 0, 0, 0, 0, 0, 0, False, False, 0, (0, 0x8000, 0)),
        Drive(0, 0, 0, 0, 0, 0, 0, False, False, 0, (0,) * 9),
        Sensors(0, 0, (), 0, (0, -1, 0)),
        Sensors(0, 0, (), 0x10000, (0, 0, 0)),
        Sensors(0, 0, (), 0, (0,) * 9),
        Sensors(0, 0, (), 0, None),
        Sensors(0, 0, ((0x10000, 1),), 0, ()),
        Sensors(0, 0, ((0, 1),) * 17, 0, ()),
        Sensors(0, 0, ((1, 1),) * 16, 0, (0,) * 8),  # 70 bytes: more than a frame holds
    ],
)
def test_validate_false_still_checks_plain_fields(msg) -> None:
    for validate in (True, False):
        with pytest.raises(ProtocolError):
            encode_frame(msg, validate=validate)


def _framed(raw_no_crc: bytes) -> bytes:
    return ref_wire(raw_no_crc)


@pytest.mark.parametrize(
    "frame",
    [
        bytes([0x10, 1, 0, 1, 1, 2, 2, 5]),  # Sensors: two ADC codes and the first byte of an edge
        bytes([0x10, 1, 0, 1]),  # Sensors without the high byte of its encoder
        bytes([0x10, 1, 0, 1, 1, 3, 7, 0]),  # Sensors whose ADC count runs past the end
        bytes([0x11, 1, 1, 1, 1, 1, 1, 1, 1]),  # Drive without the high byte of its flags
        bytes([0x11, 1, 1, 1, 1, 1, 1, 1, 1, 1, 9]),  # Drive with half a telemetry entry
    ],
)
def test_hot_types_with_a_bad_length_raise_length_error(frame: bytes) -> None:
    wire = _framed(frame)
    with pytest.raises(LengthError):
        decode_frame(wire[:-1])
    decoder = FrameDecoder()
    assert decoder.feed(wire) == []
    assert decoder.counters["length_errors"] == 1 and decoder.counters["frames"] == 0
    assert decoder.counters["garbage_bytes"] == len(wire)


def test_one_frame_per_read_counts_like_the_general_path() -> None:
    """good, bad CRC, good, fed one whole frame per call (the fast path), then all in one call."""
    good = encode_frame(Sensors(1, 2, ((3, 2),), 4, (5, 6, 7)))
    bad = ref_wire(sensors_frame(Sensors(9, 2, ((3, 2),), 4, (5, 6, 7))), crc_flip=0x10)
    per_call = FrameDecoder()
    got = [m for chunk in (good, bad, good) for m in per_call.feed(chunk)]
    at_once = FrameDecoder()
    assert at_once.feed(good + bad + good) == got == [Sensors(1, 2, ((3, 2),), 4, (5, 6, 7))] * 2
    assert per_call.counters == at_once.counters
    assert per_call.counters["crc_errors"] == 1 and per_call.counters["resyncs"] == 1


def test_fast_path_leaves_a_partial_frame_for_later() -> None:
    wire = encode_frame(Drive(3, 1, 2, 3, 1, 2, 5, True, False, 0, (1, 2, 3)))
    decoder = FrameDecoder()
    assert decoder.feed(wire[:5]) == []
    assert decoder.feed(wire[5:]) == [Drive(3, 1, 2, 3, 1, 2, 5, True, False, 0, (1, 2, 3))]
    assert decoder.feed(bytearray(wire)) == [Drive(3, 1, 2, 3, 1, 2, 5, True, False, 0, (1, 2, 3))]
