"""Plant cost per 50 us period and real-time factor (both bench motors, both backends, 1 and 2
RK4 substeps), sensor-read and OFF-coast cost, batch plant-seconds per wall second for N = 256 on
both backends, and whether gym-electric-motor / motulator are importable.

Run: python benchmarks/bench_plant.py   (medians of 5 runs; the VM is noisy, compare ratios)
"""

from __future__ import annotations

import importlib.util
import math
import statistics
import time
from pathlib import Path

import numpy as np

from hilbench.config import load_config, plant_params_from_config
from hilbench.plant import Plant
from hilbench.plant.batch import BatchPlant
from hilbench.plant.model import available_backends

ROOT = Path(__file__).resolve().parent.parent
DT = 50e-6
PHI = (0.0, -2.0 * math.pi / 3.0, 2.0 * math.pi / 3.0)


def startup_cost_us(cfg_name: str, backend: str, substeps: int, vq_frac: float = 0.45, n: int = 4000) -> tuple[float, float]:
    """Median cost (us) of one plant.step and, as a baseline, of computing the duties alone."""
    params = plant_params_from_config(load_config(ROOT / "bench_configs" / cfg_name))
    vbus = params.inverter.vbus_v
    vq = vq_frac * vbus
    duty_list = []
    plant = Plant(params, backend=backend, substeps=substeps)
    for _ in range(n):  # record the duty sequence once, then time step() alone
        d = tuple(0.5 + vq * math.cos(plant.theta_e + math.pi / 2 + ph) / vbus for ph in PHI)
        duty_list.append(d)
        plant.step(*d, 1, DT)
    runs = []
    for _ in range(5):
        plant = Plant(params, backend=backend, substeps=substeps)
        step = plant.step
        t0 = time.perf_counter()
        for d in duty_list:
            step(d[0], d[1], d[2], 1, DT)
        runs.append((time.perf_counter() - t0) / n * 1e6)
    base = []
    for _ in range(5):
        t0 = time.perf_counter()
        for d in duty_list:
            pass
        base.append((time.perf_counter() - t0) / n * 1e6)
    return statistics.median(runs), statistics.median(base)


def sensor_and_off_cost_us(backend: str) -> tuple[float, float]:
    """Median cost (us) of the bench's per-period sensor reads, and of an OFF period while coasting."""
    params = plant_params_from_config(load_config(ROOT / "bench_configs" / "hurst_mclv.toml"))
    plant = Plant(params, backend=backend)
    plant.reset(speed_rad_s=100.0)
    n = 20000
    reads, off = [], []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(n):
            plant.hall_bits, plant.last_edge_s, plant.encoder_count, plant.adc_codes((1, 2, 3))
            plant.i_abc, plant.i_bus
        reads.append((time.perf_counter() - t0) / n * 1e6)
        t0 = time.perf_counter()
        for _ in range(n):
            plant.step(0.0, 0.0, 0.0, 0, DT)
        off.append((time.perf_counter() - t0) / n * 1e6)
    return statistics.median(reads), statistics.median(off)


def batch_rate(backend: str, substeps: int, n_plants: int = 256, n: int = 1000) -> float:
    params = plant_params_from_config(load_config(ROOT / "bench_configs" / "hurst_mclv.toml"))
    rates = []
    for _ in range(3):
        bp = BatchPlant([params] * n_plants, backend=backend, substeps=substeps)
        vq = np.linspace(6.0, 12.0, n_plants)
        t0 = time.perf_counter()
        for _ in range(n):
            d = [0.5 + vq * np.cos(bp.theta_e + math.pi / 2 + ph) / 24.0 for ph in PHI]
            bp.step(d[0], d[1], d[2], 1, DT)
        rates.append(n_plants * n * DT / (time.perf_counter() - t0))
    return statistics.median(rates)


def peers() -> None:
    for name, mod in (("gym-electric-motor", "gym_electric_motor"), ("motulator", "motulator")):
        if importlib.util.find_spec(mod) is None:
            print(f"{name}: not importable here (python -m venv /tmp/peers && /tmp/peers/bin/pip install "
                  f"gym-electric-motor motulator; both install in about a minute)")
        else:
            print(f"{name}: importable, but no start-up harness is written for it yet")


def main() -> None:
    print("period 50 us (20 kHz); real-time factor = 50 us / cost; backends:", ", ".join(available_backends()))
    base = None
    for backend in available_backends()[::-1]:
        for substeps in (1, 2):
            for cfg in ("hurst_mclv.toml", "servo_200w.toml"):
                cost, loop = startup_cost_us(cfg, backend, substeps)
                if base is None:
                    base = cost
                print(f"{backend:6s} substeps {substeps} {cfg:16s} step {cost:6.2f} us/period (bare loop {loop:.2f} us)"
                      f"  real-time x{50.0 / cost:6.1f}  vs python/1-substep/hurst x{base / cost:5.1f}")
    for backend in available_backends()[::-1]:
        reads, off = sensor_and_off_cost_us(backend)
        print(f"{backend:6s} sensor reads (hall, edge, encoder, adc(1,2,3), i_abc, i_bus) {reads:5.2f} us;"
              f" OFF coast period {off:5.2f} us")
    for backend in available_backends()[::-1]:
        for substeps in (1, 2):
            print(f"{backend:6s} substeps {substeps} batch N=256: {batch_rate(backend, substeps):6.1f} plant-s per wall-s"
                  f" (incl. numpy duty computation)")
    peers()


if __name__ == "__main__":
    main()
