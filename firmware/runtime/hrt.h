/* hrt.h: the hilbench runtime, which puts a firmware in the loop (C99, no heap, no floating point,
 * exact with a 16-bit int).
 *
 * A firmware DECLARES itself in one const hrt_firmware_t named `hrt_firmware` (one firmware per
 * program, as one firmware per chip): its name and version, its clock, its PWM
 * (period, compare counts, when a written duty takes effect), the inputs it reads (hall lines, a
 * quadrature counter with index, ADC channels with their roles, buttons, the fault input), its
 * interrupt bodies (the PWM-period ISR, periodic or one-shot timers, edge events on inputs, an
 * optional main-loop body) with the order in which simultaneous ones run, its parameters and its
 * telemetry. It keeps its state in its own struct, whose FIRST member is the hrt_t the runtime
 * works on (a body gets that hrt_t and casts it to the firmware's struct), and writes its ISR bodies
 * against the services below (time, inputs, ADC codes, duty registers, timers).
 *
 * The RUNTIME owns everything around the bodies:
 * - the lockstep scheduler (hrt_span_*): one span of virtual time per Sensors frame, every body
 *   at its true time inside it, simultaneous events in the declared order, every input edge at its
 *   timestamp, the duty registers latched as the declared timing says;
 * - the real-time glue a port calls from the chip's own interrupts (hrt_rt_*);
 * - in hrt_link.c, the wire: the handshake (with the firmware's self-description), the parameter
 *   protocol (all-or-nothing writes), the watchdog in every mode, the answer to a repeated seq and
 *   the telemetry packing.
 * A PORT supplies only byte I/O, a clock and interrupt glue (the hrt_port_* functions of
 * hrt_link.h). docs/porting.md is the guide; firmware/template/ is a firmware to start from.
 *
 * Time is counted in ticks of the firmware's declared clock (ticks_per_us: a whole number of MHz)
 * in a uint32_t that wraps; a span is at most 2^31 ticks. Bodies run to completion (a body never
 * preempts another in lockstep); `priority` only orders events that fall on the same tick: lower
 * first.
 */
#ifndef HRT_H
#define HRT_H

#include <stdint.h>

#include "hbp_messages.h"
/* The firmware's own capacities (its folder provides hrt_config.h, possibly empty): every
 * translation unit of a build must see the same, so they live in a header, not on a command line. */
#include "hrt_config.h"

#define HRT_API_VERSION 1u

/* ---- capacities (hrt_config.h may set them) ---- */
#ifndef HRT_MAX_TIMERS
#define HRT_MAX_TIMERS 4u      /* declared timers */
#endif
#ifndef HRT_MAX_ADC
#define HRT_MAX_ADC 8u         /* ADC codes kept from Sensors (channels beyond it are ignored) */
#endif
#ifndef HRT_MAX_ATTACH
#define HRT_MAX_ATTACH 0u      /* edge bodies attached at run time (hrt_attach_interrupt) */
#endif
#ifndef HRT_ENCODER
#define HRT_ENCODER 1          /* keep the quadrature count (0: a firmware without an encoder saves 2 bytes) */
#endif
#ifndef HRT_MICROS
#define HRT_MICROS 1           /* hrt_micros (0: saves the 2 bytes of the tick counter's wraps) */
#endif
#ifndef HRT_HALF_PERIOD
#define HRT_HALF_PERIOD 1      /* HRT_DUTY_HALF_PERIOD served (0: a firmware that does not declare it saves its code) */
#endif
#ifndef HRT_MAIN_RATE
#define HRT_MAIN_RATE 1        /* a main body at a declared rate (0: once per span only) */
#endif
/* Room for a copy of the firmware's state, to predict the next span's duties (HostHello mode PREDICT,
 * hrt_link.c): at least the firmware's state_size. 0 (the default): no prediction, no copy, the
 * declaration without state_size; a firmware opts in in its hrt_config.h, a chip short of RAM (the
 * dsPIC30F2010's AN1017 build) opts out with 0 on its command line. Needs HRT_REPORT_MEAN 1. */
