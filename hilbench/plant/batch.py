"""N independent plants stepped together (gain sweeps): the scalar plant's equations and method
(RK4 in dq, alpha-beta voltage held over the period, its dq value taken at every stage,
stiction per plant, hall sector and edge time from a cubic Hermite of theta(t)).

Scope: output modes PWM and LOW_SIDE, loads constant/step/linear/locked (no quadratic load, no
OFF-mode diode model, no dead time, no ADC noise: use `Plant` for those).

`substeps` RK4 steps per period as the scalar plant (default the same). With the compiled core
(hilbench.plant._plantcore.Batch) the per-plant loop runs in C over the state rows; without it
(or with HILBENCH_PLANT_BACKEND=python) the numpy code below runs: at N = 256 with 2 substeps about
35 plant-s per wall-s against about 260 for the C core (benchmarks/bench_plant.py).

The attributes `i_d, i_q, w_m, theta_e, hall_bits, last_edge_s` are the plant's own state
arrays, updated in place by every `step` and `reset` (no fresh arrays and no buffer set-up of
the state per period). Copy what you keep; writing into them changes the plants.

Arithmetic (both backends, operation by operation): where the scalar plant evaluates
cos/sin(atan2(vb, va) - theta) at each RK4 stage, the batch Park-transforms the held voltage
once per period (libm cos/sin of theta at the period start) and rotates that dq voltage by each
stage's angle offset delta = h p w with sin/cos of delta from a Taylor polynomial (|delta| <= 0.1,
truncation below 3e-18 relative; libm beyond). This keeps the batch within rounding of the
scalar plant (tests/test_plant_batch.py: 1e-9 after 1200 periods) and halves the C cost: libm
sin/cos/atan2 were over half of its instructions (callgrind), the per-call overhead under 10 %.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from hilbench.plant.model import (
    DEFAULT_SUBSTEPS,
    HALL_BY_SECTOR,
    OUTPUT_LOW_SIDE,
    OUTPUT_PWM,
    SECTOR0_START_RAD,
    SIXTY,
    TWO_PI,
    _choose_backend,
    _plantcore,
)
from hilbench.plant.params import PlantParams

__all__ = ["BatchPlant"]

_HALL = np.array(HALL_BY_SECTOR, dtype=np.int64)
SMALL_ANGLE = 0.1  # rad; _plantcore.c SMALL_ANGLE
_S3, _S5, _S7, _S9 = -1.0 / 6.0, 1.0 / 120.0, -1.0 / 5040.0, 1.0 / 362880.0
_C2, _C4, _C6, _C8, _C10 = -1.0 / 2.0, 1.0 / 24.0, -1.0 / 720.0, 1.0 / 40320.0, -1.0 / 3628800.0


def small_sincos(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """sin and cos of small angles: the C core's Taylor polynomial for |d| <= SMALL_ANGLE, libm beyond."""
    z = d * d
    s = d + d * z * (_S3 + z * (_S5 + z * (_S7 + z * _S9)))
    c = 1.0 + z * (_C2 + z * (_C4 + z * (_C6 + z * (_C8 + z * _C10))))
    big = np.abs(d) > SMALL_ANGLE
    if big.any():
        s = np.where(big, np.sin(d), s)
        c = np.where(big, np.cos(d), c)
    return s, c


