/* Compiled F2812 FOC firmware model (the "c" backend of hilbench.targets.foc.FocTarget).
 *
 * Core is the base type of foc.target._CFirmware: the state of firmware.FocFirmware (its blocks'
 * fields flattened: spd_kp, qep_t2cnt, sp_speed, ...) lives in this struct as members, and the
 * per-exchange work runs here: Core.step is FocTarget.step (S2, QEP, the halves with their ISR,
 * the Drive), Core.run_halves and Core.drive the pieces FocTarget.advance uses, Core.start and
 * Core.stop the host commands. Every line mirrors firmware.py / blocks.py / svpwm.py / target.py;
 * tests/test_foc_core.py compares every Drive and the state with the Python model.
 *
 * Arithmetic: int64_t for everything; wrap32 is IQmath's 32-bit long, asr Python's floor shift.
 */
#include "hbglue.h"
#include <stdint.h>

#define ONE 16777216LL
#define T1PR 7500
#define T_PWM_QUARTER 3750
#define HALF_SQRT3 14529495LL
#define HALF 8388608LL
#define INV_SQRT3 9686330LL
#define TWO 33554432LL
#define INPUT_S2 0x08
#define ST_STOPPED 0
#define ST_ALIGN 1
#define ST_RUN 2
#define ST_FAULT 4

static int64_t SIN_TABLE[32768];
static PyTypeObject *drive_type = NULL;
static long input_index = 0x40;

static inline int64_t asr(int64_t a, int n) { return a >= 0 ? a >> n : ~((~a) >> n); }
static inline int64_t wrap32(int64_t x)
{
    uint64_t u = (uint64_t)x & 0xFFFFFFFFULL;
    return u >= 0x80000000ULL ? (int64_t)u - 0x100000000LL : (int64_t)u;
}
static inline int64_t mpy(int64_t a, int64_t b) { return wrap32(asr(a * b, 24)); }
static inline int64_t pymod(int64_t a, int64_t b) { int64_t r = a % b; return r < 0 ? r + b : r; }
static inline int64_t sat(int64_t x, int64_t hi, int64_t lo) { return x > hi ? hi : x < lo ? lo : x; }

typedef struct {
    int64_t kp, ki, kc, out_max, out_min, ui, up, sat_err, up1, out, v1, i1, pre;
} Pi;

typedef struct {
    PyObject_HEAD
    Pi spd, pid, piq;
    long long pi_form;  /* 0 PID_REG3, 1 clamping PI */
    long long state, fault, outputs_on, speed_ref, speed_setpoint, id_ref, iq_ref, torque_mode, iq_ref_set;
    long long isr_count, state_isrs, speed_loop_count, index_learned, elec_theta;
    long long i_a, i_b, i_alpha, i_beta, i_d, i_q, v_d, v_q, v_alpha, v_beta, vdc_code, sector;
    long long cs1, cs2, cs3, ca1, ca2, ca3;
    long long enc_last, have_enc;
    long long align_isrs, align_v, align_i, prescaler, ramp_step, learn_index;
    /* QEP */
    long long line_encoder, pole_pairs, cal, mech_scaler, t2pr, t2cnt, direction, raw_theta, mech_theta,
        qep_theta, qep_count_index, index_sync_flag, signed16;
    /* SPEED_FR */
    long long sp_speed, sp_old, sp_rpm, sp_k1, sp_k2, sp_k3, sp_base_rpm, sp_unwrap;
    /* target */
    long long half, halves, s2_last, last_seq;
} Core;

/* ---------------------------------------------------------------- blocks */
static int64_t pi_calc(Core *s, Pi *p, int64_t ref, int64_t fdb)
{
    if (s->pi_form == 0) {  /* PID_REG3, Kd = 0 */
        int64_t err = wrap32(ref - fdb);
        int64_t up = mpy(p->kp, err);
        int64_t ui = wrap32(p->ui + mpy(p->ki, up) + mpy(p->kc, p->sat_err));
        int64_t pre = wrap32(up + ui);
        int64_t out = pre > p->out_max ? p->out_max : pre < p->out_min ? p->out_min : pre;
        p->up = up; p->ui = ui; p->pre = pre; p->out = out;
        p->sat_err = wrap32(out - pre);
        p->up1 = up;
        return out;
    }
    int64_t up = mpy(p->kp, wrap32(ref - fdb));
    int64_t ui = p->out == p->v1 ? wrap32(mpy(p->ki, up) + p->i1) : p->i1;
    p->i1 = ui;
    int64_t v1 = wrap32(up + ui);
    int64_t out = v1 > p->out_max ? p->out_max : v1 < p->out_min ? p->out_min : v1;
    p->up = up; p->ui = ui; p->v1 = v1; p->out = out;
    return out;
}

