/* The process paths' lockstep exchange in C, on protocol 3's C library: the host's RemoteTarget.step
 * for the session's lockstep span (hilbench/bench/_span.c) with a process target, and a target
 * process's serve() loops, lockstep and real time (serve_lockstep, serve_realtime, further below).
 *
 * hilbench.targets.remote.RemoteTarget.step (over hilbench.link.Link) is the reference: send the
 * Sensors frame, one poll and one read, and when those bytes are exactly one good Drive frame with
 * the Sensors' seq on a clean stream, that Drive. This is the same exchange on C values through
 * hbglue.h's target capsule, with protocol 3's C codec (firmware_protocol/: hbp_encode_frame,
 * hbp_rx_byte, hbp_unpack) in place of the Python one. Only that common case is done here; anything
 * else goes back to the Python reference at the point the C path reached, with what it read:
 *   - the link not in its fast state (a frame pending, no direct fd, blocking, a partial frame or an
 *     owed resync), or a Sensors field outside its wire range: RemoteTarget.step on the Sensors;
 *   - a short or failed write: the rest through Link._write (as Link.send);
 *   - nothing within retry_s, a failed read, end of file, bytes that are not exactly one good Drive
 *     with our seq: Link._took (recv_or_none's end) and RemoteTarget._answer (step's end).
 * So every error (a bad frame, a timeout, the target gone, a repeated or stray seq) is raised by
 * the same Python code as in the Python loop. The link's counters (frames, bytes, the fast frames,
 * the Drive seq the link expects next and its gaps) are kept here during a span and written back
 * to the Link before any Python call and when the span ends (drive()).
 * tests/test_remote_step.py checks recordings against the Python loop and each error path.
 */
#include "hbglue.h"
#include "hbp.h"
#include <errno.h>
#include <math.h>
#include <poll.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#define READ_CHUNK 65536 /* hilbench.link.transport._READ_CHUNK */

/* A Link's counters kept in C while C exchanges frames on its fd: deltas, and the seq it expects next
 * of the sequenced type received here (Drive on the host, Sensors on a target). */
typedef struct {
    PyObject *link, *key; /* borrowed: the Link and the message type (its key in link._next_seq) */
    int fd;
    int synced;           /* no Python ran since the link was last looked at: its state is as C left it,
                             next_seq is loaded and the deltas are to be written back */
    long long frames_tx, bytes_tx, bytes_rx, fast_frames, seq_gaps;
    int sequenced;        /* the link keeps a running seq for the type (Link._next_seq has it) */
    int next_seq;         /* -1: None (none seen yet) */
} tally_t;

typedef struct {
    PyObject_HEAD
    PyObject *target, *link, *step, *drive_type, *sensors_type;
    PyObject *last_drive; /* the last step's Drive when Python made it (NULL: the C values below) */
    hb_cdrive_t last;     /* the last step's Drive as C values */
    long last_seq;
    int fd, retry_ms;
    double retry_s;
    tally_t t; /* the link's counters while a span runs */
    long long c_steps;    /* steps answered wholly in C (for the tests: the fast path is the common one) */
    unsigned char rx[READ_CHUNK];
} Remote;

static double monotonic_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts); /* time.monotonic's clock */
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Link._take_read's fast path: one good frame of the type, its seq against the one expected. */
static void tally_frame(tally_t *s, Py_ssize_t n, int seq)
{
    s->bytes_rx += n;
    s->fast_frames += 1;
    if (!s->sequenced) return;
    if (s->next_seq >= 0 && seq != s->next_seq) s->seq_gaps += 1;
    s->next_seq = (seq + 1) & 0xFF;
}

/* Wait up to timeout_ms from t0 (monotonic_s) for input on fd, the GIL released (as select.poll);
 * a signal runs its Python handlers and the wait goes on for what is left of the timeout (PEP 475).
 * poll's result: > 0 ready, 0 nothing in time, < 0 failed (with an exception when a handler raised). */
static int poll_in(int fd, int timeout_ms, double t0)
{
    struct pollfd p = {fd, POLLIN | POLLPRI, 0};
    int ready, err, wait_ms = timeout_ms;
    for (;;) {
        Py_BEGIN_ALLOW_THREADS
        ready = poll(&p, 1, wait_ms);
        err = errno;
        Py_END_ALLOW_THREADS
        if (ready >= 0 || err != EINTR || PyErr_CheckSignals() < 0) return ready;
        if (timeout_ms > 0) {
            double left_ms = (t0 - monotonic_s()) * 1000.0 + (double)timeout_ms;
            wait_ms = left_ms > 0.0 ? (int)ceil(left_ms) : 0;
        }
    }
}

/* link.<name> += delta */
static int add_attr(PyObject *link, const char *name, long long delta)
{
    if (delta == 0) return 0;
    PyObject *v = PyObject_GetAttrString(link, name);
    if (v == NULL) return -1;
    PyObject *d = PyLong_FromLongLong(delta);
    PyObject *sum = d == NULL ? NULL : PyNumber_Add(v, d);
    Py_DECREF(v);
    Py_XDECREF(d);
    if (sum == NULL) return -1;
    int r = PyObject_SetAttrString(link, name, sum);
    Py_DECREF(sum);
    return r;
}

/* The key's entry of link._next_seq; a type it has no entry for is not sequenced (Link._take_read
 * counts no gaps for it and keeps no seq). */
static int load_next_seq(tally_t *s)
{
    PyObject *table = PyObject_GetAttrString(s->link, "_next_seq");
    if (table == NULL) return -1;
    PyObject *v = PyObject_GetItem(table, s->key);
    Py_DECREF(table);
    s->sequenced = v != NULL;
    s->next_seq = -1;
    if (v == NULL) {
        if (!PyErr_ExceptionMatches(PyExc_KeyError)) return -1;
        PyErr_Clear();
        return 0;
    }
    int r = 0;
    if (v != Py_None) {
        long n = PyLong_AsLong(v);
        if (n == -1 && PyErr_Occurred()) r = -1;
        else s->next_seq = (int)n;
    }
    Py_DECREF(v);
    return r;
}

