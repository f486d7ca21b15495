/* q15_before.h: firmware/an1017/q15.h as it was before the dsPIC30F2010 size cuts (49dcac4), its names
 * prefixed old_: the reference tests/test_q15_forms.py holds the 16-bit forms equal to.
 *
 * The dsPIC30F DSP engine's fractional arithmetic on portable C99 integers.
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
 * accumulator sums in a saturating add that never overflows (old_q15_sat_add32), so no int64_t is
 * needed on a 16-bit MCU. Right shifts of negative values are written as floor divisions
 * (old_q15_asr32) because C leaves `>>` of a negative value to the implementation.
 */
#ifndef OLD_Q15_H
#define OLD_Q15_H

#include <stdint.h>

#define OLD_Q15_MAX 32767
#define OLD_Q15_MIN (-32767 - 1)
#define OLD_Q15_ACC_MAX ((int32_t)0x7FFFFFFF)
#define OLD_Q15_ACC_MIN ((int32_t)-0x7FFFFFFF - (int32_t)1)

/* Arithmetic (flooring) right shift of a signed 32-bit value, n in 0..30. */
static inline int32_t old_q15_asr32(int32_t a, uint8_t n)
{
    if (a >= 0) {
        return (int32_t)((uint32_t)a >> n);
    }
    return (int32_t)~(((uint32_t)~(uint32_t)a) >> n);
}

/* Clamp to the Q15 range (SATDW on a data write, or the firmware's own clamps). */
static inline int16_t old_q15_sat(int32_t x)
{
    if (x > (int32_t)OLD_Q15_MAX) {
        return (int16_t)OLD_Q15_MAX;
    }
    if (x < (int32_t)OLD_Q15_MIN) {
        return (int16_t)OLD_Q15_MIN;
    }
    return (int16_t)x;
}

/* Two's-complement wrap of a value to 16 bits (what a C `int` on the dsPIC holds after + or -). */
static inline int16_t old_q15_wrap(int32_t x)
{
    uint16_t u = (uint16_t)((uint32_t)x & 0xFFFFu);
    return (u & 0x8000u) ? (int16_t)(-(int16_t)(0x7FFFu - (u & 0x7FFFu)) - 1) : (int16_t)u;
}

/* a + b clamped to 1.31, without ever overflowing int32_t. */
static inline int32_t old_q15_sat_add32(int32_t a, int32_t b)
{
    uint32_t sum = (uint32_t)a + (uint32_t)b; /* wraps: defined for unsigned */
    if ((((uint32_t)a ^ sum) & ((uint32_t)b ^ sum) & 0x80000000UL) != 0u) {
        return (a < 0) ? OLD_Q15_ACC_MIN : OLD_Q15_ACC_MAX; /* a and b of one sign, the sum of the other */
    }
    return a + b;
}

/* LAC: a Q15 word into accumulator bits 31:16. */
static inline int32_t old_q15_lac(int16_t q)
{
    return (int32_t)q * (int32_t)65536;
}

/* Fractional product a*b << 1 as an accumulator value. Only -1 * -1 (2^31) does not fit 1.31:
 * the chip's 40-bit accumulator holds it, and the 1.31 saturation that follows (SATA) makes it
 * 0x7FFFFFFF; this returns that saturated value directly. */
static inline int32_t old_q15_frac_mul(int16_t a, int16_t b)
{
    int32_t p = (int32_t)a * (int32_t)b;
    if (p == (int32_t)0x40000000) {
        return OLD_Q15_ACC_MAX;
    }
    return p * (int32_t)2;
}

/* MAC with SATA: acc + a*b (fractional), clamped to 1.31 after the add. */
static inline int32_t old_q15_mac_sata(int32_t acc, int16_t a, int16_t b)
{
    int32_t p = (int32_t)a * (int32_t)b;
    if (p == (int32_t)0x40000000) { /* -1 * -1: acc + 2^31, which saturates unless acc < 0 */
        return (acc >= 0) ? OLD_Q15_ACC_MAX : (int32_t)((uint32_t)acc + 0x80000000UL);
    }
    return old_q15_sat_add32(acc, p * (int32_t)2);
}

/* SAC without rounding: bits 31:16 (truncation, i.e. floor), saturated by SATDW. */
static inline int16_t old_q15_sac(int32_t acc)
{
    return old_q15_sat(old_q15_asr32(acc, 16u));
}

/* MPY then SAC: the truncating fractional product (-1 * -1 -> 32767). */
static inline int16_t old_q15_mul(int16_t a, int16_t b)
{
    return old_q15_sac(old_q15_frac_mul(a, b));
}

/* DIVF: 1.15 quotient trunc(num * 32768 / den) for 0 <= |num| < |den| (the chip's precondition;
 * the caller guarantees it, as AN1017 does with _MINPERIOD = MINPERIOD - 1). */
static inline int16_t old_q15_divf(int16_t num, int16_t den)
{
    uint32_t n = (uint32_t)((num < 0) ? -(int32_t)num : (int32_t)num);
    uint32_t d = (uint32_t)((den < 0) ? -(int32_t)den : (int32_t)den);
    int32_t q = (int32_t)((n << 15) / d);
    return (int16_t)(((num < 0) != (den < 0)) ? -q : q);
}

#endif /* OLD_Q15_H */
