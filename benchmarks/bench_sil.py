"""Lockstep closed-loop speed with the C AN1017 firmware (SIL, firmware/an1017 host build) on a pty.

Prints, in one run (medians over interleaved repeats; the machine is a noisy, shared 2-core VM):
  - periods/s of the closed loop (AN1017 + Hurst plant, every period recorded to NPZ) against the
    SIL firmware process on a pty (issue 12 goal: >= 80 % of the raw echo),
  - the same against the Python emulator process (emulator:an1017) for comparison,
  - the baseline: a raw two-process pty echo of the same frame sizes (bench_link.raw_echo),
  - CPU time per period of the far end (the firmware process; /proc counters around the timed run)
    and of this process, which the other load on the VM disturbs much less than the rates.

    python benchmarks/bench_sil.py [--seconds 1.0] [--repeats 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_link import _proc_cpu_s, frame_sizes, raw_echo  # noqa: E402
from bench_session import PERIOD_US, scenario  # noqa: E402

from hilbench.bench import settings  # noqa: E402
from hilbench.bench.launcher import TargetHandle, open_target  # noqa: E402
from hilbench.bench.recorder import Recorder  # noqa: E402
from hilbench.bench.session import Session  # noqa: E402
from hilbench.bench.settings import load_config  # noqa: E402
from hilbench.config import plant_params_from_config  # noqa: E402
from hilbench.link.pty import open_pty_pair  # noqa: E402
from hilbench.plant.model import Plant  # noqa: E402
from hilbench.targets.sil import build_sil, start_sil, stop_sil  # noqa: E402


class Loop(NamedTuple):
    """One closed-loop run: periods/s and CPU microseconds per period on each side."""

    rate: float
    far_cpu_us: float
    host_cpu_us: float


def closed_loop(handle: TargetHandle, far_pid: int, seconds: float, record_dir: str) -> Loop:
    """bench_session's closed loop (NPZ recording) on an open target, with CPU time per period."""
    cfg = load_config(None)
    options = dataclasses.replace(settings.session_options(cfg), duration_s=seconds, period_us=PERIOD_US)
    plant = Plant(plant_params_from_config(cfg), seed=0, substeps=cfg.plant.substeps)
    recorder = Recorder(Path(record_dir) / "bench.npz", {"bench": True}, flush_rows=20_000)
    session = Session(handle.target, plant, scenario(seconds), options, recorder=recorder,
                      link_stats=handle.link_stats, target_label=handle.label)
    session.handshake()
    f0, c0, t0 = _proc_cpu_s(far_pid), time.process_time(), time.perf_counter()
    summary = session.run()
    elapsed, host, far = time.perf_counter() - t0, time.process_time() - c0, _proc_cpu_s(far_pid) - f0
    n = summary.periods
    return Loop(n / elapsed, far / n * 1e6, host / n * 1e6)


def sil_loop(exe: Path, seconds: float, record_dir: str) -> Loop:
    """Against a fresh SIL process (its pty master as the fd:N target)."""
    pair = open_pty_pair()
    process = start_sil(pair.slave_path, "seed", exe=exe)
    try:
        os.close(pair.slave_fd)  # the firmware holds the slave; the link owns (and closes) the master
        with open_target(f"fd:{pair.master_fd}", timeout_s=2.0) as handle:
            return closed_loop(handle, process.pid, seconds, record_dir)
    finally:
        stop_sil(process)


def emulator_loop(seconds: float, record_dir: str) -> Loop:
    with open_target("emulator:an1017", timeout_s=2.0) as handle:
        assert handle.process is not None
        return closed_loop(handle, handle.process.pid, seconds, record_dir)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=1.0, help="simulated seconds per run")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    exe = build_sil()
    sensors_len, drive_len = frame_sizes()
    runs: dict[str, list] = {"sil": [], "emulator": [], "raw": []}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):  # interleaved, so drifts in machine load hit every figure alike
            runs["sil"].append(sil_loop(exe, args.seconds, tmp))
            runs["emulator"].append(emulator_loop(args.seconds, tmp))
            runs["raw"].append(raw_echo(int(args.seconds * 1e6 / PERIOD_US), sensors_len, drive_len))

    def med(name: str, field: str) -> float:
        return statistics.median(getattr(r, field) for r in runs[name])

    real = 1e6 / PERIOD_US
    sil, emu, raw = med("sil", "rate"), med("emulator", "rate"), med("raw", "rate")
    print(f"AN1017 + Hurst closed loop, lockstep over a pty, {PERIOD_US} us periods, {args.seconds:g} s simulated, "
          f"NPZ recording, median of {args.repeats}")
    print(f"  SIL firmware process (C)      : {sil:9,.0f} periods/s = {sil / real:5.2f}x real time; "
          f"CPU per period: firmware {med('sil', 'far_cpu_us'):5.1f} us, host {med('sil', 'host_cpu_us'):5.1f} us")
    print(f"  Python emulator process       : {emu:9,.0f} periods/s = {emu / real:5.2f}x real time; "
          f"CPU per period: emulator {med('emulator', 'far_cpu_us'):5.1f} us, host "
          f"{med('emulator', 'host_cpu_us'):5.1f} us")
    print(f"  raw pty echo {sensors_len}/{drive_len} B (baseline): {raw:9,.0f} round trips/s; "
          f"CPU per round trip: echo {med('raw', 'far_cpu_us'):5.1f} us, host {med('raw', 'host_cpu_us'):5.1f} us")
    print(f"  SIL / raw echo                : {sil / raw:6.1%} (goal >= 80 %)")
    print(f"  emulator / raw echo           : {emu / raw:6.1%}")


if __name__ == "__main__":
    main()
