/* Compiled AN1017 firmware model (the "c" backend of hilbench.targets.an1017.An1017Target).
 *
 * Core is the base type of an1017._CFirmware: the firmware state of
 * an1017_firmware.An1017Firmware lives in this struct and is exposed as members with the same
 * attribute names, so the Python methods that the host-side commands use (press_start,
 * press_stop, set_gains, declared_gains, duties, __init__) run unchanged on it. The per-period
 * work runs here: Core.run is An1017Firmware.run (every ISR at its Tcy time; a run of PWM
 * periods between other events is one step of arithmetic, and the duty registers are held as
 * the SVM's packed arguments, volts << 16 | angle, evaluated only when a Drive reports them),
 * Core.finish builds the Drive as An1017Target._finish does, Core.step is one lockstep period
 * (run + finish).
 *
 * Arithmetic: int64_t for everything, with Python's semantics made explicit where they differ
 * from C's: right shifts of negative values floor (asr), `% 6` / `% 16` of possibly negative
 * values are taken non-negative, `& 0xFFFF` is the two's-complement mask (as Python's & on
 * negative ints). tests/test_an1017_core.py compares every Drive with the Python reference.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <structmember.h>
#include <stddef.h>
#include <stdint.h>

#define PWM_PERIOD_TCY 1000
#define TIMER1_PERIOD_TCY (314 * 64)
#define TMR3_PRESCALE 64
#define BOOTSTRAP_TCY 200000
#define ADC_POSTSCALE_V11 16
#define MINPERIOD 313
#define MAXPERIOD 31250
#define MINPERIOD_DIVF 312
#define PHASE_OFFSET_DEFAULT 4100
#define SECTOR_INVALID 0xFFFF
#define FORCE_COMMUTATION_TICKS 10
#define PHASEINC_NUMERATOR 512000
#define STATE_STOPPED 0
#define STATE_BOOTSTRAP 1
#define STATE_RUNNING 2
#define STATE_STALLED 3
#define MODE_OFF 0
#define MODE_PWM 1
#define MODE_LOW_SIDE 2
#define FAULT_NONE 0
#define FAULT_STALL 2
#define FAULT_OVERCURRENT 3
#define STATE_FAULT 4
#define INPUT_S2 0x08
#define INPUT_FAULT 0x20
#define PTPER 499
#define TPWM 998
#define VOLTS_LIMIT 28300
#define SIXTY_DEG 0x2AAA
#define EDGE_NONE 0xFFFF

static const int64_t PHASE_VALUES[6] = {57344, 2730, 13652, 24574, 35496, 46418};
static const int SECTOR_TABLE[8] = {-1, 4, 2, 3, 0, 5, 1, -1};
static const int64_t VECTORS[6] = {0x0000, 0x2AAA, 0x5555, 0x8000, 0xAAAA, 0xD555};
static int64_t SINE_TABLE[172];
static PyTypeObject *drive_type = NULL;
static PyObject *duty_ints[1001];

/* Python's a >> n (floor) for any sign, without relying on C's implementation-defined >>. */
static inline int64_t asr(int64_t a, int n) { return a >= 0 ? a >> n : ~((~a) >> n); }
/* Python's a // b and a % b for b > 0. */
static inline int64_t floordiv(int64_t a, int64_t b) { int64_t q = a / b; return (a % b != 0 && a < 0) ? q - 1 : q; }
static inline int64_t pymod(int64_t a, int64_t b) { int64_t r = a % b; return r < 0 ? r + b : r; }
static inline int64_t sat16(int64_t x) { return x > 32767 ? 32767 : x < -32768 ? -32768 : x; }
static inline int64_t wrap16(int64_t x) { x &= 0xFFFF; return (x & 0x8000) ? x - 0x10000 : x; }
static inline int64_t sata(int64_t a)
{
    return a > (int64_t)0x7FFFFFFF ? (int64_t)0x7FFFFFFF : a < -(int64_t)0x80000000 ? -(int64_t)0x80000000 : a;
}

