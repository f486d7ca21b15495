/* An NPZ archive's columns written from a run's journal on a thread of their own (hilbench.bench.npzwriter).
 *
 * A run's recording reaches its .npz at the close: the journal read back, each column of the raw
 * rows converted to float64, its CRC-32 carried along, written at its place in the archive
 * (npzwriter.ColumnArchive). That was a third of a fast run's time, spent after the run. Here the
 * recorder writes its rows to the journal a chunk at a time and tells this writer (`submit(n)`: the
 * next n rows are in the journal); its thread reads them back (pread on its own descriptor), converts
 * each column exactly as recorder.RowLayout.to_column does (the field as a double, times its scale
 * unless the scale is 1, an angle wrapped as numpy.mod wraps it), carries its CRC-32 (zlib's) and
 * writes it with pwrite at the column's place, while the run goes on. The thread never touches a
 * Python object, so it never waits for the GIL, and the simulating thread copies nothing for it.
 * `finish` joins it and gives the rows written and each column's CRC (Ctrl-C while it waits drops
 * the rest and raises KeyboardInterrupt); `abandon` joins it and drops the rest. A failed read or
 * write stops the thread: `submit` and `finish` raise OSError with its errno. The thread runs with
 * every signal blocked. tests/test_npz_writer.py checks the archive equals the one written from
 * the journal at the close, byte for byte.
 */
#define PY_SSIZE_T_CLEAN
#ifndef _GNU_SOURCE
#define _GNU_SOURCE /* SCHED_BATCH */
#endif
#include <Python.h>
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "_rawfields.h"
#include "_writerthread.h"

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "the raw rows and the .npy columns are little-endian: a little-endian host only"
#endif

/* ---- CRC-32 (zlib's: reflected 0xEDB88320), eight bytes at a time ---------------------------------- */
static uint32_t crc_table[8][256];

static void crc_init(void)
{
    for (uint32_t n = 0; n < 256; n++) {
        uint32_t c = n;
        for (int k = 0; k < 8; k++) c = (c & 1) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
        crc_table[0][n] = c;
    }
    for (uint32_t n = 0; n < 256; n++)
        for (int t = 1; t < 8; t++) crc_table[t][n] = crc_table[0][crc_table[t - 1][n] & 0xFF] ^ (crc_table[t - 1][n] >> 8);
}

static uint32_t crc32_update(uint32_t crc, const unsigned char *p, size_t n)
{
    crc = ~crc;
    for (; n >= 8; p += 8, n -= 8) {
        uint64_t w;
        memcpy(&w, p, 8);
        w ^= crc;
        crc = crc_table[7][w & 0xFF] ^ crc_table[6][(w >> 8) & 0xFF] ^ crc_table[5][(w >> 16) & 0xFF]
              ^ crc_table[4][(w >> 24) & 0xFF] ^ crc_table[3][(w >> 32) & 0xFF] ^ crc_table[2][(w >> 40) & 0xFF]
              ^ crc_table[1][(w >> 48) & 0xFF] ^ crc_table[0][w >> 56];
    }
    while (n--) crc = crc_table[0][(crc ^ *p++) & 0xFF] ^ (crc >> 8);
    return ~crc;
}

/* Four equally long streams at once: each one's chain of table look-ups waits on its last step, so
 * four independent chains keep the CPU busy where one leaves it waiting (about 3x one stream's rate). */
static void crc32_update4(uint32_t crc[4], const unsigned char *const p[4], size_t n)
{
    uint32_t c[4] = {~crc[0], ~crc[1], ~crc[2], ~crc[3]};
    size_t at = 0;
    for (; at + 8 <= n; at += 8)
        for (int s = 0; s < 4; s++) {
            uint64_t w;
            memcpy(&w, p[s] + at, 8);
            w ^= c[s];
            c[s] = crc_table[7][w & 0xFF] ^ crc_table[6][(w >> 8) & 0xFF] ^ crc_table[5][(w >> 16) & 0xFF]
                   ^ crc_table[4][(w >> 24) & 0xFF] ^ crc_table[3][(w >> 32) & 0xFF] ^ crc_table[2][(w >> 40) & 0xFF]
                   ^ crc_table[1][(w >> 48) & 0xFF] ^ crc_table[0][w >> 56];
        }
    for (int s = 0; s < 4; s++) {
        for (size_t i = at; i < n; i++) c[s] = crc_table[0][(c[s] ^ p[s][i]) & 0xFF] ^ (c[s] >> 8);
        crc[s] = ~c[s];
    }
}

