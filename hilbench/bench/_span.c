/* The session's lockstep span in C: the periods between the parts' events with no Python per period.
 *
 * hilbench.bench.session's tight loop (`Session._tight_runner`) hands a span [k, stop) here when
 * the plant and the target each have a C step (their SPAN_API capsules, hbglue.h): per period the
 * plant's sensors, protocol 3's Sensors (halls | buttons, the index mark, every hall edge and index
 * mark of the last period in 100 ns with its lines, as hilbench.bench.sensing builds them; the
 * encoder, the ADC codes), the target's step, the row (the session's own fields, the telemetry,
 * the plant's declared outputs: columns.session_row's bytes) and the plant's period. It is
 * `Session._periods_one_by_one` period for period; tests/test_span.py checks both record the same
 * bytes. A period whose Sensors would carry the overcurrent comparator's trip, or more edges than
 * the target takes (the session's bench limit), is left to Python (the span stops before it, before
 * the plant's sensors are read: the trip is noted there, the limit raised), as is anything with a sensor fault or real
 * time (the session does not call this then).
 *
 * The history sample (hilbench.bench.parts.HistoryPart: every `sample_every`-th period, after its
 * plant period) is taken here too when asked for: the period, the rotor's speed, the Drive's fault
 * code and the telemetry of the measured speed and of the firmware's reference, appended to the
 * `samples` bytearray (SAMPLE_BYTES each, `parts.SAMPLE_DTYPE`) for the part to take in bulk when the
 * span returns; a sample beyond the overspeed limit ends the span after its period (span.k is that
 * period; the part raises the bench limit there, as the Python loop does).
 *
 * A run given `hand_over_at` (a count of pending rows; 0: none) hands the recorder its rows from inside
 * the span: before the period at which that many rows are pending it calls `hand_over(n_rows)` (the
 * recorder's `span_rows`: the rows journaled and archived on the recorder's thread, its bookkeeping
 * done), which returns the next count (0: no more in this run), and writes on from the buffer's start.
 * So the recorder's chunks no longer end the span (each end is the parts' Python, ~0.1 ms on this
 * VM); the rows buffer holds at most one chunk. The buffer's size is not changed during the call (the
 * recorder reads the first n_rows rows where they are); a call that raises stops the span before that
 * period (its rows still pending when the recorder raised before taking them).
 */
#include "hbglue.h"
#include <string.h>
#include <time.h>

#define INPUT_INDEX 0x40
#define HALL_MASK 0x07
#define INPUT_FAULT 0x20
#define OWN_BYTES (8 + 8 * 4 + 8 + 8 + 1) /* k Q, hall..fault 8 i, rtt d, lateness d, marker B */
#define RTT_EVERY_MASK 63 /* the lockstep round-trip sample: one period in 64, as the Python loop */
#define SAMPLE_BYTES (8 + 8 + 3 * 4) /* k q, w_m d, fault i, measured i, reference i (parts.SAMPLE_DTYPE) */

typedef struct {
    PyObject_HEAD
    PyObject *plant, *core, *rows, *rtt_append, *hand_over;
    const hb_plant_api_t *papi;
    const hb_target_api_t *tapi;
    int roles[HB_SPAN_MAX_ADC];
    int n_roles, n_tel, n_out, read_index, host_ref, max_edges;
    long edge_limit;
    long hall_before; /* the hall bits of the last Sensors (an index mark before the period's first hall edge) */
    Py_ssize_t row_bytes;
    long long k;      /* where the last run stopped (the failing period after an exception) */
    int running;      /* a run is in progress (a Python call inside it must not start another) */
    PyObject *edge_s; /* the last period's hall edge (None: none), as Plant.advance returns it */
    PyObject *drive;  /* the last Drive (the one given when the span stepped nothing) */
    PyObject *samples; /* the history samples (a bytearray), NULL: none taken here */
    int sample_every, i_meas, i_ref; /* every how many periods; telemetry indexes (-1: none) */
    double overspeed_rpm, rpm_per_rad_s;
} Span;