typedef struct {
    PyObject_HEAD
    /* options and declared values */
    char adc_every, c1_textbook, phase_advance_on, ref_override_on;
    int phase_offset, min_period, max_period, kp, ki, kd, max_ph_adv_deg, max_ph_adv, ref_override, stall_limit;
    char has_pending;
    int pend_kp, pend_ki, pend_kd;
    /* time and peripherals */
    long long t, t3_zero, boot_end, t1_next, pend_key, act_key;
    int hall, pot_code, output_mode;
    int fifo[4];
    int fifo_n;
    /* firmware variables */
    char running, booting, cur_ccw, req_ccw, s2_level, s2_wait_release;
    int state, fault, ref_speed, measured_speed, control_output, e1, e2, c0, c1, c2;
    int phase, phase_inc, phase_adv, sector, last_sector, stall_counter, period, actual_capture, past_capture;
    /* target side */
    long long period_tcy, last_seq;
    PyObject *tel; /* the last telemetry tuple, reused while its values do not change */
    PyObject *last_drive; /* the answer to a repeated seq (a duplicated frame): no second step */
} Core;

/* ---------------------------------------------------------------- SVM (svm.svm, exact) */
static void svm_duties(int64_t volts, int64_t angle, int64_t out[3])
{
    if (volts > VOLTS_LIMIT) volts = VOLTS_LIMIT;
    int64_t a = angle & 0xFFFF;
    int sector = a < 0x2AAA ? 1 : a < 0x5555 ? 2 : a < 0x8000 ? 3 : a < 0xAAAA ? 4 : a < 0xD555 ? 5 : 6;
    int64_t angle2 = (a - VECTORS[sector - 1]) & 0xFFFF;
    int64_t angle1 = (SIXTY_DEG - angle2) & 0xFFFF;
    int64_t t1 = SINE_TABLE[(angle1 >> 6) & 0xFF];
    int64_t t2 = SINE_TABLE[(angle2 >> 6) & 0xFF];
    t1 = asr(t1 * volts, 15) & 0xFFFF;
    t1 = asr(t1 * TPWM, 15) & 0xFFFF;
    t2 = asr(t2 * volts, 15) & 0xFFFF;
    t2 = asr(t2 * TPWM, 15) & 0xFFFF;
    int64_t h = ((TPWM - t1 - t2) & 0xFFFF) >> 1;
    int64_t x = (t1 + t2 + h) & 0xFFFF, y1 = (t1 + h) & 0xFFFF, y2 = (t2 + h) & 0xFFFF;
    switch (sector) {
    case 1: out[0] = x; out[1] = y2; out[2] = h; break;
    case 2: out[0] = y1; out[1] = x; out[2] = h; break;
    case 3: out[0] = h; out[1] = x; out[2] = y2; break;
    case 4: out[0] = h; out[1] = y1; out[2] = x; break;
    case 5: out[0] = y2; out[1] = h; out[2] = x; break;
    default: out[0] = x; out[1] = h; out[2] = y1; break;
    }
}

/* ---------------------------------------------------------------- firmware routines */
static int phase_for_sector(int64_t sector, int required_ccw, int old_phase, int offset)
{
    if (required_ccw) {
        int64_t idx = ((sector + 3) & 0xFFFF) % 6;
        return (int)((PHASE_VALUES[idx] + offset) & 0xFFFF);
    }
    if (sector == SECTOR_INVALID) return old_phase;
    return (int)PHASE_VALUES[sector];
}

static void press_start(Core *s)
{
    if (s->running || s->booting) return;
    s->booting = 1;
    s->state = STATE_BOOTSTRAP;
    s->fault = FAULT_NONE;
    s->output_mode = MODE_LOW_SIDE;
    s->boot_end = s->t + BOOTSTRAP_TCY + 1;
}

static void press_stop(Core *s, int state, int fault)
{
    s->running = 0;
    s->booting = 0;
    s->output_mode = MODE_OFF;
    s->state = state;
    s->fault = fault;
}

static void coefficients(Core *s)
{
    int64_t kp = s->kp, ki = s->ki, kd = s->kd;
    s->c0 = (int)wrap16(kp + ki + kd);
    s->c1 = (int)(s->c1_textbook ? wrap16(-kp - 2 * kd) : wrap16(-(ki + 2 * kd)));
    s->c2 = (int)wrap16(kd);
}