/* Write the span's counters back to the Link (before any Python call and at the span's end). */
static int flush(tally_t *s)
{
    if (!s->synced) return 0;
    s->synced = 0;
    int r = 0;
    r |= add_attr(s->link, "frames_tx", s->frames_tx);
    r |= add_attr(s->link, "bytes_tx", s->bytes_tx);
    r |= add_attr(s->link, "bytes_rx", s->bytes_rx);
    r |= add_attr(s->link, "fast_frames", s->fast_frames);
    r |= add_attr(s->link, "seq_gaps", s->seq_gaps);
    s->frames_tx = s->bytes_tx = s->bytes_rx = s->fast_frames = s->seq_gaps = 0;
    if (r < 0) return -1;
    if (!s->sequenced) return 0;
    PyObject *table = PyObject_GetAttrString(s->link, "_next_seq");
    if (table == NULL) return -1;
    PyObject *v = s->next_seq < 0 ? Py_NewRef(Py_None) : PyLong_FromLong(s->next_seq);
    r = v == NULL ? -1 : PyObject_SetItem(table, s->key, v);
    Py_XDECREF(v);
    Py_DECREF(table);
    return r;
}

/* link.<name> as a C long (bools and ints) */
static int attr_long(PyObject *o, const char *name, long *out)
{
    PyObject *v = PyObject_GetAttrString(o, name);
    if (v == NULL) return -1;
    *out = PyLong_AsLong(v);
    Py_DECREF(v);
    return (*out == -1 && PyErr_Occurred()) ? -1 : 0;
}

/* 1 when the link is as Link.recv_or_none's fast path needs it (nothing pending, its fd read
 * directly, non-blocking, clean), 0 if not, -1 with an exception. */
static int link_fast(tally_t *s)
{
    long fd_r, blocking, clean;
    if (attr_long(s->link, "_fd_r", &fd_r) < 0 || attr_long(s->link, "_blocking", &blocking) < 0
        || attr_long(s->link, "_clean", &clean) < 0)
        return -1;
    if (fd_r != s->fd || blocking || !clean) return 0;
    PyObject *pending = PyObject_GetAttrString(s->link, "_pending");
    if (pending == NULL) return -1;
    Py_ssize_t n = PyObject_Length(pending);
    Py_DECREF(pending);
    if (n < 0) return -1;
    return n == 0;
}

/* The Sensors as hilbench.protocol's Sensors tuple (for the Python reference). */
static PyObject *sensors_object(PyObject *sensors_type, const hb_csensors_t *in)
{
    PyObject *edges = PyTuple_New(in->n_edges), *adc = PyTuple_New(in->n_adc);
    if (edges == NULL || adc == NULL) goto fail;
    for (int i = 0; i < in->n_edges; i++) {
        PyObject *e = Py_BuildValue("(ll)", in->edge_t[i], in->edge_lines[i]);
        if (e == NULL) goto fail;
        PyTuple_SET_ITEM(edges, i, e);
    }
    for (int i = 0; i < in->n_adc; i++) {
        PyObject *a = PyLong_FromLong(in->adc[i]);
        if (a == NULL) goto fail;
        PyTuple_SET_ITEM(adc, i, a);
    }
    PyObject *out = PyObject_CallFunction(sensors_type, "LlOlO", in->seq, in->inputs, edges, in->encoder, adc);
    Py_DECREF(edges);
    Py_DECREF(adc);
    return out;
fail:
    Py_XDECREF(edges);
    Py_XDECREF(adc);
    return NULL;
}

/* A Drive object -> C values (the Python reference's answer). */
static int drive_values(PyObject *drive, hb_cdrive_t *out)
{
    if (!PyTuple_Check(drive) || PyTuple_GET_SIZE(drive) != HB_DRIVE_FIELDS) {
        PyErr_SetString(PyExc_TypeError, "remote step: the answer is not a Drive");
        return -1;
    }
    long *f[9] = {&out->duty_a, &out->duty_b, &out->duty_c, &out->output_mode, &out->state, &out->sector,
                  &out->direction_ccw, &out->required_ccw, &out->fault};
    for (int i = 0; i < 9; i++) {
        *f[i] = PyLong_AsLong(PyTuple_GET_ITEM(drive, i + 1));
        if (*f[i] == -1 && PyErr_Occurred()) return -1;
    }
    PyObject *tel = PyTuple_GET_ITEM(drive, 10);
    Py_ssize_t n = PyTuple_Check(tel) ? PyTuple_GET_SIZE(tel) : -1;
    if (n < 0 || n > HB_SPAN_MAX_TEL) {
        PyErr_SetString(PyExc_ValueError, "remote step: the Drive's telemetry is not a tuple of at most 16");
        return -1;
    }
    out->n_tel = (int)n;
    for (Py_ssize_t i = 0; i < n; i++) {
        out->tel[i] = PyLong_AsLong(PyTuple_GET_ITEM(tel, i));
        if (out->tel[i] == -1 && PyErr_Occurred()) return -1;
    }
    return 0;
}

/* Keep a Drive the Python reference made as the step's answer. */
static int answer_from(Remote *s, PyObject *drive, hb_cdrive_t *out)
{
    if (drive == NULL) return -1;
    int r = drive_values(drive, out);
    if (r == 0) {
        Py_XSETREF(s->last_drive, drive);
        s->last = *out;
    } else {
        Py_DECREF(drive);
    }
    return r;
}

/* The Sensors' wire fields, or 0 when one is outside its range (the Python encoder raises). */
static int pack_sensors(const hb_csensors_t *in, hbp_sensors_t *m)
{
    if (in->seq < 0 || in->seq > 0xFF || in->inputs < 0 || in->inputs > 0xFF || in->encoder < 0 || in->encoder > 0xFFFF
        || in->n_adc > (int)HBP_MAX_ADC || in->n_edges > (int)HBP_MAX_EDGES)
        return 0;
    m->seq = (hbp_u8)in->seq;
    m->inputs = (hbp_u8)in->inputs;
    m->encoder = (uint16_t)in->encoder;
    m->n_adc = (hbp_u8)in->n_adc;
    for (int i = 0; i < in->n_adc; i++) {
        if (in->adc[i] < 0 || in->adc[i] > 0xFFFF) return 0;
        m->adc[i] = (uint16_t)in->adc[i];
    }
    m->n_edges = (hbp_u8)in->n_edges;
    for (int i = 0; i < in->n_edges; i++) {
        if (in->edge_t[i] < 0 || in->edge_t[i] > 0xFFFF || in->edge_lines[i] < 0 || in->edge_lines[i] > 0xFF) return 0;
        m->edges[i].time_100ns = (uint16_t)in->edge_t[i];
        m->edges[i].lines = (hbp_u8)in->edge_lines[i];
    }
    return 1;
}

