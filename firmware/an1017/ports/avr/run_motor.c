/* run_motor.c: the pin-level harness of the AVR real-motor build (make MODE=motor): the firmware runs
 * free on its own simulated timers in simavr against hilbench's plant, wired to the chip's pins.
 *
 * Usage: run_motor [--realtime] [--f-cpu HZ] FIRMWARE.elf [CONFIG.toml [TABLE.KEY=VALUE ...]]
 *
 * --f-cpu: the simulated clock, the firmware's F_CPU (default 80 MHz, make MODE=motor's: AN1017's
 * 20 kHz PWM interrupt takes ~2 100 AVR cycles, more than the 800 of a PWM period at a real
 * ATmega2560's 16 MHz; at 80 MHz it leaves the main loop about half the CPU: the harness prints
 * "masked_fraction", the share of cycles with interrupts held off). No CONFIG (or ""): hilbench's
 * default config. The interpreter imports hilbench from PYTHONPATH, or from the active venv
 * ($VIRTUAL_ENV's site-packages, .pth files included: an editable install works).
 *
 * The plant is hilbench's own (hilbench.bench.pinplant.PinPlant: the Plant and its C core that a
 * HIL session integrates, built from CONFIG and the overrides), run by the Python interpreter this
 * program embeds: one plant source for the bench and the harness. The wiring (main.c, HIL_MOTOR):
 * - at every PWM period boundary (Timer3, fast PWM, at BOTTOM: every ICR3 + 1 cycles from its start)
 *   the compare registers OCR3A..C as written (the double-buffered values the hardware takes at that
 *   boundary: the previous period's ISR wrote them) over ICR3 + 1 are the duties, PA0 the bridge enable;
 *   the plant advances one PWM period with them held;
 * - every hall edge of that period goes onto PD0..PD2 (INT0..INT2) at its own cycle;
 * - the pot's voltage goes onto ADC0 (AVcc = AREF = 5 V).
 * USART0 is on a pty as in run_simavr.c: prints "ready PTY_PATH", then the host opens PTY_PATH and
 * talks in HostHello mode MONITOR. --realtime paces the simulation to the wall clock (the host's
 * watchdog and keep-alive count wall time). Runs until SIGTERM/SIGINT or a crash; then prints
 * "cycles N" and "periods N" on stderr.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "avr_adc.h"
#include "avr_ioport.h"
#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_time.h"
#include "uart_pty.h"

#include "uart_link.h"

/* ATmega2560 data-space addresses (avr-libc iomxx0_1.h, the data sheet's register summary) */
#define REG_PORTA 0x22u
#define REG_TCCR3B 0x91u
#define REG_ICR3 0x96u
#define REG_OCR3A 0x98u
#define REG_OCR3B 0x9Au
#define REG_OCR3C 0x9Cu
#define BRIDGE_ENABLE 0x01u
/* hall edges queued for their cycles: one PWM period's and the rest of the last one's (a motor at
 * 60 000 rpm with 32 pole pairs makes ~10 edges in 50 us); more is refused, never dropped */
#define MAX_PENDING 64

static uart_pty_t uart_pty;
static volatile sig_atomic_t stop_requested = 0;

typedef struct {
    avr_cycle_count_t at;
    int bits;
} edge_t;

static edge_t pending[MAX_PENDING];
static int n_pending = 0;

static void on_signal(int sig)
{
    (void)sig;
    stop_requested = 1;
}

static double wall_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

static uint16_t reg16(const avr_t *avr, unsigned addr)
{
    return (uint16_t)(avr->data[addr] | (avr->data[addr + 1u] << 8));
}

static int py_fail(const char *what)
{
    fprintf(stderr, "run_motor: %s\n", what);
    if (PyErr_Occurred()) {
        PyErr_Print();
    }
    return 1;
}

/* A Python int as a C long; -1 with an error set when it is not one. */
static int py_long(PyObject *value, long *out)
{
    if (value == NULL || !PyLong_Check(value)) {
        return -1;
    }
    *out = PyLong_AsLong(value);
    return (*out == -1 && PyErr_Occurred()) ? -1 : 0;
}

/* One edge of the plant's period, (seconds from the period's start, the hall bits after it). */
static int py_edge(PyObject *edge, double *t_s, long *bits)
{
    PyObject *at;
    if (!PyTuple_Check(edge) || PyTuple_Size(edge) != 2) {
        return -1;
    }
    at = PyTuple_GetItem(edge, 0);
    *t_s = PyFloat_AsDouble(at);
    if (*t_s == -1.0 && PyErr_Occurred()) {
        return -1;
    }
    if (py_long(PyTuple_GetItem(edge, 1), bits) != 0 || *bits < 0 || *bits > 7 || *t_s < 0.0) {
        return -1;
    }
    return 0;
}