static void run_motor(Core *s)
{
    s->booting = 0;
    s->output_mode = MODE_PWM;
    s->pend_key = s->act_key = 0;
    s->e1 = s->e2 = 0;
    coefficients(s);
    long long now = s->boot_end;
    s->t1_next = now + TIMER1_PERIOD_TCY;
    s->t3_zero = now;
    s->actual_capture = s->max_period;
    s->past_capture = 0;
    int sec = SECTOR_TABLE[s->hall] & 0xFFFF;
    s->sector = s->last_sector = sec;
    s->control_output = 0;
    int ccw = s->ref_speed < 0;
    s->cur_ccw = s->req_ccw = (char)ccw;
    s->phase = phase_for_sector(sec, ccw, s->phase, s->phase_offset);
    s->stall_counter = 0;
    s->phase_inc = PHASEINC_NUMERATOR / s->max_period;
    s->running = 1;
    s->state = STATE_RUNNING;
}

static void timer1(Core *s)
{
    if (s->has_pending) {
        s->kp = s->pend_kp;
        s->ki = s->pend_ki;
        s->kd = s->pend_kd;
        s->has_pending = 0;
        coefficients(s);
    }
    int64_t period = ((int64_t)s->actual_capture - s->past_capture) & 0xFFFF;
    if (period < s->min_period) period = s->min_period;
    else if (period > s->max_period) period = s->max_period;
    s->period = (int)period;
    s->phase_inc = (int)(PHASEINC_NUMERATOR / period);
    /* DIVF: 0 < MINPERIOD - 1 < period, so the truncating quotient is a plain positive division */
    int64_t ms = ((int64_t)(s->min_period - 1) << 15) / period; /* DIVF(MINPERIOD - 1, Period) */
    if (s->cur_ccw) ms = -ms;
    s->measured_speed = (int)ms;
    /* SpeedControl: e0 = SAC(SUB), LAC ControlOutput, three MACs with SATA, SAC (bits 31:16) */
    int64_t e0 = sat16((int64_t)s->ref_speed - ms);
    int64_t acc = (int64_t)s->control_output * 65536;
    acc = sata(acc + e0 * s->c0 * 2);
    acc = sata(acc + (int64_t)s->e1 * s->c1 * 2);
    acc = sata(acc + (int64_t)s->e2 * s->c2 * 2);
    int64_t co = sat16(asr(acc, 16));
    s->e2 = s->e1;
    s->e1 = (int)e0;
    s->control_output = (int)co;
    s->req_ccw = co < 0;
    s->phase_adv = s->phase_advance_on ? (int)sat16(asr((int64_t)s->max_ph_adv * ms * 2, 16)) : 0;
    s->stall_counter += 1;
    if (s->stall_counter % FORCE_COMMUTATION_TICKS == 0) {
        int sec = SECTOR_TABLE[s->hall];
        s->sector = sec & 0xFFFF;
        if (sec >= 0) s->phase = phase_for_sector(sec, s->req_ccw, s->phase, s->phase_offset);
    } else if (s->stall_counter >= s->stall_limit) {
        press_stop(s, STATE_STALLED, FAULT_STALL);
    }
}

static void hall_isr(Core *s, int which)
{
    int sec = SECTOR_TABLE[s->hall] & 0xFFFF;
    s->sector = sec;
    if (sec == s->last_sector) return;
    if (which == 1) {
        s->past_capture = s->actual_capture;
        if (s->fifo_n > 0) {
            s->actual_capture = s->fifo[0];
            /* pop(0), then del fifo[:3] */
            int rest = s->fifo_n - 1;
            int drop = rest < 3 ? rest : 3;
            int k = 0;
            for (int i = 1 + drop; i < s->fifo_n; i++) s->fifo[k++] = s->fifo[i];
            s->fifo_n = k;
        }
    }
    s->stall_counter = 0;
    if (which == 0) s->cur_ccw = sec == 5 || sec == 2;
    else if (which == 1) s->cur_ccw = sec == 3 || sec == 0;
    else s->cur_ccw = sec == 1 || sec == 4;
    s->phase = phase_for_sector(sec, s->req_ccw, s->phase, s->phase_offset);
    s->last_sector = sec;
}