/* One read's bytes as exactly one good frame of message type ``type`` (what Link._take_read's fast
 * path and the generated decoder accept), unpacked by ``layout`` into *m: 1, or 0. */
static int one_message(const unsigned char *data, Py_ssize_t n, hbp_u8 type, const hbp_layout_t *layout, void *m)
{
    if (n < 2 || n > HBP_MAX_WIRE || data[n - 1] != 0 || memchr(data, 0, (size_t)(n - 1)) != NULL) return 0;
    hbp_rx_t rx;
    hbp_rx_init(&rx);
    hbp_u8 got = 0u;
    for (Py_ssize_t i = 0; i < n; i++) got = hbp_rx_byte(&rx, (hbp_u8)data[i]);
    if (!got || rx.frame_len < 2u || rx.buf[0] != type) return 0;
    return hbp_unpack(layout, rx.buf, rx.frame_len, m) == HBP_ERROR_NONE;
}

static int one_drive(const unsigned char *data, Py_ssize_t n, hbp_drive_t *d)
{
    return one_message(data, n, HBP_MSG_DRIVE, &hbp_layout_drive, d);
}

static void drive_to_c(const hbp_drive_t *m, hb_cdrive_t *out)
{
    out->duty_a = m->duty_a; out->duty_b = m->duty_b; out->duty_c = m->duty_c;
    out->output_mode = m->output_mode; out->state = m->state; out->sector = m->sector;
    out->direction_ccw = m->direction_ccw != 0; out->required_ccw = m->required_ccw != 0; out->fault = m->fault;
    out->n_tel = m->n_telemetry;
    for (int i = 0; i < m->n_telemetry; i++) out->tel[i] = m->telemetry[i];
}

/* Step's end in Python: Link._took(data, deadline, timeout) then RemoteTarget._answer(sensors, msg). */
static int python_rest(Remote *s, const hb_csensors_t *in, PyObject *data, double deadline, hb_cdrive_t *out)
{
    PyObject *sensors = sensors_object(s->sensors_type, in);
    if (sensors == NULL) return -1;
    PyObject *msg = PyObject_CallMethod(s->link, "_took", "Odd", data, deadline, s->retry_s);
    PyObject *drive = msg == NULL ? NULL : PyObject_CallMethod(s->target, "_answer", "OO", sensors, msg);
    Py_XDECREF(msg);
    Py_DECREF(sensors);
    return answer_from(s, drive, out);
}

static int remote_step(PyObject *self, const hb_csensors_t *in, hb_cdrive_t *out)
{
    Remote *s = (Remote *)self;
    hbp_sensors_t m;
    int fast = 1;
    if (!s->t.synced) { /* a span's first step, or the first after a Python call: how the link is now */
        fast = link_fast(&s->t);
        if (fast < 0) return -1;
    }
    if (!fast || !pack_sensors(in, &m)) { /* the Python reference, whole */
        if (flush(&s->t) < 0) return -1;
        PyObject *sensors = sensors_object(s->sensors_type, in);
        if (sensors == NULL) return -1;
        PyObject *drive = PyObject_CallOneArg(s->step, sensors);
        Py_DECREF(sensors);
        return answer_from(s, drive, out);
    }
    if (!s->t.synced) {
        if (load_next_seq(&s->t) < 0) return -1;
        s->t.synced = 1;
    }
    hbp_u8 frame[HBP_MAX_WIRE + 2], wire[HBP_MAX_WIRE + 2];
    hbp_u8 len = hbp_pack_sensors(&m, frame);
    hbp_u8 n_wire = len ? hbp_encode_frame(frame, len, wire) : 0u;
    if (n_wire == 0u) { /* cannot happen for fields in range; the reference names it if it does */
        if (flush(&s->t) < 0) return -1;
        PyObject *sensors = sensors_object(s->sensors_type, in);
        if (sensors == NULL) return -1;
        PyObject *drive = PyObject_CallOneArg(s->step, sensors);
        Py_DECREF(sensors);
        return answer_from(s, drive, out);
    }
    /* Link.send: one write; the rest (or all of it after an error) through the transport */
    ssize_t w = write(s->fd, wire, n_wire);
    if (w < 0) w = 0;
    if (w != (ssize_t)n_wire) {
        if (flush(&s->t) < 0) return -1;
        PyObject *timeout = PyObject_GetAttrString(s->link, "timeout_s");
        PyObject *rest = PyBytes_FromStringAndSize((const char *)wire + w, (Py_ssize_t)n_wire - w);
        PyObject *r = (timeout == NULL || rest == NULL) ? NULL : PyObject_CallMethod(s->link, "_write", "OO", rest, timeout);
        Py_XDECREF(timeout);
        Py_XDECREF(rest);
        if (r == NULL) return -1;
        Py_DECREF(r);
        if (load_next_seq(&s->t) < 0) return -1;
        s->t.synced = 1;
    }
    s->t.frames_tx += 1;
    s->t.bytes_tx += n_wire;
    /* recv_or_none(retry_s): one poll and one read */
    double t0 = monotonic_s();
    int ready = poll_in(s->fd, s->retry_ms, t0);
    if (ready < 0 && PyErr_Occurred()) { /* a signal handler raised (Ctrl-C): the counters kept, its error raised */
        PyObject *et, *ev, *tb;
        PyErr_Fetch(&et, &ev, &tb);
        flush(&s->t); /* (Python calls: not with an exception set) */
        PyErr_Clear();
        PyErr_Restore(et, ev, tb);
        return -1;
    }
    ssize_t n = -1;
    if (ready > 0) n = read(s->fd, s->rx, READ_CHUNK);
    hbp_drive_t d;
    if (n > 0 && one_drive(s->rx, n, &d) && d.seq == in->seq) {
        tally_frame(&s->t, n, d.seq);
        drive_to_c(&d, out);
        s->last = *out;
        s->last_seq = d.seq;
        s->c_steps += 1;
        Py_CLEAR(s->last_drive);
        return 0;
    }
    /* the bytes taken before any Python call (another thread may run then) */
    PyObject *data = n >= 0 ? PyBytes_FromStringAndSize((const char *)s->rx, n) : Py_NewRef(Py_None);
    if (data == NULL || flush(&s->t) < 0) {
        Py_XDECREF(data);
        return -1;
    }
    int r = python_rest(s, in, data, t0 + s->retry_s, out);
    Py_DECREF(data);
    return r;
}

