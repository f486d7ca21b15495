/* CRC-32 as zlib computes it (reflected polynomial 0xEDB88320, register preset to all ones and
 * inverted at the end): crc32_fast(crc, p, n) == zlib.crc32(p[:n], crc), and chaining works
 * (crc32_fast(crc32_fast(c, a), b) is the CRC of a followed by b).
 *
 *   crc32_init_tables()  builds the tables and, on x86-64, detects PCLMULQDQ + SSE4.1 once. Call it
 *                        once (module init) BEFORE any thread may call crc32_fast; calling it again
 *                        later is a no-op and is safe. crc32_fast on a thread, concurrently with other
 *                        callers, only reads the tables and the cached state: thread-safe.
 *                        Before the first init crc32_fast is still exact (a bit-at-a-time loop
 *                        without tables), only slow.
 *   crc32_fast()         on x86-64 with PCLMULQDQ and SSE4.1 (and n >= 32): carry-less multiplication
 *                        folding, 4 x 128 bits per step, then 128 at a time, the last 16 folded bytes
 *                        and the < 16 byte tail through the tables; otherwise slice-by-8 tables.
 *   HILBENCH_CRC32_PORTABLE  defined before the include (or -D): the table path only, on any host.
 *
 * Plain C99 plus GCC attributes/builtins; <immintrin.h> on x86-64 only. The accelerated function
 * carries __attribute__((target("pclmul,sse4.1"))), so no -m flag is needed to compile this.
 * Self-contained; every helper is `static inline` and prefixed hb_crc32_, so nothing is left unused.
 * tests/test_crc32_fast.py checks both paths against zlib.crc32 and re-derives the constants below.
 *
 * ---- The folding, and where its constants come from ----------------------------------------------
 * Bits are read as the reflected CRC reads them: within the message, the least significant bit of a
 * byte comes first, the earliest bit is the highest power of x. A 128-bit vector loaded (little-
 * endian) from 16 message bytes then holds in bit k the coefficient of x^(127-k), relative to the end
 * of those bytes; its low 64-bit lane H carries an extra x^64, its high lane L none, and within a
 * 64-bit lane bit j is x^(63-j). The CRC register is S(x) * x^32 mod P for the bits S read so far
 * (the preset ~crc xored into the first four bytes), so what matters is S mod P.
 *
 * To step a vector X = H x^64 + L over T further bits Y: X x^T + Y == H x^(64+T) + L x^T + Y (mod P).
 * PCLMULQDQ of two 64-bit lanes in this bit order gives their product times x (the 127-bit product
 * lands one bit low in a 128-bit vector read as above), so the lane constants are
 *     for H:  x^(63+T) mod P,     for L:  x^(T-1) mod P,
 * each a polynomial of degree < 32 written in lane order (x^d at bit 63-d: the bit-reversed 32-bit
 * remainder shifted up by 32). Both products have degree < 96: the result is again a 128-bit vector,
 * congruent, which is all folding needs. T = 512 (four vectors in flight), T = 128 (one).
 * Derivation (Python; tests/test_crc32_fast.py runs it and compares with the values below):
 *     P = 0x104C11DB7                     # x^32 + x^26 + ... + x + 1, bit d = coefficient of x^d
 *     def xmod(e):                        # x^e mod P over GF(2)
 *         r = 1
 *         for _ in range(e):
 *             r <<= 1
 *             if r >> 32: r ^= P
 *         return r
 *     def lane(e): return int(f"{xmod(e):032b}"[::-1], 2) << 32
 *     lane(575), lane(511), lane(191), lane(127)
 * The final 128-bit vector X is congruent to everything read so far, so the register is
 * X x^32 mod P: the table CRC of X's 16 bytes from a zero register; the tail bytes follow.
 */
#ifndef HILBENCH_CRC32_H
#define HILBENCH_CRC32_H

#include <stddef.h>
#include <stdint.h>

#if defined(__x86_64__) && defined(__GNUC__) && !defined(HILBENCH_CRC32_PORTABLE)
#define HB_CRC32_CLMUL 1
#include <immintrin.h>
#else
#define HB_CRC32_CLMUL 0
#endif