static void put_i32(char *p, long v)
{
    int32_t x = (int32_t)v;
    memcpy(p, &x, 4); /* little-endian hosts only (the plant core's append_state says so too) */
}

/* The row's session fields, the host's reference and the telemetry (columns.session_row). */
static char *put_own(const Span *s, char *p, long long k, long hall, const hb_cdrive_t *d, double ref_rpm)
{
    uint64_t kk = (uint64_t)k;
    double zero = 0.0;
    memcpy(p, &kk, 8);
    put_i32(p + 8, hall);
    put_i32(p + 12, d->sector);
    put_i32(p + 16, d->duty_a);
    put_i32(p + 20, d->duty_b);
    put_i32(p + 24, d->duty_c);
    put_i32(p + 28, d->output_mode);
    put_i32(p + 32, d->state);
    put_i32(p + 36, d->fault);
    memcpy(p + 40, &zero, 8); /* lockstep: no rtt, no lateness, no marker in the row */
    memcpy(p + 48, &zero, 8);
    p[56] = 0;
    p += OWN_BYTES;
    if (s->host_ref) {
        memcpy(p, &ref_rpm, 8);
        p += 8;
    }
    for (int i = 0; i < s->n_tel; i++) put_i32(p + 4 * i, d->tel[i]);
    return p + 4 * s->n_tel;
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts); /* time.perf_counter's clock */
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* int(t_s * 1e7) capped to the period (sensing.py's min(int(t * 1e7), limit)) */
static long edge_time(double t_s, long limit)
{
    double e = t_s * 1e7;
    return e >= (double)limit ? limit : (long)e;
}

/* Period k's Sensors.edges into in (sensing.hall_edges and with_index_marks): 1 when they fit,
 * 0 when there are more than the target takes (left to Python, which raises the bench limit). */
static int period_edges(const Span *s, int have_edge, hb_csensors_t *in, int *index)
{
    const double *edge_t, *mark_t;
    const int *edge_hall;
    int n_edges, n_marks, n = 0;
    s->papi->period_edges(s->plant, &edge_t, &edge_hall, &n_edges, &mark_t, &n_marks, index);
    if (have_edge) { /* every hall edge of the period, timed */
        if (n_edges > s->max_edges) return 0;
        for (; n < n_edges; n++) {
            in->edge_t[n] = edge_time(edge_t[n], s->edge_limit);
            in->edge_lines[n] = edge_hall[n];
        }
    }
    if (*index && s->read_index) { /* the index marks among them: the halls in force then, INDEX set */
        if (n + n_marks > s->max_edges) return 0;
        int n_hall = n;
        for (int m = 0; m < n_marks; m++, n++) { /* appended, each with the halls of the hall edges before it */
            long t = edge_time(mark_t[m], s->edge_limit), hall = s->hall_before;
            for (int i = 0; i < n_hall && in->edge_t[i] <= t; i++) hall = in->edge_lines[i] & HALL_MASK;
            in->edge_t[n] = t;
            in->edge_lines[n] = hall | INPUT_INDEX;
        }
        for (int i = 1; i < n; i++) { /* a stable sort by (time, INDEX bit), as sorted() */
            long t = in->edge_t[i], lines = in->edge_lines[i];
            int j = i;
            for (; j > 0 && (in->edge_t[j - 1] > t
                             || (in->edge_t[j - 1] == t && (in->edge_lines[j - 1] & INPUT_INDEX) > (lines & INPUT_INDEX)));
                 j--) {
                in->edge_t[j] = in->edge_t[j - 1];
                in->edge_lines[j] = in->edge_lines[j - 1];
            }
            in->edge_t[j] = t;
            in->edge_lines[j] = lines;
        }
    }
    in->n_edges = n;
    return 1;
}

/* Period k's history sample appended at p (SAMPLE_BYTES). */
static void put_sample(const Span *s, char *p, long long k, double w_m, const hb_cdrive_t *d)
{
    int64_t kk = (int64_t)k;
    memcpy(p, &kk, 8);
    memcpy(p + 8, &w_m, 8);
    put_i32(p + 16, d->fault);
    put_i32(p + 20, s->i_meas >= 0 && s->i_meas < d->n_tel ? d->tel[s->i_meas] : 0);
    put_i32(p + 24, s->i_ref >= 0 && s->i_ref < d->n_tel ? d->tel[s->i_ref] : 0);
}

/* Room in the rows buffer for n_rows more rows after `used` bytes (*base and *cap follow the buffer). */
static int reserve_rows(Span *s, char **base, Py_ssize_t *cap, Py_ssize_t used, long long n_rows)
{
    Py_ssize_t need = used + (Py_ssize_t)n_rows * s->row_bytes;
    if (need <= *cap) return 0;
    if (PyByteArray_Resize(s->rows, need) < 0) return -1;
    *base = PyByteArray_AS_STRING(s->rows);
    *cap = need;
    return 0;
}

/* The pending rows handed over (`hand_over(n_rows)`): 0 with *hand_at the next count and nothing
 * pending, -1 with an exception set (the rows still pending). */
static int hand_rows_over(Span *s, Py_ssize_t *used, Py_ssize_t cap, long long *hand_at)
{
    PyObject *n = PyLong_FromSsize_t(*used / s->row_bytes);
    PyObject *next = n == NULL ? NULL : PyObject_CallOneArg(s->hand_over, n);
    Py_XDECREF(n);
    if (next == NULL) return -1;
    *used = 0; /* taken by the recorder (its rows_written counts them) whatever follows */
    long long at = PyLong_AsLongLong(next);
    Py_DECREF(next);
    if (at == -1 && PyErr_Occurred()) return -1;
    if (PyByteArray_GET_SIZE(s->rows) != cap) { /* its pointer is the span's: nobody else may resize it now */
        PyErr_SetString(PyExc_RuntimeError, "Span.run: the rows buffer was resized during a hand-over");
        return -1;
    }
    *hand_at = at > 0 ? at : 0;
    return 0;
}

/* run(k, stop, buttons, ref_rpm, edge_s, drive, hall_before[, hand_over_at]) -> the period it stopped
 * before: stop, the first period whose Sensors carry the comparator's trip or too many edges, or the
 * one after a history sample beyond the overspeed limit (span.k is then the sample's period). edge_s,
 * drive and hall_before are the members after it (also after an exception, with k the failing
 * period). hand_over_at: the pending-row count at which the rows are handed over (0: not in this run). */
static PyObject *span_run(Span *s, PyObject *const *args, Py_ssize_t nargs);

static PyObject *Span_run(Span *s, PyObject *const *args, Py_ssize_t nargs)
{
    if (s->running) { /* its rows buffer is resized under the running one's pointer otherwise */
        PyErr_SetString(PyExc_RuntimeError, "Span.run: already running (called from inside a span)");
        return NULL;
    }
    PyObject *out = span_run(s, args, nargs);
    s->running = 0;
    return out;
}

static PyObject *span_run(Span *s, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 7 && nargs != 8) {
        PyErr_SetString(PyExc_TypeError, "Span.run(k, stop, buttons, ref_rpm, edge_s, drive, hall_before[, hand_over_at])");
        return NULL;
    }
    if (s->papi == NULL || s->tapi == NULL || s->plant == NULL || s->core == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "Span.run: the Span was not initialised (Span(plant, ...))");
        return NULL;
    }
    long long k = PyLong_AsLongLong(args[0]), stop = PyLong_AsLongLong(args[1]);
    long buttons = PyLong_AsLong(args[2]), hall_before = PyLong_AsLong(args[6]);
    double ref_rpm = PyFloat_AsDouble(args[3]);
    long long hand_at = nargs == 8 ? PyLong_AsLongLong(args[7]) : 0;
    if (PyErr_Occurred()) return NULL;
    if (hand_at > 0 && (s->hand_over == NULL || s->rows == NULL)) {
        PyErr_SetString(PyExc_ValueError, "Span.run: hand_over_at without a hand_over and a rows buffer");
        return NULL;
    }
    if (hand_at < 0) hand_at = 0;
    int have_edge = args[4] != Py_None;
    double edge_s = have_edge ? PyFloat_AsDouble(args[4]) : 0.0;
    if (have_edge && edge_s == -1.0 && PyErr_Occurred()) return NULL;
    s->running = 1;
    Py_XSETREF(s->edge_s, Py_NewRef(args[4]));
    Py_XSETREF(s->drive, Py_NewRef(args[5]));
    s->hall_before = hall_before;
    s->k = k;
    Py_ssize_t used = 0, sused = 0, cap = 0;
    char *base = NULL, *sbase = NULL;
    if (s->rows != NULL && stop > k) { /* the loop makes room: for the span's rows, or up to each hand-over */
        used = cap = PyByteArray_GET_SIZE(s->rows);
        base = PyByteArray_AS_STRING(s->rows);
    }
    if (s->samples != NULL && stop > k) {
        sused = PyByteArray_GET_SIZE(s->samples);
        if (PyByteArray_Resize(s->samples, sused + (Py_ssize_t)((stop - k) / s->sample_every + 1) * SAMPLE_BYTES) < 0) {
            if (base != NULL) PyByteArray_Resize(s->rows, used);
            return NULL;
        }
        sbase = PyByteArray_AS_STRING(s->samples);
    }
    int failed = 0, stepped = 0, limit = 0;
    long long last_seq = 0;
    hb_plant_sense_t ps;
    hb_csensors_t in;
    hb_cdrive_t d;
    for (; k < stop; k++) {
        /* Ctrl-C between periods, as in the Python loop (not left to the Python calls a span may make) */
        if (!(k & RTT_EVERY_MASK) && PyErr_CheckSignals() < 0) { failed = 1; break; }
        if (base != NULL) {
            if (hand_at > 0 && used >= (Py_ssize_t)hand_at * s->row_bytes) { /* the recorder's chunk: handed over here */
                if (hand_rows_over(s, &used, cap, &hand_at) < 0) { failed = 1; break; }
            }
            if (used + s->row_bytes > cap) { /* room for the rest of the span, or the rows up to the next hand-over */
                long long more = stop - k, pending = used / s->row_bytes;
                if (hand_at > pending && hand_at - pending < more) more = hand_at - pending;
                if (reserve_rows(s, &base, &cap, used, more) < 0) { failed = 1; break; }
            }
        }
        if (s->papi->fault_input(s->plant)) break; /* the trip is the Python loop's (it notes it) */
        int index = 0;
        if (!period_edges(s, have_edge, &in, &index)) break; /* too many: Python raises the bench limit */
        if (s->papi->sense(s->plant, s->roles, s->n_roles, &ps) < 0) { failed = 1; break; }
        long inputs = ps.hall | buttons;
        if (ps.index && s->read_index) inputs |= INPUT_INDEX;
        s->hall_before = ps.hall;
        in.seq = k & 0xFF;
        in.inputs = inputs;
        in.encoder = ps.encoder;
        in.n_adc = ps.n_adc;
        memcpy(in.adc, ps.adc, sizeof(long) * (size_t)ps.n_adc);
        if (s->rtt_append != NULL && !(k & RTT_EVERY_MASK)) {
            double sent = now_s();
            if (s->tapi->step(s->core, &in, &d) < 0) { failed = 1; break; }
            PyObject *r = PyFloat_FromDouble(now_s() - sent);
            PyObject *ok = r == NULL ? NULL : PyObject_CallOneArg(s->rtt_append, r);
            Py_XDECREF(r);
            if (ok == NULL) { failed = 1; stepped = 1; last_seq = in.seq; break; }
            Py_DECREF(ok);
        } else if (s->tapi->step(s->core, &in, &d) < 0) {
            failed = 1;
            break;
        }
        stepped = 1;
        last_seq = in.seq;
        char *row = NULL;
        if (base != NULL) {
            if (d.n_tel != s->n_tel) {
                PyErr_Format(PyExc_ValueError, "session span: the Drive has %d telemetry values, the row %d",
                             d.n_tel, s->n_tel);
                failed = 1;
                break;
            }
            row = put_own(s, base + used, k, ps.hall, &d, ref_rpm);
            used = row - base;
        }
        if (s->papi->advance(s->plant, d.duty_a, d.duty_b, d.duty_c, d.output_mode, row, &have_edge, &edge_s) < 0) {
            failed = 1;
            break;
        }
        if (row != NULL) used += (Py_ssize_t)s->n_out * 8;
        if (sbase != NULL && k % s->sample_every == 0) { /* the history sample, after the plant's period */
            double w_m = s->papi->speed_rad_s(s->plant), rpm = w_m * s->rpm_per_rad_s;
            put_sample(s, sbase + sused, k, w_m, &d);
            sused += SAMPLE_BYTES;
            if (!(-s->overspeed_rpm <= rpm && rpm <= s->overspeed_rpm)) { /* NaN too: the part raises there */
                limit = 1;
                break;
            }
        }
    }
    s->k = k;
    PyObject *et = NULL, *ev = NULL, *tb = NULL;
    if (failed) PyErr_Fetch(&et, &ev, &tb);
    int fine = 1;
    if (base != NULL && PyByteArray_Resize(s->rows, used) < 0) fine = 0;
    if (sbase != NULL && PyByteArray_Resize(s->samples, sused) < 0) fine = 0;
    if (fine && stepped) {
        PyObject *seq = PyLong_FromLongLong(last_seq);
        PyObject *drive = seq == NULL ? NULL : s->tapi->drive(s->core, seq);
        Py_XDECREF(seq);
        if (drive == NULL) fine = 0;
        else Py_XSETREF(s->drive, drive);
    }
    if (fine && (stepped || failed)) {
        PyObject *e = have_edge ? PyFloat_FromDouble(edge_s) : Py_NewRef(Py_None);
        if (e == NULL) fine = 0;
        else Py_XSETREF(s->edge_s, e);
    }
    if (failed) {
        if (!fine) PyErr_Clear();
        PyErr_Restore(et, ev, tb);
        return NULL;
    }
    if (!fine) return NULL;
    return PyLong_FromLongLong(limit ? k + 1 : k);
}

