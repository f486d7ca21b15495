"""Lockstep closed-loop speed with the C AN1017 firmware (SIL, firmware/an1017 host build) on a pty.

Prints, in one run (medians over interleaved repeats; the machine is a noisy 2-core VM):
  - periods/s of the closed loop (AN1017 + Hurst plant, every period recorded to NPZ) against the
    SIL firmware process on a pty (issue 12 goal: >= 80 % of the raw echo),
  - the same against the Python emulator process (emulator:an1017) for comparison,
  - the baseline: a raw two-process pty echo of the same frame sizes (bench_link.raw_echo).

    python benchmarks/bench_sil.py [--seconds 1.0] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_link import frame_sizes, raw_echo  # noqa: E402
from bench_session import PERIOD_US, closed_loop  # noqa: E402

from hilbench.link.pty import open_pty_pair  # noqa: E402
from hilbench.targets.sil import build_sil, start_sil, stop_sil  # noqa: E402


def sil_closed_loop(exe: Path, seconds: float, record_dir: str) -> float:
    """Periods/s of one closed-loop run against a fresh SIL process (its pty master as fd:N)."""
    pair = open_pty_pair()
    process = start_sil(pair.slave_path, "seed", exe=exe)
    try:
        os.close(pair.slave_fd)  # the firmware holds the slave; the link owns (and closes) the master
        return closed_loop(f"fd:{pair.master_fd}", seconds, record_dir, "npz")[0]
    finally:
        stop_sil(process)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=1.0, help="simulated seconds per run")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    exe = build_sil()
    sensors_len, drive_len = frame_sizes()
    rates: dict[str, list[float]] = {"sil": [], "emulator": [], "raw": []}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):  # interleaved, so drifts in machine load hit every figure alike
            rates["sil"].append(sil_closed_loop(exe, args.seconds, tmp))
            rates["emulator"].append(closed_loop("emulator:an1017", args.seconds, tmp, "npz")[0])
            rates["raw"].append(raw_echo(int(args.seconds * 1e6 / PERIOD_US), sensors_len, drive_len).rate)
    med = {k: statistics.median(v) for k, v in rates.items()}
    real = 1e6 / PERIOD_US
    print(f"AN1017 + Hurst closed loop, lockstep over a pty, {PERIOD_US} us periods, {args.seconds:g} s simulated, "
          f"NPZ recording, median of {args.repeats}")
    print(f"  SIL firmware process (C)      : {med['sil']:9,.0f} periods/s = {med['sil'] / real:5.2f}x real time")
    emu = med["emulator"]
    print(f"  Python emulator process       : {emu:9,.0f} periods/s = {emu / real:5.2f}x real time")
    print(f"  raw pty echo {sensors_len}/{drive_len} B (baseline): {med['raw']:9,.0f} round trips/s")
    print(f"  SIL / raw echo                : {med['sil'] / med['raw']:6.1%} (goal >= 80 %)")
    print(f"  emulator / raw echo           : {med['emulator'] / med['raw']:6.1%}")


if __name__ == "__main__":
    main()
