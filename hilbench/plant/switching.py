"""The inverter edge by edge: a switching model of the three-phase bridge (the readable reference).

`[inverter] model = "switching"` replaces the averaged bridge (each period's mean leg voltages)
with this one. Within a period every leg switches at its own PWM edges, at the exact times the
duty and the carrier give; after every edge both switches of the leg stay off for the dead time,
and meanwhile the leg's voltage is set by its current at that instant: a current into the motor
flows through the low-side diode (the leg at 0 V), a current out of it through the high-side diode
(the leg at the bus). A current that reaches zero inside the dead time stays there (the diode
blocks): the leg floats at the voltage that keeps its current at zero, the zero-crossing clamp,
unless that voltage would leave [0, Vbus] and a diode conducts again. The motor is integrated
between these events (the averaged model's RK4 step in dq under the interval's constant
alpha-beta voltage; an interval is never longer than the averaged model's step), so the PWM
ripple, the clamp and the instant at which the ADC samples come out of the model rather than from
a formula.

The carrier (hilbench.plant.params.PwmTiming): a centre-aligned counter whose zero falls on
t = 0, T, 2T, … of the plant's time; each leg's high-side pulse is d·T wide and centred on the
counter's zero or peak, as the target's PWM unit does. Time inside a period runs from 0 (its start)
to dt; the carrier's phase u (in periods, [0, 1)) is carried from period to period, so a period may
be any length (a half PWM period for the F2812 FOC's exchanges, whole periods for AN1017).

State on the plant (flat attributes, so the C core keeps the same ones as members): `_sw_u` the
carrier phase at the next period's start; `_sw_s0.._sw_s2` each leg's ideal high-side command
(1 high, 0 low) at the end of the last period; `_sw_e0.._sw_e2` the time of its last ideal edge
relative to the next period's start (−inf: none pending); `_ia_s`, `_ib_s` the phase currents the
ADC last sampled and `_adc_live` (the ADC reads the end-of-period currents: the sampling instant
is the period's end, or the bridge is off).

`hilbench/plant/_switching.c` mirrors this file operation by operation (the C backend);
tests/test_switching_backends.py checks they agree.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from hilbench.plant.params import PlantParams

if TYPE_CHECKING:
    from hilbench.plant.model import Plant

__all__ = ["BridgeConstants", "reset", "idle", "step_pwm", "HIGH", "LOW", "DEAD"]

HIGH = 1  # the leg's high-side switch is on: the leg at the bus
LOW = 0  # the low-side switch is on: the leg at 0 V
DEAD = 2  # both off (dead time): a diode decides, or the leg floats at zero current

#: carrier phases (in PWM periods) closer than this are one instant (1e-13 s at 10 kHz)
PHASE_EPS = 1e-9
#: a duty within this of 0 or 1 has no edges (a compare count is 1/7500 of a period at the finest)
DUTY_EPS = 1e-6
TWO_PI = 2.0 * math.pi
SQRT3 = math.sqrt(3.0)
INV_SQRT3 = 1.0 / SQRT3
HALF_SQRT3 = 0.5 * SQRT3


class BridgeConstants:
    """What the bridge needs of the parameters: whether it switches (else it is the averaged bridge
    whose dead band follows the edges, average_dead_time = "edges"), carrier frequency, dead time,
    where the pulses are centred (0.0 the counter's zero, 0.5 its peak), the ADC's sampling phase,
    and the phase inductance the averaged bridge's ripple estimate uses."""

    __slots__ = ("switching", "freq_hz", "dead_s", "centre", "sample", "l_h")

    def __init__(self, switching: bool, freq_hz: float, dead_s: float, centre: float, sample: float,
                 l_h: float) -> None:
        self.switching = switching
        self.freq_hz = freq_hz
        self.dead_s = dead_s
        self.centre = centre
        self.sample = sample
        self.l_h = l_h

    @classmethod
    def of(cls, params: PlantParams) -> "BridgeConstants | None":
        """The bridge of these parameters, or None for the averaged model with its default dead band."""
        inv = params.inverter
        switching = inv.model == "switching"
        if not switching and not (inv.average_dead_time == "edges" and inv.dead_time_enabled):
            return None
        sample = float(params.pwm.adc_sample_phase)
        return cls(switching, float(inv.pwm_freq_hz), float(inv.dead_time_s) if inv.dead_time_enabled else 0.0,
                   0.0 if params.pwm.pulse_centre == "zero" else 0.5, sample - math.floor(sample),
                   0.5 * (params.motor.ld_h + params.motor.lq_h))


def reset(plant: "Plant") -> None:
    """Carrier at its zero, every leg low with no dead time pending, the ADC reading live."""
    plant._sw_u = 0.0
    plant._sw_s0 = plant._sw_s1 = plant._sw_s2 = 0
    plant._sw_e0 = plant._sw_e1 = plant._sw_e2 = -math.inf
    plant._ia_s = plant._ib_s = 0.0
    plant._adc_live = True


def advance_phase(u: float, dt_s: float, freq_hz: float) -> float:
    """The carrier's phase dt later, in [0, 1); a whole number of periods within PHASE_EPS is exact."""
    u = u + dt_s * freq_hz
    n = math.floor(u + 0.5)
    if -PHASE_EPS < u - n < PHASE_EPS:
        u = float(n)
    return u - math.floor(u)


def idle(plant: "Plant", dt_s: float) -> float:
    """A period the switching bridge does not switch (outputs off, low sides on; or any period of
    the averaged bridge): the carrier runs on, no dead time is pending afterwards, the ADC reads the
    period's end. Returns the carrier's phase at the period's start."""
    b = plant._bridge
    u0 = plant._sw_u
    plant._sw_u = advance_phase(u0, dt_s, b.freq_hz)
    plant._sw_s0 = plant._sw_s1 = plant._sw_s2 = 0
    plant._sw_e0 = plant._sw_e1 = plant._sw_e2 = -math.inf
    plant._adc_live = True
    return u0


def dead_band_volt_seconds(rising: int, i_e: float, lo_v: float, hi_v: float, v_f: float, vbus: float,
                           td: float, rs: float, l_h: float) -> float:
    """What one dead time adds to a leg's volt-seconds (V·s; negative: lost) against its ideal edge
    (a rising edge should put the bus on the leg, a falling one 0 V). The current i_e at the edge
    picks the diode (into the motor: the low one, the leg at 0 V; out: the high one, at the bus);
    a current that reaches zero inside the dead time (the slope L di/dt = lo_v or hi_v − R i) stays
    there and the leg floats at v_f for the rest of it."""
    if i_e > 0.0:
        v = 0.0
        slope = (lo_v - rs * i_e) / l_h
    elif i_e < 0.0:
        v = vbus
        slope = (hi_v - rs * i_e) / l_h
    else:
        v = v_f
        slope = 0.0
    t_z = td
    if i_e != 0.0 and slope != 0.0 and (slope > 0.0) != (i_e > 0.0):
        t_z = -i_e / slope  # where the diode's current reaches zero
        if t_z > td:
            t_z = td
    held = v * t_z + v_f * (td - t_z)  # what the leg has over the dead time
    return held - (vbus * td if rising else 0.0)


def average_dead_time(plant: "Plant", u0: float, duty_a: float, duty_b: float, duty_c: float,
                      dt_s: float) -> tuple[float, float, float]:
    """The averaged bridge's duties with the dead band as the switching bridge has it on average
    (average_dead_time = "edges"): each ideal edge of a leg inside the period costs Td of the bus
    when the current flows into the motor at a rising edge (the low diode holds the leg at 0 V) and
    gives Td when it flows out at a falling edge (the high diode holds it at the bus); a leg that
    does not switch has no dead band. The current at an edge: the period-start current, plus its
    mean slope (the period's mean phase voltage, the resistance and the back-EMF over L), minus
    (rising) or plus (falling) half the ripple across the pulse, which the three duties give in
    closed form: each leg's pulse is d·T wide around the same centre, so over the half pulse of
    leg x, ∫(v_xn − mean) dt = Vbus·T/2·(d_x − Σ_y min(d_x, d_y)/3 − d_x·(d_x − mean d)).
    Not modelled: a current that reaches zero inside the dead time (the clamp), the ripple's
    curvature (R, the back-EMF's change within a period), Ld ≠ Lq (L is their mean)."""
    b = plant._bridge
    f = b.freq_hz
    td = b.dead_s
    c = b.centre
    vbus = plant.vbus_v
    duties = (duty_a, duty_b, duty_c)
    mean_d = (duty_a + duty_b + duty_c) / 3.0
    i0 = (plant.i_a, plant.i_b, plant.i_c)
    e = plant._back_emf_abc()
    half_t = 0.5 / f
    out = [0.0, 0.0, 0.0]
    for x in range(3):
        d = duties[x]
        if d <= DUTY_EPS or d >= 1.0 - DUTY_EPS:
            out[x] = d
            continue
        g = d - (min(d, duty_a) + min(d, duty_b) + min(d, duty_c)) / 3.0 - d * (d - mean_d)
        ripple = vbus * half_t * g / b.l_h
        slope = (vbus * (d - mean_d) - plant._rs * i0[x] - e[x]) / b.l_h
        # the other legs during this leg's dead times: high if their pulse is wider (same centre)
        n_hi = (duty_a > d) + (duty_b > d) + (duty_c > d)
        lo_v = -vbus * n_hi / 3.0 - e[x]  # L di/dt + R i with this leg at 0 V, at the bus, floating
        hi_v = vbus * (2 - n_hi) / 3.0 - e[x]
        v_f = 1.5 * e[x] + 0.5 * vbus * n_hi
        v_f = 0.0 if v_f < 0.0 else vbus if v_f > vbus else v_f
        err = 0.0
        u = u0
        while True:
            ph, kind = next_edge(u, c, d)
            t = (ph - u0) / f
            if t >= dt_s - PHASE_EPS / f:
                break
            i_e = i0[x] + slope * t + (-ripple if kind else ripple)
            err += dead_band_volt_seconds(kind, i_e, lo_v, hi_v, v_f, vbus, td, plant._rs, b.l_h) / vbus
            u = ph
        x_d = d + err / dt_s
        out[x] = 0.0 if x_d < 0.0 else 1.0 if x_d > 1.0 else x_d
    return out[0], out[1], out[2]


def ideal_high(u: float, centre: float, duty: float) -> int:
    """The leg's ideal high-side command just after carrier phase u (pulses [c − d/2, c + d/2))."""
    if duty <= DUTY_EPS:
        return 0
    if duty >= 1.0 - DUTY_EPS:
        return 1
    x = u + PHASE_EPS - centre + 0.5 * duty
    return 1 if x - math.floor(x) < duty else 0


def next_edge(u: float, centre: float, duty: float) -> tuple[float, int]:
    """(phase, new command) of the leg's first ideal edge later than u + PHASE_EPS; (inf, 0) for none."""
    if duty <= DUTY_EPS or duty >= 1.0 - DUTY_EPS:
        return math.inf, 0
    w = 0.5 * duty
    x = u - centre + w  # an integer at every rising edge
    r = math.floor(x) + 1.0 - x
    y = u - centre - w  # an integer at every falling edge
    f = math.floor(y) + 1.0 - y
    if r <= PHASE_EPS:
        r += 1.0
    if f <= PHASE_EPS:
        f += 1.0
    return (u + r, 1) if r < f else (u + f, 0)


def next_sample(u: float, sample: float) -> float:
    """The carrier phase of the first ADC sample later than u + PHASE_EPS."""
    x = u - sample
    r = math.floor(x) + 1.0 - x
    if r <= PHASE_EPS:
        r += 1.0
    return u + r


def phase_slopes(plant: "Plant", v: list[float]) -> list[float]:
    """di/dt of the three phase currents now with terminal voltages v (the dq model's derivative,
    turned back to phases; the neutral's voltage drops out of the alpha-beta voltage)."""
    va = (2.0 * v[0] - v[1] - v[2]) / 3.0
    vb = (v[1] - v[2]) * INV_SQRT3
    th = plant._th
    c = math.cos(th)
    s = math.sin(th)
    idv = plant.i_d
    iqv = plant.i_q
    we = plant._p * plant.w_m
    vd = va * c + vb * s
    vq = vb * c - va * s
    did = (vd - plant._rs * idv + we * plant._lq * iqv) / plant._ld
    diq = (vq - plant._rs * iqv - we * (plant._ld * idv + plant._psi)) / plant._lq
    dal = did * c - diq * s - we * (idv * s + iqv * c)
    dbe = did * s + diq * c + we * (idv * c - iqv * s)
    return [dal, -0.5 * dal + HALF_SQRT3 * dbe, -0.5 * dal - HALF_SQRT3 * dbe]


def open_leg_voltage(plant: "Plant", v: list[float], o: int, vbus: float) -> float:
    """The terminal voltage of leg o that keeps its (zero) current from changing, the others held:
    di_o/dt is affine in it, so two evaluations give it."""
    lo = list(v)
    lo[o] = 0.0
    hi = list(v)
    hi[o] = vbus
    f0 = phase_slopes(plant, lo)[o]
    f1 = phase_slopes(plant, hi)[o]
    return -f0 * vbus / (f1 - f0)


def leg_voltages(plant: "Plant", gates: list[int], i: list[float], vbus: float) -> tuple[list[float], list[int]]:
    """Terminal voltages (V) of the three legs for one interval, and the legs left open (both
    switches off, zero current: they float and their current is held at zero).

    A switch that is on fixes its leg; a leg in dead time is fixed by its diode while it carries
    current. A floating voltage outside [0, Vbus] is clamped to that rail, whose diode then
    conducts."""
    v = [0.0, 0.0, 0.0]
    open_: list[int] = []
    for x in range(3):
        g = gates[x]
        if g == HIGH:
            v[x] = vbus
        elif g == LOW:
            v[x] = 0.0
        elif i[x] > 0.0:
            v[x] = 0.0  # the low-side diode carries a current into the motor
        elif i[x] < 0.0:
            v[x] = vbus  # the high-side diode carries a current out of it
        else:
            open_.append(x)
    if len(open_) >= 2:
        open_ = float_open_legs(plant, v, open_, vbus)
    if len(open_) == 1:
        o = open_[0]
        vo = open_leg_voltage(plant, v, o, vbus)
        if vo > vbus or vo < 0.0:
            v[o] = vbus if vo > vbus else 0.0
            open_ = []
        else:
            v[o] = vo
    return v, open_


def float_open_legs(plant: "Plant", v: list[float], open_: list[int], vbus: float) -> list[int]:
    """Two or more open legs: no current flows at all, so each open terminal sits at the neutral
    plus its back-EMF (the neutral fixed by a driven leg, else centred in the bus). Sets v of the
    open legs; one that would leave [0, Vbus] is clamped to that rail (the furthest out first, then
    the rest again). Returns the legs still open (one left: its voltage is for the caller)."""
    while len(open_) >= 2:
        e = plant._back_emf_abc()
        fixed = [x for x in range(3) if x not in open_]
        if fixed:
            vn = v[fixed[0]] - e[fixed[0]]
        else:
            vn = 0.5 * (vbus - max(e) - min(e))
        worst = -1
        excess = 0.0
        for o in open_:
            v[o] = vn + e[o]
            out = v[o] - vbus if v[o] > vbus else -v[o] if v[o] < 0.0 else 0.0
            if out > excess:
                worst = o
                excess = out
        if worst < 0:
            return open_
        v[worst] = vbus if v[worst] > vbus else 0.0
        open_.remove(worst)
    return open_


def rk4_dq(plant: "Plant", va: float, vb: float, h: float) -> float:
    """One RK4 step of h seconds with the alpha-beta voltage (va, vb) held: the averaged model's
    step (model.Plant: `_friction`, `_rk4_dq`, a speed crossing zero under Coulomb friction sticks),
    the angle wrapped (`_finish` times the hall edge). Returns the input energy (J)."""
    vmag = math.sqrt(va * va + vb * vb)
    th0 = plant._th
    plant._w_start = plant.w_m
    ij, fr, w0 = plant._friction(plant.i_d, plant.i_q, plant.w_m)
    i_d, i_q, w1, dth, e_part = plant._rk4_dq(plant.i_d, plant.i_q, w0, math.atan2(vb, va) - th0, vmag, ij, fr, h)
    if fr != 0.0 and w0 != 0.0 and (w1 > 0.0) != (w0 > 0.0):
        w1 = 0.0  # the speed crossed zero under Coulomb friction: it sticks
        plant._stuck = True
    plant.i_d = i_d
    plant.i_q = i_q
    plant.w_m = w1
    th1 = th0 + dth
    k = math.floor(th1 / TWO_PI)
    plant._dturns = k
    plant._turns += k
    plant._th = th1 - k * TWO_PI
    return 1.5 * vmag * e_part


def interval(plant: "Plant", gates: list[int], dead_until: list[float], h: float, t_off: float) -> tuple[float, float]:
    """Integrate up to h seconds from t_off with these gate states; returns (time used, input
    energy J). A leg in dead time stays so until its `dead_until`, which may fall inside the
    interval when its diode holds it at the rail its switch then takes over (the step_pwm loop
    does not split there).

    Ends early where a diode's current reaches zero in dead time (found by linear interpolation
    within the step, then integrated to exactly there): that leg is open from then on. A current
    that crosses zero after its leg's dead time flows through the switch: no clamp."""
    vbus = plant.vbus_v
    i = plant._phase_currents()
    v, open_ = leg_voltages(plant, gates, i, vbus)
    va = (2.0 * v[0] - v[1] - v[2]) / 3.0
    vb = (v[1] - v[2]) * INV_SQRT3
    saved = (plant.i_d, plant.i_q, plant.w_m, plant._th, plant._turns, plant._stuck,
             plant.e_in_j, plant.e_cu_j, plant.e_fric_j, plant.e_load_j)
    th0 = plant._th
    # the energy accounts need the general integrator (the C core leaves such periods to this one)
    step = plant._rk4_general if plant.track_energy else rk4_dq
    energy = step(plant, va, vb, h) if step is rk4_dq else step(va, vb, h)
    i1 = plant._phase_currents()
    fx = [2.0, 2.0, 2.0]  # where each diode's current crossed zero, as a fraction of the step (2: no crossing)
    for x in range(3):
        if gates[x] == DEAD and i[x] != 0.0 and (i1[x] > 0.0) != (i[x] > 0.0):
            f = i[x] / (i[x] - i1[x])
            if t_off + f * h < dead_until[x]:
                fx[x] = f
    frac = min(fx)
    if frac < 1.0:  # the first to cross ends the interval there
        (plant.i_d, plant.i_q, plant.w_m, plant._th, plant._turns, plant._stuck,
         plant.e_in_j, plant.e_cu_j, plant.e_fric_j, plant.e_load_j) = saved
        h = h * frac
        energy = step(plant, va, vb, h) if step is rk4_dq else step(va, vb, h)
        i1 = plant._phase_currents()
        for x in range(3):
            if fx[x] <= frac * (1.0 + 1e-9) + 1e-12:
                open_.append(x)
    plant._finish(th0, plant._th - th0 + plant._dturns * TWO_PI, h, t_off)
    plant._project(i1, open_)
    if plant._oc > 0.0:  # the board's comparator sees the ripple's peaks, which fall on these instants
        plant._compare_now()
    return h, energy


def start_legs(u0: float, centre: float, freq_hz: float, duties: tuple[float, float, float], s: list[int],
               te: list[float]) -> tuple[list[float], list[int]]:
    """At the period's start: a leg whose command the new duty changes switches there (s, te
    updated); returns each leg's next ideal edge (time, command)."""
    nt = [0.0, 0.0, 0.0]
    nk = [0, 0, 0]
    for x in range(3):
        now = ideal_high(u0, centre, duties[x])
        if now != s[x]:
            s[x] = now
            te[x] = 0.0
        ph, nk[x] = next_edge(u0, centre, duties[x])
        nt[x] = (ph - u0) / freq_hz
    return nt, nk


def next_event(plant: "Plant", tau: float, gates: list[int], s: list[int], dead_until: list[float], nt: list[float],
               ts: float, t_end: float, dt_s: float) -> float:
    """The next instant something changes after tau: an ideal edge, the end of a dead time (unless
    the leg's diode already holds it at the rail its switch will), an ADC sample, the period's end
    (what falls within PHASE_EPS of it is the next period's)."""
    i = plant._phase_currents() if DEAD in gates else None
    t_next = dt_s
    for x in range(3):
        if nt[x] < t_next:
            t_next = nt[x]
        if tau < dead_until[x] < t_next and not (i[x] < 0.0 if s[x] else i[x] > 0.0):  # type: ignore[index]
            t_next = dead_until[x]
    if ts < t_next:
        t_next = ts
    return dt_s if t_next > t_end else t_next


def step_pwm(plant: "Plant", duty_a: float, duty_b: float, duty_c: float, dt_s: float) -> None:
    """One period of complementary PWM with these duties (fractions 0..1), edge by edge."""
    if plant._t_load_change <= plant.t_s + 1e-12:
        plant._update_load()
    b = plant._bridge
    f = b.freq_hz
    td = b.dead_s
    c = b.centre
    u0 = plant._sw_u
    if plant._adc_live:  # the last sample fell on the last period's end: hold what it read
        plant._ia_s = plant.i_a
        plant._ib_s = plant.i_b
    duties = (min(1.0, max(0.0, duty_a)), min(1.0, max(0.0, duty_b)), min(1.0, max(0.0, duty_c)))
    s = [plant._sw_s0, plant._sw_s1, plant._sw_s2]
    te = [plant._sw_e0, plant._sw_e1, plant._sw_e2]
    nt, nk = start_legs(u0, c, f, duties, s, te)
    t_end = dt_s - PHASE_EPS / f
    ts = (next_sample(u0, b.sample) - u0) / f
    h_max = dt_s / plant._substeps
    plant.last_edge_s = None
    plant._last_mode = 1
    plant._da, plant._db, plant._dc = duties
    energy = 0.0
    tau = 0.0
    while True:
        dead_until = [te[x] + td for x in range(3)]
        gates = [((HIGH if s[x] else LOW) if tau >= dead_until[x] else DEAD) for x in range(3)]
        t_next = next_event(plant, tau, gates, s, dead_until, nt, ts, t_end, dt_s)
        used, e = interval(plant, gates, dead_until, min(t_next - tau, h_max), tau)
        energy += e
        tau = t_next if used == t_next - tau else tau + used
        if tau < t_next:  # a diode stopped conducting, or the longest step: look again
            continue
        if t_next >= dt_s:
            break
        for x in range(3):  # the ideal edges due now
            if nt[x] <= t_next:
                s[x] = nk[x]
                te[x] = t_next
                ph, nk[x] = next_edge(u0 + t_next * f, c, duties[x])
                nt[x] = (ph - u0) / f
        if ts <= t_next:  # the ADC samples now
            i = plant._abc_now()
            plant._ia_s = i[0]
            plant._ib_s = i[1]
            ts = (next_sample(u0 + t_next * f, b.sample) - u0) / f
    plant._sw_s0, plant._sw_s1, plant._sw_s2 = s
    plant._sw_e0, plant._sw_e1, plant._sw_e2 = (te[0] - dt_s, te[1] - dt_s, te[2] - dt_s)
    plant._sw_u = advance_phase(u0, dt_s, f)
    # the ADC reads the period's end when a sample falls there (within PHASE_EPS), else its held sample
    plant._adc_live = ts <= dt_s + PHASE_EPS / f
    plant.t_s += dt_s
    plant._sense()
    plant.i_bus = plant._bus_average(energy, dt_s)
