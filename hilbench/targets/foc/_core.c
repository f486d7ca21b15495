/* The in-process FOC core (the "c" backend of hilbench.targets.foc.FocTarget): the firmware
 * firmware/foc/ (foc.c, foc_blocks.c, foc_sin_table.c), compiled into this extension, behind a
 * thin CPython glue.
 *
 * The firmware logic is firmware/foc's and nothing else: the same source runs in the SIL process,
 * in the simulated MCUs and here. This file owns one foc_t plus what the Python target needs
 * around it: the agreed number of half PWM periods per exchange, the last seq, and the Drive type.
 * step(sensors) is FocTarget.step: S2 (foc_buttons), the encoder and index (foc_encoder), the
 * halves with their ISRs (foc_run_halves), the Drive (foc_outputs). The members carry the names
 * target._CFirmware has always shown (spd_kp, qep_t2cnt, sp_speed, ...), so the target and the
 * tests read the firmware's state the same way on both backends; tests/test_foc_core.py compares
 * every Drive with the Python reference hilbench/targets/foc/firmware.py.
 */
#include "hbglue.h"
#include <stdint.h>

#include "foc.h"

#define HALVES_MAX 572662LL /* foc_run_halves sums T1 counts in 32 bits */

static PyTypeObject *drive_type = NULL;
static PyObject *duty_ints[FOC_T1PR + 1]; /* the duty values a Drive can carry, made once */

typedef struct {
    PyObject_HEAD
    foc_t fw;
    long long halves;   /* half PWM periods per lockstep exchange */
    long long last_seq;   /* the last Sensors' seq, stepped or refused (the watchdog's Drive carries it) */
    PyObject *last_drive; /* the answer to a repeated seq (a duplicated frame): no second step */
    char span_last;       /* the last step was the C span's: span_seq has a Drive, not yet built */
    long long span_seq;   /* the seq of the C span's last step: set only once that step ran, so that
                           * a resent Sensors the core refused is refused again, not taken as a repeat */
    uint16_t duty[3];     /* the duties of the last step */
    double frac_us;       /* real time: the part of a half period the last advance left over (FocTarget._frac_us) */
} Core;

/* ---------------------------------------------------------------- Drive */
static PyObject *make_drive(Core *s, PyObject *seq, const uint16_t duty[3])
{
    foc_out_t o;
    foc_outputs(&s->fw, &o);
    const int16_t *t = o.telemetry;
    PyObject *tel = Py_BuildValue("(hhhhhhhh)", t[0], t[1], t[2], t[3], t[4], t[5], t[6], t[7]);
    if (tel == NULL) return NULL;
    return hb_drive(drive_type, Py_NewRef(seq), Py_NewRef(duty_ints[duty[0] <= FOC_T1PR ? duty[0] : FOC_T1PR]),
                    Py_NewRef(duty_ints[duty[1] <= FOC_T1PR ? duty[1] : FOC_T1PR]),
                    Py_NewRef(duty_ints[duty[2] <= FOC_T1PR ? duty[2] : FOC_T1PR]), Py_NewRef(duty_ints[o.output_mode]),
                    Py_NewRef(duty_ints[o.state]), Py_NewRef(duty_ints[o.sector]), PyBool_FromLong(o.ccw),
                    PyBool_FromLong(o.req_ccw), Py_NewRef(duty_ints[o.fault & 63u]), tel);
}

static int need_drive(void)
{
    if (drive_type == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "foc core: init(Drive, INPUT_INDEX) was not called");
        return -1;
    }
    return 0;
}

/* ---------------------------------------------------------------- Sensors */
static long input_index = FOC_INPUT_INDEX;

typedef struct {
    PyObject *seq;
    long inputs;
    long long encoder;
    PyObject *adc;
} sensors_t;

static int unpack_sensors(PyObject *sensors, sensors_t *out)
{
    hb_sensors_t f; /* the shared glue's reading of a Sensors tuple */
    if (hb_sensors(sensors, &f, "foc core") < 0) return -1;
    out->seq = f.seq;
    out->inputs = f.inputs;
    out->adc = f.adc;
    return hb_longlong(f.encoder, &out->encoder);
}

