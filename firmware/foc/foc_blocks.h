/* foc_blocks.h: the TI Digital Motor Control blocks the F2812 FOC firmware uses, in IQ24, and the
 * seed's simplified SVPWM.
 *
 * Written for hilbench from the equations in docs/foc.md (DMC library v3.20 / PMSM3_1 and
 * math_blocks v4.3, equations and facts only, no TI code); the readable reference is
 * hilbench/targets/foc/blocks.py and svpwm.py, which every value here equals bit for bit.
 * Every product is iq24_mpy (_IQmpy: floor, wrap), every sum a wrapping 32-bit long. Only
 * fixed-width types: the same source builds with a 16-bit `int` and a 16-bit `char` (C28x).
 */
#ifndef FOC_BLOCKS_H
#define FOC_BLOCKS_H

#include <stdint.h>

#include "iq24.h"

#define FOC_T1PR 7500                   /* 150 MHz, continuous up/down, 10 kHz */
#define FOC_T_PWM_QUARTER ((int32_t)3750) /* T_PWM/4 = 2*T1PR/4 */
#define FOC_HALF_SQRT3 ((int32_t)14529495L) /* _IQ(0.8660254) */
#define FOC_INV_SQRT3 ((int32_t)9686330L)   /* _IQ(0.57735026918963) */

/* Constant tables live in flash: program space on the AVR (read with pgm_read_dword; the table
 * must sit in the low 64 KiB, where avr-gcc puts .progmem), const data elsewhere. */
#if defined(__AVR__)
#include <avr/pgmspace.h>
#define FOC_ROM PROGMEM
#define FOC_ROM_I32(p) ((int32_t)pgm_read_dword(p))
#else
#define FOC_ROM
#define FOC_ROM_I32(p) (*(p))
#endif

/* round(sin(2*pi*k/32768) * 2^24) for k = 0..4095 and 4096..8192 (foc_sin_table.c, written by
 * gen_sin_table.py): a quarter turn, in two arrays because no AVR object may exceed 32767 bytes. */
extern const int32_t foc_sin_quarter_lo[4096] FOC_ROM;
extern const int32_t foc_sin_quarter_hi[4097] FOC_ROM;

/* _IQsinPU / _IQcosPU of a Q15 angle in turns (the firmware only asks for Q15 angles). */
int32_t foc_sin_q15(uint16_t angle_q15);
int32_t foc_cos_q15(uint16_t angle_q15);

/* CLARKE v3.20: Alpha = As; Beta = (As + 2 Bs) / sqrt(3) (i_c implied). */
void foc_clarke(int32_t as, int32_t bs, int32_t *alpha, int32_t *beta);
/* PARK: Ds = a cos + b sin; Qs = b cos - a sin.   IPARK: a = Ds cos - Qs sin; b = Qs cos + Ds sin. */
void foc_park(int32_t alpha, int32_t beta, int32_t sine, int32_t cosine, int32_t *ds, int32_t *qs);
void foc_ipark(int32_t ds, int32_t qs, int32_t sine, int32_t cosine, int32_t *alpha, int32_t *beta);

/* One controller's settings and state; PID_REG3 and the clamping PI share the struct. */
typedef struct {
    int32_t kp, ki, kc, kd, out_max, out_min;
    int32_t up, ui, ud, pre, out, sat_err, up1; /* PID_REG3 (pre = OutPreSat) */
    int32_t i1, v1;                             /* clamping PI */
} foc_pi_t;

/* PID_REG3 v3.20: Up = Kp Err; Ui += Ki Up + Kc SatErr; Out = sat(Up + Ui + Ud); SatErr = Out - OutPreSat. */
int32_t foc_pid_reg3(foc_pi_t *p, int32_t ref, int32_t fdb);
/* math_blocks v4.3 PI_MACRO: up = Kp (Ref - Fbk); ui = (Out == v1) ? Ki up + i1 : i1; Out = sat(up + ui). */
int32_t foc_pi_clamp(foc_pi_t *p, int32_t ref, int32_t fdb);
void foc_pi_reset(foc_pi_t *p);

/* SPEED_FR v3.20 (hold near the wrap) or v4.3 (unwrap); speed in IQ24 pu, K1 in Q21. */
typedef struct {
    int32_t k1, k2, k3, base_rpm;
    int32_t elec_theta, old_elec_theta, speed, speed_rpm;
    uint16_t unwrap;
} foc_speed_fr_t;

void foc_speed_fr_calc(foc_speed_fr_t *s);

/* The F281x EV QEP circuit with GP timer 2 (directional up/down, 0..T2PR inclusive) and the
 * F281XQEP driver's angle: RawTheta = (Uint16)(T2CNT + Cal); MechTheta = MechScaler*RawTheta >> 15
 * & 0x7FFF (Q15); ElecTheta = PolePairs*MechTheta & 0x7FFF. */
typedef struct {
    int32_t line_encoder, pole_pairs, calibrated_angle, mech_scaler, t2pr;
    int32_t t2cnt;              /* 0..T2PR */
    uint16_t direction;         /* 1 up, 0 down */
    uint16_t signed16;          /* RawTheta read as signed by __qmpy32by16 (docs/foc.md, unverified) */
    uint16_t raw_theta, mech_theta, elec_theta, qep_count_index, index_sync_flag;
} foc_qep_t;

/* Timer 2 clocked by `delta` quadrature edges (+ up, - down), wrapping both ways. */
void foc_qep_count(foc_qep_t *q, int32_t delta);
/* The driver's CAP3 (QEPI) ISR: QepCountIndex = T2CNT; T2CNT = 0; IndexSyncFlag = 0x00F0. */
void foc_qep_index(foc_qep_t *q);
/* The driver's calc: returns ElecTheta (Q15). */
uint16_t foc_qep_calc(foc_qep_t *q);

/* The seed's SVPWM (eq. 1-7, Tables 1 and 2): sector N (0 for a zero vector) and CMPR1..3 in T1
 * counts (negative ones set to 0; values above T1PR never match) for U_alpha, U_beta in pu of Udc/sqrt3. */
uint16_t foc_svpwm(int32_t u_alpha, int32_t u_beta, int32_t cmpr[3]);

/* a mod m in 0..m-1 for m > 0 (Python's %, which the reference model uses). */
int32_t foc_mod(int32_t a, int32_t m);

#endif /* FOC_BLOCKS_H */
