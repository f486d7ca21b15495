/* firmware/runtime/ports/host/hrt_host.c: any firmware on the runtime as a host process (software
 * in the loop) on a tty. The firmware defines hrt_firmware and hrt_firmware_init(); link this file,
 * the firmware, hrt.c, hrt_link.c and firmware_protocol/hbp*.c (see firmware/template/Makefile).
 *
 * Usage: PROGRAM [--NAME VALUE]... [--ready] TTY_PATH
 *        PROGRAM [--NAME VALUE]... --pty
 * A firmware with options of its own (AN1017's --variant) takes them in hrt_host_option(); the
 * default one takes none.
 * Serves the hilbench protocol on TTY_PATH (a pty slave, a serial device) until it hangs up; exit
 * 0 then, 1 on errors, 2 on bad usage. With --ready it prints "ready TTY_PATH" on stdout once the
 * tty is open, so a launcher knows when bytes can be sent. With --pty it makes its own pty, prints
 * "ready /dev/pts/N" and serves its master like a board on a serial port: across any number of
 * host sessions (it holds the slave open itself, so a host closing the port is not a hang-up)
 * until SIGINT/SIGTERM. The same firmware and runtime as on a chip: this file only replaces the UART
 * (read/write on the tty) and the clock (CLOCK_MONOTONIC in the firmware's ticks). With a watchdog agreed an
 * interval timer (SIGALRM every millisecond) interrupts the blocking read to check it, in both modes:
 * a frame costs one read and one write, as without a watchdog (a poll before each read cost the
 * firmware process ~10 us of CPU a period, more than the FOC's arithmetic).
 */
#define _XOPEN_SOURCE 600
#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdlib.h>
#include <stdio.h>
#include <string.h>
#include <sys/time.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "hrt_link.h"

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
    unsigned long long tpu = hrt_firmware.ticks_per_us;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint32_t)((unsigned long long)ts.tv_sec * 1000000ULL * tpu + (unsigned long long)ts.tv_nsec * tpu / 1000ULL);
}

static void on_tick(int sig)
{
    (void)sig; /* only to interrupt read(): the main loop then looks at the watchdog */
}

/* Tick every millisecond (on != 0) or not at all; 0, or -1 when the timer cannot be set. */
static int watchdog_ticks(int on)
{
    struct itimerval it;
    memset(&it, 0, sizeof it);
    if (on) {
        it.it_interval.tv_usec = 1000;
        it.it_value.tv_usec = 1000;
    }
    return setitimer(ITIMER_REAL, &it, NULL);
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

/* A firmware's own option --NAME VALUE: 1 taken, 0 not its option, -1 a bad value. A firmware
 * that has options defines this function; the host port's own (weak) one takes none. */
__attribute__((weak)) int hrt_host_option(const char *name, const char *value)
{
    (void)name;
    (void)value;
    return 0;
}

static int usage(const char *argv0)
{
    fprintf(stderr, "usage: %s [--NAME VALUE]... [--ready] TTY_PATH | --pty\n", argv0);
    return 2;
}

int main(int argc, char **argv)
{
    uint8_t buf[4096];
    int ready = 0;
    int own_pty = 0;
    int slave_keep = -1;
    int ticking = 0;
    const char *path = NULL;
    int i;
    for (i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--ready") == 0) {
            ready = 1;
        } else if (strcmp(argv[i], "--pty") == 0) {
            own_pty = 1;
        } else if (strncmp(argv[i], "--", 2) == 0 && i + 1 < argc) {
            if (hrt_host_option(argv[i] + 2, argv[i + 1]) != 1) {
                return usage(argv[0]);
            }
            i++;
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
            fprintf(stderr, "hrt_host: cannot make a pty: %s\n", strerror(errno));
            return 1;
        }
        slave_keep = open(path, O_RDWR | O_NOCTTY);
        if (slave_keep < 0 || make_raw(slave_keep) != 0) {
            fprintf(stderr, "hrt_host: cannot open %s: %s\n", path, strerror(errno));
            return 1;
        }
        ready = 1;
    } else {
        tty = open(path, O_RDWR | O_NOCTTY);
    }
    if (tty < 0) {
        fprintf(stderr, "hrt_host: cannot open %s: %s\n", path, strerror(errno));
        return 1;
    }
    if (!own_pty && make_raw(tty) != 0) {
        fprintf(stderr, "hrt_host: %s is not a tty: %s\n", path, strerror(errno));
        return 1;
    }
    {
        struct sigaction sa;
        memset(&sa, 0, sizeof sa);
        sa.sa_handler = on_tick; /* no SA_RESTART: the tick interrupts read() */
        sigemptyset(&sa.sa_mask);
        if (sigaction(SIGALRM, &sa, NULL) != 0) {
            fprintf(stderr, "hrt_host: cannot catch SIGALRM: %s\n", strerror(errno));
            return 1;
        }
    }
    hrt_link_init(&host_link, hrt_firmware_init());
    if (ready) {
        printf("ready %s\n", path);
        fflush(stdout);
    }
    for (;;) {
        ssize_t n;
        ssize_t k;
        if ((host_link.watchdog_ms != 0u) != ticking) { /* a handshake agreed or dropped a watchdog */
            ticking = (host_link.watchdog_ms != 0u);
            if (watchdog_ticks(ticking) != 0) {
                fprintf(stderr, "hrt_host: cannot set the watchdog's timer: %s\n", strerror(errno));
                return 1;
            }
        }
        n = read(tty, buf, sizeof buf);
        if (n == 0 || (n < 0 && errno == EIO)) {
            break; /* hang-up: the host closed its end */
        }
        if (n < 0) {
            if (errno == EINTR || errno == EAGAIN) { /* a tick: the watchdog */
                hrt_link_poll(&host_link);
                if (out_len > 0u && flush_out() != 0) {
                    break;
                }
                continue;
            }
            fprintf(stderr, "hrt_host: read %s: %s\n", path, strerror(errno));
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
