/* Compiled period of hilbench.plant.model.Plant (the "c" backend).
 *
 * Core is the base type of model._CPlant: the plant's state and cached parameters live in this
 * struct and are exposed to the Python code as members with the Python attribute names, so the
 * Python paths (energy tracking, quadratic load, OFF with current or above-bus back-EMF) keep
 * working on the same state. Core.advance runs an exchange period in its chunks and Core.step one
 * step; PWM and LOW_SIDE steps and the zero-current OFF coast run here, the rest in
 * Plant._step_py. The functions are model.py's, one for one, in the same order (averaged_inverter,
 * friction, rk4_dq, rotate, step_dq, sense_*).
 *
 * The arithmetic mirrors model.py operation by operation (same order, no FMA contraction:
 * build with -ffp-contract=off), so both backends agree to the last bit on the same libm.
 *
 * Recorded outputs (model.OUTPUTS): append_state copies the double members the declaration names
 * (resolved once by _set_outputs), so a new recorded quantity is a double here, set with the state.
 */
#include "hbglue.h"
#include <math.h>
#include <stddef.h>
#include <string.h>

#define OUTPUT_OFF 0
#define OUTPUT_PWM 1
#define OUTPUT_LOW_SIDE 2

static double TWO_PI, SIXTY, INV_SQRT3, HALF_SQRT3;
static const int HALL_BY_SECTOR[6] = {4, 6, 2, 3, 1, 5};
static PyObject *str_step_py, *str_update_load, *str_draw_noise;

#define MAX_CHUNKS 256 /* model.MAX_CHUNKS: steps per period, so hall edges per period */
#define MAX_OUTPUTS 32 /* recorded outputs (model.OUTPUTS) */

typedef struct {
    PyObject_HEAD
    double i_d, i_q, w_m, th, t_s, vbus_v, dt_duty, hall_base, tl, kv, tc, j, t_load_change;
    double i_a, i_b, i_c, i_bus;
    double rd, rq, pq, pd, ppsi, p, ild, ilq, kt, kr, ijv;
    double da, db, dc, ell, oc;
    double psi, ld_lq, te_nm; /* the electrical torque (recorded) and its constants */
    long long turns, nidx, enc_m;
    int sector, hall_bits, encoder_count, last_mode, enc_sign, enc_offset, enc_cpt, enc_idx, substeps;
    char stuck, locked, track_energy, kq_any, encoder_index, fault_input, gate_off;
    PyObject *last_edge_s;
    /* ADC: per role (0..5) gain, offset, noise, present; pre-drawn noise list and its index */
    double pot_fraction, adc_gain[6], adc_off[6], adc_nz[6], adc_max[6];
    char adc_has[6];
    PyObject *noise;
    long long noise_i;
    PyObject *noise_seen;      /* the block noise_view describes (a reference: compared only) */
    Py_buffer noise_view;      /* a float64 block's values, held while it is the block (noise_held) */
    int noise_held;            /* 0: the block is a list (its items read, its length asked each draw) */
    /* the exchange period (model.Plant.set_period) and the hall edges of the last one */
    double period_s, chunk_s, duty_scale;
    int chunks, n_edges, n_marks;
    long long periods;
    double edge_t[MAX_CHUNKS];
    int edge_hall[MAX_CHUNKS];
    double mark_t[MAX_CHUNKS]; /* the encoder's index marks of the last advance (chunk starts) */
    /* the recorded outputs: offsets of double members, in model.OUTPUTS order */
    Py_ssize_t out_off[MAX_OUTPUTS];
    int n_out;
    /* the switching inverter (_switching.c): motor constants as model.Plant holds them, the bridge's
     * constants and state (switching.py's attributes), the ADC's held sample */
    double rs, ld, lq, w_start;
    long long dturns;
    double sw_f, sw_td, sw_c, sw_smp, sw_l, sw_u, sw_e[3], ia_s, ib_s;
    int sw_s[3];
    char sw_on, sw_avg, adc_live;
    double trig_th, trig_c, trig_s; /* _switching.c's sw_trig */
    char trig_ok;
} Core;

static long long mod6(long long n) { long long r = n % 6; return r < 0 ? r + 6 : r; }

static long long floordiv(long long a, long long b)
{
    long long q = a / b;
    return (a % b != 0 && ((a < 0) != (b < 0))) ? q - 1 : q;
}

/* The encoder count and the index mark from the unwrapped x4 count n (model.Plant._sense). */
static void set_encoder(Core *s, long long n)
{
    s->encoder_count = (int)(((long long)s->enc_sign * n + s->enc_offset) & 0xFFFF);
    long long m = floordiv(n - s->enc_idx, s->enc_cpt);
    s->encoder_index = (char)(m != s->enc_m);
    s->enc_m = m;
}

/* Time of the last hall edge inside a (sub)step: Newton on the cubic Hermite (model._edge). */
static double edge_time(double base, double th0, double th1, long long n0, long long n1,
                        double we0, double we1, double h)
{
    double target = base + (double)(n1 > n0 ? n1 : n0) * SIXTY;
    double d = th1 - th0;
    double a1 = we0 * h;
    double a2 = 3.0 * d - 2.0 * a1 - we1 * h;
    double a3 = -2.0 * d + a1 + we1 * h;
    double g = target - th0;
    double u = d != 0.0 ? g / d : 0.5;
    u = u < 0.0 ? 0.0 : u > 1.0 ? 1.0 : u;
    for (int it = 0; it < 30; it++) {
        double f = u * (a1 + u * (a2 + u * a3)) - g;
        double fp = a1 + u * (2.0 * a2 + 3.0 * u * a3);
        if (fp == 0.0) break;
        double du = f / fp;
        u -= du;
        if (u < 0.0) u = 0.0;
        else if (u > 1.0) u = 1.0;
        if (fabs(du) < 1e-15) break;
    }
    return u * h;
}

static void set_edge(Core *s, int have, double edge)
{
    PyObject *old = s->last_edge_s;
    if (have) {
        PyObject *f = PyFloat_FromDouble(edge);
        if (f == NULL) { PyErr_Clear(); f = Py_NewRef(Py_None); }
        s->last_edge_s = f;
    } else {
        if (old == Py_None) return;
        s->last_edge_s = Py_NewRef(Py_None);
    }
    Py_XDECREF(old);
}