static void pi_reset(Pi *p)
{
    p->ui = p->up = p->sat_err = p->up1 = p->out = p->v1 = p->i1 = p->pre = 0;
}

static int64_t adc_to_iq(int64_t code)
{
    int64_t q15 = ((code * 16) ^ 0x8000) & 0xFFFF;
    if (q15 & 0x8000) q15 -= 0x10000;
    return wrap32(q15 * 512);
}

static void svpwm(int64_t ua, int64_t ub, int64_t *n_out, int64_t c[3])
{
    static const int P_TO_N[8] = {0, 2, 6, 1, 4, 3, 5, 0};
    int64_t a = mpy(HALF_SQRT3, ua);
    int64_t h = mpy(HALF, ub);
    int64_t ux = ub, uy = wrap32(a - h), uz = wrap32(-a - h);
    int p = (ux > 0) + 2 * (uy > 0) + 4 * (uz > 0);
    int n = P_TO_N[p];
    int64_t v[3];
    switch (n ? (n - 1) % 3 : -1) {
    case 0: v[0] = ONE - uy - ux; v[1] = ONE + uy - ux; v[2] = ONE + uy + ux; break;
    case 1: v[0] = ONE - uy + uz; v[1] = ONE + uy + uz; v[2] = ONE - uy - uz; break;
    case 2: v[0] = ONE + ux + uz; v[1] = ONE - ux - uz; v[2] = ONE + ux - uz; break;
    default: v[0] = v[1] = v[2] = ONE; break;
    }
    for (int k = 0; k < 3; k++) {
        int64_t x = asr(wrap32(v[k]) * T_PWM_QUARTER, 24);
        c[k] = x > 0 ? x : 0;
    }
    *n_out = n;
}

static int64_t qep_calc(Core *s)
{
    int64_t raw = (int64_t)((uint64_t)(s->t2cnt + s->cal) & 0xFFFFULL);
    int64_t src16 = (s->signed16 && (raw & 0x8000)) ? raw - 0x10000 : raw;
    int64_t mech = asr(s->mech_scaler * (src16 * 65536), 31) & 0x7FFF;
    s->raw_theta = raw;
    s->mech_theta = mech;
    s->qep_theta = (s->pole_pairs * mech) & 0x7FFF;
    return s->qep_theta;
}

static void speed_calc(Core *s)
{
    int64_t theta = s->elec_theta, tmp;
    if (s->sp_unwrap) {  /* v4.3 */
        int64_t d = wrap32(theta - s->sp_old);
        if (d < -(ONE >> 1)) d = wrap32(d + ONE);
        else if (d > (ONE >> 1)) d = wrap32(d - ONE);
        tmp = mpy(s->sp_k1, d);
    } else if (1677721 < theta && theta < 15099494)
        tmp = mpy(s->sp_k1, wrap32(theta - s->sp_old));
    else
        tmp = asr(s->sp_speed, 3);
    tmp = wrap32(mpy(s->sp_k2, asr(s->sp_speed, 3)) + mpy(s->sp_k3, tmp));
    tmp = sat(tmp, 1LL << 21, -(1LL << 21));
    s->sp_speed = wrap32(tmp * 8);
    s->sp_old = theta;
    s->sp_rpm = mpy(s->sp_base_rpm, s->sp_speed);
}

/* ---------------------------------------------------------------- firmware */
static void enter(Core *s, long long state)
{
    s->state = state;
    s->state_isrs = 0;
    pi_reset(&s->pid); pi_reset(&s->piq); pi_reset(&s->spd);
    s->iq_ref = 0;
    s->speed_loop_count = 0;
    s->speed_setpoint = 0;
}

static void fw_start(Core *s)
{
    if (s->state == ST_STOPPED || s->state == ST_FAULT) {
        s->fault = 0;
        enter(s, ST_ALIGN);
        s->outputs_on = 1;
    }
}

static void fw_stop(Core *s, long long state, long long fault)
{
    s->state = state;
    s->fault = fault;
    s->outputs_on = 0;
    s->cs1 = s->cs2 = s->cs3 = s->ca1 = s->ca2 = s->ca3 = T1PR;
    s->v_d = s->v_q = 0;
    s->sector = 0;
}

