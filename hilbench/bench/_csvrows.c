/* CSV rows in C, straight from a recording's raw rows: the accelerator of Recorder._format_csv
 * (hilbench/bench/recorder.py), which formats the float64 columns `RowLayout.to_columns` makes.
 *
 * Each column is made of its raw field as to_column makes it (_rawfields.h, shared with the NPZ
 * archive's writer) and written as Python's printf-style `%` writes it: "%d" (int(x), truncated)
 * and "%.Nf" (N <= 9: the exact decimal of the binary value rounded half to even, what Python's
 * correctly rounded dtoa gives, computed in 128-bit integers; values from 2^63 on are integers,
 * written exactly from a small base-10^9 number). A NaN or an infinity is "nan", "inf" or "-inf"
 * in both (a "%d" column of NaN, which `%` refuses, too: the reference writes the same). Other
 * formats are the reference's alone (`RowWriter` refuses them with ValueError). No cell calls
 * into Python, so the formatting runs without the GIL.
 *
 * format_rows(rows, itemsize, columns) -> str: the rows of a bytes-like (whole rows) as CSV lines.
 * RowWriter(fd, itemsize, columns, max_rows): the same text written to fd (a duplicate of it, the
 * writer's own) by a thread of its own (every signal blocked in it): `submit(rows, events)` hands over a copy of whole raw rows and the
 * event lines that go before row i ((i, bytes), i up to the number of rows: after the last); it
 * waits, the GIL released, while more than max_rows rows wait to be written. `drain()` waits until
 * every row handed over is written (a signal's exception raised meanwhile is raised after it: no
 * row handed over is dropped by Ctrl-C); `close()` drains and joins the thread; `abandon()` joins
 * it dropping what waits. A failed write stops the thread: the next call raises OSError with its
 * errno. tests/test_csv_rows.py checks the text against `%` over edge values and the recordings
 * against the reference, byte for byte.
 */
#define PY_SSIZE_T_CLEAN
#ifndef _GNU_SOURCE
#define _GNU_SOURCE /* SCHED_BATCH */
#endif
#include <Python.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "_rawfields.h"
#include "_writerthread.h"

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "the raw rows are little-endian: a little-endian host only"
#endif

#define MAX_COLUMNS 1024
#define CELL_MAX 330 /* the longest cell: "-" + 309 digits of DBL_MAX + "." + 9 zeros */

typedef struct {
    Py_ssize_t field; /* the field's byte offset in a row */
    char code;        /* its struct code */
    double scale;     /* column = field x scale (1: the field as it is) */
    double modulo;    /* > 0: wrapped into [0, modulo) as numpy.mod wraps it */
    char conv;        /* 'd' or 'f' */
    int prec;         /* N of "%.Nf" */
} column_t;

/* ---- cells ------------------------------------------------------------------------------------ */
static const char PAIRS[201] = "00010203040506070809101112131415161718192021222324252627282930313233343536373839"
                               "40414243444546474849505152535455565758596061626364656667686970717273747576777879"
                               "8081828384858687888990919293949596979899";

static const uint64_t POW10_64[20] = {1ULL, 10ULL, 100ULL, 1000ULL, 10000ULL, 100000ULL, 1000000ULL, 10000000ULL,
                                       100000000ULL, 1000000000ULL, 10000000000ULL, 100000000000ULL,
                                       1000000000000ULL, 10000000000000ULL, 100000000000000ULL,
                                       1000000000000000ULL, 10000000000000000ULL, 100000000000000000ULL,
                                       1000000000000000000ULL, 10000000000000000000ULL};

/* v's digits written right-aligned to end at `end`, exactly `n` of them (zeros before) */
static void digits_before(char *end, uint64_t v, int n)
{
    char *p = end, *first = end - n;
    while (v >= 100) {
        unsigned r = (unsigned)(v % 100u);
        v /= 100u;
        p -= 2;
        memcpy(p, PAIRS + 2 * r, 2);
    }
    if (v >= 10) {
        p -= 2;
        memcpy(p, PAIRS + 2 * v, 2);
    } else if (p > first || v) {
        *--p = (char)('0' + (int)v);
    }
    while (p > first) *--p = '0';
}

/* the number of decimal digits of v (1 for 0) */
static int n_digits(uint64_t v)
{
    int n = 1;
    while (n < 20 && v >= POW10_64[n]) n++;
    return n;
}

