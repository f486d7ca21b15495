"""One place assembles a bench: `build_bench` (Bench.open, run, step tests and sweeps come through
it), with one seed rule, and a Bench over a Target or a Plant object the caller made."""

from __future__ import annotations

import numpy as np

import hilbench
from hilbench.bench.assembly import build_bench, build_plant
from hilbench.config import plant_params_from_config
from hilbench.plant import Plant
from hilbench.plant.period import Period
from hilbench.targets.loopback.target import LoopbackTarget


def test_the_run_seed_seeds_the_plant_wherever_a_bench_is_built() -> None:
    """[run] seed when given, else [plant] seed: the ADC noise the plant draws follows it."""
    seeded = hilbench.load_config(None, ["run.seed=7", "plant.seed=3", 'link.target="inprocess:an1017"'])
    twin = Plant(plant_params_from_config(seeded), seed=7)
    plant = build_plant(seeded)
    roles = (1, 2, 3)
    assert [plant.adc_codes(roles) for _ in range(50)] == [twin.adc_codes(roles) for _ in range(50)]
    parts = build_bench(seeded)
    try:
        assert parts.options.seed == 7
        twin = Plant(plant_params_from_config(seeded), seed=7)
        assert [parts.plant.adc_codes(roles) for _ in range(50)] == [twin.adc_codes(roles) for _ in range(50)]  # type: ignore[attr-defined]
    finally:
        parts.close()
    plant_only = hilbench.load_config(None, ["plant.seed=3"])
    assert build_plant(plant_only).adc_codes(roles) == Plant(plant_params_from_config(plant_only), seed=3).adc_codes(roles)


def test_a_bench_runs_a_target_and_a_plant_the_caller_made() -> None:
    target = LoopbackTarget()
    plant = Plant(plant_params_from_config(hilbench.load_config(None)))
    with hilbench.Bench(target=target, plant=plant) as bench:
        assert bench.session is not None and bench.session.target is target and bench.session.plant is plant
        bench.run(0.01)
        signals = bench.signals()
    assert len(signals["t_s"]) == 200 and np.all(signals["echo_seq"] == np.arange(200) % 256)
    assert plant.t_s == Period(50).t_s(200)  # the bench advanced the caller's plant, on its clock
