"""Lockstep closed-loop speed with the C FOC firmware (sil:foc, firmware/foc on the runtime, a host
build) on a pty, against a raw pty echo of the same frame sizes measured in the same run.

Prints medians over interleaved repeats (the machine is a noisy, shared 2-core VM):
  - periods/s of the servo closed loop (bench_configs/servo_200w.toml: the F2812 FOC + the 200 W
    servo plant, 50 us exchanges, every period recorded to NPZ) against the SIL firmware process;
  - the baseline: a raw two-process pty echo of the FOC's frame sizes (Sensors with 3 ADC codes,
    Drive with 8 telemetry words), bench_link.raw_echo; the goal is SIL >= 80 % of it;
  - CPU time per period of the firmware process and of this process.

    python benchmarks/bench_sil_foc.py [--seconds 1.0] [--repeats 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_link import _proc_cpu_s, raw_echo  # noqa: E402

from hilbench.bench import settings  # noqa: E402
from hilbench.bench.launcher import open_target  # noqa: E402
from hilbench.bench.recorder import Recorder  # noqa: E402
from hilbench.bench.scenario import Event  # noqa: E402
from hilbench.bench.session import Session  # noqa: E402
from hilbench.bench.settings import load_config  # noqa: E402
from hilbench.config import plant_params_from_config  # noqa: E402
from hilbench.plant.model import Plant  # noqa: E402
from hilbench.protocol import Drive, Sensors, encode_frame  # noqa: E402
from hilbench.targets.foc.build import build_sil  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PERIOD_US = 50


class Loop(NamedTuple):
    rate: float
    far_cpu_us: float
    host_cpu_us: float


def frame_sizes() -> tuple[int, int]:
    """Wire bytes of a typical FOC Sensors and Drive (3 ADC codes; 8 telemetry words)."""
    sensors = Sensors(17, 0x08, (), 4321, (2100, 1990, 3185))
    drive = Drive(17, 4010, 3491, 3491, 1, 2, 6, False, False, 0, (11000, 10950, 2100, -30, 2080, 9000, 200, 2600))
    return len(encode_frame(sensors)), len(encode_frame(drive))


def foc_loop(seconds: float, record_dir: str) -> Loop:
    """The servo closed loop against sil:foc (its process started by the spec), recorded to NPZ."""
    cfg = load_config(ROOT / "bench_configs" / "servo_200w.toml")
    options = dataclasses.replace(settings.session_options(cfg), duration_s=seconds, period_us=PERIOD_US)
    plant = Plant(plant_params_from_config(cfg), seed=0, substeps=cfg.plant.substeps)
    events = (Event(at_s=0.0, press="s2"), Event(at_s=0.2, params=(("ref_rpm", 1000.0),)), Event(at_s=seconds, end=True))
    with open_target("sil:foc", timeout_s=2.0) as handle:
        assert handle.started is not None
        recorder = Recorder(Path(record_dir) / "bench.npz", {"bench": True}, flush_rows=20_000)
        session = Session(handle.target, plant, events, options, recorder=recorder, link_stats=handle.link_stats,
                          target_label=handle.label)
        session.handshake()
        pid = handle.started.process.pid
        f0, c0, t0 = _proc_cpu_s(pid), time.process_time(), time.perf_counter()
        summary = session.run()
        elapsed, host, far = time.perf_counter() - t0, time.process_time() - c0, _proc_cpu_s(pid) - f0
    n = summary.periods
    return Loop(n / elapsed, far / n * 1e6, host / n * 1e6)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=1.0, help="simulated seconds per run")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    build_sil()  # built once, outside the timed runs
    sensors_len, drive_len = frame_sizes()
    runs: dict[str, list] = {"sil": [], "raw": []}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):  # interleaved, so drifts in machine load hit both alike
            runs["sil"].append(foc_loop(args.seconds, tmp))
            runs["raw"].append(raw_echo(int(args.seconds * 1e6 / PERIOD_US), sensors_len, drive_len))

    def med(name: str, field: str) -> float:
        return statistics.median(getattr(r, field) for r in runs[name])

    real = 1e6 / PERIOD_US
    sil, raw = med("sil", "rate"), med("raw", "rate")
    print(f"FOC + 200 W servo closed loop, lockstep over a pty, {PERIOD_US} us periods, {args.seconds:g} s simulated, "
          f"NPZ recording, median of {args.repeats}")
    print(f"  sil:foc firmware process (C)  : {sil:9,.0f} periods/s = {sil / real:5.2f}x real time; "
          f"CPU per period: firmware {med('sil', 'far_cpu_us'):5.1f} us, host {med('sil', 'host_cpu_us'):5.1f} us")
    print(f"  raw pty echo {sensors_len}/{drive_len} B (baseline): {raw:9,.0f} round trips/s; "
          f"CPU per round trip: echo {med('raw', 'far_cpu_us'):5.1f} us, host {med('raw', 'host_cpu_us'):5.1f} us")
    print(f"  sil:foc / raw echo            : {sil / raw:6.1%} (goal >= 80 %)")
    print(f"    rates: sil {', '.join(f'{r.rate:,.0f}' for r in runs['sil'])}; "
          f"raw {', '.join(f'{r.rate:,.0f}' for r in runs['raw'])}")


if __name__ == "__main__":
    main()