/* v's decimal digits at out; their count */
static int put_u64(char *out, uint64_t v)
{
    int n = n_digits(v);
    digits_before(out + n, v, n);
    return n;
}

/* a finite double's exact value as m * 2^e (m below 2^53; m = 0 for a zero) */
static uint64_t binary(double x, int *e)
{
    uint64_t bits;
    memcpy(&bits, &x, 8);
    int biased = (int)((bits >> 52) & 0x7FF);
    uint64_t m = bits & ((1ULL << 52) - 1);
    if (biased == 0) { /* a subnormal (or a zero) */
        *e = -1074;
        return m;
    }
    *e = biased - 1075;
    return m | (1ULL << 52);
}

/* q / 10^prec and its remainder, prec <= 9 (constant divisors: the compiler multiplies) */
static uint64_t div_pow10(uint64_t q, int prec, uint64_t *rem)
{
    uint64_t d;
    switch (prec) {
    case 0: *rem = 0; return q;
    case 1: d = q / 10u; *rem = q - d * 10u; return d;
    case 2: d = q / 100u; *rem = q - d * 100u; return d;
    case 3: d = q / 1000u; *rem = q - d * 1000u; return d;
    case 4: d = q / 10000u; *rem = q - d * 10000u; return d;
    case 5: d = q / 100000u; *rem = q - d * 100000u; return d;
    case 6: d = q / 1000000u; *rem = q - d * 1000000u; return d;
    case 7: d = q / 10000000u; *rem = q - d * 10000000u; return d;
    case 8: d = q / 100000000u; *rem = q - d * 100000000u; return d;
    default: d = q / 1000000000u; *rem = q - d * 1000000000u; return d;
    }
}

/* The exact decimal digits of |x| >= 2^53 (an integer: m * 2^e, e >= 0) at out; their count. */
static int put_huge(char *out, double x)
{
    int e;
    uint64_t m = binary(x, &e);
    uint32_t limb[40]; /* base 10^9, least significant first: 2^1024 < 10^309 fits in 35 */
    int n = 0;
    while (m) {
        limb[n++] = (uint32_t)(m % 1000000000u);
        m /= 1000000000u;
    }
    while (e > 0) {
        int k = e > 29 ? 29 : e; /* limb x 2^29 + carry stays below 2^64 */
        uint64_t carry = 0;
        for (int i = 0; i < n; i++) {
            uint64_t v = ((uint64_t)limb[i] << k) + carry;
            limb[i] = (uint32_t)(v % 1000000000u);
            carry = v / 1000000000u;
        }
        while (carry) {
            limb[n++] = (uint32_t)(carry % 1000000000u);
            carry /= 1000000000u;
        }
        e -= k;
    }
    int len = put_u64(out, limb[n - 1]);
    for (int i = n - 2; i >= 0; i--, len += 9) digits_before(out + len + 9, limb[i], 9);
    return len;
}

/* "%.Nf" of a finite |x| < 2^63, N <= 9: x = m * 2^e exactly, x * 10^N rounded half to even in
 * 128-bit integers, the point put in. Returns the length written. */
static int fixed(char *out, double x, int prec)
{
    int len = 0;
    if (signbit(x)) out[len++] = '-';
    int e;
    uint64_t m = binary(x, &e);
    unsigned __int128 p = (unsigned __int128)m * POW10_64[prec];
    unsigned __int128 q;
    if (m == 0) {
        q = 0;
    } else if (e >= 0) {
        q = p << e; /* |x| < 2^63 and 10^9 < 2^30: below 2^93 */
    } else {
        int s = -e;
        if (s >= 100) { /* p < 2^83: p / 2^s < 1/2, rounds to 0 */
            q = 0;
        } else {
            q = p >> s;
            unsigned __int128 r = p - (q << s), half = (unsigned __int128)1 << (s - 1);
            if (r > half || (r == half && (q & 1u))) q += 1;
        }
    }
    uint64_t frac;
    if (q >> 64) { /* rare: |x| * 10^N beyond 2^64, a 128-bit division a digit */
        unsigned __int128 whole = q / POW10_64[prec];
        frac = (uint64_t)(q - whole * POW10_64[prec]);
        char tmp[48];
        int nd = 0;
        while (whole) {
            tmp[nd++] = (char)('0' + (int)(whole % 10u));
            whole /= 10u;
        }
        while (nd) out[len++] = tmp[--nd];
    } else {
        len += put_u64(out + len, div_pow10((uint64_t)q, prec, &frac));
    }
    if (prec) {
        out[len++] = '.';
        digits_before(out + len + prec, frac, prec);
        len += prec;
    }
    return len;
}

