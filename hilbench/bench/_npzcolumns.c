/* An NPZ archive's columns written on a thread of their own while a run goes on (hilbench.bench.npzwriter).
 *
 * A run's recording reaches its .npz at the close: each column of the raw rows converted to float64,
 * its CRC-32 carried along, written at its place in the archive (npzwriter.ColumnArchive). That was a
 * third of a fast run's time, spent after the run. Here the recorder hands each chunk of raw rows to
 * this writer (`submit_rows(data)`: copied into one of two buffers the writer reuses, so the
 * simulating thread neither writes the journal nor touches fresh pages); its thread writes the chunk
 * to the run's journal at its place (the journal is the killed run's recording: every chunk handed
 * over goes there, in order, even once the archive is given up), then converts each column exactly
 * as recorder.RowLayout.to_column does (the field as a double, times its scale unless the scale is
 * 1, an angle wrapped as numpy.mod wraps it), carries its CRC-32 (zlib's) and writes it with pwrite
 * at the column's place. The thread never touches a Python object, so it never waits for the GIL.
 * A journal write that fails (a full disk) gives the archive up, its file emptied to free its
 * blocks, and is tried once more at its place; failing again, it stops the thread (`submit_rows`,
 * `finish` raise OSError with its errno; `abandon` returns it). A failed archive write gives the
 * archive up (`finish` raises OSError) while the journal goes on. `finish` joins the thread and
 * gives the rows written and each column's CRC (Ctrl-C while it waits drops the archive's rest and
 * raises KeyboardInterrupt, the rows handed over still journaled); `abandon` joins it once every
 * row handed over is journaled. The thread runs with every signal blocked. tests/test_npz_writer.py
 * checks the archive equals the one written from the journal at the close, byte for byte. */
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

#include "_crc32.h"
#include "_rawfields.h"
#include "_writerthread.h"

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "the raw rows and the .npy columns are little-endian: a little-endian host only"
#endif

/* ---- CRC-32 (zlib's): _crc32.h, by carry-less multiplication where the CPU has it ------------------ */

/* ---- one column of raw rows ------------------------------------------------------------------ */
typedef struct {
    Py_ssize_t field;  /* the field's byte offset in a row */
    char code;         /* its struct code (recorder._CODE_DTYPES) */
    double scale;      /* column = field x scale (1: the field as it is) */
    double modulo;     /* > 0: the column wrapped into [0, modulo) as numpy.mod does; 0: not wrapped */
    long long place;   /* the file offset of the column's row 0 */
    uint32_t crc;      /* of the member's bytes so far */
    unsigned char *prefix; /* what the thread writes before row 0: the member's ZIP local header (its CRC
                              written once every row is in: write_crcs), if given, and the .npy header */
    Py_ssize_t prefix_len;
    int has_local;
} column_t;

#define LOCAL_CRC_AT 14 /* a ZIP local header's CRC-32: after signature, versions, flags, method, time, date */

static void free_columns(column_t *cols, Py_ssize_t n)
{
    if (cols == NULL) return;
    for (Py_ssize_t j = 0; j < n; j++) free(cols[j].prefix);
    free(cols);
}

/* field_value and np_remainder: _rawfields.h (the CSV row writer reads raw rows the same way) */

/* ---- the writer and its thread --------------------------------------------------------------- */
#define READ_ROWS 8192 /* rows the thread converts at a time */
#define SLOTS 2        /* chunks handed over and not yet journaled and converted: the caller's copy, the thread's */

enum { SLOT_FREE, SLOT_FILLED, SLOT_JOURNALED };

typedef struct {
    unsigned char *data;       /* the chunk's raw rows, copied in by submit_rows */
    size_t capacity, n_rows;
    unsigned long long first;  /* the chunk's first row (of the journal) */
    int state;
} slot_t;

typedef struct {
    PyObject_HEAD
    int fd, journal_fd, n_cols;
    long long journal_offset;        /* where the journal's row 0 is */
    Py_ssize_t itemsize;
    column_t *cols;
    unsigned long long queued;       /* rows handed over */
    unsigned long long journaled;    /* rows in the journal (the thread's) */
    unsigned long long done;         /* rows written to the archive (the thread's) */
    unsigned long long planned;      /* the rows the archive is sized for (0: not said) */
    int crcs_written;                /* the local headers' CRCs written: by the thread, once it converted
                                        the planned rows (while the caller makes its summary), or by finish */
    slot_t slots[SLOTS];
    int next_fill, next_journal, next_take; /* the slot submit_rows fills next, the one the thread journals
                                               next, the one it converts next (each in turn) */
    double *values;                  /* the thread's buffer: the converted columns (values_buf's, pooled) */
    slot_t values_buf;
    pthread_mutex_t lock;
    pthread_cond_t wake;             /* the thread's: a chunk handed over, or stopping */
    pthread_cond_t freed;            /* the caller's: a slot freed, or the thread ended (exited) */
    pthread_t thread;
    int ready, running, stopping, discard, exited;
    int error;                       /* the errno of a failed archive write: the archive is given up */
    int journal_error;               /* the errno of a failed journal write (after one more try): rows lost */
    int archive_off;                 /* the archive given up (discard, a failed write, a full disk): journal only */
    int test_failures, test_errno;   /* fail_journal_writes: the next journal writes that fail (tests) */
} Writer;

