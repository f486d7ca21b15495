/* hbglue.h: the CPython glue the hilbench extensions share (the plant core hilbench/plant/_plantcore.c,
 * the AN1017 core hilbench/targets/an1017/_core.c, the FOC core hilbench/targets/foc/_core.c).
 *
 * Each extension is a thin glue between Python objects and a C model; what every glue needs is here
 * once: argument conversion (a float or an int argument, an int that must fit), the fields of a
 * Sensors tuple, the Drive NamedTuple a core builds (registered by the module's init(Drive)) and a
 * new Drive from its eleven fields, the module with its one type, and member-table rows. Header
 * only (static inline): setup.py adds this folder to each extension's include path, MANIFEST.in
 * ships it in the sdist.
 */
#ifndef HBGLUE_H
#define HBGLUE_H

#ifndef PY_SSIZE_T_CLEAN
#define PY_SSIZE_T_CLEAN
#endif
#include <Python.h>
#include <structmember.h>
#include <math.h>
#include <stddef.h>

/* ---- arguments ---------------------------------------------------------------------------- */

/* A number argument as a double: a float as it is, an int exactly (no float object is made, the
 * fast path for duties in counts), anything else through __float__. 0, or -1 with an exception. */
static inline int hb_double(PyObject *o, double *out)
{
    if (PyFloat_CheckExact(o)) {
        *out = PyFloat_AS_DOUBLE(o);
        return 0;
    }
    *out = PyLong_CheckExact(o) ? PyLong_AsDouble(o) : PyFloat_AsDouble(o);
    return (*out == -1.0 && PyErr_Occurred()) ? -1 : 0;
}

/* A core's advance(span_us, sensors) arguments, as every core's Python face reads them: exactly two,
 * the first a finite time of at most 1e15 us (int() of a non-finite one raises in the Python advance;
 * beyond 31 years it leaves the C arithmetic). 0 with *span_us, or -1 with an exception naming who. */
static inline int hb_advance_args(PyObject *const *args, Py_ssize_t nargs, const char *who, double *span_us)
{
    if (nargs != 2) {
        PyErr_Format(PyExc_TypeError, "%s advance(span_us, sensors)", who);
        return -1;
    }
    if (hb_double(args[0], span_us) < 0) return -1;
    if (!isfinite(*span_us) || fabs(*span_us) > 1e15) {
        PyErr_Format(PyExc_ValueError, "%s advance: span_us %R is not a finite time (at most 1e15)", who, args[0]);
        return -1;
    }
    return 0;
}

/* An int argument as a long / long long. 0, or -1 with an exception. */
static inline int hb_long(PyObject *o, long *out)
{
    *out = PyLong_AsLong(o);
    return (*out == -1 && PyErr_Occurred()) ? -1 : 0;
}

static inline int hb_longlong(PyObject *o, long long *out)
{
    *out = PyLong_AsLongLong(o);
    return (*out == -1 && PyErr_Occurred()) ? -1 : 0;
}

/* ---- messages ----------------------------------------------------------------------------- */

/* The fields of a Sensors tuple (protocol 3: seq, inputs, edges, encoder, adc); seq, edges, encoder
 * and adc are borrowed from the tuple (a core that reads the encoder converts it: hb_longlong; one
 * that reads the edges, (time in 100 ns, lines) pairs, walks them). */
typedef struct {
    PyObject *seq;
    long long seq_value;
    long inputs;
    PyObject *edges;
    PyObject *encoder;
    PyObject *adc;
} hb_sensors_t;

/* 0, or -1 with an exception (TypeError naming ``who`` for anything but a 5-field tuple). */
static inline int hb_sensors(PyObject *sensors, hb_sensors_t *out, const char *who)
{
    if (!PyTuple_Check(sensors) || PyTuple_GET_SIZE(sensors) != 5) {
        PyErr_Format(PyExc_TypeError, "%s: sensors must be a 5-field Sensors tuple", who);
        return -1;
    }
    out->seq = PyTuple_GET_ITEM(sensors, 0);
    out->encoder = PyTuple_GET_ITEM(sensors, 3);
    out->adc = PyTuple_GET_ITEM(sensors, 4);
    out->edges = PyTuple_GET_ITEM(sensors, 2);
    if (hb_longlong(out->seq, &out->seq_value) < 0 || hb_long(PyTuple_GET_ITEM(sensors, 1), &out->inputs) < 0)
        return -1;
    return 0;
}

/* init(Drive): keep the NamedTuple type a core builds its Drives of in *slot. 0, or -1 with a
 * TypeError naming ``who`` for anything but a tuple subclass. */
