"""The frame check keeps its promise (protocol 3, PROTOCOL.md "Frame check"): every single-bit error
and every burst of up to 16 bits is detected -- wherever it falls on the wire: in a frame, in its
COBS code bytes, in its check bytes, in the delimiters around it or in idle filler after it, and
whether it merges, splits, lengthens or shortens the frame -- and randomly corrupted frames get
through at the rate the check's width says, no more.

The stream of each golden frame (the good single-frame vectors of vectors/vectors.txt) is its
leading delimiter, its wire bytes, its delimiter and one idle byte: `00 F 00 00`. Bits are
numbered MSB first within a byte, bytes in wire order (the CRC's own order). A burst of length b
(1 <= b <= 16) flips its first and last bit and any pattern in between; a single-bit error is a
burst of length 1. A burst that touches the frame or either delimiter must leave no message
accepted; one confined to the idle byte must leave exactly the original (its error belongs to the
next frame, which is rejected).
"""

from __future__ import annotations

import multiprocessing
import os
import subprocess
from binascii import crc_hqx
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from c_build import FIRMWARE_DIR, LIBRARY_SOURCES, build_c
from hilbench.protocol import Drive, FrameDecoder, Sensors, encode_frame
from hilbench.protocol.framing import check_value
from reference_codec import check_bytes, crc16 as ref_crc  # independent
from test_protocol_vectors import ALL as VECTORS

WIDTH = 16  # bursts up to this many bits must all be detected


def golden_frames() -> list[bytes]:
    """The wire bytes (no delimiter) of every vector that is one good frame."""
    out = []
    for vec in VECTORS:
        chunks = [c for c in vec.wire.split(b"\x00")[:-1] if c]
        if len(chunks) == 1 and len(vec.expects) == 1 and not vec.expects[0].startswith("error"):
            out.append(chunks[0])
    return out


FRAMES = golden_frames()


def stream_of(frame: bytes) -> bytes:
    return b"\x00" + frame + b"\x00\x00"


def bursts_in(nbits: int, start: int) -> int:
    """How many bursts of 1..WIDTH bits start at bit `start` of an nbits-long stream."""
    return sum(1 if b == 1 else 1 << (b - 2) for b in range(1, WIDTH + 1) if start + b <= nbits)


def test_golden_frames_carry_their_crc_in_the_check_bytes() -> None:
    """T = CRC-16 of the COBS bytes, seven bits per check byte (the independent reference's layout)."""
    assert len(FRAMES) >= 28
    for f in FRAMES:
        assert f[-3:] == check_bytes(ref_crc(f[:-3]))
        assert check_value(*f[-3:]) == crc_hqx(f[:-3], 0xFFFF)
        assert f[1] == len(f)  # the leading length (the first COBS data byte)


# ---------------------------------------------------------------------------------------------
# the C receiver: every burst, brute force


@pytest.fixture(scope="module")
def burst_check_exe(tmp_path_factory, gcc: str) -> Path:
    out = tmp_path_factory.mktemp("burst")
    return build_c([FIRMWARE_DIR / "tests" / "burst_check.c", *LIBRARY_SOURCES], out / "burst_check",
                   extra_flags=("-DHBP_RX_MAX=63u", "-O2"))


WORKERS = max(1, min(4, len(os.sched_getaffinity(0))))  # the exhaustive checks split over the CPUs


def shares(frames: list[bytes], n: int) -> list[list[bytes]]:
    """The frames dealt to n workers, longest first to the least loaded (bursts grow with length)."""
    groups: list[list[bytes]] = [[] for _ in range(n)]
    load = [0] * n
    for frame in sorted(frames, key=len, reverse=True):
        k = load.index(min(load))
        groups[k].append(frame)
        load[k] += len(frame)
    return [g for g in groups if g]


