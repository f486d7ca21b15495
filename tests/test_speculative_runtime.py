"""SensorsBatch -> BatchDigest on the C runtime (firmware/runtime/hrt_link.c), against per-period lockstep.

The same Sensors stream goes to one SIL process period by period and to another in batches; each
batch's answer must carry the CRC-32 (zlib's, chained from the batch before: PROTOCOL.md "Batches")
of exactly the Drives the first process sent, and its last Drive. The records codec round-trips
against its own decoder and the C decoder (through the digest), never against copied output.
"""

from __future__ import annotations

import zlib
from pathlib import Path

import pytest

from _firmware import random_stream, require_tool
from hilbench.protocol import MODE_LOCKSTEP, PROTOCOL_VERSION, ErrorReport, HostHello, Sensors, TargetHello
from hilbench.protocol.messages import pack_drive
from hilbench.protocol.batch import BatchBuilder, BatchState, decode_records, drive_digest
from hilbench.protocol.messages import MAX_BATCH_BYTES


def _sensors(n: int, seed: int = 3) -> list[Sensors]:
    out = [s for s in random_stream(seed, n) if isinstance(s, Sensors)]
    return [s._replace(seq=k & 0xFF) for k, s in enumerate(out)]


def _batches(stream: list[Sensors]) -> list[tuple[int, int, bytes]]:
    builder = BatchBuilder()
    out: list[tuple[int, int, bytes]] = []
    first = 0
    for k, s in enumerate(stream):
        if not builder.add(s):
            count, records = builder.take()
            out.append((first, count, records))
            first = k
            assert builder.add(s)
    count, records = builder.take()
    out.append((first, count, records))
    return out


def test_records_round_trip_and_fit_a_frame() -> None:
    stream = _sensors(3000)
    batches = _batches(stream)
    state = BatchState()
    decoded: list[Sensors] = []
    for first, count, records in batches:
        assert len(records) <= MAX_BATCH_BYTES
        decoded += decode_records(state, first, count, records)
    assert [tuple(s) for s in decoded] == [tuple(s) for s in stream]


def test_an_unchanged_period_costs_at_most_a_byte_and_runs_share_one() -> None:
    s = Sensors(0, 5, (), 0, (600, 512, 700))
    builder = BatchBuilder()
    assert builder.add(s)
    for k in range(1, 101):
        assert builder.add(s._replace(seq=k & 0xFF))
    count, records = builder.take()
    # the first period: h, inputs, ADC count + 3 codes = 9 bytes; the 100 same periods: runs of at
    # most 64 (0x80 | n stands for n + 1)
    assert (count, len(records), records[-2:]) == (101, 11, bytes((0x80 | 63, 0x80 | 35)))


def _noisy(n: int, seed: int = 5) -> list[Sensors]:
    """Halls turning now and then, ADC codes with the noise of a few LSB (the plant's kind)."""
    import random

    rng = random.Random(seed)
    adc = [600, 512, 700]
    out = []
    halls = (1, 3, 2, 6, 4, 5)
    pos = 0
    encoder = step = 0
    for k in range(n):
        edges: tuple[tuple[int, int], ...] = ()
        if k % 17 == 5:
            pos = (pos + 1) % 6
            edges = ((rng.randrange(500), halls[pos]),)
        if k % 200 == 0:
            step = rng.randrange(-5, 6)  # the encoder turns steadily, at a speed that changes now and then
        encoder = (encoder + step + (rng.choice((0, 0, 0, 1, -1)) if k % 3 else 0)) & 0xFFFF
        if k % 7:  # some periods change nothing but the encoder's step: runs
            adc = [max(0, min(1023, a + rng.choice((-2, -1, 0, 0, 1, 1, 2, 3, -9, 40)))) for a in adc]
        out.append(Sensors(k & 0xFF, halls[pos] | (0x08 if k < 3 else 0), edges, encoder, tuple(adc)))
    return out


def test_small_adc_changes_cost_one_byte_and_round_trip() -> None:
    s = Sensors(0, 5, (), 0, (600, 512, 700))
    builder = BatchBuilder()
    assert builder.add(s)
    assert builder.add(s._replace(seq=1, adc=(601, 511, 702)))  # +1, -1, +2: one byte
    count, records = builder.take()
    assert records[9:] == bytes((0xC0 | 1 | 3 << 2 | 2 << 4,))
    stream = _noisy(3000)
    state = BatchState()
    decoded: list[Sensors] = []
    for first, count, records in _batches(stream):
        decoded += decode_records(state, first, count, records)
    assert [tuple(x) for x in decoded] == [tuple(x) for x in stream]


def test_chained_digest_is_zlib_crc32_over_drive_messages() -> None:
    from hilbench.protocol import Drive

    d = [Drive(k, k, 2 * k, 3, 1, 2, 1, False, False, 0, (k, -k, 7)) for k in range(5)]
    whole = zlib.crc32(b"".join(pack_drive(x) for x in d))
    assert drive_digest(d[2:], drive_digest(d[:2])) == whole