/* One cell: its length (at most CELL_MAX). */
static int cell(char *out, double x, const column_t *col)
{
    if (isnan(x)) {
        memcpy(out, "nan", 3);
        return 3;
    }
    if (isinf(x)) {
        if (x < 0) {
            memcpy(out, "-inf", 4);
            return 4;
        }
        memcpy(out, "inf", 3);
        return 3;
    }
    int len = 0;
    if (col->conv == 'd') {
        if (fabs(x) < 9.2e18) {
            long long v = (long long)x; /* int(x): truncated toward zero */
            if (v < 0) out[len++] = '-';
            return len + put_u64(out + len, v < 0 ? 0ULL - (unsigned long long)v : (unsigned long long)v);
        }
        if (x < 0) out[len++] = '-';
        return len + put_huge(out + len, x);
    }
    if (fabs(x) < 9.2e18) return fixed(out, x, col->prec);
    if (x < 0) out[len++] = '-';
    len += put_huge(out + len, x);
    if (col->prec) {
        out[len++] = '.';
        memset(out + len, '0', (size_t)col->prec);
        len += col->prec;
    }
    return len;
}

/* One row's line (ended by "\n") at out; its length (at most n_cols * (CELL_MAX + 1)). */
static size_t format_row(char *out, const unsigned char *row, const column_t *cols, int n_cols)
{
    size_t len = 0;
    for (int c = 0; c < n_cols; c++) {
        const column_t *col = &cols[c];
        double x = field_value(row + col->field, col->code);
        if (col->scale != 1.0) x = x * col->scale;
        if (col->modulo > 0.0) x = np_remainder(x, col->modulo);
        len += (size_t)cell(out + len, x, col);
        out[len++] = ',';
    }
    out[len - 1] = '\n';
    return len;
}

/* ---- the columns a caller describes ------------------------------------------------------------- */
/* "%d" or "%.Nf" (N <= 9): 1; another format: 0 */
static int parse_format(const char *s, column_t *out)
{
    if (strcmp(s, "%d") == 0) {
        out->conv = 'd';
        out->prec = 0;
        return 1;
    }
    if (s[0] == '%' && s[1] == '.' && s[2] >= '0' && s[2] <= '9' && s[3] == 'f' && s[4] == '\0') {
        out->conv = 'f';
        out->prec = s[2] - '0';
        return 1;
    }
    return 0;
}

/* columns: a sequence of (field offset, struct code, scale, modulo or 0, format); the count, or -1
 * with an exception (ValueError: a format or a field it does not take). *cols is PyMem_Malloc'd. */
static int parse_columns(PyObject *columns, Py_ssize_t itemsize, column_t **cols)
{
    *cols = NULL;
    PyObject *seq = PySequence_Fast(columns, "columns must be a sequence");
    if (seq == NULL) return -1;
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    if (n < 1 || n > MAX_COLUMNS || itemsize < 1) {
        Py_DECREF(seq);
        PyErr_Format(PyExc_ValueError, "%zd columns of %zd-byte rows (1..%d columns, rows of a byte or more)", n,
                     itemsize, MAX_COLUMNS);
        return -1;
    }
    column_t *out = PyMem_Calloc((size_t)n, sizeof(column_t));
    if (out == NULL) {
        Py_DECREF(seq);
        PyErr_NoMemory();
        return -1;
    }
    for (Py_ssize_t j = 0; j < n; j++) {
        const char *code, *fmt;
        column_t *col = &out[j];
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(seq, j), "nsdds:column", &col->field, &code, &col->scale,
                              &col->modulo, &fmt))
            goto bad;
        int width = field_width(code);
        if (width == 0 || col->field < 0 || col->field + width > itemsize) {
            PyErr_Format(PyExc_ValueError, "column %zd: a field %s at %zd of a %zd-byte row", j, code, col->field,
                         itemsize);
            goto bad;
        }
        col->code = code[0];
        if (!parse_format(fmt, col)) {
            PyErr_Format(PyExc_ValueError, "column %zd: format %.20s is the reference's (C takes %%d and %%.Nf, N <= 9)",
                         j, fmt);
            goto bad;
        }
    }
    Py_DECREF(seq);
    *cols = out;
    return (int)n;
