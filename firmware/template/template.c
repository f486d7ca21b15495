/* firmware/template/template.c: a firmware on the hilbench runtime, to copy and start from
 * (docs/porting.md walks through it).
 *
 * What it does: a hall-commutated drive at a duty set by a parameter. On every hall edge (an edge
 * event, with the capture time the runtime gives it) it takes the sector the halls say and points
 * the voltage vector 90 degrees ahead of it, at the modulation of parameter `duty_pct`; the PWM
 * period ISR writes the duties; a 1 kHz timer measures the speed from the hall period; the main
 * loop body watches the S2 button (start/stop). It declares a parameter with a constraint and three
 * telemetry values with their units, so `hilbench run sil:firmware/template` records named columns
 * with no Python module for it.
 *
 * Everything chip-specific is in a port (firmware/runtime/ports/CHIP): this file and the runtime
 * build unchanged for the host (SIL), an AVR in simavr, a Cortex-M4 in QEMU or a board.
 *
 * C99, no heap, no floating point, correct with a 16-bit int (the strict flags of the Makefile).
 */
#include "hrt.h"

/* ---- the chip this firmware is written for (the virtual clock and PWM the runtime models) ---- */
#define TPL_TICKS_PER_US 20u                                 /* a 20 MHz instruction clock */
#define TPL_PWM_TICKS 1000u                                  /* 20 kHz: 1000 ticks a period */
#define TPL_PWM_COUNTS 1000u                                 /* the compare count of 100 % duty */
#define TPL_TIMER_TICKS ((uint32_t)TPL_TICKS_PER_US * 1000u) /* 1 kHz */
#define TPL_POLE_PAIRS 5u

/* ---- parameters (ids are the order of the table below) ---- */
#define P_DUTY_PCT 0u
#define P_ADVANCE_DEG 1u
#define P_LIMIT_RPM 2u
#define N_PARAMS 3u

/* The firmware's state. The runtime's hrt_t comes FIRST: a body gets it and casts to this. */
typedef struct {
    hrt_t rt;
    uint8_t running;
    uint8_t s2_was;
    uint8_t sector;         /* 0..5 from the halls, 7: invalid */
    int16_t duty_pct;       /* parameters */
    int16_t advance_deg;
    int16_t limit_rpm;
    uint32_t last_edge;     /* the capture time of the last hall edge (ticks) */
    uint32_t edge_interval; /* ticks between the last two hall edges (0: none yet) */
    uint16_t speed_rpm;     /* measured by the 1 kHz timer */
    uint16_t quiet_ms;      /* ms since the last hall edge */
    uint16_t edges;         /* hall edges seen (wraps) */
} tpl_t;

static tpl_t fw;

static tpl_t *me(hrt_t *rt)
{
    return (tpl_t *)(void *)rt;
}

/* ---- the drive ---- */

/* Sector (0..5) of the hall pattern C B A; 7 for 000 and 111 (a broken sensor). */
static const uint8_t sector_of_halls[8] = {7u, 4u, 2u, 3u, 0u, 5u, 1u, 7u};

/* cos(k x 30 degrees) in Q15, k = 0..11 */
static const int16_t cos30[12] = {32767, 28378, 16384, 0, -16384, -28378, -32767, -28378, -16384, 0, 16384, 28378};

/* A duty of phase `phase` for a vector at angle `k30` (in 30-degree steps) with modulation `m`
 * (0..1000 per mille of half the period's counts). */
static uint16_t phase_duty(int32_t m, uint8_t k30, uint8_t phase)
{
    int32_t c = cos30[(uint8_t)(k30 + 12u - 4u * phase) % 12u]; /* phases 120 degrees apart */
    int32_t half = (int32_t)(TPL_PWM_COUNTS / 2u);
    return (uint16_t)(half + (half * m / 1000) * c / 32768);
}

