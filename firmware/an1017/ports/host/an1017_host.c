/* ports/host/an1017_host.c: the AN1017 firmware as a host process (software in the loop) on a tty.
 *
 * Usage: an1017_sil [--variant seed|v11] [--ready] TTY_PATH
 *        an1017_sil [--variant seed|v11] --pty
 * The runtime's shared host port (firmware/runtime/ports/host/hrt_host.c) replaces the UART and the
 * clock, as it does for every firmware on the runtime; this file only gives it the firmware's state
 * and AN1017's one option, the variant (the seed's code or AN1017 v1.1's).
 */
#include <string.h>

#include "an1017.h"

int hrt_host_option(const char *name, const char *value);

static an1017_t fw;
static uint8_t variant = AN1017_VARIANT_SEED;

int hrt_host_option(const char *name, const char *value)
{
    if (strcmp(name, "variant") != 0) {
        return 0;
    }
    if (strcmp(value, "seed") == 0) {
        variant = AN1017_VARIANT_SEED;
    } else if (strcmp(value, "v11") == 0) {
        variant = AN1017_VARIANT_V11;
    } else {
        return -1;
    }
    return 1;
}

hrt_t *hrt_firmware_init(void)
{
    an1017_init(&fw, variant);
    return &fw.rt;
}