@pytest.mark.slow
def test_c_receiver_rejects_every_burst_exhaustively(burst_check_exe: Path, tmp_path: Path) -> None:
    """The real C receive state machine (hbp_rx_byte) over every burst of every golden stream (the
    frames split over the CPUs, one process each)."""
    runs = []
    try:
        for k, group in enumerate(shares(FRAMES, WORKERS)):
            frames = tmp_path / f"frames{k}.txt"
            frames.write_text("".join(f.hex() + "\n" for f in group), encoding="ascii")
            runs.append((group, subprocess.Popen([str(burst_check_exe), str(frames)], stdout=subprocess.PIPE,
                                                 stderr=subprocess.PIPE, text=True)))
        outs = [(group, *proc.communicate(timeout=1800), proc.returncode) for group, proc in runs]
    finally:
        for _, proc in runs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    for group, out, err, rc in outs:
        print(out.strip())
        assert rc == 0, out + err
        total = sum(bursts_in(8 * len(stream_of(f)), s) for f in group for s in range(8 * len(stream_of(f))))
        assert f"streams {len(group)} bursts {total} accepted 0" in out
    assert sum(bursts_in(8 * len(stream_of(f)), s) for f in FRAMES for s in range(8 * len(stream_of(f)))) > 150_000_000


# ---------------------------------------------------------------------------------------------
# the Python decoder: every burst; the ones that keep the framing by linearity, the rest for real


def _windows(stream: bytes, start: int) -> np.ndarray:
    """Every burst starting at bit `start`: its flip pattern over the 16-bit window from there, as an
    int (bit 0 = bit `start`), the odd patterns that fit in the stream."""
    width = min(WIDTH, 8 * len(stream) - start)
    patterns = np.arange(1, 1 << width, 2, dtype=np.uint32)
    return patterns