static void write_vector(tpl_t *t)
{
    uint8_t k30;
    int32_t m;
    if (!t->running || t->sector > 5u) {
        hrt_pwm_write(&t->rt, TPL_PWM_COUNTS / 2u, TPL_PWM_COUNTS / 2u, TPL_PWM_COUNTS / 2u);
        return;
    }
    /* the sector's centre (sector s spans s x 60 .. s x 60 + 60 degrees: centre at 2s + 1 steps of
     * 30 against the sector numbering, which runs against the rotation), then 90 degrees and the
     * advance ahead of the rotor */
    k30 = (uint8_t)((2u * t->sector + 1u + 9u + 12u - (uint8_t)(t->advance_deg / 30)) % 12u);
    m = (t->speed_rpm > (uint16_t)t->limit_rpm) ? 0 : (int32_t)t->duty_pct * 10;
    hrt_pwm_write(&t->rt, phase_duty(m, k30, 0u), phase_duty(m, k30, 1u), phase_duty(m, k30, 2u));
}

/* ---- interrupt bodies ---- */

/* The PWM period ISR: after the runtime latched the duties written last (HRT_DUTY_NEXT_PERIOD). */
static void body_pwm(hrt_t *rt)
{
    write_vector(me(rt));
}

/* A hall line changed: hrt_now is its capture time; the sector and the interval between edges. */
static void body_hall(hrt_t *rt)
{
    tpl_t *t = me(rt);
    uint32_t now = hrt_now(rt);
    t->sector = sector_of_halls[hrt_inputs(rt) & HRT_IN_HALLS];
    if (t->edges != 0u) {
        t->edge_interval = now - t->last_edge;
    }
    t->last_edge = now;
    t->edges = (uint16_t)(t->edges + 1u);
    t->quiet_ms = 0u;
}

/* 1 kHz: the speed from the hall period (6 edges an electrical turn), zero after 100 ms without one. */
static void body_timer(hrt_t *rt)
{
    tpl_t *t = me(rt);
    if (t->quiet_ms < 100u) {
        t->quiet_ms = (uint16_t)(t->quiet_ms + 1u);
    }
    if (t->quiet_ms >= 100u || t->edge_interval == 0u) {
        t->speed_rpm = 0u;
    } else {
        /* rpm = 60 s / (6 edges x pole pairs x interval) */
        uint32_t rpm = (60UL * 1000000UL * TPL_TICKS_PER_US / (6UL * TPL_POLE_PAIRS)) / t->edge_interval;
        t->speed_rpm = (uint16_t)(rpm > 65535UL ? 65535UL : rpm);
    }
}

/* The main loop's body (once per span in lockstep): the S2 button toggles running. */
static void body_main(hrt_t *rt)
{
    tpl_t *t = me(rt);
    uint8_t s2 = hrt_pin(rt, HRT_IN_S2);
    if (s2 && !t->s2_was) {
        t->running = (uint8_t)!t->running;
    }
    t->s2_was = s2;
}

/* ---- the declaration ---- */

static const hrt_timer_decl_t timers[1] = {
    {body_timer, TPL_TIMER_TICKS, 1u},
};

static const hrt_edge_decl_t edges[1] = {
    {body_hall, HRT_IN_HALLS, HRT_EDGE_BOTH},
};

static const hrt_param_decl_t params[N_PARAMS] = {
    HRT_PARAM("duty_pct", "%", 0, 100, HBP_PTYPE_INT, HBP_ACCESS_RW),
    HRT_PARAM("advance_deg", "deg", 0, 60, HBP_PTYPE_INT, HBP_ACCESS_RW),
    HRT_PARAM("limit_rpm", "rpm", 100, 20000, HBP_PTYPE_INT, HBP_ACCESS_RW),
};

static const hrt_telemetry_decl_t telemetry[3] = {
    HRT_TELEMETRY("speed", "rpm", 1, 1, HBP_TELEMETRY_MEASURED_SPEED, HBP_PTYPE_INT),
    HRT_TELEMETRY("sector", "", 1, 1, 0x80u, HBP_PTYPE_INT),
    HRT_TELEMETRY("edge_interval", "us", 1, 1, 0x81u, HBP_PTYPE_INT),
};

static const uint8_t adc_roles[1] = {HBP_ADC_POT};

static int32_t decl_param_get(hrt_t *rt, uint8_t id)
{
    tpl_t *t = me(rt);
    return (id == P_DUTY_PCT) ? t->duty_pct : (id == P_ADVANCE_DEG) ? t->advance_deg : t->limit_rpm;
}

