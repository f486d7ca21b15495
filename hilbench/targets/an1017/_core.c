/* The in-process AN1017 core (the "c" backend of hilbench.targets.an1017.An1017Target): the board
 * firmware firmware/an1017/an1017.c on the runtime firmware/runtime/hrt.c, compiled into this
 * extension, behind a thin CPython glue.
 *
 * The firmware logic is an1017.c's and its scheduling the runtime's, nothing else: the same sources
 * run on the board (dsPIC, AVR), in the SIL process (sil:an1017) and here. This file owns one
 * an1017_t (its hrt_t inside) plus what the Python target needs around it: absolute time in Tcy (the
 * runtime's clock is 32 bits), the agreed lockstep period, the last seq and its Drive (a repeated seq
 * is answered without a step), and the Drive type. step(sensors) is one runtime span (hrt_span_*)
 * + hrt_report as a Drive; the members carry the Python model's attribute names
 * (hilbench/targets/an1017/firmware.py), so tests and the target read the firmware state the same
 * way on both backends.
 * tests/test_an1017_core.py compares every Drive with the Python reference.
 */
#include "hbglue.h"
#include <stdint.h>
#include <math.h>

#include "an1017.h"

#define SPAN_MAX_TCY 0x40000000LL /* the runtime counts a span in 32 bits: longer ones are cut */

static PyTypeObject *drive_type = NULL;
static PyObject *duty_ints[AN1017_DUTY_MAX + 1];

typedef struct {
    PyObject_HEAD
    an1017_t fw;
    long long t;          /* Tcy since power-on */
    long long period_tcy; /* the lockstep period */
    long long last_seq;
    int16_t tel_vals[3];  /* the values in tel */
    PyObject *tel;        /* the last telemetry tuple, reused while its values do not change */
    PyObject *last_drive; /* the answer to a repeated seq (a duplicated frame): no second step */
    char span_last;       /* the last step was the C span's: last_seq has a Drive, not yet built */
    double frac_tcy;      /* real time: the Tcy fraction the last advance left over (An1017Target._frac_tcy) */
} Core;

#define MAX_SPAN_EDGES 64 /* edges of one span in process (a wire Sensors carries at most 16) */

typedef struct {
    long long offset; /* Tcy from the span's start */
    uint8_t lines;
} span_edge_t;

/* The edges an argument names: None (none), an offset in Tcy (the halls of `inputs` change then: the
 * older one-edge form), or a sequence of (time, lines) pairs, time x scale Tcy (Sensors.edges: 2 Tcy
 * per 100 ns). Returns the count, -1 with an exception. */
static int edges_of(PyObject *obj, long inputs, long long scale, span_edge_t *out)
{
    if (obj == Py_None) {
        return 0;
    }
    if (PyLong_Check(obj)) {
        long long off = PyLong_AsLongLong(obj);
        if (off == -1 && PyErr_Occurred()) return -1;
        out[0].offset = off;
        out[0].lines = (uint8_t)(inputs & HRT_IN_HALLS);
        return 1;
    }
    PyObject *seq = PySequence_Fast(obj, "an1017 core: edges must be a sequence of (time, lines) pairs");
    if (seq == NULL) return -1;
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    if (n > MAX_SPAN_EDGES) {
        Py_DECREF(seq);
        PyErr_Format(PyExc_ValueError, "an1017 core: %zd edges in one span (at most %d)", n, MAX_SPAN_EDGES);
        return -1;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *pair = PySequence_Fast_GET_ITEM(seq, i);
        if (!PyTuple_Check(pair) || PyTuple_GET_SIZE(pair) != 2) {
            Py_DECREF(seq);
            PyErr_SetString(PyExc_TypeError, "an1017 core: an edge is a (time, lines) pair");
            return -1;
        }
        long long t = PyLong_AsLongLong(PyTuple_GET_ITEM(pair, 0));
        long lines = PyLong_AsLong(PyTuple_GET_ITEM(pair, 1));
        if (PyErr_Occurred()) {
            Py_DECREF(seq);
            return -1;
        }
        out[i].offset = t * scale;
        out[i].lines = (uint8_t)(lines & 0xFF);
    }
    Py_DECREF(seq);
    return (int)n;
}