static void set_halls(avr_irq_t **halls, int bits)
{
    int i;
    for (i = 0; i < 3; i++) {
        avr_raise_irq(halls[i], (uint32_t)((bits >> i) & 1));
    }
}

/* One PWM period of the plant with the registers as they are; its edges queued at their cycles. */
static int plant_period(avr_t *avr, PyObject *plant, avr_cycle_count_t start, avr_irq_t *pot)
{
    double top = (double)reg16(avr, REG_ICR3) + 1.0;
    double a = top > 0 ? reg16(avr, REG_OCR3A) / top : 0.0;
    double b = top > 0 ? reg16(avr, REG_OCR3B) / top : 0.0;
    double c = top > 0 ? reg16(avr, REG_OCR3C) / top : 0.0;
    int enabled = (avr->data[REG_PORTA] & BRIDGE_ENABLE) != 0;
    PyObject *edges = PyObject_CallMethod(plant, "period", "dddi", a, b, c, enabled);
    PyObject *mv;
    Py_ssize_t i;
    Py_ssize_t n;
    long value;
    if (edges == NULL || !PyTuple_Check(edges)) {
        Py_XDECREF(edges);
        return py_fail("the plant's period did not return a tuple of edges");
    }
    n = PyTuple_Size(edges);
    if (n > (Py_ssize_t)(MAX_PENDING - n_pending)) {
        fprintf(stderr, "run_motor: %ld hall edges in one PWM period with %d still queued, more than the %d the "
                "harness holds (refused: an edge dropped would be a wrong motor)\n", (long)n, n_pending, MAX_PENDING);
        Py_DECREF(edges);
        return 1;
    }
    for (i = 0; i < n; i++) {
        double t_s;
        if (py_edge(PyTuple_GetItem(edges, i), &t_s, &value) != 0) {
            Py_DECREF(edges);
            return py_fail("the plant's edge is not (seconds >= 0, hall bits 0..7)");
        }
        pending[n_pending].at = start + (avr_cycle_count_t)(t_s * (double)avr->frequency + 0.5);
        pending[n_pending].bits = (int)value;
        n_pending++;
    }
    Py_DECREF(edges);
    mv = PyObject_CallMethod(plant, "pot_mv", NULL);
    if (py_long(mv, &value) != 0 || value < 0 || value > 65535L) {
        Py_XDECREF(mv);
        return py_fail("the plant's pot_mv is not a voltage in mV");
    }
    avr_raise_irq(pot, (uint32_t)value);
    Py_DECREF(mv);
    return 0;
}

static PyObject *make_plant(const char *config, int n_overrides, char **overrides, unsigned period_us)
{
    PyObject *module = PyImport_ImportModule("hilbench.bench.pinplant");
    PyObject *words;
    PyObject *plant;
    int i;
    if (module == NULL) {
        return NULL;
    }
    words = PyTuple_New(n_overrides);
    if (words == NULL) {
        Py_DECREF(module);
        return NULL;
    }
    for (i = 0; i < n_overrides; i++) {
        PyObject *word = PyUnicode_DecodeFSDefault(overrides[i]);
        if (word == NULL) {
            Py_DECREF(words);
            Py_DECREF(module);
            return NULL;
        }
        PyTuple_SET_ITEM(words, i, word); /* steals the reference */
    }
    plant = PyObject_CallMethod(module, "PinPlant", "sOI", config, words, period_us);
    Py_DECREF(words);
    Py_DECREF(module);
    return plant;
}

