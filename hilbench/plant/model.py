"""Scalar PMSM plant: averaged inverter, dq-frame motor, mechanics, hall/encoder/ADC sensors.

Model (amplitude-invariant Clarke/Park, theta = rotor d-axis electrical angle, 0 = phase-1 axis):

    Ld did/dt = vd - Rs id + we Lq iq
    Lq diq/dt = vq - Rs iq - we (Ld id + psi)
    Te = 1.5 p (psi iq + (Ld - Lq) id iq)
    J dwm/dt = Te - B wm - Tc sign(wm) - T_load
    dtheta/dt = we = p wm

Integration: classic RK4 in the dq frame, `substeps` RK4 steps per period (default
DEFAULT_SUBSTEPS). The inverter's alpha-beta voltage is held over the period (it is the period
average of the PWM) and Park-transformed with each stage's own angle, so a rotating rotor sees
the correct rotating voltage. Accuracy against scipy DOP853 (tests/test_plant_accuracy.py) and
cost: see the README of benchmarks/bench_plant.py and the report in the git log.

Two backends with the same per-period arithmetic (tests/test_plant_backends.py checks they agree):
"c" (hilbench/plant/_plantcore.c, an optional compiled extension; PWM and LOW_SIDE periods and
the zero-current OFF coast run in C) and "python" (this file). `Plant(...)` picks "c" when the
extension is importable unless HILBENCH_PLANT_BACKEND=python (or backend="python") asks otherwise;
`plant.backend` says which one runs.

Coulomb friction with stiction: at rest the rotor stays exactly at rest while |Te - T_load| <= Tc;
when moving, the friction sign is frozen over a substep (the ODE stays smooth for RK4) and a
speed that crosses zero inside a substep is set to zero and the rotor sticks again.

Sensors (`i_a, i_b, i_c, i_bus, encoder_count, hall_bits, last_edge_s`) are plain attributes
refreshed at the end of every step, so the bench reads them at attribute cost.

Protection (ProtectionParams): an overcurrent comparator on the end-of-period phase currents sets
`fault_input` (latched; the bench clears it) and, with `gate_off_on_fault`, every later period runs
OFF until it is cleared: the board's hardware trip, whatever the firmware does.

Output modes: PWM (1) averaged duties; LOW_SIDE (2) the three phases shorted to the negative rail;
OFF (0, and the reserved 3) all six switches open: see `_step_off`.
"""

from __future__ import annotations

import math
import operator
import os
import struct
from collections import deque
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from hilbench.plant import switching
from hilbench.plant.params import ADC_ROLE_CODES, LoadProfile, PlantParams
from hilbench.plant.period import MAX_STEP_US, Period

try:  # the optional compiled core (setup.py builds it when a C compiler is present)
    from hilbench.plant import _plantcore
except ImportError:  # pragma: no cover - depends on the build
    _plantcore = None

__all__ = [
    "Plant", "PlantOutput", "OUTPUTS", "HALL_BY_SECTOR", "OUTPUT_OFF", "OUTPUT_PWM", "OUTPUT_LOW_SIDE",
    "DEFAULT_SUBSTEPS", "RPM_PER_RAD_S", "available_backends",
]

OUTPUT_OFF = 0
OUTPUT_PWM = 1
OUTPUT_LOW_SIDE = 2

TWO_PI = 2.0 * math.pi
SIXTY = math.pi / 3.0
SQRT3 = math.sqrt(3.0)
INV_SQRT3 = 1.0 / SQRT3
HALF_SQRT3 = 0.5 * SQRT3
# AN1017 Table 8 in the forward direction: sector 0..5 -> hall bits (bit0 A, bit1 B, bit2 C).
HALL_BY_SECTOR = (0b100, 0b110, 0b010, 0b011, 0b001, 0b101)
# Sector 0 (CBA 100) starts at theta_e = 210 deg for offset 0 (docs/facts.md §2.5).
SECTOR0_START_RAD = math.radians(210.0)
NOISE_BLOCK = 4096
OFF_SUBSTEPS = 8
RPM_PER_RAD_S = 60.0 / TWO_PI
#: the longest period `set_period` takes, in steps of MAX_STEP_US (the C core's edge list holds one per step)
MAX_CHUNKS = 256
#: the longest actuation delay `set_period` takes, in periods
MAX_DELAY_PERIODS = 1000


@dataclass(frozen=True)
class PlantOutput:
    """One quantity a recording keeps of the plant every period, after the period's step: the
    plant's attribute ``source`` (SI units; a double member of the C core) as the raw field
    ``field``, recorded as the column ``column`` = field × ``scale`` in ``unit``."""

    source: str
    field: str
    column: str
    unit: str
    scale: float = 1.0
    fmt: str = "%.5f"
    wrap: float = 0.0  # the column is kept within [0, wrap) (an angle); 0: not wrapped


#: what the plant records every period, in order (`append_state` appends them as doubles); a new
#: recorded quantity is a line here and the attribute in both backends (the C core's struct)
OUTPUTS: tuple[PlantOutput, ...] = (
    PlantOutput("theta_e", "theta_e_rad", "theta_e_deg", "deg", 180.0 / math.pi, "%.3f", 360.0),
    PlantOutput("w_m", "w_m_rad_s", "speed_rpm", "rpm", RPM_PER_RAD_S, "%.3f"),
    PlantOutput("i_a", "ia_a", "ia_a", "A"),
    PlantOutput("i_b", "ib_a", "ib_a", "A"),
    PlantOutput("i_c", "ic_a", "ic_a", "A"),
    PlantOutput("i_bus", "ibus_a", "ibus_a", "A"),
    PlantOutput("load_nm", "load_nm", "load_nm", "N*m"),
    PlantOutput("te_nm", "te_nm", "torque_nm", "N*m"),  # the electrical torque 1.5 p (psi iq + (Ld - Lq) id iq)
)

DEFAULT_SUBSTEPS = 2  # energy balance 1.7e-7 at 50 us (1 step: 2.7e-6); C cost +0.17 us/period
N_ROLES = 6

#: the largest angle (rad) an RK4 stage turns by polynomial: at 20 kHz in 2 substeps stage 4 (a
#: whole substep) reaches it at p * w_m = 2500 rad/s electrical, stages 2-3 (half a substep) at 5000;
#: beyond it a stage calls cos and sin (the result is then the direct one). The polynomials'
#: truncation is below 3e-19 there, under a rounding of the sum.
TURN_MAX_RAD = 0.0625
_C2, _C4, _C6, _C8 = 0.5, 1.0 / 24.0, 1.0 / 720.0, 1.0 / 40320.0
_S3, _S5, _S7, _S9 = 1.0 / 6.0, 1.0 / 120.0, 1.0 / 5040.0, 1.0 / 362880.0


