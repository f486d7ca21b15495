"""A three-phase bridge and a PMSM at fixed speed as an ngspice netlist, run in batch mode, and the
same case on hilbench's switching plant: the circuit simulator is the switching model's reference.

The netlist: a stiff bus; per leg two voltage-controlled switches (`S`, Ron 1 mΩ, Roff 100 MΩ),
each with its antiparallel diode (a sharp diode, about 30 mV at 1 A, so the bridge is close to the
ideal one the model assumes); per phase R, L (with its initial current) and a sinusoidal back-EMF
source at the fixed electrical speed, a 0 V source that measures the current, and the star point.
The gates are piecewise-linear sources (1 ns transitions) whose edges are derived here from the
duty counts and the carrier on their own: the carrier's up and down ramps are intersected with
each period's compare level (no code of the model's edge schedule is used), then every turn-on is
delayed by the dead time and a pulse shorter than it is dropped, as a dead-band unit does.

The motor is a round rotor (Ld = Lq): its phases are then R, L and a back-EMF each, exactly. The
fixed speed is given to the plant as a rotor of huge inertia (1e6 kg·m²: 1e-11 of speed change
over a run).
"""

from __future__ import annotations

import dataclasses
import math
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hilbench.plant import MotorParams, Plant, PlantParams
from hilbench.plant.params import InverterParams, PwmTiming

PHASE_AXES = (0.0, 2.0 * math.pi / 3.0, -2.0 * math.pi / 3.0)
EDGE_S = 1e-9  # gate transition time in the netlist


@dataclass(frozen=True)
class BridgeCase:
    """One open-loop case: a motor at fixed speed fed a duty sequence by a bridge."""

    rs_ohm: float
    l_h: float
    psi_wb: float
    pole_pairs: int
    speed_rpm: float
    vbus_v: float
    pwm_freq_hz: float
    dead_s: float
    pulse_centre: str  # "zero" (dsPIC30F up/down) or "peak" (F2812 active high)
    period_s: float  # one exchange: the duties hold over it
    counts: int  # compare counts of 100 % duty (duties are counts / counts)
    duties: tuple[tuple[float, float, float], ...]  # per period, fractions of whole counts
    theta0_rad: float = 0.0
    i0_dq: tuple[float, float] = (0.0, 0.0)

    @property
    def we_rad_s(self) -> float:
        return self.speed_rpm * 2.0 * math.pi / 60.0 * self.pole_pairs

    @property
    def t_end_s(self) -> float:
        return len(self.duties) * self.period_s

    def initial_currents(self) -> tuple[float, float, float]:
        i_d, i_q = self.i0_dq
        return tuple(i_d * math.cos(self.theta0_rad - a) - i_q * math.sin(self.theta0_rad - a) for a in PHASE_AXES)


def steady_duties(*, rs_ohm: float, l_h: float, psi_wb: float, pole_pairs: int, speed_rpm: float, vbus_v: float,
                  period_s: float, n_periods: int, counts: int, i_q_a: float, theta0_rad: float = 0.0,
                  dead_comp_v: float = 0.0) -> tuple[tuple[float, float, float], ...]:
    """Min-max SVPWM duties (whole counts) of the voltage that holds i_d = 0, i_q at fixed speed,
    at each period's mid angle; `dead_comp_v` adds that much along the current (to keep the same
    current roughly with a dead band)."""
    we = speed_rpm * 2.0 * math.pi / 60.0 * pole_pairs
    vd = -we * l_h * i_q_a
    vq = rs_ohm * i_q_a + we * psi_wb + dead_comp_v
    out = []
    for k in range(n_periods):
        th = theta0_rad + we * (k + 0.5) * period_s
        al = vd * math.cos(th) - vq * math.sin(th)
        be = vd * math.sin(th) + vq * math.cos(th)
        v = (al, -0.5 * al + math.sqrt(3) / 2 * be, -0.5 * al - math.sqrt(3) / 2 * be)
        mid = 0.5 * (max(v) + min(v))
        out.append(tuple(min(counts, max(0, round((0.5 + (x - mid) / vbus_v) * counts))) / counts for x in v))
    return tuple(out)