bad:
    Py_DECREF(seq);
    PyMem_Free(out);
    return -1;
}

static PyObject *format_rows(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "format_rows(rows, itemsize, columns)");
        return NULL;
    }
    Py_ssize_t itemsize = PyLong_AsSsize_t(args[1]);
    if (itemsize == -1 && PyErr_Occurred()) return NULL;
    column_t *cols;
    int n_cols = parse_columns(args[2], itemsize, &cols);
    if (n_cols < 0) return NULL;
    Py_buffer view;
    if (PyObject_GetBuffer(args[0], &view, PyBUF_SIMPLE) < 0) {
        PyMem_Free(cols);
        return NULL;
    }
    Py_ssize_t n_rows = view.len / itemsize;
    size_t row_max = (size_t)n_cols * (CELL_MAX + 1);
    char *text = PyMem_Malloc((size_t)n_rows * row_max + 1);
    PyObject *result = NULL;
    if (text == NULL) {
        PyErr_NoMemory();
    } else {
        size_t len = 0;
        for (Py_ssize_t r = 0; r < n_rows; r++)
            len += format_row(text + len, (const unsigned char *)view.buf + r * itemsize, cols, n_cols);
        result = PyUnicode_DecodeASCII(text, (Py_ssize_t)len, NULL);
    }
    PyMem_Free(text);
    PyBuffer_Release(&view);
    PyMem_Free(cols);
    return result;
}

/* ---- the writer and its thread ------------------------------------------------------------------ */
typedef struct chunk {
    struct chunk *next;
    size_t n_rows, n_events;
    unsigned char *rows;
    size_t *ev_index, *ev_end; /* event i goes before row ev_index[i]; its text ends at ev_end[i] */
    char *ev_text;
} chunk_t;

#define TEXT_BYTES (256 * 1024) /* the thread's text buffer: written out when the next row may not fit */

typedef struct {
    PyObject_HEAD
    int fd, n_cols, ready, running;
    Py_ssize_t itemsize;
    size_t max_rows;
    column_t *cols;
    char *text;
    size_t text_cap;
    pthread_mutex_t lock;
    pthread_cond_t wake;  /* the thread's: a chunk queued, or stopping */
    pthread_cond_t moved; /* the caller's: a chunk written, the thread stopped or failed */
    pthread_t thread;
    chunk_t *head, *tail;
    size_t queued_rows; /* in the queue and in the thread's hands */
    size_t queued_chunks; /* the same in chunks (a chunk of events alone has no rows) */
    unsigned long long accepted; /* chunks ever queued: the caller tells a submit that took its chunk */
    size_t want_rows;   /* the rows of the chunk a submit waits to queue */
    int busy, stopping, discard, exited, error;
} Writer;

static void free_chunks(chunk_t *c)
{
    while (c != NULL) {
        chunk_t *next = c->next;
        free(c);
        c = next;
    }
}

static int write_all(int fd, const char *p, size_t n)
{
    while (n) {
        ssize_t done = write(fd, p, n);
        if (done < 0) {
            if (errno == EINTR) continue;
            return errno;
        }
        if (done == 0) return EIO; /* nothing written of n > 0 bytes: never loop on it */
        p += done;
        n -= (size_t)done;
    }
    return 0;
}

/* A chunk's rows and events as text, written to the file: 0 or an errno. */
static int write_chunk(Writer *w, const chunk_t *c)
{
    size_t len = 0, ev = 0, row_max = (size_t)w->n_cols * (CELL_MAX + 1);
    int err;
    for (size_t r = 0; r <= c->n_rows; r++) {
        for (; ev < c->n_events && c->ev_index[ev] == r; ev++) {
            size_t start = ev ? c->ev_end[ev - 1] : 0, n = c->ev_end[ev] - start;
            if (len + n > w->text_cap) {
                if ((err = write_all(w->fd, w->text, len))) return err;
                len = 0;
            }
            if (n > w->text_cap) {
                if ((err = write_all(w->fd, c->ev_text + start, n))) return err;
            } else {
                memcpy(w->text + len, c->ev_text + start, n);
                len += n;
            }
        }
        if (r == c->n_rows) break;
        if (len + row_max > w->text_cap) {
            if ((err = write_all(w->fd, w->text, len))) return err;
            len = 0;
        }
        len += format_row(w->text + len, c->rows + r * (size_t)w->itemsize, w->cols, w->n_cols);
    }
    return write_all(w->fd, w->text, len);
}