/* edges(have_edge, hall_before) -> ((time in 100 ns, lines), ...) or None (more than max_edges): the
 * Sensors.edges a period after the plant's last advance gets in a run (tests/test_span.py compares
 * them with hilbench.bench.sensing's); nothing is stepped or sensed. */
static PyObject *Span_edges(Span *s, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "Span.edges(have_edge, hall_before)");
        return NULL;
    }
    int have_edge = PyObject_IsTrue(args[0]);
    long hall_before = PyLong_AsLong(args[1]);
    if (have_edge < 0 || (hall_before == -1 && PyErr_Occurred())) return NULL;
    long keep = s->hall_before;
    hb_csensors_t in;
    int index = 0;
    s->hall_before = hall_before;
    int fits = period_edges(s, have_edge, &in, &index);
    s->hall_before = keep;
    if (!fits) Py_RETURN_NONE;
    PyObject *out = PyTuple_New(in.n_edges);
    if (out == NULL) return NULL;
    for (int i = 0; i < in.n_edges; i++) {
        PyObject *e = Py_BuildValue("(ll)", in.edge_t[i], in.edge_lines[i]);
        if (e == NULL) { Py_DECREF(out); return NULL; }
        PyTuple_SET_ITEM(out, i, e);
    }
    return out;
}