/* One span of the runtime (at most SPAN_MAX_TCY): the Sensors' levels at its start, each edge at its
 * time (one beyond the span at its last Tcy), as the runtime's link serves a wire Sensors. */
static void one_span(an1017_t *fw, uint32_t duration, uint8_t in, const span_edge_t *edges, int n, int have_pot,
                     uint16_t pot)
{
    hrt_t *rt = &fw->rt;
    uint32_t start = rt->now;
    uint8_t has_index = 0u;
    int i;
    for (i = 0; i < n; i++) {
        has_index = (uint8_t)(has_index | (edges[i].lines & HRT_IN_INDEX));
    }
    hrt_span_begin(rt, in, (uint8_t)n, has_index, &pot, (uint8_t)(have_pot != 0), 0u);
    for (i = 0; i < n; i++) {
        long long off = edges[i].offset;
        uint32_t at = (off <= 0) ? 0u : (off >= (long long)duration) ? duration - 1u : (uint32_t)off;
        hrt_span_edge(rt, start + at, edges[i].lines);
    }
    hrt_span_end(rt, start + duration);
}

/* A span of any length from now: one runtime span per at most SPAN_MAX_TCY, each edge in the one it
 * falls in. The Sensors' FLTA bit acts at the span's start only (as in one span); S2 and the halls are
 * idempotent when repeated. */
static void run_span(Core *s, long long duration, long inputs, span_edge_t *edges, int n, int have_pot, long pot)
{
    uint8_t in = (uint8_t)(inputs & 0xFF);
    if (duration <= 0) {
        return;
    }
    s->t += duration;
    while (duration > SPAN_MAX_TCY) {
        int k = 0;
        while (k < n && edges[k].offset < SPAN_MAX_TCY) {
            k++;
        }
        one_span(&s->fw, (uint32_t)SPAN_MAX_TCY, in, edges, k, have_pot, (uint16_t)pot);
        for (int i = k; i < n; i++) {
            edges[i].offset -= SPAN_MAX_TCY;
        }
        edges += k;
        n -= k;
        duration -= SPAN_MAX_TCY;
        in = (uint8_t)(in & ~AN1017_INPUT_FAULT);
    }
    one_span(&s->fw, (uint32_t)duration, in, edges, n, have_pot, (uint16_t)pot);
}

static PyObject *finish(Core *s, PyObject *seq)
{
    hrt_report_t o;
    hrt_report(&s->fw.rt, 0u, &o);
    PyObject *tel = s->tel;
    if (tel == NULL || s->tel_vals[0] != o.telemetry[0] || s->tel_vals[1] != o.telemetry[1]
        || s->tel_vals[2] != o.telemetry[2]) {
        PyObject *n = Py_BuildValue("(hhh)", o.telemetry[0], o.telemetry[1], o.telemetry[2]);
        if (n == NULL) return NULL;
        Py_XSETREF(s->tel, n);
        s->tel_vals[0] = o.telemetry[0];
        s->tel_vals[1] = o.telemetry[1];
        s->tel_vals[2] = o.telemetry[2];
        tel = n;
    }
    return hb_drive(drive_type, Py_NewRef(seq), Py_NewRef(duty_ints[o.duty_a]), Py_NewRef(duty_ints[o.duty_b]),
                    Py_NewRef(duty_ints[o.duty_c]), Py_NewRef(duty_ints[o.output_mode]), Py_NewRef(duty_ints[o.state]),
                    Py_NewRef(duty_ints[o.sector]), PyBool_FromLong(o.direction_ccw), PyBool_FromLong(o.required_ccw),
                    Py_NewRef(duty_ints[o.fault]), Py_NewRef(tel));
}

/* ---------------------------------------------------------------- Python methods */
static int need_drive(void)
{
    if (drive_type == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "an1017 core: init(Drive) was not called");
        return -1;
    }
    return 0;
}

static int pot_of(PyObject *adc, long *pot, int *have)
{
    *have = 0;
    if (PyTuple_Check(adc)) {
        if (PyTuple_GET_SIZE(adc) == 0) return 0;
        long v = PyLong_AsLong(PyTuple_GET_ITEM(adc, 0));
        if (v == -1 && PyErr_Occurred()) return -1;
        *pot = v;
        *have = 1;
        return 0;
    }
    int truth = PyObject_IsTrue(adc);
    if (truth <= 0) return truth;
    PyObject *x = PySequence_GetItem(adc, 0);
    if (x == NULL) return -1;
    long v = PyLong_AsLong(x);
    Py_DECREF(x);
    if (v == -1 && PyErr_Occurred()) return -1;
    *pot = v;
    *have = 1;
    return 0;
}

