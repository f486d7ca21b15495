/* foc_hrt.c: the F2812 FOC firmware (foc.c) declared to the hilbench runtime (firmware/runtime/hrt.h).
 *
 * What the runtime is told (docs/foc.md "The ISR, and when its outputs act"):
 * - the clock: HSPCLK, 150 MHz; the agreed period a multiple of 50 us (half a PWM period);
 * - the PWM: 10 kHz (15 000 ticks), 7 500 compare counts = 100 % (T1PR); the PWM-period ISR is
 *   the timer-1 underflow ISR. The compare values it writes (the CMPR shadows; a duty register
 *   holds the high-side on-time T1PR - CMPRx, 0 for a CMPR above T1PR) are loaded half a period
 *   later, at the period match (COMCONA = 0xA200; its reload at the underflow finds nothing new):
 *   HRT_DUTY_HALF_PERIOD. The Drive reports the duties ACTIVE over its span, their mean when a
 *   reload falls inside it (HRT_REPORT_ACTIVE, HRT_REPORT_MEAN in hrt_config.h), as the in-process
 *   core does (foc_run_halves);
 * - the inputs: S2, the encoder's 16-bit x4 count (timer 2 follows it in the main body, once at a
 *   span's start, as the QEP circuit counts between two looks) and its index (CAP3, an edge body
 *   that runs before the PWM boundary of the same instant); i_a, i_b, Udc on 12-bit ADC channels;
 * - parameters and telemetry: the tables below, the same as hilbench/targets/foc's PARAMS and
 *   TELEMETRY_SPEC.
 * The firmware's own state is foc.h's foc_t; this file only binds it to the runtime.
 */
#include "foc_hrt.h"

#define FW(rt) ((foc_app_t *)(void *)(rt))

#define FOC_FIRMWARE_NAME "F2812FOC"
#define FOC_FIRMWARE_VERSION 0x0100u
#define FOC_TICKS_PER_US 150u           /* HSPCLK = SYSCLKOUT = 150 MHz */
#define FOC_PWM_PERIOD_TICKS 15000UL    /* 2 * T1PR: continuous up/down at 10 kHz */

/* ---------------------------------------------------------------------------- bodies */

static uint16_t on_time(int32_t cmpr)
{
    return cmpr < FOC_T1PR ? (uint16_t)(FOC_T1PR - cmpr) : 0u;
}

/* T1 underflow: the ADC results sampled at it, the ISR, the compare values it wrote (the runtime
 * loads them at the period match). */
static void body_t1_underflow(hrt_t *rt)
{
    foc_t *s = &FW(rt)->foc;
    s->adc_result[0] = hrt_adc(rt, 0u);
    s->adc_result[1] = hrt_adc(rt, 1u);
    s->adc_result[2] = hrt_adc(rt, 2u);
    foc_isr_t1_underflow(s);
    if (s->outputs_on) {
        hrt_pwm_write(rt, on_time(s->compare_shadow[0]), on_time(s->compare_shadow[1]),
                      on_time(s->compare_shadow[2]));
    }
}

/* CAP3 (QEPI1): the index ISR. */
static void body_index(hrt_t *rt)
{
    foc_isr_cap3(&FW(rt)->foc);
}

/* Once at a span's start: the main loop's S2, and timer 2 catching up with the encoder. */
static void body_main(hrt_t *rt)
{
    foc_t *s = &FW(rt)->foc;
    uint16_t was_on = s->outputs_on;
    foc_buttons(s, hrt_inputs(rt));
    foc_encoder(s, hrt_encoder(rt), 0u);
    if (was_on != s->outputs_on) {
        hrt_pwm_preset(rt, 0u, 0u, 0u); /* started (compares at T1PR) or stopped: no on-time, at once */
    }
}

/* ---------------------------------------------------------------------------- commands */

/* Start: from stopped or faulted, the outputs come on with no on-time (compares at T1PR), at once.
 * While running it changes nothing (foc_start), so the duties in effect stay as they are. */
static void decl_start(hrt_t *rt)
{
    foc_t *s = &FW(rt)->foc;
    uint16_t was_on = s->outputs_on;
    foc_start(s);
    if (was_on != s->outputs_on) {
        hrt_pwm_preset(rt, 0u, 0u, 0u);
    }
}

static void decl_stop(hrt_t *rt, hbp_u8 why)
{
    if (why == HRT_STOP_WATCHDOG) {
        foc_stop(&FW(rt)->foc, FOC_STATE_FAULT, FOC_FAULT_WATCHDOG);
    } else {
        foc_stop(&FW(rt)->foc, FOC_STATE_STOPPED, FOC_FAULT_NONE);
    }
    hrt_pwm_preset(rt, 0u, 0u, 0u);
}

/* ---------------------------------------------------------------------------- parameters */

