/* firmware/tiny/tiny.c: the tiny open-loop V/f drive of tests/plugin_tiny, in C on the hilbench
 * runtime.
 *
 * A voltage vector turns at the (rate-limited) reference speed with an amplitude proportional to it,
 * 90 degrees ahead of where the rotor would be: a rotating field the motor follows without any
 * sensor. The reference is the parameter `speed_ref` (rpm), so a bench that knows nothing of this
 * firmware finds it by the porting guide's convention (docs/porting.md: a read-write INT in rpm
 * named `speed_ref`) and drives it from `ref_rpm` events and `step`; S2 or Start/Stop run and stop it.
 * The PWM-period ISR does all the work, every 50 us: the ramp, the angle (a 32-bit phase accumulator,
 * one electrical turn = 2^32), the duties from a quarter-wave sine table.
 *
 * The Python model (tests/plugin_tiny) computes in floating point once per exchange; this one in
 * integers every PWM period, so the two agree in behaviour (the speed the motor reaches, the
 * ramp), not bit for bit. C99, no heap, no floating point, correct with a 16-bit int.
 */
#include "hrt.h"

#define TINY_TICKS_PER_US 20u
#define TINY_PWM_TICKS 1000u   /* 20 kHz */
#define TINY_PWM_HZ ((int32_t)20000)
#define TINY_COUNTS 1000u
#ifndef TINY_POLE_PAIRS
#define TINY_POLE_PAIRS 5      /* the motor it drives (tests/plugin_tiny's default) */
#endif
#ifndef TINY_BOOST_PERMILLE
#define TINY_BOOST_PERMILLE 40 /* modulation at zero speed: 4 % */
#endif

/* one mrpm as electrical angle per PWM period, 2^32 a turn, in Q16 */
#define TINY_DTHETA_Q16 ((int64_t)TINY_POLE_PAIRS * 281474976710656LL / (60000LL * TINY_PWM_HZ))

#define P_SPEED_REF 0u
#define P_V_PER_KRPM 1u
#define P_ACCEL 2u

#define TELEMETRY_ANGLE 0x80u
#define TELEMETRY_MODULATION 0x81u

typedef struct {
    hrt_t rt;
    uint8_t running;
    uint8_t s2_was;
    int32_t value[3];   /* the parameters */
    int32_t speed_mrpm; /* the ramped speed, 1/1000 rpm */
    uint32_t theta;     /* electrical angle, 2^32 a turn */
    int32_t m;          /* modulation, per mille */
} tiny_t;

static tiny_t fw;

static tiny_t *me(hrt_t *rt)
{
    return (tiny_t *)(void *)rt;
}

/* sin(2 pi i / 256) in Q15, i = 0..64 (a quarter wave) */
static const int16_t quarter_sine[65] = {
    0, 804, 1608, 2410, 3212, 4011, 4808, 5602, 6393, 7179, 7962, 8739, 9512,
    10278, 11039, 11793, 12539, 13279, 14010, 14732, 15446, 16151, 16846, 17530, 18204, 18868,
    19519, 20159, 20787, 21403, 22005, 22594, 23170, 23731, 24279, 24811, 25329, 25832, 26319,
    26790, 27245, 27683, 28105, 28510, 28898, 29268, 29621, 29956, 30273, 30571, 30852, 31113,
    31356, 31580, 31785, 31971, 32137, 32285, 32412, 32521, 32609, 32678, 32728, 32757, 32767};

/* cos of an angle (2^32 a turn) in Q15, to 1/256 of a turn */
static int32_t cos_q15(uint32_t angle)
{
    uint8_t i = (uint8_t)((angle >> 24) + 64u); /* cos x = sin(x + 90 degrees) */
    uint8_t q = (uint8_t)(i & 63u);
    switch (i >> 6) {
    case 0u:
        return quarter_sine[q];
    case 1u:
        return quarter_sine[64u - q];
    case 2u:
        return -(int32_t)quarter_sine[q];
    default:
        return -(int32_t)quarter_sine[64u - q];
    }
}

static int32_t abs32(int32_t v)
{
    return v < 0 ? -v : v;
}

/* Every PWM period: the ramp, the angle, the duties. */
static void body_pwm(hrt_t *rt)
{
    tiny_t *t = me(rt);
    int32_t ref = t->running ? t->value[P_SPEED_REF] * (int32_t)1000 : (int32_t)0;
    int32_t step = t->value[P_ACCEL] * (int32_t)1000 / TINY_PWM_HZ; /* mrpm per PWM period */
    int32_t diff = ref - t->speed_mrpm;
    uint32_t lead;
    int32_t half = (int32_t)(TINY_COUNTS / 2u);
    uint8_t k;
    uint16_t d[3];
    if (step < 1) {
        step = 1;
    }
    t->speed_mrpm += (diff > step) ? step : (diff < -step) ? -step : diff;
    /* d theta = speed / 60 x pole pairs x 2^32 / f_pwm; speed in mrpm: x 2^32 / (60 000 x 20 000), as
     * a Q16 factor (a multiplication each period, no 64-bit division: the AVR keeps up in real time) */
    t->theta += (uint32_t)((int64_t)t->speed_mrpm * TINY_DTHETA_Q16 / 65536);
    t->m = (int32_t)TINY_BOOST_PERMILLE + t->value[P_V_PER_KRPM] * (abs32(t->speed_mrpm) / (int32_t)1000) / (int32_t)100;
    if (t->m > (int32_t)1000) {
        t->m = 1000;
    }
    lead = (t->speed_mrpm >= 0) ? (uint32_t)0x40000000UL : (uint32_t)0xC0000000UL; /* +-90 degrees */
    for (k = 0u; k < 3u; k++) {
        /* phase k lags by k x 120 degrees: 2^32 / 3 = 0x55555555 */
        uint32_t angle = t->theta + lead - (uint32_t)k * (uint32_t)0x55555555UL;
        d[k] = t->running ? (uint16_t)(half + (half * t->m / (int32_t)1000) * cos_q15(angle) / (int32_t)32768) : (uint16_t)half;
    }
    hrt_pwm_write(rt, d[0], d[1], d[2]);
}

