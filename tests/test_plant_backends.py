"""The C and Python plant backends run the same per-period arithmetic: they must agree to
1e-12 relative in every state and sensor over start-up, load step, reversal, OFF (diode decay
and coast), LOW_SIDE, stiction and dead time, on both bench motors and for 1 and 2 substeps."""

from __future__ import annotations

import array
import dataclasses
import math
from pathlib import Path

import pytest

from conftest import require_c_plant

from hilbench.bench.settings import load_config

from hilbench.config import plant_params_from_config
from hilbench.plant import LoadProfile, Plant
from hilbench.plant.model import available_backends

CONFIGS = Path(__file__).resolve().parent.parent / "bench_configs"
PHI = (0.0, -2.0 * math.pi / 3.0, 2.0 * math.pi / 3.0)
DT = 50e-6

needs_c = pytest.mark.skipif(not require_c_plant(), reason="C plant core not built")


def q_duties(theta: float, vq: float, vbus: float):
    return tuple(min(1.0, max(0.0, 0.5 + vq * math.cos(theta + math.pi / 2 + ph) / vbus)) for ph in PHI)


def schedule(k: int, n: int):
    """(mode, vq fraction of the bus) over the run: start-up, reversal, OFF, start-up, LOW_SIDE."""
    f = k / n
    if f < 0.30:
        return 1, 0.45
    if f < 0.45:
        return 1, -0.45  # reversal through zero speed
    if f < 0.60:
        return 0, 0.0  # outputs off: diode decay, then coast
    if f < 0.80:
        return 1, 0.40
    return 2, 0.0  # low side


def snapshot(p: Plant):
    return (p.i_d, p.i_q, p.w_m, p.theta_e, p.t_s, p.i_a, p.i_b, p.i_c, p.i_bus,
            p.encoder_count, p.hall_bits, p.last_edge_s, p.sector, p.theta_m_total)


def assert_close(a, b, where: str):
    for k, (x, y) in enumerate(zip(a, b)):
        if x is None or y is None:
            assert x is y, (where, k, x, y)
        elif isinstance(x, int) and isinstance(y, int):
            assert x == y, (where, k, x, y)
        else:
            assert abs(x - y) <= 1e-12 * max(abs(x), abs(y), 1e-9), (where, k, x, y)


@needs_c
@pytest.mark.parametrize("cfg_name", ["hurst_mclv.toml", "servo_200w.toml"])
@pytest.mark.parametrize("variant", ["plain", "stiction_deadtime", "substeps2"])
def test_c_and_python_backends_agree(cfg_name, variant):
    params = plant_params_from_config(load_config(CONFIGS / cfg_name))
    substeps = 1
    if variant == "stiction_deadtime":
        params = dataclasses.replace(
            params,
            motor=dataclasses.replace(params.motor, coulomb_nm=0.02 * params.motor.kt_nm_per_a),
            inverter=dataclasses.replace(params.inverter, dead_time_enabled=True),
        )
    elif variant == "substeps2":
        substeps = 2
    load_nm = 0.1 * params.motor.kt_nm_per_a
    plants = [Plant(params, seed=3, substeps=substeps, backend=b) for b in ("c", "python")]
    assert [p.backend for p in plants] == ["c", "python"]
    vbus = params.inverter.vbus_v
    n = 6000
    edges = 0
    for pl in plants:
        pl.load = LoadProfile("step", torque_nm=0.0, step_time_s=0.1 * n * DT, step_torque_nm=load_nm)
        pl.pot_fraction = 0.3
    for k in range(n):
        mode, frac = schedule(k, n)
        for pl in plants:
            d = q_duties(pl.theta_e, frac * vbus, vbus)
            pl.step(d[0], d[1], d[2], mode, DT)
        a, b = (snapshot(pl) for pl in plants)
        assert_close(a, b, f"period {k}")
        edges += a[11] is not None
        if k % 7 == 0:
            roles = (1, 2, 3, 4, 5, 0)
            assert plants[0].adc_codes(roles) == plants[1].adc_codes(roles)
    assert edges > 20  # hall edges were crossed and timed on both