/* Chunk buffers and the converted columns' buffer kept for the next writer when one is done with them
 * (a process runs many runs: fresh pages cost a virtual machine 2-4 us each, the thread's 1.6 MB of
 * columns ~1 ms of a 1 s run), at most POOLED of at most POOLED_BYTES each: about 2 MB held after
 * a run of the default layout. */
#define POOLED 4
#define POOLED_BYTES (16u << 20)
static struct {
    unsigned char *data;
    size_t capacity;
} pool[POOLED];
static pthread_mutex_t pool_lock = PTHREAD_MUTEX_INITIALIZER;

/* The slot (free, not the thread's) with room for n bytes: the smallest pooled buffer that has it
 * (a chunk's buffer does not take the larger one the converted columns need), or its own grown:
 * 0, or -1 (no memory). */
static int slot_reserve(slot_t *slot, size_t n)
{
    if (slot->capacity >= n) return 0;
    pthread_mutex_lock(&pool_lock);
    int best = -1;
    for (int i = 0; i < POOLED; i++)
        if (pool[i].data != NULL && pool[i].capacity >= n && (best < 0 || pool[i].capacity < pool[best].capacity))
            best = i;
    if (best >= 0) {
        unsigned char *old = slot->data;
        size_t old_capacity = slot->capacity;
        slot->data = pool[best].data;
        slot->capacity = pool[best].capacity;
        pool[best].data = old; /* (NULL, or a smaller one: kept for a smaller chunk) */
        pool[best].capacity = old_capacity;
        pthread_mutex_unlock(&pool_lock);
        return 0;
    }
    pthread_mutex_unlock(&pool_lock);
    unsigned char *grown = realloc(slot->data, n);
    if (grown == NULL) return -1;
    slot->data = grown;
    slot->capacity = n;
    return 0;
}

/* A writer's slot buffer back to the pool (the largest kept), or freed. */
static void slot_release(slot_t *slot)
{
    unsigned char *data = slot->data;
    size_t capacity = slot->capacity;
    slot->data = NULL;
    slot->capacity = 0;
    if (data == NULL) return;
    if (capacity <= POOLED_BYTES) {
        pthread_mutex_lock(&pool_lock);
        for (int i = 0; i < POOLED && data != NULL; i++)
            if (pool[i].data == NULL || pool[i].capacity < capacity) { /* an empty place, or a smaller one out */
                unsigned char *out = pool[i].data;
                size_t out_capacity = pool[i].capacity;
                pool[i].data = data;
                pool[i].capacity = capacity;
                data = out;
                capacity = out_capacity;
            }
        pthread_mutex_unlock(&pool_lock);
    }
    free(data);
}

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

/* One journal write of the chunk at its place, or (the tests' fail_journal_writes) a failure after
 * some of its bytes landed, and a few beyond its end. */
static int journal_pwrite(Writer *w, const slot_t *slot, long long offset)
{
    size_t bytes = slot->n_rows * (size_t)w->itemsize;
    pthread_mutex_lock(&w->lock);
    int fail = w->test_failures > 0 ? w->test_errno : 0;
    if (fail) w->test_failures--;
    pthread_mutex_unlock(&w->lock);
    if (fail) {
        unsigned char stray[777];
        memset(stray, 0xEE, sizeof stray);
        pwrite_all(w->journal_fd, slot->data, bytes / 2, offset);
        pwrite_all(w->journal_fd, stray, sizeof stray, offset + (long long)bytes);
        return fail;
    }
    return pwrite_all(w->journal_fd, slot->data, bytes, offset);
}

/* The archive given up after a failed write (err: what finish says): no more of it written, its
 * file emptied so its blocks go back to a full disk, where the journal needs them. */
static void give_archive_up(Writer *w, int err)
{
    pthread_mutex_lock(&w->lock);
    w->archive_off = 1;
    if (!w->error) w->error = err;
    pthread_mutex_unlock(&w->lock);
    if (ftruncate(w->fd, 0)) { /* (the close writes the archive from the journal, or says why it cannot) */
    }
}

/* The chunk written to the journal at its place. A failed write (a full disk) gives the archive up,
 * its blocks freed (its file emptied), cuts what part of the write landed, and is tried once more:
 * the journal, not the archive, keeps the rows. 0, or the errno of the second try (what part of it
 * landed cut off too: the journal ends with the rows before the chunk). */