/* A Drive object (drive_type) of C values with this seq. */
static PyObject *drive_of(PyObject *drive_type, PyObject *seq, const hb_cdrive_t *d)
{
    PyObject *tel = PyTuple_New(d->n_tel);
    if (tel == NULL) return NULL;
    for (int i = 0; i < d->n_tel; i++) {
        PyObject *v = PyLong_FromLong(d->tel[i]);
        if (v == NULL) { Py_DECREF(tel); return NULL; }
        PyTuple_SET_ITEM(tel, i, v);
    }
    PyObject *drive = PyObject_CallFunction(drive_type, "OllllllOOlO", seq, d->duty_a, d->duty_b, d->duty_c,
                                            d->output_mode, d->state, d->sector,
                                            d->direction_ccw ? Py_True : Py_False, d->required_ccw ? Py_True : Py_False,
                                            d->fault, tel);
    Py_DECREF(tel);
    return drive;
}

/* The Drive object of the last step (the span's end): the one Python made, or one from the C values. */
static PyObject *remote_drive(PyObject *self, PyObject *seq)
{
    Remote *s = (Remote *)self;
    if (flush(&s->t) < 0) return NULL;
    if (s->last_drive != NULL) return Py_NewRef(s->last_drive);
    return drive_of(s->drive_type, seq, &s->last);
}

static hb_target_api_t span_api = {remote_step, remote_drive, NULL}; /* a process answers real time itself */

/* ------------------------------------------------- serve()'s lockstep and real-time loops in C */
/* hilbench.targets.serve._Server._lockstep is the reference: wait for a frame; a Sensors is counted,
 * its time noted when a watchdog is agreed, answered with answer.step(msg) (RepeatAnswer: the last
 * Drive again for a repeated seq, else the target's step with the Sensors' seq) and the Drive sent;
 * anything else returns to the server. _Server._realtime is real time's: the wait up to the
 * watchdog's due time (realtime_wait), each new Sensors the target's advance by the wall time since
 * the last one (_new_period: its time always noted, `tripped` cleared). Here the same for the common case, on C values through the
 * target's capsule: a read that is exactly one good Sensors whose seq is not the last Drive's, on a
 * link in its fast state. Everything else goes back to Python where C stopped: the bytes read through
 * Link._took (the message it makes is returned, and the server's loop handles it as its own recv's);
 * a step that raises through _Server.handler_fault; a Drive outside its wire ranges through
 * Link.send. The server's and the answer's state (report.sensors, last_sensors_t, tripped,
 * answer.last) and the link's counters are written back before any Python call and on return. */

typedef struct {
    PyObject *server, *answer, *report, *api_core, *drive_type;
    const hb_target_api_t *api;
    int watching;
    long long stepped;    /* Sensors answered by C since the last write-back */
    long last_seq;        /* the seq of the last Drive C made (-1: none since the write-back) */
    double last_t;
    hb_cdrive_t sent;     /* that Drive's values, as sent */
} serving_t;

static int set_attr_obj(PyObject *o, const char *name, PyObject *v)
{
    if (v == NULL) return -1;
    int r = PyObject_SetAttrString(o, name, v);
    Py_DECREF(v);
    return r;
}

/* The server's and answer's state after the Sensors C answered; the link's counters. */
static int serving_sync(serving_t *g, tally_t *t)
{
    int r = flush(t);
    if (g->stepped > 0) {
        if (add_attr(g->report, "sensors", g->stepped) < 0) r = -1;
        if (g->watching) {
            if (set_attr_obj(g->server, "last_sensors_t", PyFloat_FromDouble(g->last_t)) < 0) r = -1;
            if (PyObject_SetAttrString(g->server, "tripped", Py_False) < 0) r = -1;
        }
        g->stepped = 0;
    }
    if (g->last_seq >= 0) { /* answer.last: the Drive of C's last step (RepeatAnswer's own rule) */
        PyObject *seq = PyLong_FromLong(g->last_seq);
        PyObject *drive = seq == NULL ? NULL : g->api->drive(g->api_core, seq);
        Py_XDECREF(seq);
        if (set_attr_obj(g->answer, "last", drive) < 0) r = -1;
        g->last_seq = -1;
    }
    return r;
}

/* answer.last after a step that raised: the Drive C last sent, as the Python loop keeps the one it
 * sent (the core's state may have moved before the raise: S2 applied, the carried fraction). */
static int keep_sent(serving_t *g)
{
    if (g->last_seq < 0) return 0; /* answer.last was written back since: it is the sent one */
    PyObject *seq = PyLong_FromLong(g->last_seq);
    PyObject *drive = seq == NULL ? NULL : drive_of(g->drive_type, seq, &g->sent);
    Py_XDECREF(seq);
    g->last_seq = -1;
    return set_attr_obj(g->answer, "last", drive);
}

/* answer.last's seq: -1 when None */
static int answer_last_seq(serving_t *g, long *out)
{
    PyObject *last = PyObject_GetAttrString(g->answer, "last");
    if (last == NULL) return -1;
    *out = -1;
    if (last != Py_None) {
        PyObject *seq = PySequence_GetItem(last, 0);
        *out = seq == NULL ? -1 : PyLong_AsLong(seq);
        Py_XDECREF(seq);
    }
    Py_DECREF(last);
    return PyErr_Occurred() ? -1 : 0;
}