@needs_c
def test_env_var_forces_python(monkeypatch):
    monkeypatch.setenv("HILBENCH_PLANT_BACKEND", "python")
    params = plant_params_from_config(load_config(CONFIGS / "hurst_mclv.toml"))
    assert Plant(params).backend == "python"
    monkeypatch.delenv("HILBENCH_PLANT_BACKEND")
    assert Plant(params).backend == "c"


def test_unknown_backend_is_rejected():
    params = plant_params_from_config(load_config(CONFIGS / "hurst_mclv.toml"))
    with pytest.raises(ValueError, match="backend"):
        Plant(params, backend="fortran")


@needs_c
def test_backends_agree_in_off_mode_above_the_bus():
    """Back-EMF above the bus: diode braking (Python path in both), then the C coast takes over."""
    params = plant_params_from_config(load_config(CONFIGS / "hurst_mclv.toml"))
    plants = [Plant(params, backend=b) for b in ("c", "python")]
    for pl in plants:
        pl.reset(theta_e=0.3, speed_rad_s=600.0)  # line back-EMF peak 42 V > 24 V
    for k in range(3000):
        for pl in plants:
            pl.step(0.5, 0.5, 0.5, 0, DT)
        assert_close(*(snapshot(pl) for pl in plants), f"period {k}")
    assert plants[0].w_m < 400.0 and plants[0].i_abc == (0.0, 0.0, 0.0)


def test_append_state_writes_the_recorded_state_in_both_backends() -> None:
    """append_state is the recorder's one-call view of the plant: its declared outputs, little-endian doubles."""
    import struct

    from hilbench.plant.model import OUTPUTS

    for backend in available_backends():
        plant = Plant(plant_params_from_config(load_config(CONFIGS / "hurst_mclv.toml")), seed=3, backend=backend)
        for _ in range(40):
            plant.step(0.62, 0.41, 0.47, 1, 50e-6)
        buf = bytearray(b"ab")
        plant.append_state(buf)
        values = struct.unpack("<" + "d" * len(OUTPUTS), buf[2:])
        assert buf[:2] == b"ab"
        assert values == tuple(getattr(plant, out.source) for out in OUTPUTS)
        assert values[:7] == (plant.theta_e, plant.w_m, plant.i_a, plant.i_b, plant.i_c, plant.i_bus, plant.load_nm)


def test_the_hot_loop_calls_equal_the_attribute_reads_in_both_backends() -> None:
    """The session's per-period calls: ``step(..., state_to)`` returns last_edge_s and appends what
    append_state appends; ``sense(roles)`` is hall, comparator, index, count and adc_codes(roles)
    (one plant stepped with the calls, a twin with the attribute reads; same seed, same noise)."""
    roles = (1, 4, 5, 2, 3)
    for backend in available_backends():
        params = plant_params_from_config(load_config(CONFIGS / "hurst_mclv.toml"))
        fast, slow = (Plant(params, seed=7, backend=backend) for _ in range(2))
        rows, expected = bytearray(), bytearray()
        edges = 0
        for k in range(3000):
            duties = q_duties(fast.theta_e, 9.0, fast.vbus_v)
            edge_s = fast.step(*duties, 1, DT, rows)
            assert slow.step(*duties, 1, DT) == edge_s == slow.last_edge_s
            slow.append_state(expected)
            edges += edge_s is not None
            reading = fast.sense(roles)
            assert reading == (slow.hall_bits, slow.fault_input, slow.encoder_index, slow.encoder_count,
                               slow.adc_codes(roles)), f"{backend} period {k}"
        assert rows == expected and edges > 20


