/* foc_blocks.c: the DMC blocks and the seed's SVPWM (see foc_blocks.h; docs/foc.md "Blocks"). */
#include "foc_blocks.h"

#define IQ_ZERO_POINT_1 ((int32_t)1677721L)  /* _IQ(0.1) */
#define IQ_ZERO_POINT_9 ((int32_t)15099494L) /* _IQ(0.9) */
#define IQ21_ONE ((int32_t)2097152L)         /* _IQ21(1.0) */

/* sin of k/32768 turn for k = 0..8192 */
static int32_t quarter(uint16_t k)
{
    return k < 4096u ? FOC_ROM_I32(&foc_sin_quarter_lo[k]) : FOC_ROM_I32(&foc_sin_quarter_hi[k - 4096u]);
}

int32_t foc_sin_q15(uint16_t angle_q15)
{
    uint16_t k = (uint16_t)(angle_q15 & 0x7FFFu);
    if (k <= 8192u) {
        return quarter(k);
    }
    if (k <= 16384u) {
        return quarter((uint16_t)(16384u - k));
    }
    if (k <= 24576u) {
        return iq24_neg(quarter((uint16_t)(k - 16384u)));
    }
    return iq24_neg(quarter((uint16_t)(32768UL - k)));
}

int32_t foc_cos_q15(uint16_t angle_q15)
{
    return foc_sin_q15((uint16_t)((angle_q15 + 8192u) & 0x7FFFu));
}

void foc_clarke(int32_t as, int32_t bs, int32_t *alpha, int32_t *beta)
{
    *alpha = as;
    *beta = iq24_mpy(iq24_add(as, iq24_mpy(IQ24_TWO, bs)), FOC_INV_SQRT3);
}

void foc_park(int32_t alpha, int32_t beta, int32_t sine, int32_t cosine, int32_t *ds, int32_t *qs)
{
    *ds = iq24_add(iq24_mpy(alpha, cosine), iq24_mpy(beta, sine));
    *qs = iq24_sub(iq24_mpy(beta, cosine), iq24_mpy(alpha, sine));
}

void foc_ipark(int32_t ds, int32_t qs, int32_t sine, int32_t cosine, int32_t *alpha, int32_t *beta)
{
    *alpha = iq24_sub(iq24_mpy(ds, cosine), iq24_mpy(qs, sine));
    *beta = iq24_add(iq24_mpy(qs, cosine), iq24_mpy(ds, sine));
}

int32_t foc_pid_reg3(foc_pi_t *p, int32_t ref, int32_t fdb)
{
    int32_t up = iq24_mpy(p->kp, iq24_sub(ref, fdb));
    int32_t ui = iq24_add(p->ui, iq24_add(iq24_mpy(p->ki, up), iq24_mpy(p->kc, p->sat_err)));
    int32_t ud = p->kd != 0 ? iq24_mpy(p->kd, iq24_sub(up, p->up1)) : 0;
    int32_t pre = iq24_add(iq24_add(up, ui), ud);
    int32_t out = iq24_sat(pre, p->out_max, p->out_min);
    p->up = up;
    p->ui = ui;
    p->ud = ud;
    p->pre = pre;
    p->out = out;
    p->sat_err = iq24_sub(out, pre);
    p->up1 = up;
    return out;
}

int32_t foc_pi_clamp(foc_pi_t *p, int32_t ref, int32_t fdb)
{
    int32_t up = iq24_mpy(p->kp, iq24_sub(ref, fdb));
    int32_t ui = p->out == p->v1 ? iq24_add(iq24_mpy(p->ki, up), p->i1) : p->i1;
    int32_t v1;
    p->i1 = ui;
    v1 = iq24_add(up, ui);
    p->up = up;
    p->ui = ui;
    p->v1 = v1;
    p->out = iq24_sat(v1, p->out_max, p->out_min);
    return p->out;
}

void foc_pi_reset(foc_pi_t *p)
{
    p->up = p->ui = p->ud = p->pre = p->out = p->sat_err = p->up1 = 0;
    p->i1 = p->v1 = 0;
}