def ideal_transitions(case: BridgeCase, leg: int) -> list[tuple[float, int]]:
    """(time, level) of the leg's ideal high-side command: the carrier (0 at t = n T, 1 at
    (n + 1/2) T, centre-aligned) compared with each period's level: high while carrier < d
    ("zero") or carrier > 1 − d ("peak"). Starts low before t = 0."""
    tpwm = 1.0 / case.pwm_freq_hz
    half = 0.5 * tpwm
    level = 0
    out: list[tuple[float, int]] = []
    for k, duties in enumerate(case.duties):
        d = duties[leg]
        t0, t1 = k * case.period_s, (k + 1) * case.period_s
        # the ramps (each half of the carrier) that overlap [t0, t1)
        m = math.floor(t0 / half + 1e-9)
        while m * half < t1 - 1e-15:
            a, b = max(t0, m * half), min(t1, (m + 1) * half)
            rising = m % 2 == 0  # carrier 0 -> 1 over [m half, (m+1) half)

            def carrier(t: float) -> float:
                x = (t - m * half) / half
                return x if rising else 1.0 - x

            def high(c: float) -> int:
                return int(c < d) if case.pulse_centre == "zero" else int(c > 1.0 - d)

            start = high(carrier(a) + (1e-12 if rising else -1e-12))
            if start != level:
                out.append((a, start))
                level = start
            thr = d if case.pulse_centre == "zero" else 1.0 - d
            if 0.0 < thr < 1.0:
                x = thr if rising else 1.0 - thr
                t = m * half + x * half
                if a < t < b:
                    new = 1 - level
                    out.append((t, new))
                    level = new
            m += 1
    return out


def gate_waveforms(case: BridgeCase, leg: int) -> tuple[list[tuple[float, int]], list[tuple[float, int]]]:
    """(high gate, low gate) transitions: the ideal command with every turn-on delayed by the dead
    time; a pulse shorter than the dead time never turns its switch on. Before t = 0 the command
    is low and has been for long: the low switch is on at t = 0 unless the command rises there."""
    ideal = ideal_transitions(case, leg)
    td = case.dead_s

    def delayed(levels: list[tuple[float, int]]) -> list[tuple[float, int]]:
        out: list[tuple[float, int]] = []
        for n, (t, lv) in enumerate(levels):
            if lv == 1:
                end = levels[n + 1][0] if n + 1 < len(levels) else math.inf
                on = t + td if t >= 0.0 else 0.0  # t < 0: on since before the start
                if on < end:
                    out.append((max(on, 0.0), 1))
            elif out and out[-1][1] == 1:
                out.append((t, 0))
        return out

    low = [(-1.0, 1)] + [(t, 1 - lv) for t, lv in ideal]
    return delayed(ideal), delayed(low)


def _pwl(transitions: list[tuple[float, int]], t_end: float) -> str:
    points = [(0.0, 0.0)]
    level = 0
    for t, lv in transitions:
        if lv == level:
            continue
        if t <= 0.0:
            points = [(0.0, float(lv))]
        else:
            points.append((t - EDGE_S / 2, float(level)))
            points.append((t + EDGE_S / 2, float(lv)))
        level = lv
    points.append((t_end, float(level)))
    return " ".join(f"{t:.12e} {v:g}" for t, v in points)


def netlist(case: BridgeCase, max_step_s: float, wrdata: str) -> str:
    """The ngspice deck of the case (batch mode, results written by `wrdata`)."""
    t_end = case.t_end_s
    we = case.we_rad_s
    amp = we * case.psi_wb
    f_e = we / (2.0 * math.pi)
    i0 = case.initial_currents()
    lines = [f"* hilbench switching bridge check: {case.speed_rpm:g} rpm, dead time {case.dead_s * 1e6:g} us",
             f"Vbus p 0 DC {case.vbus_v:.9g}"]
    for leg, name in enumerate("abc"):
        hi, lo = gate_waveforms(case, leg)
        lines += [
            f"S{name}h p {name} g{name}h 0 sw", f"S{name}l {name} 0 g{name}l 0 sw",
            f"D{name}h {name} p dd", f"D{name}l 0 {name} dd",
            f"Vg{name}h g{name}h 0 PWL({_pwl(hi, t_end)})", f"Vg{name}l g{name}l 0 PWL({_pwl(lo, t_end)})",
            f"R{name} {name} {name}1 {case.rs_ohm:.9g}", f"L{name} {name}1 {name}2 {case.l_h:.9g} IC={i0[leg]:.12g}",
            # e = -we psi sin(theta - axis) = we psi sin(we t + theta0 - axis + pi)
            f"Ve{name} {name}2 {name}3 SIN(0 {amp:.12g} {f_e:.12g} 0 0 "
            f"{math.degrees(case.theta0_rad - PHASE_AXES[leg] + math.pi):.12g})",
            f"Vi{name} {name}3 n DC 0",
        ]
    lines += [
        ".model sw SW(Ron=1e-3 Roff=1e8 Vt=0.5 Vh=0.1)",
        ".model dd D(Is=1e-9 N=0.05 Rs=1e-3)",
        # Gear's method: the trapezoidal rule lost its step ("timestep too small") at a diode turning
        # off next to a clamped phase 39 ms into a 400 rpm case
        ".options method=gear reltol=1e-5 abstol=1e-9 vntol=1e-7",
        f".tran 10n {t_end:.12e} 0 {max_step_s:.12e} uic",
        ".control", "run", f"wrdata {wrdata} i(via) i(vib) i(vic)", "quit 0", ".endc", ".end",
    ]
    return "\n".join(lines) + "\n"