static PyObject *Core_step(Core *s, PyObject *sensors)
{
    hb_sensors_t in;
    if (need_drive() < 0 || hb_sensors(sensors, &in, "an1017 core step") < 0) return NULL;
    if (s->last_drive != NULL) { /* a repeat of the last Drive's own seq (as the Python model): no step */
        PyObject *last_seq = PyTuple_GET_ITEM(s->last_drive, 0);
        if (last_seq == in.seq || PyLong_AsLongLong(last_seq) == in.seq_value) return Py_NewRef(s->last_drive);
        if (PyErr_Occurred()) return NULL;
    } else if (s->span_last && s->last_seq == in.seq_value) { /* the C span's last step, repeated */
        PyObject *drive = finish(s, in.seq);
        if (drive != NULL) {
            Py_XSETREF(s->last_drive, Py_NewRef(drive));
            s->span_last = 0;
        }
        return drive;
    }
    span_edge_t edges[MAX_SPAN_EDGES];
    PyObject *given = in.edges; /* Sensors.edges: (time in 100 ns, lines) pairs */
    int n = (PyTuple_Check(given) && PyTuple_GET_SIZE(given) == 0) ? 0 : edges_of(given, in.inputs, 2, edges);
    if (n < 0) return NULL;
    long pot = 0;
    int have_pot = 0;
    if (pot_of(in.adc, &pot, &have_pot) < 0) return NULL;
    run_span(s, s->period_tcy, in.inputs, edges, n, have_pot, pot);
    s->last_seq = in.seq_value;
    PyObject *drive = finish(s, in.seq);
    if (drive != NULL) {
        Py_XSETREF(s->last_drive, Py_NewRef(drive));
        s->span_last = 0;
    }
    return drive;
}

/* ---------------------------------------------------------------- the C span's step (hbglue.h) */
/* A Sensors' edges on C values as Core_step reads Sensors.edges (2 Tcy per 100 ns); their count. */
static int wire_edges(const hb_csensors_t *in, span_edge_t *edges)
{
    int n = in->n_edges < HB_SPAN_MAX_EDGES ? in->n_edges : HB_SPAN_MAX_EDGES;
    for (int i = 0; i < n; i++) {
        edges[i].offset = (long long)in->edge_t[i] * 2;
        edges[i].lines = (uint8_t)(in->edge_lines[i] & 0xFF);
    }
    return n;
}

/* The Drive's values of the firmware's state now (what finish() builds the Drive from). */
static void report_values(Core *s, hb_cdrive_t *out)
{
    hrt_report_t o;
    hrt_report(&s->fw.rt, 0u, &o);
    out->duty_a = o.duty_a; out->duty_b = o.duty_b; out->duty_c = o.duty_c;
    out->output_mode = o.output_mode; out->state = o.state; out->sector = o.sector;
    out->direction_ccw = o.direction_ccw != 0; out->required_ccw = o.required_ccw != 0; out->fault = o.fault;
    out->n_tel = 3;
    out->tel[0] = o.telemetry[0]; out->tel[1] = o.telemetry[1]; out->tel[2] = o.telemetry[2];
}

/* Core_step on C values: the same span, the same repeat rule; the Drive object is built only
 * when the span ends (span_drive). */
static int span_step(PyObject *self, const hb_csensors_t *in, hb_cdrive_t *out)
{
    Core *s = (Core *)self;
    int repeat = s->span_last && s->last_seq == in->seq;
    if (s->last_drive != NULL) { /* as Core_step: the kept Drive's own seq */
        long long last = PyLong_AsLongLong(PyTuple_GET_ITEM(s->last_drive, 0));
        if (last == -1 && PyErr_Occurred()) return -1;
        repeat = last == in->seq;
    }
    if (!repeat) {
        span_edge_t edges[HB_SPAN_MAX_EDGES];
        int n = wire_edges(in, edges);
        run_span(s, s->period_tcy, in->inputs, edges, n, in->n_adc > 0, in->n_adc > 0 ? in->adc[0] : 0);
        s->last_seq = in->seq;
        Py_CLEAR(s->last_drive);
        s->span_last = 1;
    }
    report_values(s, out);
    return 0;
}