def _turned(c: float, s: float, x: float, d: float) -> tuple[float, float]:
    """cos and sin of x - d from c = cos x and s = sin x: a stage of RK4 turns the voltage's angle by
    a small d, so Taylor polynomials of d and a rotation replace two libm calls. _plantcore.c's
    `turned` is the same arithmetic in the same order (the backends stay bit-identical)."""
    if -TURN_MAX_RAD <= d <= TURN_MAX_RAD:
        d2 = d * d
        cd = 1.0 - d2 * (_C2 - d2 * (_C4 - d2 * (_C6 - d2 * _C8)))
        sd = d * (1.0 - d2 * (_S3 - d2 * (_S5 - d2 * (_S7 - d2 * _S9))))
        return c * cd + s * sd, s * cd - c * sd
    x = x - d
    return math.cos(x), math.sin(x)


def available_backends() -> tuple[str, ...]:
    """Backends this installation can run ("python" always; "c" when the extension was built)."""
    return ("c", "python") if _plantcore is not None else ("python",)


def _choose_backend(backend: str | None) -> str:
    choice = backend or os.environ.get("HILBENCH_PLANT_BACKEND", "") or ("c" if _plantcore is not None else "python")
    if choice not in ("c", "python"):
        raise ValueError(f"Plant backend {choice!r}: expected 'c' or 'python'")
    if choice == "c" and _plantcore is None:
        raise ValueError("Plant backend 'c': hilbench.plant._plantcore is not built (pip install . with a C compiler)")
    return choice