static void sensors_to_c(const hbp_sensors_t *m, hb_csensors_t *in)
{
    in->seq = m->seq;
    in->inputs = m->inputs;
    in->encoder = m->encoder;
    in->n_adc = m->n_adc < HB_SPAN_MAX_ADC ? m->n_adc : HB_SPAN_MAX_ADC;
    for (int i = 0; i < in->n_adc; i++) in->adc[i] = m->adc[i];
    in->n_edges = m->n_edges < HB_SPAN_MAX_EDGES ? m->n_edges : HB_SPAN_MAX_EDGES;
    for (int i = 0; i < in->n_edges; i++) {
        in->edge_t[i] = m->edges[i].time_100ns;
        in->edge_lines[i] = m->edges[i].lines;
    }
}

/* A Drive in its wire ranges (encode_frame's checks): its frame in wire, else 0. */
static hbp_u8 drive_wire(long seq, const hb_cdrive_t *d, hbp_u8 *wire)
{
    if (d->duty_a < 0 || d->duty_a > 0xFFFF || d->duty_b < 0 || d->duty_b > 0xFFFF || d->duty_c < 0
        || d->duty_c > 0xFFFF || d->output_mode < 0 || d->output_mode > 3 || d->state < 0 || d->state > 7
        || d->sector < 0 || d->sector > 7 || d->fault < 0 || d->fault > 63 || d->n_tel > (int)HBP_MAX_TELEMETRY)
        return 0u;
    hbp_drive_t m;
    m.seq = (hbp_u8)seq;
    m.duty_a = (uint16_t)d->duty_a; m.duty_b = (uint16_t)d->duty_b; m.duty_c = (uint16_t)d->duty_c;
    m.output_mode = (hbp_u8)d->output_mode; m.state = (hbp_u8)d->state; m.sector = (hbp_u8)d->sector;
    m.direction_ccw = d->direction_ccw != 0; m.required_ccw = d->required_ccw != 0; m.fault = (hbp_u8)d->fault;
    m.n_telemetry = (hbp_u8)d->n_tel;
    for (int i = 0; i < d->n_tel; i++) {
        if (d->tel[i] < -32768 || d->tel[i] > 32767) return 0u;
        m.telemetry[i] = (int16_t)d->tel[i];
    }
    hbp_u8 frame[HBP_MAX_WIRE + 2];
    hbp_u8 len = hbp_pack_drive(&m, frame);
    return len ? hbp_encode_frame(frame, len, wire) : 0u;
}

/* The Python server's answer to an exception while handling ``in`` (handler_fault); -1 when it
 * re-raises (LinkClosed). */
static int handler_fault(serving_t *g, const hb_csensors_t *in, PyObject *sensors_type)
{
    PyObject *et, *ev, *tb;
    PyErr_Fetch(&et, &ev, &tb);
    PyErr_NormalizeException(&et, &ev, &tb);
    if (ev == NULL) { PyErr_Restore(et, ev, tb); return -1; }
    if (tb != NULL) PyException_SetTraceback(ev, tb);
    PyObject *sensors = sensors_object(sensors_type, in);
    PyObject *r = sensors == NULL ? NULL : PyObject_CallMethod(g->server, "handler_fault", "OO", sensors, ev);
    Py_XDECREF(sensors);
    Py_XDECREF(et); Py_XDECREF(ev); Py_XDECREF(tb);
    if (r == NULL) return -1;
    Py_DECREF(r);
    return 0;
}

/* The Drive of a Sensors C stepped, sent as Link.send sends it; a Drive outside its wire ranges, or
 * what a short write left, through the Link in Python (a failure other than LinkClosed goes to the
 * server's handler_fault, as in its loop). 0, or -1 with an exception (the server's loop ends). */
static int send_drive(serving_t *g, tally_t *t, PyObject *link, int fd, const hb_csensors_t *in,
                      const hb_cdrive_t *d, PyObject *sensors_type)
{
    hbp_u8 wire[HBP_MAX_WIRE + 2];
    hbp_u8 n_wire = drive_wire((long)in->seq, d, wire);
    ssize_t w = n_wire ? write(fd, wire, n_wire) : 0;
    if (w < 0) w = 0;
    if (n_wire && w == (ssize_t)n_wire) {
        t->frames_tx += 1;
        t->bytes_tx += n_wire;
        return 0;
    }
    if (serving_sync(g, t) < 0) return -1;
    PyObject *drive = PyObject_GetAttrString(g->answer, "last"); /* the Drive object, as the server sends it */
    PyObject *r = NULL;
    if (drive != NULL && n_wire == 0u) r = PyObject_CallMethod(link, "send", "O", drive);
    else if (drive != NULL) { /* Link.send's own continuation after a short write */
        PyObject *timeout = PyObject_GetAttrString(link, "timeout_s");
        PyObject *rest = PyBytes_FromStringAndSize((const char *)wire + w, (Py_ssize_t)n_wire - w);
        r = (timeout == NULL || rest == NULL) ? NULL : PyObject_CallMethod(link, "_write", "OO", rest, timeout);
        Py_XDECREF(timeout);
        Py_XDECREF(rest);
        if (r != NULL && (add_attr(link, "frames_tx", 1) < 0 || add_attr(link, "bytes_tx", n_wire) < 0)) Py_CLEAR(r);
    }
    Py_XDECREF(drive);
    if (r != NULL) {
        Py_DECREF(r);
        return 0;
    }
    PyObject *errors = PyImport_ImportModule("hilbench.errors");
    PyObject *link_closed = errors == NULL ? NULL : PyObject_GetAttrString(errors, "LinkClosed");
    Py_XDECREF(errors);
    int is_closed = link_closed == NULL || PyErr_ExceptionMatches(link_closed);
    Py_XDECREF(link_closed);
    if (is_closed || !PyErr_ExceptionMatches(PyExc_Exception)) return -1; /* LinkClosed: the server's end */
    return handler_fault(g, in, sensors_type);
}

/* How a serve loop waits and steps: lockstep (a fixed wait, each Sensors one agreed period: the
 * core's step) or real time (_Server._realtime: waiting at most until the watchdog is due, each new
 * Sensors the wall time since the last one: the core's advance). */