static PyObject *span_drive(PyObject *self, PyObject *seq)
{
    Core *s = (Core *)self;
    if (!s->span_last && s->last_drive != NULL) return Py_NewRef(s->last_drive);
    if (need_drive() < 0) return NULL;
    PyObject *drive = finish(s, seq);
    if (drive != NULL) {
        Py_XSETREF(s->last_drive, Py_NewRef(drive));
        s->span_last = 0;
    }
    return drive;
}

/* An1017Target.advance on C values (real time): span_us of wall time as whole Tcy, the fraction carried
 * in frac_tcy (the same double arithmetic as the Python method's), the firmware run for them with the
 * Sensors' levels, edges and pot; the Drive's values as span_step gives them (built by span_drive). */
static int span_advance(PyObject *self, double span_us, const hb_csensors_t *in, hb_cdrive_t *out)
{
    Core *s = (Core *)self;
    double total = span_us * (double)AN1017_TCY_PER_US + s->frac_tcy;
    long long tcy = (long long)total; /* int(): toward zero */
    s->frac_tcy = total - (double)tcy;
    if (tcy > 0) {
        span_edge_t edges[HB_SPAN_MAX_EDGES];
        int n = wire_edges(in, edges);
        run_span(s, tcy, in->inputs, edges, n, in->n_adc > 0, in->n_adc > 0 ? in->adc[0] : 0);
    }
    s->last_seq = in->seq;
    Py_CLEAR(s->last_drive);
    s->span_last = 1;
    report_values(s, out);
    return 0;
}

static hb_target_api_t span_api = {span_step, span_drive, span_advance};

static PyObject *Core_run(Core *s, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "an1017 core run(duration_tcy, inputs, edges, pot_code)");
        return NULL;
    }
    long long duration = PyLong_AsLongLong(args[0]);
    if (duration == -1 && PyErr_Occurred()) return NULL;
    if (duration < 0) {
        PyErr_Format(PyExc_ValueError, "an1017 core run: duration_tcy %lld is negative", duration);
        return NULL;
    }
    long inputs = PyLong_AsLong(args[1]);
    if (inputs == -1 && PyErr_Occurred()) return NULL;
    span_edge_t edges[MAX_SPAN_EDGES];
    int n = edges_of(args[2], inputs, 1, edges); /* None, an offset in Tcy, or (offset in Tcy, lines) pairs */
    if (n < 0) return NULL;
    long pot = 0;
    int have_pot = args[3] != Py_None;
    if (have_pot) {
        pot = PyLong_AsLong(args[3]);
        if (pot == -1 && PyErr_Occurred()) return NULL;
    }
    run_span(s, duration, inputs, edges, n, have_pot, pot);
    Py_RETURN_NONE;
}

/* advance(span_us, sensors) -> Drive: real time's C step (span_advance) from Python, the accelerator of
 * An1017Target.advance that the emulator's real-time serve loop runs (tests/test_realtime_serve.py
 * holds the two equal). */
static PyObject *Core_advance(Core *s, PyObject *const *args, Py_ssize_t nargs)
{
    double span_us;
    if (hb_advance_args(args, nargs, "an1017 core", &span_us) < 0) return NULL;
    hb_sensors_t given;
    if (need_drive() < 0 || hb_sensors(args[1], &given, "an1017 core advance") < 0) return NULL;
    hb_csensors_t in;
    memset(&in, 0, sizeof in);
    in.seq = given.seq_value;
    in.inputs = given.inputs;
    span_edge_t edges[MAX_SPAN_EDGES];
    int n = (PyTuple_Check(given.edges) && PyTuple_GET_SIZE(given.edges) == 0) ? 0 : edges_of(given.edges, in.inputs, 1, edges);
    if (n < 0) return NULL;
    if (n > HB_SPAN_MAX_EDGES) {
        PyErr_Format(PyExc_ValueError, "an1017 core advance: %d edges (a Sensors carries at most %d)", n, HB_SPAN_MAX_EDGES);
        return NULL;
    }
    in.n_edges = n;
    for (int i = 0; i < n; i++) {
        in.edge_t[i] = (long)edges[i].offset;
        in.edge_lines[i] = edges[i].lines;
    }
    long pot = 0;
    int have_pot = 0;
    if (pot_of(given.adc, &pot, &have_pot) < 0) return NULL;
    in.n_adc = have_pot;
    in.adc[0] = pot;
    hb_cdrive_t out;
    span_advance((PyObject *)s, span_us, &in, &out);
    return finish(s, given.seq);
}