static void index_isr(Core *s)
{
    if (s->learn_index && !s->index_learned) {
        s->cal = pymod(s->t2cnt + s->cal, 4 * s->line_encoder);
        s->index_learned = 1;
    }
    s->qep_count_index = s->t2cnt;
    s->t2cnt = 0;
    s->index_sync_flag = 0x00F0;
}

static void encoder(Core *s, int64_t count16, int index)
{
    if (s->have_enc) {
        int64_t delta = ((count16 - s->enc_last + 0x8000) & 0xFFFF) - 0x8000;
        if (delta) {
            s->t2cnt = pymod(s->t2cnt + delta, s->t2pr + 1);
            s->direction = delta > 0;
        }
    }
    s->enc_last = count16;
    s->have_enc = 1;
    if (index) index_isr(s);
}

static void isr(Core *s, int64_t adc_ia, int64_t adc_ib, int64_t adc_vdc)
{
    s->isr_count += 1;
    s->vdc_code = adc_vdc;
    int64_t ia = s->i_a = adc_to_iq(adc_ia);
    int64_t ib = s->i_b = adc_to_iq(adc_ib);
    int64_t alpha = ia, beta = mpy(wrap32(ia + mpy(TWO, ib)), INV_SQRT3);
    s->i_alpha = alpha; s->i_beta = beta;
    long long state = s->state;
    int64_t angle = s->elec_theta;
    if (state == ST_ALIGN) angle = (-(ONE >> 2)) & (ONE - 1);
    int64_t k = asr(angle, 9) & 0x7FFF;
    int64_t sine = SIN_TABLE[k], cosine = SIN_TABLE[(k + 8192) & 0x7FFF];
    int64_t i_d = wrap32(mpy(alpha, cosine) + mpy(beta, sine));
    int64_t i_q = wrap32(mpy(beta, cosine) - mpy(alpha, sine));
    s->i_d = i_d; s->i_q = i_q;
    int64_t v_d, v_q;
    if (state == ST_RUN) {
        s->speed_loop_count += 1;
        if (s->torque_mode) {
            s->iq_ref = s->iq_ref_set;
            s->speed_loop_count = 0;
        } else if (s->speed_loop_count >= s->prescaler) {
            s->speed_loop_count = 0;
            int64_t ref = s->speed_ref, step = s->ramp_step;
            if (step) {
                int64_t sp = s->speed_setpoint;
                ref = ref > sp + step ? sp + step : ref < sp - step ? sp - step : ref;
            }
            s->speed_setpoint = ref;
            s->iq_ref = pi_calc(s, &s->spd, ref, s->sp_speed);
        }
        v_q = pi_calc(s, &s->piq, s->iq_ref, i_q);
        v_d = pi_calc(s, &s->pid, s->id_ref, i_d);
    } else if (state == ST_ALIGN) {
        if (s->align_i) {
            v_q = pi_calc(s, &s->piq, s->align_i, i_q);
            v_d = pi_calc(s, &s->pid, 0, i_d);
        } else {
            v_d = 0;
            v_q = s->align_v;
        }
        s->state_isrs += 1;
        if (s->state_isrs >= s->align_isrs) {
            s->t2cnt = 0;
            enter(s, ST_RUN);
        }
    } else {
        v_d = v_q = 0;
    }
    s->v_d = v_d; s->v_q = v_q;
    if (s->outputs_on) {
        int64_t va = wrap32(mpy(v_d, cosine) - mpy(v_q, sine));
        int64_t vb = wrap32(mpy(v_q, cosine) + mpy(v_d, sine));
        s->v_alpha = va; s->v_beta = vb;
        int64_t n, c[3];
        svpwm(va, vb, &n, c);
        s->sector = n;
        s->cs1 = c[0]; s->cs2 = c[1]; s->cs3 = c[2];
    }
    int64_t q15 = qep_calc(s);
    s->elec_theta = wrap32(q15 * 512);
    speed_calc(s);
}

/* ---------------------------------------------------------------- target */
static void inputs(Core *s, long in)
{
    int s2 = (in & INPUT_S2) != 0;
    if (s2 && !s->s2_last) {
        if (s->state == ST_ALIGN || s->state == ST_RUN) fw_stop(s, ST_STOPPED, 0);
        else fw_start(s);
    }
    s->s2_last = s2;
}