#ifndef HRT_PREDICT_BYTES
#define HRT_PREDICT_BYTES 0u
#endif
#ifndef HRT_REPORT_MEAN
#define HRT_REPORT_MEAN 0      /* HRT_REPORT_ACTIVE as a mean over the span (1: 3 x 64-bit accumulators) */
#endif
#define HRT_NONE 0xFFu
/* Monitor mode (a real-motor build, hrt_link.h) and real time (HostHello mode REALTIME): the modes in
 * which a port's own clock and interrupts drive the firmware. HRT_REALTIME is 1 by default (0 in a
 * monitor build, which agrees to no other mode); a lockstep-only build (the dsPIC30F2010's board
 * profile, docs/board.md "Does it fit") sets 0: the link refuses the mode and neither it nor the
 * runtime keeps code for it. */
#ifndef HRT_MONITOR
#define HRT_MONITOR 0
#endif
#ifndef HRT_REALTIME
#define HRT_REALTIME (!HRT_MONITOR)
#endif
#if HRT_MONITOR && HRT_REALTIME
#error "a real-motor build (HRT_MONITOR) agrees to mode MONITOR only: leave HRT_REALTIME at 0"
#endif
/* The port runs timers in hardware (HRT_PORT_HW) in a mode this build has (hrt_port_timer). */
#if defined(HRT_PORT_HW) && HRT_PORT_HW && (HRT_REALTIME || HRT_MONITOR)
#define HRT_HW_TIMERS 1
#else
#define HRT_HW_TIMERS 0
#endif
/* The self-description beyond the HELLO (hrt_link.h explains it): 1 by default. A build without it keeps
 * none of the texts and scales only a description sends (parameter and telemetry names, units, types:
 * HRT_PARAM, HRT_TELEMETRY; HRT_DESCRIBED("rpm") for a text elsewhere). */
#ifndef HRT_DESCRIBE
#define HRT_DESCRIBE 1
#endif
#if HRT_DESCRIBE
#define HRT_DESCRIBED(text) text
#else
#define HRT_DESCRIBED(text) ""
#endif

/* ---- input lines: the bits of Sensors.inputs (the protocol's HBP_INPUT_*) ---- */
#define HRT_IN_HALL_A HBP_INPUT_HALL_A
#define HRT_IN_HALL_B HBP_INPUT_HALL_B
#define HRT_IN_HALL_C HBP_INPUT_HALL_C
#define HRT_IN_HALLS (HRT_IN_HALL_A | HRT_IN_HALL_B | HRT_IN_HALL_C)
#define HRT_IN_S2 HBP_INPUT_S2
#define HRT_IN_S3 HBP_INPUT_S3
#define HRT_IN_FAULT HBP_INPUT_FAULT
#define HRT_IN_INDEX HBP_INPUT_INDEX /* an event: a pulse began at the edge's time */
/* Lines that change at timed edges (the rest change at a span's start). */
#define HRT_IN_EDGE_LINES (HRT_IN_HALLS | HRT_IN_INDEX)
/* INDEX for a firmware that reads it (its declaration's inputs), else 0: one that does not never sees an
 * INDEX pulse, and a build whose declaration is a constant in the unit (the dsPIC's) keeps no code for one. */
#define HRT_INDEX_READ ((unsigned)hrt_firmware.inputs & HRT_IN_INDEX)

/* ---- declarations ---- */
/* When a duty written by hrt_pwm_write takes effect (the PWM's reload rule). */
#define HRT_DUTY_IMMEDIATE 0u   /* at once (the compare register is the output) */
#define HRT_DUTY_NEXT_PERIOD 1u /* at the next PWM period boundary (dsPIC MCPWM with IUE = 0) */
#define HRT_DUTY_HALF_PERIOD 2u /* half a PWM period after each boundary (F28x compare reload at period match) */