/* The ADC results the underflow samples: read only when an underflow falls in the n halves. */
static int load_adc(Core *s, PyObject *adc, long long n)
{
    if (n == 0 || (n == 1 && s->fw.half != 0u)) return 0;
    if (!PyTuple_Check(adc) || PyTuple_GET_SIZE(adc) < 3) {
        PyErr_SetString(PyExc_ValueError, "foc core: Sensors.adc must hold (ia, ib, vbus)");
        return -1;
    }
    for (int k = 0; k < 3; k++) {
        long long v = PyLong_AsLongLong(PyTuple_GET_ITEM(adc, k));
        if (v == -1 && PyErr_Occurred()) return -1;
        s->fw.adc_result[k] = (uint16_t)((unsigned long long)v & 0xFFFFULL);
    }
    return 0;
}

static int run_halves(Core *s, long long n, const sensors_t *in, uint16_t duty[3])
{
    if (n < 0 || n > HALVES_MAX) {
        PyErr_Format(PyExc_ValueError, "foc core: %lld half periods in one exchange (0..%lld)", n, HALVES_MAX);
        return -1;
    }
    if (load_adc(s, in->adc, n) < 0) return -1;
    foc_encoder(&s->fw, (uint16_t)((unsigned long long)in->encoder & 0xFFFFULL), (in->inputs & input_index) != 0);
    foc_run_halves(&s->fw, (uint32_t)n, duty);
    return 0;
}

/* ---------------------------------------------------------------- methods */
/* step(sensors) -> Drive: FocTarget.step, with the kit's RepeatAnswer rule here (a Sensors
 * repeating the last Drive's seq gets that Drive, no step), as the AN1017 core answers repeats. */
static PyObject *Core_step(Core *s, PyObject *sensors)
{
    sensors_t in;
    if (need_drive() < 0 || unpack_sensors(sensors, &in) < 0) return NULL;
    long long seq = PyLong_AsLongLong(in.seq);
    if (seq == -1 && PyErr_Occurred()) return NULL;
    if (s->last_drive != NULL) {
        long long last = PyLong_AsLongLong(PyTuple_GET_ITEM(s->last_drive, 0));
        if (last == -1 && PyErr_Occurred()) return NULL;
        if (last == seq) return Py_NewRef(s->last_drive);
    } else if (s->span_last && s->span_seq == seq) { /* the C span's last step, repeated */
        PyObject *drive = make_drive(s, in.seq, s->duty);
        if (drive != NULL) {
            s->last_drive = Py_NewRef(drive);
            s->span_last = 0;
        }
        return drive;
    }
    s->last_seq = seq;
    foc_buttons(&s->fw, (uint16_t)(in.inputs & 0xFFFF));
    if (run_halves(s, s->halves, &in, s->duty) < 0) return NULL;
    PyObject *drive = make_drive(s, in.seq, s->duty);
    if (drive != NULL) {
        Py_XSETREF(s->last_drive, Py_NewRef(drive));
        s->span_last = 0;
    }
    return drive;
}

/* ---------------------------------------------------------------- the C span's step (hbglue.h) */
/* The Drive's values of the last step (its duties clamped to the wire's range, as make_drive does) */
static void report_values(Core *s, hb_cdrive_t *out)
{
    foc_out_t o;
    foc_outputs(&s->fw, &o);
    out->duty_a = s->duty[0] <= FOC_T1PR ? s->duty[0] : FOC_T1PR;
    out->duty_b = s->duty[1] <= FOC_T1PR ? s->duty[1] : FOC_T1PR;
    out->duty_c = s->duty[2] <= FOC_T1PR ? s->duty[2] : FOC_T1PR;
    out->output_mode = o.output_mode; out->state = o.state; out->sector = o.sector;
    out->direction_ccw = o.ccw != 0; out->required_ccw = o.req_ccw != 0; out->fault = o.fault & 63u;
    out->n_tel = 8;
    for (int k = 0; k < 8; k++) out->tel[k] = o.telemetry[k];
}

/* run_halves on C values: the ADC results when an underflow falls in the n halves (load_adc's
 * rule), the encoder and index, the halves; their duties in s->duty. 0, or -1 with run_halves's
 * ValueError. */