static int write_journal(Writer *w, const slot_t *slot)
{
    long long offset = w->journal_offset + (long long)(slot->first * (unsigned long long)w->itemsize);
    int err = journal_pwrite(w, slot, offset);
    if (!err) return 0;
    give_archive_up(w, err);
    if (ftruncate(w->journal_fd, (off_t)offset)) return err; /* (the recorder cuts the journal to `journaled`) */
    err = journal_pwrite(w, slot, offset);
    if (err && ftruncate(w->journal_fd, (off_t)offset)) { /* failed again: the journal ends at the rows before */
    }
    return err;
}

/* The chunk's rows (already journaled) converted, each column's CRC carried, written at its place:
 * 0 or an errno. */
static int write_rows(Writer *w, const unsigned char *rows, size_t n)
{
    size_t bytes = n * sizeof(double);
    for (int j = 0; j < w->n_cols; j++) { /* every column converted (READ_ROWS values each) */
        column_t *col = &w->cols[j];
        double *values = w->values + (size_t)j * READ_ROWS;
        field_column(values, rows + col->field, n, (size_t)w->itemsize, col->code);
        if (col->scale != 1.0)
            for (size_t i = 0; i < n; i++) values[i] = values[i] * col->scale;
        if (col->modulo > 0.0)
            for (size_t i = 0; i < n; i++) values[i] = np_remainder(values[i], col->modulo);
    }
    for (int j = 0; j < w->n_cols; j++) /* their CRCs */
        w->cols[j].crc = crc32_fast(w->cols[j].crc, (const unsigned char *)(w->values + (size_t)j * READ_ROWS), bytes);
    for (int j = 0; j < w->n_cols; j++) {
        int err = pwrite_all(w->fd, (const unsigned char *)(w->values + (size_t)j * READ_ROWS), bytes,
                             w->cols[j].place + (long long)(8 * w->done));
        if (err) return err;
    }
    return 0;
}

/* Each local header's CRC-32, now known: 0 or an errno. */
static int write_crcs(Writer *w)
{
    int err = 0;
    for (int j = 0; j < w->n_cols && !err; j++) {
        const column_t *col = &w->cols[j];
        const unsigned char crc[4] = {(unsigned char)col->crc, (unsigned char)(col->crc >> 8),
                                      (unsigned char)(col->crc >> 16), (unsigned char)(col->crc >> 24)};
        if (col->has_local) err = pwrite_all(w->fd, crc, 4, col->place - col->prefix_len + LOCAL_CRC_AT);
    }
    return err;
}

/* A journaled chunk into the archive, READ_ROWS rows at a time (unless the archive is off):
 * a failed write gives the archive up (its errno kept for finish). Called without the lock. */
static void archive_chunk(Writer *w, const slot_t *slot)
{
    for (size_t at = 0; at < slot->n_rows;) {
        pthread_mutex_lock(&w->lock);
        int off = w->archive_off || w->discard;
        pthread_mutex_unlock(&w->lock);
        if (off) return;
        size_t n = slot->n_rows - at < READ_ROWS ? slot->n_rows - at : READ_ROWS;
        int err = write_rows(w, slot->data + at * (size_t)w->itemsize, n);
        if (err) {
            give_archive_up(w, err);
            return;
        }
        pthread_mutex_lock(&w->lock);
        w->done += n;
        int last = w->done == w->planned;
        pthread_mutex_unlock(&w->lock);
        at += n;
        if (last) { /* the planned rows all in: the CRCs now, not in finish's wait */
            err = write_crcs(w);
            if (err) {
                give_archive_up(w, err);
                return;
            }
            pthread_mutex_lock(&w->lock);
            w->crcs_written = 1;
            pthread_mutex_unlock(&w->lock);
        }
    }
}

/* Each chunk handed over, in order: into the journal first (every chunk waiting goes there before
 * the next conversion: a killed run loses as little as can be; always, even when the archive is off
 * or dropped), then into the archive. A failed journal write stops the thread (its chunk stays
 * filled). */
