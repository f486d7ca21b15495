/* foc.c: the F2812 FOC firmware (see foc.h; docs/foc.md "The ISR, and when its outputs act"). */
#include "foc.h"

#include "foc_config.h"

#define ALIGN_ANGLE_Q15 24576u          /* -0.25 pu: Vq along -90 deg puts the vector on phase A */
#define HALVES_MAX 572662UL             /* T1PR * n stays below 2^32 */

void foc_config_default(foc_config_t *c)
{
    c->pi_form = (uint16_t)FOC_CFG_PI_FORM;
    c->speed_fr_unwrap = (uint16_t)FOC_CFG_SPEED_FR_UNWRAP;
    c->learn_index = (uint16_t)FOC_CFG_LEARN_INDEX;
    c->qep_signed16 = (uint16_t)FOC_CFG_QEP_SIGNED16;
    c->line_encoder = FOC_CFG_LINE_ENCODER;
    c->pole_pairs = FOC_CFG_POLE_PAIRS;
    c->t2pr = FOC_CFG_T2PR;
    c->calibrated_angle = FOC_CFG_CALIBRATED_ANGLE;
    c->mech_scaler = FOC_CFG_MECH_SCALER;
    c->sp_k1 = FOC_CFG_SP_K1;
    c->sp_k2 = FOC_CFG_SP_K2;
    c->sp_k3 = FOC_CFG_SP_K3;
    c->base_rpm = FOC_CFG_BASE_RPM;
    c->speed_loop_prescaler = FOC_CFG_SPEED_LOOP_PRESCALER;
    c->align_isrs = FOC_CFG_ALIGN_ISRS;
    c->align_v = FOC_CFG_ALIGN_V;
    c->align_i = FOC_CFG_ALIGN_I;
    c->ramp_step = FOC_CFG_RAMP_STEP;
    c->cur_kp = FOC_CFG_CUR_KP;
    c->cur_ki = FOC_CFG_CUR_KI;
    c->cur_kc = FOC_CFG_CUR_KC;
    c->id_out_max = FOC_CFG_ID_OUT_MAX;
    c->iq_out_max = FOC_CFG_IQ_OUT_MAX;
    c->spd_kp = FOC_CFG_SPD_KP;
    c->spd_ki = FOC_CFG_SPD_KI;
    c->spd_kc = FOC_CFG_SPD_KC;
    c->spd_out_max = FOC_CFG_SPD_OUT_MAX;
}

static void pi_init(foc_pi_t *p, int32_t kp, int32_t ki, int32_t kc, int32_t out_max)
{
    p->kp = kp;
    p->ki = ki;
    p->kc = kc;
    p->kd = 0;
    p->out_max = out_max;
    p->out_min = iq24_neg(out_max);
    foc_pi_reset(p);
}