int main(int argc, char **argv)
{
    elf_firmware_t fw;
    int realtime = argc > 1 && strcmp(argv[1], "--realtime") == 0;
    uint32_t f_cpu = 80000000u;
    avr_t *avr;
    avr_irq_t *halls[3];
    avr_irq_t *pot;
    PyObject *plant;
    PyObject *bits;
    int state = cpu_Running;
    avr_cycle_count_t t3_start = 0;
    avr_cycle_count_t next_boundary = 0;
    avr_cycle_count_t pwm_cycles = 0;
    avr_cycle_count_t next_pace = 0;
    unsigned long periods = 0;
    avr_cycle_count_t busy_cycles = 0;
    int plant_failed = 0;
    double start_s;
    int i;
    if (realtime) {
        argv++;
        argc--;
    }
    if (argc > 2 && strcmp(argv[1], "--f-cpu") == 0) {
        f_cpu = (uint32_t)strtoul(argv[2], NULL, 10);
        argv += 2;
        argc -= 2;
    }
    if (argc < 2) {
        fprintf(stderr, "usage: run_motor [--realtime] [--f-cpu HZ] FIRMWARE.elf [CONFIG.toml [TABLE.KEY=VALUE ...]]\n");
        return 2;
    }
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(argv[1], &fw) != 0) {
        fprintf(stderr, "run_motor: cannot read %s\n", argv[1]);
        return 1;
    }
    avr = avr_make_mcu_by_name("atmega2560");
    if (avr == NULL) {
        fprintf(stderr, "run_motor: simavr has no atmega2560\n");
        return 1;
    }
    avr_init(avr);
    avr_load_firmware(avr, &fw);
    avr->frequency = f_cpu;
    avr->vcc = avr->avcc = avr->aref = 5000u;
    Py_InitializeEx(0); /* no Python signal handlers: SIGTERM stays ours */
    if (PyRun_SimpleString("import os, site, sys\n"
                           "venv = os.environ.get('VIRTUAL_ENV')\n"
                           "if venv: site.addsitedir(os.path.join(venv, 'lib', 'python%d.%d' % sys.version_info[:2], "
                           "'site-packages'))\n") != 0) {
        return py_fail("cannot read the venv's site-packages");
    }
    plant = make_plant(argc > 2 ? argv[2] : "", argc > 3 ? argc - 3 : 0, argv + 3, 50u);
    if (plant == NULL) {
        return py_fail("cannot make the plant (hilbench.bench.pinplant.PinPlant)");
    }
    for (i = 0; i < 3; i++) {
        halls[i] = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), i);
    }
    pot = avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0);
    bits = PyObject_GetAttrString(plant, "hall_bits");
    {
        long value;
        if (py_long(bits, &value) != 0 || value < 0 || value > 7) {
            Py_XDECREF(bits);
            return py_fail("the plant's hall_bits is not 0..7");
        }
        set_halls(halls, (int)value); /* the rotor's position at power-on */
    }
    Py_DECREF(bits);
    uart_pty_init(avr, &uart_pty);
    uart_pty_connect(&uart_pty, '0');
    signal(SIGTERM, on_signal);
    signal(SIGINT, on_signal);
    printf("ready %s\n", uart_pty.pty.slavename);
    fflush(stdout);
    start_s = wall_s();
    while (!stop_requested && !plant_failed && state != cpu_Done && state != cpu_Crashed) {
        {
            avr_cycle_count_t before = avr->cycle;
            int masked = !avr->sreg[S_I];
            state = avr_run(avr);
            if (masked) {
                busy_cycles += avr->cycle - before; /* interrupts held off: an ISR or a locked section */
            }
        }
        if (pwm_cycles == 0u) {
            if ((avr->data[REG_TCCR3B] & 7u) != 0u && reg16(avr, REG_ICR3) != 0u) { /* Timer3 started: BOTTOM now */
                t3_start = avr->cycle;
                pwm_cycles = (avr_cycle_count_t)reg16(avr, REG_ICR3) + 1u;
                next_boundary = t3_start;
            }
        }
        if (pwm_cycles != 0u && avr->cycle >= next_boundary) {
            if (plant_period(avr, plant, next_boundary, pot) != 0) {
                plant_failed = 1; /* its error printed; the loop ends, the pty's link is removed below */
                break;
            }
            periods++;
            next_boundary += pwm_cycles;
        }
        while (n_pending > 0 && avr->cycle >= pending[0].at) {
            set_halls(halls, pending[0].bits);
            n_pending--;
            memmove(&pending[0], &pending[1], (size_t)n_pending * sizeof pending[0]);
        }
        if (realtime && avr->cycle >= next_pace) { /* never ahead of the wall clock (1 ms grain) */
            double ahead_s = (double)avr->cycle / (double)avr->frequency - (wall_s() - start_s);
            next_pace = avr->cycle + avr->frequency / 1000u;
            if (ahead_s > 0.0) {
                struct timespec ts;
                ts.tv_sec = (time_t)ahead_s;
                ts.tv_nsec = (long)((ahead_s - (double)ts.tv_sec) * 1e9);
                nanosleep(&ts, NULL);
            }
        }
    }
    fprintf(stderr, "cycles %llu\n", (unsigned long long)avr->cycle);
    fprintf(stderr, "periods %lu\n", periods);
    fprintf(stderr, "masked_fraction %.3f\n", avr->cycle ? (double)busy_cycles / (double)avr->cycle : 0.0);
    remove_uart_link(uart_pty.pty.slavename);
    if (plant_failed) {
        return 1;
    }
    if (state == cpu_Crashed) {
        fprintf(stderr, "run_motor: the firmware crashed at pc 0x%05x\n", (unsigned)avr->pc);
        return 1;
    }
    return 0;
}