static int run_halves(Core *s, int64_t n, long in, int64_t enc, PyObject *adc, int64_t duty[3])
{
    int64_t a[3] = {0, 0, 0};
    int have_adc = 0;
    encoder(s, enc, (in & input_index) != 0);
    int64_t sa = 0, sb = 0, sc = 0;
    for (int64_t i = 0; i < n; i++) {
        if (s->half == 0) {
            s->ca1 = s->cs1; s->ca2 = s->cs2; s->ca3 = s->cs3;
            if (!have_adc) {
                have_adc = 1;
                if (!PyTuple_Check(adc) || PyTuple_GET_SIZE(adc) < 3) {
                    PyErr_SetString(PyExc_ValueError, "foc core: Sensors.adc must hold (ia, ib, vbus)");
                    return -1;
                }
                for (int k = 0; k < 3; k++) {
                    a[k] = PyLong_AsLongLong(PyTuple_GET_ITEM(adc, k));
                    if (a[k] == -1 && PyErr_Occurred()) return -1;
                }
            }
            isr(s, a[0], a[1], a[2]);
            s->half = 1;
        } else {
            s->ca1 = s->cs1; s->ca2 = s->cs2; s->ca3 = s->cs3;
            s->half = 0;
        }
        if (s->outputs_on) {
            sa += s->ca1 < T1PR ? T1PR - s->ca1 : 0;
            sb += s->ca2 < T1PR ? T1PR - s->ca2 : 0;
            sc += s->ca3 < T1PR ? T1PR - s->ca3 : 0;
        }
    }
    int64_t sum[3] = {sa, sb, sc};
    for (int k = 0; k < 3; k++) {
        if (n <= 1) { duty[k] = sum[k]; continue; }
        int64_t q = sum[k] / n, r = sum[k] - q * n;  /* Python's round(sum/n): half to even */
        duty[k] = 2 * r > n ? q + 1 : 2 * r == n ? q + (q & 1) : q;
    }
    return 0;
}

static PyObject *make_drive(Core *s, PyObject *seq, const int64_t duty[3])
{
    if (drive_type == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "foc core: init(Drive, SIN_TABLE) was not called");
        return NULL;
    }
    int64_t ref = s->ramp_step ? s->speed_setpoint : s->speed_ref;
    PyObject *tel = Py_BuildValue("(LLLLLLLL)", (long long)asr(ref, 9), (long long)asr(s->sp_speed, 9),
                                  (long long)asr(s->iq_ref, 9), (long long)asr(s->i_d, 9), (long long)asr(s->i_q, 9),
                                  (long long)asr(s->elec_theta, 9), (long long)asr(s->v_d, 9), (long long)asr(s->v_q, 9));
    if (tel == NULL) return NULL;
    PyObject *fields[HB_DRIVE_FIELDS] = {
        Py_NewRef(seq), PyLong_FromLongLong(duty[0]), PyLong_FromLongLong(duty[1]), PyLong_FromLongLong(duty[2]),
        PyLong_FromLong(s->outputs_on ? 1 : 0), PyLong_FromLongLong(s->state), PyLong_FromLongLong(s->sector & 7),
        PyBool_FromLong(s->sp_speed < 0), PyBool_FromLong(s->speed_ref < 0), PyLong_FromLongLong(s->fault), tel,
    };
    return hb_drive(drive_type, fields);
}

static int unpack_sensors(PyObject *sensors, PyObject **seq, long *in, int64_t *enc, PyObject **adc)
{
    hb_sensors_t f;
    if (hb_sensors(sensors, &f, "foc core") < 0) return -1;
    *seq = f.seq;
    *in = f.inputs;
    *enc = f.encoder;
    *adc = f.adc;
    return 0;
}

static PyObject *Core_step(Core *s, PyObject *sensors)
{
    PyObject *seq, *adc;
    long in;
    int64_t enc, duty[3];
    if (unpack_sensors(sensors, &seq, &in, &enc, &adc) < 0) return NULL;
    s->last_seq = PyLong_AsLongLong(seq);
    if (s->last_seq == -1 && PyErr_Occurred()) return NULL;
    inputs(s, in);
    if (run_halves(s, s->halves, in, enc, adc, duty) < 0) return NULL;
    return make_drive(s, seq, duty);
}

