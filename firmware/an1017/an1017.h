/* an1017.h: hilbench's AN1017 sinusoidal BLDC firmware for the dsPIC30F2010, as a portable C99 core.
 *
 * Written for hilbench from the application note's description and docs/board.md's fact table
 * (not from Microchip's source). One struct holds everything the firmware owns: its variables (as
 * the chip keeps them: 16-bit words), its declared parameters, and the "virtual peripherals" that
 * replace the chip's timers and pins when the firmware runs under the bench (hall states and the
 * pot from Sensors frames, Timer1/Timer3/PWM time bases counted in Tcy).
 *
 * The firmware runs on the hilbench runtime (firmware/runtime/hrt.h): this file keeps only the
 * firmware's state and its ISR bodies (an1017_isr_*), and declares them in `hrt_firmware` — the
 * PWM period boundary (ADC ISR when due, PWM ISR after the duty latch), Timer1 and the end of
 * ChargeBootstraps as runtime timers, the hall lines' edges (CN5 = A, IC7 = B with its capture,
 * IC8 = C) — in the dsPIC's natural order for simultaneous interrupts: Timer1, then RunMotor's end
 * of ChargeBootstraps, then the hall ISRs, then the PWM/ADC boundary. The runtime schedules them in
 * virtual time (lockstep), runs them from the chip's interrupts (real time) and speaks the
 * protocol. Every value equals the Python reference model hilbench/targets/an1017/firmware.py
 * (tests/test_firmware_sil.py compares whole sessions; hilbench/targets/an1017/_core.c runs this
 * file in the bench's own process).
 *
 * Time: Tcy = 50 ns (FCY = 20 MHz, 5 MHz crystal with PLLx16). PWM period 1000 Tcy (PTPER 499,
 * centre-aligned, 20 kHz); Timer1 every (PR1 + 1) * 64 = 20096 Tcy; TMR3 ticks every 64 Tcy.
 * No heap, no floating point, exact with a 16-bit `int`.
 */
#ifndef AN1017_H
#define AN1017_H

#include <stdint.h>

#include "hrt.h"

/* ---- time base (Tcy) ---- */
#define AN1017_FCY_HZ 20000000UL
#define AN1017_TCY_PER_US 20u
#define AN1017_PWM_PERIOD_TCY 1000u       /* 2 * (PTPER + 1) */
#define AN1017_TIMER1_PERIOD_TCY 20096u   /* (PR1 + 1) * 64, PR1 = 313 */
#define AN1017_BOOTSTRAP_TCY 200000UL     /* ChargeBootstraps: 10 ms of low sides on */
#define AN1017_TMR3_MASK 0x3FFFFFUL       /* TMR3 counts Tcy/64 in 16 bits: 2^22 Tcy per wrap */
#define AN1017_PWM_FREQ_HZ 20000UL
#define AN1017_PERIOD_STEP_US 50u         /* an agreed period is a whole number of PWM periods */
#define AN1017_ADC_BITS 10u               /* the dsPIC30F2010's 10-bit ADC */
/* the HELLO's identity; a fork or a later version defines its own (-D), and a host then does not take the
 * registered model's word for its parameters (hilbench RemoteTarget.describe) */
#ifndef AN1017_FIRMWARE_NAME
#define AN1017_FIRMWARE_NAME "AN1017"
#endif
#ifndef AN1017_FIRMWARE_VERSION
#define AN1017_FIRMWARE_VERSION 0x0101u   /* v1.1 */
#endif

/* ---- runtime timers (ids into hrt_firmware.timers) ---- */
#define AN1017_TIMER_T1 0u                /* Timer1, the speed loop tick, while the motor runs */
#define AN1017_TIMER_BOOT 1u              /* the end of ChargeBootstraps, while booting */

/* ---- firmware constants ---- */
#define AN1017_PTPER 499u
#define AN1017_TPWM 998u                  /* PTPER << 1: the period in duty-register units */
#define AN1017_VOLTS_LIMIT 28300          /* 0.866 = sqrt(3)/2 in Q15 */
/* The motor the firmware is built for (docs/board.md "Building for a motor"): override with
 * -DAN1017_POLE_PAIRS=4 -DAN1017_MAX_SPEED_RPM=6000. Period counts TMR3 ticks (Tcy/64 = 3.2 us)
 * between two hall-B edges, half an electrical revolution: Period = 9375000 / (pole pairs * rpm).
 * MINPERIOD rounds up at the maximum speed; MAXPERIOD is the 60 rpm period, kept a positive
 * 16-bit DIVF divisor. The note's build (10 poles, 6000 rpm) gives 313 and 31250. */