@needs_c
def test_a_noise_block_changed_in_place_reads_as_in_python() -> None:
    """The C core reads the noise block where it lies (a float64 array's buffer, held exported; a
    list's items, its length asked each draw): a list that shrinks, an index counted from the end
    and a float64 block that cannot be resized under it give what Plant.adc_codes gives, never a stray read."""
    params = plant_params_from_config(load_config(CONFIGS / "hurst_mclv.toml"))
    noisy = (2,)  # the bus current: a noisy ADC channel in this config
    out = []
    for backend in ("python", "c"):
        plant = Plant(params, seed=3, backend=backend)
        codes = [plant.adc_codes(noisy)]
        plant._noise = [0.5, -0.5, 1.5]
        plant._noise_i = 0
        codes.append(plant.adc_codes(noisy))
        plant._noise.clear()  # the same list, now empty: a new block is drawn
        codes.append(plant.adc_codes(noisy))
        plant._noise = [2.0, -2.0, 3.0]
        plant._noise_i = -2  # noise[-2]
        codes.append(plant.adc_codes(noisy))
        plant._noise_i = -9
        with pytest.raises(IndexError):
            plant.adc_codes(noisy)
        plant._noise = block = array.array("d", [0.25, -1.25, 0.75, 1.0])
        plant._noise_i = 0
        codes.append(plant.adc_codes(noisy))
        if backend == "c":  # the block the core reads in place cannot move under it
            with pytest.raises(BufferError):
                block.extend([0.0] * 4096)
        codes.append(plant.adc_codes(noisy) + plant.adc_codes(noisy) + plant.adc_codes(noisy))
        out.append((codes, plant._noise_i))
    assert out[0] == out[1]


def test_the_turned_stage_angle_is_cos_and_sin_of_the_difference() -> None:
    """`model._turned` (RK4 stages 2-4): as close to cos and sin of x - d as libm's values of the
    rounded difference (which carries half an ulp of x) within 2 units in the last place of 1, for
    every small turn; libm's own values beyond TURN_MAX_RAD."""
    from hilbench.plant.model import TURN_MAX_RAD, _turned

    for i in range(-400, 401):
        x = i * 0.0157  # beyond +-2 pi: the voltage's angle in the rotor frame is not wrapped
        tol = 2.0 * math.ulp(1.0) + math.ulp(x) / 2.0
        for d in (0.0, 1e-9, -3e-5, 0.0101, -0.031, 0.05, -TURN_MAX_RAD, TURN_MAX_RAD):
            c, s = _turned(math.cos(x), math.sin(x), x, d)
            assert abs(c - math.cos(x - d)) <= tol and abs(s - math.sin(x - d)) <= tol, (x, d)
        for d in (0.0626, -0.3, 2.0):
            assert _turned(math.cos(x), math.sin(x), x, d) == (math.cos(x - d), math.sin(x - d))


@needs_c
def test_backends_are_bit_identical_where_the_stages_turn_by_libm(monkeypatch: pytest.MonkeyPatch) -> None:
    """1 ms periods in one substep at speed turn the RK4 stages by more than TURN_MAX_RAD: the C core
    and the Python step take the libm branch there (counted on the Python side) and still agree bit
    for bit, the bridge driven all along (no comparator trip: every step through the RK4 in dq)."""
    from hilbench.plant import model

    turned, beyond = model._turned, [0]

    def counted(c: float, s: float, x: float, d: float) -> tuple[float, float]:
        beyond[0] += not -model.TURN_MAX_RAD <= d <= model.TURN_MAX_RAD
        return turned(c, s, x, d)

    monkeypatch.setattr(model, "_turned", counted)
    params = plant_params_from_config(load_config(CONFIGS / "hurst_mclv.toml"))
    plants = [Plant(params, backend=b, substeps=1) for b in ("c", "python")]
    for k in range(3600):  # 0.15 s of start-up in 50 us periods, then 1 ms periods at speed
        for p in plants:
            p.step(*q_duties(p.theta_e, 5.0, 24.0), 1, 50e-6 if k < 3000 else 1e-3)
        assert snapshot(plants[0]) == snapshot(plants[1]), k
    assert not any(p.fault_input for p in plants)
    assert beyond[0] > 1000  # the Python step's stages that took libm (the C core took the same)