class Plant:
    """One motor on one inverter. `step()` integrates one period; sensors are read after it."""

    backend = "python"

    def __new__(cls, params: PlantParams, seed: int = 0, *, substeps: int = DEFAULT_SUBSTEPS,
                backend: str | None = None) -> "Plant":
        if cls is Plant and _choose_backend(backend) == "c":
            cls = _CPlant
        return super().__new__(cls)

    def __init__(self, params: PlantParams, seed: int = 0, *, substeps: int = DEFAULT_SUBSTEPS,
                 backend: str | None = None) -> None:
        if int(substeps) < 1:
            raise ValueError(f"Plant substeps {substeps}: must be >= 1")
        self._substeps = int(substeps)
        self.params = params
        m = params.motor
        self._rs = float(m.rs_ohm)
        self._ld = float(m.ld_h)
        self._lq = float(m.lq_h)
        self._psi = float(m.psi_wb)
        self._p = float(m.pole_pairs)
        self._j = float(m.j_kgm2)
        self._b = float(m.b_nms_per_rad)
        self._tc = float(m.coulomb_nm)
        # back-EMF line-line peak per unit mechanical speed (the OFF coast test)
        self._ell = SQRT3 * self._p * self._psi
        self._ld_lq = self._ld - self._lq  # the reluctance torque's inductance difference
        inv = params.inverter
        self.vbus_v = float(inv.vbus_v)
        self._dt_duty = float(inv.dead_time_s * inv.pwm_freq_hz) if inv.dead_time_enabled else 0.0
        self._bridge = switching.BridgeConstants.of(params)  # None: the averaged inverter
        prot = params.protection
        self._oc = float(prot.overcurrent_a)  # the board's comparator on |phase current| (0: none)
        self._gate_off = bool(prot.gate_off_on_fault)
        self._hall_base = (SECTOR0_START_RAD + math.radians(params.hall.offset_deg)) % TWO_PI
        enc = params.encoder
        self._enc_cpt = 4 * int(enc.lines)
        self._enc_sign = -1 if enc.reverse else 1
        self._enc_offset = int(enc.offset_counts)
        self._enc_idx = int(enc.index_counts) % self._enc_cpt
        # ADC: one (gain, offset, noise, largest code) per role number, None for an absent role
        tab: list[tuple[float, float, float, float] | None] = [None] * N_ROLES
        for ch in params.adc:
            tab[ADC_ROLE_CODES[ch.role]] = (float(ch.gain_codes_per_unit), float(ch.offset_codes), float(ch.noise_lsb),
                                            float((1 << int(ch.bits)) - 1))
        self._adc_tab = tab
        self._rng = np.random.Generator(np.random.PCG64(seed))
        self._noise: list[float] = []
        self._noise_i = 0
        ild = 1.0 / self._ld
        ilq = 1.0 / self._lq
        ij = 1.0 / self._j
        k15 = 1.5 * self._p
        self._hot = hot = (
            self._rs * ild, self._rs * ilq, self._p * self._lq * ild, self._p * self._ld * ilq,
            self._p * self._psi * ilq, self._p, ild, ilq, k15 * self._psi * ij,
            k15 * (self._ld - self._lq) * ij, ij,
        )
        (self._rd, self._rq, self._pq, self._pd, self._ppsi, _p, self._ild, self._ilq,
         self._kt, self._kr, self._ijv) = hot
        self.pot_fraction = 0.0
        self.track_energy = False
        self.t_s = 0.0
        self._load = params.load
        self.outputs = OUTPUTS
        self._outputs_get = operator.attrgetter(*(out.source for out in OUTPUTS))
        self._outputs_struct = struct.Struct("<" + "d" * len(OUTPUTS))
        self.reset()
        self.set_period(MAX_STEP_US)

    # ----------------------------------------------------------------- state
    def reset(self, *, theta_e: float = 0.0, speed_rad_s: float = 0.0) -> None:
        """Standstill (or a given mechanical speed) at electrical angle theta_e, zero currents."""
        self.i_d = 0.0
        self.i_q = 0.0
        self.w_m = float(speed_rad_s)
        th = float(theta_e)
        self._turns = math.floor(th / TWO_PI)
        self._th = th - self._turns * TWO_PI
        self.t_s = 0.0
        self._periods = 0
        self._edges: list[tuple[float, int]] = []
        self._index_marks: list[float] = []
        self.fault_input = False  # the overcurrent comparator's latched output (the target's FAULT input)
        self._stuck = self.w_m == 0.0 and self._tc > 0.0
        self._nidx = math.floor((self._th - self._hall_base) / SIXTY)
        self._sector = self._nidx % 6
        self._dturns = 0
        self._w_start = self.w_m
        self._tl_now = 0.0
        self._update_load()
        self.hall_bits = HALL_BY_SECTOR[self._sector]
        self.last_edge_s: float | None = None
        self._da = self._db = self._dc = 0.5
        self._last_mode = OUTPUT_OFF
        n0 = math.floor((self._turns + self._th / TWO_PI) * self._enc_cpt / self._p)
        self._enc_m = (n0 - self._enc_idx) // self._enc_cpt  # index marks passed, counted from below
        # energy accounts (J), integrated only when track_energy is set
        self.e_in_j = 0.0
        self.e_cu_j = 0.0
        self.e_fric_j = 0.0
        self.e_load_j = 0.0
        switching.reset(self)
        self._sense()

    def _sense(self) -> None:
        """Refresh the sensor attributes from the state (the end of a step; same order in C)."""
        self._sense_currents()
        mode = self._last_mode
        if mode == OUTPUT_PWM:
            self.i_bus = self._da * self.i_a + self._db * self.i_b + self._dc * self.i_c
        elif mode == OUTPUT_LOW_SIDE:
            self.i_bus = 0.0
        else:  # the diodes return the negative phase currents to the bus
            ia, ib, ic = self.i_a, self.i_b, self.i_c
            self.i_bus = (ia if ia < 0.0 else 0.0) + (ib if ib < 0.0 else 0.0) + (ic if ic < 0.0 else 0.0)
        self._sense_encoder()

    def _sense_currents(self) -> None:
        """The phase currents from the dq state, and the board's overcurrent comparator on them
        (it latches `fault_input`); the electrical torque of the same state (recorded)."""
        th = self._th
        c = math.cos(th)
        s = math.sin(th)
        ia = self.i_d * c - self.i_q * s
        ibe = self.i_d * s + self.i_q * c
        ib = -0.5 * ia + HALF_SQRT3 * ibe
        ic = -0.5 * ia - HALF_SQRT3 * ibe
        self.i_a = ia
        self.i_b = ib
        self.i_c = ic
        oc = self._oc
        if oc > 0.0 and (ia > oc or ia < -oc or ib > oc or ib < -oc or ic > oc or ic < -oc):
            self.fault_input = True
        self.te_nm = 1.5 * self._p * self.i_q * (self._psi + self._ld_lq * self.i_d)

    def _compare_now(self) -> None:
        """The overcurrent comparator between two sensor reads (the switching bridge's interval
        ends, where its ripple peaks): no phase current can exceed |i_dq|, so the phases are only
        computed when that does."""
        oc = self._oc
        if self.i_d * self.i_d + self.i_q * self.i_q > oc * oc:
            ia, ib, ic = self._abc_now()
            if ia > oc or ia < -oc or ib > oc or ib < -oc or ic > oc or ic < -oc:
                self.fault_input = True

    def _sense_encoder(self) -> None:
        """The quadrature encoder's x4 count from the unwrapped angle, and whether an index mark
        passed since the last refresh."""
        n = math.floor((self._turns + self._th / TWO_PI) * self._enc_cpt / self._p)
        self.encoder_count = (self._enc_sign * n + self._enc_offset) & 0xFFFF
        m = (n - self._enc_idx) // self._enc_cpt
        self.encoder_index = m != self._enc_m
        self._enc_m = m

    @property
    def encoder_ab(self) -> tuple[int, int]:
        """Levels of the encoder's A and B channels now: x4 state (A, B) = 00, 10, 11, 01 in
        order of increasing count, so A leads B when the count rises (forward, unless reversed)."""
        return ((0, 0), (1, 0), (1, 1), (0, 1))[self.encoder_count & 3]

    @property
    def theta_e(self) -> float:
        """Electrical rotor angle in [0, 2 pi)."""
        return self._th

    @property
    def theta_m_total(self) -> float:
        """Unwrapped mechanical angle (rad) since reset."""
        return (self._turns * TWO_PI + self._th) / self._p

    @property
    def speed_rpm(self) -> float:
        return self.w_m * 60.0 / TWO_PI

    @property
    def sector(self) -> int:
        return self._sector

    @property
    def substeps(self) -> int:
        """RK4 steps per period."""
        return self._substeps

    @property
    def i_abc(self) -> tuple[float, float, float]:
        """Phase currents (A) at the end of the last step."""
        return (self.i_a, self.i_b, self.i_c)

    @property
    def torque_nm(self) -> float:
        return 1.5 * self._p * self.i_q * (self._psi + (self._ld - self._lq) * self.i_d)

    @property
    def load_torque_nm(self) -> float:
        """Constant part of the load (setting it replaces the profile with a constant load)."""
        return self.load.torque_nm if self.load.kind != "step" or self.t_s < self.load.step_time_s else self.load.step_torque_nm

    @load_torque_nm.setter
    def load_torque_nm(self, value: float) -> None:
        self.load = LoadProfile("constant", torque_nm=float(value))

    @property
    def load(self) -> LoadProfile:
        return self._load

    @load.setter
    def load(self, profile: LoadProfile) -> None:
        self._load = profile
        self._update_load()

    def _update_load(self) -> None:
        """Cache the load terms for the hot path; remember when a step load changes next."""
        tl, kl, kq, locked = self._load_terms()
        self._tl = tl
        self.load_nm = tl  # the constant part of the load now, as a plain attribute for recorders
        self._kv = self._b + kl
        self._kq_any = kq != 0.0
        self._locked = locked
        ld = self._load
        if locked:
            self.w_m = 0.0
        pending = ld.kind == "step" and self.t_s < ld.step_time_s - 1e-12
        self._t_load_change = ld.step_time_s if pending else math.inf

    @property
    def magnetic_energy_j(self) -> float:
        return 0.75 * (self._ld * self.i_d * self.i_d + self._lq * self.i_q * self.i_q)

    @property
    def kinetic_energy_j(self) -> float:
        return 0.5 * self._j * self.w_m * self.w_m

    # ----------------------------------------------------------------- sensors
    def sense(self, roles: Sequence[int]) -> tuple[int, bool, bool, int, tuple[int, ...]]:
        """What the board's sensors read after the last step, in one call (the bench's hot loop):
        (hall_bits, fault_input, encoder_index, encoder_count, adc_codes(roles))."""
        return self.hall_bits, self.fault_input, self.encoder_index, self.encoder_count, self.adc_codes(roles)

    def adc_codes(self, roles: Sequence[int]) -> tuple[int, ...]:
        """ADC codes (each channel's own bits) for the given ADC roles (docs/design.md role numbers); NONE -> 0.

        Per-role gain/offset/noise precomputed; Gaussian noise from a pre-drawn block."""
        tab = self._adc_tab
        out = []
        for r in roles:
            ch = tab[r]
            if ch is None:
                out.append(0)
                continue
            if r == 4:
                x = self.i_a if self._adc_live else self._ia_s
            elif r == 2:
                x = self.i_bus
            elif r == 5:
                x = self.i_b if self._adc_live else self._ib_s
            elif r == 3:
                x = self.vbus_v
            else:
                x = self.pot_fraction
            g, v, nz, top = ch
            v += g * x
            if nz:
                i = self._noise_i
                noise = self._noise
                if i >= len(noise):
                    noise = self._draw_noise()
                    i = 0
                self._noise_i = i + 1
                v += nz * noise[i]
            code = math.floor(v + 0.5)
            out.append(0 if code < 0 else int(top) if code > top else code)
        return tuple(out)

    def append_state(self, buf: bytearray) -> None:
        """Append the recorded `outputs` (end of the last step) to a recorder's row buffer as
        little-endian doubles, in one call."""
        buf.extend(self._outputs_struct.pack(*self._outputs_get(self)))

    def _draw_noise(self) -> list[float]:
        """The next block of standard-normal ADC noise (both backends draw the same blocks)."""
        self._noise = self._rng.standard_normal(NOISE_BLOCK).tolist()
        self._noise_i = 0
        return self._noise

    # ----------------------------------------------------------------- load
    def _load_terms(self) -> tuple[float, float, float, bool]:
        """(constant torque, linear coeff, quadratic coeff, locked) for the period starting now."""
        ld = self.load
        k = ld.kind
        if k == "constant":
            return ld.torque_nm, 0.0, 0.0, False
        if k == "step":
            return (ld.step_torque_nm if self.t_s >= ld.step_time_s - 1e-12 else ld.torque_nm), 0.0, 0.0, False
        if k == "linear":
            return ld.torque_nm, ld.coeff, 0.0, False
        if k == "quadratic":
            return ld.torque_nm, 0.0, ld.coeff, False
        return ld.torque_nm, 0.0, 0.0, True

    # ----------------------------------------------------------------- the exchange period
    def set_period(self, period_us: int, actuation_delay_periods: int = 0, duty_full_scale: float = 1.0) -> None:
        """The period `advance` integrates (in chunks of at most MAX_STEP_US), the whole periods the
        duties wait before they reach the switches (the delay starts with all switches open) and the
        full scale of the duties `advance` gets (a PWM period's counts; 1.0: fractions)."""
        period = Period(int(period_us))
        if period.chunks > MAX_CHUNKS:
            raise ValueError(f"Plant.set_period: {period_us} us is more than {MAX_CHUNKS} steps of {MAX_STEP_US} us")
        if not 0 <= int(actuation_delay_periods) <= MAX_DELAY_PERIODS:
            raise ValueError(f"Plant.set_period: actuation delay {actuation_delay_periods} is not 0..{MAX_DELAY_PERIODS} periods")
        if not duty_full_scale > 0:
            raise ValueError(f"Plant.set_period: duty full scale {duty_full_scale!r} is not positive")
        self.period = period
        self._duty_scale = 1.0 / duty_full_scale
        self._period_s = period.s
        self._chunks = period.chunks
        self._chunk_s = period.chunk_s
        self._periods = round(self.t_s / period.s)  # the plant's clock in whole periods (0 when fresh)
        self._pending: deque[tuple[float, float, float, int]] = deque()
        self._delay = int(actuation_delay_periods)
        if self._delay:  # the delay's queue in front of the period (rare: a plain method call otherwise)
            self.advance = self._advance_delayed  # type: ignore[method-assign]
        else:
            self.__dict__.pop("advance", None)

    def _advance_delayed(self, duty_a: float, duty_b: float, duty_c: float, output_mode: int,
                         state_to: bytearray | None = None, /) -> float | None:
        """`advance` with the duties of ``actuation_delay_periods`` periods before (all switches open
        until the first of them arrives)."""
        pending = self._pending
        pending.append((duty_a, duty_b, duty_c, output_mode))
        if len(pending) > self._delay:
            return type(self).advance(self, *pending.popleft(), state_to)
        return type(self).advance(self, 0.0, 0.0, 0.0, OUTPUT_OFF, state_to)

    def _advance_py(self, duty_a: float, duty_b: float, duty_c: float, output_mode: int,
                    state_to: bytearray | None = None, /) -> float | None:
        """One exchange period (`set_period`) with these duties (in counts of its full scale) held
        over it: its chunks, the clock, and the recorded outputs appended to ``state_to`` (a
        recorder's row buffer, or None).
        Returns the time of the period's last hall edge from its start (None: no edge); `edges()`
        has every one."""
        if state_to is not None and not isinstance(state_to, bytearray):
            raise TypeError("Plant.advance: state_to must be a bytearray (a recorder's row buffer) or None")
        scale = self._duty_scale
        duty_a, duty_b, duty_c = duty_a * scale, duty_b * scale, duty_c * scale
        h = self._chunk_s
        edges: list[tuple[float, int]] = []
        marks: list[float] = []
        edge_s = None
        for i in range(self._chunks):  # long periods: the plant keeps its accurate step, duties held
            self._step_py(duty_a, duty_b, duty_c, output_mode, h)
            if self.last_edge_s is not None:
                edge_s = i * h + self.last_edge_s
                edges.append((edge_s, self.hall_bits))
            if self.encoder_index:  # an index mark passed in this chunk: timed at its start
                marks.append(i * h)
        self._edges = edges
        self._index_marks = marks
        self.encoder_index = bool(marks)  # a mark anywhere in the period, not only in its last chunk
        self.last_edge_s = edge_s
        self._periods += 1
        self.t_s = self._periods * self._period_s  # one time base: k periods are Period.t_s(k)
        if state_to is not None:
            self.append_state(state_to)
        return edge_s

    advance = _advance_py

    def edges(self) -> tuple[tuple[float, int], ...]:
        """Every hall edge of the last `advance`: (time from the period's start in s, the hall bits
        after it), in order; one per chunk of at most MAX_STEP_US (two sector changes in 50 us
        would be above 40 000 rpm with five pole pairs)."""
        return tuple(self._edges)

    def index_marks(self) -> tuple[float, ...]:
        """The encoder's index marks of the last `advance`: the start of each chunk (at most MAX_STEP_US)
        in which one passed, from the period's start, in order (a period of one chunk: its start, where
        a target that reads only Sensors.inputs' INDEX bit takes it too)."""
        return tuple(self._index_marks)

    # ----------------------------------------------------------------- one step, by physics
    def step(self, duty_a: float, duty_b: float, duty_c: float, output_mode: int, dt_s: float,
             state_to: bytearray | None = None, /) -> float | None:
        """Integrate ``dt_s`` with the duties held (`_step_py`); returns `last_edge_s`. With
        ``state_to`` the recorded outputs are appended to that row buffer after the step (the C
        backend has the same signature). The bench uses `advance`; this is the plant's one step."""
        if state_to is not None and not isinstance(state_to, bytearray):
            raise TypeError("Plant.step: state_to must be a bytearray (a recorder's row buffer) or None")
        self._step_py(duty_a, duty_b, duty_c, output_mode, dt_s)
        if state_to is not None:
            self.append_state(state_to)
        return self.last_edge_s

    def _step_py(self, duty_a: float, duty_b: float, duty_c: float, output_mode: int, dt_s: float) -> None:
        """Integrate ``dt_s`` with the duties (fractions 0..1) held over it: the Python backend and
        the readable reference of the C core (`_plantcore.c` has the same functions in the same
        order; it calls this for the cases it leaves to Python). The board's comparator gates the
        switches, the inverter makes the voltage, the motor and its mechanics move, the sensors
        read the result."""
        if self.fault_input and self._gate_off:  # the comparator's hardware trip: every switch open
            output_mode = OUTPUT_OFF
        bridge = self._bridge
        u0 = 0.0
        if bridge is not None:  # the switching inverter, or the averaged one's carrier (hilbench/plant/switching.py)
            if bridge.switching and output_mode == OUTPUT_PWM:
                switching.step_pwm(self, duty_a, duty_b, duty_c, dt_s)
                return
            u0 = switching.idle(self, dt_s)
        if output_mode == OUTPUT_PWM:
            va, vb = self._averaged_inverter(duty_a, duty_b, duty_c, u0, dt_s)
        elif output_mode == OUTPUT_LOW_SIDE:
            va = vb = 0.0
        else:
            self._step_switches_open(dt_s)
            return
        self._last_mode = output_mode
        if self.track_energy or self._kq_any:
            self._step_general(va, vb, dt_s)
        else:
            self._step_dq(va, vb, dt_s)

    def _averaged_inverter(self, duty_a: float, duty_b: float, duty_c: float, u0: float,
                           dt_s: float) -> tuple[float, float]:
        """The averaged inverter: the alpha-beta voltage of the phases' duties over the step (the
        period average of the PWM), each duty shortened or lengthened by the dead time against its
        phase current's sign; with average_dead_time = "edges", by the dead time of each PWM edge
        in the step (switching.average_dead_time; u0: the carrier's phase at the step's start).
        The switching inverter sits beside this one (hilbench/plant/switching.py)."""
        dtd = self._dt_duty
        if dtd and self._bridge is not None:  # average_dead_time = "edges"
            duty_a, duty_b, duty_c = switching.average_dead_time(self, u0, duty_a, duty_b, duty_c, dt_s)
        elif dtd:
            ia = self.i_a
            ib = self.i_b
            ic = self.i_c
            duty_a = min(1.0, max(0.0, duty_a - (dtd if ia > 0.0 else -dtd if ia < 0.0 else 0.0)))
            duty_b = min(1.0, max(0.0, duty_b - (dtd if ib > 0.0 else -dtd if ib < 0.0 else 0.0)))
            duty_c = min(1.0, max(0.0, duty_c - (dtd if ic > 0.0 else -dtd if ic < 0.0 else 0.0)))
        self._da = duty_a
        self._db = duty_b
        self._dc = duty_c
        vbus = self.vbus_v
        return vbus * (2.0 * duty_a - duty_b - duty_c) / 3.0, vbus * (duty_b - duty_c) * INV_SQRT3

    def _step_switches_open(self, dt_s: float) -> None:
        """Every switch open: the windings conduct through the freewheel diodes (`_step_off`)."""
        self._last_mode = OUTPUT_OFF
        th0 = self._th
        self.last_edge_s = None
        e_in0 = self.e_in_j
        self._step_off(dt_s)
        self._finish(th0, self._th - th0 + self._dturns * TWO_PI, dt_s, 0.0)
        self.t_s += dt_s
        self._sense()
        self.i_bus = self._bus_average(self.e_in_j - e_in0, dt_s)

    def _step_general(self, va: float, vb: float, dt_s: float) -> None:
        """The general integrator (energy accounts, a quadratic load): `_rk4_general` per substep."""
        h = dt_s / self._substeps
        self.last_edge_s = None
        e_in0 = self.e_in_j
        for j in range(self._substeps):
            th0 = self._th
            self._rk4_general(va, vb, h)
            self._finish(th0, self._th - th0 + self._dturns * TWO_PI, h, j * h)
        self.t_s += dt_s
        self._sense()
        self.i_bus = self._bus_average(self.e_in_j - e_in0, dt_s)

    def _step_dq(self, va: float, vb: float, dt_s: float) -> None:
        """The motor in its rotor frame under a held alpha-beta voltage: `substeps` RK4 steps of the
        currents, speed and angle (`_rk4_dq`), the friction state before each (`_friction`), the
        hall sector and edge after each (`_rotate`), then the sensors. The held voltage is carried
        as magnitude and angle: vd = V cos(phi - theta), vq = V sin(phi - theta)."""
        if self._t_load_change <= self.t_s + 1e-12:
            self._update_load()
        vmag = math.sqrt(va * va + vb * vb)
        phi = math.atan2(vb, va)
        h = dt_s / self._substeps
        id0 = self.i_d
        iq0 = self.i_q
        w0 = self.w_m
        th0 = self._th
        n0 = self._nidx
        edge = None
        e_in = 0.0  # the step's input energy / (1.5 |v|): RK4 quadrature of vd id + vq iq
        for j in range(self._substeps):
            ij, fr, w0 = self._friction(id0, iq0, w0)
            id0, iq0, w1, dth, e_part = self._rk4_dq(id0, iq0, w0, phi - th0, vmag, ij, fr, h)
            e_in += e_part
            if fr != 0.0 and w0 != 0.0 and (w1 > 0.0) != (w0 > 0.0):
                w1 = 0.0  # speed crossed zero under Coulomb friction: stick
                self._stuck = True
            th0, n0, sub_edge = self._rotate(th0, dth, n0, w0, w1, h)
            if sub_edge is not None:
                edge = j * h + sub_edge
            w0 = w1
        self.i_d = id0
        self.i_q = iq0
        self.w_m = w0
        self._nidx = n0
        self._th = th0
        self.hall_bits = HALL_BY_SECTOR[self._sector]
        self.last_edge_s = edge
        self.t_s += dt_s
        self._sense_currents()
        self.i_bus = self._bus_average(1.5 * vmag * e_in, dt_s)
        self._sense_encoder()

    def _friction(self, i_d: float, i_q: float, w: float) -> tuple[float, float, float]:
        """Mechanics over the next substep: (1/J or 0 while held, the Coulomb friction's signed
        torque frozen over it, the speed). A locked rotor and a stuck one (|Te - T_load| within
        the Coulomb torque) do not move; a stuck rotor breaks away against the net torque."""
        tc = self._tc
        if self._locked:
            return 0.0, 0.0, 0.0
        if self._stuck:
            net = (self._kt + self._kr * i_d) * i_q * self._j - self._tl
            if -tc <= net <= tc:
                return 0.0, 0.0, w
            self._stuck = False
            return self._ijv, tc if net > 0.0 else -tc, w
        return self._ijv, tc if w > 0.0 else -tc if w < 0.0 else 0.0, w

    def _rk4_dq(self, id0: float, iq0: float, w0: float, x0: float, vmag: float, ij: float, fr: float,
                h: float) -> tuple[float, float, float, float, float]:
        """One classic RK4 step of (i_d, i_q, w_m) and the angle it turns, with x = phi - theta the
        voltage's angle in the rotor frame: returns (i_d, i_q, w_m, dtheta, input energy part).
        The trigonometry once per step: stages 2-4 turn stage 1's cos and sin (`_turned`)."""
        turned = _turned
        rd, rq, pq, pd, ppsi, p, ild, ilq, kt, kr, _ = self._hot
        vdm = vmag * ild
        vqm = vmag * ilq
        h2 = 0.5 * h
        h6 = h / 6.0
        ftj = (fr + self._tl) * ij
        kvj = self._kv * ij
        if ij == 0.0:
            ktj = krj = 0.0
        else:
            ktj = kt
            krj = kr
        # stage 1
        c0 = c = math.cos(x0)
        s0 = s = math.sin(x0)
        p1 = c * id0 + s * iq0
        k1d = vdm * c + w0 * pq * iq0 - rd * id0
        k1q = vqm * s - w0 * (pd * id0 + ppsi) - rq * iq0
        k1w = iq0 * (ktj + krj * id0) - kvj * w0 - ftj
        # stage 2
        a = id0 + h2 * k1d
        b = iq0 + h2 * k1q
        w = w0 + h2 * k1w
        c, s = turned(c0, s0, x0, h2 * p * w0)
        p2 = c * a + s * b
        k2d = vdm * c + w * pq * b - rd * a
        k2q = vqm * s - w * (pd * a + ppsi) - rq * b
        k2w = b * (ktj + krj * a) - kvj * w - ftj
        w2 = w
        # stage 3
        a = id0 + h2 * k2d
        b = iq0 + h2 * k2q
        w = w0 + h2 * k2w
        c, s = turned(c0, s0, x0, h2 * p * w2)
        p3 = c * a + s * b
        k3d = vdm * c + w * pq * b - rd * a
        k3q = vqm * s - w * (pd * a + ppsi) - rq * b
        k3w = b * (ktj + krj * a) - kvj * w - ftj
        w3 = w
        # stage 4
        a = id0 + h * k3d
        b = iq0 + h * k3q
        w = w0 + h * k3w
        c, s = turned(c0, s0, x0, h * p * w3)
        p4 = c * a + s * b
        k4d = vdm * c + w * pq * b - rd * a
        k4q = vqm * s - w * (pd * a + ppsi) - rq * b
        k4w = b * (ktj + krj * a) - kvj * w - ftj
        return (id0 + h6 * (k1d + 2.0 * (k2d + k3d) + k4d), iq0 + h6 * (k1q + 2.0 * (k2q + k3q) + k4q),
                w0 + h6 * (k1w + 2.0 * (k2w + k3w) + k4w), h6 * p * (w0 + 2.0 * (w2 + w3) + w),
                h6 * (p1 + 2.0 * (p2 + p3) + p4))

    def _rotate(self, th0: float, dth: float, n0: int, w0: float, w1: float, h: float) -> tuple[float, int, float | None]:
        """The rotor turned by dth over a substep: its new angle (wrapped to [0, 2 pi)) and hall
        sector index, and the time of the substep's hall edge (None: no sector change)."""
        th1 = th0 + dth
        n1 = math.floor((th1 - self._hall_base) / SIXTY)
        edge = None
        if n1 != n0:
            edge = self._edge(th0, th1, n0, n1, self._p * w0, self._p * w1, h)
            self._sector = n1 % 6
        if th1 >= TWO_PI or th1 < 0.0:
            k = math.floor(th1 / TWO_PI)
            self._turns += k
            th1 -= k * TWO_PI
            n1 -= 6 * k
        return th1, n1, edge

    def _bus_average(self, e_in_j: float, dt_s: float) -> float:
        """The period's average bus current: the energy the inverter drew over it / (Vbus dt).
        With the phases' own duties (or diodes) it is the mean of sum(d_x i_x), not the end sample."""
        vbus = self.vbus_v
        return e_in_j / (vbus * dt_s) if vbus > 0.0 and dt_s > 0.0 else 0.0

    def _finish(self, th0: float, dth: float, h: float, t_off: float) -> None:
        """Sector/edge bookkeeping after a (sub)step done outside the hot path (angle already
        wrapped); an edge is timed at t_off + its time inside the substep."""
        th1 = th0 + dth
        base = self._hall_base
        n0 = math.floor((th0 - base) / SIXTY)
        n1 = math.floor((th1 - base) / SIXTY)
        if n1 != n0:
            self.last_edge_s = t_off + self._edge(th0, th1, n0, n1, self._p * self._w_start, self._p * self.w_m, h)
            self._sector = n1 % 6
            self.hall_bits = HALL_BY_SECTOR[self._sector]
        self._nidx = math.floor((self._th - base) / SIXTY)

    def _edge(self, th0: float, th1: float, n0: int, n1: int, we0: float, we1: float, h: float) -> float:
        """Time of the last hall edge inside a (sub)step: Newton on the cubic Hermite theta(t)."""
        target = self._hall_base + (n1 if n1 > n0 else n0) * SIXTY
        d = th1 - th0
        # Hermite on [0, 1]: theta(u) = th0 + a1 u + a2 u^2 + a3 u^3
        a1 = we0 * h
        a2 = 3.0 * d - 2.0 * a1 - we1 * h
        a3 = -2.0 * d + a1 + we1 * h
        g = target - th0
        u = g / d if d != 0.0 else 0.5
        u = 0.0 if u < 0.0 else 1.0 if u > 1.0 else u
        for _ in range(30):
            f = u * (a1 + u * (a2 + u * a3)) - g
            fp = a1 + u * (2.0 * a2 + 3.0 * u * a3)
            if fp == 0.0:
                break
            du = f / fp
            u -= du
            if u < 0.0:
                u = 0.0
            elif u > 1.0:
                u = 1.0
            if abs(du) < 1e-15:
                break
        return u * h

    # ----------------------------------------------------------------- general integrator
    def _deriv(self, idv: float, iqv: float, w: float, th: float, va: float, vb: float,
               kv: float, kq: float, ft: float, ij: float) -> tuple[float, ...]:
        c = math.cos(th)
        s = math.sin(th)
        vd = va * c + vb * s
        vq = vb * c - va * s
        we = self._p * w
        te = 1.5 * self._p * iqv * (self._psi + (self._ld - self._lq) * idv)
        did = (vd - self._rs * idv + we * self._lq * iqv) / self._ld
        diq = (vq - self._rs * iqv - we * (self._ld * idv + self._psi)) / self._lq
        dw = (te - kv * w - kq * w * abs(w) - ft) * ij
        wm = w if ij else 0.0
        p_in = 1.5 * (vd * idv + vq * iqv)
        p_cu = 1.5 * self._rs * (idv * idv + iqv * iqv)
        p_fr = (self._b * wm + (ft - self._tl_now)) * wm
        p_ld = (self._tl_now + (kv - self._b) * wm + kq * wm * abs(wm)) * wm
        return did, diq, dw, we if ij else 0.0, p_in, p_cu, p_fr, p_ld

    def _rk4_general(self, va: float, vb: float, h: float) -> float:
        """One RK4 step with energy accounts; same stiction logic as the hot path. Angle wrapped.
        Returns the step's input energy (J)."""
        tl, kl, kq, locked = self._load_terms()
        self._tl_now = tl
        kv = self._b + kl
        id0, iq0, w0, th0 = self.i_d, self.i_q, self.w_m, self._th
        self._w_start = w0
        if locked:
            ij, fr, w0 = 0.0, 0.0, 0.0
        elif self._stuck:
            net = 1.5 * self._p * iq0 * (self._psi + (self._ld - self._lq) * id0) - tl
            if abs(net) <= self._tc:
                ij, fr = 0.0, 0.0
            else:
                self._stuck = False
                ij, fr = 1.0 / self._j, math.copysign(self._tc, net)
        else:
            ij = 1.0 / self._j
            fr = self._tc if w0 > 0.0 else -self._tc if w0 < 0.0 else 0.0
        ft = fr + tl
        y0 = (id0, iq0, w0, th0, 0.0, 0.0, 0.0, 0.0)
        k1 = self._deriv(*y0[:4], va, vb, kv, kq, ft, ij)
        y = [a + 0.5 * h * b for a, b in zip(y0, k1)]
        k2 = self._deriv(*y[:4], va, vb, kv, kq, ft, ij)
        y = [a + 0.5 * h * b for a, b in zip(y0, k2)]
        k3 = self._deriv(*y[:4], va, vb, kv, kq, ft, ij)
        y = [a + h * b for a, b in zip(y0, k3)]
        k4 = self._deriv(*y[:4], va, vb, kv, kq, ft, ij)
        y1 = [a + h / 6.0 * (b1 + 2.0 * (b2 + b3) + b4) for a, b1, b2, b3, b4 in zip(y0, k1, k2, k3, k4)]
        w1 = y1[2]
        if fr != 0.0 and w0 != 0.0 and (w1 > 0.0) != (w0 > 0.0):
            w1 = 0.0
            self._stuck = True
        self.i_d, self.i_q, self.w_m = y1[0], y1[1], w1
        th1 = y1[3]
        k = math.floor(th1 / TWO_PI)
        self._dturns = k
        self._turns += k
        self._th = th1 - k * TWO_PI
        self.e_in_j += y1[4]
        self.e_cu_j += y1[5]
        self.e_fric_j += y1[6]
        self.e_load_j += y1[7]
        return y1[4]

    # ----------------------------------------------------------------- outputs off
    def _abc_now(self) -> tuple[float, float, float]:
        c = math.cos(self._th)
        s = math.sin(self._th)
        ia = self.i_d * c - self.i_q * s
        ibe = self.i_d * s + self.i_q * c
        return (ia, -0.5 * ia + HALF_SQRT3 * ibe, -0.5 * ia - HALF_SQRT3 * ibe)

    def _phase_currents(self) -> list[float]:
        """Phase currents with transform round-off (< 1e-12 A) of an open phase snapped to zero."""
        return [0.0 if -1e-12 < x < 1e-12 else x for x in self._abc_now()]

    def _set_phase_currents(self, i: list[float]) -> None:
        c = math.cos(self._th)
        s = math.sin(self._th)
        ial = i[0]
        ibe = (i[0] + 2.0 * i[1]) * INV_SQRT3
        self.i_d = ial * c + ibe * s
        self.i_q = -ial * s + ibe * c

    def _step_off(self, dt_s: float) -> None:
        """All six switches open. Each winding conducts only through a freewheel diode: a phase
        carrying positive current (into the motor) is clamped to the negative rail, a negative one
        to the bus. A phase with zero current is open; its terminal floats to the voltage that
        keeps its current at zero, and it starts conducting only if that voltage would leave
        [0, vbus]. A current that reaches zero inside a substep is cut there (crossing found by
        linear interpolation, then set exactly to zero), so currents reach zero and stay there
        while the line back-EMF is below the bus. The rotor coasts. Substeps: OFF_SUBSTEPS per
        period; open-phase currents are projected back to exactly zero after each substep
        (exact for Ld = Lq, a small correction for salient rotors). With zero currents and the
        back-EMF line-line peak below the bus the whole period is one `_coast` step."""
        turns0 = self._turns
        w_start = self.w_m
        vbus = self.vbus_v
        if self.i_d == 0.0 and self.i_q == 0.0 and self._ell * abs(w_start) < vbus:
            # no current and the line back-EMF peak below the bus: no diode can conduct
            self._coast(dt_s)
            self._dturns = self._turns - turns0
            self._w_start = w_start
            return
        t_left = dt_s
        h_nom = dt_s / OFF_SUBSTEPS
        for _guard in range(4 * OFF_SUBSTEPS + 8):
            if t_left <= 1e-15:
                break
            h = min(h_nom, t_left)
            i = self._phase_currents()
            terminals = self._diode_terminals(i, vbus)
            if terminals is None:  # no current and the line back-EMF within the bus: a coast
                self._coast(h)
                t_left -= h
                continue
            t_left -= self._off_substep(h, i, *terminals)
        self._dturns = self._turns - turns0
        self._w_start = w_start

    def _back_emf_abc(self) -> list[float]:
        """The phases' back-EMF now."""
        th = self._th
        we = self._p * self.w_m
        e_al = -we * self._psi * math.sin(th)
        e_be = we * self._psi * math.cos(th)
        return [e_al, -0.5 * e_al + HALF_SQRT3 * e_be, -0.5 * e_al - HALF_SQRT3 * e_be]

    def _diode_terminals(self, i: list[float], vbus: float) -> tuple[list[float], list[int]] | None:
        """The terminal voltages of an open bridge over the next substep and the phases left open:
        a conducting phase sits on the rail its diode clamps it to (positive current: the negative
        rail), an open one floats where its current stays zero unless that leaves [0, vbus]. With
        no current, the phases of the largest and smallest back-EMF start conducting once the line
        back-EMF exceeds the bus; None while it does not (a coast)."""
        e = self._back_emf_abc()
        cond = [x != 0.0 for x in i]
        if not any(cond):
            if max(e) - min(e) <= vbus:
                return None
            hi = e.index(max(e))
            lo = e.index(min(e))
            v = [0.0, 0.0, 0.0]
            v[hi] = vbus
            open_ = [k for k in range(3) if k not in (hi, lo)]
            fixed = {hi, lo}
        else:
            v = [0.0 if x > 0.0 else vbus for x in i]
            open_ = [k for k in range(3) if not cond[k]]
            fixed = {k for k in range(3) if cond[k]}
        return v, self._float_open_phases(v, open_, fixed, e, vbus)

    @staticmethod
    def _float_open_phases(v: list[float], open_: list[int], fixed: set[int], e: list[float], vbus: float) -> list[int]:
        """Each open phase floats to the voltage that keeps its current at zero, or its diode
        clamps it to a rail when that voltage leaves [0, vbus] (then it conducts); returns the
        phases still open (v is set in place)."""
        for o in open_:
            others = [v[k] for k in range(3) if k != o]
            vo = 1.5 * e[o] + 0.5 * (others[0] + others[1])
            if vo > vbus or vo < 0.0:
                v[o] = vbus if vo > vbus else 0.0
                fixed.add(o)
            else:
                v[o] = vo
        return [k for k in range(3) if k not in fixed]

    def _off_substep(self, h: float, i: list[float], v: list[float], still_open: list[int]) -> float:
        """One substep of an open bridge under terminal voltages v: a conducting phase whose current
        changes sign is cut at the crossing (the substep ends there, that phase opens); the open
        phases' currents are projected back to zero. Returns the time integrated."""
        va = (2.0 * v[0] - v[1] - v[2]) / 3.0
        vb = (v[1] - v[2]) * INV_SQRT3
        saved = (self.i_d, self.i_q, self.w_m, self._th, self._turns, self._stuck,
                 self.e_in_j, self.e_cu_j, self.e_fric_j, self.e_load_j)
        self._rk4_general(va, vb, h)
        i_new = self._phase_currents()
        fracs = [1.0, 1.0, 1.0]
        for k in range(3):
            if i[k] != 0.0 and (i_new[k] > 0.0) != (i[k] > 0.0):
                fracs[k] = i[k] / (i[k] - i_new[k])
        frac = min(fracs)
        used = h
        if frac < 1.0:
            (self.i_d, self.i_q, self.w_m, self._th, self._turns, self._stuck,
             self.e_in_j, self.e_cu_j, self.e_fric_j, self.e_load_j) = saved
            used = h * frac
            if used > 0.0:
                self._rk4_general(va, vb, used)
            i_new = self._phase_currents()
            still_open = still_open + [k for k in range(3) if fracs[k] <= frac * (1.0 + 1e-9) + 1e-12]
        self._project(i_new, still_open)
        return used

    def _project(self, i: list[float], open_: list[int]) -> None:
        """Force the open phases' currents to exactly zero, keeping the sum of currents zero."""
        if not open_:
            return
        open_set = set(open_)
        live = [k for k in range(3) if k not in open_set]
        if len(live) < 2:
            self.i_d = 0.0
            self.i_q = 0.0
            return
        a, b = live
        x = 0.5 * (i[a] - i[b])
        out = [0.0, 0.0, 0.0]
        out[a] = x
        out[b] = -x
        if x == 0.0:
            self.i_d = 0.0
            self.i_q = 0.0
            return
        self._set_phase_currents(out)

    def _coast(self, h: float) -> None:
        """Zero currents: mechanics only (one RK4 step on speed, same friction/stiction rules).
        The C core has the same arithmetic (`coast` in _plantcore.c)."""
        self.i_d = 0.0
        self.i_q = 0.0
        tl, kl, kq, locked = self._load_terms()
        kv = self._b + kl
        w0 = self.w_m
        if locked or (self._stuck and abs(tl) <= self._tc):
            self.w_m = 0.0
            return
        if self._stuck:
            self._stuck = False
            fr = -math.copysign(self._tc, tl)
        else:
            fr = math.copysign(self._tc, w0) if w0 != 0.0 else 0.0
        ij = 1.0 / self._j
        a = kv * ij
        c = kq * ij
        f0 = (fr + tl) * ij
        k1 = -a * w0 - c * w0 * abs(w0) - f0
        wa = w0 + 0.5 * h * k1
        k2 = -a * wa - c * wa * abs(wa) - f0
        wb = w0 + 0.5 * h * k2
        k3 = -a * wb - c * wb * abs(wb) - f0
        wc = w0 + h * k3
        k4 = -a * wc - c * wc * abs(wc) - f0
        w1 = w0 + h / 6.0 * (k1 + 2.0 * (k2 + k3) + k4)
        dth = self._p * h / 6.0 * (w0 + 2.0 * (wa + wb) + wc)
        if fr != 0.0 and w0 != 0.0 and (w1 > 0.0) != (w0 > 0.0):
            w1 = 0.0
            self._stuck = True
        self.w_m = w1
        th1 = self._th + dth
        k = math.floor(th1 / TWO_PI)
        self._turns += k
        self._th = th1 - k * TWO_PI


