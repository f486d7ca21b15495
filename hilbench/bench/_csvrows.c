/* CSV rows in C: the accelerator of Recorder._format_csv's `fmt % row` (hilbench/bench/recorder.py).
 *
 * format_rows(columns, formats, start, stop) -> str: rows start..stop-1 of float64 columns, each
 * cell as Python's printf-style `%` formats it, cells joined by "," and rows ended by "\n"; or None
 * when a format or a value is one it leaves to Python (the caller formats the block there). Formats
 * it takes: "%d" (int(x): finite values below 2^63) and "%.Nf", "%.Ne", "%.Ng" (N <= 17).
 * "%.Nf" of a finite value below 2^63 with N <= 9 is the exact decimal of the binary value rounded
 * half to even (what Python's correctly rounded dtoa gives); every other float goes through
 * PyOS_double_to_string, the function Python's `%` calls. tests/test_csv_rows.py checks both paths
 * against `%` over edge values (ties, signed zeros, NaN, infinities, huge and tiny values).
 */
#ifndef PY_SSIZE_T_CLEAN
#define PY_SSIZE_T_CLEAN
#endif
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#define MAX_COLUMNS 256
#define CELL_MAX 400 /* the longest cell: %.17f of 2^63 is 37 characters; the others go to PyOS */

typedef struct {
    char conv;  /* 'd', 'f', 'e', 'g' */
    int prec;
} spec_t;

static int parse_format(PyObject *f, spec_t *out)
{
    Py_ssize_t n;
    const char *s = PyUnicode_AsUTF8AndSize(f, &n);
    if (s == NULL) return -1;
    if (n == 2 && s[0] == '%' && s[1] == 'd') {
        out->conv = 'd';
        out->prec = 0;
        return 1;
    }
    if ((n == 4 || n == 5) && s[0] == '%' && s[1] == '.' && s[2] >= '0' && s[2] <= '9') {
        int prec = s[2] - '0';
        const char *c = s + 3;
        if (n == 5) {
            if (s[3] < '0' || s[3] > '9') return 0;
            prec = prec * 10 + (s[3] - '0');
            c = s + 4;
        }
        if ((*c == 'f' || *c == 'e' || *c == 'g') && prec <= 17) {
            out->conv = *c;
            out->prec = prec;
            return 1;
        }
    }
    return 0;
}

static const uint64_t POW10[10] = {1ULL, 10ULL, 100ULL, 1000ULL, 10000ULL, 100000ULL, 1000000ULL, 10000000ULL,
                                   100000000ULL, 1000000000ULL};

/* "%.Nf" of a finite |x| < 2^63, N <= 9: x = m * 2^e exactly, x * 10^N rounded half to even in
 * 128-bit integers, the point put in. Returns the length written. */