static int Span_init(Span *s, PyObject *args, PyObject *kwds)
{
    static char *kw[] = {"plant", "plant_api", "core", "target_api", "roles", "edge_limit", "read_index", "rows",
                         "n_telemetry", "host_ref", "rtt_append", "max_edges", "sample_every", "samples",
                         "meas_index", "ref_index", "overspeed_rpm", "rpm_per_rad_s", "hand_over", NULL};
    PyObject *plant, *papi, *core, *tapi, *roles, *rows, *rtt, *samples = Py_None, *hand_over = Py_None;
    long edge_limit;
    int read_index, n_tel, host_ref, max_edges, sample_every = 0, i_meas = -1, i_ref = -1;
    double overspeed_rpm = Py_HUGE_VAL, rpm_per_rad_s = 0.0;
    if (s->running) {
        PyErr_SetString(PyExc_RuntimeError, "Span: cannot be initialised again while it runs");
        return -1;
    }
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OOOOOlpOipOi|$iOiiddO:Span", kw, &plant, &papi, &core, &tapi, &roles,
                                     &edge_limit, &read_index, &rows, &n_tel, &host_ref, &rtt, &max_edges,
                                     &sample_every, &samples, &i_meas, &i_ref, &overspeed_rpm, &rpm_per_rad_s,
                                     &hand_over))
        return -1;
    if (samples != Py_None && (!PyByteArray_Check(samples) || sample_every < 1)) {
        PyErr_SetString(PyExc_TypeError, "Span: samples must be a bytearray (with sample_every >= 1) or None");
        return -1;
    }
    if (hand_over != Py_None && !PyCallable_Check(hand_over)) {
        PyErr_SetString(PyExc_TypeError, "Span: hand_over must be callable or None");
        return -1;
    }
    if (max_edges < 0 || max_edges > HB_SPAN_MAX_EDGES) {
        PyErr_Format(PyExc_ValueError, "Span: max_edges %d (0..%d)", max_edges, HB_SPAN_MAX_EDGES);
        return -1;
    }
    const hb_plant_api_t *plant_api = PyCapsule_GetPointer(papi, HB_PLANT_API);
    const hb_target_api_t *target_api = PyCapsule_GetPointer(tapi, HB_TARGET_API);
    if (plant_api == NULL || target_api == NULL) return -1;
    if (rows != Py_None && !PyByteArray_Check(rows)) {
        PyErr_SetString(PyExc_TypeError, "Span: rows must be a bytearray or None");
        return -1;
    }
    if (n_tel < 0 || n_tel > HB_SPAN_MAX_TEL) {
        PyErr_Format(PyExc_ValueError, "Span: %d telemetry values (at most %d)", n_tel, HB_SPAN_MAX_TEL);
        return -1;
    }
    PyObject *seq = PySequence_Fast(roles, "Span: roles must be a sequence");
    if (seq == NULL) return -1;
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    if (n > HB_SPAN_MAX_ADC) {
        Py_DECREF(seq);
        PyErr_Format(PyExc_ValueError, "Span: %zd ADC roles (at most %d)", n, HB_SPAN_MAX_ADC);
        return -1;
    }
    int role[HB_SPAN_MAX_ADC];
    for (Py_ssize_t i = 0; i < n; i++) {
        long r = PyLong_AsLong(PySequence_Fast_GET_ITEM(seq, i));
        if (r == -1 && PyErr_Occurred()) { Py_DECREF(seq); return -1; }
        role[i] = (int)r;
    }
    Py_DECREF(seq);
    /* every argument is good: the members change together (a failed init leaves the old ones) */
    s->papi = plant_api;
    s->tapi = target_api;
    memcpy(s->roles, role, sizeof(int) * (size_t)n);
    s->n_roles = (int)n;
    Py_XSETREF(s->plant, Py_NewRef(plant));
    Py_XSETREF(s->core, Py_NewRef(core));
    Py_XSETREF(s->rows, rows == Py_None ? NULL : Py_NewRef(rows));
    Py_XSETREF(s->rtt_append, rtt == Py_None ? NULL : Py_NewRef(rtt));
    Py_XSETREF(s->samples, samples == Py_None ? NULL : Py_NewRef(samples));
    Py_XSETREF(s->hand_over, hand_over == Py_None ? NULL : Py_NewRef(hand_over));
    s->sample_every = sample_every;
    s->i_meas = i_meas;
    s->i_ref = i_ref;
    s->overspeed_rpm = overspeed_rpm;
    s->rpm_per_rad_s = rpm_per_rad_s;
    s->edge_limit = edge_limit;
    s->read_index = read_index;
    s->n_tel = n_tel;
    s->host_ref = host_ref;
    s->max_edges = max_edges;
    s->hall_before = 0;
    s->n_out = s->papi->n_outputs(plant);
    s->row_bytes = OWN_BYTES + (host_ref ? 8 : 0) + 4 * n_tel + 8 * (Py_ssize_t)s->n_out;
    Py_XSETREF(s->edge_s, Py_NewRef(Py_None));
    Py_XSETREF(s->drive, Py_NewRef(Py_None));
    return 0;
}