/* model.Plant._sense_currents: the phase currents and the overcurrent comparator (latches fault_input) */
static void sense_currents(Core *s)
{
    double th = s->th, c = cos(th), sn = sin(th);
    double ia = s->i_d * c - s->i_q * sn;
    double ibe = s->i_d * sn + s->i_q * c;
    double ib = -0.5 * ia + HALF_SQRT3 * ibe;
    double ic = -0.5 * ia - HALF_SQRT3 * ibe;
    s->i_a = ia; s->i_b = ib; s->i_c = ic;
    double oc = s->oc;
    if (oc > 0.0 && (ia > oc || ia < -oc || ib > oc || ib < -oc || ic > oc || ic < -oc))
        s->fault_input = 1;
    s->te_nm = 1.5 * s->p * s->i_q * (s->psi + s->ld_lq * s->i_d);
}

/* model.Plant._sense_encoder */
static void sense_encoder(Core *s)
{
    long long n = (long long)floor(((double)s->turns + s->th / TWO_PI) * (double)s->enc_cpt / s->p);
    set_encoder(s, n);
}

/* model.Plant._sense */
static void sense(Core *s)
{
    sense_currents(s);
    double ia = s->i_a, ib = s->i_b, ic = s->i_c;
    if (s->last_mode == OUTPUT_PWM)
        s->i_bus = s->da * ia + s->db * ib + s->dc * ic;
    else if (s->last_mode == OUTPUT_LOW_SIDE)
        s->i_bus = 0.0;
    else
        s->i_bus = (ia < 0.0 ? ia : 0.0) + (ib < 0.0 ? ib : 0.0) + (ic < 0.0 ? ic : 0.0);
    sense_encoder(s);
}

/* model.Plant._bus_average */
static double bus_average(const Core *s, double e_in_j, double dt_s)
{
    return (s->vbus_v > 0.0 && dt_s > 0.0) ? e_in_j / (s->vbus_v * dt_s) : 0.0;
}

/* model.Plant._finish: the hall sector and the edge's time (t_off + its time inside the step) after a
 * step done outside the hot path (angle already wrapped); *have and *edge are set only for an edge */
static void finish(Core *s, double th0, double dth, double h, double t_off, double w_start, int *have, double *edge)
{
    double th1 = th0 + dth, base = s->hall_base;
    long long n0 = (long long)floor((th0 - base) / SIXTY);
    long long n1 = (long long)floor((th1 - base) / SIXTY);
    if (n1 != n0) {
        *edge = t_off + edge_time(base, th0, th1, n0, n1, s->p * w_start, s->p * s->w_m, h);
        *have = 1;
        s->sector = (int)mod6(n1);
        s->hall_bits = HALL_BY_SECTOR[s->sector];
    }
    s->nidx = (long long)floor((s->th - base) / SIXTY);
}

/* OFF with zero currents and the back-EMF below the bus: model.Plant._coast over the step,
 * then model.Plant._finish and _sense. The step's hall edge, if any, goes to *edge (*have = 1). */
static void coast_step(Core *s, double h, int *have, double *edge)
{
    double th0 = s->th, w_start = s->w_m;
    long long turns0 = s->turns;
    s->last_mode = OUTPUT_OFF;
    s->i_d = 0.0;
    s->i_q = 0.0;
    double tl = s->tl, kv = s->kv, kq = 0.0, w0 = s->w_m;
    if (s->locked || (s->stuck && fabs(tl) <= s->tc)) {
        s->w_m = 0.0;
    } else {
        double fr;
        if (s->stuck) {
            s->stuck = 0;
            fr = -copysign(s->tc, tl);
        } else {
            fr = w0 != 0.0 ? copysign(s->tc, w0) : 0.0;
        }
        double ij = 1.0 / s->j;
        double a = kv * ij, c = kq * ij, f0 = (fr + tl) * ij;
        double k1 = -a * w0 - c * w0 * fabs(w0) - f0;
        double wa = w0 + 0.5 * h * k1;
        double k2 = -a * wa - c * wa * fabs(wa) - f0;
        double wb = w0 + 0.5 * h * k2;
        double k3 = -a * wb - c * wb * fabs(wb) - f0;
        double wc = w0 + h * k3;
        double k4 = -a * wc - c * wc * fabs(wc) - f0;
        double w1 = w0 + h / 6.0 * (k1 + 2.0 * (k2 + k3) + k4);
        double dth = s->p * h / 6.0 * (w0 + 2.0 * (wa + wb) + wc);
        if (fr != 0.0 && w0 != 0.0 && ((w1 > 0.0) != (w0 > 0.0))) {
            w1 = 0.0;
            s->stuck = 1;
        }
        s->w_m = w1;
        double th1 = s->th + dth;
        double k = floor(th1 / TWO_PI);
        s->turns += (long long)k;
        s->th = th1 - k * TWO_PI;
    }
    *have = 0;
    finish(s, th0, s->th - th0 + (double)(s->turns - turns0) * TWO_PI, h, 0.0, w_start, have, edge);
    s->t_s += h;
    sense(s);
}

static void sw_average_dead_time(Core *s, double u0, double *duty_a, double *duty_b, double *duty_c, double dt_s);

/* model.Plant._averaged_inverter: the alpha-beta voltage of the duties held over the step, each
 * duty corrected for the dead time against its phase current's sign (or, average_dead_time =
 * "edges", by each PWM edge's: _switching.c; u0 the carrier's phase at the step's start). */
