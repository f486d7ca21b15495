"""Helpers for the FOC target's closed-loop tests: the servo plant, a session, and an index shim.

Until protocol v2's session forwards the encoder index (INPUT_INDEX in Sensors.inputs), the
plant here reports the index through `hall_bits`, which the session copies into Sensors.inputs
unchanged — exactly the bit a v2 session will set. Nothing else differs from the bench.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from hilbench.bench.scenario import Event
from hilbench.bench.session import Session, SessionOptions
from hilbench.bench.settings import load_config
from hilbench.config import plant_params_from_config
from hilbench.plant.model import Plant, _CPlant
from hilbench.targets.foc.target import INPUT_INDEX, FocTarget

CONFIG = Path(__file__).resolve().parents[1] / "bench_configs" / "servo_200w.toml"

_Base = _CPlant if _CPlant is not None else Plant


class IndexPlant(_Base):  # type: ignore[misc,valid-type]
    """The plant with its index pulse in bit INPUT_INDEX of `hall_bits` (see the module doc)."""

    # the base's own hall_bits: the C struct's member descriptor, or a plain attribute in Python
    _raw_hall = next((k.__dict__["hall_bits"] for k in _Base.__mro__ if "hall_bits" in k.__dict__),
                     property(lambda s: s.__dict__["_hb"], lambda s, v: s.__dict__.__setitem__("_hb", v)))

    @property
    def hall_bits(self) -> int:
        return self._raw_hall | (INPUT_INDEX if self.encoder_index else 0)

    @hall_bits.setter
    def hall_bits(self, value: int) -> None:
        self._raw_hall = value


def servo_params(**inverter: object):
    import dataclasses

    params = plant_params_from_config(load_config(CONFIG))
    if inverter:
        params = dataclasses.replace(params, inverter=dataclasses.replace(params.inverter, **inverter))
    return params


def speed_events(*steps: tuple[float, float], end_s: float, loads: tuple[tuple[float, float], ...] = ()) -> list[Event]:
    """S2 at 0, the speed reference as the target's parameter at the given times, loads, end."""
    ev = [Event(at_s=0.0, press="s2")]
    ev += [Event(at_s=t, params=(("ref_rpm", float(rpm)),)) for t, rpm in steps]
    ev += [Event(at_s=t, load_nm=nm) for t, nm in loads]
    ev.append(Event(at_s=end_s, end=True))
    return ev


class Trace:
    """Per-period arrays of one run (true plant state and the target's telemetry)."""

    def __init__(self) -> None:
        self.rows: list[tuple[float, ...]] = []

    def arrays(self) -> dict[str, np.ndarray]:
        a = np.array(self.rows)
        keys = ("t", "speed_rpm", "theta_e", "ia", "ib", "ic", "meas_q15", "id_q15", "iq_q15", "iqref_q15", "state",
                "t2cnt", "enc")
        return {k: a[:, i] for i, k in enumerate(keys)}


def run(events: list[Event], *, dead_time: bool = False, target: FocTarget | None = None,
        index: bool = True, seed: int = 0) -> tuple[dict[str, np.ndarray], FocTarget, Plant]:
    """A lockstep session at 50 us; returns per-period arrays."""
    target = target or FocTarget()
    params = servo_params(dead_time_enabled=dead_time)
    plant = (IndexPlant if index else Plant)(params, seed=seed, substeps=1)
    trace = Trace()
    inner_step = target.step
    fw = target.fw

    def step(sensors):  # record the plant after the previous period and the target's telemetry
        d = inner_step(sensors)
        tel = d.telemetry
        trace.rows.append((plant.t_s, plant.w_m * 60 / (2 * math.pi), plant.theta_e, plant.i_a, plant.i_b, plant.i_c,
                           tel[1], tel[3], tel[4], tel[2], d.state, fw.qep.t2cnt, sensors.encoder))
        return d

    target.step = step  # type: ignore[method-assign]
    session = Session(target, plant, events, SessionOptions(period_us=50, observe_every_periods=10 ** 9))
    session.run()
    return trace.arrays(), target, plant


def param_value(name: str, value_pu: float) -> float:
    """What the session must be given for an IQ24 parameter: pu under protocol v2's IQ24 type,
    the raw IQ24 integer while the target declares such parameters as INT."""
    from hilbench.protocol import ParamType
    from hilbench.targets.foc.iqmath import iq
    from hilbench.targets.foc.target import PARAM_IDS, PARAMS

    ptype = PARAMS[PARAM_IDS[name]][1]
    if hasattr(ParamType, "IQ24") and ptype == int(ParamType.IQ24):
        return value_pu
    return float(iq(value_pu))


def recorded_run(tmp_dir: Path, events: list[Event], *, dead_time: bool, target: FocTarget | None = None,
                 name: str = "run"):
    """A lockstep session at 50 us recorded to NPZ; returns (columns, target, plant)."""
    from hilbench.bench.recorder import Recorder, read_recording

    target = target or FocTarget()
    plant = IndexPlant(servo_params(dead_time_enabled=dead_time), seed=0, substeps=1)
    path = Path(tmp_dir) / f"{name}.npz"
    session = Session(target, plant, events, SessionOptions(period_us=50, observe_every_periods=10 ** 9),
                      recorder=Recorder(path, {"test": name}))
    session.run()
    return read_recording(path).columns, target, plant


def dq_currents(cols: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The plant's true i_d, i_q (A, amplitude-invariant) from recorded phase currents and angle."""
    th = np.radians(cols["theta_e_deg"])
    ia, ib = cols["ia_a"], cols["ib_a"]
    beta = (ia + 2 * ib) / math.sqrt(3)
    return ia * np.cos(th) + beta * np.sin(th), -ia * np.sin(th) + beta * np.cos(th)


def thd(x: np.ndarray, dt_s: float, f1_hz: float) -> float:
    """THD (harmonics 2..40 over the fundamental) of a whole number of cycles of x."""
    n = int(round(len(x) * dt_s * f1_hz)) / f1_hz / dt_s
    x = x[-int(n):]
    spec = np.abs(np.fft.rfft(x))
    k1 = int(round(len(x) * dt_s * f1_hz))
    harm = [spec[k1 * h] for h in range(2, 41) if k1 * h < len(spec)]
    return math.sqrt(sum(h * h for h in harm)) / spec[k1]