static PyObject *Core_finish(Core *s, PyObject *seq)
{
    if (need_drive() < 0) return NULL;
    return finish(s, seq);
}

static PyObject *Core_press_start(Core *s, PyObject *unused)
{
    (void)unused;
    an1017_press_start(&s->fw);
    Py_RETURN_NONE;
}

static PyObject *Core_press_stop(Core *s, PyObject *args)
{
    int state = AN1017_STATE_STOPPED, fault = AN1017_FAULT_NONE;
    if (!PyArg_ParseTuple(args, "|ii:press_stop", &state, &fault)) return NULL;
    an1017_press_stop(&s->fw, (uint8_t)state, (uint8_t)fault);
    Py_RETURN_NONE;
}

static PyObject *Core_param_value(Core *s, PyObject *id)
{
    long v = PyLong_AsLong(id);
    if (v == -1 && PyErr_Occurred()) return NULL;
    if (v < 0 || v >= (long)AN1017_N_PARAMS) {
        PyErr_Format(PyExc_ValueError, "an1017 core param_value: unknown id %ld", v);
        return NULL;
    }
    return PyLong_FromLong(an1017_param_value(&s->fw, (uint8_t)v));
}

static PyObject *Core_apply_params(Core *s, PyObject *args)
{
    PyObject *values;
    int gains_touched;
    if (!PyArg_ParseTuple(args, "Op:apply_params", &values, &gains_touched)) return NULL;
    PyObject *seq = PySequence_Fast(values, "an1017 core apply_params: values must be a sequence");
    if (seq == NULL) return NULL;
    if (PySequence_Fast_GET_SIZE(seq) != (Py_ssize_t)AN1017_N_PARAMS) {
        Py_DECREF(seq);
        PyErr_SetString(PyExc_ValueError, "an1017 core apply_params: one value per declared parameter");
        return NULL;
    }
    int32_t v[AN1017_N_PARAMS];
    for (Py_ssize_t i = 0; i < (Py_ssize_t)AN1017_N_PARAMS; i++) {
        long x = PyLong_AsLong(PySequence_Fast_GET_ITEM(seq, i));
        if (x == -1 && PyErr_Occurred()) { Py_DECREF(seq); return NULL; }
        if (x < -32768 || x > 32767) {
            Py_DECREF(seq);
            PyErr_Format(PyExc_ValueError, "an1017 core apply_params: value %ld does not fit 16 bits", x);
            return NULL;
        }
        v[i] = (int32_t)x;
    }
    Py_DECREF(seq);
    /* a checked, complete set of declared values: the gains as one set when written, the others as
     * they are (the same state as the firmware's own writes, id by id) */
    if (gains_touched) {
        an1017_set_gains(&s->fw, (int16_t)v[AN1017_PARAM_KP], (int16_t)v[AN1017_PARAM_KI], (int16_t)v[AN1017_PARAM_KD]);
    }
    for (uint8_t id = AN1017_PARAM_PH_ADV_ON; id < AN1017_N_PARAMS; id++) {
        an1017_param_set(&s->fw, id, v[id]);
    }
    Py_RETURN_NONE;
}

static PyObject *mod_check_gains(PyObject *self, PyObject *args)
{
    (void)self;
    long kp, ki, kd;
    if (!PyArg_ParseTuple(args, "lll:check_gains", &kp, &ki, &kd)) return NULL;
    uint8_t broken = an1017_check_gains((int32_t)kp, (int32_t)ki, (int32_t)kd);
    if (broken == 0u) Py_RETURN_NONE;
    return PyLong_FromLong(broken);
}

static PyObject *Core_duties(Core *s, PyObject *unused)
{
    (void)unused;
    const hrt_t *rt = &s->fw.rt;
    return Py_BuildValue("(HHH)", hrt_duty_active(rt, 0), hrt_duty_active(rt, 1), hrt_duty_active(rt, 2));
}