static void *writer_thread(void *arg)
{
    Writer *w = arg;
    become_batch_thread();
    int err = 0;
    for (int j = 0; j < w->n_cols && !err; j++)
        err = pwrite_all(w->fd, w->cols[j].prefix, (size_t)w->cols[j].prefix_len, w->cols[j].place - w->cols[j].prefix_len);
    if (err) give_archive_up(w, err);
    pthread_mutex_lock(&w->lock);
    for (;;) {
        slot_t *to_journal = &w->slots[w->next_journal], *to_convert = &w->slots[w->next_take];
        if (to_journal->state == SLOT_FILLED) {
            pthread_mutex_unlock(&w->lock);
            err = write_journal(w, to_journal);
            pthread_mutex_lock(&w->lock);
            if (err) {
                w->journal_error = err;
                break;
            }
            w->journaled += to_journal->n_rows;
            to_journal->state = SLOT_JOURNALED;
            w->next_journal = (w->next_journal + 1) % SLOTS;
        } else if (to_convert->state == SLOT_JOURNALED) {
            pthread_mutex_unlock(&w->lock);
            archive_chunk(w, to_convert);
            pthread_mutex_lock(&w->lock);
            to_convert->state = SLOT_FREE;
            w->next_take = (w->next_take + 1) % SLOTS;
            pthread_cond_broadcast(&w->freed);
        } else if (w->stopping) {
            break; /* every chunk handed over journaled and converted (or dropped) */
        } else {
            pthread_cond_wait(&w->wake, &w->lock);
        }
    }
    w->exited = 1;
    pthread_cond_broadcast(&w->freed);
    pthread_mutex_unlock(&w->lock);
    return NULL;
}

#define STOP_POLL_NS 50000000L /* how often a wait for the thread looks for a signal (Ctrl-C) */

/* Wait on `freed` (the GIL released) until ready(w) or the thread has exited, looking for a signal
 * every STOP_POLL_NS when interruptible: 0 with the lock held, or -1 without it and with a signal
 * handler's exception set (Ctrl-C). Called without the lock: the lock is never held while the GIL
 * is taken or given back (a Python thread that holds the GIL may be waiting for the lock). */
static int wait_freed(Writer *w, int (*ready)(Writer *), int interruptible)
{
    for (;;) {
        int done;
        Py_BEGIN_ALLOW_THREADS
        pthread_mutex_lock(&w->lock);
        if (!ready(w) && !w->exited) {
            struct timespec until;
            clock_gettime(CLOCK_MONOTONIC, &until);
            until.tv_nsec += STOP_POLL_NS;
            if (until.tv_nsec >= 1000000000L) {
                until.tv_sec += 1;
                until.tv_nsec -= 1000000000L;
            }
            pthread_cond_timedwait(&w->freed, &w->lock, &until);
        }
        done = ready(w) || w->exited;
        pthread_mutex_unlock(&w->lock);
        Py_END_ALLOW_THREADS
        if (done) break;
        if (interruptible && PyErr_CheckSignals() < 0) return -1;
    }
    pthread_mutex_lock(&w->lock); /* (still ready: only the caller, one at a time, changes it back) */
    return 0;
}

static int never(Writer *w) { (void)w; return 0; }

/* Stop the thread and join it, the GIL released: every chunk handed over is journaled first (a
 * journal write is short, and the journal must keep every row); the archive gets them too unless
 * discard. Waiting for the archive (not discard), a signal's handler that raises (Ctrl-C:
 * KeyboardInterrupt) turns the wait into a discard: the thread still journals what it holds and is
 * joined, -1 returned with the exception set (the caller gives the archive up). */