static void averaged_inverter(Core *s, double duty_a, double duty_b, double duty_c, double u0, double dt_s,
                              double *va, double *vb)
{
    double dtd = s->dt_duty;
    if (dtd != 0.0 && s->sw_avg) {
        sw_average_dead_time(s, u0, &duty_a, &duty_b, &duty_c, dt_s);
    } else if (dtd != 0.0) {
        double ia = s->i_a, ib = s->i_b, ic = s->i_c, x;
        x = duty_a - (ia > 0.0 ? dtd : ia < 0.0 ? -dtd : 0.0);
        x = x > 0.0 ? x : 0.0; duty_a = x < 1.0 ? x : 1.0;
        x = duty_b - (ib > 0.0 ? dtd : ib < 0.0 ? -dtd : 0.0);
        x = x > 0.0 ? x : 0.0; duty_b = x < 1.0 ? x : 1.0;
        x = duty_c - (ic > 0.0 ? dtd : ic < 0.0 ? -dtd : 0.0);
        x = x > 0.0 ? x : 0.0; duty_c = x < 1.0 ? x : 1.0;
    }
    s->da = duty_a; s->db = duty_b; s->dc = duty_c;
    double vbus = s->vbus_v;
    *va = vbus * (2.0 * duty_a - duty_b - duty_c) / 3.0;
    *vb = vbus * (duty_b - duty_c) * INV_SQRT3;
}

/* model.Plant._friction: 1/J (0 while held) and the Coulomb friction frozen over the substep */
static void friction(Core *s, double i_d, double i_q, double *w, double *ij, double *fr)
{
    const double tc = s->tc;
    if (s->locked) {
        *ij = 0.0; *fr = 0.0; *w = 0.0;
    } else if (s->stuck) {
        double net = (s->kt + s->kr * i_d) * i_q * s->j - s->tl;
        if (-tc <= net && net <= tc) {
            *ij = 0.0; *fr = 0.0;
        } else {
            s->stuck = 0;
            *ij = s->ijv;
            *fr = net > 0.0 ? tc : -tc;
        }
    } else {
        *ij = s->ijv;
        *fr = *w > 0.0 ? tc : *w < 0.0 ? -tc : 0.0;
    }
}

/* model._turned: cos and sin of x - d from c = cos x and s = sin x, by Taylor polynomials of the
 * small angle d an RK4 stage turns and a rotation (beyond TURN_MAX_RAD, libm). The same arithmetic
 * in the same order as the Python backend (-ffp-contract=off: no fused multiply-add). */
#define TURN_MAX_RAD 0.0625
static inline void turned(double c, double s, double x, double d, double *c_out, double *s_out)
{
    if (d >= -TURN_MAX_RAD && d <= TURN_MAX_RAD) {
        const double d2 = d * d;
        const double cd = 1.0 - d2 * (0.5 - d2 * (1.0 / 24.0 - d2 * (1.0 / 720.0 - d2 * (1.0 / 40320.0))));
        const double sd = d * (1.0 - d2 * (1.0 / 6.0 - d2 * (1.0 / 120.0 - d2 * (1.0 / 5040.0 - d2 * (1.0 / 362880.0)))));
        *c_out = c * cd + s * sd;
        *s_out = s * cd - c * sd;
    } else {
        x = x - d;
        *c_out = cos(x);
        *s_out = sin(x);
    }
}

/* model.Plant._rk4_dq: one RK4 step of (i_d, i_q, w_m) with x0 = phi - theta; y[] = i_d, i_q, w_m
 * in, and out with y[3] = the angle turned, y[4] = the input energy part */
#if defined(__GNUC__)
__attribute__((always_inline)) /* the period's hot loop; _switching.c calls it too */
#endif
static inline void rk4_dq(const Core *s, double y[5], double x0, double vmag, double ij, double fr, double h)
{
    const double rd = s->rd, rq = s->rq, pq = s->pq, pd = s->pd, ppsi = s->ppsi, p = s->p;
    const double id0 = y[0], iq0 = y[1], w0 = y[2];
    double vdm = vmag * s->ild, vqm = vmag * s->ilq;
    double h2 = 0.5 * h, h6 = h / 6.0;
    double ftj = (fr + s->tl) * ij, kvj = s->kv * ij, ktj, krj;
    if (ij == 0.0) { ktj = krj = 0.0; } else { ktj = s->kt; krj = s->kr; }
    double a, b, w;
    const double c0 = cos(x0), s0 = sin(x0); /* the step's trigonometry: stages 2-4 turn it */
    double cc = c0, ss = s0;
    double p1 = cc * id0 + ss * iq0;
    double k1d = vdm * cc + w0 * pq * iq0 - rd * id0;
    double k1q = vqm * ss - w0 * (pd * id0 + ppsi) - rq * iq0;
    double k1w = iq0 * (ktj + krj * id0) - kvj * w0 - ftj;
    a = id0 + h2 * k1d; b = iq0 + h2 * k1q; w = w0 + h2 * k1w;
    turned(c0, s0, x0, h2 * p * w0, &cc, &ss);
    double p2 = cc * a + ss * b;
    double k2d = vdm * cc + w * pq * b - rd * a;
    double k2q = vqm * ss - w * (pd * a + ppsi) - rq * b;
    double k2w = b * (ktj + krj * a) - kvj * w - ftj;
    double w2 = w;
    a = id0 + h2 * k2d; b = iq0 + h2 * k2q; w = w0 + h2 * k2w;
    turned(c0, s0, x0, h2 * p * w2, &cc, &ss);
    double p3 = cc * a + ss * b;
    double k3d = vdm * cc + w * pq * b - rd * a;
    double k3q = vqm * ss - w * (pd * a + ppsi) - rq * b;
    double k3w = b * (ktj + krj * a) - kvj * w - ftj;
    double w3 = w;
    a = id0 + h * k3d; b = iq0 + h * k3q; w = w0 + h * k3w;
    turned(c0, s0, x0, h * p * w3, &cc, &ss);
    double p4 = cc * a + ss * b;
    double k4d = vdm * cc + w * pq * b - rd * a;
    double k4q = vqm * ss - w * (pd * a + ppsi) - rq * b;
    double k4w = b * (ktj + krj * a) - kvj * w - ftj;
    y[0] = id0 + h6 * (k1d + 2.0 * (k2d + k3d) + k4d);
    y[1] = iq0 + h6 * (k1q + 2.0 * (k2q + k3q) + k4q);
    y[2] = w0 + h6 * (k1w + 2.0 * (k2w + k3w) + k4w);
    y[3] = h6 * p * (w0 + 2.0 * (w2 + w3) + w);
    y[4] = h6 * (p1 + 2.0 * (p2 + p3) + p4);
}

