/* firmware/an1017/ports/avr/uart_link.h: the end of simavr's convenience link, for the harnesses
 * (run_simavr.c, run_motor.c). simavr's uart_pty_connect links /tmp/simavr-uart0 to the pty; at the
 * end the link goes, unless another simulator started since has pointed it at its own pty (one
 * re-pointing it between the readlink and the unlink loses it: a convenience link, not a port).
 */
#ifndef UART_LINK_H
#define UART_LINK_H

#include <string.h>
#include <unistd.h>

#define UART_LINK "/tmp/simavr-uart0"

static inline void remove_uart_link(const char *pty)
{
    char target[256];
    ssize_t n = readlink(UART_LINK, target, sizeof target - 1);
    if (n > 0) {
        target[n] = '\0';
        if (strcmp(target, pty) == 0) {
            unlink(UART_LINK);
        }
    }
}

#endif