static int span_halves(Core *s, long long n, const hb_csensors_t *in)
{
    if (n < 0 || n > HALVES_MAX) {
        PyErr_Format(PyExc_ValueError, "foc core: %lld half periods in one exchange (0..%lld)", n, HALVES_MAX);
        return -1;
    }
    if (!(n == 0 || (n == 1 && s->fw.half != 0u))) {
        if (in->n_adc < 3) {
            PyErr_SetString(PyExc_ValueError, "foc core: Sensors.adc must hold (ia, ib, vbus)");
            return -1;
        }
        for (int k = 0; k < 3; k++) s->fw.adc_result[k] = (uint16_t)((unsigned long)in->adc[k] & 0xFFFFUL);
    }
    foc_encoder(&s->fw, (uint16_t)((unsigned long)in->encoder & 0xFFFFUL), (in->inputs & input_index) != 0);
    foc_run_halves(&s->fw, (uint32_t)n, s->duty);
    return 0;
}

static int span_step(PyObject *self, const hb_csensors_t *in, hb_cdrive_t *out)
{
    Core *s = (Core *)self;
    int repeat = s->span_last && s->span_seq == in->seq;
    if (s->last_drive != NULL) { /* as Core_step: the kept Drive's own seq */
        long long last = PyLong_AsLongLong(PyTuple_GET_ITEM(s->last_drive, 0));
        if (last == -1 && PyErr_Occurred()) return -1;
        repeat = last == in->seq;
    }
    if (!repeat) {
        s->last_seq = in->seq;
        foc_buttons(&s->fw, (uint16_t)(in->inputs & 0xFFFF));
        if (span_halves(s, s->halves, in) < 0) return -1;
        Py_CLEAR(s->last_drive);
        s->span_last = 1;
        s->span_seq = in->seq;
    }
    report_values(s, out);
    return 0;
}

/* Python's float floor division (CPython's float_floor_div: fmod, then the quotient rounded), so
 * that the C advance splits a span into half periods exactly as FocTarget.advance's `//` does */
static double py_floordiv(double a, double b)
{
    double mod = fmod(a, b);
    double div = (a - mod) / b;
    if (mod != 0.0 && ((b < 0) != (mod < 0))) div -= 1.0;
    if (div == 0.0) return copysign(0.0, a / b);
    double floordiv = floor(div);
    if (div - floordiv > 0.5) floordiv += 1.0;
    return floordiv;
}

/* FocTarget.advance on C values (real time): whole half periods of span_us, the remainder carried in
 * frac_us (the same double arithmetic as the Python method's), S2, then the halves run with the
 * Sensors' encoder and ADC results (none: the active compare values' on-times kept); the Drive's
 * values as span_step gives them (built by span_drive). 0, or -1 with the ValueError run_halves
 * raises for a span of more halves than one exchange may hold. */
static int span_advance(PyObject *self, double span_us, const hb_csensors_t *in, hb_cdrive_t *out)
{
    Core *s = (Core *)self;
    double total = span_us + s->frac_us;
    long long n = (long long)py_floordiv(total, (double)FOC_HALF_PERIOD_US);
    s->frac_us = total - (double)(n * (long long)FOC_HALF_PERIOD_US);
    s->last_seq = in->seq;
    foc_buttons(&s->fw, (uint16_t)(in->inputs & 0xFFFF));
    if (n != 0) {
        if (span_halves(s, n, in) < 0) return -1;
    } else {
        foc_active_duties(&s->fw, s->duty);
    }
    Py_CLEAR(s->last_drive);
    s->span_last = 1;
    s->span_seq = in->seq;
    report_values(s, out);
    return 0;
}

static PyObject *span_drive(PyObject *self, PyObject *seq)
{
    Core *s = (Core *)self;
    if (!s->span_last && s->last_drive != NULL) return Py_NewRef(s->last_drive);
    if (need_drive() < 0) return NULL;
    PyObject *drive = make_drive(s, seq, s->duty);
    if (drive != NULL) {
        Py_XSETREF(s->last_drive, Py_NewRef(drive));
        s->span_last = 0;
    }
    return drive;
}