static void apply_hall(Core *s, int new_bits, long long t_edge)
{
    int changed = s->hall ^ new_bits;
    s->hall = new_bits;
    if ((changed & 2) && s->fifo_n < 4)
        s->fifo[s->fifo_n++] = (int)(floordiv(t_edge - s->t3_zero, TMR3_PRESCALE) & 0xFFFF);
    if (!s->running) return;
    if (changed & 1) hall_isr(s, 0);
    if ((changed & 2) && s->running) hall_isr(s, 1);
    if ((changed & 4) && s->running) hall_isr(s, 2);
}

static inline int ref_input(Core *s)
{
    return s->ref_override_on ? s->ref_override : ((s->pot_code & 0x3FF) - 512) * 64;
}

static void pwm_run(Core *s, long long first_index, long long n)
{
    if (s->adc_every) s->ref_speed = ref_input(s);
    else if (pymod(-first_index, ADC_POSTSCALE_V11) < n) s->ref_speed = ref_input(s);
    if (!s->running) {
        s->act_key = s->pend_key;
        return;
    }
    int64_t co = s->control_output, volts, dphase;
    if (s->req_ccw) {
        volts = -(co + 1);
        dphase = s->cur_ccw ? -(int64_t)s->phase_inc : 0;
    } else {
        volts = co;
        dphase = s->cur_ccw ? 0 : s->phase_inc;
    }
    int64_t adv = s->phase_adv;
    int64_t phase = s->phase;
    int64_t vkey = (volts < VOLTS_LIMIT ? volts : VOLTS_LIMIT) * 65536;
    if (n >= 2) s->act_key = vkey | ((phase + (n - 1) * dphase + adv) & 0xFFFF);
    else s->act_key = s->pend_key;
    phase = (phase + n * dphase) & 0xFFFF;
    s->phase = (int)phase;
    s->pend_key = vkey | ((phase + adv) & 0xFFFF);
}

static void main_loop_buttons(Core *s, int inputs)
{
    char s2 = (inputs & INPUT_S2) != 0;
    if (s->booting) {
        s->s2_level = s2;
        return;
    }
    if (s2) s->s2_wait_release = 1;
    else if (s->s2_wait_release) {
        s->s2_wait_release = 0;
        if (s->running) press_stop(s, STATE_STOPPED, FAULT_NONE);
        else press_start(s);
    }
    s->s2_level = s2;
}

static inline long long ceildiv_pos(long long a) { return -floordiv(-a, PWM_PERIOD_TCY); }

/* An1017Firmware.run; edge_offset < 0 means "no time given" (None). */
static void fw_run(Core *s, long long duration, int inputs, long long edge_offset, int have_edge, int pot, int have_pot)
{
    if (have_pot) s->pot_code = pot;
    main_loop_buttons(s, inputs);
    if ((inputs & INPUT_FAULT) && (s->running || s->booting)) /* FLTA: An1017Firmware._flta */
        press_stop(s, STATE_FAULT, FAULT_OVERCURRENT);
    long long t = s->t, t_end = t + duration;
    int new_hall = inputs & 7;
    long long edge_at = -1;
    if (new_hall != s->hall) {
        long long off = have_edge ? edge_offset : 0;
        if (off >= duration) off = duration - 1;
        edge_at = t + (off > 0 ? off : 0);
    }
    for (;;) {
        long long nxt = t_end;
        int kind = 0;
        if (s->running && s->t1_next < nxt) { nxt = s->t1_next; kind = 1; }
        if (s->booting && s->boot_end < nxt) { nxt = s->boot_end; kind = 2; }
        if (edge_at >= 0 && edge_at < nxt) { nxt = edge_at; kind = 3; }
        long long first = ceildiv_pos(t), last = ceildiv_pos(nxt);
        if (last > first) pwm_run(s, first, last - first);
        t = nxt;
        if (kind == 0) break;
        if (kind == 1) {
            s->t1_next += TIMER1_PERIOD_TCY;
            timer1(s);
        } else if (kind == 2) {
            run_motor(s);
        } else {
            edge_at = -1;
            apply_hall(s, new_hall, nxt);
        }
    }
    s->t = t_end;
}