static void *writer_thread(void *arg)
{
    Writer *w = arg;
    become_batch_thread();
    pthread_mutex_lock(&w->lock);
    for (;;) {
        while (w->head == NULL && !w->stopping) pthread_cond_wait(&w->wake, &w->lock);
        if (w->head == NULL || w->discard) break;
        chunk_t *c = w->head;
        w->head = c->next;
        if (w->head == NULL) w->tail = NULL;
        w->busy = 1;
        pthread_mutex_unlock(&w->lock);
        int err = write_chunk(w, c);
        pthread_mutex_lock(&w->lock);
        w->busy = 0;
        w->queued_rows -= c->n_rows;
        w->queued_chunks--;
        free(c);
        if (err) {
            w->error = err;
            break;
        }
        pthread_cond_broadcast(&w->moved);
    }
    free_chunks(w->head); /* dropped: discarded, or after a failed write */
    w->head = w->tail = NULL;
    w->queued_rows = 0;
    w->queued_chunks = 0;
    w->exited = 1;
    pthread_cond_broadcast(&w->moved);
    pthread_mutex_unlock(&w->lock);
    return NULL;
}

static PyObject *os_error(int err)
{
    errno = err;
    return PyErr_SetFromErrno(PyExc_OSError);
}

/* Wait, the GIL released, until `done(w)` (under the lock) or an error. Signals are the Python
 * thread's: their handlers run when the wait is over (no row handed over is dropped by Ctrl-C). */
static int wait_until(Writer *w, int (*done)(Writer *))
{
    int err;
    Py_BEGIN_ALLOW_THREADS
    pthread_mutex_lock(&w->lock);
    while (!w->error && !w->exited && !done(w)) pthread_cond_wait(&w->moved, &w->lock);
    err = w->error;
    pthread_mutex_unlock(&w->lock);
    Py_END_ALLOW_THREADS
    return err;
}

static int has_room(Writer *w) { return w->queued_rows == 0 || w->queued_rows + w->want_rows <= w->max_rows; }

static int drained(Writer *w) { return w->queued_chunks == 0; }

/* submit(rows, events): whole raw rows (a copy is taken) and [(row index, event line bytes), ...] */
static PyObject *Writer_submit(Writer *w, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "submit(rows, events)");
        return NULL;
    }
    if (!w->running) {
        PyErr_SetString(PyExc_ValueError, "RowWriter.submit: closed or abandoned");
        return NULL;
    }
    PyObject *events = PySequence_Fast(args[1], "RowWriter.submit: events must be a sequence");
    if (events == NULL) return NULL;
    Py_buffer view;
    if (PyObject_GetBuffer(args[0], &view, PyBUF_SIMPLE) < 0) {
        Py_DECREF(events);
        return NULL;
    }
    size_t n_rows = (size_t)(view.len / w->itemsize), n_events = (size_t)PySequence_Fast_GET_SIZE(events);
    size_t text_len = 0;
    chunk_t *c = NULL;
    for (size_t i = 0; i < n_events; i++) {
        PyObject *item = PySequence_Fast_GET_ITEM(events, (Py_ssize_t)i);
        if (!PyTuple_Check(item) || PyTuple_GET_SIZE(item) != 2 || !PyBytes_Check(PyTuple_GET_ITEM(item, 1))) {
            PyErr_SetString(PyExc_TypeError, "RowWriter.submit: an event is (row index, bytes)");
            goto bad;
        }
        text_len += (size_t)PyBytes_GET_SIZE(PyTuple_GET_ITEM(item, 1));
    }
    size_t rows_bytes = n_rows * (size_t)w->itemsize;
    c = malloc(sizeof(chunk_t) + rows_bytes + 2 * n_events * sizeof(size_t) + text_len + 1);
    if (c == NULL) {
        PyErr_NoMemory();
        goto bad;
    }
    c->next = NULL;
    c->n_rows = n_rows;
    c->n_events = n_events;
    c->ev_index = (size_t *)(c + 1);
    c->ev_end = c->ev_index + n_events;
    c->rows = (unsigned char *)(c->ev_end + n_events);
    c->ev_text = (char *)(c->rows + rows_bytes);
    memcpy(c->rows, view.buf, rows_bytes);
    size_t at = 0, last = 0;
    for (size_t i = 0; i < n_events; i++) {
        PyObject *item = PySequence_Fast_GET_ITEM(events, (Py_ssize_t)i), *text = PyTuple_GET_ITEM(item, 1);
        Py_ssize_t index = PyLong_AsSsize_t(PyTuple_GET_ITEM(item, 0));
        if (index == -1 && PyErr_Occurred()) goto bad;
        if (index < 0 || (size_t)index > n_rows || (size_t)index < last) {
            PyErr_Format(PyExc_ValueError, "RowWriter.submit: event at row %zd of %zu (in order)", index, n_rows);
            goto bad;
        }
        last = (size_t)index;
        memcpy(c->ev_text + at, PyBytes_AS_STRING(text), (size_t)PyBytes_GET_SIZE(text));
        at += (size_t)PyBytes_GET_SIZE(text);
        c->ev_index[i] = (size_t)index;
        c->ev_end[i] = at;
    }
    PyBuffer_Release(&view);
    Py_DECREF(events);
    w->want_rows = n_rows; /* one caller at a time: the GIL is held until the wait begins */
    int err = wait_until(w, has_room);
    pthread_mutex_lock(&w->lock);
    if (!err && w->exited) err = w->error ? w->error : EIO;
    if (!err) {
        if (w->tail != NULL) w->tail->next = c; else w->head = c;
        w->tail = c;
        w->queued_rows += n_rows;
        w->queued_chunks++;
        w->accepted++;
        c = NULL;
        pthread_cond_signal(&w->wake);
    }
    pthread_mutex_unlock(&w->lock);
    free(c);
    if (err) return os_error(err);
    Py_RETURN_NONE;