/* ---- one column of raw rows ------------------------------------------------------------------ */
typedef struct {
    Py_ssize_t field;  /* the field's byte offset in a row */
    char code;         /* its struct code (recorder._CODE_DTYPES) */
    double scale;      /* column = field x scale (1: the field as it is) */
    double modulo;     /* > 0: the column wrapped into [0, modulo) as numpy.mod does; 0: not wrapped */
    long long place;   /* the file offset of the column's row 0 */
    uint32_t crc;      /* of the member's bytes so far */
} column_t;

/* field_value and np_remainder: _rawfields.h (the CSV row writer reads raw rows the same way) */

/* ---- the writer and its thread --------------------------------------------------------------- */
#define READ_ROWS 8192 /* rows the thread reads back from the journal at a time */

typedef struct {
    PyObject_HEAD
    int fd, journal_fd, n_cols;
    long long journal_offset;        /* where the journal's row 0 is */
    Py_ssize_t itemsize;
    column_t *cols;
    unsigned long long queued, done; /* rows handed over, rows written (done: the thread's) */
    unsigned char *rows;             /* the thread's buffers: raw rows read back, their columns */
    double *values;
    unsigned char *header;           /* each column's .npy header, written by the thread before its row 0 */
    Py_ssize_t header_len;
    pthread_mutex_t lock;
    pthread_cond_t wake;             /* the thread's: rows queued, or stopping */
    pthread_cond_t ended;            /* the caller's: the thread is about to return (exited) */
    pthread_t thread;
    int ready, running, stopping, discard, exited, error; /* error: the errno of the failed read or write */
} Writer;

static int pwrite_all(int fd, const unsigned char *p, size_t n, long long offset)
{
    while (n) {
        ssize_t done = pwrite(fd, p, n, (off_t)offset);
        if (done < 0) {
            if (errno == EINTR) continue;
            return errno;
        }
        if (done == 0) return EIO; /* nothing written of n > 0 bytes: never loop on it */
        p += done;
        n -= (size_t)done;
        offset += done;
    }
    return 0;
}

static int pread_all(int fd, unsigned char *p, size_t n, long long offset)
{
    while (n) {
        ssize_t done = pread(fd, p, n, (off_t)offset);
        if (done < 0) {
            if (errno == EINTR) continue;
            return errno;
        }
        if (done == 0) return EIO; /* the journal is shorter than the rows handed over */
        p += done;
        n -= (size_t)done;
        offset += done;
    }
    return 0;
}

/* The next n rows read back from the journal, every column converted, its CRC carried, written at
 * its place: 0 or an errno. */
static int write_rows(Writer *w, size_t n)
{
    int err = pread_all(w->journal_fd, w->rows, n * (size_t)w->itemsize,
                        w->journal_offset + (long long)(w->done * (unsigned long long)w->itemsize));
    if (err) return err;
    size_t bytes = n * sizeof(double);
    for (int j = 0; j < w->n_cols; j++) { /* every column converted (READ_ROWS values each) */
        column_t *col = &w->cols[j];
        double *values = w->values + (size_t)j * READ_ROWS;
        const unsigned char *p = w->rows + col->field;
        for (size_t i = 0; i < n; i++, p += w->itemsize) values[i] = field_value(p, col->code);
        if (col->scale != 1.0)
            for (size_t i = 0; i < n; i++) values[i] = values[i] * col->scale;
        if (col->modulo > 0.0)
            for (size_t i = 0; i < n; i++) values[i] = np_remainder(values[i], col->modulo);
    }
    int j = 0;
    for (; j + 4 <= w->n_cols; j += 4) { /* their CRCs four at a time */
        uint32_t crc[4] = {w->cols[j].crc, w->cols[j + 1].crc, w->cols[j + 2].crc, w->cols[j + 3].crc};
        const unsigned char *p[4];
        for (int s = 0; s < 4; s++) p[s] = (const unsigned char *)(w->values + (size_t)(j + s) * READ_ROWS);
        crc32_update4(crc, p, bytes);
        for (int s = 0; s < 4; s++) w->cols[j + s].crc = crc[s];
    }
    for (; j < w->n_cols; j++)
        w->cols[j].crc = crc32_update(w->cols[j].crc, (const unsigned char *)(w->values + (size_t)j * READ_ROWS), bytes);
    for (j = 0; j < w->n_cols; j++) {
        err = pwrite_all(w->fd, (const unsigned char *)(w->values + (size_t)j * READ_ROWS), bytes,
                         w->cols[j].place + (long long)(8 * w->done));
        if (err) return err;
    }
    return 0;
}