static PyObject *Core_inputs(Core *s, PyObject *arg)
{
    long in = PyLong_AsLong(arg);
    if (in == -1 && PyErr_Occurred()) return NULL;
    inputs(s, in);
    Py_RETURN_NONE;
}

static PyObject *Core_run_halves(Core *s, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 2) { PyErr_SetString(PyExc_TypeError, "run_halves(n, sensors)"); return NULL; }
    long long n = PyLong_AsLongLong(args[0]);
    if (n == -1 && PyErr_Occurred()) return NULL;
    PyObject *seq, *adc;
    long in;
    int64_t enc, duty[3];
    if (unpack_sensors(args[1], &seq, &in, &enc, &adc) < 0) return NULL;
    if (run_halves(s, n, in, enc, adc, duty) < 0) return NULL;
    return Py_BuildValue("(LLL)", (long long)duty[0], (long long)duty[1], (long long)duty[2]);
}

static PyObject *Core_drive(Core *s, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 4) { PyErr_SetString(PyExc_TypeError, "drive(seq, a, b, c)"); return NULL; }
    int64_t duty[3];
    for (int k = 0; k < 3; k++) {
        duty[k] = PyLong_AsLongLong(args[k + 1]);
        if (duty[k] == -1 && PyErr_Occurred()) return NULL;
    }
    return make_drive(s, args[0], duty);
}

static PyObject *Core_start(Core *s, PyObject *unused)
{
    (void)unused;
    fw_start(s);
    Py_RETURN_NONE;
}

static PyObject *Core_stop(Core *s, PyObject *const *args, Py_ssize_t nargs)
{
    long long st = ST_STOPPED, ft = 0;
    if (nargs > 2) { PyErr_SetString(PyExc_TypeError, "stop(state=0, fault=0)"); return NULL; }
    if (nargs > 0 && (st = PyLong_AsLongLong(args[0])) == -1 && PyErr_Occurred()) return NULL;
    if (nargs > 1 && (ft = PyLong_AsLongLong(args[1])) == -1 && PyErr_Occurred()) return NULL;
    fw_stop(s, st, ft);
    Py_RETURN_NONE;
}

static PyObject *Core_new(PyTypeObject *type, PyObject *args, PyObject *kwds)
{
    (void)args; (void)kwds;
    Core *s = (Core *)type->tp_alloc(type, 0);
    if (s == NULL) return NULL;
    s->ca1 = s->ca2 = s->ca3 = s->cs1 = s->cs2 = s->cs3 = T1PR;
    s->halves = 1;
    s->direction = 1;
    s->line_encoder = 2500;
    s->t2pr = 10000;
    s->prescaler = 10;
    return (PyObject *)s;
}

#define LM(name, field) HB_MEMBER(name, T_LONGLONG, Core, field, 0)
#define PIM(nm, f) LM(nm "_kp", f.kp), LM(nm "_ki", f.ki), LM(nm "_kc", f.kc), LM(nm "_out_max", f.out_max), \
    LM(nm "_out_min", f.out_min), LM(nm "_ui", f.ui), LM(nm "_up", f.up), LM(nm "_sat_err", f.sat_err), \
    LM(nm "_up1", f.up1), LM(nm "_out", f.out), LM(nm "_v1", f.v1), LM(nm "_i1", f.i1), LM(nm "_pre", f.pre)