/* Which duties the Drive reports (hrt_firmware_t.duty_report). */
#define HRT_REPORT_WRITTEN 0u /* the compare registers as written: in effect from the next latch (AN1017) */
/* the duties active at the outputs over the span: their time-weighted mean, an integer rounded half
 * to even (with HRT_REPORT_MEAN 1 in hrt_config.h; else the active ones at the span's end). With the
 * latches on the span's boundaries that is the value active during the span. */
#define HRT_REPORT_ACTIVE 1u

#define HRT_EDGE_BOTH 0u
#define HRT_EDGE_RISING 1u
#define HRT_EDGE_FALLING 2u

/* Why the firmware is told to stop (hrt_firmware_t.stop). */
#define HRT_STOP_COMMAND 0u  /* the host's Stop */
#define HRT_STOP_WATCHDOG 1u /* no Sensors for the watchdog time: outputs off, fault WATCHDOG */

typedef struct hrt hrt_t;
typedef void (*hrt_body_fn)(hrt_t *rt);

/* A timer: started and stopped by the firmware (hrt_timer_start/stop), its body at every expiry. */
typedef struct {
    hrt_body_fn body;
    uint32_t period_ticks; /* 0: one-shot (stops after its body), else periodic */
    hbp_u8 priority;
} hrt_timer_decl_t;

/* An edge event: body runs when one of `lines` changes with the polarity asked for. The bodies of
 * lines that change at the same instant run in the order of the declaration. */
typedef struct {
    hrt_body_fn body;
    hbp_u8 lines;    /* HRT_IN_* */
    hbp_u8 polarity; /* HRT_EDGE_* */
} hrt_edge_decl_t;

/* A parameter: the wire's ParamInfo. Values are int32_t; ptype says how to read them. A build without
 * the self-description (HRT_DESCRIBE 0) keeps only what a checked write reads: the range and the access.
 * A declaration that is built both ways writes its entries with HRT_PARAM (the fields in this order). */
typedef struct {
#if HRT_DESCRIBE
    const char *name; /* <= HBP_MAX_NAME printable ASCII */
    const char *unit; /* <= HRT_MAX_UNIT printable ASCII ("" = none) */
#endif
    int32_t min_value;
    int32_t max_value;
#if HRT_DESCRIBE
    hbp_u8 ptype;    /* HBP_PTYPE_* */
#endif
    hbp_u8 access;   /* HBP_ACCESS_* */
} hrt_param_decl_t;
#if HRT_DESCRIBE
#define HRT_PARAM(name, unit, min, max, ptype, access) {name, unit, min, max, ptype, access}
#else
#define HRT_PARAM(name, unit, min, max, ptype, access) {min, max, access}
#endif

#define HRT_MAX_UNIT 8u

/* A telemetry slot of Drive: value (int16_t) x scale_num / scale_den is the quantity in `unit`. A build
 * without the self-description keeps only the id (TargetHello's); HRT_TELEMETRY writes an entry both ways. */
typedef struct {
#if HRT_DESCRIBE
    const char *name; /* <= HBP_MAX_NAME printable ASCII, a column name: [a-z0-9_] */
    const char *unit;
    int32_t scale_num;
    int32_t scale_den; /* > 0 */
#endif
    hbp_u8 id;       /* HBP_TELEMETRY_*, or a target-defined id 0x80..0xFE */
#if HRT_DESCRIBE
    hbp_u8 ptype;    /* HBP_PTYPE_Q15 / INT / BOOL: how the raw value reads */
#endif
} hrt_telemetry_decl_t;
#if HRT_DESCRIBE
#define HRT_TELEMETRY(name, unit, num, den, id, ptype) {name, unit, num, den, id, ptype}
#else
#define HRT_TELEMETRY(name, unit, num, den, id, ptype) {id}
#endif

/* A checked parameter write (at most HBP_MAX_PARAM_PAIRS distinct ids). */
typedef struct {
    hbp_u8 n;
    hbp_u8 id[HBP_MAX_PARAM_PAIRS];
    int32_t value[HBP_MAX_PARAM_PAIRS];
} hrt_param_request_t;