if _plantcore is not None:

    class _CPlant(Plant, _plantcore.Core):
        """Plant whose state lives in the C struct of `_plantcore.Core`; `advance` and `step` are
        the C methods (they call `Plant._step_py` for the steps they leave to Python)."""

        backend = "c"
        step = _plantcore.Core.step
        advance = _plantcore.Core.advance
        edges = _plantcore.Core.edges
        index_marks = _plantcore.Core.index_marks
        adc_codes = _plantcore.Core.adc_codes
        sense = _plantcore.Core.sense
        append_state = _plantcore.Core.append_state
        theta_e = _plantcore.Core.theta_e  # the same read-only angle, without a Python property call

        def _draw_noise(self) -> Any:
            """The next block of standard-normal ADC noise, the same draws as `Plant._draw_noise`,
            kept as a float64 array: the C core reads it in place (no Python float per draw)."""
            self._noise = self._rng.standard_normal(NOISE_BLOCK)
            self._noise_i = 0
            return self._noise

        def span_api(self) -> Any:
            """The C step the session's C span runs (hbglue.h's plant capsule), or None while the
            loop's `sense` or `advance` is not the C core's: an actuation delay's queue in front of
            the period, or a subclass or an instance that put its own in their place (the C span
            would step past them)."""
            cls, mine = type(self), self.__dict__
            if "advance" in mine or "sense" in mine or cls.advance is not _plantcore.Core.advance \
                    or cls.sense is not _plantcore.Core.sense:
                return None
            return _plantcore.SPAN_API

        def __init__(self, params: PlantParams, seed: int = 0, *, substeps: int = DEFAULT_SUBSTEPS,
                     backend: str | None = None) -> None:
            super().__init__(params, seed, substeps=substeps, backend=backend)
            for role, ch in enumerate(self._adc_tab):
                if ch is not None:
                    self._set_adc(role, *ch)
            self._set_outputs(tuple(out.source for out in self.outputs))  # what append_state copies
            bridge = self._bridge
            if bridge is not None:  # the bridge's constants, for _switching.c
                self._sw_on = bridge.switching
                self._sw_avg = not bridge.switching
                self._sw_f, self._sw_td, self._sw_c, self._sw_smp = bridge.freq_hz, bridge.dead_s, bridge.centre, bridge.sample
                self._sw_l = bridge.l_h
else:  # pragma: no cover
    _CPlant = None  # type: ignore[assignment,misc]