static void *writer_thread(void *arg)
{
    Writer *w = arg;
    int err = 0;
    become_batch_thread();
    for (int j = 0; j < w->n_cols && !err; j++)
        err = pwrite_all(w->fd, w->header, (size_t)w->header_len, w->cols[j].place - w->header_len);
    pthread_mutex_lock(&w->lock);
    if (err) w->error = err;
    for (; !err;) {
        while (w->queued == w->done && !w->stopping) pthread_cond_wait(&w->wake, &w->lock);
        if (w->discard || w->queued == w->done) break; /* stopping: dropped, or every row written */
        unsigned long long n = w->queued - w->done;
        if (n > READ_ROWS) n = READ_ROWS;
        pthread_mutex_unlock(&w->lock);
        err = write_rows(w, (size_t)n);
        pthread_mutex_lock(&w->lock);
        if (err) {
            w->error = err;
            break;
        }
        w->done += n;
    }
    w->exited = 1;
    pthread_cond_signal(&w->ended);
    pthread_mutex_unlock(&w->lock);
    return NULL;
}

#define STOP_POLL_NS 50000000L /* how often a wait for the thread looks for a signal (Ctrl-C) */

/* Stop the thread (after every row handed over, or dropping them) and join it, the GIL released.
 * Waiting for every row (not discard), a signal's handler that raises (Ctrl-C: KeyboardInterrupt)
 * ends the wait: the rows not written yet are dropped, the thread joined, -1 returned with the
 * exception set (the caller gives the archive up; the journal keeps every row). */
static int stop_thread(Writer *w, int discard)
{
    if (!w->running) return 0;
    int status = 0, exited = 0;
    while (!exited) {
        Py_BEGIN_ALLOW_THREADS
        pthread_mutex_lock(&w->lock);
        w->stopping = 1;
        if (discard) w->discard = 1;
        pthread_cond_signal(&w->wake);
        if (!w->exited) {
            struct timespec until;
            clock_gettime(CLOCK_MONOTONIC, &until);
            until.tv_nsec += STOP_POLL_NS;
            if (until.tv_nsec >= 1000000000L) {
                until.tv_sec += 1;
                until.tv_nsec -= 1000000000L;
            }
            pthread_cond_timedwait(&w->ended, &w->lock, &until);
        }
        exited = w->exited;
        pthread_mutex_unlock(&w->lock);
        Py_END_ALLOW_THREADS
        if (!exited && !discard && PyErr_CheckSignals() < 0) { /* interrupted: drop the rest, still join */
            discard = 1;
            status = -1;
        }
    }
    Py_BEGIN_ALLOW_THREADS
    pthread_join(w->thread, NULL); /* it has returned, or is returning */
    Py_END_ALLOW_THREADS
    w->running = 0;
    return status;
}

static PyObject *os_error(int err)
{
    errno = err;
    return PyErr_SetFromErrno(PyExc_OSError);
}

/* submit(n_rows): the journal's next n_rows rows (written and flushed) are the thread's to write */
static PyObject *Writer_submit(Writer *w, PyObject *arg)
{
    unsigned long long n = PyLong_AsUnsignedLongLong(arg);
    if (n == (unsigned long long)-1 && PyErr_Occurred()) return NULL;
    if (!w->running) {
        PyErr_SetString(PyExc_ValueError, "ColumnWriter.submit: finished or abandoned");
        return NULL;
    }
    pthread_mutex_lock(&w->lock);
    int err = w->error;
    if (!err && n) {
        w->queued += n;
        pthread_cond_signal(&w->wake);
    }
    pthread_mutex_unlock(&w->lock);
    if (err) return os_error(err);
    Py_RETURN_NONE;
}