static inline PyObject *duty_obj(int64_t d)
{
    if (d > 1000) d = 1000;
    if (d >= 0) return Py_NewRef(duty_ints[d]);
    return PyLong_FromLongLong(d);
}

static PyObject *fw_finish(Core *s, PyObject *seq)
{
    int64_t key = s->pend_key, duty[3]; /* what the PWM ISR wrote: PDC for the next period */
    svm_duties(asr(key, 16), key & 0xFFFF, duty);
    int sec = s->running ? s->sector : (SECTOR_TABLE[s->hall] & 0xFFFF);
    PyObject *tel = s->tel;
    if (tel == NULL || PyLong_AsLong(PyTuple_GET_ITEM(tel, 0)) != s->ref_speed
        || PyLong_AsLong(PyTuple_GET_ITEM(tel, 1)) != s->measured_speed
        || PyLong_AsLong(PyTuple_GET_ITEM(tel, 2)) != s->control_output) {
        PyObject *n = Py_BuildValue("(iii)", s->ref_speed, s->measured_speed, s->control_output);
        if (n == NULL) return NULL;
        Py_XSETREF(s->tel, n);
        tel = n;
    }
    PyObject *d = drive_type->tp_alloc(drive_type, 11);
    if (d == NULL) return NULL;
    PyTuple_SET_ITEM(d, 0, Py_NewRef(seq));
    PyTuple_SET_ITEM(d, 1, duty_obj(duty[0]));
    PyTuple_SET_ITEM(d, 2, duty_obj(duty[1]));
    PyTuple_SET_ITEM(d, 3, duty_obj(duty[2]));
    PyTuple_SET_ITEM(d, 4, PyLong_FromLong(s->output_mode));
    PyTuple_SET_ITEM(d, 5, PyLong_FromLong(s->state));
    PyTuple_SET_ITEM(d, 6, PyLong_FromLong(sec == SECTOR_INVALID ? 7 : sec));
    PyTuple_SET_ITEM(d, 7, PyBool_FromLong(s->cur_ccw));
    PyTuple_SET_ITEM(d, 8, PyBool_FromLong(s->req_ccw));
    PyTuple_SET_ITEM(d, 9, PyLong_FromLong(s->fault));
    PyTuple_SET_ITEM(d, 10, Py_NewRef(tel));
    for (int i = 1; i < 10; i++) {
        if (PyTuple_GET_ITEM(d, i) == NULL) { Py_DECREF(d); return NULL; }
    }
    return d;
}

/* ---------------------------------------------------------------- Python methods */
static int need_drive(void)
{
    if (drive_type == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "an1017 core: init(Drive) was not called");
        return -1;
    }
    return 0;
}

static int pot_of(PyObject *adc, int *pot, int *have)
{
    *have = 0;
    if (PyTuple_CheckExact(adc) || PyTuple_Check(adc)) {
        if (PyTuple_GET_SIZE(adc) == 0) return 0;
        long v = PyLong_AsLong(PyTuple_GET_ITEM(adc, 0));
        if (v == -1 && PyErr_Occurred()) return -1;
        *pot = (int)v;
        *have = 1;
        return 0;
    }
    int truth = PyObject_IsTrue(adc);
    if (truth <= 0) return truth;
    PyObject *x = PySequence_GetItem(adc, 0);
    if (x == NULL) return -1;
    long v = PyLong_AsLong(x);
    Py_DECREF(x);
    if (v == -1 && PyErr_Occurred()) return -1;
    *pot = (int)v;
    *have = 1;
    return 0;
}