#define HB_CRC32_POLY 0xEDB88320u           /* reflected x^32 + x^26 + x^23 + ... + x + 1 */
#define HB_CRC32_X575 0x653d982200000000ULL /* lane(575): fold by 512 bits, low lane */
#define HB_CRC32_X511 0xcad38e8f00000000ULL /* lane(511): fold by 512 bits, high lane */
#define HB_CRC32_X191 0x65673b4600000000ULL /* lane(191): fold by 128 bits, low lane */
#define HB_CRC32_X127 0x9ba54c6f00000000ULL /* lane(127): fold by 128 bits, high lane */
#define HB_CRC32_CLMUL_MIN 32               /* shorter buffers go through the tables */

/* hb_crc32_table[k][b]: the register's change for the byte b followed by k zero bytes */
static uint32_t hb_crc32_table[8][256];
/* 0: crc32_init_tables not run yet; 1: tables ready; 2: tables ready and PCLMULQDQ + SSE4.1 usable */
static int hb_crc32_state;

#if defined(__GNUC__)
#define HB_CRC32_LOAD_STATE() __atomic_load_n(&hb_crc32_state, __ATOMIC_ACQUIRE)
#define HB_CRC32_STORE_STATE(v) __atomic_store_n(&hb_crc32_state, (v), __ATOMIC_RELEASE)
#else
#define HB_CRC32_LOAD_STATE() (*(volatile int *)&hb_crc32_state)
#define HB_CRC32_STORE_STATE(v) (*(volatile int *)&hb_crc32_state = (v))
#endif

/* one bit of the register: shift out the x^31 end, subtract P where it carried */
static inline uint32_t hb_crc32_shift1(uint32_t r)
{
    return (r >> 1) ^ (HB_CRC32_POLY & (0u - (r & 1u)));
}

static inline void crc32_init_tables(void)
{
    if (HB_CRC32_LOAD_STATE() != 0) return;
    for (uint32_t b = 0; b < 256; b++) {
        uint32_t r = b;
        for (int i = 0; i < 8; i++) r = hb_crc32_shift1(r);
        hb_crc32_table[0][b] = r;
    }
    for (int k = 1; k < 8; k++)
        for (uint32_t b = 0; b < 256; b++) {
            uint32_t before = hb_crc32_table[k - 1][b]; /* one more zero byte after it */
            hb_crc32_table[k][b] = (before >> 8) ^ hb_crc32_table[0][before & 0xFFu];
        }
    int state = 1;
#if HB_CRC32_CLMUL
    __builtin_cpu_init();
    if (__builtin_cpu_supports("pclmul") && __builtin_cpu_supports("sse4.1")) state = 2;
#endif
    HB_CRC32_STORE_STATE(state);
}