/* finish() -> (rows written, (crc, ...)): every row handed over written, the thread joined */
static PyObject *Writer_finish(Writer *w, PyObject *Py_UNUSED(ignored))
{
    if (!w->running) {
        PyErr_SetString(PyExc_ValueError, "ColumnWriter.finish: finished or abandoned");
        return NULL;
    }
    if (stop_thread(w, 0) < 0) return NULL; /* a signal's exception (Ctrl-C) */
    if (w->error) return os_error(w->error);
    PyObject *crcs = PyTuple_New(w->n_cols);
    if (crcs == NULL) return NULL;
    for (int j = 0; j < w->n_cols; j++) {
        PyObject *v = PyLong_FromUnsignedLong(w->cols[j].crc);
        if (v == NULL) {
            Py_DECREF(crcs);
            return NULL;
        }
        PyTuple_SET_ITEM(crcs, j, v);
    }
    return Py_BuildValue("(KN)", w->done, crcs);
}

/* abandon(): the thread joined, the rows not written yet dropped (idempotent) */
static PyObject *Writer_abandon(Writer *w, PyObject *Py_UNUSED(ignored))
{
    stop_thread(w, 1);
    Py_RETURN_NONE;
}

static int Writer_init(Writer *w, PyObject *args, PyObject *kwds)
{
    static char *kw[] = {"fd", "journal_fd", "journal_offset", "itemsize", "columns", "header", NULL};
    int fd, journal_fd;
    long long journal_offset;
    Py_ssize_t itemsize;
    PyObject *columns;
    Py_buffer header = {0};
    if (w->ready) {
        PyErr_SetString(PyExc_RuntimeError, "ColumnWriter: cannot be initialised twice");
        return -1;
    }
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "iiLnOy*:ColumnWriter", kw, &fd, &journal_fd, &journal_offset,
                                     &itemsize, &columns, &header))
        return -1;
    if (itemsize < 1 || journal_offset < 0) {
        PyBuffer_Release(&header);
        PyErr_SetString(PyExc_ValueError, "ColumnWriter: itemsize must be positive, journal_offset not negative");
        return -1;
    }
    PyObject *seq = PySequence_Fast(columns, "ColumnWriter: columns must be a sequence");
    if (seq == NULL) {
        PyBuffer_Release(&header);
        return -1;
    }
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    if (n < 1 || n > INT_MAX) {
        Py_DECREF(seq);
        PyBuffer_Release(&header);
        PyErr_SetString(PyExc_ValueError, "ColumnWriter: no columns");
        return -1;
    }
    column_t *cols = calloc((size_t)n, sizeof(column_t));
    unsigned char *rows = malloc((size_t)READ_ROWS * (size_t)itemsize);
    double *values = malloc((size_t)n * READ_ROWS * sizeof(double));
    unsigned char *head = malloc((size_t)header.len + 1);
    if (head != NULL) memcpy(head, header.buf, (size_t)header.len);
    Py_ssize_t head_len = header.len;
    PyBuffer_Release(&header);
    if (cols == NULL || rows == NULL || values == NULL || head == NULL) {
        PyErr_NoMemory();
        goto bad;
    }
    for (Py_ssize_t j = 0; j < n; j++) {
        const char *code;
        unsigned long crc;
        column_t *col = &cols[j];
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(seq, j), "nsddLk:ColumnWriter column", &col->field, &code,
                              &col->scale, &col->modulo, &col->place, &crc))
            goto bad;
        int width = field_width(code);
        if (width == 0 || col->field < 0 || col->field + width > itemsize || col->place < head_len) {
            PyErr_Format(PyExc_ValueError, "ColumnWriter: column %zd: a field %s at %zd of a %zd-byte row", j, code,
                         col->field, itemsize);
            goto bad;
        }
        col->code = code[0];
        col->crc = (uint32_t)crc;
    }
    if (pthread_mutex_init(&w->lock, NULL)) {
        PyErr_SetString(PyExc_OSError, "ColumnWriter: no lock");
        goto bad;
    }
    pthread_condattr_t monotonic;
    int no_cond = pthread_condattr_init(&monotonic);
    if (!no_cond) {
        no_cond = pthread_condattr_setclock(&monotonic, CLOCK_MONOTONIC) || pthread_cond_init(&w->ended, &monotonic);
        pthread_condattr_destroy(&monotonic);
    }
    if (no_cond || pthread_cond_init(&w->wake, NULL)) {
        if (!no_cond) pthread_cond_destroy(&w->ended);
        pthread_mutex_destroy(&w->lock);
        PyErr_SetString(PyExc_OSError, "ColumnWriter: no condition");
        goto bad;
    }
    Py_DECREF(seq);
    w->fd = fd;
    w->journal_fd = journal_fd;
    w->journal_offset = journal_offset;
    w->itemsize = itemsize;
    w->n_cols = (int)n;
    w->cols = cols;
    w->rows = rows;
    w->values = values;
    w->header = head;
    w->header_len = head_len;
    w->ready = 1;
    int err = start_writer_thread(&w->thread, writer_thread, w);
    if (err) {
        os_error(err);
        return -1;
    }
    w->running = 1;
    return 0;