class BatchPlant:
    """`BatchPlant(params_list)`; `step(duty_a, duty_b, duty_c, output_mode, dt_s)` with arrays of
    shape (N,) (or scalars). After a step: `i_d, i_q, w_m, theta_e, hall_bits, last_edge_s`
    (NaN where no edge), `speed_rpm`."""

    def __init__(self, params: Sequence[PlantParams], *, substeps: int = DEFAULT_SUBSTEPS,
                 backend: str | None = None) -> None:
        self.params = tuple(params)
        if int(substeps) < 1:
            raise ValueError(f"BatchPlant substeps {substeps}: must be >= 1")
        self.substeps = int(substeps)
        self.backend = _choose_backend(backend)
        n = len(self.params)
        if n == 0:
            raise ValueError("BatchPlant: no plants")

        def arr(get) -> np.ndarray:
            return np.array([float(get(p)) for p in self.params])

        for p in self.params:
            if p.load.kind == "quadratic" or p.inverter.dead_time_enabled:
                raise ValueError("BatchPlant: quadratic load and dead time are scalar-Plant only")
        rs = arr(lambda p: p.motor.rs_ohm)
        ld = arr(lambda p: p.motor.ld_h)
        lq = arr(lambda p: p.motor.lq_h)
        psi = arr(lambda p: p.motor.psi_wb)
        self._p = arr(lambda p: p.motor.pole_pairs)
        j = arr(lambda p: p.motor.j_kgm2)
        self._tc = arr(lambda p: p.motor.coulomb_nm)
        self._j = j
        self._ild, self._ilq = 1.0 / ld, 1.0 / lq
        self._rd, self._rq = rs / ld, rs / lq
        self._pq = self._p * lq / ld
        self._pd = self._p * ld / lq
        self._ppsi = self._p * psi / lq
        self._kt = 1.5 * self._p * psi / j
        self._kr = 1.5 * self._p * (ld - lq) / j
        self._ij = 1.0 / j
        self._b = arr(lambda p: p.motor.b_nms_per_rad)
        self.vbus_v = np.ascontiguousarray(arr(lambda p: p.inverter.vbus_v))
        self._base = np.array([(SECTOR0_START_RAD + math.radians(p.hall.offset_deg)) % TWO_PI for p in self.params])
        loads = [p.load for p in self.params]
        self._tl_before = np.array([ld.torque_nm for ld in loads])
        self._tl_after = np.array([ld.step_torque_nm if ld.kind == "step" else ld.torque_nm for ld in loads])
        self._t_step = np.array([ld.step_time_s if ld.kind == "step" else 0.0 for ld in loads])
        self._kl = np.array([ld.coeff if ld.kind == "linear" else 0.0 for ld in loads])
        self._locked = np.array([ld.kind == "locked" for ld in loads])
        self._t_step_last = float(self._t_step.max())
        self._simple = not self._locked.any() and not (self._tc > 0).any()
        self._kvj = (self._b + self._kl) * self._ij
        self.n = n
        # state rows [i_d, i_q, w_m, theta_e, sector index, stuck] (order fixed by _plantcore.c Batch)
        self._state = np.zeros((6, n))
        self.i_d, self.i_q, self.w_m, self.theta_e = self._state[0], self._state[1], self._state[2], self._state[3]
        self._nidx = self._state[4]
        self.hall_bits = np.zeros(n, dtype=np.int64)
        self.last_edge_s = np.full(n, np.nan)
        self._tl = np.zeros(n)
        self._core = None
        if self.backend == "c":
            cparams = np.ascontiguousarray(np.stack([
                self._rd, self._rq, self._pq, self._pd, self._ppsi, self._p, self._ild, self._ilq,
                self._kt, self._kr, self._ij, self._kvj, self._tc, self._j, self._base,
                self._locked.astype(float), self.vbus_v,
            ], axis=0))
            self._core = _plantcore.Batch(cparams, self._state, self.hall_bits, self.last_edge_s, self._tl,
                                          self.substeps)
            self._core_step = self._core.step
        self.reset()

    def reset(self) -> None:
        """Every plant at rest at theta_e = 0, t = 0 (in place: the attribute arrays stay the same objects)."""
        self._state.fill(0.0)
        self.t_s = 0.0
        self._stuck = self._tc > 0.0
        self._state[5] = self._stuck
        self._nidx[...] = np.floor((self.theta_e - self._base) / SIXTY)
        self.hall_bits[...] = _HALL[self._nidx.astype(np.int64) % 6]
        self.last_edge_s.fill(np.nan)
        self._tl_live = True  # the load torque row still has a step ahead

    @property
    def speed_rpm(self) -> np.ndarray:
        return self.w_m * (60.0 / TWO_PI)

    def _vec(self, x) -> np.ndarray:
        """x as a C-contiguous float64 array of shape (N,) (no copy when it already is one)."""
        if type(x) is np.ndarray and x.dtype == np.float64 and x.shape == (self.n,) and x.flags.c_contiguous:
            return x
        return np.ascontiguousarray(np.broadcast_to(np.asarray(x, dtype=float), (self.n,)))

    def step(self, duty_a, duty_b, duty_c, output_mode: int, dt_s: float) -> None:
        """Integrate one period for every plant (same dt). output_mode: PWM (1) or LOW_SIDE (2).
        Duties: float64 arrays of shape (N,) (or anything that broadcasts to it)."""
        if output_mode != OUTPUT_PWM and output_mode != OUTPUT_LOW_SIDE:
            raise NotImplementedError("BatchPlant: output mode OFF is modelled by the scalar Plant only")
        if self._tl_live:
            np.copyto(self._tl, np.where(self.t_s >= self._t_step - 1e-12, self._tl_after, self._tl_before))
            self._tl_live = self.t_s < self._t_step_last - 1e-12
        if self._core is not None:
            try:
                self._core_step(duty_a, duty_b, duty_c, output_mode, dt_s)
            except (ValueError, TypeError, BufferError):  # not float64 (N,) buffers: convert, retry once
                vec = self._vec
                self._core_step(vec(duty_a), vec(duty_b), vec(duty_c), output_mode, dt_s)
            self.t_s += dt_s
            return
        tl, kl, locked = self._tl, self._kl, self._locked
        if output_mode == OUTPUT_PWM:
            da = np.asarray(duty_a, dtype=float)
            db = np.asarray(duty_b, dtype=float)
            dc = np.asarray(duty_c, dtype=float)
            va = self.vbus_v * (2.0 * da - db - dc) / 3.0
            vb = self.vbus_v * (db - dc) / math.sqrt(3.0)
            c0 = np.cos(self.theta_e)
            s0 = np.sin(self.theta_e)
            ud = va * c0 + vb * s0
            uq = vb * c0 - va * s0
        else:
            ud = uq = np.zeros(self.n)
        nsub = self.substeps
        h = dt_s / nsub
        edge = np.full(self.n, np.nan)
        for j in range(nsub):
            ud, uq = self._substep(ud, uq, tl, kl, locked, h, j * h, edge, j + 1 < nsub)
        self.last_edge_s[...] = edge
        self.t_s += dt_s

    def _substep(self, ud, uq, tl, kl, locked, h, t_off, edge, more):
        """One RK4 substep of every plant (numpy backend, the C core's arithmetic): ud, uq is the
        dq voltage at the substep start; returns it rotated to the next substep's start (if `more`).
        Edge times land in `edge`; the state rows are updated in place."""
        rd, rq, pq, pd, ppsi, p = self._rd, self._rq, self._pq, self._pd, self._ppsi, self._p
        ild, ilq = self._ild, self._ilq
        id0, iq0, w0, th0 = self.i_d.copy(), self.i_q.copy(), self.w_m.copy(), self.theta_e.copy()
        if self._simple:
            ftj = tl * self._ij
            kvj = self._kvj
            kt = self._kt
            kr = self._kr
            fr = None
        else:
            ftj, kvj, kt, kr, fr, w0 = self._friction(id0, iq0, w0, tl, kl, locked)
        h2 = 0.5 * h

        def f(a, b, w, uds, uqs):
            kd = ild * uds + w * pq * b - rd * a
            kq = ilq * uqs - w * (pd * a + ppsi) - rq * b
            kw = b * (kt + kr * a) - kvj * w - ftj
            return kd, kq, kw

        def rot(delta):
            sd, cd = small_sincos(delta)
            return cd * ud + sd * uq, cd * uq - sd * ud

        k1d, k1q, k1w = f(id0, iq0, w0, ud, uq)
        w2 = w0 + h2 * k1w
        k2d, k2q, k2w = f(id0 + h2 * k1d, iq0 + h2 * k1q, w2, *rot(h2 * p * w0))
        w3 = w0 + h2 * k2w
        k3d, k3q, k3w = f(id0 + h2 * k2d, iq0 + h2 * k2q, w3, *rot(h2 * p * w2))
        w4 = w0 + h * k3w
        k4d, k4q, k4w = f(id0 + h * k3d, iq0 + h * k3q, w4, *rot(h * p * w3))
        h6 = h / 6.0
        self.i_d[...] = id0 + h6 * (k1d + 2.0 * (k2d + k3d) + k4d)
        self.i_q[...] = iq0 + h6 * (k1q + 2.0 * (k2q + k3q) + k4q)
        w1 = w0 + h6 * (k1w + 2.0 * (k2w + k3w) + k4w)
        dth = h6 * p * (w0 + 2.0 * (w2 + w3) + w4)
        th1 = th0 + dth
        if fr is not None:
            stick = (fr != 0.0) & (w0 != 0.0) & ((w1 > 0.0) != (w0 > 0.0))
            if stick.any():
                w1 = np.where(stick, 0.0, w1)
                self._stuck = self._stuck | stick
        self.w_m[...] = w1
        n0 = self._nidx.copy()
        n1 = np.floor((th1 - self._base) / SIXTY)
        moved = n1 != n0
        if moved.any():
            idx = np.nonzero(moved)[0]
            pi = p[idx]
            edge[idx] = t_off + self._edge(self._base[idx], th0[idx], th1[idx], n0[idx], n1[idx], pi * w0[idx], pi * w1[idx], h)
            self.hall_bits[idx] = _HALL[n1[idx].astype(np.int64) % 6]
        k = np.floor(th1 / TWO_PI)
        self.theta_e[...] = th1 - k * TWO_PI
        self._nidx[...] = n1 - 6.0 * k
        self._state[5] = self._stuck
        return rot(dth) if more else (ud, uq)

    def _friction(self, id0, iq0, w0, tl, kl, locked):
        """Stiction and Coulomb sign per plant, frozen over the period (as the scalar plant)."""
        net = (self._kt + self._kr * id0) * iq0 * self._j - tl
        hold = locked | (self._stuck & (np.abs(net) <= self._tc))
        release = self._stuck & ~hold
        self._stuck = self._stuck & hold
        fr = np.where(release, np.copysign(self._tc, net), np.where(w0 > 0, self._tc, np.where(w0 < 0, -self._tc, 0.0)))
        ij = np.where(hold, 0.0, self._ij)
        w0 = np.where(locked, 0.0, w0)
        fr = np.where(hold, 0.0, fr)
        ftj = (fr + tl) * ij
        kvj = (self._b + kl) * ij
        kt = np.where(hold, 0.0, self._kt)
        kr = np.where(hold, 0.0, self._kr)
        return ftj, kvj, kt, kr, fr, w0

    @staticmethod
    def _edge(base, th0, th1, n0, n1, we0, we1, h):
        """Newton on the cubic Hermite theta(u), u in [0, 1] (only plants whose sector moved: d != 0)."""
        target = base + np.where(n1 > n0, n1, n0) * SIXTY
        d = th1 - th0
        a1 = we0 * h
        a2 = 3.0 * d - 2.0 * a1 - we1 * h
        a3 = -2.0 * d + a1 + we1 * h
        g = target - th0
        u = np.clip(g / d, 0.0, 1.0)
        for _ in range(4):
            fv = u * (a1 + u * (a2 + u * a3)) - g
            fp = a1 + u * (2.0 * a2 + 3.0 * u * a3)
            u = np.clip(u - fv / fp, 0.0, 1.0)
        return u * h
