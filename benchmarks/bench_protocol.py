"""Codec cost per frame of the hot-path messages (Sensors, Drive): protocol v1 vs this tree's (v3) and a struct baseline.

One lockstep period costs the host an encode of Sensors and a decode of Drive, and the target the
reverse. This prints, all measured in the same run (median over interleaved repeats, µs per frame):

- baseline: a bare struct.pack / struct.unpack of the same fields (no CRC, no COBS, no message
  object), the least any pure-Python codec could cost;
- v1: the protocol-1 codec (10-bit duties in a u32 word, CRC low byte first checked by a table),
  loaded from git at --baseline-rev (default: the last protocol-1 commit) into a private package;
- v3: this tree's hilbench.protocol encode_frame / decode_frame / FrameDecoder.feed (one frame per read).

The machine is a noisy shared 2-core VM: compare the ratios, not the absolute times.
Run: python benchmarks/bench_protocol.py [--baseline-rev REV] [--repeats N] [--profile]
"""

from __future__ import annotations

import argparse
import cProfile
import importlib
import pstats
import statistics
import struct
import subprocess
import sys
import tempfile
import timeit
from pathlib import Path
from types import ModuleType

from hilbench.protocol import Drive, FrameDecoder, Sensors, decode_frame, encode_frame

REPO = Path(__file__).resolve().parent.parent
V1_REV = "c0fb63a"  # the last commit of protocol version 1
REPEATS = 15
NUMBER = 20_000

#: protocol 1's Sensors fields (one edge time); this tree's lists each edge as (time, hall state)
SENSORS_V1 = (17, 0x0B, 1234, 40000, (512, 300, 800))  # AN1017 profile: 3 ADC channels
SENSORS = Sensors(17, 0x0B, ((1234, 0x03),), 40000, (512, 300, 800))
DRIVE = Drive(17, 1000, 512, 3, 1, 2, 4, True, False, 0, (-1234, 300, 17))  # 3 telemetry slots


def load_codec(rev: str) -> ModuleType:
    """hilbench.protocol as of `rev`, imported as the private package hbv1.protocol (git show)."""
    names = ("__init__", "framing", "codec", "messages")
    with tempfile.TemporaryDirectory(prefix="hbv1-") as folder:  # every module imported before it goes
        root = Path(folder)
        pkg = root / "hbv1" / "protocol"
        pkg.mkdir(parents=True)
        (root / "hbv1" / "__init__.py").write_text("")
        for name in names:
            text = subprocess.run(["git", "-C", str(REPO), "show", f"{rev}:hilbench/protocol/{name}.py"],
                                  capture_output=True, text=True, check=True, timeout=30).stdout
            (pkg / f"{name}.py").write_text(text.replace("hilbench.protocol", "hbv1.protocol"))
        sys.path.insert(0, folder)
        try:
            codec = importlib.import_module("hbv1.protocol")
            for name in names[1:]:
                importlib.import_module(f"hbv1.protocol.{name}")
        finally:
            sys.path.remove(folder)
    return codec


