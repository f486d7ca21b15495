"""Plant cost per 50 us period and real-time factor (both bench motors), batch plant-seconds per
wall second for N = 256, and the same start-up on gym-electric-motor / motulator if installed.

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

ROOT = Path(__file__).resolve().parent.parent
DT = 50e-6
PHI = (0.0, -2.0 * math.pi / 3.0, 2.0 * math.pi / 3.0)


def startup_cost_us(cfg_name: str, vq_frac: float = 0.45, n: int = 4000) -> tuple[float, float]:
    """Median cost (us) of one plant.step and, as a baseline, of computing the duties alone."""
    params = plant_params_from_config(load_config(ROOT / "bench_configs" / cfg_name))
    vbus = params.inverter.vbus_v
    vq = vq_frac * vbus
    duty_list = []
    plant = Plant(params)
    for _ in range(n):  # record the duty sequence once, then time step() alone
        d = tuple(0.5 + vq * math.cos(plant.theta_e + math.pi / 2 + ph) / vbus for ph in PHI)
        duty_list.append(d)
        plant.step(*d, 1, DT)
    runs = []
    for _ in range(5):
        plant = Plant(params)
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


def batch_rate(n_plants: int = 256, n: int = 1000) -> float:
    params = plant_params_from_config(load_config(ROOT / "bench_configs" / "hurst_mclv.toml"))
    rates = []
    for _ in range(3):
        bp = BatchPlant([params] * n_plants)
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
            print(f"{name}: not installed (pip install gym-electric-motor motulator, in a throwaway venv)")
        else:
            print(f"{name}: installed, but no start-up harness is written for it yet")


def main() -> None:
    print(f"period 50 us (20 kHz); real-time factor = 50 us / cost")
    for cfg in ("hurst_mclv.toml", "servo_200w.toml"):
        cost, loop = startup_cost_us(cfg)
        print(f"{cfg:18s} plant.step {cost:6.2f} us/period (bare loop {loop:.2f} us)  real-time x{50.0 / cost:5.1f}")
    rate = batch_rate()
    print(f"BatchPlant N=256: {rate:7.1f} plant-seconds per wall second (goal 200), incl. numpy duty computation")
    peers()


if __name__ == "__main__":
    main()