void foc_init(foc_t *s, const foc_config_t *c)
{
    uint16_t k;
    s->pi_form = c->pi_form;
    s->learn_index = c->learn_index;
    s->speed_loop_prescaler = c->speed_loop_prescaler;
    s->align_isrs = c->align_isrs;
    s->align_v = c->align_v;
    s->align_i = c->align_i;
    s->ramp_step = c->ramp_step;
    pi_init(&s->pid_id, c->cur_kp, c->cur_ki, c->cur_kc, c->id_out_max);
    pi_init(&s->pid_iq, c->cur_kp, c->cur_ki, c->cur_kc, c->iq_out_max);
    pi_init(&s->pid_spd, c->spd_kp, c->spd_ki, c->spd_kc, c->spd_out_max);
    s->qep.line_encoder = c->line_encoder;
    s->qep.pole_pairs = c->pole_pairs;
    s->qep.calibrated_angle = c->calibrated_angle;
    s->qep.mech_scaler = c->mech_scaler;
    s->qep.t2pr = c->t2pr;
    s->qep.t2cnt = 0;
    s->qep.direction = 1u;
    s->qep.signed16 = c->qep_signed16;
    s->qep.raw_theta = s->qep.mech_theta = s->qep.elec_theta = 0u;
    s->qep.qep_count_index = s->qep.index_sync_flag = 0u;
    s->speed.k1 = c->sp_k1;
    s->speed.k2 = c->sp_k2;
    s->speed.k3 = c->sp_k3;
    s->speed.base_rpm = c->base_rpm;
    s->speed.unwrap = c->speed_fr_unwrap;
    s->speed.elec_theta = s->speed.old_elec_theta = s->speed.speed = s->speed.speed_rpm = 0;
    s->speed_ref = s->speed_setpoint = s->id_ref = s->iq_ref = s->iq_ref_set = 0;
    s->torque_mode = 0u;
    s->state = FOC_STATE_STOPPED;
    s->fault = FOC_FAULT_NONE;
    s->isr_count = 0UL;
    s->state_isrs = s->speed_loop_count = 0;
    s->index_learned = 0u;
    s->elec_theta = 0;
    s->i_a = s->i_b = s->i_alpha = s->i_beta = s->i_d = s->i_q = 0;
    s->v_d = s->v_q = s->v_alpha = s->v_beta = 0;
    s->vdc_code = 0u;
    s->sector = 0u;
    s->s2_last = 0u;
    for (k = 0u; k < 3u; k++) {
        s->adc_result[k] = 0u;
        s->compare_shadow[k] = s->compare_active[k] = FOC_T1PR;
    }
    s->outputs_on = 0u;
    s->half = 0u;
    s->enc_last = s->have_enc = 0u;
}

/* ------------------------------------------------------------------------------ commands */

static void enter(foc_t *s, uint16_t state)
{
    s->state = state;
    s->state_isrs = 0;
    foc_pi_reset(&s->pid_id);
    foc_pi_reset(&s->pid_iq);
    foc_pi_reset(&s->pid_spd);
    s->iq_ref = 0;
    s->speed_loop_count = 0;
    s->speed_setpoint = 0;
}

void foc_start(foc_t *s)
{
    if (s->state == FOC_STATE_STOPPED || s->state == FOC_STATE_FAULT) {
        s->fault = FOC_FAULT_NONE;
        enter(s, FOC_STATE_ALIGN);
        s->outputs_on = 1u;
    }
}

void foc_stop(foc_t *s, uint16_t state, uint16_t fault)
{
    uint16_t k;
    s->state = state;
    s->fault = fault;
    s->outputs_on = 0u;
    for (k = 0u; k < 3u; k++) {
        s->compare_shadow[k] = s->compare_active[k] = FOC_T1PR;
    }
    s->v_d = s->v_q = 0;
    s->sector = 0u;
}

void foc_buttons(foc_t *s, uint16_t inputs)
{
    uint16_t s2 = (inputs & FOC_INPUT_S2) ? 1u : 0u;
    if (s2 && !s->s2_last) {
        if (s->state == FOC_STATE_ALIGN || s->state == FOC_STATE_RUN) {
            foc_stop(s, FOC_STATE_STOPPED, FOC_FAULT_NONE);
        } else {
            foc_start(s);
        }
    }
    s->s2_last = s2;
}

void foc_set_speed_ref_rpm(foc_t *s, int32_t rpm)
{
    /* trunc(|rpm| * 2^24 / BaseRpm) by long division: exact, no 64-bit product, no float */
    uint32_t base = (uint32_t)s->speed.base_rpm;
    uint32_t rem = rpm < 0 ? 0UL - (uint32_t)rpm : (uint32_t)rpm;
    uint32_t q = 0UL;
    uint16_t bit;
    if (rem >= base) {
        s->speed_ref = rpm < 0 ? -IQ24_ONE : IQ24_ONE;
        return;
    }
    for (bit = 0u; bit < IQ24_Q; bit++) {
        rem <<= 1;
        q <<= 1;
        if (rem >= base) {
            rem -= base;
            q |= 1UL;
        }
    }
    s->speed_ref = rpm < 0 ? -(int32_t)q : (int32_t)q;
}

/* ------------------------------------------------------------------------------ ISR bodies */