/* bytes p[0..3] as a little-endian word, on any host (gcc makes it one load on x86) */
static inline uint32_t hb_crc32_le32(const unsigned char *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

/* eight bytes at once: first = bytes 0..3, second = bytes 4..7, both little-endian words */
static inline uint32_t hb_crc32_eight(uint32_t r, uint32_t first, uint32_t second)
{
    const uint32_t(*t)[256] = (const uint32_t(*)[256])hb_crc32_table;
    first ^= r;
    return t[7][first & 0xFFu] ^ t[6][(first >> 8) & 0xFFu] ^ t[5][(first >> 16) & 0xFFu] ^ t[4][first >> 24]
           ^ t[3][second & 0xFFu] ^ t[2][(second >> 8) & 0xFFu] ^ t[1][(second >> 16) & 0xFFu] ^ t[0][second >> 24];
}

/* the register r (no inversions) over n bytes, slice-by-8 */
static inline uint32_t hb_crc32_sliced(uint32_t r, const unsigned char *p, size_t n)
{
    for (; n >= 8; p += 8, n -= 8) r = hb_crc32_eight(r, hb_crc32_le32(p), hb_crc32_le32(p + 4));
    for (; n > 0; p++, n--) r = (r >> 8) ^ hb_crc32_table[0][(r ^ *p) & 0xFFu];
    return r;
}

/* the register r over n bytes a bit at a time: before crc32_init_tables only */
static inline uint32_t hb_crc32_bitwise(uint32_t r, const unsigned char *p, size_t n)
{
    for (; n > 0; p++, n--) {
        r ^= *p;
        for (int i = 0; i < 8; i++) r = hb_crc32_shift1(r);
    }
    return r;
}

#if HB_CRC32_CLMUL
/* X x^T + next, with k = {lane for H (low), lane for L (high)} of that T */
__attribute__((target("pclmul,sse4.1"))) static inline __m128i hb_crc32_fold(__m128i x, __m128i k, __m128i next)
{
    __m128i h = _mm_clmulepi64_si128(x, k, 0x00); /* H * low lane  */
    __m128i l = _mm_clmulepi64_si128(x, k, 0x11); /* L * high lane */
    return _mm_xor_si128(_mm_xor_si128(h, l), next);
}

__attribute__((target("pclmul,sse4.1"))) static inline __m128i hb_crc32_load(const unsigned char *p)
{
    return _mm_loadu_si128((const __m128i *)(const void *)p); /* any alignment */
}

/* the register r (no inversions) over n >= 16 bytes, by folding */
__attribute__((target("pclmul,sse4.1"))) static inline uint32_t hb_crc32_clmul(uint32_t r, const unsigned char *p, size_t n)
{
    const __m128i k128 = _mm_set_epi64x((long long)HB_CRC32_X127, (long long)HB_CRC32_X191);
    __m128i x = _mm_xor_si128(hb_crc32_load(p), _mm_cvtsi32_si128((int)r));
    p += 16;
    n -= 16;
    if (n >= 48) { /* four vectors in flight, each stepping over the other three and the next one */
        const __m128i k512 = _mm_set_epi64x((long long)HB_CRC32_X511, (long long)HB_CRC32_X575);
        __m128i x1 = hb_crc32_load(p), x2 = hb_crc32_load(p + 16), x3 = hb_crc32_load(p + 32);
        p += 48;
        n -= 48;
        for (; n >= 64; p += 64, n -= 64) {
            x = hb_crc32_fold(x, k512, hb_crc32_load(p));
            x1 = hb_crc32_fold(x1, k512, hb_crc32_load(p + 16));
            x2 = hb_crc32_fold(x2, k512, hb_crc32_load(p + 32));
            x3 = hb_crc32_fold(x3, k512, hb_crc32_load(p + 48));
        }
        x = hb_crc32_fold(x, k128, x1);
        x = hb_crc32_fold(x, k128, x2);
        x = hb_crc32_fold(x, k128, x3);
    }
    for (; n >= 16; p += 16, n -= 16) x = hb_crc32_fold(x, k128, hb_crc32_load(p));
    /* X x^32 mod P: X's 16 bytes through the tables from a zero register, then the tail */
    uint64_t first = (uint64_t)_mm_cvtsi128_si64(x), second = (uint64_t)_mm_extract_epi64(x, 1);
    r = hb_crc32_eight(0, (uint32_t)first, (uint32_t)(first >> 32));
    r = hb_crc32_eight(r, (uint32_t)second, (uint32_t)(second >> 32));
    return hb_crc32_sliced(r, p, n);
}
#endif

/* 1 when crc32_fast takes the PCLMULQDQ path (after crc32_init_tables), else 0 */
static inline int crc32_accelerated(void)
{
    return HB_CRC32_LOAD_STATE() == 2;
}

static inline uint32_t crc32_fast(uint32_t crc, const unsigned char *p, size_t n)
{
    int state = HB_CRC32_LOAD_STATE();
    if (state == 0) return ~hb_crc32_bitwise(~crc, p, n); /* exact without the tables, if slow */
#if HB_CRC32_CLMUL
    if (state == 2 && n >= HB_CRC32_CLMUL_MIN) return ~hb_crc32_clmul(~crc, p, n);
#endif
    return ~hb_crc32_sliced(~crc, p, n);
}

#endif /* HILBENCH_CRC32_H */