static inline int hb_set_tuple_type(PyObject *type, PyTypeObject **slot, const char *who)
{
    if (!PyType_Check(type) || !PyType_IsSubtype((PyTypeObject *)type, &PyTuple_Type)) {
        PyErr_Format(PyExc_TypeError, "%s: Drive must be a tuple subclass (NamedTuple)", who);
        return -1;
    }
    Py_INCREF(type);
    Py_XSETREF(*slot, (PyTypeObject *)type);
    return 0;
}

#define HB_DRIVE_FIELDS 11

/* A new Drive of ``type`` from its fields by name (new references, stolen; a NULL among them, a
 * failed conversion, releases the others): NULL with an exception, or the Drive. */
static inline PyObject *hb_drive(PyTypeObject *type, PyObject *seq, PyObject *duty_a, PyObject *duty_b,
                                 PyObject *duty_c, PyObject *output_mode, PyObject *state, PyObject *sector,
                                 PyObject *direction_ccw, PyObject *required_ccw, PyObject *fault, PyObject *telemetry)
{
    PyObject *d = NULL;
    if (type != NULL && seq && duty_a && duty_b && duty_c && output_mode && state && sector && direction_ccw
        && required_ccw && fault && telemetry)
        d = type->tp_alloc(type, HB_DRIVE_FIELDS);
    if (d == NULL) {
        Py_XDECREF(seq); Py_XDECREF(duty_a); Py_XDECREF(duty_b); Py_XDECREF(duty_c); Py_XDECREF(output_mode);
        Py_XDECREF(state); Py_XDECREF(sector); Py_XDECREF(direction_ccw); Py_XDECREF(required_ccw);
        Py_XDECREF(fault); Py_XDECREF(telemetry);
        if (type == NULL && !PyErr_Occurred()) PyErr_SetString(PyExc_RuntimeError, "core: init(Drive) was not called");
        return NULL;
    }
    PyTuple_SET_ITEM(d, 0, seq);
    PyTuple_SET_ITEM(d, 1, duty_a);
    PyTuple_SET_ITEM(d, 2, duty_b);
    PyTuple_SET_ITEM(d, 3, duty_c);
    PyTuple_SET_ITEM(d, 4, output_mode);
    PyTuple_SET_ITEM(d, 5, state);
    PyTuple_SET_ITEM(d, 6, sector);
    PyTuple_SET_ITEM(d, 7, direction_ccw);
    PyTuple_SET_ITEM(d, 8, required_ccw);
    PyTuple_SET_ITEM(d, 9, fault);
    PyTuple_SET_ITEM(d, 10, telemetry);
    return d;
}

/* ---- the module ------------------------------------------------------------------------------ */