static int stop_thread(Writer *w, int discard)
{
    if (!w->running) return 0;
    int status = 0;
    pthread_mutex_lock(&w->lock);
    w->stopping = 1;
    if (discard) w->discard = 1;
    pthread_cond_signal(&w->wake);
    pthread_mutex_unlock(&w->lock);
    if (wait_freed(w, never, !discard) < 0) { /* interrupted: the archive's rest dropped, still joined */
        status = -1;
        pthread_mutex_lock(&w->lock);
        w->discard = 1;
        pthread_mutex_unlock(&w->lock);
        wait_freed(w, never, 0);
    }
    pthread_mutex_unlock(&w->lock);
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

static int slot_free(Writer *w) { return w->slots[w->next_fill].state == SLOT_FREE; }

/* submit_rows(first_row, data): whole raw rows, the journal's rows from first_row on (the rows handed
 * over so far: `queued`; another first_row is a ValueError, so no row is taken twice or skipped),
 * copied: the thread writes them to the journal at their place, then into the archive. Waits while
 * the thread still holds two chunks. OSError: a journal write failed (the rows of that chunk are not
 * in the journal). One caller at a time (the recorder's thread). */
static PyObject *Writer_submit_rows(Writer *w, PyObject *args)
{
    unsigned long long first_row;
    Py_buffer data;
    if (!PyArg_ParseTuple(args, "Ky*:submit_rows", &first_row, &data)) return NULL;
    PyObject *result = NULL;
    if (!w->running) {
        PyErr_SetString(PyExc_ValueError, "ColumnWriter.submit_rows: finished or abandoned");
        goto out;
    }
    if (data.len % w->itemsize) {
        PyErr_Format(PyExc_ValueError, "ColumnWriter.submit_rows: %zd bytes are not whole %zd-byte rows", data.len,
                     w->itemsize);
        goto out;
    }
    size_t n_rows = (size_t)(data.len / w->itemsize);
    if (first_row != w->queued) { /* (queued changes only here: no lock needed to read it) */
        PyErr_Format(PyExc_ValueError, "ColumnWriter.submit_rows: rows from %llu, expected from %llu", first_row,
                     w->queued);
        goto out;
    }
    if (w->planned && w->queued + n_rows > w->planned) { /* (the archive is sized for the plan) */
        PyErr_Format(PyExc_ValueError, "ColumnWriter.submit_rows: rows up to %llu, beyond the %llu planned",
                     w->queued + (unsigned long long)n_rows, w->planned);
        goto out;
    }
    if (wait_freed(w, slot_free, 1) < 0) goto out; /* (a signal's exception: nothing handed over) */
    int err = w->journal_error ? w->journal_error : (w->exited ? EIO : 0);
    pthread_mutex_unlock(&w->lock);
    if (err) {
        os_error(err);
        goto out;
    }
    if (n_rows) {
        slot_t *slot = &w->slots[w->next_fill]; /* free: the thread does not touch it */
        if (slot_reserve(slot, (size_t)data.len) < 0) {
            PyErr_NoMemory();
            goto out;
        }
        memcpy(slot->data, data.buf, (size_t)data.len);
        pthread_mutex_lock(&w->lock);
        slot->n_rows = n_rows;
        slot->first = w->queued;
        slot->state = SLOT_FILLED;
        w->queued += n_rows;
        w->next_fill = (w->next_fill + 1) % SLOTS;
        pthread_cond_signal(&w->wake);
        pthread_mutex_unlock(&w->lock);
    }
    result = Py_NewRef(Py_None);
out:
    PyBuffer_Release(&data);
    return result;
}

static int all_journaled(Writer *w) { return w->journaled == w->queued || w->journal_error; }

/* sync() -> None: returns once every row handed over is in the journal (the thread goes on with the
 * archive); OSError: a journal write failed. Ctrl-C ends the wait (KeyboardInterrupt). */
static PyObject *Writer_sync(Writer *w, PyObject *Py_UNUSED(ignored))
{
    if (!w->running) Py_RETURN_NONE; /* joined: whatever it journaled is there */
    if (wait_freed(w, all_journaled, 1) < 0) return NULL;
    int err = w->journal_error;
    pthread_mutex_unlock(&w->lock);
    if (err) return os_error(err);
    Py_RETURN_NONE;
}

/* finish() -> (rows written, (crc, ...)): every row handed over journaled and written, the thread
 * joined. OSError: a journal write failed, or an archive write (the archive is given up). */
static PyObject *Writer_finish(Writer *w, PyObject *Py_UNUSED(ignored))
{
    if (!w->running) {
        PyErr_SetString(PyExc_ValueError, "ColumnWriter.finish: finished or abandoned");
        return NULL;
    }
    if (stop_thread(w, 0) < 0) return NULL; /* a signal's exception (Ctrl-C) */
    if (w->journal_error) return os_error(w->journal_error);
    if (w->error) return os_error(w->error);
    int err = 0;
    if (!w->crcs_written || w->done != w->planned) { /* (the thread joined: no lock) */
        Py_BEGIN_ALLOW_THREADS
        err = write_crcs(w);
        Py_END_ALLOW_THREADS
    }
    if (err) return os_error(err);
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

/* abandon() -> None or the errno of a failed journal write: the thread joined once every chunk
 * handed over is journaled, the archive's work dropped (idempotent) */
static PyObject *Writer_abandon(Writer *w, PyObject *Py_UNUSED(ignored))
{
    stop_thread(w, 1);
    if (w->journal_error) return PyLong_FromLong(w->journal_error);
    Py_RETURN_NONE;
}

/* fail_journal_writes(count, errno): the next count journal writes fail with errno after half their
 * bytes and some beyond their end landed (a full disk, for the tests) */
static PyObject *Writer_fail_journal_writes(Writer *w, PyObject *args)
{
    int count, err;
    if (!PyArg_ParseTuple(args, "ii:fail_journal_writes", &count, &err)) return NULL;
    pthread_mutex_lock(&w->lock);
    w->test_failures = count;
    w->test_errno = err;
    pthread_mutex_unlock(&w->lock);
    Py_RETURN_NONE;
}

static int Writer_init(Writer *w, PyObject *args, PyObject *kwds)
{
    static char *kw[] = {"fd", "journal_fd", "journal_offset", "itemsize", "columns", "header", "planned_rows", NULL};
    int fd, journal_fd;
    long long journal_offset, planned_rows = 0;
    Py_ssize_t itemsize;
    PyObject *columns;
    Py_buffer header = {0};
    if (w->ready) {
        PyErr_SetString(PyExc_RuntimeError, "ColumnWriter: cannot be initialised twice");
        return -1;
    }
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "iiLnOy*|L:ColumnWriter", kw, &fd, &journal_fd, &journal_offset,
                                     &itemsize, &columns, &header, &planned_rows))
        return -1;
    if (itemsize < 1 || journal_offset < 0 || planned_rows < 0) {
        PyBuffer_Release(&header);
        PyErr_SetString(PyExc_ValueError,
                        "ColumnWriter: itemsize must be positive, journal_offset and planned_rows not negative");
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
    if (cols == NULL || slot_reserve(&w->values_buf, (size_t)n * READ_ROWS * sizeof(double)) < 0) {
        PyErr_NoMemory();
        goto bad;
    }
    for (Py_ssize_t j = 0; j < n; j++) {
        const char *code, *local = NULL;
        Py_ssize_t local_len = 0;
        unsigned long crc;
        column_t *col = &cols[j];
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(seq, j), "nsddLk|y#:ColumnWriter column", &col->field, &code,
                              &col->scale, &col->modulo, &col->place, &crc, &local, &local_len))
            goto bad;
        int width = field_width(code);
        col->prefix_len = local_len + header.len;
        if (width == 0 || col->field < 0 || col->field + width > itemsize || col->place < col->prefix_len) {
            PyErr_Format(PyExc_ValueError, "ColumnWriter: column %zd: a field %s at %zd of a %zd-byte row", j, code,
                         col->field, itemsize);
            goto bad;
        }
        if (local_len > 0 && local_len < LOCAL_CRC_AT + 4) {
            PyErr_Format(PyExc_ValueError, "ColumnWriter: column %zd: a %zd-byte local header has no CRC field", j,
                         local_len);
            goto bad;
        }
        col->code = code[0];
        col->crc = (uint32_t)crc;
        col->has_local = local_len > 0;
        col->prefix = malloc((size_t)col->prefix_len + 1);
        if (col->prefix == NULL) {
            PyErr_NoMemory();
            goto bad;
        }
        if (local_len) memcpy(col->prefix, local, (size_t)local_len);
        memcpy(col->prefix + local_len, header.buf, (size_t)header.len);
    }
    PyBuffer_Release(&header);
    if (pthread_mutex_init(&w->lock, NULL)) {
        PyErr_SetString(PyExc_OSError, "ColumnWriter: no lock");
        goto bad;
    }
    pthread_condattr_t monotonic;
    int no_cond = pthread_condattr_init(&monotonic);
    if (!no_cond) {
        no_cond = pthread_condattr_setclock(&monotonic, CLOCK_MONOTONIC) || pthread_cond_init(&w->freed, &monotonic);
        pthread_condattr_destroy(&monotonic);
    }
    if (no_cond || pthread_cond_init(&w->wake, NULL)) {
        if (!no_cond) pthread_cond_destroy(&w->freed);
        pthread_mutex_destroy(&w->lock);
        PyErr_SetString(PyExc_OSError, "ColumnWriter: no condition");
        goto bad;
    }
    Py_DECREF(seq);
    w->fd = fd;
    w->journal_fd = journal_fd;
    w->journal_offset = journal_offset;
    w->itemsize = itemsize;
    w->planned = (unsigned long long)planned_rows;
    w->n_cols = (int)n;
    w->cols = cols;
    w->values = (double *)w->values_buf.data;
    w->ready = 1;
    int err = start_writer_thread(&w->thread, writer_thread, w);
    if (err) {
        os_error(err);
        return -1;
    }
    w->running = 1;
    return 0;