typedef struct {
    int realtime;
    double wait_s;                        /* lockstep: recv's timeout */
    double poll_s, watchdog_s, period_us; /* real time: _POLL_S, the agreed watchdog, the first span */
    int tripped;                          /* real time: the server's `tripped` (its watchdog fired), read from it */
} serve_mode_t;

/* The wait before the next read: lockstep's fixed one, or real time's _Server.realtime_wait. */
static double serve_wait(const serve_mode_t *mode, const serving_t *g, double now)
{
    if (!mode->realtime) return mode->wait_s;
    double wait = mode->poll_s;
    if (mode->watchdog_s > 0 && g->last_t >= 0 && !mode->tripped) {
        double left = g->last_t + mode->watchdog_s - now;
        wait = left < 0 ? 0 : left < wait ? left : wait;
    }
    return wait;
}

/* One new Sensors through the core: lockstep's step, or real time's advance by the wall time since
 * the last one (_Server._new_period); 0 or -1 with the model's exception. */
static int serve_step(serve_mode_t *mode, serving_t *g, const hb_csensors_t *in, hb_cdrive_t *d)
{
    if (!mode->realtime) {
        if (g->watching) g->last_t = monotonic_s();
        return g->api->step(g->api_core, in, d);
    }
    double now = monotonic_s();
    double span_us = g->last_t >= 0 ? (now - g->last_t) * 1e6 : mode->period_us;
    g->last_t = now;
    mode->tripped = 0;
    return g->api->advance(g->api_core, span_us, in, d);
}

/* The serve loop of both modes (serve_lockstep, serve_realtime): the first message C did not answer
 * (None: nothing within the wait), as the server's recv gives it. */
static PyObject *serve_loop(PyObject *server, PyObject *link, int fd, PyObject *capsule, PyObject *core, int watching,
                            PyObject *drive_type, PyObject *sensors_type, serve_mode_t *mode)
{
    const hb_target_api_t *api = PyCapsule_GetPointer(capsule, HB_TARGET_API);
    if (api == NULL) return NULL;
    if (mode->realtime && api->advance == NULL) {
        PyErr_SetString(PyExc_TypeError, "serve_realtime: the target's core has no C advance");
        return NULL;
    }
    serving_t g = {server, NULL, NULL, core, drive_type, api, watching, 0, -1, -1.0};
    tally_t t;
    memset(&t, 0, sizeof t);
    t.link = link;
    t.key = sensors_type;
    t.fd = fd;
    PyObject *out = NULL;
    unsigned char *rx = NULL; /* this call's own read buffer: the GIL may change hands in the loop */
    g.answer = PyObject_GetAttrString(server, "answer");
    g.report = g.answer == NULL ? NULL : PyObject_GetAttrString(server, "report");
    if (g.report == NULL) goto done;
    if (mode->realtime) { /* the last Sensors' time and whether the watchdog fired, as the Python loop left them */
        PyObject *last = PyObject_GetAttrString(server, "last_sensors_t");
        if (last == NULL) goto done;
        g.last_t = last == Py_None ? -1.0 : PyFloat_AsDouble(last);
        Py_DECREF(last);
        if (PyErr_Occurred()) goto done;
        PyObject *tripped = PyObject_GetAttrString(server, "tripped");
        if (tripped == NULL) goto done;
        mode->tripped = PyObject_IsTrue(tripped);
        Py_DECREF(tripped);
        if (mode->tripped < 0) goto done;
    }
    rx = PyMem_Malloc(READ_CHUNK);
    if (rx == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    long repeat_seq = -2; /* answer.last's seq, looked at again after any Python call */
    for (;;) {
        /* Ctrl-C between periods, as the Python loop sees it (a signal that lands while C steps or
         * sends interrupts no poll: the next one finds data) */
        if (PyErr_CheckSignals() < 0) goto done;
        double t0 = monotonic_s();
        double wait_s = serve_wait(mode, &g, t0);
        if (!t.synced) {
            int fast = link_fast(&t);
            if (fast < 0 || (fast && load_next_seq(&t) < 0)) goto done;
            if (!fast) { /* the reference's recv, whole */
                out = PyObject_CallMethod(link, "recv_or_none", "d", wait_s);
                goto done;
            }
            t.synced = 1;
            if (answer_last_seq(&g, &repeat_seq) < 0) goto done;
        }
        int ready = poll_in(fd, wait_s > 0 ? (int)ceil(wait_s * 1000.0) : 0, t0);
        if (ready < 0 && PyErr_Occurred()) goto done;
        ssize_t n = ready > 0 ? read(fd, rx, READ_CHUNK) : -1;
        hbp_sensors_t m;
        if (!(n > 0 && one_message(rx, n, HBP_MSG_SENSORS, &hbp_layout_sensors, &m) && (long)m.seq != repeat_seq)) {
            PyObject *data = n >= 0 ? PyBytes_FromStringAndSize((const char *)rx, n) : Py_NewRef(Py_None);
            if (data == NULL) goto done;
            if (serving_sync(&g, &t) < 0) { /* the reference takes it from here */
                Py_DECREF(data);
                goto done;
            }
            out = PyObject_CallMethod(link, "_took", "Odd", data, t0 + wait_s, wait_s);
            Py_DECREF(data);
            goto done;
        }
        tally_frame(&t, n, m.seq); /* Link._take_read's fast path */
        g.stepped += 1;
        hb_csensors_t in;
        hb_cdrive_t d;
        sensors_to_c(&m, &in);
        if (serve_step(mode, &g, &in, &d) < 0) { /* the model raised: the server answers BAD_REQUEST */
            if (!PyErr_ExceptionMatches(PyExc_Exception)) goto done; /* KeyboardInterrupt, SystemExit: out */
            PyObject *et, *ev, *tb;
            PyErr_Fetch(&et, &ev, &tb);
            if (keep_sent(&g) < 0 || serving_sync(&g, &t) < 0) { /* that error wins: out */
                Py_XDECREF(et); Py_XDECREF(ev); Py_XDECREF(tb);
                goto done;
            }
            PyErr_Restore(et, ev, tb);
            if (handler_fault(&g, &in, sensors_type) < 0) goto done;
            continue;
        }
        repeat_seq = g.last_seq = m.seq;
        g.sent = d;
        if (send_drive(&g, &t, link, fd, &in, &d, sensors_type) < 0) goto done;
    }
done:
    if (out == NULL) {
        PyObject *et, *ev, *tb;
        PyErr_Fetch(&et, &ev, &tb);
        if (g.report != NULL) serving_sync(&g, &t);
        PyErr_Clear();
        PyErr_Restore(et, ev, tb);
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_RuntimeError, "serve loop: lost its error");
    } else if (g.report != NULL && serving_sync(&g, &t) < 0) {
        Py_CLEAR(out);
    }
    PyMem_Free(rx);
    Py_XDECREF(g.answer);
    Py_XDECREF(g.report);
    return out;
}