static PyMemberDef Core_members[] = {
    PIM("spd", spd), PIM("id", pid), PIM("iq", piq),
    LM("pi_form", pi_form), LM("state", state), LM("fault", fault), LM("_outputs_on", outputs_on),
    LM("speed_ref", speed_ref), LM("speed_setpoint", speed_setpoint), LM("id_ref", id_ref), LM("iq_ref", iq_ref),
    LM("_torque_mode", torque_mode), LM("iq_ref_set", iq_ref_set), LM("isr_count", isr_count),
    LM("state_isrs", state_isrs), LM("speed_loop_count", speed_loop_count), LM("_index_learned", index_learned),
    LM("elec_theta", elec_theta), LM("i_a", i_a), LM("i_b", i_b), LM("i_alpha", i_alpha), LM("i_beta", i_beta),
    LM("i_d", i_d), LM("i_q", i_q), LM("v_d", v_d), LM("v_q", v_q), LM("v_alpha", v_alpha), LM("v_beta", v_beta),
    LM("vdc_code", vdc_code), LM("sector", sector), LM("cs1", cs1), LM("cs2", cs2), LM("cs3", cs3),
    LM("ca1", ca1), LM("ca2", ca2), LM("ca3", ca3), LM("enc_last", enc_last), LM("have_enc", have_enc),
    LM("align_isrs", align_isrs), LM("align_v", align_v), LM("align_i", align_i), LM("prescaler", prescaler),
    LM("ramp_step", ramp_step), LM("learn_index", learn_index),
    LM("qep_line_encoder", line_encoder), LM("qep_pole_pairs", pole_pairs), LM("qep_calibrated_angle", cal),
    LM("qep_mech_scaler", mech_scaler), LM("qep_t2pr", t2pr), LM("qep_t2cnt", t2cnt), LM("qep_direction", direction),
    LM("qep_raw_theta", raw_theta), LM("qep_mech_theta", mech_theta), LM("qep_elec_theta", qep_theta),
    LM("qep_qep_count_index", qep_count_index), LM("qep_index_sync_flag", index_sync_flag),
    LM("qep_signed16", signed16),
    LM("sp_speed", sp_speed), LM("sp_old_elec_theta", sp_old), LM("sp_speed_rpm", sp_rpm), LM("sp_k1", sp_k1),
    LM("sp_k2", sp_k2), LM("sp_k3", sp_k3), LM("sp_base_rpm", sp_base_rpm), LM("sp_unwrap", sp_unwrap),
    LM("half", half), LM("halves", halves), LM("s2_last", s2_last), LM("last_seq", last_seq),
    {NULL, 0, 0, 0, NULL},
};

static PyMethodDef Core_methods[] = {
    {"step", (PyCFunction)Core_step, METH_O, "step(sensors) -> Drive: FocTarget.step for `halves` half periods."},
    {"inputs", (PyCFunction)Core_inputs, METH_O, "inputs(bits): S2 as FocTarget._inputs."},
    {"run_halves", (PyCFunction)(void (*)(void))Core_run_halves, METH_FASTCALL,
     "run_halves(n, sensors) -> (a, b, c): FocTarget._run_halves."},
    {"drive", (PyCFunction)(void (*)(void))Core_drive, METH_FASTCALL, "drive(seq, a, b, c) -> Drive."},
    {"start", (PyCFunction)Core_start, METH_NOARGS, "FocFirmware.start."},
    {"stop", (PyCFunction)(void (*)(void))Core_stop, METH_FASTCALL, "stop(state=0, fault=0): FocFirmware.stop."},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject CoreType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "hilbench.targets.foc._core.Core",
    .tp_basicsize = sizeof(Core),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_BASETYPE,
    .tp_doc = "Firmware state and compiled step of the FOC C backend (base of foc.target._CFirmware).",
    .tp_new = Core_new,
    .tp_members = Core_members,
    .tp_methods = Core_methods,
};

static PyObject *mod_init(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 3) { PyErr_SetString(PyExc_TypeError, "init(Drive, SIN_Q15_TABLE, INPUT_INDEX)"); return NULL; }
    PyObject *drive = args[0];
    PyObject *table = PySequence_Fast(args[1], "foc core init: the table must be a sequence");
    if (table == NULL) return NULL;
    if (PySequence_Fast_GET_SIZE(table) != 32768) {
        Py_DECREF(table);
        PyErr_SetString(PyExc_ValueError, "foc core init: SIN_Q15_TABLE must have 32768 entries");
        return NULL;
    }
    for (int i = 0; i < 32768; i++) {
        long long v = PyLong_AsLongLong(PySequence_Fast_GET_ITEM(table, i));
        if (v == -1 && PyErr_Occurred()) { Py_DECREF(table); return NULL; }
        SIN_TABLE[i] = v;
    }
    Py_DECREF(table);
    if (hb_long(args[2], &input_index) < 0 || hb_set_tuple_type(drive, &drive_type, "foc core init") < 0) return NULL;
    Py_RETURN_NONE;
}

static PyMethodDef module_methods[] = {
    {"init", (PyCFunction)(void (*)(void))mod_init, METH_FASTCALL,
     "init(Drive, SIN_Q15_TABLE, INPUT_INDEX): the NamedTuple the core builds, the sine table, the index bit."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moduledef = {
    PyModuleDef_HEAD_INIT, "_core", "Compiled F2812 FOC firmware model (optional).", -1, module_methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__core(void)
{
    return hb_module(&moduledef, &CoreType, "Core");
}