/* model.Plant._rotate: the new angle (wrapped) and sector index; 1 and *edge when a sector changed */
static int rotate(Core *s, double *th, long long *n, double dth, double w0, double w1, double h, double *edge)
{
    double th0 = *th, th1 = th0 + dth, base = s->hall_base;
    long long n0 = *n, n1 = (long long)floor((th1 - base) / SIXTY);
    int have = 0;
    if (n1 != n0) {
        *edge = edge_time(base, th0, th1, n0, n1, s->p * w0, s->p * w1, h);
        have = 1;
        s->sector = (int)mod6(n1);
    }
    if (th1 >= TWO_PI || th1 < 0.0) {
        double k = floor(th1 / TWO_PI);
        s->turns += (long long)k;
        th1 -= k * TWO_PI;
        n1 -= 6 * (long long)k;
    }
    *th = th1;
    *n = n1;
    return have;
}

/* model.Plant._step_dq: substeps of RK4 in the rotor frame under a held voltage, then the sensors */
static void step_dq(Core *s, double va, double vb, double dt_s, int *have, double *edge)
{
    double vmag = sqrt(va * va + vb * vb);
    double phi = atan2(vb, va);
    const int nsub = s->substeps;
    double h = dt_s / (double)nsub;
    double y[5] = {s->i_d, s->i_q, s->w_m, 0.0, 0.0};
    double th0 = s->th;
    long long n0 = s->nidx;
    double e_in = 0.0; /* the step's input energy / (1.5 |v|), as model.py */
    *have = 0;
    for (int jj = 0; jj < nsub; jj++) {
        double ij, fr, w0 = y[2], sub_edge = 0.0;
        friction(s, y[0], y[1], &w0, &ij, &fr);
        y[2] = w0;
        rk4_dq(s, y, phi - th0, vmag, ij, fr, h);
        e_in += y[4];
        double w1 = y[2];
        if (fr != 0.0 && w0 != 0.0 && ((w1 > 0.0) != (w0 > 0.0))) {
            w1 = 0.0; /* speed crossed zero under Coulomb friction: stick */
            s->stuck = 1;
        }
        if (rotate(s, &th0, &n0, y[3], w0, w1, h, &sub_edge)) {
            *edge = (double)jj * h + sub_edge;
            *have = 1;
        }
        y[2] = w1;
    }
    s->i_d = y[0]; s->i_q = y[1]; s->w_m = y[2]; s->nidx = n0; s->th = th0;
    s->hall_bits = HALL_BY_SECTOR[s->sector];
    s->t_s += dt_s;
    sense_currents(s);
    s->i_bus = bus_average(s, 1.5 * vmag * e_in, dt_s);
    sense_encoder(s);
}

#define get_double hb_double /* the shared glue's number argument */

#include "_switching.c"

/* model.Plant._step_py in Python, for the steps the C core leaves to it */
static int step_in_python(Core *s, const double duty[3], long mode, double dt_s, int *have, double *edge)
{
    PyObject *cargs[6] = {(PyObject *)s, PyFloat_FromDouble(duty[0]), PyFloat_FromDouble(duty[1]),
                          PyFloat_FromDouble(duty[2]), PyLong_FromLong(mode), PyFloat_FromDouble(dt_s)};
    PyObject *r = NULL;
    if (cargs[1] && cargs[2] && cargs[3] && cargs[4] && cargs[5])
        r = PyObject_VectorcallMethod(str_step_py, cargs, 6, NULL);
    for (int i = 1; i < 6; i++) Py_XDECREF(cargs[i]);
    if (r == NULL) return -1;
    Py_DECREF(r);
    *have = s->last_edge_s != NULL && s->last_edge_s != Py_None;
    if (*have && get_double(s->last_edge_s, edge) < 0) return -1;
    return 0;
}

/* model.Plant._step_py: one step of dt_s with the duties (fractions) and output mode held; the
 * steps with energy accounts, a quadratic load or current in an open bridge go to Python. 0, or -1
 * with an exception set; the step's hall edge in *have and *edge. */
static int integrate(Core *s, const double duty[3], long mode, double dt_s, int *have, double *edge)
{
    long gated = (s->fault_input && s->gate_off) ? OUTPUT_OFF : mode; /* the comparator's hardware trip */
    int driven = (gated == OUTPUT_PWM || gated == OUTPUT_LOW_SIDE);
    if (s->track_energy || s->kq_any || (!driven && !(s->i_d == 0.0 && s->i_q == 0.0 && s->ell * fabs(s->w_m) < s->vbus_v)))
        return step_in_python(s, duty, mode, dt_s, have, edge);
    if (s->t_load_change <= s->t_s + 1e-12) {
        PyObject *r = PyObject_CallMethodNoArgs((PyObject *)s, str_update_load);
        if (r == NULL) return -1;
        Py_DECREF(r);
    }
    double u0 = 0.0;
    if (s->sw_on || s->sw_avg) { /* the switching inverter, or the averaged one's carrier (_switching.c) */
        if (s->sw_on && gated == OUTPUT_PWM) return sw_step_pwm(s, duty[0], duty[1], duty[2], dt_s, have, edge);
        u0 = sw_idle(s, dt_s);
    }
    if (!driven) {
        coast_step(s, dt_s, have, edge);
        return 0;
    }
    double va = 0.0, vb = 0.0;
    if (gated == OUTPUT_PWM)
        averaged_inverter(s, duty[0], duty[1], duty[2], u0, dt_s, &va, &vb);
    s->last_mode = (int)gated;
    step_dq(s, va, vb, dt_s, have, edge);
    return 0;
}

/* the duties (times scale) and the output mode of args[0..3] */
static int get_drive(PyObject *const *args, double scale, double duty[3], long *mode)
{
    if (get_double(args[0], &duty[0]) || get_double(args[1], &duty[1]) || get_double(args[2], &duty[2]))
        return -1;
    duty[0] *= scale; duty[1] *= scale; duty[2] *= scale;
    *mode = PyLong_AsLong(args[3]);
    return (*mode == -1 && PyErr_Occurred()) ? -1 : 0;
}

static PyObject *Core_append_state(Core *s, PyObject *buf);