static hb_target_api_t span_api = {span_step, span_drive, span_advance};

/* advance(span_us, sensors) -> Drive: real time's C step (span_advance) from Python, the accelerator of
 * FocTarget.advance that the emulator's real-time serve loop runs (tests/test_realtime_serve.py
 * holds the two equal). */
static PyObject *Core_advance(Core *s, PyObject *const *args, Py_ssize_t nargs)
{
    double span_us;
    if (hb_advance_args(args, nargs, "foc core", &span_us) < 0) return NULL;
    sensors_t given;
    if (need_drive() < 0 || unpack_sensors(args[1], &given) < 0) return NULL;
    hb_csensors_t in;
    memset(&in, 0, sizeof in);
    in.seq = PyLong_AsLongLong(given.seq);
    if (in.seq == -1 && PyErr_Occurred()) return NULL;
    in.inputs = given.inputs;
    in.encoder = (long)((unsigned long long)given.encoder & 0xFFFFULL);
    if (PyTuple_Check(given.adc)) {
        Py_ssize_t n = PyTuple_GET_SIZE(given.adc);
        in.n_adc = n < 3 ? (int)n : 3;
        for (int k = 0; k < in.n_adc; k++) {
            long long v = PyLong_AsLongLong(PyTuple_GET_ITEM(given.adc, k));
            if (v == -1 && PyErr_Occurred()) return NULL;
            in.adc[k] = (long)((unsigned long long)v & 0xFFFFULL);
        }
    }
    hb_cdrive_t out;
    if (span_advance((PyObject *)s, span_us, &in, &out) < 0) return NULL;
    return span_drive((PyObject *)s, given.seq);
}

/* last_drive: None or the Drive a repeated seq gets; only None may be written (forget it) */
static PyObject *get_last_drive(Core *s, void *c)
{
    (void)c;
    return hb_last_drive_get(s->last_drive);
}

static int set_last_drive(Core *s, PyObject *v, void *c)
{
    (void)c;
    return hb_last_drive_forget(&s->last_drive, &s->span_last, v, "foc");
}

static PyGetSetDef Core_getset[] = {
    {"last_drive", (getter)get_last_drive, (setter)set_last_drive, "the Drive a repeated seq gets (None: none)", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

static void Core_dealloc(Core *s)
{
    Py_CLEAR(s->last_drive);
    Py_TYPE(s)->tp_free((PyObject *)s);
}

static PyObject *Core_inputs(Core *s, PyObject *arg)
{
    long in = PyLong_AsLong(arg);
    if (in == -1 && PyErr_Occurred()) return NULL;
    foc_buttons(&s->fw, (uint16_t)(in & 0xFFFF));
    Py_RETURN_NONE;
}

static PyObject *Core_run_halves(Core *s, PyObject *const *args, Py_ssize_t nargs)
{
    sensors_t in;
    uint16_t duty[3];
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "run_halves(n, sensors)");
        return NULL;
    }
    long long n = PyLong_AsLongLong(args[0]);
    if (n == -1 && PyErr_Occurred()) return NULL;
    if (unpack_sensors(args[1], &in) < 0 || run_halves(s, n, &in, duty) < 0) return NULL;
    return Py_BuildValue("(HHH)", duty[0], duty[1], duty[2]);
}

static PyObject *Core_drive(Core *s, PyObject *const *args, Py_ssize_t nargs)
{
    uint16_t duty[3];
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "drive(seq, a, b, c)");
        return NULL;
    }
    if (need_drive() < 0) return NULL;
    for (int k = 0; k < 3; k++) {
        long v = PyLong_AsLong(args[k + 1]);
        if (v == -1 && PyErr_Occurred()) return NULL;
        if (v < 0 || v > FOC_T1PR) {
            PyErr_Format(PyExc_ValueError, "foc core drive: duty %ld out of 0..%d", v, FOC_T1PR);
            return NULL;
        }
        duty[k] = (uint16_t)v;
    }
    return make_drive(s, args[0], duty);
}

static PyObject *Core_active_duties(Core *s, PyObject *unused)
{
    (void)unused;
    uint16_t duty[3];
    foc_active_duties(&s->fw, duty);
    return Py_BuildValue("(HHH)", duty[0], duty[1], duty[2]);
}