/* ADCRESULT holds code << 4; XOR 0x8000 makes it a signed Q15 (mid-scale 2048 = 0), then Q24. */
static int32_t adc_to_iq(uint16_t code12)
{
    uint16_t q15 = (uint16_t)(((uint16_t)(code12 << 4) ^ 0x8000u) & 0xFFFFu);
    int32_t v = (q15 & 0x8000u) ? (int32_t)q15 - 65536L : (int32_t)q15;
    return iq24_shl(v, 9u);
}

static int32_t pi_calc(const foc_t *s, foc_pi_t *p, int32_t ref, int32_t fdb)
{
    return s->pi_form == FOC_PI_REG3 ? foc_pid_reg3(p, ref, fdb) : foc_pi_clamp(p, ref, fdb);
}

/* The speed PI every prescaler ISRs, its setpoint slewed toward the reference (RMPCNTL's job). */
static void speed_loop(foc_t *s)
{
    s->speed_loop_count += 1;
    if (s->torque_mode) {
        s->iq_ref = s->iq_ref_set;
        s->speed_loop_count = 0;
    } else if (s->speed_loop_count >= s->speed_loop_prescaler) {
        int32_t ref = s->speed_ref, step = s->ramp_step, sp = s->speed_setpoint;
        s->speed_loop_count = 0;
        if (step != 0) {
            if (ref - sp > step) {
                ref = sp + step;
            } else if (sp - ref > step) {
                ref = sp - step;
            }
        }
        s->speed_setpoint = ref;
        s->iq_ref = pi_calc(s, &s->pid_spd, ref, s->speed.speed);
    }
}

void foc_isr_t1_underflow(foc_t *s)
{
    int32_t sine, cosine, v_d, v_q;
    uint16_t angle_q15;
    s->isr_count += 1UL;
    s->vdc_code = s->adc_result[2];
    s->i_a = adc_to_iq(s->adc_result[0]);
    s->i_b = adc_to_iq(s->adc_result[1]);
    foc_clarke(s->i_a, s->i_b, &s->i_alpha, &s->i_beta);
    angle_q15 = s->state == FOC_STATE_ALIGN ? ALIGN_ANGLE_Q15 : (uint16_t)(iq24_asr(s->elec_theta, 9u) & 0x7FFF);
    sine = foc_sin_q15(angle_q15);
    cosine = foc_cos_q15(angle_q15);
    foc_park(s->i_alpha, s->i_beta, sine, cosine, &s->i_d, &s->i_q);
    if (s->state == FOC_STATE_RUN) {
        speed_loop(s);
        v_q = pi_calc(s, &s->pid_iq, s->iq_ref, s->i_q);
        v_d = pi_calc(s, &s->pid_id, s->id_ref, s->i_d);
    } else if (s->state == FOC_STATE_ALIGN) {
        if (s->align_i != 0) { /* the current loops size the vector: i_q to align_i in PMSM3_1's frame */
            v_q = pi_calc(s, &s->pid_iq, s->align_i, s->i_q);
            v_d = pi_calc(s, &s->pid_id, 0, s->i_d);
        } else {
            v_d = 0;
            v_q = s->align_v;
        }
        s->state_isrs += 1;
        if (s->state_isrs >= s->align_isrs) {
            s->qep.t2cnt = 0; /* the rotor's d axis is at theta_e = 0 now */
            enter(s, FOC_STATE_RUN);
        }
    } else {
        v_d = v_q = 0;
    }
    s->v_d = v_d;
    s->v_q = v_q;
    if (s->outputs_on) {
        foc_ipark(v_d, v_q, sine, cosine, &s->v_alpha, &s->v_beta);
        s->sector = foc_svpwm(s->v_alpha, s->v_beta, s->compare_shadow);
    }
    /* QEP and speed: every ISR, outputs on or off */
    s->elec_theta = iq24_shl((int32_t)foc_qep_calc(&s->qep), 9u);
    s->speed.elec_theta = s->elec_theta;
    foc_speed_fr_calc(&s->speed);
}