static int check_state_to(PyObject *const *args, Py_ssize_t nargs, Py_ssize_t at, const char *what)
{
    if (nargs > at && args[at] != Py_None && !PyByteArray_Check(args[at])) {
        PyErr_Format(PyExc_TypeError, "Plant.%s: state_to must be a bytearray (a recorder's row buffer) or None", what);
        return -1;
    }
    return 0;
}

/* the recorded outputs onto state_to, when given; the step's return value (last_edge_s) */
static PyObject *finish_call(Core *s, PyObject *const *args, Py_ssize_t nargs, Py_ssize_t at, int have, double edge)
{
    set_edge(s, have, edge);
    if (nargs > at && args[at] != Py_None) {
        PyObject *r = Core_append_state(s, args[at]);
        if (r == NULL) return NULL;
        Py_DECREF(r);
    }
    return Py_NewRef(s->last_edge_s != NULL ? s->last_edge_s : Py_None);
}

/* step(duty_a, duty_b, duty_c, output_mode, dt_s[, state_to]) -> last_edge_s: one step (model.Plant.step) */
static PyObject *Core_step(Core *s, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 5 && nargs != 6) {
        PyErr_Format(PyExc_TypeError, "Plant.step: expected 5 or 6 arguments (duty_a, duty_b, duty_c, output_mode, dt_s[, state_to]), got %zd", nargs);
        return NULL;
    }
    if (check_state_to(args, nargs, 5, "step") < 0) return NULL;
    double duty[3], dt_s, edge = 0.0;
    long mode;
    int have = 0;
    if (get_drive(args, 1.0, duty, &mode) < 0 || get_double(args[4], &dt_s) < 0
        || integrate(s, duty, mode, dt_s, &have, &edge) < 0)
        return NULL;
    return finish_call(s, args, nargs, 5, have, edge);
}

/* One exchange period in its chunks with the duties (fractions) held: the clock, the hall edges
 * (edges()), the index marks (index_marks()), last_edge_s. 0, or -1 with an exception. */
static int advance_period(Core *s, const double duty[3], long mode)
{
    const double h = s->chunk_s;
    const int chunks = s->chunks < 1 ? 1 : s->chunks > MAX_CHUNKS ? MAX_CHUNKS : s->chunks;
    int have = 0;
    double edge = 0.0;
    s->n_edges = 0;
    s->n_marks = 0;
    for (int i = 0; i < chunks; i++) { /* long periods: the plant keeps its accurate step, duties held */
        int sub_have = 0;
        double sub_edge = 0.0;
        if (integrate(s, duty, mode, h, &sub_have, &sub_edge) < 0) return -1;
        if (sub_have) {
            edge = (double)i * h + sub_edge;
            have = 1;
            s->edge_t[s->n_edges] = edge;
            s->edge_hall[s->n_edges] = s->hall_bits;
            s->n_edges++;
        }
        if (s->encoder_index) /* an index mark passed in this chunk: timed at its start */
            s->mark_t[s->n_marks++] = (double)i * h;
    }
    s->encoder_index = (char)(s->n_marks > 0); /* a mark anywhere in the period */
    s->periods += 1;
    s->t_s = (double)s->periods * s->period_s; /* one time base: k periods are Period.t_s(k) */
    set_edge(s, have, edge);
    return 0;
}

/* advance(duty_a, duty_b, duty_c, output_mode[, state_to]) -> last_edge_s: one exchange period in
 * its chunks, duties in counts of the full scale set_period gave (model.Plant._advance_py; the
 * actuation delay stays in Python) */
static PyObject *Core_advance(Core *s, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 4 && nargs != 5) {
        PyErr_Format(PyExc_TypeError, "Plant.advance: expected 4 or 5 arguments (duty_a, duty_b, duty_c, output_mode[, state_to]), got %zd", nargs);
        return NULL;
    }
    if (check_state_to(args, nargs, 4, "advance") < 0) return NULL;
    double duty[3];
    long mode;
    if (get_drive(args, s->duty_scale, duty, &mode) < 0 || advance_period(s, duty, mode) < 0) return NULL;
    if (nargs > 4 && args[4] != Py_None) {
        PyObject *r = Core_append_state(s, args[4]);
        if (r == NULL) return NULL;
        Py_DECREF(r);
    }
    return Py_NewRef(s->last_edge_s != NULL ? s->last_edge_s : Py_None);
}

/* edges() -> ((t_s, hall_bits), ...): every hall edge of the last advance (model.Plant.edges) */
static PyObject *Core_edges(Core *s, PyObject *unused)
{
    (void)unused;
    PyObject *out = PyTuple_New(s->n_edges);
    if (out == NULL) return NULL;
    for (int i = 0; i < s->n_edges; i++) {
        PyObject *e = Py_BuildValue("(di)", s->edge_t[i], s->edge_hall[i]);
        if (e == NULL) { Py_DECREF(out); return NULL; }
        PyTuple_SET_ITEM(out, i, e);
    }
    return out;
}

/* index_marks() -> (t_s, ...): the encoder's index marks of the last advance (model.Plant.index_marks) */
static PyObject *Core_index_marks(Core *s, PyObject *unused)
{
    (void)unused;
    PyObject *out = PyTuple_New(s->n_marks);
    if (out == NULL) return NULL;
    for (int i = 0; i < s->n_marks; i++) {
        PyObject *t = PyFloat_FromDouble(s->mark_t[i]);
        if (t == NULL) { Py_DECREF(out); return NULL; }
        PyTuple_SET_ITEM(out, i, t);
    }
    return out;
}

/* append_state(buf): the recorded outputs (model.OUTPUTS) appended to a bytearray as
 * little-endian doubles: one call instead of an attribute read each. */
static PyObject *Core_append_state(Core *s, PyObject *buf)
{
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "append_state writes host doubles as little-endian"
#endif
    if (!PyByteArray_Check(buf)) {
        PyErr_SetString(PyExc_TypeError, "append_state: expected a bytearray");
        return NULL;
    }
    Py_ssize_t n = PyByteArray_GET_SIZE(buf);
    if (PyByteArray_Resize(buf, n + (Py_ssize_t)sizeof(double) * s->n_out) < 0) return NULL;
    char *out = PyByteArray_AS_STRING(buf) + n;
    for (int i = 0; i < s->n_out; i++)
        memcpy(out + i * sizeof(double), (const char *)s + s->out_off[i], sizeof(double));
    Py_RETURN_NONE;
}