/* The Drive as the firmware reports it: it fills output_mode (HBP_OUTPUT_*), state (HBP_STATE_*),
 * sector (0..5, 7 = none/invalid), direction_ccw, required_ccw (0/1), fault (HBP_FAULT_*, 0..63)
 * and telemetry[] in the declared order; the runtime fills seq, the duties and n_telemetry. */
typedef hbp_drive_t hrt_report_t;

typedef struct {
    /* identity */
    const char *name;            /* <= HBP_MAX_NAME printable ASCII: the HELLO's firmware_name */
    uint16_t version;
    hbp_u8 ticks_per_us;        /* the virtual clock: its ticks per microsecond (20: a 20 MHz Tcy) */
    uint16_t period_step_us;     /* an agreed period must be a multiple of it (0: any) */
    /* PWM */
    uint32_t pwm_period_ticks;   /* one PWM period (the PWM-period ISR's rate) */
    uint16_t pwm_counts;         /* the compare count of 100 % duty (Drive's scale) */
    hbp_u8 duty_timing;         /* HRT_DUTY_* */
    hbp_u8 duty_report;         /* HRT_REPORT_* (default 0: WRITTEN) */
    hbp_u8 pwm_priority;
    hrt_body_fn pwm_isr;         /* at every PWM period boundary, after the duty latch; may be 0 */
    /* inputs */
    hbp_u8 inputs;              /* HRT_IN_* lines the firmware reads (its self-description) */
    uint16_t encoder_counts;     /* quadrature counts per revolution (0: no encoder) */
    hbp_u8 adc_bits;
    hbp_u8 n_adc;               /* ADC channels, in the order Sensors carries them */
    const hbp_u8 *adc_roles;    /* HBP_ADC_* per channel */
    /* interrupt bodies */
    const hrt_timer_decl_t *timers;
    hbp_u8 n_timers;            /* <= HRT_MAX_TIMERS */
    const hrt_edge_decl_t *edges;
    hbp_u8 n_edges;
    hbp_u8 edge_priority;       /* of input edges against timers and the PWM at the same tick */
    hrt_body_fn main_body;       /* the main loop's body, or 0 */
    /* 0: once at the start of every span, before any ISR; else its rate (it then takes the timer
     * slot n_timers, so HRT_MAX_TIMERS > n_timers) */
    uint32_t main_period_ticks;
    hbp_u8 main_priority;
    /* parameters */
    const hrt_param_decl_t *params;
    hbp_u8 n_params;
    int32_t (*param_get)(hrt_t *rt, hbp_u8 id);
    void (*param_set)(hrt_t *rt, hbp_u8 id, int32_t value); /* a checked value; ids of one write in order */
    /* Cross-parameter constraints of a write whose ids, access and ranges are already checked: return
     * HBP_RESULT_OK, or HBP_RESULT_CONSTRAINT with *param_id and *detail (the constraint number) set.
     * hrt_param_candidate gives the value an id would have after the write. May be 0. */
    hbp_u8 (*param_check)(hrt_t *rt, const hrt_param_request_t *req, hbp_u8 *param_id, hbp_u8 *detail);
    /* telemetry and the Drive */
    const hrt_telemetry_decl_t *telemetry;
    hbp_u8 n_telemetry;         /* <= HBP_MAX_TELEMETRY */
    void (*report)(hrt_t *rt, hrt_report_t *out);
    /* commands */
    void (*start)(hrt_t *rt);                 /* the host's Start (the S2 button as a command) */
    void (*stop)(hrt_t *rt, hbp_u8 why);     /* HRT_STOP_*: outputs off */
#if HRT_PREDICT_BYTES > 0
    /* sizeof the firmware's state struct (its hrt_t first): what the link copies and puts back to
     * predict a span (mode PREDICT; HRT_PREDICT_BYTES >= it). The state must be all of the firmware's
     * state: its bodies write nothing else (no other statics, no port registers). 0: no prediction. */
    uint16_t state_size;
#endif
} hrt_firmware_t;