def measure(cases: dict[str, str], env: dict, repeats: int = REPEATS) -> dict[str, float]:
    """Median µs per call of each statement; the cases take turns so drift hits them alike."""
    timers = {name: timeit.Timer(stmt, globals=env) for name, stmt in cases.items()}
    samples: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(repeats):
        for name, timer in timers.items():
            samples[name].append(timer.timeit(NUMBER) / NUMBER * 1e6)
    return {name: statistics.median(v) for name, v in samples.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline-rev", default=V1_REV, help="git revision of the v1 codec (default %(default)s)")
    parser.add_argument("--repeats", type=int, default=REPEATS, help="interleaved repeats (default %(default)s)")
    parser.add_argument("--profile", action="store_true", help="also print a cProfile of the v3 path")
    args = parser.parse_args()

    v1 = load_codec(args.baseline_rev)
    s1 = v1.Sensors(*SENSORS_V1)
    d1 = v1.Drive(*DRIVE)
    wire_s, wire_d = encode_frame(SENSORS), encode_frame(DRIVE)
    wire_s1, wire_d1 = v1.encode_frame(s1), v1.encode_frame(d1)
    assert decode_frame(wire_s[:-1]) == SENSORS and decode_frame(wire_d[:-1]) == DRIVE
    assert v1.decode_frame(wire_s1[:-1]) == s1 and v1.decode_frame(wire_d1[:-1]) == d1
    base_s = struct.Struct("<BBBHH3H")
    base_d = struct.Struct("<BB3HH3h")  # protocol 2 layout: three u16 duties, a u16 flags word, telemetry
    packed_s = base_s.pack(0x10, 17, 0x0B, 1234, 40000, 512, 300, 800)
    packed_d = base_d.pack(0x11, 17, 1000, 512, 3, 0x189, -1234, 300, 17)
    env = dict(globals(), base_s=base_s, base_d=base_d, packed_s=packed_s, packed_d=packed_d,
               body_s=wire_s[:-1], body_d=wire_d[:-1], dec=FrameDecoder(), s=SENSORS, d=DRIVE,
               wire_s=wire_s, wire_d=wire_d, v1=v1, s1=s1, d1=d1, body_s1=wire_s1[:-1], body_d1=wire_d1[:-1],
               dec1=v1.FrameDecoder(), wire_s1=wire_s1, wire_d1=wire_d1)
    cases = {
        "baseline struct.pack Sensors": "base_s.pack(0x10, 17, 0x0B, 1234, 40000, 512, 300, 800)",
        "baseline struct.unpack Sensors": "base_s.unpack(packed_s)",
        "baseline struct.pack Drive": "base_d.pack(0x11, 17, 1000, 512, 3, 0x189, -1234, 300, 17)",
        "baseline struct.unpack Drive": "base_d.unpack(packed_d)",
        "v1 encode Sensors": "v1.encode_frame(s1)",
        "v1 decode Sensors": "v1.decode_frame(body_s1)",
        "v1 encode Drive": "v1.encode_frame(d1)",
        "v1 decode Drive": "v1.decode_frame(body_d1)",
        "v1 feed Sensors (1 frame/read)": "dec1.feed(wire_s1)",
        "v1 feed Drive (1 frame/read)": "dec1.feed(wire_d1)",
        "v3 encode Sensors": "encode_frame(s)",
        "v3 decode Sensors": "decode_frame(body_s)",
        "v3 encode Drive": "encode_frame(d)",
        "v3 decode Drive": "decode_frame(body_d)",
        "v3 encode Drive validate=False": "encode_frame(d, False)",
        "v3 feed Sensors (1 frame/read)": "dec.feed(wire_s)",
        "v3 feed Drive (1 frame/read)": "dec.feed(wire_d)",
    }
    r = measure(cases, env, args.repeats)
    print(f"wire bytes: v1 Sensors {len(wire_s1)}, Drive {len(wire_d1)}; v3 Sensors {len(wire_s)}, "
          f"Drive {len(wire_d)} (delimiter included)")
    print(f"{'case':38s} {'µs/frame (median)':>18s} {'x baseline':>11s}")
    for name, us in r.items():
        kind = "Sensors" if "Sensors" in name else "Drive"
        op = "unpack" if ("decode" in name or "feed" in name or "unpack" in name) else "pack"
        base = r[f"baseline struct.{op} {kind}"]
        print(f"{name:38s} {us:18.2f} {us / base:10.1f}x")
    print()
    for kind in ("Sensors", "Drive"):
        for op in ("encode", "decode", "feed"):
            key = f"{op} {kind}" + (" (1 frame/read)" if op == "feed" else "")
            old, new = r[f"v1 {key}"], r[f"v3 {key}"]
            print(f"{op:6s} {kind:8s} v1 {old:5.2f} µs  v3 {new:5.2f} µs  v3/v1 {new / old:5.2f}")
    for label in ("v1", "v3"):
        host = r[f"{label} encode Sensors"] + r[f"{label} decode Drive"]
        target = r[f"{label} decode Sensors"] + r[f"{label} encode Drive"]
        print(f"{label} per lockstep period: host {host:5.2f} µs, target {target:5.2f} µs "
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