static PyObject *Core_pending_duties(Core *s, PyObject *unused)
{
    (void)unused;
    const hrt_t *rt = &s->fw.rt;
    return Py_BuildValue("(HHH)", hrt_duty(rt, 0), hrt_duty(rt, 1), hrt_duty(rt, 2));
}

static int Core_init(Core *s, PyObject *args, PyObject *kwds)
{
    static char *kw[] = {"variant_v11", "adc_every", "c1_textbook", "phase_advance", "stall_limit", "phase_offset",
                         "max_ph_adv_deg", "min_period", "max_period", NULL};
    int v11, adc_every, c1_textbook, phase_advance, stall_limit, phase_offset, deg, min_period, max_period;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "ppppiiiii:Core", kw, &v11, &adc_every, &c1_textbook,
                                     &phase_advance, &stall_limit, &phase_offset, &deg, &min_period, &max_period)) {
        return -1;
    }
    if (!(2 <= min_period && min_period < max_period && max_period <= 32767) || stall_limit < 1
        || stall_limit > 65535 || deg < 0 || deg > 60 || phase_offset < -32768 || phase_offset > 32767) {
        PyErr_SetString(PyExc_ValueError, "an1017 core: option out of range");
        return -1;
    }
    an1017_t *f = &s->fw;
    an1017_init(f, v11 ? AN1017_VARIANT_V11 : AN1017_VARIANT_SEED);
    f->adc_every = (uint8_t)adc_every;
    f->c1_textbook = (uint8_t)c1_textbook;
    f->phase_advance_on = (uint8_t)phase_advance;
    f->stall_limit = (uint16_t)stall_limit;
    f->phase_offset = (int16_t)phase_offset;
    f->max_ph_adv_deg = (int16_t)deg;
    f->max_ph_adv = an1017_max_ph_adv((int16_t)deg);
    an1017_set_periods(f, (uint16_t)min_period, (uint16_t)max_period);
    s->t = 0;
    s->last_seq = 0;
    Py_CLEAR(s->tel);
    Py_CLEAR(s->last_drive);
    s->span_last = 0;
    return 0;
}

static PyObject *Core_new(PyTypeObject *type, PyObject *args, PyObject *kwds)
{
    (void)args; (void)kwds;
    Core *s = (Core *)type->tp_alloc(type, 0);
    if (s == NULL) return NULL;
    an1017_init(&s->fw, AN1017_VARIANT_SEED);
    s->period_tcy = AN1017_PWM_PERIOD_TCY;
    return (PyObject *)s;
}

static int Core_traverse(Core *s, visitproc visit, void *arg)
{
    Py_VISIT(s->tel);
    Py_VISIT(s->last_drive);
    return 0;
}

static int Core_clear(Core *s)
{
    Py_CLEAR(s->tel);
    Py_CLEAR(s->last_drive);
    return 0;
}

static void Core_dealloc(Core *s)
{
    PyObject_GC_UnTrack(s);
    Core_clear(s);
    Py_TYPE(s)->tp_free((PyObject *)s);
}

/* pending_gains: None or (kp, ki, kd), as An1017Firmware.pending_gains */
static PyObject *get_pending(Core *s, void *c)
{
    (void)c;
    if (!s->fw.has_pending) Py_RETURN_NONE;
    return Py_BuildValue("(hhh)", s->fw.pend_kp, s->fw.pend_ki, s->fw.pend_kd);
}

/* the runtime's clock is 32 bits: its timers as absolute times here (meaningful while they run) */
static PyObject *get_t1_next(Core *s, void *c)
{
    (void)c;
    const hrt_t *rt = &s->fw.rt;
    return PyLong_FromLongLong(s->t + (long long)(uint32_t)(rt->timer_due[AN1017_TIMER_T1] - rt->now));
}

static PyObject *get_boot_end(Core *s, void *c)
{
    (void)c;
    const hrt_t *rt = &s->fw.rt;
    return PyLong_FromLongLong(s->t + (long long)(uint32_t)(rt->timer_due[AN1017_TIMER_BOOT] - rt->now));
}