static foc_pi_t *loop_of(foc_t *s, hbp_u8 id)
{
    if (id <= FOC_PARAM_SPD_OUT_MAX) {
        return &s->pid_spd;
    }
    return id <= FOC_PARAM_ID_OUT_MAX ? &s->pid_id : &s->pid_iq;
}

static int32_t decl_param_get(hrt_t *rt, hbp_u8 id)
{
    foc_app_t *app = FW(rt);
    foc_t *s = &app->foc;
    foc_pi_t *p;
    switch (id) {
    case FOC_PARAM_REF_RPM:
        return app->ref_rpm;
    case FOC_PARAM_ID_REF:
        return s->id_ref;
    case FOC_PARAM_TORQUE_MODE:
        return (int32_t)s->torque_mode;
    case FOC_PARAM_IQ_REF_SET:
        return s->iq_ref_set;
    default:
        break;
    }
    p = loop_of(s, id);
    switch ((hbp_u8)((id - FOC_PARAM_SPD_KP) % 4u)) {
    case 0u:
        return p->kp;
    case 1u:
        return p->ki;
    case 2u:
        return p->kc;
    default:
        return p->out_max;
    }
}

static void decl_param_set(hrt_t *rt, hbp_u8 id, int32_t value)
{
    foc_app_t *app = FW(rt);
    foc_t *s = &app->foc;
    foc_pi_t *p;
    switch (id) {
    case FOC_PARAM_REF_RPM:
        app->ref_rpm = value;
        foc_set_speed_ref_rpm(s, value);
        return;
    case FOC_PARAM_ID_REF:
        s->id_ref = value;
        return;
    case FOC_PARAM_TORQUE_MODE:
        s->torque_mode = (uint16_t)(value != 0);
        return;
    case FOC_PARAM_IQ_REF_SET:
        s->iq_ref_set = value;
        return;
    default:
        break;
    }
    p = loop_of(s, id);
    switch ((hbp_u8)((id - FOC_PARAM_SPD_KP) % 4u)) {
    case 0u:
        p->kp = value;
        break;
    case 1u:
        p->ki = value;
        break;
    case 2u:
        p->kc = value;
        break;
    default:
        p->out_max = value;
        p->out_min = iq24_neg(value); /* the limits are symmetric */
        break;
    }
}

#define ONE_IQ24 16777216L
/* ids 0..15, the table of hilbench/targets/foc/target.py's PARAMS */
static const hrt_param_decl_t params[FOC_N_PARAMS] = {
    HRT_PARAM("ref_rpm", "rpm", -3000L, 3000L, HBP_PTYPE_INT, HBP_ACCESS_RW),
    HRT_PARAM("id_ref", "pu", -ONE_IQ24 / 2L, ONE_IQ24 / 2L, HBP_PTYPE_IQ24, HBP_ACCESS_RW),
    HRT_PARAM("spd_kp", "", 0L, 8L * ONE_IQ24, HBP_PTYPE_IQ24, HBP_ACCESS_RW),
    HRT_PARAM("spd_ki", "", 0L, ONE_IQ24, HBP_PTYPE_IQ24, HBP_ACCESS_RW),
    HRT_PARAM("spd_kc", "", 0L, ONE_IQ24, HBP_PTYPE_IQ24, HBP_ACCESS_RW),
    HRT_PARAM("spd_out_max", "pu", 0L, ONE_IQ24, HBP_PTYPE_IQ24, HBP_ACCESS_RW),
    HRT_PARAM("id_kp", "", 0L, 8L * ONE_IQ24, HBP_PTYPE_IQ24, HBP_ACCESS_RW),
    HRT_PARAM("id_ki", "", 0L, ONE_IQ24, HBP_PTYPE_IQ24, HBP_ACCESS_RW),
    HRT_PARAM("id_kc", "", 0L, ONE_IQ24, HBP_PTYPE_IQ24, HBP_ACCESS_RW),
    HRT_PARAM("id_out_max", "pu", 0L, ONE_IQ24, HBP_PTYPE_IQ24, HBP_ACCESS_RW),
    HRT_PARAM("iq_kp", "", 0L, 8L * ONE_IQ24, HBP_PTYPE_IQ24, HBP_ACCESS_RW),
    HRT_PARAM("iq_ki", "", 0L, ONE_IQ24, HBP_PTYPE_IQ24, HBP_ACCESS_RW),
    HRT_PARAM("iq_kc", "", 0L, ONE_IQ24, HBP_PTYPE_IQ24, HBP_ACCESS_RW),
    HRT_PARAM("iq_out_max", "pu", 0L, ONE_IQ24, HBP_PTYPE_IQ24, HBP_ACCESS_RW),
    HRT_PARAM("torque_mode", "", 0L, 1L, HBP_PTYPE_BOOL, HBP_ACCESS_RW),
    HRT_PARAM("iq_ref_set", "pu", -ONE_IQ24, ONE_IQ24, HBP_PTYPE_IQ24, HBP_ACCESS_RW),
};