/* serve_lockstep(server, link, fd, api, core, wait_s, watching, drive_type, sensors_type) -> the
 * first message C did not answer (None: nothing within wait_s), as the server's recv(wait) gives it. */
static PyObject *serve_lockstep(PyObject *mod, PyObject *args)
{
    (void)mod;
    PyObject *server, *link, *capsule, *core, *drive_type, *sensors_type;
    int fd, watching;
    serve_mode_t mode = {0, 0.0, 0.0, 0.0, 0.0, 0};
    if (!PyArg_ParseTuple(args, "OOiOOdpOO:serve_lockstep", &server, &link, &fd, &capsule, &core, &mode.wait_s,
                          &watching, &drive_type, &sensors_type))
        return NULL;
    return serve_loop(server, link, fd, capsule, core, watching, drive_type, sensors_type, &mode);
}

/* serve_realtime(server, link, fd, api, core, poll_s, watchdog_s, period_us, drive_type, sensors_type)
 * -> the first message C did not answer (None: nothing before the watchdog is due or within poll_s),
 * as _Server._realtime's recv(realtime_wait()) gives it; the server's last_sensors_t and tripped read
 * from it, and they, its report and answer written back as _new_period leaves them. */
static PyObject *serve_realtime(PyObject *mod, PyObject *args)
{
    (void)mod;
    PyObject *server, *link, *capsule, *core, *drive_type, *sensors_type;
    int fd;
    serve_mode_t mode = {1, 0.0, 0.0, 0.0, 0.0, 0};
    if (!PyArg_ParseTuple(args, "OOiOOdddOO:serve_realtime", &server, &link, &fd, &capsule, &core, &mode.poll_s,
                          &mode.watchdog_s, &mode.period_us, &drive_type, &sensors_type))
        return NULL;
    return serve_loop(server, link, fd, capsule, core, 1, drive_type, sensors_type, &mode);
}

/* ---------------------------------------------------------------- the type and the module */

static int Remote_init(Remote *s, PyObject *args, PyObject *kwds)
{
    static char *kw[] = {"target", "link", "step", "drive_type", "sensors_type", "fd", "retry_s", NULL};
    PyObject *target, *link, *step, *drive_type, *sensors_type;
    int fd;
    double retry_s;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OOOOOid:Remote", kw, &target, &link, &step, &drive_type,
                                     &sensors_type, &fd, &retry_s))
        return -1;
    if (fd < 0 || !(retry_s >= 0.0) || retry_s > 1e6) {
        PyObject *retry = PyFloat_FromDouble(retry_s); /* (PyErr_Format has no %g) */
        if (retry != NULL) {
            PyErr_Format(PyExc_ValueError, "Remote: fd %d, retry_s %R", fd, retry);
            Py_DECREF(retry);
        }
        return -1;
    }
    Py_XSETREF(s->target, Py_NewRef(target));
    Py_XSETREF(s->link, Py_NewRef(link));
    Py_XSETREF(s->step, Py_NewRef(step));
    Py_XSETREF(s->drive_type, Py_NewRef(drive_type));
    Py_XSETREF(s->sensors_type, Py_NewRef(sensors_type));
    Py_CLEAR(s->last_drive);
    s->fd = fd;
    s->retry_s = retry_s;
    s->retry_ms = retry_s > 0 ? (int)ceil(retry_s * 1000.0) : 0; /* select.poll's rounding: up */
    memset(&s->t, 0, sizeof s->t);
    s->c_steps = 0;
    s->t.link = s->link;
    s->t.key = s->drive_type;
    s->t.fd = fd;
    memset(&s->last, 0, sizeof s->last);
    return 0;
}

static int Remote_traverse(Remote *s, visitproc visit, void *arg)
{
    Py_VISIT(s->target);
    Py_VISIT(s->link);
    Py_VISIT(s->step);
    Py_VISIT(s->drive_type);
    Py_VISIT(s->sensors_type);
    Py_VISIT(s->last_drive);
    return 0;
}

static int Remote_clear(Remote *s)
{
    Py_CLEAR(s->target);
    Py_CLEAR(s->link);
    Py_CLEAR(s->step);
    Py_CLEAR(s->drive_type);
    Py_CLEAR(s->sensors_type);
    Py_CLEAR(s->last_drive);
    return 0;
}

static void Remote_dealloc(Remote *s)
{
    PyObject_GC_UnTrack(s);
    Remote_clear(s);
    Py_TYPE(s)->tp_free((PyObject *)s);
}

static PyMemberDef Remote_members[] = {
    {"step", T_OBJECT, offsetof(Remote, step), READONLY, "the Python step this one stands for (RemoteTarget.step)"},
    {"c_steps", T_LONGLONG, offsetof(Remote, c_steps), READONLY, "steps answered wholly in C (no Python call)"},
    {NULL, 0, 0, 0, NULL},
};

static PyTypeObject RemoteType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "hilbench.targets._remotestep.Remote",
    .tp_basicsize = sizeof(Remote),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC,
    .tp_doc = "Remote(target, link, step, drive_type, sensors_type, fd, retry_s): RemoteTarget.step in C "
              "for the session's C span (SPAN_API).",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Remote_init,
    .tp_dealloc = (destructor)Remote_dealloc,
    .tp_traverse = (traverseproc)Remote_traverse,
    .tp_clear = (inquiry)Remote_clear,
    .tp_members = Remote_members,
};

/* encode_sensors(seq, inputs, edges, encoder, adc) -> the wire bytes, or None outside the wire ranges
 * (the Python encoder raises there): for the tests, which compare it with encode_frame. */
