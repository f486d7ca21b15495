"""Codec cost per frame of the hot-path messages (Sensors, Drive): before/after and a struct baseline.

One lockstep period costs the host an encode of Sensors and a decode of Drive, and the target the
reverse. This prints, all measured in the same run (median over interleaved repeats, µs per frame):

- baseline: a bare struct.pack / struct.unpack of the same fields (no CRC, no COBS, no message
  object), the least any pure-Python codec could cost;
- before: the previous codec (dict lookup, pack_X + CRC + COBS by list comprehension; decode by
  block slices joined, CRC over a slice, dict dispatch) rebuilt here from the generated
  PACKERS/UNPACKERS tables;
- after: hilbench.protocol encode_frame / decode_frame / FrameDecoder.feed (one frame per read).

The machine is a noisy shared 2-core VM: compare the ratios, not the absolute times.
Run: python benchmarks/bench_protocol.py [--profile]
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import statistics
import struct
import timeit
from binascii import crc_hqx

from hilbench.protocol import Drive, FrameDecoder, Sensors, decode_frame, encode_frame
from hilbench.protocol.messages import PACKERS, UNPACKERS

REPEATS = 15
NUMBER = 20_000

SENSORS = Sensors(17, 0x0B, 1234, 40000, (512, 300, 800))  # AN1017 profile: 3 ADC channels
DRIVE = Drive(17, 1000, 512, 3, 1, 2, 4, True, False, 0, (-1234, 300, 17))  # 3 telemetry slots

_CODE = tuple(bytes((i,)) for i in range(256))


def before_encode(msg) -> bytes:
    """The codec as of commit 5cea6ca: generic packer, CRC, COBS by a list comprehension."""
    body = PACKERS[type(msg)](msg)
    crc = crc_hqx(body, 0xFFFF)
    code = _CODE
    return b"".join([code[len(p) + 1] + p for p in (body + code[crc & 0xFF] + code[crc >> 8]).split(b"\x00")]) + b"\x00"


def before_decode(body: bytes):
    """The codec as of commit 5cea6ca: COBS blocks sliced and joined, CRC over a slice, dict dispatch."""
    n = len(body)
    if n > 65 or n == 0 or 0 in body:
        raise ValueError("bad frame")
    i = 0
    parts = []
    while True:
        j = i + body[i]
        if j > n:
            raise ValueError("bad COBS")
        parts.append(body[i + 1:j])
        if j == n:
            break
        i = j
    raw = parts[0] if len(parts) == 1 else b"\x00".join(parts)
    frame = raw[:-2]
    if crc_hqx(frame, 0xFFFF) != raw[-2] | raw[-1] << 8:
        raise ValueError("bad CRC")
    return UNPACKERS[frame[0]](frame)


def measure(cases: dict[str, str], env: dict) -> dict[str, float]:
    """Median µs per call of each statement; the cases take turns so drift hits them alike."""
    timers = {name: timeit.Timer(stmt, globals=env) for name, stmt in cases.items()}
    samples: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(REPEATS):
        for name, timer in timers.items():
            samples[name].append(timer.timeit(NUMBER) / NUMBER * 1e6)
    return {name: statistics.median(v) for name, v in samples.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", action="store_true", help="also print a cProfile of the after path")
    args = parser.parse_args()

    wire_s, wire_d = encode_frame(SENSORS), encode_frame(DRIVE)
    assert before_encode(SENSORS) == wire_s and before_encode(DRIVE) == wire_d
    assert before_decode(wire_s[:-1]) == SENSORS and before_decode(wire_d[:-1]) == DRIVE
    base_s = struct.Struct("<BBBHH3H")
    base_d = struct.Struct("<BBIBB3h")
    packed_s = base_s.pack(0x10, 17, 0x0B, 1234, 40000, 512, 300, 800)
    packed_d = base_d.pack(0x11, 17, 0x40080BE8, 0x62, 0, -1234, 300, 17)
    env = dict(globals(), base_s=base_s, base_d=base_d, packed_s=packed_s, packed_d=packed_d,
               body_s=wire_s[:-1], body_d=wire_d[:-1], dec=FrameDecoder(), s=SENSORS, d=DRIVE,
               wire_s=wire_s, wire_d=wire_d)
    cases = {
        "baseline struct.pack Sensors": "base_s.pack(0x10, 17, 0x0B, 1234, 40000, 512, 300, 800)",
        "baseline struct.unpack Sensors": "base_s.unpack(packed_s)",
        "baseline struct.pack Drive": "base_d.pack(0x11, 17, 0x40080BE8, 0x62, 0, -1234, 300, 17)",
        "baseline struct.unpack Drive": "base_d.unpack(packed_d)",
        "before encode Sensors": "before_encode(s)",
        "before decode Sensors": "before_decode(body_s)",
        "before encode Drive": "before_encode(d)",
        "before decode Drive": "before_decode(body_d)",
        "after encode Sensors": "encode_frame(s)",
        "after decode Sensors": "decode_frame(body_s)",
        "after encode Drive": "encode_frame(d)",
        "after decode Drive": "decode_frame(body_d)",
        "after encode Drive validate=False": "encode_frame(d, False)",
        "after feed Sensors (1 frame/read)": "dec.feed(wire_s)",
        "after feed Drive (1 frame/read)": "dec.feed(wire_d)",
    }
    r = measure(cases, env)
    print(f"wire bytes: Sensors {len(wire_s)}, Drive {len(wire_d)} (delimiter included)")
    print(f"{'case':38s} {'µs/frame (median)':>18s} {'x baseline':>11s}")
    for name, us in r.items():
        kind = "Sensors" if "Sensors" in name else "Drive"
        op = "unpack" if ("decode" in name or "feed" in name or "unpack" in name) else "pack"
        base = r[f"baseline struct.{op} {kind}"]
        print(f"{name:38s} {us:18.2f} {us / base:10.1f}x")
    print()
    for kind in ("Sensors", "Drive"):
        for op in ("encode", "decode"):
            before, after = r[f"before {op} {kind}"], r[f"after {op} {kind}"]
            print(f"{op} {kind:8s} before {before:5.2f} µs  after {after:5.2f} µs  speed-up {before / after:4.1f}x")
    for label, prefix in (("before", "before"), ("after", "after")):
        host = r[f"{prefix} encode Sensors"] + r[f"{prefix} decode Drive"]
        target = r[f"{prefix} decode Sensors"] + r[f"{prefix} encode Drive"]
        print(f"{label:6s} per lockstep period: host {host:5.2f} µs, target {target:5.2f} µs "
              f"-> {1e6 / (host + target):9,.0f} periods/s of pure codec time")
    if args.profile:
        def loop() -> None:
            for _ in range(50_000):
                decode_frame(encode_frame(SENSORS)[:-1])
                decode_frame(encode_frame(DRIVE)[:-1])

        prof = cProfile.Profile()
        prof.runcall(loop)
        pstats.Stats(prof).sort_stats("tottime").print_stats(8)


if __name__ == "__main__":
    main()