bad:
    free(c);
    PyBuffer_Release(&view);
    Py_DECREF(events);
    return NULL;
}

/* drain(): every row handed over written (OSError: a failed write) */
static PyObject *Writer_drain(Writer *w, PyObject *Py_UNUSED(ignored))
{
    if (!w->running) {
        PyErr_SetString(PyExc_ValueError, "RowWriter.drain: closed or abandoned");
        return NULL;
    }
    int err = wait_until(w, drained);
    if (err) return os_error(err);
    Py_RETURN_NONE;
}

/* The thread stopped (what waits written first, or dropped with discard) and joined, the GIL released. */
static void stop_thread(Writer *w, int discard)
{
    if (!w->running) return;
    Py_BEGIN_ALLOW_THREADS
    pthread_mutex_lock(&w->lock);
    w->stopping = 1;
    if (discard) w->discard = 1;
    pthread_cond_signal(&w->wake);
    pthread_mutex_unlock(&w->lock);
    pthread_join(w->thread, NULL);
    Py_END_ALLOW_THREADS
    w->running = 0;
    close(w->fd); /* its own duplicate: nothing written on it any more */
    w->fd = -1;
}

/* close(): every row handed over written, the thread joined (OSError: a failed write) */
static PyObject *Writer_close(Writer *w, PyObject *Py_UNUSED(ignored))
{
    stop_thread(w, 0);
    if (w->error) return os_error(w->error);
    Py_RETURN_NONE;
}

/* abandon(): the thread joined, the rows not written dropped (idempotent) */
static PyObject *Writer_abandon(Writer *w, PyObject *Py_UNUSED(ignored))
{
    stop_thread(w, 1);
    Py_RETURN_NONE;
}