def _error_bytes(start: int, patterns: np.ndarray, n_bytes: int) -> tuple[int, np.ndarray]:
    """The first byte a window touches and the XOR masks of the (up to 3) bytes it covers."""
    first = start // 8
    shift = start % 8
    # bit k of the pattern is stream bit start + k: MSB-first within bytes
    wide = np.zeros((patterns.size, 3), dtype=np.uint8)
    for k in range(WIDTH):
        bit = ((patterns >> k) & 1).astype(np.uint8)
        pos = shift + k
        if pos // 8 < 3:
            wide[:, pos // 8] |= bit << (7 - pos % 8)
    return first, wide[:, : max(1, min(3, n_bytes - first))]


def _syndromes(frame: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per bit of the frame: its CRC response (a flip of a COBS byte), its check-bit response (a flip
    of a CRC bit in T) and whether it is a check byte's fixed bit (top bit or reserved zeros)."""
    n = len(frame)
    e_len = n - 3
    crc_of = np.zeros(8 * n, dtype=np.uint16)
    check_of = np.zeros(8 * n, dtype=np.uint16)
    fixed = np.zeros(8 * n, dtype=bool)
    for i in range(8 * e_len):
        e = bytearray(e_len)
        e[i // 8] = 0x80 >> (i % 8)
        crc_of[i] = crc_hqx(bytes(e), 0)
    # T0 = 1 c15..c9, T1 = 1 c8..c2, T2 = 1 c1 c0 00000
    order = [None, 15, 14, 13, 12, 11, 10, 9, None, 8, 7, 6, 5, 4, 3, 2, None, 1, 0, None, None, None, None, None]
    for j, c in enumerate(order):
        bit = 8 * e_len + j
        if c is None:
            fixed[bit] = True
        else:
            check_of[bit] = 1 << c
    return crc_of, check_of, fixed


def _python_check(frame: bytes) -> tuple[int, int, int]:
    """Every burst over the frame's stream. Returns (bursts, checked by linearity, decoded for real)."""
    stream = stream_of(frame)
    n = len(stream)
    nbits = 8 * n
    assert nbits - 8 >= 8 * (len(frame) + 2)  # the idle byte is the stream's last
    crc_of, check_of, fixed = _syndromes(frame)
    zero = np.frombuffer(stream, dtype=np.uint8) == 0
    orig = np.frombuffer(stream, dtype=np.uint8)
    total = linear = real = 0
    for start in range(nbits):
        patterns = _windows(stream, start)
        first, masks = _error_bytes(start, patterns, n)
        new = orig[first:first + masks.shape[1]] ^ masks
        keeps = np.all((new == 0) == zero[first:first + masks.shape[1]], axis=1)
        last = (start + np.floor(np.log2(patterns)).astype(np.int64)) // 8  # the last byte a burst touches
        # bursts inside the frame's bytes (stream bytes 1..n-3) that keep its zeros: by linearity
        inside = keeps & (first >= 1) & (last <= n - 3)
        bits = np.zeros(patterns.size, dtype=bool)
        syn = np.zeros(patterns.size, dtype=np.uint16)
        chk = np.zeros(patterns.size, dtype=np.uint16)
        for k in range(WIDTH):
            fb = start + k - 8  # the frame's bit number (the stream has one leading byte)
            if not 0 <= fb < 8 * len(frame):
                continue
            on = ((patterns >> k) & 1).astype(bool)
            syn ^= np.where(on, crc_of[fb], 0).astype(np.uint16)
            chk ^= np.where(on, check_of[fb], 0).astype(np.uint16)
            bits |= on & fixed[fb]
        passes = inside & ~bits & (syn == chk)
        assert not passes.any(), (frame.hex(), start, int(patterns[np.flatnonzero(passes)[0]]))
        linear += int(np.count_nonzero(inside))
        # every other burst (it moves a zero, or touches a delimiter or the idle byte): the real
        # decoder, on all of them at once: the corrupted streams one after another, each behind a
        # guard delimiter (so a stream's corrupted edge merges with nothing of its neighbours')
        others = ~inside
        if others.any():
            block = np.tile(np.concatenate((orig, np.zeros(1, dtype=np.uint8))), (int(np.count_nonzero(others)), 1))
            block[:, first:first + masks.shape[1]] ^= masks[others]
            got = FrameDecoder().feed(block.tobytes())
            n_idle = int(np.count_nonzero(others)) if start >= nbits - 8 else 0
            assert len(got) == n_idle, (frame.hex(), start, len(got), n_idle)
            assert all(encode_frame(m)[:-1] == frame for m in got)
            real += int(np.count_nonzero(others))
        total += patterns.size
    return total, linear, real


#: `_python_check`'s result per frame, kept for the session: the hot frames are golden frames too, and
#: the exhaustive test takes theirs from here instead of checking them a second time
CHECKED: dict[bytes, tuple[int, int, int]] = {}


def test_python_decoder_rejects_every_burst_of_the_hot_frames() -> None:
    """Sensors and Drive frames (the ones on the wire every period), every burst (a frame per worker)."""
    hot = [f for f in FRAMES if len(f) < 40 and f[2] in (0x10, 0x11)][:3]
    assert hot
    with ProcessPoolExecutor(WORKERS, mp_context=multiprocessing.get_context("forkserver")) as pool:
        CHECKED.update(zip(hot, pool.map(_python_check, hot, timeout=1800)))
    for frame in hot:
        total, linear, real = CHECKED[frame]
        nbits = 8 * len(stream_of(frame))
        assert total == sum(bursts_in(nbits, s) for s in range(nbits))
        assert linear + real == total and real > 0
        print(f"frame {frame.hex()[:16]}...: {total} bursts, {linear} by linearity, {real} through FrameDecoder")


@pytest.mark.slow
def test_python_decoder_rejects_every_burst_exhaustively() -> None:
    """Every golden frame: the bursts that keep the frame's zeros where they were are checked by
    linearity (the receiver's CRC check is affine over GF(2): with the check bytes' fixed bits
    intact it accepts iff the CRC response of the flipped COBS bits equals the flipped CRC bits in
    the check bytes; computed here from the real crc_hqx on single bits); every other burst goes
    through the real FrameDecoder. The frames the hot-frames test checked in this session are taken
    from CHECKED (the same deterministic check: `_python_check` asserted every burst of them)."""
    grand = lin = real = 0
    todo = sorted((f for f in FRAMES if f not in CHECKED), key=len, reverse=True)
    with ProcessPoolExecutor(WORKERS, mp_context=multiprocessing.get_context("forkserver")) as pool:
        results = [*pool.map(_python_check, todo, timeout=1800), *(CHECKED[f] for f in FRAMES if f in CHECKED)]
    for total, linear, r in results:
        grand, lin, real = grand + total, lin + linear, real + r
    print(f"{grand} bursts over {len(FRAMES)} golden streams: all rejected ({lin} by linearity, {real} "
          "through FrameDecoder)")
    assert grand > 150_000_000


def _merge_check(f1: bytes, f2: bytes) -> int:
    """Every burst with a flipped bit in the delimiter between two frames (`00 F1 00 F2 00 00`), or
    ending just before or starting just after it, through the real FrameDecoder: exactly the frames
    whose bytes and delimiters are intact come out. Returns the bursts tried."""
    stream = b"\x00" + f1 + b"\x00" + f2 + b"\x00\x00"
    orig = np.frombuffer(stream, dtype=np.uint8)
    mid = 1 + len(f1)  # the delimiter between them
    spans = ((1, mid - 1), (mid + 1, mid + len(f2)))  # each frame's bytes (stream indices, inclusive)
    msgs = [FrameDecoder().feed(b"\x00" + f + b"\x00")[0] for f in (f1, f2)]
    tried = 0
    for start in range(8 * mid - WIDTH, 8 * mid + 8 + WIDTH):
        patterns = _windows(stream, start)
        first, masks = _error_bytes(start, patterns, len(stream))
        block = np.tile(np.concatenate((orig, np.zeros(1, dtype=np.uint8))), (patterns.size, 1))
        block[:, first:first + masks.shape[1]] ^= masks
        changed = block[:, :len(stream)] != orig
        # per burst (row) and frame (column): its bytes and both its delimiters intact
        intact = np.stack([~changed[:, lo - 1:hi + 2].any(axis=1) for lo, hi in spans], axis=1)
        want = [msgs[j] for j in np.nonzero(intact)[1]]  # row by row, each row's frames in stream order
        got = FrameDecoder().feed(block.tobytes())
        assert got == want, (f1.hex(), f2.hex(), start)
        tried += patterns.size
    return tried


@pytest.mark.parametrize("order", [pytest.param("sensors-drive"), pytest.param("drive-sensors", marks=pytest.mark.slow)])
def test_python_decoder_rejects_every_burst_that_merges_two_frames(order: str) -> None:
    """A Sensors then a Drive (and the reverse, slow): every burst around the delimiter between them
    (one that turns it into data merges the two) leaves exactly the untouched frames."""
    sensors = [f for f in FRAMES if f[2] == 0x10 and len(f) < 40][0]
    drive = [f for f in FRAMES if f[2] == 0x11 and len(f) < 40][0]
    pair = (sensors, drive) if order == "sensors-drive" else (drive, sensors)
    tried = _merge_check(*pair)
    print(f"{tried} bursts around the delimiter between two frames: no corrupted frame accepted")
    assert tried > 1_000_000


def test_linearity_the_python_check_relies_on() -> None:
    """crc(E ^ e) == crc(E) ^ crc0(e), against the real function on random patterns."""
    rng = np.random.default_rng(16)
    for frame in FRAMES[:6]:
        e_bytes = frame[:-3]
        for _ in range(50):
            e = rng.integers(0, 256, len(e_bytes), dtype=np.uint8).tobytes()
            assert crc_hqx(bytes(a ^ b for a, b in zip(e_bytes, e)), 0xFFFF) == crc_hqx(e_bytes, 0xFFFF) ^ crc_hqx(e, 0)


# ---------------------------------------------------------------------------------------------
# residual acceptance of randomly corrupted frames


_T = np.array([crc_hqx(bytes((k,)), 0) for k in range(256)], dtype=np.uint32)  # one-byte step table


def _crc_rows(rows: np.ndarray) -> np.ndarray:
    """CRC-16/CCITT-FALSE register after each row (uint8 matrix), the table step vectorised over rows."""
    crc = np.full(rows.shape[0], 0xFFFF, dtype=np.uint32)
    for col in rows.T:
        crc = ((crc << 8) & 0xFFFF) ^ _T[(crc >> 8) ^ col]
    return crc


def test_numpy_crc_is_the_real_crc() -> None:
    rng = np.random.default_rng(3)
    rows = rng.integers(0, 256, (200, 18), dtype=np.uint8)
    assert [int(c) for c in _crc_rows(rows)] == [crc_hqx(r.tobytes(), 0xFFFF) for r in rows]


@pytest.mark.slow
def test_residual_acceptance_of_random_frames_at_the_crc_is_2_to_the_minus_16() -> None:
    """16.8 M random 20-byte COBS bodies with random CRC bits (a Drive's length; random = every bit
    flipped with p = 1/2): the fraction whose CRC matches is 2^-16 within 4 sigma. Seeded. (The
    check bytes' 8 fixed bits and the two length bytes then leave 2^-16 * 2^-8 * 2^-16 = 2^-40 of
    random byte strings.)"""
    rng = np.random.default_rng(2026)
    chunks, rows_per_chunk = 8, 1 << 21
    accepted = 0
    for _ in range(chunks):
        rows = rng.integers(0, 256, (rows_per_chunk, 20), dtype=np.uint8)
        sent = rng.integers(0, 1 << 16, rows_per_chunk, dtype=np.uint32)
        accepted += int(np.count_nonzero(_crc_rows(rows) == sent))
    n = chunks * rows_per_chunk
    expect = n / 65536
    print(f"CRC level: {accepted} of {n} random frames accepted = {accepted / n:.3e} (2^-16 = {1 / 65536:.3e})")
    assert abs(accepted - expect) < 4 * expect ** 0.5


def test_residual_acceptance_through_the_real_decoder() -> None:
    """Heavy random corruption of real Sensors and Drive wire frames (every bit flipped with p = 0.1),
    through the FrameDecoder (check bytes, CRC, COBS, lengths, type): accepted at most at 2^-16. The
    corruption is drawn with NumPy, a chunk of trials at once; each corrupted frame is fed on its own."""
    rng = np.random.default_rng(7)
    good = [encode_frame(Sensors(k, 0x0B, ((1234, 3),), 40000 + k, (512, 300, 800))) for k in range(16)]
    good += [encode_frame(Drive(k, 1000, 512, 3, 1, 2, 4, True, False, 0, (-1234, 300, k))) for k in range(16)]
    width = max(len(w) - 1 for w in good)
    bodies = np.zeros((len(good), width), dtype=np.uint8)  # each frame's bytes (no delimiter), zero-padded
    for k, wire in enumerate(good):
        bodies[k, :len(wire) - 1] = np.frombuffer(wire[:-1], dtype=np.uint8)
    lengths = np.array([len(w) - 1 for w in good])
    trials, chunk = 400_000, 25_000
    accepted = corrupted = 0
    decoder = FrameDecoder()
    for _ in range(trials // chunk):
        pick = rng.integers(0, len(good), chunk)
        flips = rng.random((chunk, width, 8), dtype=np.float32) < 0.1  # every bit, p = 0.1
        masks = np.packbits(flips, axis=2, bitorder="little")[:, :, 0]
        masks[np.arange(width) >= lengths[pick][:, None]] = 0  # nothing past a frame's end
        rows = bodies[pick] ^ masks
        changed = np.flatnonzero(masks.any(axis=1))
        data = rows.tobytes()
        for j in changed.tolist():
            start = j * width
            accepted += len(decoder.feed(data[start:start + lengths[pick[j]]] + b"\x00"))
        corrupted += changed.size
    print(f"real decoder: {accepted} of {corrupted} corrupted frames accepted "
          f"({accepted / corrupted:.2e}; 2^-16 = {1 / 65536:.2e})")
    assert corrupted > 0.2 * trials
    assert accepted <= corrupted / 65536 + 4 * (corrupted / 65536) ** 0.5
