/* hostcheck/c28x_types.h: the C28x type environment, as far as a host compiler can show it.
 *
 * On the C28x (TI C2000 compiler) char, short and int are 16 bits (CHAR_BIT = 16, sizeof(int) = 1),
 * long is 32 and long long 64; <stdint.h> has int16_t/uint16_t/int32_t/uint32_t/int64_t/uint64_t
 * and the least/fast types, but NO int8_t/uint8_t: no type is 8 bits wide. A host compiler cannot
 * make char 16 bits, so this header defines the TI spellings the port and TI's headers use (Uint16,
 * Int32, ...), and with C28X_POISON_UINT8 defined (the check of the sources that must build for the
 * C28x as they are: the FOC firmware) any use of int8_t/uint8_t is an error: they are poisoned
 * after <stdint.h> has defined them. What this leaves unverified (sizeof counting 16-bit chars,
 * char arithmetic wider than 8 bits, int promotions at 16 bits) is listed in docs/foc.md. */
#ifndef HOSTCHECK_C28X_TYPES_H
#define HOSTCHECK_C28X_TYPES_H

#include <stdint.h>

#if defined(C28X_POISON_UINT8)
#pragma GCC poison int8_t uint8_t
#endif

typedef int16_t int16;
typedef int32_t int32;
typedef uint16_t Uint16;
typedef uint32_t Uint32;
typedef int16_t Int16;
typedef int32_t Int32;

#endif /* HOSTCHECK_C28X_TYPES_H */
