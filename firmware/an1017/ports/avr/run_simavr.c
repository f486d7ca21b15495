/* run_simavr.c: run the AVR build of the AN1017 firmware in simavr with USART0 on a pty.
 *
 * Usage: run_simavr [--realtime] FIRMWARE.elf [MCU [F_CPU]]      (default atmega328p 16000000)
 * --realtime paces the simulation to the wall clock (simulated time never runs ahead of it), as a
 * chip's would: for real-time sessions, whose host paces by the wall clock and whose firmware
 * watchdog counts simulated time. Without it simavr runs as fast as it can (lockstep needs no more).
 * Prints "ready PTY_PATH" once the simulated UART listens on a pty (simavr's uart_pty part: a
 * thread moves bytes between the pty and the simulated USART0 with its XON/XOFF flow control, and
 * the USART delivers them at the programmed baud rate in simulated cycles). The bench opens
 * PTY_PATH as a serial device. Runs until the firmware crashes or SIGTERM/SIGINT; then prints
 * "stack_bytes N" on stderr: the deepest stack seen (RAMEND - lowest SP, sampled after every
 * instruction), the measured stack figure of docs/board.md, and "cycles N", the simulated time in
 * CPU cycles (tests compare it with the wall time to know the simulator's speed).
 */
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_time.h"
#include "uart_pty.h"

#include "uart_link.h"

static uart_pty_t uart_pty;
static volatile sig_atomic_t stop_requested = 0;

static double wall_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

/* Sleep while the simulated time is ahead of the wall time since start (checked every 1/1000 s of
 * simulated time: the pacing's granularity). */
static void pace(const avr_t *avr, double start_s, avr_cycle_count_t *next_check)
{
    double ahead_s;
    if (avr->cycle < *next_check) {
        return;
    }
    *next_check = avr->cycle + avr->frequency / 1000u;
    ahead_s = (double)avr->cycle / (double)avr->frequency - (wall_s() - start_s);
    if (ahead_s > 0.0) {
        struct timespec ts;
        ts.tv_sec = (time_t)ahead_s;
        ts.tv_nsec = (long)((ahead_s - (double)ts.tv_sec) * 1e9);
        nanosleep(&ts, NULL);
    }
}

/* The CPU sleeps (SLEEP with interrupts on) for how_long cycles, until its next timer event. simavr's
 * own callback sleeps until the wall clock reaches the simulated time of that event since the start:
 * after the firmware ran busy for a while (real time on a port without its own timers never sleeps)
 * the simulated time is seconds ahead of the wall, and the next sleep waits all of it out, serving no
 * UART byte meanwhile (a host's Stop in real time, then lockstep traffic: no answer for ~5x the time
 * spent in real time). Here a sleep lasts at most its own length in wall time: the lead taken while
 * busy is not paid back (lockstep counts virtual time; --realtime paces the busy time itself). */
static void sleep_own_length(avr_t *avr, avr_cycle_count_t how_long)
{
    uint64_t deadline_ns = avr_cycles_to_nsec(avr, avr->cycle + how_long);
    uint64_t runtime_ns = avr_get_time_stamp(avr);
    uint64_t own_ns = avr_cycles_to_nsec(avr, how_long);
    uint64_t wait_ns;
    struct timespec ts;
    if (runtime_ns >= deadline_ns) {
        return;
    }
    wait_ns = deadline_ns - runtime_ns;
    if (wait_ns > own_ns) {
        wait_ns = own_ns;
    }
    ts.tv_sec = (time_t)(wait_ns / 1000000000u);
    ts.tv_nsec = (long)(wait_ns % 1000000000u);
    nanosleep(&ts, NULL);
}

static void on_signal(int sig)
{
    (void)sig;
    stop_requested = 1;
}

int main(int argc, char **argv)
{
    elf_firmware_t fw;
    int realtime = argc > 1 && strcmp(argv[1], "--realtime") == 0;
    const char *mcu;
    unsigned long freq;
    avr_t *avr;
    int state = cpu_Running;
    avr_cycle_count_t next_check = 0;
    double start_s;
    if (realtime) {
        argv++;
        argc--;
    }
    mcu = argc > 2 ? argv[2] : "atmega328p";
    freq = argc > 3 ? strtoul(argv[3], NULL, 10) : 16000000UL;
    if (argc < 2) {
        fprintf(stderr, "usage: %s [--realtime] FIRMWARE.elf [MCU [F_CPU]]\n", argv[0]);
        return 2;
    }
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(argv[1], &fw) != 0) {
        fprintf(stderr, "run_simavr: cannot read %s\n", argv[1]);
        return 1;
    }
    avr = avr_make_mcu_by_name(mcu);
    if (avr == NULL) {
        fprintf(stderr, "run_simavr: unknown MCU %s\n", mcu);
        return 1;
    }
    avr_init(avr);
    avr_load_firmware(avr, &fw);
    avr->frequency = (uint32_t)freq;
    avr->sleep = sleep_own_length;
    uart_pty_init(avr, &uart_pty);
    uart_pty_connect(&uart_pty, '0');
    signal(SIGTERM, on_signal);
    signal(SIGINT, on_signal);
    printf("ready %s\n", uart_pty.pty.slavename);
    fflush(stdout);
    start_s = wall_s();
    {
        uint16_t ramend = (uint16_t)avr->ramend;
        uint16_t lowest_sp = ramend;
        int started = 0;
        while (!stop_requested && state != cpu_Done && state != cpu_Crashed) {
            uint16_t sp;
            state = avr_run(avr);
            if (realtime) {
                pace(avr, start_s, &next_check);
            }
            sp = (uint16_t)(avr->data[R_SPL] | (avr->data[R_SPH] << 8));
            if (sp == ramend) {
                started = 1; /* the C start-up code has set SP = RAMEND */
            }
            if (started && sp < lowest_sp) {
                lowest_sp = sp;
            }
        }
        fprintf(stderr, "stack_bytes %u\n", (unsigned)(ramend - lowest_sp));
        fprintf(stderr, "cycles %llu\n", (unsigned long long)avr->cycle); /* simulated time x F_CPU */
    }
    /* no uart_pty_stop(): its thread may sit in select(); exiting the process ends it */
    remove_uart_link(uart_pty.pty.slavename);
    if (state == cpu_Crashed) {
        fprintf(stderr, "run_simavr: the firmware crashed at pc 0x%04x\n", (unsigned)avr->pc);
        return 1;
    }
    return 0;
}