/* ---------------------------------------------------------------------------- telemetry */

static void decl_report(hrt_t *rt, hrt_report_t *out)
{
    foc_out_t o;
    hbp_u8 k;
    foc_outputs(&FW(rt)->foc, &o);
    out->output_mode = (hbp_u8)o.output_mode;
    out->state = (hbp_u8)o.state;
    out->sector = (hbp_u8)o.sector;
    out->direction_ccw = (hbp_u8)o.ccw;
    out->required_ccw = (hbp_u8)o.req_ccw;
    out->fault = (hbp_u8)o.fault;
    for (k = 0u; k < FOC_N_TELEMETRY; k++) {
        out->telemetry[k] = o.telemetry[k];
    }
}

/* Q15 per unit of the servo build's bases: speed of BaseRpm 3000, current of 5 A, voltage of Udc/sqrt3 */
static const hrt_telemetry_decl_t telemetry[FOC_N_TELEMETRY] = {
    HRT_TELEMETRY("ref_speed_rpm", "rpm", 3000L, 32768L, HBP_TELEMETRY_REF_SPEED, HBP_PTYPE_Q15),
    HRT_TELEMETRY("measured_speed_rpm", "rpm", 3000L, 32768L, HBP_TELEMETRY_MEASURED_SPEED, HBP_PTYPE_Q15),
    HRT_TELEMETRY("iq_ref_a", "A", 5L, 32768L, HBP_TELEMETRY_IQ_REF, HBP_PTYPE_Q15),
    HRT_TELEMETRY("i_d_a", "A", 5L, 32768L, HBP_TELEMETRY_ID, HBP_PTYPE_Q15),
    HRT_TELEMETRY("i_q_a", "A", 5L, 32768L, HBP_TELEMETRY_IQ, HBP_PTYPE_Q15),
    HRT_TELEMETRY("fw_theta_e_deg", "deg", 45L, 4096L, HBP_TELEMETRY_THETA_E, HBP_PTYPE_Q15),
    HRT_TELEMETRY("v_d_pu", "pu", 1L, 32768L, HBP_TELEMETRY_VD, HBP_PTYPE_Q15),
    HRT_TELEMETRY("v_q_pu", "pu", 1L, 32768L, HBP_TELEMETRY_VQ, HBP_PTYPE_Q15),
};

static const hbp_u8 adc_roles[3] = {HBP_ADC_IA, HBP_ADC_IB, HBP_ADC_VBUS};

static const hrt_edge_decl_t edges[1] = {
    {body_index, HRT_IN_INDEX, HRT_EDGE_RISING},
};

const hrt_firmware_t hrt_firmware = {
    .name = FOC_FIRMWARE_NAME,
    .version = FOC_FIRMWARE_VERSION,
    .ticks_per_us = FOC_TICKS_PER_US,
    .period_step_us = FOC_HALF_PERIOD_US,
    .pwm_period_ticks = FOC_PWM_PERIOD_TICKS,
    .pwm_counts = FOC_T1PR,
    .duty_timing = HRT_DUTY_HALF_PERIOD, /* COMCONA = 0xA200: the ISR's values load at the period match */
    .duty_report = HRT_REPORT_ACTIVE,
    .pwm_priority = 2u,
    .pwm_isr = body_t1_underflow,
    .inputs = (hbp_u8)(HRT_IN_S2 | HRT_IN_INDEX),
    .encoder_counts = 10000u,
    .adc_bits = 12u,
    .n_adc = 3u,
    .adc_roles = adc_roles,
    .timers = 0,
    .n_timers = 0u,
    .edges = edges,
    .n_edges = 1u,
    .edge_priority = 1u, /* the index before the underflow of the same instant */
    .main_body = body_main,
    .main_period_ticks = 0u,
    .params = params,
    .n_params = FOC_N_PARAMS,
    .param_get = decl_param_get,
    .param_set = decl_param_set,
    .param_check = 0,
    .telemetry = telemetry,
    .n_telemetry = FOC_N_TELEMETRY,
    .report = decl_report,
    .start = decl_start,
    .stop = decl_stop,
};

void foc_app_init(foc_app_t *app, const foc_config_t *config)
{
    hrt_init(&app->rt);
    foc_init(&app->foc, config);
    app->ref_rpm = 0;
    hrt_pwm_preset(&app->rt, 0u, 0u, 0u); /* outputs off: no on-time */
}

#if !defined(FOC_NO_FIRMWARE_INIT)
static foc_app_t the_app;

/* Power-on for the runtime's shared ports (firmware/runtime/ports/): the build's settings
 * (foc_config.h, -DFOC_CFG_*). */
hrt_t *hrt_firmware_init(void)
{
    foc_config_t config;
    foc_config_default(&config);
    foc_app_init(&the_app, &config);
    return &the_app.rt;
}
#endif