static int Writer_init(Writer *w, PyObject *args, PyObject *kwds)
{
    static char *kw[] = {"fd", "itemsize", "columns", "max_rows", NULL};
    int fd;
    Py_ssize_t itemsize, max_rows;
    PyObject *columns;
    if (w->ready) {
        PyErr_SetString(PyExc_RuntimeError, "RowWriter: cannot be initialised twice");
        return -1;
    }
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "inOn:RowWriter", kw, &fd, &itemsize, &columns, &max_rows)) return -1;
    if (max_rows < 1) {
        PyErr_SetString(PyExc_ValueError, "RowWriter: max_rows must be positive");
        return -1;
    }
    column_t *cols;
    int n_cols = parse_columns(columns, itemsize, &cols);
    if (n_cols < 0) return -1;
    size_t cap = (size_t)n_cols * (CELL_MAX + 1);
    cap = cap < TEXT_BYTES ? TEXT_BYTES : cap;
    char *text = malloc(cap);
    if (text == NULL) {
        PyMem_Free(cols);
        PyErr_NoMemory();
        return -1;
    }
    /* a descriptor of its own (the same open file): whoever closes the caller's, the thread never
     * writes on a closed or reused number */
    int own_fd = fcntl(fd, F_DUPFD_CLOEXEC, 0);
    if (own_fd < 0) {
        PyErr_SetFromErrno(PyExc_OSError);
        free(text);
        PyMem_Free(cols);
        return -1;
    }
    if (pthread_mutex_init(&w->lock, NULL)) goto no_sync;
    if (pthread_cond_init(&w->wake, NULL)) {
        pthread_mutex_destroy(&w->lock);
        goto no_sync;
    }
    if (pthread_cond_init(&w->moved, NULL)) {
        pthread_cond_destroy(&w->wake);
        pthread_mutex_destroy(&w->lock);
        goto no_sync;
    }
    w->fd = own_fd;
    w->itemsize = itemsize;
    w->max_rows = (size_t)max_rows;
    w->n_cols = n_cols;
    w->cols = cols;
    w->text = text;
    w->text_cap = cap;
    w->ready = 1;
    int err = start_writer_thread(&w->thread, writer_thread, w);
    if (err) {
        os_error(err);
        return -1; /* dealloc closes own_fd */
    }
    w->running = 1;
    return 0;
no_sync:
    close(own_fd);
    free(text);
    PyMem_Free(cols);
    PyErr_SetString(PyExc_OSError, "RowWriter: no lock or condition");
    return -1;
}

static void Writer_dealloc(Writer *w)
{
    stop_thread(w, 1);
    if (w->ready && w->fd >= 0) close(w->fd); /* the thread never started */
    if (w->ready) {
        pthread_mutex_destroy(&w->lock);
        pthread_cond_destroy(&w->wake);
        pthread_cond_destroy(&w->moved);
    }
    PyMem_Free(w->cols);
    free(w->text);
    Py_TYPE(w)->tp_free((PyObject *)w);
}

static PyMethodDef Writer_methods[] = {
    {"submit", (PyCFunction)(void (*)(void))Writer_submit, METH_FASTCALL,
     "submit(rows, events): whole raw rows (copied) and [(row index, event line bytes)] for the thread to write."},
    {"drain", (PyCFunction)Writer_drain, METH_NOARGS, "drain(): every row handed over written."},
    {"close", (PyCFunction)Writer_close, METH_NOARGS, "close(): every row handed over written, the thread joined."},
    {"abandon", (PyCFunction)Writer_abandon, METH_NOARGS, "abandon(): the thread joined, rows not written dropped."},
    {NULL, NULL, 0, NULL},
};

static PyObject *Writer_accepted(Writer *w, void *Py_UNUSED(closure))
{
    return PyLong_FromUnsignedLongLong(w->accepted);
}

static PyGetSetDef Writer_getset[] = {
    {"accepted", (getter)Writer_accepted, NULL,
     "chunks submit has queued so far: a caller interrupted right after a submit returned tells whether it took the chunk", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject WriterType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "hilbench.bench._csvrows.RowWriter",
    .tp_basicsize = sizeof(Writer),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "RowWriter(fd, itemsize, columns, max_rows): raw rows as CSV lines written to fd on a thread; columns: "
              "(field offset, struct code, scale, modulo or 0, format) each; at most max_rows rows wait.",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Writer_init,
    .tp_dealloc = (destructor)Writer_dealloc,
    .tp_methods = Writer_methods,
    .tp_getset = Writer_getset,
};

static PyMethodDef methods[] = {
    {"format_rows", (PyCFunction)(void (*)(void))format_rows, METH_FASTCALL,
     "format_rows(rows, itemsize, columns) -> str: whole raw rows as CSV lines (columns as RowWriter takes them)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moduledef = {
    PyModuleDef_HEAD_INIT, "_csvrows", "CSV rows in C from raw rows (optional; Recorder._format_csv is the reference).",
    -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__csvrows(void)
{
    if (PyType_Ready(&WriterType) < 0) return NULL;
    PyObject *m = PyModule_Create(&moduledef);
    if (m == NULL) return NULL;
    Py_INCREF(&WriterType);
    if (PyModule_AddObject(m, "RowWriter", (PyObject *)&WriterType) < 0) {
        Py_DECREF(&WriterType);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