/* The one firmware of this program (the firmware's source defines it). HRT_DESCRIBE changes the layout
 * of the parameter and telemetry entries, so the symbol carries it: a declaration compiled one way and a
 * runtime compiled the other fail to link (undefined reference to hrt_firmware_built_with_HRT_DESCRIBE_N)
 * instead of reading each other's entries at the wrong offsets. The source still writes `hrt_firmware`. */
#if HRT_DESCRIBE
#define hrt_firmware hrt_firmware_built_with_HRT_DESCRIBE_1
#else
#define hrt_firmware hrt_firmware_built_with_HRT_DESCRIBE_0
#endif
extern const hrt_firmware_t hrt_firmware;
/* The firmware's power-on, for the runtime's shared ports (firmware/runtime/ports/CHIP): initialise its
 * one static state (hrt_init first) and return its runtime. A firmware with ports of its own (AN1017)
 * need not define it. */
hrt_t *hrt_firmware_init(void);

/* ---- runtime state (the first member of the firmware's struct; the fields are the runtime's) ---- */
typedef struct {
    hbp_u8 lines;
    hbp_u8 polarity;
    hrt_body_fn body;
} hrt_attached_t;

struct hrt {
    uint32_t now;                /* the current instant (ticks, wraps) */
    uint32_t pwm_due;            /* the next PWM period boundary */
    uint32_t timer_due[HRT_MAX_TIMERS]; /* the next expiry of each running timer */
#if HRT_MICROS
    uint16_t now_hi;             /* wraps of `now` (hrt_micros) */
#endif
    uint16_t pwm_count;          /* PWM boundaries so far (wraps): in the PWM ISR, this one's number */
    uint16_t duty[3];            /* the compare registers as the firmware wrote them */
    uint16_t duty_active[3];     /* in effect at the outputs (NEXT_PERIOD / HALF_PERIOD) */
    uint16_t adc[HRT_MAX_ADC];   /* the newest codes (mid-scale until the first) */
#if HRT_ENCODER
    uint16_t encoder;            /* the newest quadrature count */
#endif
    hbp_u8 timers_on;           /* bit i: timer i runs */
    hbp_u8 timers_hw;           /* bit i: the port runs timer i in hardware (real time) */
    hbp_u8 in;                  /* input levels now (HRT_IN_*; INDEX set only during its edge) */
    hbp_u8 changed;             /* the lines of the edge being served */
    hbp_u8 flags;               /* HRT_F_* */
#if HRT_REPORT_MEAN
    uint64_t duty_acc[3];        /* sum of duty_active x ticks since acc_mark's span began */
    uint32_t acc_mark;           /* the tick up to which duty_acc counts */
    uint32_t span_start;
    uint16_t duty_mean[3];       /* over the last lockstep span */
#endif
#if HRT_MAX_ATTACH > 0
    hrt_attached_t attached[HRT_MAX_ATTACH];
#endif
};

#define HRT_F_RELOAD 0x01u       /* a half-period reload is due at pwm_due - period / 2 */
#define HRT_F_HW 0x02u           /* real time on a port whose interrupts run the bodies */
#define HRT_F_MEAN 0x04u         /* the span's mean duties are kept (HRT_REPORT_MEAN: duty_report ACTIVE, or a prediction) */

/* ---- setup ---- */
/* Zero the runtime state: time 0, the first PWM boundary at 0, duties at half the period counts,
 * ADC codes at mid-scale (the firmware's init may write others). */
void hrt_init(hrt_t *rt);

/* ---- lockstep: one span of virtual time ----
 * A span (one Sensors frame in lockstep) is served in three steps:
 * hrt_span_begin: the lines that are not edge lines take `inputs`' levels, the ADC codes (n_adc of
 *   them; channels beyond HRT_MAX_ADC ignored; none: the previous codes stay) and the encoder count
 *   are the new ones, the main-loop body runs if it runs once per span, and the edge lines change
 *   now where no listed edge accounts for `inputs`: the hall levels of `inputs` when the span has
 *   no edge (n_edges = 0), an INDEX pulse when `inputs` has one and no edge carries it;
 * hrt_span_edge, for each edge in time order: every event before it runs (earlier ticks, or the
 *   same tick with a priority below edge_priority), then the edge: the hall lines take `lines`'
 *   levels and the edge bodies of the changed lines run (HRT_IN_INDEX in `lines`: a pulse began);
 * hrt_span_end: every event before `end` runs and time stands at `end` (an event due exactly at
 *   `end` belongs to the next span).
 * Times are absolute ticks (hrt_now at begin + an offset); an edge at or after the span's end is
 * the caller's to move to the span's last tick (end - 1). A span of no ticks runs nothing. */