#ifndef AN1017_POLE_PAIRS
#define AN1017_POLE_PAIRS 5UL
#endif
#ifndef AN1017_MAX_SPEED_RPM
#define AN1017_MAX_SPEED_RPM 6000UL
#endif
#define AN1017_PERIOD_X_RPM 9375000UL     /* 60 s / (2 * 3.2 us) */
#define AN1017_POLES_X_RPM (1UL * (AN1017_POLE_PAIRS) * (AN1017_MAX_SPEED_RPM)) /* unsigned long, also in #if */
#define AN1017_MINPERIOD_RAW ((AN1017_PERIOD_X_RPM + AN1017_POLES_X_RPM - 1UL) / AN1017_POLES_X_RPM)
#define AN1017_MAXPERIOD_RAW (AN1017_PERIOD_X_RPM / (1UL * (AN1017_POLE_PAIRS) * 60UL))
#define AN1017_MINPERIOD ((uint16_t)AN1017_MINPERIOD_RAW)
#define AN1017_MAXPERIOD ((uint16_t)((AN1017_MAXPERIOD_RAW > 32767UL) ? 32767UL : AN1017_MAXPERIOD_RAW))
#if (AN1017_MINPERIOD_RAW < 2UL) || (AN1017_MINPERIOD_RAW >= AN1017_MAXPERIOD_RAW) || (AN1017_MINPERIOD_RAW >= 32767UL)
#error "AN1017_POLE_PAIRS / AN1017_MAX_SPEED_RPM: MINPERIOD out of 2..MAXPERIOD-1"
#endif
#define AN1017_PHASE_OFFSET 4100          /* 22.5 deg, the CCW offset of the 30F source */
#define AN1017_SECTOR_INVALID 0xFFFFu     /* -1 in the firmware's unsigned Sector */
#define AN1017_DUTY_MAX 1000u             /* a duty above 100 % (CCW start-up only) is reported as 1000 */

/* ---- Drive codes (the same numbers as the protocol's) ---- */
#define AN1017_MODE_OFF 0u
#define AN1017_MODE_PWM 1u
#define AN1017_MODE_LOW_SIDE 2u
#define AN1017_STATE_STOPPED 0u
#define AN1017_STATE_BOOTSTRAP 1u
#define AN1017_STATE_RUNNING 2u
#define AN1017_STATE_STALLED 3u
#define AN1017_STATE_FAULT 4u
#define AN1017_FAULT_NONE 0u
#define AN1017_FAULT_WATCHDOG 1u
#define AN1017_FAULT_STALL 2u
#define AN1017_INPUT_S2 0x08u
#define AN1017_INPUT_FAULT 0x20u          /* FLTA, the board's over-current comparator (Sensors bit) */
#define AN1017_FAULT_OVERCURRENT 3u

/* ---- declared parameters (ids as the protocol numbers them) ---- */
#define AN1017_PARAM_KP 0u
#define AN1017_PARAM_KI 1u
#define AN1017_PARAM_KD 2u
#define AN1017_PARAM_PH_ADV_ON 3u
#define AN1017_PARAM_PH_ADV_DEG 4u
#define AN1017_PARAM_REF_OVR_ON 5u
#define AN1017_PARAM_REF_OVR 6u
#define AN1017_PARAM_STALL_MS 7u
#define AN1017_N_PARAMS 8u

/* Variants: where the application note and the v1.1 source differ (docs/board.md). */
#define AN1017_VARIANT_SEED 0u
#define AN1017_VARIANT_V11 1u