static PyObject *Core_step(Core *s, PyObject *sensors)
{
    if (need_drive() < 0) return NULL;
    if (!PyTuple_Check(sensors) || PyTuple_GET_SIZE(sensors) != 5) {
        PyErr_SetString(PyExc_TypeError, "an1017 core step: sensors must be a 5-field Sensors tuple");
        return NULL;
    }
    PyObject *seq = PyTuple_GET_ITEM(sensors, 0);
    long inputs = PyLong_AsLong(PyTuple_GET_ITEM(sensors, 1));
    long edge = PyLong_AsLong(PyTuple_GET_ITEM(sensors, 2));
    long long seqv = PyLong_AsLongLong(seq);
    if (PyErr_Occurred()) return NULL;
    if (s->last_drive != NULL && seqv == s->last_seq) {
        Py_INCREF(s->last_drive);
        return s->last_drive;
    }
    int pot = 0, have_pot = 0;
    if (pot_of(PyTuple_GET_ITEM(sensors, 4), &pot, &have_pot) < 0) return NULL;
    int have_edge = edge != EDGE_NONE;
    fw_run(s, s->period_tcy, (int)inputs, have_edge ? (long long)edge * 2 : 0, have_edge, pot, have_pot);
    s->last_seq = seqv;
    PyObject *drive = fw_finish(s, seq);
    if (drive != NULL) {
        Py_INCREF(drive);
        Py_XSETREF(s->last_drive, drive);
    }
    return drive;
}

static PyObject *Core_run(Core *s, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "an1017 core run(duration_tcy, inputs, edge_offset_tcy, pot_code)");
        return NULL;
    }
    long long duration = PyLong_AsLongLong(args[0]);
    long inputs = PyLong_AsLong(args[1]);
    if (PyErr_Occurred()) return NULL;
    long long edge = 0;
    int have_edge = args[2] != Py_None, have_pot = args[3] != Py_None, pot = 0;
    if (have_edge) {
        edge = PyLong_AsLongLong(args[2]);
        if (edge == -1 && PyErr_Occurred()) return NULL;
    }
    if (have_pot) {
        long v = PyLong_AsLong(args[3]);
        if (v == -1 && PyErr_Occurred()) return NULL;
        pot = (int)v;
    }
    fw_run(s, duration, (int)inputs, edge, have_edge, pot, have_pot);
    Py_RETURN_NONE;
}

static PyObject *Core_finish(Core *s, PyObject *seq)
{
    if (need_drive() < 0) return NULL;
    return fw_finish(s, seq);
}

static PyObject *Core_new(PyTypeObject *type, PyObject *args, PyObject *kwds)
{
    (void)args; (void)kwds;
    Core *s = (Core *)type->tp_alloc(type, 0);
    if (s == NULL) return NULL;
    s->phase_offset = PHASE_OFFSET_DEFAULT;
    s->pot_code = 512;
    s->sector = s->last_sector = SECTOR_INVALID;
    s->min_period = MINPERIOD; /* the note's build; An1017Firmware.__init__ sets the options' */
    s->max_period = MAXPERIOD;
    s->period = MAXPERIOD;
    s->stall_limit = 100;
    s->period_tcy = PWM_PERIOD_TCY;
    return (PyObject *)s;
}

static int Core_traverse(Core *s, visitproc visit, void *arg)
{
    Py_VISIT(s->tel);
    Py_VISIT(s->last_drive);
    return 0;
}

static int Core_clear(Core *s)
{
    Py_CLEAR(s->tel);
    Py_CLEAR(s->last_drive);
    return 0;
}

static void Core_dealloc(Core *s)
{
    /* (a Python subclass's subtype_dealloc releases its heap type itself) */
    PyObject_GC_UnTrack(s);
    Core_clear(s);
    Py_TYPE(s)->tp_free((PyObject *)s);
}

/* pending_gains: None or (kp, ki, kd), as An1017Firmware.pending_gains */
static PyObject *get_pending(Core *s, void *c)
{
    (void)c;
    if (!s->has_pending) Py_RETURN_NONE;
    return Py_BuildValue("(iii)", s->pend_kp, s->pend_ki, s->pend_kd);
}

static int set_pending(Core *s, PyObject *v, void *c)
{
    (void)c;
    if (v == NULL || v == Py_None) { s->has_pending = 0; return 0; }
    int kp, ki, kd;
    if (!PyArg_ParseTuple(v, "iii", &kp, &ki, &kd)) return -1;
    s->pend_kp = kp; s->pend_ki = ki; s->pend_kd = kd;
    s->has_pending = 1;
    return 0;
}