def _sil_pair():
    require_tool("gcc", "the SIL build")
    from hilbench.bench.launcher import open_target

    return open_target("sil:an1017", timeout_s=2.0), open_target("sil:an1017", timeout_s=2.0)


@pytest.mark.parametrize("kind", ["random", "noisy"])
def test_a_batch_runs_its_periods_exactly_as_per_period_lockstep(kind: str) -> None:
    stream = _sensors(4000, seed=11) if kind == "random" else _noisy(4000)
    one, two = _sil_pair()
    with one, two:
        hello = HostHello(0, PROTOCOL_VERSION, 50, MODE_LOCKSTEP, 0)
        a, b = one.target, two.target
        assert a.hello(hello) == b.hello(hello)
        a.start()
        b.start()
        drives = [a.step(s) for s in stream]
        digest = 0
        for first, count, records in _batches(stream):
            b.send_batch(first, count, records)
            reply = b.recv_digest(2.0)
            assert reply is not None and (reply.first_seq, reply.count) == (first, count)
            digest = drive_digest(drives[first:first + count], digest)
            assert reply.digest == digest, f"batch at period {first}"
            last = drives[first + count - 1]
            assert tuple(reply)[6:] == tuple(last)[1:], f"batch at period {first}: the last Drive"
            assert reply.next_seq == first + count
        # a repeat (the answer was lost) is answered from the kept digest, not run again
        first, count, records = _batches(stream)[-1]
        b.send_batch(first, count, records)
        again = b.recv_digest(2.0)
        assert again is not None and again.digest == digest and again.count == count
        # a batch out of order is refused with the period expected next
        b.send_batch(first + count + 5, 1, bytes((0x80,)))
        refused = b.recv_digest(2.0)
        assert refused is not None and (refused.count, refused.next_seq) == (0, first + count)
        # and the state did not move: the same period now runs as per period lockstep does
        nxt = stream[-1]._replace(seq=(first + count) & 0xFF)
        b.send_batch(first + count, 1, bytes((0x80,)))
        c = b.recv_digest(2.0)
        d = a.step(nxt)
        assert c is not None and c.digest == drive_digest([d], digest)


@pytest.mark.parametrize("records, count", [
    (bytes((0x40, 0x00)), 1),          # an edge count of 0
    (bytes((0x04, 0x01)), 1),          # a change of an ADC channel that does not exist yet
    (bytes((0x80,)), 2),               # one period of records, a count of 2
    (bytes((0x81,)), 1),               # a run past the count
    (bytes((0x01,)), 1),               # the inputs byte missing
])
def test_malformed_records_are_refused_and_change_nothing(records: bytes, count: int) -> None:
    require_tool("gcc", "the SIL build")
    from hilbench.bench.launcher import open_target

    with open_target("sil:an1017", timeout_s=2.0) as handle:
        t = handle.target
        t.hello(HostHello(0, PROTOCOL_VERSION, 50, MODE_LOCKSTEP, 0))
        t.send_batch(0, count, records)
        msg = t.link.recv(2.0)
        while type(msg) is TargetHello:  # the hello's retry answered late (a loaded machine): not the batch's reply
            msg = t.link.recv(2.0)
        assert type(msg) is ErrorReport
        with pytest.raises(Exception):
            decode_records(BatchState(), 0, count, records)
        # nothing ran: the first good batch starts the records afresh at period 0
        t.send_batch(0, 1, bytes((0x80,)))
        reply = t.recv_digest(2.0)
        assert reply is not None and reply.count == 1


def test_the_golden_batch_vector_decodes_as_protocol_md_describes_it() -> None:
    """firmware_protocol/vectors 'sensors_batch', read by hand from PROTOCOL.md's record table: a first
    period with inputs 5 and ADC (600, 512, 700); a 1-byte record +1 on channel 0, -1 on channel 1; a run of
    3; a period with inputs 1 and one edge at 12.3 us to lines 1."""
    from hilbench.protocol import decode_frame
    from hilbench.protocol.messages import SensorsBatch

    vectors = (Path(__file__).resolve().parents[1] / "firmware_protocol" / "vectors" / "vectors.txt").read_text()
    block = vectors.split("vector sensors_batch\n", 1)[1]
    wire = bytes.fromhex(block.split("wire ", 1)[1].split("\n", 1)[0])
    msg = decode_frame(wire[:-1])
    assert type(msg) is SensorsBatch and (msg.first_seq, msg.count) == (65535, 6)
    got = decode_records(BatchState(), msg.first_seq, msg.count, bytes(msg.records))
    adc0, adc1 = (600, 512, 700), (601, 511, 700)
    want = [(255, 5, (), 0, adc0), (0, 5, (), 0, adc1), (1, 5, (), 0, adc1), (2, 5, (), 0, adc1), (3, 5, (), 0, adc1),
            (4, 1, ((123, 1),), 0, adc1)]
    assert [tuple(s) for s in got] == want
