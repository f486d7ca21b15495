/* iq24.h: TI IQmath semantics for GLOBAL_Q = 24 (a C28x `_iq`) on portable C99 integers.
 *
 * Written for hilbench from docs/foc.md ("IQmath"; sources there: IQmathLib.h v1.5c and the C28x
 * IQmath user guide), not from TI's library. What the F2812 firmware relies on, and what each
 * primitive here does exactly:
 *   _iq        a 32-bit long: every sum, difference and product wraps modulo 2^32 (iq24_add, ...)
 *   _IQ(x)     (long)(x * 2^24), truncating toward zero. Constants are written here as the integer
 *              that cast yields (foc_config.h), never computed in the target's floating point:
 *              avr-gcc's double is 32 bits and would truncate differently.
 *   _IQmpy     the 64-bit product shifted right by 24 (floor), low 32 bits kept: no rounding, no
 *              saturation (iq24_mpy)
 *   _IQsat     clamp (iq24_sat); Q conversions are shifts, right shifts flooring (iq24_asr)
 *
 * No signed overflow and no right shift of a negative value is left to the compiler: sums wrap in
 * uint32_t and come back through iq24_from_u32, shifts floor explicitly. Safe with a 16-bit `int`
 * (AVR, C28x: every operand is a fixed-width type of at least 32 bits before it is combined).
 *
 * The 64-bit product, per target (IQ24_MPY_*, chosen below, overridable with -D):
 *   host, Cortex-M4: int64_t (one SMULL on the M4);
 *   AVR: four 16x16 -> 32 partial products in uint32_t (avr-gcc's 64-bit multiply is a slow libgcc
 *        call; IQ24_MPY_LIMBS), proven equal to the int64_t form by tests/test_foc_firmware_c.py;
 *   C28x under TI's compiler: the __IQmpy intrinsic (IMPYL/QMPYL: 32x32 -> 64 in hardware), which
 *        computes exactly this; with any other compiler for it, the int64_t form (long long is 64
 *        bits on the C28x).
 */
#ifndef FOC_IQ24_H
#define FOC_IQ24_H

#include <stdint.h>

#define IQ24_Q 24
#define IQ24_ONE ((int32_t)16777216L)   /* _IQ(1.0) */
#define IQ24_HALF ((int32_t)8388608L)   /* _IQ(0.5) */
#define IQ24_TWO ((int32_t)33554432L)   /* _IQ(2.0) */
#define IQ24_MAX ((int32_t)0x7FFFFFFFL)
#define IQ24_MIN ((int32_t)(-0x7FFFFFFFL - 1L))

typedef int32_t iq24_t;

#if !defined(IQ24_MPY_INT64) && !defined(IQ24_MPY_LIMBS) && !defined(IQ24_MPY_TI_INTRINSIC)
#if defined(__AVR__)
#define IQ24_MPY_LIMBS 1
#elif defined(__TMS320C28XX__)
#define IQ24_MPY_TI_INTRINSIC 1
#else
#define IQ24_MPY_INT64 1
#endif
#endif

/* The signed value of a 32-bit two's-complement pattern (what a C28x long holds). */
static inline int32_t iq24_from_u32(uint32_t u)
{
    if (u & 0x80000000UL) {
        return (int32_t)(-(int32_t)(0x7FFFFFFFUL - (u & 0x7FFFFFFFUL)) - (int32_t)1);
    }
    return (int32_t)u;
}

static inline int32_t iq24_add(int32_t a, int32_t b)
{
    return iq24_from_u32((uint32_t)a + (uint32_t)b);
}

static inline int32_t iq24_sub(int32_t a, int32_t b)
{
    return iq24_from_u32((uint32_t)a - (uint32_t)b);
}

static inline int32_t iq24_neg(int32_t a)
{
    return iq24_from_u32(0UL - (uint32_t)a);
}

/* a << n, wrapping (a Q conversion up: _IQ15toIQ is iq24_shl(a, 9)). */
static inline int32_t iq24_shl(int32_t a, uint16_t n)
{
    return iq24_from_u32((uint32_t)a << n);
}

/* a >> n, flooring (an arithmetic shift; C leaves >> of a negative value to the compiler). */
static inline int32_t iq24_asr(int32_t a, uint16_t n)
{
    if (a >= 0) {
        return (int32_t)((uint32_t)a >> n);
    }
    return iq24_from_u32(~(((uint32_t)~(uint32_t)a) >> n));
}

static inline int32_t iq24_sat(int32_t a, int32_t pos, int32_t neg)
{
    return a > pos ? pos : (a < neg ? neg : a);
}

/* Bits 24..55 of the 64-bit two's-complement product a*b: _IQmpy(a, b). Also _IQmpyI32int(a, n)
 * for an integer n (floor of a*n/2^24), and any _IQNmpy whose shift is 24 (Q21 x Q24 -> Q21). */
#if defined(IQ24_MPY_TI_INTRINSIC)
#define iq24_mpy(a, b) ((int32_t)__IQmpy((a), (b), 24))
#elif defined(IQ24_MPY_LIMBS)
static inline int32_t iq24_mpy(int32_t a, int32_t b)
{
    const uint32_t m16 = 0xFFFFu;
    uint32_t ua = (uint32_t)a, ub = (uint32_t)b;
    uint32_t al = ua & m16, ah = ua >> 16, bl = ub & m16, bh = ub >> 16;
    uint32_t ll = al * bl, lh = al * bh, hl = ah * bl, hh = ah * bh;
    uint32_t mid = (ll >> 16) + (lh & m16) + (hl & m16); /* < 3 * 2^16 */
    uint32_t lo = (ll & m16) | (mid << 16);
    uint32_t hi = hh + (lh >> 16) + (hl >> 16) + (mid >> 16);     /* unsigned product, mod 2^64 */
    if (a < 0) {
        hi -= ub; /* the signed product: minus 2^32 * b for a negative a, and likewise for b */
    }
    if (b < 0) {
        hi -= ua;
    }
    return iq24_from_u32((hi << 8) | (lo >> 24));
}
#else
static inline int32_t iq24_mpy(int32_t a, int32_t b)
{
    uint64_t p = (uint64_t)((int64_t)a * (int64_t)b);
    return iq24_from_u32((uint32_t)(p >> 24));
}
#endif

#endif /* FOC_IQ24_H */