bad:
    PyBuffer_Release(&header); /* (a no-op once released) */
    Py_DECREF(seq);
    free_columns(cols, n);
    slot_release(&w->values_buf);
    return -1;
}

static void Writer_dealloc(Writer *w)
{
    stop_thread(w, 1);
    if (w->ready) {
        pthread_mutex_destroy(&w->lock);
        pthread_cond_destroy(&w->wake);
        pthread_cond_destroy(&w->freed);
    }
    for (int i = 0; i < SLOTS; i++) slot_release(&w->slots[i]);
    free_columns(w->cols, w->n_cols);
    slot_release(&w->values_buf);
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
    uint32_t crc = crc32_fast((uint32_t)value, view.buf, (size_t)view.len);
    PyBuffer_Release(&view);
    return PyLong_FromUnsignedLong(crc);
}

static PyMethodDef Writer_methods[] = {
    {"submit_rows", (PyCFunction)Writer_submit_rows, METH_VARARGS,
     "submit_rows(first_row, data): whole raw rows from the journal's first_row on (== queued), copied: the "
     "thread journals them, then writes them to the archive."},
    {"sync", (PyCFunction)Writer_sync, METH_NOARGS, "sync(): returns once every row handed over is in the journal."},
    {"finish", (PyCFunction)Writer_finish, METH_NOARGS,
     "finish() -> (rows written, (crc, ...)): every row handed over journaled and written, the thread joined."},
    {"abandon", (PyCFunction)Writer_abandon, METH_NOARGS,
     "abandon() -> None or a failed journal write's errno: the thread joined once every row handed over is "
     "journaled, the archive's work dropped."},
    {"fail_journal_writes", (PyCFunction)Writer_fail_journal_writes, METH_VARARGS,
     "fail_journal_writes(count, errno): the next count journal writes fail (tests: a full disk)."},
    {NULL, NULL, 0, NULL},
};

