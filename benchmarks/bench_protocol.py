"""Encode+decode cost per frame of the hot-path messages (Sensors, Drive) in the Python codec.

Prints the median over repeats (µs per frame) and the ratio to a baseline measured in the same run:
a bare struct.pack + struct.unpack of the same fields (no CRC, no COBS, no message object), i.e.
the least any Python codec could cost. The machine is noisy: compare ratios, not absolute times.
Run: python benchmarks/bench_protocol.py
"""

from __future__ import annotations

import statistics
import struct
import timeit

from hilbench.protocol import Drive, Sensors, decode_frame, encode_frame

REPEATS = 9
NUMBER = 20_000


def median_us(fn) -> float:
    times = timeit.repeat(fn, repeat=REPEATS, number=NUMBER)
    return statistics.median(times) / NUMBER * 1e6


def main() -> None:
    sensors = Sensors(17, 0x0B, 1234, 40000, (512, 300, 800))
    drive = Drive(17, 1000, 512, 3, 1, 2, 4, True, False, 0, (-1234, 300, 17))
    base_s = struct.Struct("<BBBHH3H")
    base_d = struct.Struct("<BBIBB3h")

    def baseline_sensors() -> None:
        base_s.unpack(base_s.pack(0x10, 17, 0x0B, 1234, 40000, 512, 300, 800))

    def baseline_drive() -> None:
        base_d.unpack(base_d.pack(0x11, 17, 0x40080BE8, 0x62, 0, -1234, 300, 17))

    def codec_sensors() -> None:
        decode_frame(encode_frame(sensors)[:-1])

    def codec_drive() -> None:
        decode_frame(encode_frame(drive)[:-1])

    def encode_sensors() -> None:
        encode_frame(sensors)

    wire_s = encode_frame(sensors)[:-1]

    def decode_sensors() -> None:
        decode_frame(wire_s)

    results = {}
    for name, fn in [("baseline struct Sensors", baseline_sensors), ("baseline struct Drive", baseline_drive),
                     ("codec Sensors encode+decode", codec_sensors), ("codec Drive encode+decode", codec_drive),
                     ("codec Sensors encode only", encode_sensors), ("codec Sensors decode only", decode_sensors)]:
        results[name] = median_us(fn)
    print(f"{'case':34s} {'µs/frame (median)':>18s}")
    for name, us in results.items():
        print(f"{name:34s} {us:18.2f}")
    for kind in ("Sensors", "Drive"):
        ratio = results[f"codec {kind} encode+decode"] / results[f"baseline struct {kind}"]
        print(f"ratio codec/baseline {kind}: {ratio:.1f}x")
    per_period = results["codec Sensors encode+decode"] + results["codec Drive encode+decode"]
    print(f"one lockstep period (Sensors + Drive, both ends' codec work): {per_period:.1f} µs "
          f"-> {1e6 / per_period:,.0f} periods/s of pure codec time")


if __name__ == "__main__":
    main()