/* Where the noise block `_noise` keeps its values: a float64 array's in place (as _CPlant._draw_noise
 * leaves it), or a list's items (Plant._draw_noise). The array's buffer stays exported while it is
 * the block (nothing can resize or free its data under the pointer); a list's length is asked at
 * every draw (the list may shrink). noise_seen holds the block it describes. 0, or -1. */
static void noise_release(Core *s)
{
    if (s->noise_held) {
        s->noise_held = 0;
        PyBuffer_Release(&s->noise_view);
    }
}

static int noise_locate(Core *s)
{
    noise_release(s);
    Py_XSETREF(s->noise_seen, Py_XNewRef(s->noise));
    if (s->noise != NULL && !PyList_Check(s->noise) && PyObject_CheckBuffer(s->noise)) {
        Py_buffer *view = &s->noise_view;
        if (PyObject_GetBuffer(s->noise, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) {
            Py_CLEAR(s->noise_seen); /* looked at again next time */
            return -1;
        }
        if (view->itemsize == 8 && view->format != NULL && strcmp(view->format, "d") == 0) s->noise_held = 1;
        else PyBuffer_Release(view);
    }
    return 0;
}

static Py_ssize_t noise_len(const Core *s)
{
    if (s->noise_held) return s->noise_view.len / 8;
    return s->noise != NULL && PyList_Check(s->noise) ? PyList_GET_SIZE(s->noise) : 0;
}

/* The next standard-normal draw of the noise block, a new block drawn when it is used up; an index
 * below 0 counts from the block's end, as Plant.adc_codes's `noise[i]`. */
static int noise_next(Core *s, double *g)
{
    if (s->noise != s->noise_seen && noise_locate(s) < 0) return -1;
    long long i = s->noise_i;
    if (i >= noise_len(s)) {
        PyObject *blk = PyObject_CallMethodNoArgs((PyObject *)s, str_draw_noise);
        if (blk == NULL) return -1;
        Py_DECREF(blk);
        if (noise_locate(s) < 0) return -1;
        if (noise_len(s) == 0) {
            PyErr_SetString(PyExc_RuntimeError, "adc_codes: _draw_noise left no noise block");
            return -1;
        }
        i = 0;
    }
    Py_ssize_t n = noise_len(s);
    long long at = i < 0 ? i + n : i;
    s->noise_i = i + 1;
    if (at < 0) {
        PyErr_Format(PyExc_IndexError, "adc_codes: noise index %lld is outside the block of %zd", i, n);
        return -1;
    }
    if (s->noise_held) {
        *g = ((const double *)s->noise_view.buf)[at];
        return 0;
    }
    PyObject *item = Py_NewRef(PyList_GET_ITEM(s->noise, (Py_ssize_t)at)); /* its __float__ may change the list */
    *g = PyFloat_AsDouble(item);
    Py_DECREF(item);
    return *g == -1.0 && PyErr_Occurred() ? -1 : 0;
}

/* The ADC code of one role (model.Plant.adc_codes): 0, or -1 with an exception. */
static int adc_code(Core *s, long r, long *code)
{
    if (r < 0 || r > 5) {
        PyErr_Format(PyExc_IndexError, "adc_codes: role %ld is not 0..5", r);
        return -1;
    }
    *code = 0;
    if (!s->adc_has[r]) return 0;
    double x = r == 4 ? (s->adc_live ? s->i_a : s->ia_s) : r == 2 ? s->i_bus
               : r == 5 ? (s->adc_live ? s->i_b : s->ib_s) : r == 3 ? s->vbus_v : s->pot_fraction;
    double v = s->adc_off[r];
    v += s->adc_gain[r] * x;
    double nz = s->adc_nz[r];
    if (nz != 0.0) {
        double g;
        if (noise_next(s, &g) < 0) return -1;
        v += nz * g;
    }
    double c = floor(v + 0.5);
    *code = c < 0.0 ? 0 : c > s->adc_max[r] ? (long)s->adc_max[r] : (long)c;
    return 0;
}

/* model.Plant.adc_codes */
static PyObject *Core_adc_codes(Core *s, PyObject *roles)
{
    PyObject *seq = PySequence_Fast(roles, "adc_codes: roles must be a sequence of role numbers");
    if (seq == NULL) return NULL;
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    PyObject **items = PySequence_Fast_ITEMS(seq);
    PyObject *out = PyTuple_New(n);
    if (out == NULL) { Py_DECREF(seq); return NULL; }
    for (Py_ssize_t k = 0; k < n; k++) {
        long r = PyLong_AsLong(items[k]), code;
        if ((r == -1 && PyErr_Occurred()) || adc_code(s, r, &code) < 0) goto fail;
        PyObject *o = PyLong_FromLong(code);
        if (o == NULL) goto fail;
        PyTuple_SET_ITEM(out, k, o);
    }
    Py_DECREF(seq);
    return out;
fail:
    Py_DECREF(seq);
    Py_DECREF(out);
    return NULL;
}

static PyObject *Core_set_adc(Core *s, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 5) { PyErr_SetString(PyExc_TypeError, "_set_adc(role, gain, offset, noise, max_code)"); return NULL; }
    long r = PyLong_AsLong(args[0]);
    if (r == -1 && PyErr_Occurred()) return NULL;
    if (r < 0 || r > 5) { PyErr_Format(PyExc_IndexError, "_set_adc: role %ld is not 0..5", r); return NULL; }
    double g, o, nz, top;
    if (get_double(args[1], &g) || get_double(args[2], &o) || get_double(args[3], &nz) || get_double(args[4], &top))
        return NULL;
    s->adc_gain[r] = g; s->adc_off[r] = o; s->adc_nz[r] = nz; s->adc_max[r] = top; s->adc_has[r] = 1;
    Py_RETURN_NONE;
}

