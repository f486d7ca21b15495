/* The 16-bit forms of firmware/an1017/q15.h (and AN1017's TPWM scaling) against the forms they
 * replaced (q15_before.h), operand by operand. Run by tests/test_q15_forms.py.
 *
 *   q15_equal full     every int16 pair of sub_sat and mul, every t x k of the scaling, every
 *                      0 <= num < den of DIVF, the MAC on edge operands and 2e8 random ones
 *   q15_equal          the same with every 5th first operand (all second operands) and 2e7 random
 *
 * Prints one line per form with its count of differences and exits 1 if any. */
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "q15.h"
#include "q15_before.h"

static uint64_t rng_state = 88172645463325252ULL;

static uint32_t rnd(void)
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return (uint32_t)rng_state;
}

/* AN1017's TPWM scaling: (t * k) >> 15 with a flooring shift before, the product's bits 30:15 now */
static uint16_t scale_before(uint16_t t, int16_t k)
{
    return (uint16_t)((uint32_t)old_q15_asr32((int32_t)t * (int32_t)k, 15u) & 0xFFFFu);
}

static uint16_t scale_now(uint16_t t, int16_t k)
{
    return (uint16_t)(((uint32_t)((int32_t)t * (int32_t)k) << 1) >> 16);
}

int main(int argc, char **argv)
{
    int full = argc > 1 && strcmp(argv[1], "full") == 0;
    int32_t step = full ? 1 : 5;
    long random_cases = full ? 200000000L : 20000000L;
    long bad_sub = 0, bad_mul = 0, bad_scale = 0, bad_divf = 0, bad_mac = 0;
    int32_t a, b;
    static const int32_t acc_edges[] = {0, 1, -1, 0x7FFFFFFF, (int32_t)-0x7FFFFFFF - 1, 0x40000000, -0x40000000,
                                        0x7FFF0000, (int32_t)0x80000001, 0x3FFFFFFF};
    static const int16_t q_edges[] = {0, 1, -1, 32767, -32768, 16384, -16384};
    unsigned i, j, k;
    long n;

    for (a = -32768; a <= 32767; a += (a >= 32767 - step) ? 1 : step) {
        for (b = -32768; b <= 32767; b++) {
            bad_sub += q15_sub_sat((int16_t)a, (int16_t)b) != old_q15_sat(a - b);
            bad_mul += q15_mul((int16_t)a, (int16_t)b) != old_q15_sac(old_q15_frac_mul((int16_t)a, (int16_t)b));
        }
    }
    for (a = 0; a <= 32767; a += (a >= 32767 - step) ? 1 : step) {
        for (b = -32768; b <= 32767; b++) {
            bad_scale += scale_before((uint16_t)a, (int16_t)b) != scale_now((uint16_t)a, (int16_t)b);
        }
    }
    for (b = 1; b <= 32767; b += (full || b < 64) ? 1 : step) {
        for (a = 0; a < b; a++) {
            bad_divf += q15_divf_pos((uint16_t)a, (uint16_t)b) != old_q15_divf((int16_t)a, (int16_t)b);
        }
    }
    for (i = 0; i < sizeof acc_edges / sizeof acc_edges[0]; i++) {
        for (j = 0; j < sizeof q_edges / sizeof q_edges[0]; j++) {
            for (k = 0; k < sizeof q_edges / sizeof q_edges[0]; k++) {
                bad_mac += q15_mac_sata(acc_edges[i], q_edges[j], q_edges[k])
                           != old_q15_mac_sata(acc_edges[i], q_edges[j], q_edges[k]);
            }
        }
    }
    for (n = 0; n < random_cases; n++) {
        int32_t acc = (int32_t)rnd();
        int16_t x = (int16_t)rnd(), y = (int16_t)rnd();
        if ((n & 1) && (rnd() & 0x80000000u)) { /* near the saturation limits, both signs */
            acc = (int32_t)(0x7FFFFFFF - (int32_t)(rnd() & 0xFFFFFF)) * ((n & 2) ? 1 : -1);
        }
        bad_mac += q15_mac_sata(acc, x, y) != old_q15_mac_sata(acc, x, y);
    }
    printf("q15_sub_sat: %ld differ\nq15_mul: %ld differ\nscale15: %ld differ\nq15_divf_pos: %ld differ\n"
           "q15_mac_sata: %ld differ (%ld random)\n", bad_sub, bad_mul, bad_scale, bad_divf, bad_mac, random_cases);
    return (bad_sub || bad_mul || bad_scale || bad_divf || bad_mac) ? 1 : 0;
}