static PyObject *encode_sensors(PyObject *mod, PyObject *args)
{
    (void)mod;
    long long seq;
    long inputs, encoder;
    PyObject *edges, *adc;
    if (!PyArg_ParseTuple(args, "LlOlO:encode_sensors", &seq, &inputs, &edges, &encoder, &adc)) return NULL;
    hb_csensors_t in;
    memset(&in, 0, sizeof in);
    in.seq = seq;
    in.inputs = inputs;
    in.encoder = encoder;
    Py_ssize_t ne = PySequence_Length(edges), na = PySequence_Length(adc);
    if (ne < 0 || na < 0) return NULL;
    if (ne > HB_SPAN_MAX_EDGES || na > HB_SPAN_MAX_ADC) Py_RETURN_NONE;
    in.n_edges = (int)ne;
    in.n_adc = (int)na;
    for (Py_ssize_t i = 0; i < ne; i++) {
        PyObject *e = PySequence_GetItem(edges, i);
        if (e == NULL) return NULL;
        int ok = PyArg_ParseTuple(e, "ll", &in.edge_t[i], &in.edge_lines[i]);
        Py_DECREF(e);
        if (!ok) return NULL;
    }
    for (Py_ssize_t i = 0; i < na; i++) {
        PyObject *a = PySequence_GetItem(adc, i);
        if (a == NULL) return NULL;
        in.adc[i] = PyLong_AsLong(a);
        Py_DECREF(a);
        if (in.adc[i] == -1 && PyErr_Occurred()) return NULL;
    }
    hbp_sensors_t m;
    hbp_u8 frame[HBP_MAX_WIRE + 2], wire[HBP_MAX_WIRE + 2];
    if (!pack_sensors(&in, &m)) Py_RETURN_NONE;
    hbp_u8 len = hbp_pack_sensors(&m, frame);
    hbp_u8 n = len ? hbp_encode_frame(frame, len, wire) : 0u;
    if (n == 0u) Py_RETURN_NONE;
    return PyBytes_FromStringAndSize((const char *)wire, n);
}

/* decode_drive(data) -> (seq, duty_a, duty_b, duty_c, output_mode, state, sector, ccw, required_ccw, fault,
 * telemetry) when data (one read, delimiter included) is exactly one good Drive frame, else None:
 * for the tests, which compare it with decode_frame. */
static PyObject *decode_drive(PyObject *mod, PyObject *arg)
{
    (void)mod;
    char *data;
    Py_ssize_t n;
    if (PyBytes_AsStringAndSize(arg, &data, &n) < 0) return NULL;
    hbp_drive_t d;
    if (!one_drive((const unsigned char *)data, n, &d)) Py_RETURN_NONE;
    hb_cdrive_t c;
    drive_to_c(&d, &c);
    PyObject *tel = PyTuple_New(c.n_tel);
    if (tel == NULL) return NULL;
    for (int i = 0; i < c.n_tel; i++) {
        PyObject *v = PyLong_FromLong(c.tel[i]);
        if (v == NULL) { Py_DECREF(tel); return NULL; }
        PyTuple_SET_ITEM(tel, i, v);
    }
    return Py_BuildValue("(illlllliiiN)", d.seq, c.duty_a, c.duty_b, c.duty_c, c.output_mode, c.state, c.sector,
                         (int)c.direction_ccw, (int)c.required_ccw, c.fault, tel);
}

/* decode_sensors(data) -> (seq, inputs, edges, encoder, adc) when data is exactly one good Sensors
 * frame, else None: for the tests, which compare it with decode_frame. */
static PyObject *decode_sensors(PyObject *mod, PyObject *arg)
{
    (void)mod;
    char *data;
    Py_ssize_t n;
    if (PyBytes_AsStringAndSize(arg, &data, &n) < 0) return NULL;
    hbp_sensors_t m;
    if (!one_message((const unsigned char *)data, n, HBP_MSG_SENSORS, &hbp_layout_sensors, &m)) Py_RETURN_NONE;
    PyObject *edges = PyTuple_New(m.n_edges), *adc = PyTuple_New(m.n_adc);
    if (edges == NULL || adc == NULL) { Py_XDECREF(edges); Py_XDECREF(adc); return NULL; }
    for (int i = 0; i < m.n_edges + m.n_adc; i++) {
        PyObject *v = i < m.n_edges ? Py_BuildValue("(ii)", m.edges[i].time_100ns, m.edges[i].lines)
                                    : PyLong_FromLong(m.adc[i - m.n_edges]);
        if (v == NULL) { Py_DECREF(edges); Py_DECREF(adc); return NULL; }
        if (i < m.n_edges) PyTuple_SET_ITEM(edges, i, v);
        else PyTuple_SET_ITEM(adc, i - m.n_edges, v);
    }
    return Py_BuildValue("(iiNiN)", m.seq, m.inputs, edges, m.encoder, adc);
}

static PyMethodDef module_methods[] = {
    {"encode_sensors", encode_sensors, METH_VARARGS, "encode_sensors(seq, inputs, edges, encoder, adc) -> bytes or None"},
    {"decode_drive", decode_drive, METH_O, "decode_drive(data) -> the Drive's fields or None"},
    {"decode_sensors", decode_sensors, METH_O, "decode_sensors(data) -> the Sensors' fields or None"},
    {"serve_realtime", serve_realtime, METH_VARARGS,
     "serve_realtime(server, link, fd, api, core, poll_s, watchdog_s, period_us, drive_type, sensors_type) "
     "-> the first message C did not answer: the real-time serve loop's common case in C."},
    {"serve_lockstep", serve_lockstep, METH_VARARGS,
     "serve_lockstep(server, link, fd, api, core, wait_s, watching, drive_type, sensors_type) -> the first message "
     "not answered in C, or None"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moduledef = {
    PyModuleDef_HEAD_INIT, "_remotestep",
    "The process paths' lockstep exchange in C: RemoteTarget.step for the session's C span, serve()'s loop (optional).", -1,
    module_methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__remotestep(void)
{
    PyObject *m = hb_module(&moduledef, &RemoteType, "Remote");
    return hb_add_span_api(m, &span_api, HB_TARGET_API);
}