/* the hall pins and the pot's ADC code are the runtime's inputs */
static PyObject *get_hall(Core *s, void *c)
{
    (void)c;
    return PyLong_FromLong(AN1017_HALL(&s->fw));
}

static int set_hall(Core *s, PyObject *v, void *c)
{
    (void)c;
    long x = v == NULL ? -1 : PyLong_AsLong(v);
    if (x < 0 || x > 7) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "an1017 core hall: 0..7");
        return -1;
    }
    s->fw.rt.in = (uint8_t)((s->fw.rt.in & (uint8_t)~HRT_IN_HALLS) | (uint8_t)x);
    return 0;
}

static PyObject *get_pot_code(Core *s, void *c)
{
    (void)c;
    return PyLong_FromLong(hrt_adc(&s->fw.rt, 0u));
}

static int set_pot_code(Core *s, PyObject *v, void *c)
{
    (void)c;
    long x = v == NULL ? -1 : PyLong_AsLong(v);
    if (x < 0 || x > 0xFFFF) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "an1017 core pot_code: 0..65535");
        return -1;
    }
    s->fw.rt.adc[0] = (uint16_t)x;
    return 0;
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
    return hb_last_drive_forget(&s->last_drive, &s->span_last, v, "an1017");
}

static PyGetSetDef Core_getset[] = {
    {"last_drive", (getter)get_last_drive, (setter)set_last_drive, "the Drive a repeated seq gets (None: none)", NULL},
    {"pending_gains", (getter)get_pending, NULL, "gains waiting for the next Timer1 ISR (None: none)", NULL},
    {"t1_next", (getter)get_t1_next, NULL, "Tcy of the next Timer1 interrupt (while running)", NULL},
    {"boot_end", (getter)get_boot_end, NULL, "Tcy at which ChargeBootstraps ends (while booting)", NULL},
    {"hall", (getter)get_hall, (setter)set_hall, "the hall pins C B A", NULL},
    {"pot_code", (getter)get_pot_code, (setter)set_pot_code, "AN2, the pot's 10-bit code", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

#define FW(field) (offsetof(Core, fw) + offsetof(an1017_t, field))
#define BM(name, field) {name, T_BOOL, FW(field), 0, NULL}
#define UB(name, field) {name, T_UBYTE, FW(field), 0, NULL}
#define SH(name, field) {name, T_SHORT, FW(field), 0, NULL}
#define US(name, field) {name, T_USHORT, FW(field), 0, NULL}
#define RO(name, field) {name, T_USHORT, FW(field), READONLY, NULL} /* divisors: set by the constructor only */

static PyMemberDef Core_members[] = {
    BM("_adc_every", adc_every), BM("_c1_textbook", c1_textbook), SH("phase_offset", phase_offset),
    RO("min_period", min_period), RO("max_period", max_period),
    SH("kp", kp), SH("ki", ki), SH("kd", kd),
    BM("phase_advance_on", phase_advance_on), SH("max_ph_adv_deg", max_ph_adv_deg), SH("max_ph_adv", max_ph_adv),
    BM("ref_override_on", ref_override_on), SH("ref_override", ref_override), US("stall_limit", stall_limit),
    BM("running", running), BM("booting", booting), UB("state", state), UB("fault", fault),
    UB("output_mode", output_mode), BM("cur_ccw", cur_ccw), BM("req_ccw", req_ccw),
    BM("s2_wait_release", s2_wait_release),
    SH("ref_speed", ref_speed), SH("measured_speed", measured_speed), SH("control_output", control_output),
    SH("e1", e1), SH("e2", e2), SH("c0", c0), SH("c1", c1), SH("c2", c2),
    US("phase", phase), US("phase_inc", phase_inc), SH("phase_adv", phase_adv),
    US("sector", sector), US("last_sector", last_sector), US("stall_counter", stall_counter), US("period", period),
    US("actual_capture", actual_capture), US("past_capture", past_capture),
    {"t", T_LONGLONG, offsetof(Core, t), READONLY, "Tcy since power-on"},
    {"period_tcy", T_LONGLONG, offsetof(Core, period_tcy), 0, "the lockstep period in Tcy"},
    {"last_seq", T_LONGLONG, offsetof(Core, last_seq), 0, "seq of the last Sensors"},
    {"frac_tcy", T_DOUBLE, offsetof(Core, frac_tcy), 0, "real time: the Tcy fraction the last advance left over"},
    {NULL, 0, 0, 0, NULL},
};

static PyMethodDef Core_methods[] = {
    {"step", (PyCFunction)Core_step, METH_O, "step(sensors) -> Drive: one lockstep period of period_tcy."},
    {"advance", (PyCFunction)(void (*)(void))Core_advance, METH_FASTCALL,
     "advance(span_us, sensors) -> Drive: real time's step in C (An1017Target.advance's accelerator)."},
    {"run", (PyCFunction)(void (*)(void))Core_run, METH_FASTCALL,
     "run(duration_tcy, inputs, edges | edge_offset_tcy | None, pot_code | None): An1017Firmware.run."},
    {"finish", (PyCFunction)Core_finish, METH_O, "finish(seq) -> Drive for the current state."},
    {"press_start", (PyCFunction)Core_press_start, METH_NOARGS, "S2 while stopped: ChargeBootstraps, then RunMotor."},
    {"press_stop", (PyCFunction)Core_press_stop, METH_VARARGS, "press_stop(state=STOPPED, fault=NONE): StopMotor()."},
    {"param_value", (PyCFunction)Core_param_value, METH_O, "param_value(id): the declared value (pending gains included)."},
    {"apply_params", (PyCFunction)Core_apply_params, METH_VARARGS,
     "apply_params(values, gains_touched): a checked set of the 8 declared values."},
    {"duties", (PyCFunction)Core_duties, METH_NOARGS, "The duty registers in effect now."},
    {"pending_duties", (PyCFunction)Core_pending_duties, METH_NOARGS, "The duty registers the PWM ISR wrote last."},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject CoreType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "hilbench.targets.an1017._core.Core",
    .tp_basicsize = sizeof(Core),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC,
    .tp_doc = "Core(variant_v11, adc_every, c1_textbook, phase_advance, stall_limit, phase_offset, max_ph_adv_deg, "
              "min_period, max_period): firmware/an1017/an1017.c in this process.",
    .tp_new = Core_new,
    .tp_init = (initproc)Core_init,
    .tp_dealloc = (destructor)Core_dealloc,
    .tp_traverse = (traverseproc)Core_traverse,
    .tp_clear = (inquiry)Core_clear,
    .tp_members = Core_members,
    .tp_getset = Core_getset,
    .tp_methods = Core_methods,
};

static PyObject *mod_init(PyObject *self, PyObject *drive)
{
    (void)self;
    if (hb_set_tuple_type(drive, &drive_type, "an1017 core init") < 0) return NULL;
    Py_RETURN_NONE;
}

static PyObject *mod_svm(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 2) { PyErr_SetString(PyExc_TypeError, "svm(volts, angle_u16)"); return NULL; }
    long v = PyLong_AsLong(args[0]), a = PyLong_AsLong(args[1]);
    if (PyErr_Occurred()) return NULL;
    if (v < -1 || v > 32767) {
        PyErr_SetString(PyExc_ValueError, "svm: volts must be in -1..32767");
        return NULL;
    }
    uint16_t d[3];
    an1017_svm((int16_t)v, (uint16_t)(a & 0xFFFF), d);
    return Py_BuildValue("(HHH)", d[0], d[1], d[2]);
}

static PyMethodDef module_methods[] = {
    {"init", (PyCFunction)mod_init, METH_O, "init(Drive): the NamedTuple type the core builds."},
    {"svm", (PyCFunction)(void (*)(void))mod_svm, METH_FASTCALL, "svm(volts, angle_u16): an1017_svm."},
    {"check_gains", (PyCFunction)mod_check_gains, METH_VARARGS,
     "check_gains(kp, ki, kd): None when the note's constraints hold, else the first broken one (1, 2, 3)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moduledef = {
    PyModuleDef_HEAD_INIT, "_core", "firmware/an1017/an1017.c in this process (optional).", -1, module_methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__core(void)
{
    for (int i = 0; i <= (int)AN1017_DUTY_MAX; i++) {
        duty_ints[i] = PyLong_FromLong(i);
        if (duty_ints[i] == NULL) return NULL;
    }
    PyObject *m = hb_module(&moduledef, &CoreType, "Core");
    return hb_add_span_api(m, &span_api, HB_TARGET_API);
}