def run_ngspice(ngspice: str, case: BridgeCase, *, max_step_s: float = 50e-9, workdir: Path | None = None,
                timeout_s: float = 600.0) -> tuple[np.ndarray, np.ndarray]:
    """(times, currents[n, 3]) from ngspice for the case."""
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        deck = Path(tmp) / "bridge.cir"
        out = Path(tmp) / "currents.txt"
        deck.write_text(netlist(case, max_step_s, str(out)))
        proc = subprocess.run([ngspice, "-b", str(deck)], capture_output=True, text=True, timeout=timeout_s)
        if proc.returncode != 0 or not out.exists():
            raise RuntimeError(f"ngspice failed ({proc.returncode}): {proc.stdout[-800:]} {proc.stderr[-800:]}")
        data = np.loadtxt(out)
    t = data[:, 0]
    if t[-1] < case.t_end_s * (1.0 - 1e-9):  # ngspice gave up part way (it says why on stdout)
        why = [line for line in proc.stdout.splitlines() if "too small" in line or "abort" in line]
        raise RuntimeError(f"ngspice stopped at {t[-1]:.6g} s of {case.t_end_s:.6g} s: {' '.join(why) or proc.stdout[-400:]}")
    keep = np.concatenate(([True], np.diff(t) > 0))  # ngspice repeats a time point at breakpoints
    return t[keep], data[keep][:, [1, 3, 5]]


def plant_for(case: BridgeCase, *, model: str = "switching", backend: str | None = None,
              substeps: int = 1) -> Plant:
    """The case's motor at fixed speed on the plant's inverter (`model`: "switching", "average", or
    "average-edges": the averaged one with average_dead_time = "edges"), currents as the case starts."""
    motor = MotorParams(rs_ohm=case.rs_ohm, ld_h=case.l_h, lq_h=case.l_h, psi_wb=case.psi_wb,
                        pole_pairs=case.pole_pairs, j_kgm2=1e6)
    dead = "edges" if model == "average-edges" else "sign"
    inv = InverterParams(vbus_v=case.vbus_v, pwm_freq_hz=case.pwm_freq_hz, dead_time_s=case.dead_s,
                         dead_time_enabled=case.dead_s > 0.0, model=model.split("-")[0],  # type: ignore[arg-type]
                         average_dead_time=dead)  # type: ignore[arg-type]
    params = PlantParams(motor=motor, inverter=inv, pwm=PwmTiming(pulse_centre=case.pulse_centre))  # type: ignore[arg-type]
    plant = Plant(params, backend=backend, substeps=substeps)
    plant.reset(theta_e=case.theta0_rad, speed_rad_s=case.speed_rpm * 2.0 * math.pi / 60.0)
    plant.i_d, plant.i_q = case.i0_dq
    plant._sense()  # the sensors (and the averaged dead band's current sign) from these currents
    return plant


def pwm_period_means(case: BridgeCase, *, model: str, points: int) -> np.ndarray:
    """Each phase current's mean over every whole PWM period of the case (trapezoids over `points`
    samples per exchange period), shape (PWM periods, 3)."""
    t, i = run_plant(case, model=model, points=points)
    per = round(1.0 / (case.pwm_freq_hz * case.period_s)) * points  # samples per PWM period
    n = (len(t) - 1) // per
    return np.array([(i[k * per] / 2 + i[k * per + 1:(k + 1) * per].sum(axis=0) + i[(k + 1) * per] / 2) / per
                     for k in range(n)])


def run_plant(case: BridgeCase, *, model: str = "switching", backend: str | None = None, points: int = 10,
              substeps: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(times, currents[n, 3]) of the plant: each period stepped in `points` equal pieces with its
    duties held (the switching model depends on absolute time only, so this samples its ripple)."""
    plant = plant_for(case, model=model, backend=backend, substeps=substeps)
    h = case.period_s / points
    ts = [0.0]
    cur = [case.initial_currents()]
    for k, d in enumerate(case.duties):
        for j in range(points):
            plant.step(d[0], d[1], d[2], 1, h)
            ts.append(k * case.period_s + (j + 1) * h)
            cur.append(plant.i_abc)
    return np.array(ts), np.array(cur)


def fundamental(t: np.ndarray, x: np.ndarray, f_hz: float) -> complex:
    """Complex amplitude of x at f_hz (least squares with a constant) over the samples given."""
    a = np.column_stack([np.cos(2 * np.pi * f_hz * t), np.sin(2 * np.pi * f_hz * t), np.ones_like(t)])
    c, *_ = np.linalg.lstsq(a, x, rcond=None)
    return complex(c[0], -c[1])


def with_(case: BridgeCase, **changes: object) -> BridgeCase:
    return dataclasses.replace(case, **changes)  # type: ignore[arg-type]