static int Span_traverse(Span *s, visitproc visit, void *arg)
{
    Py_VISIT(s->plant);
    Py_VISIT(s->core);
    Py_VISIT(s->rows);
    Py_VISIT(s->rtt_append);
    Py_VISIT(s->edge_s);
    Py_VISIT(s->drive);
    Py_VISIT(s->samples);
    Py_VISIT(s->hand_over);
    return 0;
}

static int Span_clear(Span *s)
{
    Py_CLEAR(s->plant);
    Py_CLEAR(s->core);
    Py_CLEAR(s->rows);
    Py_CLEAR(s->rtt_append);
    Py_CLEAR(s->edge_s);
    Py_CLEAR(s->drive);
    Py_CLEAR(s->samples);
    Py_CLEAR(s->hand_over);
    return 0;
}

static void Span_dealloc(Span *s)
{
    PyObject_GC_UnTrack(s);
    Span_clear(s);
    Py_TYPE(s)->tp_free((PyObject *)s);
}

static PyMemberDef Span_members[] = {
    {"k", T_LONGLONG, offsetof(Span, k), READONLY, "where the last run stopped (the failing period after an error, an overspeed sample's period)"},
    {"edge_s", T_OBJECT, offsetof(Span, edge_s), READONLY, "the last period's hall edge (None: none)"},
    {"drive", T_OBJECT, offsetof(Span, drive), READONLY, "the last Drive"},
    {"hall_before", T_LONG, offsetof(Span, hall_before), READONLY, "the hall bits of the last Sensors"},
    {"row_bytes", T_PYSSIZET, offsetof(Span, row_bytes), READONLY, "bytes per recorded row"},
    {NULL, 0, 0, 0, NULL},
};