static PyObject *Core_start(Core *s, PyObject *unused)
{
    (void)unused;
    foc_start(&s->fw);
    Py_RETURN_NONE;
}

static PyObject *Core_stop(Core *s, PyObject *const *args, Py_ssize_t nargs)
{
    long st = FOC_STATE_STOPPED, ft = FOC_FAULT_NONE;
    if (nargs > 2) {
        PyErr_SetString(PyExc_TypeError, "stop(state=0, fault=0)");
        return NULL;
    }
    if (nargs > 0 && (st = PyLong_AsLong(args[0])) == -1 && PyErr_Occurred()) return NULL;
    if (nargs > 1 && (ft = PyLong_AsLong(args[1])) == -1 && PyErr_Occurred()) return NULL;
    foc_stop(&s->fw, (uint16_t)(st & 7), (uint16_t)(ft & 63));
    Py_RETURN_NONE;
}

static PyObject *Core_set_speed_ref_rpm(Core *s, PyObject *arg)
{
    long rpm = PyLong_AsLong(arg);
    if (rpm == -1 && PyErr_Occurred()) return NULL;
    if (rpm < -1000000L || rpm > 1000000L) {
        PyErr_Format(PyExc_ValueError, "foc core set_speed_ref_rpm: %ld rpm out of +-1e6", rpm);
        return NULL;
    }
    foc_set_speed_ref_rpm(&s->fw, (int32_t)rpm);
    Py_RETURN_NONE;
}

/* Core(**config): foc_init with a foc_config_t whose fields are the keywords (all of them). */
static int Core_init(Core *s, PyObject *args, PyObject *kwds)
{
    static char *kw[] = {"pi_form", "speed_fr_unwrap", "learn_index", "qep_signed16", "line_encoder", "pole_pairs",
                         "t2pr", "calibrated_angle", "mech_scaler", "sp_k1", "sp_k2", "sp_k3", "base_rpm",
                         "speed_loop_prescaler", "align_isrs", "align_v", "align_i", "ramp_step", "cur_kp",
                         "cur_ki", "cur_kc", "id_out_max", "iq_out_max", "spd_kp", "spd_ki", "spd_kc",
                         "spd_out_max", NULL};
    int f[4];
    int v[23];
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "$ppppiiiiiiiiiiiiiiiiiiiiiii:Core", kw, &f[0], &f[1], &f[2], &f[3],
                                     &v[0], &v[1], &v[2], &v[3], &v[4], &v[5], &v[6], &v[7], &v[8], &v[9], &v[10],
                                     &v[11], &v[12], &v[13], &v[14], &v[15], &v[16], &v[17], &v[18], &v[19], &v[20],
                                     &v[21], &v[22])) {
        return -1;
    }
    if (v[0] <= 0 || v[1] <= 0 || v[2] < 0 || v[8] <= 0 || v[9] <= 0) {
        PyErr_SetString(PyExc_ValueError, "foc core: line_encoder, pole_pairs, base_rpm, speed_loop_prescaler > 0, t2pr >= 0");
        return -1;
    }
    foc_config_t c = {
        .pi_form = (uint16_t)f[0], .speed_fr_unwrap = (uint16_t)f[1], .learn_index = (uint16_t)f[2],
        .qep_signed16 = (uint16_t)f[3], .line_encoder = v[0], .pole_pairs = v[1], .t2pr = v[2],
        .calibrated_angle = v[3], .mech_scaler = v[4], .sp_k1 = v[5], .sp_k2 = v[6], .sp_k3 = v[7],
        .base_rpm = v[8], .speed_loop_prescaler = v[9], .align_isrs = v[10], .align_v = v[11], .align_i = v[12],
        .ramp_step = v[13], .cur_kp = v[14], .cur_ki = v[15], .cur_kc = v[16], .id_out_max = v[17],
        .iq_out_max = v[18], .spd_kp = v[19], .spd_ki = v[20], .spd_kc = v[21], .spd_out_max = v[22],
    };
    foc_init(&s->fw, &c);
    s->halves = 1;
    s->last_seq = 0;
    s->span_seq = 0;
    Py_CLEAR(s->last_drive);
    s->span_last = 0;
    return 0;
}