/* ic7_fifo: a copy of the capture FIFO (a list of at most 4 TMR3 values) */
static PyObject *get_fifo(Core *s, void *c)
{
    (void)c;
    PyObject *l = PyList_New(s->fifo_n);
    if (l == NULL) return NULL;
    for (int i = 0; i < s->fifo_n; i++) {
        PyObject *x = PyLong_FromLong(s->fifo[i]);
        if (x == NULL) { Py_DECREF(l); return NULL; }
        PyList_SET_ITEM(l, i, x);
    }
    return l;
}

static int set_fifo(Core *s, PyObject *v, void *c)
{
    (void)c;
    if (v == NULL) { s->fifo_n = 0; return 0; }
    PyObject *seq = PySequence_Fast(v, "ic7_fifo must be a sequence of ints");
    if (seq == NULL) return -1;
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    if (n > 4) { Py_DECREF(seq); PyErr_SetString(PyExc_ValueError, "ic7_fifo holds at most 4 captures"); return -1; }
    int vals[4];
    for (Py_ssize_t i = 0; i < n; i++) {
        long x = PyLong_AsLong(PySequence_Fast_GET_ITEM(seq, i));
        if (x == -1 && PyErr_Occurred()) { Py_DECREF(seq); return -1; }
        vals[i] = (int)x;
    }
    Py_DECREF(seq);
    for (Py_ssize_t i = 0; i < n; i++) s->fifo[i] = vals[i];
    s->fifo_n = (int)n;
    return 0;
}

/* last_drive: None or the Drive a repeated seq gets; only None may be written (forget it) */
static PyObject *get_last_drive(Core *s, void *c)
{
    (void)c;
    if (s->last_drive == NULL) Py_RETURN_NONE;
    Py_INCREF(s->last_drive);
    return s->last_drive;
}

static int set_last_drive(Core *s, PyObject *v, void *c)
{
    (void)c;
    if (v != NULL && v != Py_None) {
        PyErr_SetString(PyExc_TypeError, "an1017 core last_drive: only None may be written");
        return -1;
    }
    Py_CLEAR(s->last_drive);
    return 0;
}