/* The module of ``def`` with its one type added as ``name``; NULL with an exception. */
static inline PyObject *hb_module(struct PyModuleDef *def, PyTypeObject *type, const char *name)
{
    if (PyType_Ready(type) < 0) return NULL;
    PyObject *m = PyModule_Create(def);
    if (m == NULL) return NULL;
    Py_INCREF(type);
    if (PyModule_AddObject(m, name, (PyObject *)type) < 0) {
        Py_DECREF(type);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}

/* ``m`` with the span's C API ``api`` added as the capsule SPAN_API named ``capsule`` (HB_PLANT_API,
 * HB_TARGET_API); on failure ``m`` is released and NULL returned with an exception. */
static inline PyObject *hb_add_span_api(PyObject *m, void *api, const char *capsule)
{
    if (m == NULL) return NULL;
    PyObject *c = PyCapsule_New(api, capsule, NULL);
    if (c == NULL || PyModule_AddObject(m, "SPAN_API", c) < 0) {
        Py_XDECREF(c);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}

/* A member-table row: the Python name, the structmember type (T_DOUBLE, T_LONGLONG, ...), the
 * field of struct ``st`` and the flags (0 or READONLY). */
#define HB_MEMBER(pyname, tcode, st, field, flags) {pyname, tcode, offsetof(st, field), flags, NULL}

/* ---- the lockstep span in C (hilbench/bench/_span.c) --------------------------------------------- */

/* The session's tight loop between parts' events can run in C (hilbench/bench/_span.c): the plant
 * and the target each hand it their step as a C function through a capsule (PyCapsule named
 * HB_PLANT_API / HB_TARGET_API holding one of the structs below). The Python loop
 * (Session._periods_one_by_one) stays the reference; tests/test_span.py checks the C span records
 * the same bytes. */
#define HB_SPAN_MAX_ADC 8
#define HB_SPAN_MAX_TEL 16
/* The plant's capsule is versioned with its struct: v2 has speed_rad_s (a module built before it,
 * left in place by a stale build, is refused by name instead of read past its end). */
#define HB_PLANT_API "hilbench.plant.span_api.v2"
#define HB_TARGET_API "hilbench.target.span_api"

/* What a plant's sense() gives, in C. */
typedef struct {
    int hall, tripped, index;
    long encoder;
    int n_adc;
    long adc[HB_SPAN_MAX_ADC];
} hb_plant_sense_t;

typedef struct {
    /* sense(plant, roles, n_roles, out): the sensors as the last period left them; 0 or -1 with an exception */
    int (*sense)(PyObject *plant, const int *roles, int n_roles, hb_plant_sense_t *out);
    /* advance(plant, duty_a, duty_b, duty_c, output_mode, row, &have_edge, &edge_s): one exchange period
     * (Plant.advance without the actuation delay), its recorded outputs written to row when not NULL
     * (n_outputs doubles); 0 or -1 with an exception */
    int (*advance)(PyObject *plant, long duty_a, long duty_b, long duty_c, long output_mode, char *row,
                   int *have_edge, double *edge_s);
    int (*n_outputs)(PyObject *plant);
    int (*fault_input)(PyObject *plant); /* the comparator's latch */
    /* period_edges(plant, &edge_t, &edge_hall, &n_edges, &mark_t, &n_marks, &index): the hall edges (s from
     * the period's start, hall bits after) and index marks (s) of the last advance (Plant.edges,
     * Plant.index_marks: the plant's own arrays, read only) and sense()'s index flag, all without
     * sense()'s ADC noise draws */
    void (*period_edges)(PyObject *plant, const double **edge_t, const int **edge_hall, int *n_edges,
                         const double **mark_t, int *n_marks, int *index);
    double (*speed_rad_s)(PyObject *plant); /* the rotor's mechanical speed (Plant.w_m) */
} hb_plant_api_t;

#define HB_SPAN_MAX_EDGES 16 /* protocol 3's Sensors: at most MAX_EDGES input edges */

/* A Sensors and a Drive as C values (the protocol's fields; Sensors.edges as n_edges (time in
 * 100 ns, lines) pairs). */
typedef struct {
    long long seq;
    long inputs, encoder;
    int n_edges;
    long edge_t[HB_SPAN_MAX_EDGES], edge_lines[HB_SPAN_MAX_EDGES];
    int n_adc;
    long adc[HB_SPAN_MAX_ADC];
} hb_csensors_t;

typedef struct {
    long duty_a, duty_b, duty_c, output_mode, state, sector, direction_ccw, required_ccw, fault;
    int n_tel;
    long tel[HB_SPAN_MAX_TEL];
} hb_cdrive_t;

typedef struct {
    /* step(core, in, out): Target.step on C values (a repeated seq answered without a step, as the
     * Python step does); 0 or -1 with an exception */
    int (*step)(PyObject *core, const hb_csensors_t *in, hb_cdrive_t *out);
    /* drive(core, seq): the Drive object Target.step would have returned for the last step (it
     * becomes the core's answer to a repeat); a new reference or NULL with an exception */
    PyObject *(*drive)(PyObject *core, PyObject *seq);
    /* advance(core, span_us, in, out): Target.advance on C values, real time's step: the model run for
     * span_us of wall time (sub-cycle remainders carried), no repeat rule (the server's); 0 or -1 with
     * an exception. After it, drive(core, seq) must give the Drive of this advance (not a Drive kept
     * from an earlier step). NULL where the core has none: serve_realtime refuses it (TypeError), and
     * a target offers the C loop only with `realtime_core`. */
    int (*advance)(PyObject *core, double span_us, const hb_csensors_t *in, hb_cdrive_t *out);
} hb_target_api_t;

/* A core's answer to a repeated seq, as its `last_drive` attribute: None or the Drive kept; only None
 * may be written (forget it, and that the C span stepped last). One getter and setter for every core. */
static inline PyObject *hb_last_drive_get(PyObject *last_drive)
{
    if (last_drive == NULL) Py_RETURN_NONE;
    return Py_NewRef(last_drive);
}

static inline int hb_last_drive_forget(PyObject **last_drive, char *span_last, PyObject *v, const char *core)
{
    if (v != NULL && v != Py_None) {
        PyErr_Format(PyExc_TypeError, "%s core last_drive: only None may be written", core);
        return -1;
    }
    Py_CLEAR(*last_drive);
    *span_last = 0;
    return 0;
}

#endif /* HBGLUE_H */