void foc_speed_fr_calc(foc_speed_fr_t *s)
{
    int32_t theta = s->elec_theta;
    int32_t tmp;
    if (s->unwrap) { /* v4.3: every sample, the difference unwrapped by one turn */
        int32_t d = iq24_sub(theta, s->old_elec_theta);
        if (d < -IQ24_HALF) {
            d = iq24_add(d, IQ24_ONE);
        } else if (d > IQ24_HALF) {
            d = iq24_sub(d, IQ24_ONE);
        }
        tmp = iq24_mpy(s->k1, d);
    } else if (IQ_ZERO_POINT_1 < theta && theta < IQ_ZERO_POINT_9) {
        tmp = iq24_mpy(s->k1, iq24_sub(theta, s->old_elec_theta)); /* Q21 = Q21 * GLOBAL_Q */
    } else {
        tmp = iq24_asr(s->speed, 3); /* hold: _IQtoIQ21(Speed) */
    }
    tmp = iq24_add(iq24_mpy(s->k2, iq24_asr(s->speed, 3)), iq24_mpy(s->k3, tmp));
    tmp = iq24_sat(tmp, IQ21_ONE, -IQ21_ONE);
    s->speed = iq24_shl(tmp, 3); /* _IQ21toIQ */
    s->old_elec_theta = theta;
    s->speed_rpm = iq24_mpy(s->base_rpm, s->speed); /* BaseRpm (Q0) * Speed (Q24) -> Q0 */
}

int32_t foc_mod(int32_t a, int32_t m)
{
    int32_t r = a % m;
    return r < 0 ? r + m : r;
}

void foc_qep_count(foc_qep_t *q, int32_t delta)
{
    if (delta != 0) {
        q->t2cnt = foc_mod(q->t2cnt + delta, q->t2pr + 1);
        q->direction = delta > 0 ? 1u : 0u;
    }
}

void foc_qep_index(foc_qep_t *q)
{
    q->qep_count_index = (uint16_t)q->t2cnt;
    q->t2cnt = 0;
    q->index_sync_flag = 0x00F0u;
}

uint16_t foc_qep_calc(foc_qep_t *q)
{
    uint16_t raw = (uint16_t)((uint32_t)(q->t2cnt + q->calibrated_angle) & 0xFFFFUL);
    /* __qmpy32by16(MechScaler, RawTheta, 31): bits 15..29 of the product are all that survive the
     * mask, and a 32-bit product holds them exactly (the low bits of a two's-complement product do
     * not depend on the high ones), so no 64-bit multiply is needed here. */
    uint32_t src16 = (q->signed16 && (raw & 0x8000u)) ? (uint32_t)raw | 0xFFFF0000UL : (uint32_t)raw;
    uint16_t mech = (uint16_t)((((uint32_t)q->mech_scaler * src16) >> 15) & 0x7FFFUL);
    q->raw_theta = raw;
    q->mech_theta = mech;
    q->elec_theta = (uint16_t)(((uint32_t)q->pole_pairs * (uint32_t)mech) & 0x7FFFUL);
    return q->elec_theta;
}

/* seed Table 1: P -> N (P = 0 and 7 only for a zero vector) */
static const uint16_t p_to_sector[8] = {0u, 2u, 6u, 1u, 4u, 3u, 5u, 0u};

uint16_t foc_svpwm(int32_t u_alpha, int32_t u_beta, int32_t cmpr[3])
{
    int32_t a = iq24_mpy(FOC_HALF_SQRT3, u_alpha);
    int32_t h = iq24_mpy(IQ24_HALF, u_beta);
    int32_t ux = u_beta, uy = iq24_sub(a, h), uz = iq24_sub(iq24_neg(a), h);
    uint16_t p = (uint16_t)((ux > 0 ? 1u : 0u) | (uy > 0 ? 2u : 0u) | (uz > 0 ? 4u : 0u));
    uint16_t n = p_to_sector[p];
    int32_t v[3];
    uint16_t k;
    if (n == 1u || n == 4u) {
        v[0] = iq24_sub(iq24_sub(IQ24_ONE, uy), ux);
        v[1] = iq24_sub(iq24_add(IQ24_ONE, uy), ux);
        v[2] = iq24_add(iq24_add(IQ24_ONE, uy), ux);
    } else if (n == 2u || n == 5u) {
        v[0] = iq24_add(iq24_sub(IQ24_ONE, uy), uz);
        v[1] = iq24_add(iq24_add(IQ24_ONE, uy), uz);
        v[2] = iq24_sub(iq24_sub(IQ24_ONE, uy), uz);
    } else if (n == 3u || n == 6u) {
        v[0] = iq24_add(iq24_add(IQ24_ONE, ux), uz);
        v[1] = iq24_sub(iq24_sub(IQ24_ONE, ux), uz);
        v[2] = iq24_sub(iq24_add(IQ24_ONE, ux), uz);
    } else {
        v[0] = v[1] = v[2] = IQ24_ONE;
    }
    for (k = 0u; k < 3u; k++) {
        int32_t c = iq24_mpy(v[k], FOC_T_PWM_QUARTER); /* _IQmpyI32int(value, T_PWM/4) */
        cmpr[k] = c > 0 ? c : 0;
    }
    return n;
}