static PyGetSetDef Core_getset[] = {
    {"last_drive", (getter)get_last_drive, (setter)set_last_drive, "the Drive a repeated seq gets (None: none)", NULL},
    {"pending_gains", (getter)get_pending, (setter)set_pending, "gains waiting for the next Timer1 ISR", NULL},
    {"ic7_fifo", (getter)get_fifo, (setter)set_fifo, "IC7 capture FIFO (copy)", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

#define IM(name, field) {name, T_INT, offsetof(Core, field), 0, NULL}
#define LM(name, field) {name, T_LONGLONG, offsetof(Core, field), 0, NULL}
#define BM(name, field) {name, T_BOOL, offsetof(Core, field), 0, NULL}

static PyMemberDef Core_members[] = {
    BM("_adc_every", adc_every), BM("_c1_textbook", c1_textbook), BM("phase_advance_on", phase_advance_on),
    BM("ref_override_on", ref_override_on),
    IM("phase_offset", phase_offset), IM("min_period", min_period), IM("max_period", max_period), IM("kp", kp), IM("ki", ki), IM("kd", kd), IM("max_ph_adv_deg", max_ph_adv_deg),
    IM("max_ph_adv", max_ph_adv), IM("ref_override", ref_override), IM("stall_limit", stall_limit),
    LM("t", t), LM("t3_zero", t3_zero), LM("boot_end", boot_end), LM("t1_next", t1_next),
    LM("pend_key", pend_key), LM("act_key", act_key),
    IM("hall", hall), IM("pot_code", pot_code), IM("output_mode", output_mode),
    BM("running", running), BM("booting", booting), BM("cur_ccw", cur_ccw), BM("req_ccw", req_ccw),
    BM("s2_level", s2_level), BM("s2_wait_release", s2_wait_release),
    IM("state", state), IM("fault", fault), IM("ref_speed", ref_speed), IM("measured_speed", measured_speed),
    IM("control_output", control_output), IM("e1", e1), IM("e2", e2), IM("c0", c0), IM("c1", c1), IM("c2", c2),
    IM("phase", phase), IM("phase_inc", phase_inc), IM("phase_adv", phase_adv), IM("sector", sector),
    IM("last_sector", last_sector), IM("stall_counter", stall_counter), IM("period", period),
    IM("actual_capture", actual_capture), IM("past_capture", past_capture),
    LM("period_tcy", period_tcy), LM("last_seq", last_seq),
    {NULL, 0, 0, 0, NULL},
};

static PyMethodDef Core_methods[] = {
    {"step", (PyCFunction)Core_step, METH_O, "step(sensors) -> Drive: one lockstep period of period_tcy."},
    {"run", (PyCFunction)(void (*)(void))Core_run, METH_FASTCALL,
     "run(duration_tcy, inputs, edge_offset_tcy | None, pot_code | None): An1017Firmware.run."},
    {"finish", (PyCFunction)Core_finish, METH_O, "finish(seq) -> Drive for the current state."},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject CoreType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "hilbench.targets.an1017._core.Core",
    .tp_basicsize = sizeof(Core),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_BASETYPE | Py_TPFLAGS_HAVE_GC,
    .tp_doc = "Firmware state and compiled step of the AN1017 C backend (base of an1017._CFirmware).",
    .tp_new = Core_new,
    .tp_dealloc = (destructor)Core_dealloc,
    .tp_traverse = (traverseproc)Core_traverse,
    .tp_clear = (inquiry)Core_clear,
    .tp_members = Core_members,
    .tp_getset = Core_getset,
    .tp_methods = Core_methods,
};

static PyObject *mod_init(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 2) { PyErr_SetString(PyExc_TypeError, "init(Drive, SINE_TABLE)"); return NULL; }
    PyObject *drive = args[0];
    PyObject *table = PySequence_Fast(args[1], "an1017 core init: SINE_TABLE must be a sequence");
    if (table == NULL) return NULL;
    if (PySequence_Fast_GET_SIZE(table) != 172) {
        Py_DECREF(table);
        PyErr_SetString(PyExc_ValueError, "an1017 core init: SINE_TABLE must have 172 entries");
        return NULL;
    }
    for (int i = 0; i < 172; i++) {
        long long v = PyLong_AsLongLong(PySequence_Fast_GET_ITEM(table, i));
        if (v == -1 && PyErr_Occurred()) { Py_DECREF(table); return NULL; }
        SINE_TABLE[i] = v;
    }
    Py_DECREF(table);
    if (!PyType_Check(drive) || !PyType_IsSubtype((PyTypeObject *)drive, &PyTuple_Type)) {
        PyErr_SetString(PyExc_TypeError, "an1017 core init: Drive must be a tuple subclass (NamedTuple)");
        return NULL;
    }
    Py_INCREF(drive);
    Py_XSETREF(drive_type, (PyTypeObject *)drive);
    Py_RETURN_NONE;
}

static PyObject *mod_svm(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 2) { PyErr_SetString(PyExc_TypeError, "svm(volts, angle_u16)"); return NULL; }
    long long v = PyLong_AsLongLong(args[0]), a = PyLong_AsLongLong(args[1]);
    if (PyErr_Occurred()) return NULL;
    int64_t d[3];
    svm_duties(v, a, d);
    return Py_BuildValue("(LLL)", (long long)d[0], (long long)d[1], (long long)d[2]);
}

static PyMethodDef module_methods[] = {
    {"init", (PyCFunction)(void (*)(void))mod_init, METH_FASTCALL,
     "init(Drive, SINE_TABLE): the NamedTuple type the cores build and svm.SINE_TABLE."},
    {"svm", (PyCFunction)(void (*)(void))mod_svm, METH_FASTCALL, "svm(volts, angle_u16): svm.svm in C."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moduledef = {
    PyModuleDef_HEAD_INIT, "_core", "Compiled AN1017 firmware model (optional).", -1, module_methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__core(void)
{
    for (int i = 0; i <= 1000; i++) {
        duty_ints[i] = PyLong_FromLong(i);
        if (duty_ints[i] == NULL) return NULL;
    }
    if (PyType_Ready(&CoreType) < 0) return NULL;
    PyObject *m = PyModule_Create(&moduledef);
    if (m == NULL) return NULL;
    Py_INCREF(&CoreType);
    if (PyModule_AddObject(m, "Core", (PyObject *)&CoreType) < 0) {
        Py_DECREF(&CoreType);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