void hrt_span_begin(hrt_t *rt, hbp_u8 inputs, hbp_u8 n_edges, hbp_u8 edges_have_index, const uint16_t *adc,
                    hbp_u8 n_adc, uint16_t encoder);
void hrt_span_edge(hrt_t *rt, uint32_t at_ticks, hbp_u8 lines);
void hrt_span_end(hrt_t *rt, uint32_t end_ticks);
#if HRT_REPORT_MEAN
/* After hrt_span_end of a span run with HRT_F_MEAN: the time-weighted mean of a phase's active duty
 * over it (rounded half to even). */
static inline uint16_t hrt_span_mean(const hrt_t *rt, hbp_u8 phase)
{
    return rt->duty_mean[phase];
}
#endif

/* ---- real time: the glue a port calls from the chip's own interrupts (docs/porting.md) ----
 * `now` is the port's clock in the firmware's ticks. Timers a port runs in hardware (it says so in
 * hrt_port_timer, HRT_PORT_HW builds) expire through hrt_rt_timer; the others are served by
 * hrt_rt_pwm at PWM-period resolution. */
void hrt_rt_pwm(hrt_t *rt, uint32_t now);            /* the PWM-period interrupt: latch, PWM ISR, soft timers */
#if HRT_HALF_PERIOD
void hrt_rt_reload(hrt_t *rt, uint32_t now);         /* the half-period reload interrupt (HALF_PERIOD) */
#endif
void hrt_rt_timer(hrt_t *rt, hbp_u8 id, uint32_t now); /* a hardware-run timer expired */
void hrt_rt_edge(hrt_t *rt, hbp_u8 lines, uint32_t at); /* input edge lines changed (capture time `at`) */
void hrt_rt_levels(hrt_t *rt, hbp_u8 levels, const uint16_t *adc, hbp_u8 n_adc, uint16_t encoder);
void hrt_rt_main(hrt_t *rt, uint32_t now);           /* from the main loop: the main body */
void hrt_rt_enter(hrt_t *rt, hbp_u8 hw);            /* real time begins (hw: the port's interrupts run it) */

#if HRT_HW_TIMERS
/* A port whose interrupts run the bodies in real time provides this: start (on = 1, first expiry
 * `first_ticks` from now) or stop a timer in hardware; return 1 if it does so, 0 to leave the
 * timer to the runtime (served in hrt_rt_pwm). */
hbp_u8 hrt_port_timer(hbp_u8 id, hbp_u8 on, uint32_t first_ticks);
#endif

/* ---- services for the firmware's bodies ---- */
static inline uint32_t hrt_now(const hrt_t *rt)      /* ticks: an edge body's capture timestamp */
{
    return rt->now;
}
#if HRT_MICROS
uint32_t hrt_micros(hrt_t *rt);                      /* microseconds (wraps at 2^32 us) */
#endif
static inline hbp_u8 hrt_inputs(const hrt_t *rt)    /* HRT_IN_* levels now */
{
    return rt->in;
}
static inline hbp_u8 hrt_pin(const hrt_t *rt, hbp_u8 line)
{
    return (hbp_u8)((rt->in & line) != 0u);
}
static inline hbp_u8 hrt_edge_lines(const hrt_t *rt) /* in an edge body: the lines that changed */
{
    return rt->changed;
}
static inline uint16_t hrt_adc(const hrt_t *rt, hbp_u8 channel)
{
    return rt->adc[channel];
}
static inline uint16_t hrt_encoder(const hrt_t *rt)
{
#if HRT_ENCODER
    return rt->encoder;
#else
    (void)rt;
    return 0u;
#endif
}
static inline uint16_t hrt_pwm_count(const hrt_t *rt) /* in the PWM ISR: this boundary's number */
{
    return rt->pwm_count;
}
/* The compare registers (0..pwm_counts, larger values are reported as pwm_counts); they take effect
 * as duty_timing says. */