static PyMethodDef Span_methods[] = {
    {"run", (PyCFunction)(void (*)(void))Span_run, METH_FASTCALL,
     "run(k, stop, buttons, ref_rpm, edge_s, drive, hall_before[, hand_over_at]) -> the period it stopped before."},
    {"edges", (PyCFunction)(void (*)(void))Span_edges, METH_FASTCALL,
     "edges(have_edge, hall_before) -> the Sensors.edges of the period after the plant's last advance, or None."},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject SpanType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "hilbench.bench._span.Span",
    .tp_basicsize = sizeof(Span),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC,
    .tp_doc = "Span(plant, plant_api, core, target_api, roles, edge_limit, read_index, rows, n_telemetry, host_ref, "
              "rtt_append, max_edges, *, sample_every=0, samples=None, meas_index=-1, ref_index=-1, overspeed_rpm=inf, "
              "rpm_per_rad_s=0.0, hand_over=None): the session's lockstep periods in C (and its history samples, and the "
              "hand-over of its rows to the recorder).",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Span_init,
    .tp_dealloc = (destructor)Span_dealloc,
    .tp_traverse = (traverseproc)Span_traverse,
    .tp_clear = (inquiry)Span_clear,
    .tp_members = Span_members,
    .tp_methods = Span_methods,
};

static struct PyModuleDef moduledef = {
    PyModuleDef_HEAD_INIT, "_span", "The session's lockstep span in C (optional).", -1, NULL, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__span(void)
{
    return hb_module(&moduledef, &SpanType, "Span");
}
