/* A raw row's field as a recording's column value: recorder.RowLayout.to_column in C, shared by the
 * NPZ archive's column writer (_npzcolumns.c) and the CSV row writer (_csvrows.c), so both read a
 * raw row one way: the field as a double, times its scale unless the scale is 1, an angle wrapped
 * into [0, modulo) as numpy.mod wraps it. Little-endian hosts only. */
#ifndef HILBENCH_RAWFIELDS_H
#define HILBENCH_RAWFIELDS_H

#include <math.h>
#include <stdint.h>
#include <string.h>

static double field_value(const unsigned char *p, char code)
{
    switch (code) {
    case 'B': return (double)p[0];
    case 'h': { int16_t v; memcpy(&v, p, 2); return (double)v; }
    case 'H': { uint16_t v; memcpy(&v, p, 2); return (double)v; }
    case 'i': { int32_t v; memcpy(&v, p, 4); return (double)v; }
    case 'I': { uint32_t v; memcpy(&v, p, 4); return (double)v; }
    case 'q': { int64_t v; memcpy(&v, p, 8); return (double)v; }
    case 'Q': { uint64_t v; memcpy(&v, p, 8); return (double)v; }
    case 'f': { float v; memcpy(&v, p, 4); return (double)v; }
    default: { double v; memcpy(&v, p, 8); return v; }
    }
}

/* field_value of n rows ``stride`` bytes apart into out: the code's switch once, not once a row */
static inline void field_column(double *out, const unsigned char *p, size_t n, size_t stride, char code)
{
#define HILBENCH_FIELD_LOOP(type)                                                                       \
    for (size_t i = 0; i < n; i++, p += stride) {                                                     \
        type v;                                                                                         \
        memcpy(&v, p, sizeof v);                                                                        \
        out[i] = (double)v;                                                                             \
    }                                                                                                   \
    return;
    switch (code) {
    case 'B': HILBENCH_FIELD_LOOP(uint8_t)
    case 'h': HILBENCH_FIELD_LOOP(int16_t)
    case 'H': HILBENCH_FIELD_LOOP(uint16_t)
    case 'i': HILBENCH_FIELD_LOOP(int32_t)
    case 'I': HILBENCH_FIELD_LOOP(uint32_t)
    case 'q': HILBENCH_FIELD_LOOP(int64_t)
    case 'Q': HILBENCH_FIELD_LOOP(uint64_t)
    case 'f': HILBENCH_FIELD_LOOP(float)
    default: HILBENCH_FIELD_LOOP(double)
    }
#undef HILBENCH_FIELD_LOOP
}

/* numpy's float remainder (npy_remainder / npy_divmod): the sign of the divisor */
static double np_remainder(double a, double b)
{
    double mod = fmod(a, b);
    if (!b) return mod;
    if (mod) {
        if ((b < 0) != (mod < 0)) mod += b;
    } else {
        mod = copysign(0.0, b);
    }
    return mod;
}

/* the width of a struct code's field (recorder._CODE_DTYPES), 0 for a code it does not know */
static int field_width(const char *code)
{
    static const char codes[] = "BhHiIqQfd", widths[] = {1, 2, 2, 4, 4, 8, 8, 4, 8};
    const char *at = strlen(code) == 1 ? strchr(codes, code[0]) : NULL;
    return at != NULL ? widths[at - codes] : 0;
}

#endif
