/* foc.h: hilbench's sensored-FOC firmware of the TMS320F2812 servo (the second seed), portable C99.
 *
 * Written for hilbench from docs/foc.md (the seed, TI's DMC v3.20 equations and the F281x Event
 * Manager facts; no TI code). One struct holds everything the firmware owns: its settings, its
 * blocks' state, and the "virtual peripherals" that stand for the chip's under the bench: the ADC
 * result registers, timer 1's compare shadow and active registers, timer 2 fed by the encoder.
 *
 * ISR bodies: foc_isr_t1_underflow (the main computation, once per 10 kHz PWM period, in
 * PMSM3_1's level-5 order: ADC, CLARKE, PARK with the previous ISR's angle, speed PI every
 * prescaler ISRs, i_q and i_d PI, IPARK, the seed's SVPWM into the CMPR shadows, QEP, SPEED_FR)
 * and foc_isr_cap3 (the encoder index). The Event Manager reloads the compare registers at the
 * underflow and at the period match (COMCONA = 0xA200), so a value the ISR writes acts from the
 * period match half a PWM period later (foc_em_*). The readable reference is
 * hilbench/targets/foc/firmware.py; every value here equals it bit for bit.
 *
 * Only fixed-width types of 16 and 32 bits (no uint8_t, no char data): the same source builds for
 * a 16-bit `int` (AVR) and a 16-bit `char` (C28x). No heap, no floating point, no I/O.
 */
#ifndef FOC_H
#define FOC_H

#include <stdint.h>

#include "foc_blocks.h"

#define FOC_ISR_PERIOD_US 100u          /* one ISR per PWM period */
#define FOC_HALF_PERIOD_US 50u          /* one up- or down-count of timer 1 */

/* ---- Drive codes (the protocol's numbers) ---- */
#define FOC_STATE_STOPPED 0u
#define FOC_STATE_ALIGN 1u              /* the protocol's BOOTSTRAP */
#define FOC_STATE_RUN 2u
#define FOC_STATE_FAULT 4u
#define FOC_FAULT_NONE 0u
#define FOC_FAULT_WATCHDOG 1u
#define FOC_OUTPUT_OFF 0u
#define FOC_OUTPUT_PWM 1u
#define FOC_INPUT_S2 0x08u
#define FOC_INPUT_INDEX 0x40u

#define FOC_PI_REG3 0u
#define FOC_PI_CLAMP 1u
#define FOC_N_TELEMETRY 8u              /* ref speed, speed, i_q ref, i_d, i_q, theta_e, V_d, V_q (Q15) */

/* Build-time settings as the chip holds them (foc_config.h has the servo build's). */
typedef struct {
    uint16_t pi_form, speed_fr_unwrap, learn_index, qep_signed16;
    int32_t line_encoder, pole_pairs, t2pr, calibrated_angle, mech_scaler;
    int32_t sp_k1, sp_k2, sp_k3, base_rpm;
    int32_t speed_loop_prescaler, align_isrs, align_v, align_i, ramp_step;
    int32_t cur_kp, cur_ki, cur_kc, id_out_max, iq_out_max;
    int32_t spd_kp, spd_ki, spd_kc, spd_out_max;
} foc_config_t;

typedef struct {
    /* settings */
    uint16_t pi_form, learn_index;
    int32_t speed_loop_prescaler, align_isrs, align_v, align_i, ramp_step;
    /* blocks */
    foc_pi_t pid_spd, pid_id, pid_iq;
    foc_qep_t qep;
    foc_speed_fr_t speed;
    /* firmware variables */
    int32_t speed_ref;          /* IQ24 pu of BaseRpm: the reference as set */
    int32_t speed_setpoint;     /* what the speed PI follows (the reference through the slew) */
    int32_t id_ref, iq_ref, iq_ref_set;
    uint16_t torque_mode;       /* the speed loop bypassed: i_q follows iq_ref_set */
    uint16_t state, fault;
    uint32_t isr_count;
    int32_t state_isrs;
    int32_t speed_loop_count;
    uint16_t index_learned;
    int32_t elec_theta;         /* speed1.ElecTheta: IQ24, from the previous ISR's QEP read */
    int32_t i_a, i_b, i_alpha, i_beta, i_d, i_q, v_d, v_q, v_alpha, v_beta;
    uint16_t vdc_code;
    uint16_t sector;
    uint16_t s2_last;           /* main loop: S2's level at the last look */
    /* virtual peripherals */
    uint16_t adc_result[3];     /* 12-bit codes of i_a, i_b, Udc, sampled at the underflow */
    int32_t compare_shadow[3];  /* CMPR1..3 as the ISR wrote them */
    int32_t compare_active[3];  /* what the full-compare units follow */
    uint16_t outputs_on;        /* ACTRA/COMCONA full-compare outputs enabled */
    uint16_t half;              /* 0: timer 1's next event is the underflow, 1: the period match */
    uint16_t enc_last, have_enc; /* the encoder count at the last look */
} foc_t;

/* The firmware's outputs as a Drive carries them (the duties come from foc_run_halves). */
typedef struct {
    uint16_t output_mode, state, sector, ccw, req_ccw, fault;
    int16_t telemetry[FOC_N_TELEMETRY];
} foc_out_t;

void foc_config_default(foc_config_t *c);
void foc_init(foc_t *s, const foc_config_t *c);

/* ---- ISR bodies ---- */
void foc_isr_t1_underflow(foc_t *s);    /* reads adc_result; writes compare_shadow */
void foc_isr_cap3(foc_t *s);            /* the index: the first one calibrates, each resets T2 */

/* ---- commands ---- */
void foc_start(foc_t *s);               /* stopped or faulted: rotor alignment, then closed loop */
void foc_stop(foc_t *s, uint16_t state, uint16_t fault); /* all switches off, the motor coasts */
void foc_buttons(foc_t *s, uint16_t inputs); /* main loop: S2's press toggles start/stop */
void foc_set_speed_ref_rpm(foc_t *s, int32_t rpm); /* _IQ(rpm / BaseRpm), truncating, within +-1 */

/* ---- virtual peripherals ---- */
void foc_em_underflow(foc_t *s);        /* T1CNT = 0: compare reload, then the ISR */
void foc_em_period_match(foc_t *s);     /* T1CNT = T1PR: compare reload */
/* Timer 2 follows the encoder's 16-bit x4 count (its differences; the first look only records
 * it), then the CAP3 ISR runs if an index pulse passed. */
void foc_encoder(foc_t *s, uint16_t count16, uint16_t index);
/* n half PWM periods from now (underflow and period match alternating) with the ADC results as
 * set: the high-side on-time of each phase in T1 counts, 0..T1PR, averaged over the n halves
 * (rounded half to even). */
void foc_run_halves(foc_t *s, uint32_t n, uint16_t duty[3]);
/* The on-time the active compare values give one half period (0 with the outputs off). */
void foc_active_duties(const foc_t *s, uint16_t duty[3]);

void foc_outputs(const foc_t *s, foc_out_t *out);
/* An IQ24 value as the Q15 telemetry word (_IQtoIQ15, saturated to 16 bits). */
int16_t foc_q15_word(int32_t x);

#endif /* FOC_H */