static PyObject *Core_new(PyTypeObject *type, PyObject *args, PyObject *kwds)
{
    (void)args; (void)kwds;
    Core *s = (Core *)type->tp_alloc(type, 0);
    if (s == NULL) return NULL;
    s->last_edge_s = Py_NewRef(Py_None);
    s->substeps = 1;
    s->p = 1.0;
    s->j = 1.0;
    s->enc_cpt = 4;
    s->t_load_change = INFINITY;
    s->sw_e[0] = s->sw_e[1] = s->sw_e[2] = -INFINITY;
    s->adc_live = 1;
    s->chunks = 1;
    s->duty_scale = 1.0;
    return (PyObject *)s;
}

static void Core_dealloc(Core *s)
{
    Py_CLEAR(s->last_edge_s);
    noise_release(s); /* before the block itself goes */
    Py_CLEAR(s->noise);
    Py_CLEAR(s->noise_seen);
    Py_TYPE(s)->tp_free((PyObject *)s);
}

#define DM(name, field) HB_MEMBER(name, T_DOUBLE, Core, field, 0)
#define IM(name, field) HB_MEMBER(name, T_INT, Core, field, 0)
#define LM(name, field) HB_MEMBER(name, T_LONGLONG, Core, field, 0)
#define BM(name, field) HB_MEMBER(name, T_BOOL, Core, field, 0)

static PyMemberDef Core_members[] = {
    DM("load_nm", tl), /* the constant part of the load now, recorded (model.Plant.load_nm) */
    DM("i_d", i_d), DM("i_q", i_q), DM("w_m", w_m), DM("_th", th), DM("t_s", t_s), DM("vbus_v", vbus_v),
    DM("_dt_duty", dt_duty), DM("_hall_base", hall_base), DM("_tl", tl), DM("_kv", kv), DM("_tc", tc), DM("_oc", oc),
    DM("_j", j), DM("_t_load_change", t_load_change), DM("i_a", i_a), DM("i_b", i_b), DM("i_c", i_c),
    DM("i_bus", i_bus), DM("_rd", rd), DM("_rq", rq), DM("_pq", pq), DM("_pd", pd), DM("_ppsi", ppsi),
    DM("_p", p), DM("_ild", ild), DM("_ilq", ilq), DM("_kt", kt), DM("_kr", kr), DM("_ijv", ijv),
    DM("_da", da), DM("_db", db), DM("_dc", dc), DM("_ell", ell),
    DM("_psi", psi), DM("_ld_lq", ld_lq), DM("te_nm", te_nm),
    LM("_turns", turns), LM("_nidx", nidx),
    IM("_sector", sector), IM("hall_bits", hall_bits), IM("encoder_count", encoder_count),
    IM("_last_mode", last_mode), IM("_enc_sign", enc_sign), IM("_enc_offset", enc_offset),
    IM("_enc_cpt", enc_cpt), IM("_enc_idx", enc_idx), LM("_enc_m", enc_m), BM("encoder_index", encoder_index),
    IM("_substeps", substeps),
    BM("_stuck", stuck), BM("_locked", locked), BM("track_energy", track_energy), BM("_kq_any", kq_any), BM("fault_input", fault_input), BM("_gate_off", gate_off),
    {"last_edge_s", T_OBJECT_EX, offsetof(Core, last_edge_s), 0, NULL},
    {"_noise", T_OBJECT_EX, offsetof(Core, noise), 0, NULL},
    LM("_noise_i", noise_i), DM("pot_fraction", pot_fraction),
    {"theta_e", T_DOUBLE, offsetof(Core, th), READONLY, "Electrical rotor angle in [0, 2 pi) (read-only)."},
    DM("_period_s", period_s), DM("_chunk_s", chunk_s), IM("_chunks", chunks), LM("_periods", periods),
    DM("_duty_scale", duty_scale),
    DM("_rs", rs), DM("_ld", ld), DM("_lq", lq), DM("_w_start", w_start), LM("_dturns", dturns),
    DM("_sw_f", sw_f), DM("_sw_td", sw_td), DM("_sw_c", sw_c), DM("_sw_smp", sw_smp), DM("_sw_l", sw_l), BM("_sw_avg", sw_avg),
    DM("_sw_u", sw_u), DM("_sw_e0", sw_e[0]), DM("_sw_e1", sw_e[1]), DM("_sw_e2", sw_e[2]),
    IM("_sw_s0", sw_s[0]), IM("_sw_s1", sw_s[1]), IM("_sw_s2", sw_s[2]),
    DM("_ia_s", ia_s), DM("_ib_s", ib_s), BM("_sw_on", sw_on), BM("_adc_live", adc_live),
    {NULL, 0, 0, 0, NULL},
};

/* _set_outputs(names): the double members append_state copies, in order (model.OUTPUTS' sources) */
static PyObject *Core_set_outputs(Core *s, PyObject *names)
{
    PyObject *seq = PySequence_Fast(names, "_set_outputs: expected a sequence of member names");
    if (seq == NULL) return NULL;
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    if (n > MAX_OUTPUTS) {
        Py_DECREF(seq);
        return PyErr_Format(PyExc_ValueError, "_set_outputs: at most %d outputs, got %zd", MAX_OUTPUTS, n);
    }
    Py_ssize_t off[MAX_OUTPUTS];
    for (Py_ssize_t i = 0; i < n; i++) {
        const char *name = PyUnicode_AsUTF8(PySequence_Fast_GET_ITEM(seq, i));
        const PyMemberDef *m = Core_members;
        if (name == NULL) { Py_DECREF(seq); return NULL; }
        while (m->name != NULL && !(m->type == T_DOUBLE && strcmp(m->name, name) == 0)) m++;
        if (m->name == NULL) {
            PyErr_Format(PyExc_ValueError, "_set_outputs: %s is not a double of the C core (add it to Core)", name);
            Py_DECREF(seq);
            return NULL;
        }
        off[i] = m->offset;
    }
    Py_DECREF(seq);
    memcpy(s->out_off, off, sizeof(Py_ssize_t) * (size_t)n);
    s->n_out = (int)n;
    Py_RETURN_NONE;
}