static void body_main(hrt_t *rt)
{
    tiny_t *t = me(rt);
    uint8_t s2 = hrt_pin(rt, HRT_IN_S2);
    if (s2 && !t->s2_was) {
        t->running = (uint8_t)!t->running;
    }
    t->s2_was = s2;
}

static const hrt_param_decl_t params[3] = {
    HRT_PARAM("speed_ref", "rpm", -6000, 6000, HBP_PTYPE_INT, HBP_ACCESS_RW),
    HRT_PARAM("v_per_krpm", "%", 0, 100, HBP_PTYPE_INT, HBP_ACCESS_RW),
    HRT_PARAM("accel_rpm_s", "rpm/s", 1, 20000, HBP_PTYPE_INT, HBP_ACCESS_RW),
};

static const hrt_telemetry_decl_t telemetry[3] = {
    HRT_TELEMETRY("ref_speed", "rpm", 1, 1, HBP_TELEMETRY_REF_SPEED, HBP_PTYPE_INT),
    HRT_TELEMETRY("tiny_angle", "deg", 1, 10, TELEMETRY_ANGLE, HBP_PTYPE_INT),
    HRT_TELEMETRY("tiny_modulation", "", 1, 1000, TELEMETRY_MODULATION, HBP_PTYPE_INT),
};

static int32_t decl_param_get(hrt_t *rt, uint8_t id)
{
    return me(rt)->value[id];
}

static void decl_param_set(hrt_t *rt, uint8_t id, int32_t value)
{
    me(rt)->value[id] = value;
}

static void decl_report(hrt_t *rt, hrt_report_t *out)
{
    tiny_t *t = me(rt);
    int32_t rpm = t->speed_mrpm / (int32_t)1000;
    out->output_mode = t->running ? HBP_OUTPUT_PWM : HBP_OUTPUT_OFF;
    out->state = t->running ? HBP_STATE_RUNNING : HBP_STATE_STOPPED;
    out->sector = 0u;
    out->direction_ccw = (uint8_t)(t->speed_mrpm < 0);
    out->required_ccw = (uint8_t)(t->value[P_SPEED_REF] < 0);
    out->fault = HBP_FAULT_NONE;
    out->telemetry[0] = (int16_t)rpm;
    out->telemetry[1] = (int16_t)((uint32_t)(t->theta >> 16) * (uint32_t)3600 / (uint32_t)65536); /* 0.1 degree */
    out->telemetry[2] = (int16_t)t->m;
}

static void decl_start(hrt_t *rt)
{
    me(rt)->running = 1u;
}

static void decl_stop(hrt_t *rt, uint8_t why)
{
    (void)why;
    me(rt)->running = 0u;
    hrt_pwm_preset(rt, TINY_COUNTS / 2u, TINY_COUNTS / 2u, TINY_COUNTS / 2u);
}

const hrt_firmware_t hrt_firmware = {
    .name = "TINYC",
    .version = 0x0100u,
    .ticks_per_us = TINY_TICKS_PER_US,
    .period_step_us = 50u,
    .pwm_period_ticks = TINY_PWM_TICKS,
    .pwm_counts = TINY_COUNTS,
    .duty_timing = HRT_DUTY_NEXT_PERIOD,
    .duty_report = HRT_REPORT_WRITTEN,
    .pwm_priority = 1u,
    .pwm_isr = body_pwm,
    .inputs = HRT_IN_S2,
    .adc_bits = 10u,
    .n_adc = 0u,
    .adc_roles = 0,
    .main_body = body_main,
    .params = params,
    .n_params = 3u,
    .param_get = decl_param_get,
    .param_set = decl_param_set,
    .telemetry = telemetry,
    .n_telemetry = 3u,
    .report = decl_report,
    .start = decl_start,
    .stop = decl_stop,
};

hrt_t *hrt_firmware_init(void)
{
    hrt_init(&fw.rt);
    fw.running = 0u;
    fw.s2_was = 0u;
    fw.value[P_SPEED_REF] = 0;
    fw.value[P_V_PER_KRPM] = 36;
    fw.value[P_ACCEL] = 4000;
    fw.speed_mrpm = 0;
    fw.theta = 0u;
    fw.m = TINY_BOOST_PERMILLE;
    return &fw.rt;
}
