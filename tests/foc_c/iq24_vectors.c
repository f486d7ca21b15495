/* iq24_vectors.c: iq24_mpy of each "a b" line on stdin, one result a line (tests/test_foc_firmware_c.py
 * builds it once with the int64_t product and once with the 16-bit limbs the AVR build uses). */
#include <stdio.h>

#include "iq24.h"

int main(void)
{
    long a, b;
    while (scanf("%ld %ld", &a, &b) == 2) {
        printf("%ld\n", (long)iq24_mpy((int32_t)a, (int32_t)b));
    }
    return 0;
}