static int fixed(char *out, double x, int prec)
{
    int neg = signbit(x) != 0;
    double a = fabs(x);
    int e2;
    double fr = frexp(a, &e2); /* a = fr * 2^e2, fr in [0.5, 1) */
    uint64_t m = (uint64_t)ldexp(fr, 53); /* exact: 53 bits */
    int e = e2 - 53;                       /* a = m * 2^e */
    unsigned __int128 p = (unsigned __int128)m * POW10[prec];
    unsigned __int128 q;
    if (a == 0.0) {
        q = 0;
    } else if (e >= 0) {
        q = p << e; /* a < 2^63 and 10^9 < 2^30: below 2^93 */
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
    char digits[48];
    int nd = 0;
    while (q >> 64) { /* rare: the 128-bit division is a library call */
        digits[nd++] = (char)('0' + (int)(q % 10u));
        q /= 10u;
    }
    uint64_t q64 = (uint64_t)q;
    do {
        digits[nd++] = (char)('0' + (int)(q64 % 10u));
        q64 /= 10u;
    } while (q64 != 0);
    while (nd <= prec) digits[nd++] = '0'; /* at least one digit before the point */
    int len = 0;
    if (neg) out[len++] = '-';
    for (int i = nd - 1; i >= 0; i--) {
        if (i == prec - 1) out[len++] = '.';
        out[len++] = digits[i];
    }
    return len;
}

/* One cell: its length, or -1 with an exception, or -2 when Python should format the block. */
static int cell(char *out, double x, const spec_t *sp)
{
    if (sp->conv == 'd') {
        if (!isfinite(x) || fabs(x) >= 9.2e18) return -2; /* int(x): Python's own (or its error) */
        long long v = (long long)x;
        unsigned long long u = v < 0 ? 0ULL - (unsigned long long)v : (unsigned long long)v;
        char digits[24];
        int nd = 0, len = 0;
        do {
            digits[nd++] = (char)('0' + (int)(u % 10u));
            u /= 10u;
        } while (u != 0);
        if (v < 0) out[len++] = '-';
        while (nd > 0) out[len++] = digits[--nd];
        return len;
    }
    if (sp->conv == 'f' && sp->prec <= 9 && isfinite(x) && fabs(x) < 9.2e18) return fixed(out, x, sp->prec);
    char *s = PyOS_double_to_string(x, sp->conv, sp->prec, 0, NULL);
    if (s == NULL) return -1;
    size_t n = strlen(s);
    if (n >= CELL_MAX) {
        PyMem_Free(s);
        return -2;
    }
    memcpy(out, s, n);
    PyMem_Free(s);
    return (int)n;
}

static PyObject *format_rows(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "format_rows(columns, formats, start, stop)");
        return NULL;
    }
    Py_ssize_t start = PyLong_AsSsize_t(args[2]), stop = PyLong_AsSsize_t(args[3]);
    if (PyErr_Occurred()) return NULL;
    PyObject *cols = PySequence_Fast(args[0], "format_rows: columns must be a sequence");
    if (cols == NULL) return NULL;
    PyObject *fmts = PySequence_Fast(args[1], "format_rows: formats must be a sequence");
    if (fmts == NULL) { Py_DECREF(cols); return NULL; }
    Py_ssize_t nc = PySequence_Fast_GET_SIZE(cols);
    PyObject *result = NULL;
    Py_buffer views[MAX_COLUMNS];
    spec_t specs[MAX_COLUMNS];
    Py_ssize_t got = 0;
    char *text = NULL;
    if (nc != PySequence_Fast_GET_SIZE(fmts) || nc == 0 || nc > MAX_COLUMNS) {
        result = Py_NewRef(Py_None); /* Python's path says what is wrong, if anything */
        goto done;
    }
    for (Py_ssize_t c = 0; c < nc; c++) {
        int ok = parse_format(PySequence_Fast_GET_ITEM(fmts, c), &specs[c]);
        if (ok < 0) goto done;
        if (ok == 0) { result = Py_NewRef(Py_None); goto done; }
    }
    for (; got < nc; got++) {
        if (PyObject_GetBuffer(PySequence_Fast_GET_ITEM(cols, got), &views[got], PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
            goto done;
        Py_buffer *v = &views[got];
        if (v->itemsize != 8 || v->format == NULL || strcmp(v->format, "d") != 0 || v->len / 8 < stop
            || start < 0 || start > stop) {
            got++;
            result = Py_NewRef(Py_None);
            goto done;
        }
    }
    Py_ssize_t cap = 4096, len = 0;
    text = PyMem_Malloc((size_t)cap);
    if (text == NULL) { PyErr_NoMemory(); goto done; }
    for (Py_ssize_t r = start; r < stop; r++) {
        for (Py_ssize_t c = 0; c < nc; c++) {
            if (len + CELL_MAX + 2 > cap) {
                cap *= 2;
                char *t = PyMem_Realloc(text, (size_t)cap);
                if (t == NULL) { PyErr_NoMemory(); goto done; }
                text = t;
            }
            int n = cell(text + len, ((const double *)views[c].buf)[r], &specs[c]);
            if (n == -1) goto done;
            if (n == -2) { result = Py_NewRef(Py_None); goto done; }
            len += n;
            text[len++] = c + 1 < nc ? ',' : '\n';
        }
    }
    result = PyUnicode_DecodeASCII(text, len, NULL);
done:
    PyMem_Free(text);
    for (Py_ssize_t c = 0; c < got; c++) PyBuffer_Release(&views[c]);
    Py_DECREF(cols);
    Py_DECREF(fmts);
    return result;
}

static PyMethodDef methods[] = {
    {"format_rows", (PyCFunction)(void (*)(void))format_rows, METH_FASTCALL,
     "format_rows(columns, formats, start, stop) -> str | None: rows of float64 columns as `fmt % row` writes them."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moduledef = {
    PyModuleDef_HEAD_INIT, "_csvrows", "CSV rows in C (optional; Recorder._format_csv is the reference).", -1, methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__csvrows(void) { return PyModule_Create(&moduledef); }