static PyObject *Core_new(PyTypeObject *type, PyObject *args, PyObject *kwds)
{
    (void)args;
    (void)kwds;
    Core *s = (Core *)type->tp_alloc(type, 0);
    if (s == NULL) return NULL;
    foc_config_t c;
    foc_config_default(&c);
    foc_init(&s->fw, &c);
    s->halves = 1;
    return (PyObject *)s;
}

#define FW(field) (offsetof(Core, fw) + offsetof(foc_t, field))
#define I32(name, field) {name, T_INT, FW(field), 0, NULL}
#define U16(name, field) {name, T_USHORT, FW(field), 0, NULL}
#define ARR(name, field, k) {name, T_INT, FW(field) + (k) * sizeof(int32_t), 0, NULL}
#define PI(nm, f) I32(nm "_kp", f.kp), I32(nm "_ki", f.ki), I32(nm "_kc", f.kc), I32(nm "_kd", f.kd), \
    I32(nm "_out_max", f.out_max), I32(nm "_out_min", f.out_min), I32(nm "_ui", f.ui), I32(nm "_up", f.up), \
    I32(nm "_ud", f.ud), I32(nm "_sat_err", f.sat_err), I32(nm "_up1", f.up1), I32(nm "_out", f.out), \
    I32(nm "_v1", f.v1), I32(nm "_i1", f.i1), I32(nm "_pre", f.pre)

static PyMemberDef Core_members[] = {
    PI("spd", pid_spd), PI("id", pid_id), PI("iq", pid_iq),
    U16("pi_form", pi_form), U16("learn_index", learn_index), I32("prescaler", speed_loop_prescaler),
    I32("align_isrs", align_isrs), I32("align_v", align_v), I32("align_i", align_i), I32("ramp_step", ramp_step),
    U16("state", state), U16("fault", fault), U16("_outputs_on", outputs_on),
    I32("speed_ref", speed_ref), I32("speed_setpoint", speed_setpoint), I32("id_ref", id_ref), I32("iq_ref", iq_ref),
    U16("_torque_mode", torque_mode), I32("iq_ref_set", iq_ref_set),
    {"isr_count", T_UINT, FW(isr_count), 0, NULL},
    I32("state_isrs", state_isrs), I32("speed_loop_count", speed_loop_count), U16("_index_learned", index_learned),
    I32("elec_theta", elec_theta), I32("i_a", i_a), I32("i_b", i_b), I32("i_alpha", i_alpha), I32("i_beta", i_beta),
    I32("i_d", i_d), I32("i_q", i_q), I32("v_d", v_d), I32("v_q", v_q), I32("v_alpha", v_alpha), I32("v_beta", v_beta),
    U16("vdc_code", vdc_code), U16("sector", sector), U16("s2_last", s2_last),
    ARR("cs1", compare_shadow, 0), ARR("cs2", compare_shadow, 1), ARR("cs3", compare_shadow, 2),
    ARR("ca1", compare_active, 0), ARR("ca2", compare_active, 1), ARR("ca3", compare_active, 2),
    U16("half", half), U16("enc_last", enc_last), U16("have_enc", have_enc),
    I32("qep_line_encoder", qep.line_encoder), I32("qep_pole_pairs", qep.pole_pairs),
    I32("qep_calibrated_angle", qep.calibrated_angle), I32("qep_mech_scaler", qep.mech_scaler),
    I32("qep_t2pr", qep.t2pr), I32("qep_t2cnt", qep.t2cnt), U16("qep_direction", qep.direction),
    U16("qep_raw_theta", qep.raw_theta), U16("qep_mech_theta", qep.mech_theta), U16("qep_elec_theta", qep.elec_theta),
    U16("qep_qep_count_index", qep.qep_count_index), U16("qep_index_sync_flag", qep.index_sync_flag),
    U16("qep_signed16", qep.signed16),
    I32("sp_speed", speed.speed), I32("sp_old_elec_theta", speed.old_elec_theta), I32("sp_speed_rpm", speed.speed_rpm),
    I32("sp_k1", speed.k1), I32("sp_k2", speed.k2), I32("sp_k3", speed.k3), I32("sp_base_rpm", speed.base_rpm),
    U16("sp_unwrap", speed.unwrap), I32("sp_elec_theta", speed.elec_theta),
    {"halves", T_LONGLONG, offsetof(Core, halves), 0, "half PWM periods per lockstep exchange"},
    {"last_seq", T_LONGLONG, offsetof(Core, last_seq), 0, "seq of the last Sensors"},
    {"frac_us", T_DOUBLE, offsetof(Core, frac_us), 0, "real time: the part of a half period the last advance left over"},
    {NULL, 0, 0, 0, NULL},
};