static void decl_param_set(hrt_t *rt, uint8_t id, int32_t value)
{
    tpl_t *t = me(rt);
    if (id == P_DUTY_PCT) {
        t->duty_pct = (int16_t)value;
    } else if (id == P_ADVANCE_DEG) {
        t->advance_deg = (int16_t)value;
    } else {
        t->limit_rpm = (int16_t)value;
    }
}

/* Constraint 1: more than 50 % duty only with an advance of at most 30 degrees (an example of a
 * rule across parameters: checked on the values the write would leave, all or nothing). */
static uint8_t decl_param_check(hrt_t *rt, const hrt_param_request_t *req, uint8_t *param_id, uint8_t *detail)
{
    if (hrt_param_candidate(rt, req, P_DUTY_PCT) > 50 && hrt_param_candidate(rt, req, P_ADVANCE_DEG) > 30) {
        *param_id = P_DUTY_PCT;
        *detail = 1u;
        return HBP_RESULT_CONSTRAINT;
    }
    return HBP_RESULT_OK;
}

static void decl_report(hrt_t *rt, hrt_report_t *out)
{
    tpl_t *t = me(rt);
    uint32_t us = t->edge_interval / TPL_TICKS_PER_US;
    out->output_mode = t->running ? HBP_OUTPUT_PWM : HBP_OUTPUT_OFF;
    out->state = t->running ? HBP_STATE_RUNNING : HBP_STATE_STOPPED;
    out->sector = t->sector;
    out->direction_ccw = 0u;
    out->required_ccw = 0u;
    out->fault = HBP_FAULT_NONE;
    out->telemetry[0] = (int16_t)(t->speed_rpm > 32767u ? 32767u : t->speed_rpm);
    out->telemetry[1] = (int16_t)t->sector;
    out->telemetry[2] = (int16_t)(us > 32767UL ? 32767UL : us);
}

static void decl_start(hrt_t *rt)
{
    me(rt)->running = 1u;
}

static void decl_stop(hrt_t *rt, uint8_t why)
{
    (void)why; /* HRT_STOP_COMMAND or HRT_STOP_WATCHDOG: either way, outputs off */
    me(rt)->running = 0u;
    hrt_pwm_preset(rt, TPL_PWM_COUNTS / 2u, TPL_PWM_COUNTS / 2u, TPL_PWM_COUNTS / 2u);
}

const hrt_firmware_t hrt_firmware = {
    .name = "TEMPLATE",
    .version = 0x0100u,
    .ticks_per_us = TPL_TICKS_PER_US,
    .period_step_us = 50u, /* the bench's period: whole PWM periods */
    .pwm_period_ticks = TPL_PWM_TICKS,
    .pwm_counts = TPL_PWM_COUNTS,
    .duty_timing = HRT_DUTY_NEXT_PERIOD,
    .duty_report = HRT_REPORT_WRITTEN,
    .pwm_priority = 2u,
    .pwm_isr = body_pwm,
    .inputs = (uint8_t)(HRT_IN_HALLS | HRT_IN_S2),
    .encoder_counts = 0u,
    .adc_bits = 10u,
    .n_adc = 1u,
    .adc_roles = adc_roles,
    .timers = timers,
    .n_timers = 1u,
    .edges = edges,
    .n_edges = 1u,
    .edge_priority = 1u, /* a hall edge on the same tick as the PWM boundary runs first */
    .main_body = body_main,
    .main_period_ticks = 0u,
    .params = params,
    .n_params = N_PARAMS,
    .param_get = decl_param_get,
    .param_set = decl_param_set,
    .param_check = decl_param_check,
    .telemetry = telemetry,
    .n_telemetry = 3u,
    .report = decl_report,
    .start = decl_start,
    .stop = decl_stop,
};

/* Power-on: the state, the runtime, the timer (the shared ports call this). */
hrt_t *hrt_firmware_init(void)
{
    hrt_init(&fw.rt);
    fw.running = 0u;
    fw.s2_was = 0u;
    fw.sector = 7u;
    fw.duty_pct = 20;
    fw.advance_deg = 0;
    fw.limit_rpm = 3000;
    fw.edges = 0u;
    fw.edge_interval = 0u;
    fw.quiet_ms = 100u;
    fw.speed_rpm = 0u;
    hrt_timer_start(&fw.rt, 0u, TPL_TIMER_TICKS);
    return &fw.rt;
}