/* model.Plant.sense: (hall_bits, fault_input, encoder_index, encoder_count, adc_codes(roles)) in one call */
static PyObject *Core_sense(Core *s, PyObject *roles)
{
    PyObject *codes = Core_adc_codes(s, roles);
    if (codes == NULL) return NULL;
    PyObject *out = PyTuple_New(5);
    PyObject *hall = PyLong_FromLong(s->hall_bits), *count = PyLong_FromLong(s->encoder_count);
    if (out == NULL || hall == NULL || count == NULL) {
        Py_XDECREF(out); Py_XDECREF(hall); Py_XDECREF(count); Py_DECREF(codes);
        return NULL;
    }
    PyTuple_SET_ITEM(out, 0, hall);
    PyTuple_SET_ITEM(out, 1, Py_NewRef(s->fault_input ? Py_True : Py_False));
    PyTuple_SET_ITEM(out, 2, Py_NewRef(s->encoder_index ? Py_True : Py_False));
    PyTuple_SET_ITEM(out, 3, count);
    PyTuple_SET_ITEM(out, 4, codes);
    return out;
}

static PyMethodDef Core_methods[] = {
    {"step", (PyCFunction)(void (*)(void))Core_step, METH_FASTCALL,
     "step(duty_a, duty_b, duty_c, output_mode, dt_s[, state_to]) -> last_edge_s: one step (see model.Plant)."},
    {"advance", (PyCFunction)(void (*)(void))Core_advance, METH_FASTCALL,
     "advance(duty_a, duty_b, duty_c, output_mode[, state_to]) -> last_edge_s: one exchange period (see model.Plant)."},
    {"edges", (PyCFunction)Core_edges, METH_NOARGS, "edges(): ((t_s, hall_bits), ...) of the last advance."},
    {"index_marks", (PyCFunction)Core_index_marks, METH_NOARGS, "index_marks(): (t_s, ...) of the last advance."},
    {"_set_outputs", (PyCFunction)Core_set_outputs, METH_O, "_set_outputs(names): what append_state copies."},
    {"adc_codes", (PyCFunction)Core_adc_codes, METH_O, "adc_codes(roles): ADC codes (see model.Plant)."},
    {"sense", (PyCFunction)Core_sense, METH_O,
     "sense(roles): (hall_bits, fault_input, encoder_index, encoder_count, adc_codes(roles)) (see model.Plant)."},
    {"append_state", (PyCFunction)Core_append_state, METH_O,
     "append_state(buf): the recorded outputs (model.OUTPUTS) as doubles onto a bytearray."},
    {"_set_adc", (PyCFunction)(void (*)(void))Core_set_adc, METH_FASTCALL, "_set_adc(role, gain, offset, noise)"},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject CoreType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "hilbench.plant._plantcore.Core",
    .tp_basicsize = sizeof(Core),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_BASETYPE,
    .tp_doc = "State and compiled step of the C plant backend (base of model._CPlant).",
    .tp_new = Core_new,
    .tp_dealloc = (destructor)Core_dealloc,
    .tp_members = Core_members,
    .tp_methods = Core_methods,
};

/* ---- the C span's plant (hbglue.h, hilbench/bench/_span.c) ---------------------------------- */
static int span_sense(PyObject *self, const int *roles, int n_roles, hb_plant_sense_t *out)
{
    Core *s = (Core *)self;
    out->n_adc = n_roles;
    for (int k = 0; k < n_roles; k++)
        if (adc_code(s, roles[k], &out->adc[k]) < 0) return -1;
    out->hall = s->hall_bits;
    out->tripped = s->fault_input != 0;
    out->index = s->encoder_index != 0;
    out->encoder = s->encoder_count;
    return 0;
}

static int span_advance(PyObject *self, long duty_a, long duty_b, long duty_c, long output_mode, char *row,
                        int *have_edge, double *edge_s)
{
    Core *s = (Core *)self;
    double duty[3] = {(double)duty_a * s->duty_scale, (double)duty_b * s->duty_scale, (double)duty_c * s->duty_scale};
    if (advance_period(s, duty, output_mode) < 0) return -1;
    if (row != NULL)
        for (int i = 0; i < s->n_out; i++)
            memcpy(row + i * sizeof(double), (const char *)s + s->out_off[i], sizeof(double));
    *have_edge = s->last_edge_s != NULL && s->last_edge_s != Py_None;
    *edge_s = *have_edge ? PyFloat_AsDouble(s->last_edge_s) : 0.0;
    return 0;
}

static int span_n_outputs(PyObject *self) { return ((Core *)self)->n_out; }
static int span_fault_input(PyObject *self) { return ((Core *)self)->fault_input != 0; }

static void span_period_edges(PyObject *self, const double **edge_t, const int **edge_hall, int *n_edges,
                              const double **mark_t, int *n_marks, int *index)
{
    Core *s = (Core *)self;
    *edge_t = s->edge_t;
    *edge_hall = s->edge_hall;
    *n_edges = s->n_edges;
    *mark_t = s->mark_t;
    *n_marks = s->n_marks;
    *index = s->encoder_index != 0;
}

static double span_speed_rad_s(PyObject *self) { return ((Core *)self)->w_m; }

static hb_plant_api_t span_api = {span_sense, span_advance, span_n_outputs, span_fault_input, span_period_edges,
                                  span_speed_rad_s};

static PyMethodDef module_methods[] = {
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moduledef = {
    PyModuleDef_HEAD_INIT, "_plantcore", "Compiled core of hilbench.plant (optional).", -1, module_methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__plantcore(void)
{
    TWO_PI = 2.0 * Py_MATH_PI;
    SIXTY = Py_MATH_PI / 3.0;
    INV_SQRT3 = 1.0 / sqrt(3.0);
    HALF_SQRT3 = 0.5 * sqrt(3.0);
    str_step_py = PyUnicode_InternFromString("_step_py");
    str_update_load = PyUnicode_InternFromString("_update_load");
    str_draw_noise = PyUnicode_InternFromString("_draw_noise");
    if (str_step_py == NULL || str_update_load == NULL || str_draw_noise == NULL) return NULL;
    PyObject *m = hb_module(&moduledef, &CoreType, "Core");
    return hb_add_span_api(m, &span_api, HB_PLANT_API);
}