typedef struct {
    hrt_t rt;                 /* the runtime's state: time, timers, inputs, ADC codes, duty registers */
    /* options (fixed at init) */
    uint8_t adc_every;        /* app note: ADC ISR every PWM period; v1.1: every 16th (SEVOPS 1:16) */
    uint8_t c1_textbook;      /* app note: C1 = -Kp - 2Kd; v1.1: C1 = -(Ki + 2Kd) */
    int16_t phase_offset;     /* PhaseOffset, CCW */
    uint16_t min_period;      /* MINPERIOD, MAXPERIOD of the motor built for: an1017_init sets the */
    uint16_t max_period;      /* macros' values; a host may set others (then an1017_set_periods) */
    /* declared, tunable values */
    int16_t kp, ki, kd;       /* gains in use (Q15) */
    int16_t pend_kp, pend_ki, pend_kd;
    uint8_t has_pending;      /* gains written while running wait for the next Timer1 ISR */
    uint8_t phase_advance_on;
    uint8_t ref_override_on;
    int16_t max_ph_adv_deg;
    int16_t max_ph_adv;       /* (int)(deg / 360 * 65536) */
    int16_t ref_override;
    uint16_t stall_limit;     /* Timer1 ticks without a hall edge before StopMotor */
    /* firmware variables */
    uint8_t running;          /* Flags.MotorRunning */
    uint8_t booting;          /* main() is inside ChargeBootstraps */
    uint8_t state, fault, output_mode;
    uint8_t cur_ccw, req_ccw; /* Current_Direction, Required_Direction */
    uint8_t s2_wait_release;
    int16_t ref_speed, measured_speed, control_output;
    int16_t e1, e2;           /* ControlDifference[1], [2] */
    int16_t c0, c1, c2;       /* PIDCoefficients */
    uint16_t phase, phase_inc;
    int16_t phase_adv;
    uint16_t sector, last_sector;
    uint16_t stall_counter;
    uint16_t period, actual_capture, past_capture;
    /* peripherals the runtime does not model */
    uint8_t ic7_n;            /* captures in the IC7 FIFO (4 deep on the chip) */
    uint16_t ic7_first;       /* the oldest one: the only one the firmware reads (it flushes the rest) */
    uint32_t tmr3_zero;       /* the tick at which TMR3 was cleared (TMR3 = (now - tmr3_zero) / 64) */
} an1017_t;

/* The hall lines C B A (bit0 A = RB3/CN5, bit1 B = RB4/IC7, bit2 C = RB5/IC8) as the firmware reads them. */
#define AN1017_HALL(s) ((uint8_t)(hrt_inputs(&(s)->rt) & 7u))

/* The firmware at power-on, with its runtime (hrt_init) at time 0. */
void an1017_init(an1017_t *s, uint8_t variant);
/* Another motor build at run time (the in-process host): MINPERIOD and MAXPERIOD as
 * build_periods() gives them (2 <= min_period < max_period <= 32767), before the motor starts. */
void an1017_set_periods(an1017_t *s, uint16_t min_period, uint16_t max_period);

/* SVM(volts, angle): PDC1..3 for amplitude volts (Q15, >= -1) at a 16-bit angle (65536 = 360 deg). */
void an1017_svm(int16_t volts, uint16_t angle, uint16_t pdc[3]);

/* ---- ISR bodies ---- */
void an1017_isr_adc(an1017_t *s);           /* RefSpeed = ADCBUF0 (or the reference override) */
void an1017_isr_pwm(an1017_t *s);           /* Phase += PhaseInc, SVM into the PDC registers */
void an1017_isr_timer1(an1017_t *s);        /* speed, SpeedControl, phase advance, stall */
void an1017_isr_hall(an1017_t *s, uint8_t which); /* 0 = CN5 (A), 1 = IC7 (B), 2 = IC8 (C) */
void an1017_run_motor(an1017_t *s);          /* RunMotor() after ChargeBootstraps: Timer1 and TMR3 from now */

/* ---- commands ---- */
void an1017_press_start(an1017_t *s);        /* S2 while stopped: ChargeBootstraps, then RunMotor */
void an1017_press_stop(an1017_t *s, uint8_t state, uint8_t fault); /* StopMotor() */
void an1017_main_loop_buttons(an1017_t *s, uint8_t inputs);

uint8_t an1017_sector_reported(const an1017_t *s);          /* 0..5, 7 = invalid */

/* ---- parameters ---- */
int16_t an1017_param_value(const an1017_t *s, uint8_t id);   /* declared value (pending gains included) */
void an1017_set_gains(an1017_t *s, int16_t kp, int16_t ki, int16_t kd);
/* The note's PID constraints: 0 when all hold, else the first broken one:
 * 1 Kp + Ki + Kd < 0.9999, 2 -Kp - 2Kd > -1.0, 3 Kd < 0.9999. */
uint8_t an1017_check_gains(int32_t kp, int32_t ki, int32_t kd);
/* One declared value already checked against its range (all fit 16 bits); the ids of one write in
 * order: gains written together end as one set, pending until the next Timer1 ISR while running. */
void an1017_param_set(an1017_t *s, uint8_t id, int32_t value);
int16_t an1017_max_ph_adv(int16_t deg);

#endif /* AN1017_H */