bad:
    Py_DECREF(seq);
    free(cols);
    free(rows);
    free(values);
    free(head);
    return -1;
}

static void Writer_dealloc(Writer *w)
{
    stop_thread(w, 1);
    if (w->ready) {
        pthread_mutex_destroy(&w->lock);
        pthread_cond_destroy(&w->wake);
        pthread_cond_destroy(&w->ended);
    }
    free(w->cols);
    free(w->rows);
    free(w->values);
    free(w->header);
    Py_TYPE(w)->tp_free((PyObject *)w);
}

static PyObject *Writer_rows_done(Writer *w, void *Py_UNUSED(closure))
{
    if (w->running) Py_RETURN_NONE; /* the thread's, known once it is joined */
    return PyLong_FromUnsignedLongLong(w->done);
}

static PyObject *crc32_func(PyObject *Py_UNUSED(module), PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs < 1 || nargs > 2) {
        PyErr_SetString(PyExc_TypeError, "crc32(data, value=0)");
        return NULL;
    }
    unsigned long value = 0;
    if (nargs == 2) {
        value = PyLong_AsUnsignedLongMask(args[1]);
        if (value == (unsigned long)-1 && PyErr_Occurred()) return NULL;
    }
    Py_buffer view;
    if (PyObject_GetBuffer(args[0], &view, PyBUF_SIMPLE) < 0) return NULL;
    uint32_t crc = crc32_update((uint32_t)value, view.buf, (size_t)view.len);
    PyBuffer_Release(&view);
    return PyLong_FromUnsignedLong(crc);
}

static PyMethodDef Writer_methods[] = {
    {"submit", (PyCFunction)Writer_submit, METH_O,
     "submit(n_rows): the journal's next n_rows rows (written, flushed) are the thread's to write."},
    {"finish", (PyCFunction)Writer_finish, METH_NOARGS,
     "finish() -> (rows written, (crc, ...)): every row handed over written, the thread joined."},
    {"abandon", (PyCFunction)Writer_abandon, METH_NOARGS, "abandon(): the thread joined, rows not written dropped."},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef Writer_getset[] = {
    {"rows_done", (getter)Writer_rows_done, NULL, "rows written (None while the thread runs)", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject WriterType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "hilbench.bench._npzcolumns.ColumnWriter",
    .tp_basicsize = sizeof(Writer),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "ColumnWriter(fd, journal_fd, journal_offset, itemsize, columns, header): a journal's raw rows to an "
              "archive's float64 columns on a thread; columns: (field offset, struct code, scale, modulo or 0, file "
              "offset of row 0, crc so far); header: the .npy header the thread writes before each column's row 0.",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Writer_init,
    .tp_dealloc = (destructor)Writer_dealloc,
    .tp_methods = Writer_methods,
    .tp_getset = Writer_getset,
};

static PyMethodDef module_methods[] = {
    {"crc32", (PyCFunction)(void (*)(void))crc32_func, METH_FASTCALL, "crc32(data, value=0): zlib.crc32's value."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moduledef = {
    PyModuleDef_HEAD_INIT, "_npzcolumns", "An NPZ archive's columns written on a thread of their own (optional).", -1,
    module_methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__npzcolumns(void)
{
    crc_init();
    if (PyType_Ready(&WriterType) < 0) return NULL;
    PyObject *m = PyModule_Create(&moduledef);
    if (m == NULL) return NULL;
    Py_INCREF(&WriterType);
    if (PyModule_AddObject(m, "ColumnWriter", (PyObject *)&WriterType) < 0) {
        Py_DECREF(&WriterType);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