static PyObject *Writer_journaled(Writer *w, void *Py_UNUSED(closure))
{
    pthread_mutex_lock(&w->lock);
    unsigned long long journaled = w->journaled;
    pthread_mutex_unlock(&w->lock);
    return PyLong_FromUnsignedLongLong(journaled);
}

static PyObject *Writer_queued(Writer *w, void *Py_UNUSED(closure))
{
    return PyLong_FromUnsignedLongLong(w->queued);
}

static PyGetSetDef Writer_getset[] = {
    {"queued", (getter)Writer_queued, NULL, "rows handed over so far", NULL},
    {"journaled", (getter)Writer_journaled, NULL, "rows the thread has written to the journal so far", NULL},
    {"rows_done", (getter)Writer_rows_done, NULL, "rows written (None while the thread runs)", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject WriterType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "hilbench.bench._npzcolumns.ColumnWriter",
    .tp_basicsize = sizeof(Writer),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "ColumnWriter(fd, journal_fd, journal_offset, itemsize, columns, header, planned_rows=0): raw rows "
              "handed over (submit_rows) written to the journal and as an archive's float64 columns on a thread; "
              "columns: (field offset, struct code, scale, modulo or 0, file "
              "offset of row 0, crc so far[, its member's ZIP local header]); header: the .npy header the thread "
              "writes before each column's row 0, after the local header (whose CRC the thread writes once it has "
              "converted planned_rows rows, else finish).",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Writer_init,
    .tp_dealloc = (destructor)Writer_dealloc,
    .tp_methods = Writer_methods,
    .tp_getset = Writer_getset,
};

/* ---- a file's last descriptor closed on a thread of its own ---------------------------------- */
/* The last close of an unlinked file frees its pages in the closing thread: a 1 s run's journal,
 * ~300 pages, 0.25 ms of the run's close on these VMs. The recorder unlinks the journal (cheap while
 * a descriptor is open), then hands that descriptor here (`close_later`). One detached thread,
 * started at need, closes them in turn and ends after CLOSER_IDLE_S without work (the process is
 * single-threaded again between runs that are not back to back); with the queue full, or no thread,
 * the caller closes it at once. A fork waits for a close in progress (`closing`); the child, which
 * has no closer thread, closes the descriptors it inherited queued. */
#define CLOSE_QUEUE 64
#define CLOSER_IDLE_S 2
static struct {
    pthread_mutex_t lock;    /* the queue's */
    pthread_mutex_t closing; /* the closer's from taking a descriptor off the queue to its close (lock order:
                                closing, then lock) */
    pthread_cond_t wake;
    int fds[CLOSE_QUEUE];
    int head, count;
    int in_flight;           /* taken off the queue, not yet closed */
    int running;             /* a closer thread runs in this process */
    int held;                /* hold_closer (tests): the closer takes nothing off the queue */
    long closed;             /* descriptors the closer threads closed (tests) */
} closer = {.lock = PTHREAD_MUTEX_INITIALIZER, .closing = PTHREAD_MUTEX_INITIALIZER, .wake = PTHREAD_COND_INITIALIZER};

/* Wait (lock held) until there is work or CLOSER_IDLE_S passed: 1 with work, 0 when idle. */
static int closer_wait(void)
{
    struct timespec until;
    clock_gettime(CLOCK_REALTIME, &until); /* (the condition's clock) */
    until.tv_sec += CLOSER_IDLE_S;
    while (closer.count == 0 || closer.held)
        if (pthread_cond_timedwait(&closer.wake, &closer.lock, &until) == ETIMEDOUT) {
            if (closer.count == 0) return 0;
            clock_gettime(CLOCK_REALTIME, &until); /* held with descriptors queued: on waiting */
            until.tv_sec += CLOSER_IDLE_S;
        }
    return 1;
}

static void *closer_thread(void *Py_UNUSED(arg))
{
    become_batch_thread();
    for (;;) {
        pthread_mutex_lock(&closer.lock);
        if (!closer_wait()) {
            closer.running = 0; /* (the next close_later starts another) */
            pthread_mutex_unlock(&closer.lock);
            return NULL;
        }
        pthread_mutex_unlock(&closer.lock);
        pthread_mutex_lock(&closer.closing);
        pthread_mutex_lock(&closer.lock);
        int fd = -1;
        if (closer.count > 0 && !closer.held) { /* (a fork's child handler may have emptied it meanwhile: not here) */
            fd = closer.fds[closer.head];
            closer.head = (closer.head + 1) % CLOSE_QUEUE;
            closer.count--;
            closer.in_flight = 1;
        }
        pthread_mutex_unlock(&closer.lock);
        if (fd >= 0) {
            close(fd);
            pthread_mutex_lock(&closer.lock);
            closer.in_flight = 0;
            closer.closed++;
            pthread_mutex_unlock(&closer.lock);
        }
        pthread_mutex_unlock(&closer.closing);
    }
}

static void closer_before_fork(void)
{
    pthread_mutex_lock(&closer.closing); /* no close in progress across the fork */
    pthread_mutex_lock(&closer.lock);
}

static void closer_after_fork_parent(void)
{
    pthread_mutex_unlock(&closer.lock);
    pthread_mutex_unlock(&closer.closing);
}

static void closer_after_fork_child(void) /* no closer thread here: what it inherited queued is closed now */
{
    for (; closer.count > 0; closer.count--) {
        close(closer.fds[closer.head]);
        closer.head = (closer.head + 1) % CLOSE_QUEUE;
    }
    closer.head = closer.in_flight = closer.running = closer.held = 0;
    pthread_cond_init(&closer.wake, NULL); /* (the parent's closer may have been waiting on it) */
    pthread_mutex_unlock(&closer.lock);    /* (this thread locked both before the fork) */
    pthread_mutex_unlock(&closer.closing);
}

/* close_later(fd): fd closed on the closer thread (now, on this one, when that cannot be) */
static PyObject *close_later(PyObject *Py_UNUSED(module), PyObject *arg)
{
    long value = PyLong_AsLong(arg);
    if (value == -1 && PyErr_Occurred()) return NULL;
    if (value < 0 || value > INT_MAX) {
        PyErr_SetString(PyExc_ValueError, "close_later: not a descriptor");
        return NULL;
    }
    int fd = (int)value, queued = 0;
    pthread_mutex_lock(&closer.lock);
    if (!closer.running) {
        pthread_t thread;
        if (start_writer_thread(&thread, closer_thread, NULL) == 0) {
            pthread_detach(thread);
            closer.running = 1;
        }
    }
    if (closer.running && closer.count < CLOSE_QUEUE) {
        closer.fds[(closer.head + closer.count) % CLOSE_QUEUE] = fd;
        closer.count++;
        pthread_cond_signal(&closer.wake);
        queued = 1;
    }
    pthread_mutex_unlock(&closer.lock);
    if (!queued) {
        Py_BEGIN_ALLOW_THREADS
        close(fd);
        Py_END_ALLOW_THREADS
    }
    Py_RETURN_NONE;
}

/* closer_state() -> (queued or being closed, closed by closer threads so far, a closer thread runs) (tests) */
static PyObject *closer_state(PyObject *Py_UNUSED(module), PyObject *Py_UNUSED(ignored))
{
    pthread_mutex_lock(&closer.lock);
    int pending = closer.count + closer.in_flight, running = closer.running;
    long closed = closer.closed;
    pthread_mutex_unlock(&closer.lock);
    return Py_BuildValue("(ilO)", pending, closed, running ? Py_True : Py_False);
}

/* hold_closer(flag) (tests): while held, the closer takes nothing off its queue */
static PyObject *hold_closer(PyObject *Py_UNUSED(module), PyObject *arg)
{
    int held = PyObject_IsTrue(arg);
    if (held < 0) return NULL;
    pthread_mutex_lock(&closer.lock);
    closer.held = held;
    pthread_cond_signal(&closer.wake);
    pthread_mutex_unlock(&closer.lock);
    Py_RETURN_NONE;
}

static PyMethodDef module_methods[] = {
    {"crc32", (PyCFunction)(void (*)(void))crc32_func, METH_FASTCALL, "crc32(data, value=0): zlib.crc32's value."},
    {"close_later", (PyCFunction)close_later, METH_O,
     "close_later(fd): fd closed on a thread of its own (the last close of an unlinked file frees its pages)."},
    {"closer_state", (PyCFunction)closer_state, METH_NOARGS,
     "closer_state() -> (descriptors queued or being closed, closed by closer threads so far, a closer runs)."},
    {"hold_closer", (PyCFunction)hold_closer, METH_O, "hold_closer(flag): the closer takes nothing while held (tests)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moduledef = {
    PyModuleDef_HEAD_INIT, "_npzcolumns", "An NPZ archive's columns written on a thread of their own (optional).", -1,
    module_methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__npzcolumns(void)
{
    crc32_init_tables(); /* before any writer thread: it only reads the tables */
    static int fork_handlers;
    if (!fork_handlers && pthread_atfork(closer_before_fork, closer_after_fork_parent, closer_after_fork_child) == 0)
        fork_handlers = 1;
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
