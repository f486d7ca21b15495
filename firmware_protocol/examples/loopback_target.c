/* loopback_target.c: a host-built target that serves the hilbench protocol on a tty with the C library.
 *
 * Usage: loopback_target TTY_PATH   (serves until the tty hangs up; exit 0 then, 1 on errors)
 * The protocol handling is loopback_core.c (the documented loopback mapping of PROTOCOL.md); this
 * file is the POSIX platform: the tty, and the read loop that feeds the receive state machine.
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

/* The platform-free part, compiled in this translation unit (so one source file builds the target). */
#include "loopback_core.c"

static int tty = -1;

int loopback_send(const uint8_t *out, uint8_t n)
{
    uint8_t done = 0u;
    while (done < n) {
        ssize_t w = write(tty, &out[done], (size_t)(n - done));
        if (w < 0) {
            if (errno == EINTR || errno == EAGAIN) {
                continue;
            }
            return -1;
        }
        done = (uint8_t)(done + (uint8_t)w);
    }
    return 0;
}

static int make_raw(int fd)
{
    struct termios t;
    if (tcgetattr(fd, &t) != 0) {
        return -1;
    }
    t.c_iflag &= (tcflag_t) ~(IGNBRK | BRKINT | PARMRK | ISTRIP | INLCR | IGNCR | ICRNL | IXON | IXOFF);
    t.c_oflag &= (tcflag_t)~OPOST;
    t.c_lflag &= (tcflag_t) ~(ECHO | ECHONL | ICANON | ISIG | IEXTEN);
    t.c_cflag &= (tcflag_t) ~(CSIZE | PARENB);
    t.c_cflag |= (tcflag_t)(CS8 | CREAD | CLOCAL);
    t.c_cc[VMIN] = 1;
    t.c_cc[VTIME] = 0;
    return tcsetattr(fd, TCSANOW, &t);
}

int main(int argc, char **argv)
{
    uint8_t buf[256];
    if (argc != 2) {
        fprintf(stderr, "usage: %s TTY_PATH\n", argv[0]);
        return 2;
    }
    tty = open(argv[1], O_RDWR | O_NOCTTY);
    if (tty < 0) {
        fprintf(stderr, "loopback_target: cannot open %s: %s\n", argv[1], strerror(errno));
        return 1;
    }
    if (make_raw(tty) != 0) {
        fprintf(stderr, "loopback_target: %s is not a tty: %s\n", argv[1], strerror(errno));
        return 1;
    }
    hbp_rx_init(&loopback_rx);
    for (;;) {
        ssize_t n = read(tty, buf, sizeof buf);
        ssize_t i;
        if (n == 0 || (n < 0 && errno == EIO)) {
            break; /* hang-up: the host closed its end */
        }
        if (n < 0) {
            if (errno == EINTR || errno == EAGAIN) {
                continue;
            }
            fprintf(stderr, "loopback_target: read %s: %s\n", argv[1], strerror(errno));
            return 1;
        }
        for (i = 0; i < n; i++) {
            if (hbp_rx_byte(&loopback_rx, buf[i])) {
                int r = loopback_handle(loopback_rx.buf, loopback_rx.frame_len);
                hbp_rx_release(&loopback_rx);
                if (r != 0) {
                    return (errno == EIO) ? 0 : 1;
                }
            }
        }
    }
    close(tty);
    return 0;
}
