"""Board and bench protections (issue 11, finding 3): the overcurrent comparator drives the
target's FAULT input and trips the bridge; bench limits end a run with a fault marker and exit 8."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import hilbench
from conftest import run_cli
from hilbench.bench.recorder import MARKER_FAULT
from hilbench.errors import BenchLimitError
from hilbench.plant.model import OUTPUT_PWM, Plant, available_backends
from hilbench.plant.params import LOAD_IS_ACTIVE, PlantParams, ProtectionParams
from hilbench.protocol import Input

REPO = Path(__file__).resolve().parent.parent
RUNAWAY = """
[link]
target = "inprocess:an1017"

[[scenario]]
at_s = 0.0
ref_rpm = 1500.0
ramp_s = 0.3

[[scenario]]
at_s = 0.03
press = "s2"

[[scenario]]
at_s = 0.8
load_nm = 0.5

[[scenario]]
at_s = 3.8
end = true
"""


def _runaway_config(tmp_path: Path) -> Path:
    path = tmp_path / "runaway.toml"
    path.write_text((REPO / "bench_configs" / "hurst_mclv.toml").read_text() + RUNAWAY)
    return path


def _peak_phase_current(data: object) -> np.ndarray:
    return np.max(np.abs(np.stack([np.asarray(data[c], dtype=float) for c in ("ia_a", "ib_a", "ic_a")])), axis=0)  # type: ignore[index]


def test_runaway_load_ends_with_a_fault_a_marker_one_line_and_exit_7(tmp_path: Path) -> None:
    record = tmp_path / "runaway.npz"
    result = run_cli("run", str(_runaway_config(tmp_path)), "--record", str(record), "--no-control", timeout=180)
    assert result.returncode == BenchLimitError.exit_code == 8, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.startswith("hilbench:")]
    assert len(lines) == 1 and "bench limit" in lines[0] and "overspeed" in lines[0], result.stderr
    data = hilbench.read_recording(record)
    assert data.columns["marker"][-1] == MARKER_FAULT
    speed = np.abs(np.asarray(data.columns["speed_rpm"], dtype=float))
    assert speed.max() < 4000 * 1.25  # stopped at the bench limit (checked every 16 periods), not at 200 krpm
    # the comparator: the phase current passes 3.0 A by at most the rise of the period it tripped in
    ipk = _peak_phase_current(data.columns)
    threshold = 3.0
    over = np.flatnonzero(ipk > threshold)
    assert over.size, "the comparator never tripped"
    k = over[0]
    rise = ipk[k] - ipk[k - 1]
    motor = PlantParams.hurst().motor
    assert 0.0 < rise < (24.0 + 7.32 * 4.0) / motor.ld_h * 50e-6  # one period's rise is bounded by (Vbus + e)/L Ts
    assert ipk.max() <= threshold + rise
    assert any("overcurrent" in e for e in data.events)


def test_comparator_latches_sets_fault_and_gates_the_bridge_off() -> None:
    for backend in available_backends():
        params = PlantParams(PlantParams.hurst().motor, protection=ProtectionParams(1.0, True, 0.0))
        plant = Plant(params, backend=backend)
        periods = 0
        while not plant.fault_input:
            plant.step(1.0, 0.0, 0.0, OUTPUT_PWM, 50e-6)  # phase a to the bus: the current climbs
            periods += 1
            assert periods < 100
        tripped_at = abs(plant.i_a)
        assert 1.0 < tripped_at < 1.0 + 24.0 / plant.params.motor.ld_h * 50e-6
        for _ in range(40):  # the firmware keeps asking for full duty: the bridge stays open
            plant.step(1.0, 0.0, 0.0, OUTPUT_PWM, 50e-6)
            assert abs(plant.i_a) <= tripped_at
        assert plant.fault_input and abs(plant.i_a) < 1e-9, backend  # freewheeled to zero through the diodes
        plant.fault_input = False  # the bench clears the latch when the firmware stops its outputs
        plant.step(1.0, 0.0, 0.0, OUTPUT_PWM, 50e-6)
        assert plant.i_a > 0.0


def test_session_sends_the_fault_input_while_the_comparator_is_latched() -> None:
    cfg = hilbench.load_config(None, ['link.target="inprocess:an1017"', "protection.overcurrent_a=0.3",
                                      "protection.overspeed_rpm=0"])
    seen: list[int] = []
    with hilbench.Bench(cfg) as bench:
        target = bench.session.target  # type: ignore[union-attr]
        step = target.step

        def spy(sensors):  # type: ignore[no-untyped-def]
            seen.append(sensors.inputs)
            return step(sensors)

        target.step = spy  # type: ignore[method-assign]
        bench.set_reference(1500)
        bench.press("s2")
        bench.run(0.3)
        events = bench.events
    faults = [bool(x & int(Input.FAULT)) for x in seen]
    assert any(faults) and not faults[0]
    assert any("overcurrent" in e for e in events)


def test_load_kinds_say_whether_they_drive_the_motor() -> None:
    assert LOAD_IS_ACTIVE["constant"] and LOAD_IS_ACTIVE["step"]  # a weight: gravity drives
    assert not LOAD_IS_ACTIVE["linear"] and not LOAD_IS_ACTIVE["quadratic"] and not LOAD_IS_ACTIVE["locked"]


def test_protection_defaults_are_the_hurst_and_mclv_values() -> None:
    cfg = hilbench.load_config(None)
    assert cfg.protection == ProtectionParams(3.0, True, 4000.0)
    servo = hilbench.load_config(REPO / "bench_configs" / "servo_200w.toml")
    assert servo.protection.overcurrent_a == 4.0 and servo.protection.overspeed_rpm == 4500.0
    assert math.isclose(ProtectionParams().overspeed_rpm, 4000.0)
    with pytest.raises(hilbench.ConfigError):
        hilbench.load_config(None, ["protection.overcurrent_a=-1"])


@pytest.mark.parametrize("kind, value", [("constant", 0.2), ("linear", 0.2)])
def test_an_active_load_turns_a_stopped_motor_to_the_bench_limit_a_passive_one_does_not(kind: str, value: float) -> None:
    cfg = hilbench.load_config(None, ['link.target="inprocess:an1017"'])
    with hilbench.Bench(cfg) as bench:
        bench.set_load(value, kind=kind)  # the firmware is stopped: the bridge is open
        if LOAD_IS_ACTIVE[kind]:
            with pytest.raises(BenchLimitError, match="overspeed"):
                bench.run(1.0)
            assert -4000 * 1.25 < bench.speed_rpm < -4000
        else:
            bench.run(0.2)
            assert bench.speed_rpm == 0.0
    if LOAD_IS_ACTIVE[kind]:
        assert bench.signals()["marker"][-1] == MARKER_FAULT


def test_regeneration_charges_the_bus_capacitor_to_the_over_voltage_limit() -> None:
    """An active load turns the stopped motor past the speed where its line back-EMF (7.32 V/krpm)
    exceeds the 24 V bus: the open bridge's diodes return current, which charges 100 uF."""
    cfg = hilbench.load_config(None, ['link.target="inprocess:an1017"', "protection.overspeed_rpm=0",
                                      "protection.bus_capacitance_f=100e-6", "protection.overvoltage_v=30"])
    with hilbench.Bench(cfg) as bench:
        bench.set_load(0.2)
        with pytest.raises(BenchLimitError, match="over-voltage"):
            bench.run(1.0)
    signals = bench.signals()
    assert signals["marker"][-1] == MARKER_FAULT
    speed = abs(float(signals["speed_rpm"][-1]))
    assert speed > 24.0 / 7.32 * 1000  # the diodes conduct only above ~3.3 krpm
    assert float(np.min(signals["ibus_a"])) < 0.0  # regeneration: current back into the bus