static PyMethodDef Core_methods[] = {
    {"step", (PyCFunction)Core_step, METH_O, "step(sensors) -> Drive: FocTarget.step for `halves` half periods."},
    {"inputs", (PyCFunction)Core_inputs, METH_O, "inputs(bits): S2 as the firmware's main loop sees it."},
    {"run_halves", (PyCFunction)(void (*)(void))Core_run_halves, METH_FASTCALL,
     "run_halves(n, sensors) -> (a, b, c): the encoder, then n halves; their mean on-times."},
    {"drive", (PyCFunction)(void (*)(void))Core_drive, METH_FASTCALL, "drive(seq, a, b, c) -> Drive."},
    {"active_duties", (PyCFunction)Core_active_duties, METH_NOARGS, "the on-times of the active compare values"},
    {"advance", (PyCFunction)(void (*)(void))Core_advance, METH_FASTCALL,
     "advance(span_us, sensors) -> Drive: real time's step in C (FocTarget.advance's accelerator)."},
    {"start", (PyCFunction)Core_start, METH_NOARGS, "foc_start."},
    {"stop", (PyCFunction)(void (*)(void))Core_stop, METH_FASTCALL, "stop(state=0, fault=0): foc_stop."},
    {"set_speed_ref_rpm", (PyCFunction)Core_set_speed_ref_rpm, METH_O, "foc_set_speed_ref_rpm: _IQ(rpm/BaseRpm)."},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject CoreType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "hilbench.targets.foc._core.Core",
    .tp_basicsize = sizeof(Core),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_BASETYPE,
    .tp_doc = "The FOC firmware (firmware/foc) in process: Core(**foc_config_t fields).",
    .tp_new = Core_new,
    .tp_dealloc = (destructor)Core_dealloc,
    .tp_getset = Core_getset,
    .tp_init = (initproc)Core_init,
    .tp_members = Core_members,
    .tp_methods = Core_methods,
};

static PyObject *mod_init(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "init(Drive, INPUT_INDEX)");
        return NULL;
    }
    long index;
    if (hb_long(args[1], &index) < 0 || hb_set_tuple_type(args[0], &drive_type, "foc core init") < 0) return NULL;
    input_index = index;
    Py_RETURN_NONE;
}

static PyObject *mod_sin_q15(PyObject *self, PyObject *arg)
{
    (void)self;
    long a = PyLong_AsLong(arg);
    if (a == -1 && PyErr_Occurred()) return NULL;
    return PyLong_FromLong((long)foc_sin_q15((uint16_t)(a & 0x7FFF)));
}

static PyMethodDef module_methods[] = {
    {"init", (PyCFunction)(void (*)(void))mod_init, METH_FASTCALL,
     "init(Drive, INPUT_INDEX): the NamedTuple the core builds and the index bit of Sensors.inputs."},
    {"sin_q15", (PyCFunction)mod_sin_q15, METH_O, "foc_sin_q15(angle): the firmware's _IQsinPU of a Q15 angle."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moduledef = {
    PyModuleDef_HEAD_INIT, "_core", "The F2812 FOC firmware (firmware/foc) in process (optional).", -1,
    module_methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__core(void)
{
    for (int i = 0; i <= FOC_T1PR; i++) {
        if ((duty_ints[i] = PyLong_FromLong(i)) == NULL) return NULL;
    }
    PyObject *m = hb_module(&moduledef, &CoreType, "Core");
    return hb_add_span_api(m, &span_api, HB_TARGET_API);
}