void foc_isr_cap3(foc_t *s)
{
    foc_qep_t *q = &s->qep;
    if (s->learn_index && !s->index_learned) {
        /* keep RawTheta continuous: Cal = T2CNT + Cal, kept in 0..4*lines-1 (never negative) */
        q->calibrated_angle = foc_mod(q->t2cnt + q->calibrated_angle, 4L * q->line_encoder);
        s->index_learned = 1u;
    }
    foc_qep_index(q);
}

/* ------------------------------------------------------------------------------ virtual peripherals */

static void reload(foc_t *s)
{
    s->compare_active[0] = s->compare_shadow[0];
    s->compare_active[1] = s->compare_shadow[1];
    s->compare_active[2] = s->compare_shadow[2];
}

void foc_em_underflow(foc_t *s)
{
    reload(s);
    foc_isr_t1_underflow(s);
}

void foc_em_period_match(foc_t *s)
{
    reload(s);
}

void foc_encoder(foc_t *s, uint16_t count16, uint16_t index)
{
    if (s->have_enc) {
        uint16_t d = (uint16_t)(count16 - s->enc_last);
        int32_t delta = (d & 0x8000u) ? (int32_t)d - 65536L : (int32_t)d;
        foc_qep_count(&s->qep, delta);
    }
    s->enc_last = count16;
    s->have_enc = 1u;
    if (index) {
        foc_isr_cap3(s);
    }
}

static uint16_t on_time(int32_t cmpr)
{
    return cmpr < FOC_T1PR ? (uint16_t)(FOC_T1PR - cmpr) : 0u;
}

void foc_active_duties(const foc_t *s, uint16_t duty[3])
{
    uint16_t k;
    for (k = 0u; k < 3u; k++) {
        duty[k] = s->outputs_on ? on_time(s->compare_active[k]) : 0u;
    }
}

void foc_run_halves(foc_t *s, uint32_t n, uint16_t duty[3])
{
    uint32_t sum[3] = {0UL, 0UL, 0UL};
    uint32_t i;
    uint16_t k;
    if (n > HALVES_MAX) {
        n = HALVES_MAX;
    }
    for (i = 0UL; i < n; i++) {
        if (s->half == 0u) {
            foc_em_underflow(s);
            s->half = 1u;
        } else {
            foc_em_period_match(s);
            s->half = 0u;
        }
        if (s->outputs_on) {
            for (k = 0u; k < 3u; k++) {
                sum[k] += on_time(s->compare_active[k]);
            }
        }
    }
    for (k = 0u; k < 3u; k++) {
        uint32_t q = n > 1UL ? sum[k] / n : sum[k];
        uint32_t r = n > 1UL ? sum[k] - q * n : 0UL;
        if (2UL * r > n || (2UL * r == n && r != 0UL && (q & 1UL))) {
            q += 1UL; /* half to even, as Python's round() of the mean */
        }
        duty[k] = (uint16_t)q;
    }
}

/* ------------------------------------------------------------------------------ outputs */

int16_t foc_q15_word(int32_t x)
{
    int32_t q = iq24_asr(x, 9u);
    return (int16_t)(q > 32767L ? 32767L : (q < -32768L ? -32768L : q));
}

void foc_outputs(const foc_t *s, foc_out_t *o)
{
    o->output_mode = s->outputs_on ? FOC_OUTPUT_PWM : FOC_OUTPUT_OFF;
    o->state = s->state;
    o->sector = (uint16_t)(s->sector & 7u);
    o->ccw = (uint16_t)(s->speed.speed < 0 ? 1 : 0);
    o->req_ccw = (uint16_t)(s->speed_ref < 0 ? 1 : 0);
    o->fault = s->fault;
    o->telemetry[0] = foc_q15_word(s->ramp_step != 0 ? s->speed_setpoint : s->speed_ref);
    o->telemetry[1] = foc_q15_word(s->speed.speed);
    o->telemetry[2] = foc_q15_word(s->iq_ref);
    o->telemetry[3] = foc_q15_word(s->i_d);
    o->telemetry[4] = foc_q15_word(s->i_q);
    o->telemetry[5] = foc_q15_word(s->elec_theta);
    o->telemetry[6] = foc_q15_word(s->v_d);
    o->telemetry[7] = foc_q15_word(s->v_q);
}