void hrt_pwm_write(hrt_t *rt, uint16_t a, uint16_t b, uint16_t c);
/* Registers and outputs at once (a start-up preset, an override): no latch to wait for. */
void hrt_pwm_preset(hrt_t *rt, uint16_t a, uint16_t b, uint16_t c);
static inline uint16_t hrt_duty(const hrt_t *rt, hbp_u8 phase) /* as written */
{
    return rt->duty[phase];
}
static inline uint16_t *hrt_duty_registers(hrt_t *rt) /* the three registers, to write in place */
{
    return rt->duty;
}
uint16_t hrt_duty_active(const hrt_t *rt, hbp_u8 phase); /* at the outputs now */
/* Start a declared timer: its first expiry first_ticks from now (>= 1), then every period_ticks. */
/* (inline: a firmware starts and stops its timers with constant ids and times, which then fold) */
static inline void hrt_timer_start(hrt_t *rt, hbp_u8 id, uint32_t first_ticks)
{
    hbp_u8 bit = (hbp_u8)(1u << id);
    if (first_ticks == 0u) {
        first_ticks = 1u;
    }
    rt->timer_due[id] = rt->now + first_ticks;
    rt->timers_on = (hbp_u8)(rt->timers_on | bit);
#if HRT_HW_TIMERS
    rt->timers_hw = (hbp_u8)(rt->timers_hw & (hbp_u8)~bit);
    if ((rt->flags & HRT_F_HW) != 0u && hrt_port_timer(id, 1u, first_ticks)) {
        rt->timers_hw = (hbp_u8)(rt->timers_hw | bit);
    }
#endif
}

static inline void hrt_timer_stop(hrt_t *rt, hbp_u8 id)
{
    hbp_u8 bit = (hbp_u8)(1u << id);
#if HRT_HW_TIMERS
    if ((rt->timers_hw & bit) != 0u) {
        (void)hrt_port_timer(id, 0u, 0u);
    }
    rt->timers_hw = (hbp_u8)(rt->timers_hw & (hbp_u8)~bit);
#endif
    rt->timers_on = (hbp_u8)(rt->timers_on & (hbp_u8)~bit);
}

static inline hbp_u8 hrt_timer_running(const hrt_t *rt, hbp_u8 id)
{
    return (hbp_u8)(((unsigned)rt->timers_on >> id) & 1u);
}
/* Arduino-style attachInterrupt on the virtual inputs (HRT_MAX_ATTACH > 0): body runs on the lines'
 * edges of that polarity, after the declared edge bodies; body 0 detaches. Returns 0 when full. */
hbp_u8 hrt_attach_interrupt(hrt_t *rt, hbp_u8 lines, hbp_u8 polarity, hrt_body_fn body);

/* ---- parameters (the link calls these; a firmware may too) ---- */
/* The value id would have after req (req's value if it writes id, else the present one). */
int32_t hrt_param_candidate(hrt_t *rt, const hrt_param_request_t *req, hbp_u8 id);
/* Check a write whole (ids, access, ranges, duplicates, then the firmware's constraints) and apply
 * all of it or nothing. Returns HBP_RESULT_*; *param_id names the offending id (the last written id
 * when OK), *detail the constraint number. */
hbp_u8 hrt_param_write(hrt_t *rt, const hrt_param_request_t *req, hbp_u8 *param_id, hbp_u8 *detail);

/* ---- outputs ---- */
/* The Drive of the present state: the duties the declaration's duty_report names (clamped to
 * pwm_counts), then the firmware's report. */
void hrt_report(hrt_t *rt, hbp_u8 seq, hrt_report_t *out);

#endif /* HRT_H */
