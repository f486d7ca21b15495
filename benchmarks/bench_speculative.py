"""Twin-speculative lockstep against per-period lockstep, both measured in this run (issue 25).

Each case runs the packaged default AN1017 scenario with `hilbench run` (a real process, recording
every period to CSV) once per mode and repeat, interleaved: per-period lockstep ([link] twin =
"off") and twin-speculative lockstep (twin = "auto"). The rate is periods over the session's own
wall time (the summary's wall_s: the loop, without the firmware build, start and handshake).

  - 250 kbaud: sil:an1017 behind a wire held to 250 000 baud (?wire_baud=250000, 10 bits a byte each
    way); goal: speculative >= 10x per-period on the same wire,
  - simavr: the AN1017 firmware built for the ATmega328P in simavr; goal >= 20x,
  - 1.25 Mbaud: sil:an1017 behind 1 250 000 baud (the dsPIC30F2010's fastest exact UART rate at 20
    MIPS); goal: speculative >= 1x real time at 20 kHz (periods/s over 20 000).

The last lines are `identical: yes|no` (every speculative recording equals its per-period one, row
for row) and one line per case.

    python benchmarks/bench_speculative.py [--quick] [--repeats N]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

PERIOD_US = 50
REAL_TIME_HZ = 1e6 / PERIOD_US


@dataclass(frozen=True)
class Case:
    label: str
    target: str
    seconds: float  # simulated seconds of each run (quick)
    full_seconds: float


CASES = (
    Case("250 kbaud", "sil:an1017?wire_baud=250000", 0.1, 0.4),
    Case("simavr", "simavr:an1017", 0.05, 0.2),
    Case("1.25 Mbaud", "sil:an1017?wire_baud=1250000", 0.2, 1.0),
)


@dataclass
class Run:
    rate: float
    rows: list[str]
    link: dict[str, int]


def run_once(case: Case, twin: str, seconds: float, folder: Path) -> Run:
    record = folder / f"{case.label.replace(' ', '_')}-{twin}.csv"
    argv = [sys.executable, "-m", "hilbench", "run", "--target", case.target, "--set", f"link.twin={twin}",
            "--set", "link.timeout_ms=10000", "--duration", str(seconds), "--record", str(record),
            "--no-ui", "--no-control", "--json"]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=3600)
    if done.returncode != 0:
        raise SystemExit(f"bench_speculative: {case.label} twin={twin}: {done.stderr.strip()}")
    summary = json.loads(done.stdout)
    rows = [line for line in record.read_text().splitlines() if not line.startswith("#")]
    return Run(summary["periods"] / summary["wall_s"], rows, summary["link"])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short runs that still show the ratios (< 10 min)")
    parser.add_argument("--repeats", type=int, default=None, help="runs per case and mode (default 1 quick, 3 full)")
    args = parser.parse_args(argv)
    repeats = args.repeats or (1 if args.quick else 3)
    identical = True
    results: dict[str, tuple[float, float]] = {}
    with tempfile.TemporaryDirectory(prefix="bench_speculative-") as tmp:
        folder = Path(tmp)
        print(f"{'case':<12} {'mode':<12} {'periods':>8} {'periods/s':>10} {'wire B/period tx':>17} {'batches':>8} {'resends':>8}")
        for case in CASES:
            seconds = case.seconds if args.quick else case.full_seconds
            rates: dict[str, list[float]] = {"off": [], "auto": []}
            for _ in range(repeats):
                runs = {twin: run_once(case, twin, seconds, folder) for twin in ("off", "auto")}
                same = runs["off"].rows == runs["auto"].rows
                identical = identical and same
                for twin, r in runs.items():
                    rates[twin].append(r.rate)
                    periods = len(r.rows) - 1
                    mode = "per-period" if twin == "off" else "speculative"
                    print(f"{case.label:<12} {mode:<12} {periods:>8} {r.rate:>10.0f} "
                          f"{r.link['bytes_tx'] / periods:>17.2f} {r.link.get('speculative_batches', 0):>8} "
                          f"{r.link.get('speculative_resends', 0):>8}" + ("" if same else "  RECORDINGS DIFFER"))
            results[case.label] = (statistics.median(rates["off"]), statistics.median(rates["auto"]))
    off_250, on_250 = results["250 kbaud"]
    off_avr, on_avr = results["simavr"]
    off_125, on_125 = results["1.25 Mbaud"]
    print(f"per-period lockstep behind 250 kbaud: {off_250:.0f} exchanges/s (the wire's bound with protocol 3's "
          f"19 + 23-byte frames: {250_000 / 10 / 42:.0f}/s)")
    print(f"per-period lockstep at 1.25 Mbaud: {off_125 / REAL_TIME_HZ:.2f}x real time; speculative: "
          f"{on_125:.0f} periods/s")
    print(f"machine: {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}; medians of {repeats} run(s) per case and mode")
    print(f"identical: {'yes' if identical else 'no'}")
    print(f"speed-up 250 kbaud: {on_250 / off_250:.1f}x")
    print(f"speed-up simavr: {on_avr / off_avr:.1f}x")
    print(f"real time at 1.25 Mbaud: {on_125 / REAL_TIME_HZ:.1f}x")
    return 0 if identical else 1


if __name__ == "__main__":
    raise SystemExit(main())
