/* ports/host/main.c: the AN1017 firmware as a host process (software in the loop) on a tty.
 *
 * Usage: an1017_sil [--variant seed|v11] [--ready] TTY_PATH
 *        an1017_sil [--variant seed|v11] --pty
 * Serves the hilbench protocol on TTY_PATH (a pty slave, a serial device) until it hangs up; exit
 * 0 then, 1 on errors, 2 on bad usage. With --ready it prints "ready TTY_PATH" on stdout once the
 * tty is open, so a launcher knows when bytes can be sent. With --pty it makes its own pty, prints
 * "ready /dev/pts/N" and serves its master like a board on a serial port: across any number of
 * host sessions (it holds the slave open itself, so a host closing the port is not a hang-up)
 * until SIGINT/SIGTERM. The same firmware and runtime as the board: this file only replaces the UART
 * (read/write on the tty) and the clock (CLOCK_MONOTONIC in Tcy). With a watchdog agreed it wakes
 * every millisecond to check it, in both modes.
 */
#define _XOPEN_SOURCE 600
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdlib.h>
#include <stdio.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "an1017.h"
#include "hrt_link.h"

static an1017_t fw;
static hrt_link_t host_link;
static int tty = -1;
static int send_failed = 0;
/* replies are gathered and written once per batch of received bytes: one write per Drive */
static uint8_t out_buf[4096];
static size_t out_len = 0u;

static int flush_out(void)
{
    size_t done = 0u;
    while (done < out_len) {
        ssize_t w = write(tty, &out_buf[done], out_len - done);
        if (w < 0) {
            if (errno == EINTR || errno == EAGAIN) {
                continue;
            }
            out_len = 0u;
            return -1;
        }
        done += (size_t)w;
    }
    out_len = 0u;
    return 0;
}

void hrt_port_send(const uint8_t *wire, uint8_t len)
{
    if (out_len + len > sizeof out_buf && flush_out() != 0) {
        send_failed = 1;
        return;
    }
    memcpy(&out_buf[out_len], wire, len);
    out_len += len;
}

void hrt_port_lock(void)
{
    /* one thread, no interrupts: nothing to hold off */
}

void hrt_port_unlock(void)
{
}

uint32_t hrt_port_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint32_t)((unsigned long long)ts.tv_sec * 20000000ULL + (unsigned long long)ts.tv_nsec / 50ULL);
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

static int usage(const char *argv0)
{
    fprintf(stderr, "usage: %s [--variant seed|v11] [--ready] TTY_PATH\n", argv0);
    return 2;
}

int main(int argc, char **argv)
{
    uint8_t buf[4096];
    uint8_t variant = AN1017_VARIANT_SEED;
    int ready = 0;
    int own_pty = 0;
    int slave_keep = -1;
    const char *path = NULL;
    int i;
    for (i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--variant") == 0 && i + 1 < argc) {
            i++;
            if (strcmp(argv[i], "seed") == 0) {
                variant = AN1017_VARIANT_SEED;
            } else if (strcmp(argv[i], "v11") == 0) {
                variant = AN1017_VARIANT_V11;
            } else {
                return usage(argv[0]);
            }
        } else if (strcmp(argv[i], "--ready") == 0) {
            ready = 1;
        } else if (strcmp(argv[i], "--pty") == 0) {
            own_pty = 1;
        } else if (argv[i][0] == '-' || path != NULL) {
            return usage(argv[0]);
        } else {
            path = argv[i];
        }
    }
    if ((path == NULL) == (own_pty == 0)) {
        return usage(argv[0]);
    }
    if (own_pty) {
        tty = posix_openpt(O_RDWR | O_NOCTTY);
        if (tty < 0 || grantpt(tty) != 0 || unlockpt(tty) != 0 || (path = ptsname(tty)) == NULL) {
            fprintf(stderr, "an1017_sil: cannot make a pty: %s\n", strerror(errno));
            return 1;
        }
        slave_keep = open(path, O_RDWR | O_NOCTTY);
        if (slave_keep < 0 || make_raw(slave_keep) != 0) {
            fprintf(stderr, "an1017_sil: cannot open %s: %s\n", path, strerror(errno));
            return 1;
        }
        ready = 1;
    } else {
        tty = open(path, O_RDWR | O_NOCTTY);
    }
    if (tty < 0) {
        fprintf(stderr, "an1017_sil: cannot open %s: %s\n", path, strerror(errno));
        return 1;
    }
    if (!own_pty && make_raw(tty) != 0) {
        fprintf(stderr, "an1017_sil: %s is not a tty: %s\n", path, strerror(errno));
        return 1;
    }
    an1017_init(&fw, variant);
    hrt_link_init(&host_link, &fw.rt);
    if (ready) {
        printf("ready %s\n", path);
        fflush(stdout);
    }
    for (;;) {
        ssize_t n;
        ssize_t k;
        if (host_link.watchdog_ms != 0u) {
            struct pollfd p;
            int r;
            p.fd = tty;
            p.events = POLLIN;
            p.revents = 0;
            r = poll(&p, 1, 1); /* wake every ms for the watchdog */
            if (r == 0) {
                hrt_link_poll(&host_link);
                if (out_len > 0u && flush_out() != 0) {
                    break;
                }
                continue;
            }
        }
        n = read(tty, buf, sizeof buf);
        if (n == 0 || (n < 0 && errno == EIO)) {
            break; /* hang-up: the host closed its end */
        }
        if (n < 0) {
            if (errno == EINTR || errno == EAGAIN) {
                continue;
            }
            fprintf(stderr, "an1017_sil: read %s: %s\n", path, strerror(errno));
            return 1;
        }
        for (k = 0; k < n; k++) {
            if (hrt_link_rx_byte(&host_link, buf[k])) {
                hrt_link_poll(&host_link); /* handles the frame and releases the buffer */
            }
        }
        if (out_len > 0u && flush_out() != 0) {
            break;
        }
        if (send_failed) {
            break;
        }
    }
    close(tty);
    if (slave_keep >= 0) {
        close(slave_keep);
    }
    return 0;
}
