/* q15.h: the dsPIC30F DSP engine's fractional arithmetic on portable C99 integers.
 *
 * 1.15 signed fractional (Q15) words are int16_t. The accumulator is modelled as an int32_t holding
 * bits 31:0 of the chip's 40-bit accumulator: with CORCON.SATA = 1 and ACCSAT = 0 ("normal"
 * saturation, 1.31) the guard bits 39:32 never hold anything but sign, so 32 bits carry it exactly.
 * Sources (see docs/board.md, "Facts and sources"): dsPIC30F Family Reference Manual DS70062 (DSP
 * engine): a fractional multiply shifts the 16x16 product left by one; MAC adds into the
 * accumulator and, with SATA, clamps to 1.31 after the add; SAC stores bits 31:16 with no rounding
 * (SAC.R would round), saturated to 16 bits by SATDW; DIVF with REPEAT #17 gives the 1.15 quotient
 * of |dividend| < |divisor|, truncated toward zero.
 *
 * Every operation is exact with a 16-bit `int` (dsPIC30F, AVR): products are formed in int32_t,
 * the MAC's sum as one 32-bit unsigned add whose overflow is read from the high words and the
 * product's sign, SAC and the shifted product as high words (a floor division by 2^16 that C's `>>`
 * of a negative value would leave to the implementation), and differences that fit 16 bits in
 * 16 bits, so no int64_t is needed on a 16-bit MCU. These forms replaced 32-bit ones to fit the
 * dsPIC30F2010 (docs/board.md, section 3a); tests/test_q15_forms.py holds them equal to the earlier
 * forms (tests/q15_c/q15_before.h) on every operand pair of the 16-bit operations.
 */
#ifndef AN1017_Q15_H
#define AN1017_Q15_H

#include <stdint.h>

#define Q15_MAX 32767
#define Q15_MIN (-32767 - 1)
#define Q15_ACC_MAX ((int32_t)0x7FFFFFFF)
#define Q15_ACC_MIN ((int32_t)-0x7FFFFFFF - (int32_t)1)

/* Clamp to the Q15 range (SATDW on a data write, or the firmware's own clamps). */
static inline int16_t q15_sat(int32_t x)
{
    if (x > (int32_t)Q15_MAX) {
        return (int16_t)Q15_MAX;
    }
    if (x < (int32_t)Q15_MIN) {
        return (int16_t)Q15_MIN;
    }
    return (int16_t)x;
}

/* Two's-complement wrap of a value to 16 bits (what a C `int` on the dsPIC holds after + or -). */
static inline int16_t q15_wrap(int32_t x)
{
    uint16_t u = (uint16_t)((uint32_t)x & 0xFFFFu);
    return (u & 0x8000u) ? (int16_t)(-(int16_t)(0x7FFFu - (u & 0x7FFFu)) - 1) : (int16_t)u;
}

/* LAC: a Q15 word into accumulator bits 31:16. */
static inline int32_t q15_lac(int16_t q)
{
    return (int32_t)q * (int32_t)65536;
}

/* MAC with SATA: acc + a*b (fractional), clamped to 1.31 after the add. The product shifted once is
 * added as a 32-bit word; the addend's sign is the product's (only -1 * -1, whose shifted product 2^31
 * does not fit, would read negative from the word's top bit): the sum overflows when acc and the
 * addend have one sign and the wrapped sum the other. */
static inline int32_t q15_mac_sata(int32_t acc, int16_t a, int16_t b)
{
    int32_t p = (int32_t)a * (int32_t)b;
    uint32_t sum = (uint32_t)acc + ((uint32_t)p << 1);
    uint16_t hi = (uint16_t)(sum >> 16);
    uint16_t addend_sign = (p < 0) ? 0x8000u : 0u;
    if (((((uint16_t)((uint32_t)acc >> 16)) ^ hi) & (addend_sign ^ hi) & 0x8000u) != 0u) {
        return (acc < 0) ? Q15_ACC_MIN : Q15_ACC_MAX;
    }
    return (sum < 0x80000000UL) ? (int32_t)sum : (int32_t)(-(int32_t)(0xFFFFFFFFUL - sum) - 1);
}

/* Bits 31:16 of an accumulator value as a Q15 word (a register move on the chip). */
static inline int16_t q15_hi(uint32_t acc)
{
    return q15_wrap((int32_t)(acc >> 16));
}

/* SAC without rounding: bits 31:16 (truncation, i.e. floor), saturated by SATDW. floor(acc / 2^16) of
 * an int32_t always lies in -32768..32767, so the saturation never acts: SAC is the high word. */
static inline int16_t q15_sac(int32_t acc)
{
    return q15_hi((uint32_t)acc);
}

/* MPY then SAC: the truncating fractional product (-1 * -1 -> 32767): bits 31:16 of a*b << 1. */
static inline int16_t q15_mul(int16_t a, int16_t b)
{
    int32_t p = (int32_t)a * (int32_t)b;
    if (p == (int32_t)0x40000000) {
        return (int16_t)Q15_MAX;
    }
    return q15_hi((uint32_t)p << 1);
}

/* a - b clamped to Q15 (SAC of A - B), in 16-bit arithmetic: the difference overflows only when a and b
 * differ in sign and the wrapped difference has b's sign; then it saturates toward a's side. */
static inline int16_t q15_sub_sat(int16_t a, int16_t b)
{
    uint16_t d = (uint16_t)((uint16_t)a - (uint16_t)b);
    if ((((uint16_t)a ^ (uint16_t)b) & ((uint16_t)a ^ d) & 0x8000u) != 0u) {
        return (a < 0) ? (int16_t)Q15_MIN : (int16_t)Q15_MAX;
    }
    return (int16_t)(a - b); /* no overflow: exact */
}

/* DIVF: 1.15 quotient trunc(num * 32768 / den) for 0 <= |num| < |den| (the chip's precondition;
 * the caller guarantees it, as AN1017 does with _MINPERIOD = MINPERIOD - 1). */
static inline int16_t q15_divf(int16_t num, int16_t den)
{
    uint32_t n = (uint32_t)((num < 0) ? -(int32_t)num : (int32_t)num);
    uint32_t d = (uint32_t)((den < 0) ? -(int32_t)den : (int32_t)den);
    int32_t q = (int32_t)((n << 15) / d);
    return (int16_t)(((num < 0) != (den < 0)) ? -q : q);
}

/* DIVF of 0 <= num < den (AN1017's MeasuredSpeed): q15_divf without the signs. */
static inline int16_t q15_divf_pos(uint16_t num, uint16_t den)
{
    return (int16_t)(((uint32_t)num << 15) / den);
}

#endif /* AN1017_Q15_H */
