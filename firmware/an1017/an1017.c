/* an1017.c: the AN1017 firmware: its state, its ISR bodies and their declaration to the runtime
 * (see an1017.h). Written for hilbench; facts and sources in docs/board.md ("Facts and sources"),
 * tags [SVM], [T1], [HALL], [PID], [PWM], [ADC] below refer to its sections. */
#include "an1017.h"

#include "q15.h"

/* Constant tables live in flash: program space on AVR (read with pgm_read_word), PSV/const
 * section on the dsPIC (XC16 places const data in program memory by default). */
#if defined(__AVR__)
#include <avr/pgmspace.h>
#define AN1017_ROM PROGMEM
#define AN1017_ROM_U16(p) ((uint16_t)pgm_read_word(p))
#else
#define AN1017_ROM
#define AN1017_ROM_U16(p) (*(p))
#endif

/* [SVM] round(32767 * sin(i * 60 deg / 171)), i = 0..171: 1024 points per electrical cycle over
 * 60 degrees; index 171 is never reached (the largest index is 0x2AAA >> 6 = 170). */
static const uint16_t sine_table[172] AN1017_ROM = {
    0u, 201u, 401u, 602u, 803u, 1003u, 1204u, 1404u, 1605u, 1805u, 2005u, 2206u,
    2406u, 2606u, 2806u, 3006u, 3205u, 3405u, 3605u, 3804u, 4003u, 4202u, 4401u, 4600u,
    4799u, 4997u, 5195u, 5393u, 5591u, 5789u, 5986u, 6183u, 6380u, 6577u, 6773u, 6970u,
    7166u, 7361u, 7557u, 7752u, 7947u, 8141u, 8335u, 8529u, 8723u, 8916u, 9109u, 9302u,
    9494u, 9686u, 9877u, 10068u, 10259u, 10449u, 10639u, 10829u, 11018u, 11207u, 11395u, 11583u,
    11771u, 11958u, 12144u, 12331u, 12516u, 12701u, 12886u, 13070u, 13254u, 13437u, 13620u, 13802u,
    13984u, 14165u, 14346u, 14526u, 14706u, 14885u, 15063u, 15241u, 15419u, 15595u, 15772u, 15947u,
    16122u, 16297u, 16470u, 16643u, 16816u, 16988u, 17159u, 17330u, 17500u, 17669u, 17838u, 18006u,
    18173u, 18340u, 18506u, 18671u, 18835u, 18999u, 19162u, 19325u, 19487u, 19647u, 19808u, 19967u,
    20126u, 20284u, 20441u, 20598u, 20753u, 20908u, 21062u, 21216u, 21368u, 21520u, 21671u, 21821u,
    21970u, 22119u, 22266u, 22413u, 22559u, 22704u, 22848u, 22992u, 23134u, 23276u, 23417u, 23557u,
    23696u, 23834u, 23971u, 24107u, 24243u, 24377u, 24511u, 24644u, 24776u, 24906u, 25036u, 25165u,
    25293u, 25420u, 25547u, 25672u, 25796u, 25919u, 26042u, 26163u, 26283u, 26403u, 26521u, 26638u,
    26755u, 26870u, 26984u, 27098u, 27210u, 27321u, 27431u, 27541u, 27649u, 27756u, 27862u, 27967u,
    28071u, 28174u, 28276u, 28377u
};

/* [HALL] PhaseValues: 57344 (315 deg), then + 65536/6 each. */
static const uint16_t phase_values[6] AN1017_ROM = {57344u, 2730u, 13652u, 24574u, 35496u, 46418u};

/* [HALL] SectorTable indexed by hall C B A; 0xFFFF (-1) = the illegal states 000 and 111. */
static const uint16_t sector_table[8] AN1017_ROM = {0xFFFFu, 4u, 2u, 3u, 0u, 5u, 1u, 0xFFFFu};

#define SIXTY_DEG 0x2AAAu
#define PHASEINC_NUMERATOR 512000UL     /* 65536 * 1000 Tcy / (2 * 64 Tcy): FCY-independent */
#define FORCE_COMMUTATION_TICKS 10u     /* _10MILLISEC */
#define ADC_POSTSCALE_MASK 15u          /* SEVOPS 1:16 (v1.1) */
#define GAIN_LIMIT_Q15 ((int32_t)32764)          /* SFloat_To_SFrac16(0.9999) = (int)(32767 * 0.9999 + 0.5) */
#define KP_DEFAULT 3277                 /* 0.1 */
#define KI_DEFAULT 328                  /* 0.01 */
#define KD_DEFAULT 0

#define FW(rt) ((an1017_t *)(void *)(rt)) /* the runtime's state is the firmware's first member */

/* `static inline`: a small helper, or one called once, that XC16's -O1 inlines as GCC's does (the
 * dsPIC30F2010's 4K words, docs/board.md section 3a, measured one by one); the others stay calls. */
/* Keep a helper out of its callers (GCC, XC16, clang): one copy in flash instead of one per call. */
#if defined(__GNUC__)
#define AN1017_NOINLINE __attribute__((noinline))
#else
#define AN1017_NOINLINE
#endif

static inline uint16_t sector_of(uint8_t hall)
{
    return AN1017_ROM_U16(&sector_table[hall & 7u]);
}

/* ------------------------------------------------------------------------------------- SVM */

/* t * k >> 15 in the firmware's 32-bit intermediate, truncated to an unsigned 16-bit result: bits 30:15
 * of the product, i.e. the high word of the product shifted left once. */
static uint16_t scale15(uint16_t t, int16_t k)
{
    return (uint16_t)(((uint32_t)((int32_t)t * (int32_t)k) << 1) >> 16);
}

void an1017_svm(int16_t volts, uint16_t angle, uint16_t pdc[3])
{
    uint8_t sector;
    uint16_t angle1, angle2, t1, t2, h, x, y1, y2;
    if (volts > AN1017_VOLTS_LIMIT) {
        volts = AN1017_VOLTS_LIMIT; /* only an upper clamp: volts >= -1 by construction */
    }
    /* [SVM] sector k by the `angle < VECTORk+1` tests in order */
    if (angle < 0x2AAAu) {
        sector = 1u;
        angle2 = angle;
    } else if (angle < 0x5555u) {
        sector = 2u;
        angle2 = (uint16_t)(angle - 0x2AAAu);
    } else if (angle < 0x8000u) {
        sector = 3u;
        angle2 = (uint16_t)(angle - 0x5555u);
    } else if (angle < 0xAAAAu) {
        sector = 4u;
        angle2 = (uint16_t)(angle - 0x8000u);
    } else if (angle < 0xD555u) {
        sector = 5u;
        angle2 = (uint16_t)(angle - 0xAAAAu);
    } else {
        sector = 6u;
        angle2 = (uint16_t)(angle - 0xD555u);
    }
    angle1 = (uint16_t)(SIXTY_DEG - angle2);
    t1 = AN1017_ROM_U16(&sine_table[(uint8_t)(angle1 >> 6)]);
    t2 = AN1017_ROM_U16(&sine_table[(uint8_t)(angle2 >> 6)]);
    /* then * TPWM >> 15: the product is below 2^26, so bits 30:15 are all of the quotient */
    t1 = scale15(t1, volts);
    t1 = (uint16_t)((((uint32_t)t1 * AN1017_TPWM) << 1) >> 16);
    t2 = scale15(t2, volts);
    t2 = (uint16_t)((((uint32_t)t2 * AN1017_TPWM) << 1) >> 16);
    h = (uint16_t)((uint16_t)(AN1017_TPWM - t1 - t2) >> 1);
    x = (uint16_t)(t1 + t2 + h);
    y1 = (uint16_t)(t1 + h);
    y2 = (uint16_t)(t2 + h);
    switch (sector) {
    case 1u: pdc[0] = x; pdc[1] = y2; pdc[2] = h; break;
    case 2u: pdc[0] = y1; pdc[1] = x; pdc[2] = h; break;
    case 3u: pdc[0] = h; pdc[1] = x; pdc[2] = y2; break;
    case 4u: pdc[0] = h; pdc[1] = y1; pdc[2] = x; break;
    case 5u: pdc[0] = y2; pdc[1] = h; pdc[2] = x; break;
    default: pdc[0] = x; pdc[1] = h; pdc[2] = y1; break;
    }
}

/* -------------------------------------------------------------------------------- routines */

int16_t an1017_max_ph_adv(int16_t deg)
{
    /* MAX_PH_ADV = (int)(deg / 360 * 65536), deg in 0..60 */
    return (int16_t)(((uint32_t)(uint16_t)deg * 65536UL) / 360UL);
}

/* [HALL] re-sync: PhaseValues[Sector] (CW) or PhaseValues[(Sector + 3) % 6] + PhaseOffset (CCW).
 * An invalid sector (0xFFFF) wraps to index (0xFFFF + 3) % 6 = 2 in CCW; in CW the chip would read
 * PhaseValues[-1] (out of bounds, not reproducible), so Phase is left as it is. */
static uint16_t phase_for_sector(const an1017_t *s, uint16_t sector, uint8_t required_ccw)
{
    if (required_ccw) {
        uint16_t idx = (uint16_t)((uint16_t)(sector + 3u) % 6u);
        return (uint16_t)(AN1017_ROM_U16(&phase_values[idx]) + (uint16_t)s->phase_offset);
    }
    if (sector == AN1017_SECTOR_INVALID) {
        return s->phase;
    }
    return AN1017_ROM_U16(&phase_values[sector]);
}

static void coefficients(an1017_t *s)
{
    /* [PID] C0 = Kp + Ki + Kd; C1 = -Kp - 2Kd (seed) or -(Ki + 2Kd) (v1.1); C2 = Kd; 16-bit words */
    s->c0 = q15_wrap((int32_t)s->kp + s->ki + s->kd);
    if (s->c1_textbook) {
        s->c1 = q15_wrap(-(int32_t)s->kp - (int32_t)2 * s->kd);
    } else {
        s->c1 = q15_wrap(-((int32_t)s->ki + (int32_t)2 * s->kd));
    }
    s->c2 = s->kd;
}

void an1017_init(an1017_t *s, uint8_t variant)
{
    uint16_t k;
    uint8_t v11 = (uint8_t)(variant == AN1017_VARIANT_V11);
    uint8_t *p = (uint8_t *)s;
    for (k = 0u; k < (uint16_t)sizeof *s; k++) { /* no memset: no C library needed */
        p[k] = 0u;
    }
    hrt_init(&s->rt);
    hrt_pwm_preset(&s->rt, AN1017_PTPER, AN1017_PTPER, AN1017_PTPER); /* PDC1..3 = PTPER */
    s->adc_every = (uint8_t)!v11;
    s->c1_textbook = (uint8_t)!v11;
    s->phase_offset = AN1017_PHASE_OFFSET;
    an1017_set_periods(s, AN1017_MINPERIOD, AN1017_MAXPERIOD);
    s->kp = KP_DEFAULT;
    s->ki = KI_DEFAULT;
    s->kd = KD_DEFAULT;
    s->phase_advance_on = v11;
    s->max_ph_adv_deg = 40;
    s->max_ph_adv = an1017_max_ph_adv(40);
    s->stall_limit = v11 ? 1000u : 100u; /* [T1] _1000MILLISEC (v1.1) / "(i.e. 100 ms)" */
    s->state = AN1017_STATE_STOPPED;
    s->fault = AN1017_FAULT_NONE;
    s->output_mode = AN1017_MODE_OFF;
    s->sector = AN1017_SECTOR_INVALID;
    s->last_sector = AN1017_SECTOR_INVALID;
}

void an1017_set_periods(an1017_t *s, uint16_t min_period, uint16_t max_period)
{
    s->min_period = min_period;
    s->max_period = max_period;
    s->period = max_period;
}

void an1017_press_start(an1017_t *s)
{
    if (s->running || s->booting) {
        return;
    }
    s->booting = 1u;
    s->state = AN1017_STATE_BOOTSTRAP;
    s->fault = AN1017_FAULT_NONE;
    s->output_mode = AN1017_MODE_LOW_SIDE; /* OVDCON = 0x0015: PWM1L/2L/3L on */
    /* the busy loop of ChargeBootstraps ends just after the 10 ms boundary */
    hrt_timer_start(&s->rt, AN1017_TIMER_BOOT, AN1017_BOOTSTRAP_TCY + 1UL);
}

void an1017_press_stop(an1017_t *s, uint8_t state, uint8_t fault)
{
    /* StopMotor(): OVDCON = 0 (all six switches off, the motor coasts), motor interrupts off */
    s->running = 0u;
    s->booting = 0u;
    hrt_timer_stop(&s->rt, AN1017_TIMER_T1);
    hrt_timer_stop(&s->rt, AN1017_TIMER_BOOT);
    s->output_mode = AN1017_MODE_OFF;
    s->state = state;
    s->fault = fault;
}

void an1017_run_motor(an1017_t *s)
{
    s->booting = 0u;
    s->output_mode = AN1017_MODE_PWM; /* PDC1..3 = PTPER, OVDCON = 0x3F00 */
    hrt_pwm_preset(&s->rt, AN1017_PTPER, AN1017_PTPER, AN1017_PTPER);
    s->e1 = 0;
    s->e2 = 0;
    coefficients(s);
    s->actual_capture = s->max_period; /* the first Period is MAXPERIOD (31250) */
    s->past_capture = 0u;
    s->sector = sector_of(AN1017_HALL(s));
    s->last_sector = s->sector;
    s->control_output = 0;
    s->cur_ccw = (uint8_t)(s->ref_speed < 0);
    s->req_ccw = s->cur_ccw;
    s->phase = phase_for_sector(s, s->sector, s->req_ccw);
    s->stall_counter = 0u;
    s->phase_inc = (uint16_t)(PHASEINC_NUMERATOR / s->max_period);
    s->running = 1u;
    s->state = AN1017_STATE_RUNNING;
    hrt_timer_start(&s->rt, AN1017_TIMER_T1, AN1017_TIMER1_PERIOD_TCY); /* TMR1 = 0 */
    s->tmr3_zero = hrt_now(&s->rt);                                     /* TMR3 = 0 */
}

void an1017_set_gains(an1017_t *s, int16_t kp, int16_t ki, int16_t kd)
{
    if (s->running) { /* taken by the next Timer1 ISR */
        s->pend_kp = kp;
        s->pend_ki = ki;
        s->pend_kd = kd;
        s->has_pending = 1u;
    } else { /* RunMotor computes the coefficients */
        s->kp = kp;
        s->ki = ki;
        s->kd = kd;
        s->has_pending = 0u;
    }
}

/* ------------------------------------------------------------------------------ ISR bodies */

/* The PID's MAC with SATA, out of line: three calls cost less flash than three copies. */
static AN1017_NOINLINE int32_t mac_sata(int32_t acc, int16_t a, int16_t b)
{
    return q15_mac_sata(acc, a, b);
}

void an1017_isr_adc(an1017_t *s)
{
    /* [ADC] FORM = 11 signed fractional: ADCBUF0 = (code - 512) << 6; RefSpeed = ADCBUF0 */
    if (s->ref_override_on) {
        s->ref_speed = s->ref_override;
    } else {
        s->ref_speed = (int16_t)(((int16_t)(hrt_adc(&s->rt, 0u) & 0x3FFu) - 512) * 64);
    }
}

void an1017_isr_pwm(an1017_t *s)
{
    int16_t volts;
    if (s->req_ccw) {
        if (s->cur_ccw) {
            s->phase = (uint16_t)(s->phase - s->phase_inc);
        }
        volts = (int16_t)(-((int32_t)s->control_output + 1L)); /* SVM(-(ControlOutput + 1), ...) */
    } else {
        if (!s->cur_ccw) {
            s->phase = (uint16_t)(s->phase + s->phase_inc);
        }
        volts = s->control_output;
    }
    /* without PHASE_ADVANCE the firmware adds nothing: phase_adv stays 0 */
    an1017_svm(volts, (uint16_t)(s->phase + (uint16_t)s->phase_adv), hrt_duty_registers(&s->rt));
#ifdef AN1017_TEST_ONE_LSB_PHASE
    /* tests/test_speculative.py only: a deliberate one-LSB difference under a rare condition (the phase
     * passing one value), which twin-speculative lockstep must catch and locate */
    if ((uint16_t)(s->phase - (uint16_t)(AN1017_TEST_ONE_LSB_PHASE)) < s->phase_inc) {
        hrt_duty_registers(&s->rt)[0]++;
    }
#endif
}

void an1017_isr_timer1(an1017_t *s)
{
    uint16_t period;
    int16_t ms, e0;
    int32_t acc;
    if (s->has_pending) {
        s->kp = s->pend_kp;
        s->ki = s->pend_ki;
        s->kd = s->pend_kd;
        s->has_pending = 0u;
        coefficients(s);
    }
    /* [T1] Period between the last two IC7 captures (16-bit wrap), clamped */
    period = (uint16_t)(s->actual_capture - s->past_capture);
    if (period < s->min_period) {
        period = s->min_period;
    } else if (period > s->max_period) {
        period = s->max_period;
    }
    s->period = period;
    s->phase_inc = (uint16_t)(PHASEINC_NUMERATOR / period);
    /* MeasuredSpeed = DIVF(_MINPERIOD, Period), _MINPERIOD = MINPERIOD - 1 keeps DIVF's |num| < |den|;
     * MINPERIOD <= Period <= MAXPERIOD <= 32767 fits a positive int16 */
    ms = q15_divf_pos((uint16_t)(s->min_period - 1u), period);
    if (s->cur_ccw) {
        ms = (int16_t)-ms;
    }
    s->measured_speed = ms;
    /* [PID] SpeedControl: e0 = SAC(Ref - Meas); A = LAC ControlOutput; three MACs with SATA;
     * ControlOutput = SAC A (truncating) */
    e0 = q15_sub_sat(s->ref_speed, ms);
    acc = q15_lac(s->control_output);
    acc = mac_sata(acc, e0, s->c0);
    acc = mac_sata(acc, s->e1, s->c1);
    acc = mac_sata(acc, s->e2, s->c2);
    s->control_output = q15_sac(acc);
    s->e2 = s->e1;
    s->e1 = e0;
    s->req_ccw = (uint8_t)(s->control_output < 0);
    /* [T1] PhaseAdvance = MPY MAX_PH_ADV * MeasuredSpeed, SAC A (no rounding) */
    s->phase_adv = s->phase_advance_on ? q15_mul(s->max_ph_adv, ms) : 0;
    /* [T1] stall: force a commutation every 10 ticks without a hall edge, stop at the limit */
    s->stall_counter = (uint16_t)(s->stall_counter + 1u);
    if (s->stall_counter % FORCE_COMMUTATION_TICKS == 0u) {
        s->sector = sector_of(AN1017_HALL(s));
        if (s->sector != AN1017_SECTOR_INVALID) {
            s->phase = phase_for_sector(s, s->sector, s->req_ccw);
        }
    } else if (s->stall_counter >= s->stall_limit) {
        an1017_press_stop(s, AN1017_STATE_STALLED, AN1017_FAULT_STALL);
    }
}

void an1017_isr_hall(an1017_t *s, uint8_t which)
{
    uint16_t sec = sector_of(AN1017_HALL(s));
    s->sector = sec;
    if (sec == s->last_sector) {
        return; /* a slow edge's glitch: nothing changed */
    }
    if (which == 1u) {
        /* IC7: PastCapture = ActualCapture; ActualCapture = IC7BUF; three more reads of IC7BUF
         * flush the rest of the 4-deep FIFO, so it is empty afterwards */
        s->past_capture = s->actual_capture;
        if (s->ic7_n > 0u) {
            s->actual_capture = s->ic7_first;
        }
        s->ic7_n = 0u;
    }
    s->stall_counter = 0u;
    /* [HALL] direction from the new sector: CW = sector index increasing */
    if (which == 0u) {
        s->cur_ccw = (uint8_t)(sec == 5u || sec == 2u);
    } else if (which == 1u) {
        s->cur_ccw = (uint8_t)(sec == 3u || sec == 0u);
    } else {
        s->cur_ccw = (uint8_t)(sec == 1u || sec == 4u);
    }
    s->phase = phase_for_sector(s, sec, s->req_ccw);
    s->last_sector = sec;
}

void an1017_main_loop_buttons(an1017_t *s, uint8_t inputs)
{
    /* main(): S2 (RC14, active low; here the Sensors bit) acts on release, toggling Run/Stop */
    uint8_t s2 = (uint8_t)((inputs & AN1017_INPUT_S2) != 0u);
    if (s->booting) {
        return; /* main() is busy in ChargeBootstraps */
    }
    if (s2) {
        s->s2_wait_release = 1u;
    } else if (s->s2_wait_release) {
        s->s2_wait_release = 0u;
        if (s->running) {
            an1017_press_stop(s, AN1017_STATE_STOPPED, AN1017_FAULT_NONE);
        } else {
            an1017_press_start(s);
        }
    }
}

uint8_t an1017_sector_reported(const an1017_t *s)
{
    uint16_t sec = s->running ? s->sector : sector_of(AN1017_HALL(s));
    return (uint8_t)((sec == AN1017_SECTOR_INVALID) ? 7u : sec);
}

/* ------------------------------------------------------------------------------ parameters */

int16_t an1017_param_value(const an1017_t *s, uint8_t id)
{
    switch (id) {
    case AN1017_PARAM_KP: return s->has_pending ? s->pend_kp : s->kp;
    case AN1017_PARAM_KI: return s->has_pending ? s->pend_ki : s->ki;
    case AN1017_PARAM_KD: return s->has_pending ? s->pend_kd : s->kd;
    case AN1017_PARAM_PH_ADV_ON: return (int16_t)s->phase_advance_on;
    case AN1017_PARAM_PH_ADV_DEG: return s->max_ph_adv_deg;
    case AN1017_PARAM_REF_OVR_ON: return (int16_t)s->ref_override_on;
    case AN1017_PARAM_REF_OVR: return s->ref_override;
    case AN1017_PARAM_STALL_MS: return (int16_t)s->stall_limit;
    default: return 0;
    }
}

uint8_t an1017_check_gains(int32_t kp, int32_t ki, int32_t kd)
{
    /* [PID] the note's constraints on the 1.15 gains */
    if (!(kp + ki + kd < GAIN_LIMIT_Q15)) {
        return 1u;
    }
    if (!(-kp - (int32_t)2 * kd > (int32_t)-32768)) {
        return 2u;
    }
    if (!(kd < GAIN_LIMIT_Q15)) {
        return 3u;
    }
    return 0u;
}

/* an1017_check_gains for gains within their declared range 0..32767, the same verdict in 16-bit
 * unsigned arithmetic (what a 16-bit chip computes without 32-bit adds and compares). Exact there:
 * kp + ki <= 65534 does not wrap, and past its test kp + ki < 32764, so kp + ki + kd <= 65530;
 * -kp - 2 kd > -32768 is kp + 2 kd < 32768, false for kd >= 16384, else kp + 2 kd <= 65533. */
static inline uint8_t check_gains_in_range(uint16_t kp, uint16_t ki, uint16_t kd)
{
    uint16_t sum = (uint16_t)(kp + ki);
    if (sum >= (uint16_t)GAIN_LIMIT_Q15 || (uint16_t)(sum + kd) >= (uint16_t)GAIN_LIMIT_Q15) {
        return 1u;
    }
    if (kd >= 16384u || (uint16_t)(kp + (uint16_t)(2u * kd)) >= 32768u) {
        return 2u;
    }
    if (kd >= (uint16_t)GAIN_LIMIT_Q15) {
        return 3u;
    }
    return 0u;
}

void an1017_param_set(an1017_t *s, uint8_t id, int32_t value)
{
    int16_t v = (int16_t)value; /* every declared range fits 16 bits */
    if (id <= AN1017_PARAM_KD) { /* the others as they stand (pending ones included), this one new */
        int16_t g[3];
        g[0] = an1017_param_value(s, AN1017_PARAM_KP);
        g[1] = an1017_param_value(s, AN1017_PARAM_KI);
        g[2] = an1017_param_value(s, AN1017_PARAM_KD);
        g[id] = v;
        an1017_set_gains(s, g[0], g[1], g[2]);
        return;
    }
    switch (id) {
    case AN1017_PARAM_PH_ADV_ON:
        s->phase_advance_on = (uint8_t)(v != 0);
        break;
    case AN1017_PARAM_PH_ADV_DEG:
        if (v != s->max_ph_adv_deg) {
            s->max_ph_adv_deg = v;
            s->max_ph_adv = an1017_max_ph_adv(v);
        }
        break;
    case AN1017_PARAM_REF_OVR_ON:
        s->ref_override_on = (uint8_t)(v != 0);
        break;
    case AN1017_PARAM_REF_OVR:
        s->ref_override = v;
        break;
    default: /* AN1017_PARAM_STALL_MS */
        s->stall_limit = (uint16_t)v;
        break;
    }
}

/* ------------------------------------------------------------------ the runtime's declaration */

static inline uint8_t is_gain(uint8_t id)
{
    return (uint8_t)(id <= AN1017_PARAM_KD);
}

static inline int32_t decl_param_get(hrt_t *rt, uint8_t id)
{
    return an1017_param_value(FW(rt), id);
}

static inline void decl_param_set(hrt_t *rt, uint8_t id, int32_t value)
{
    an1017_param_set(FW(rt), id, value);
}

/* The note's PID constraints on the candidate gains, checked only when a gain is written. The
 * offending id is the first written gain that takes part in the broken constraint. The candidates
 * are the gains as they stand (pending ones included) with the request's written over them (the
 * runtime has refused a request that names an id twice), in one pass over the request. */
static uint8_t decl_param_check(hrt_t *rt, const hrt_param_request_t *req, uint8_t *param_id, uint8_t *detail)
{
    /* bit id of involved[broken]: gain id takes part in constraint broken (1: all, 2: kp and kd, 3: kd) */
    static const uint8_t involved[4] = {0u, 7u, 5u, 4u};
    const an1017_t *s = FW(rt);
    uint16_t gain[3]; /* 0..32767: the runtime checked the request's ranges, the stored gains were */
    uint8_t i;
    uint8_t broken;
    uint8_t first_gain = HRT_NONE;
    gain[AN1017_PARAM_KP] = (uint16_t)an1017_param_value(s, AN1017_PARAM_KP);
    gain[AN1017_PARAM_KI] = (uint16_t)an1017_param_value(s, AN1017_PARAM_KI);
    gain[AN1017_PARAM_KD] = (uint16_t)an1017_param_value(s, AN1017_PARAM_KD);
    for (i = 0u; i < req->n; i++) {
        uint8_t id = req->id[i];
        if (is_gain(id)) {
            gain[id] = (uint16_t)req->value[i];
            if (first_gain == HRT_NONE) {
                first_gain = id;
            }
        }
    }
    if (first_gain == HRT_NONE) {
        return HBP_RESULT_OK;
    }
    broken = check_gains_in_range(gain[AN1017_PARAM_KP], gain[AN1017_PARAM_KI], gain[AN1017_PARAM_KD]);
    if (broken == 0u) {
        return HBP_RESULT_OK;
    }
    *param_id = first_gain;
    for (i = 0u; i < req->n; i++) {
        uint8_t id = req->id[i];
        if (is_gain(id) && (((unsigned)involved[broken] >> id) & 1u) != 0u) {
            *param_id = id;
            break;
        }
    }
    *detail = broken;
    return HBP_RESULT_CONSTRAINT;
}

/* The PWM period boundary: the ADC ISR when due (every period, or every 16th with SEVOPS 1:16),
 * then, after the duty latch, the PWM ISR. */
static inline void body_pwm(hrt_t *rt)
{
    an1017_t *s = FW(rt);
    if (s->adc_every || (hrt_pwm_count(rt) & ADC_POSTSCALE_MASK) == 0u) {
        an1017_isr_adc(s);
    }
    if (s->running) {
        an1017_isr_pwm(s);
    }
}

static void body_timer1(hrt_t *rt)
{
    an1017_isr_timer1(FW(rt)); /* Timer1 runs only while the motor does */
}

static void body_boot(hrt_t *rt)
{
    an1017_run_motor(FW(rt)); /* ChargeBootstraps is over */
}

/* The hall lines' interrupts: CN5 (A), IC7 (B, which captures TMR3 at every B edge into its 4-deep
 * FIFO, interrupt enabled or not; the ISR reads the oldest and flushes the others, so only the
 * oldest is kept), IC8 (C). They act only while the motor runs. */
static void body_hall_a(hrt_t *rt)
{
    an1017_t *s = FW(rt);
    if (s->running) {
        an1017_isr_hall(s, 0u);
    }
}

static void body_hall_b(hrt_t *rt)
{
    an1017_t *s = FW(rt);
    if (s->ic7_n < 4u) {
        if (s->ic7_n == 0u) {
            s->ic7_first = (uint16_t)(((hrt_now(rt) - s->tmr3_zero) & AN1017_TMR3_MASK) >> 6);
        }
        s->ic7_n++;
    }
    if (s->running) {
        an1017_isr_hall(s, 1u);
    }
}

static void body_hall_c(hrt_t *rt)
{
    an1017_t *s = FW(rt);
    if (s->running) {
        an1017_isr_hall(s, 2u);
    }
}

/* main(): S2 as the main loop polls it, then FLTA (FLTACON = 0x0007, latched): outputs inactive,
 * the FLTA ISR stops with FAULT; only a stop/start restarts, not while the pin is asserted. Under
 * the bench the span's fault bit acts at its start. */
static inline void body_main(hrt_t *rt)
{
    an1017_t *s = FW(rt);
    uint8_t in = hrt_inputs(rt);
    an1017_main_loop_buttons(s, in);
    if ((in & AN1017_INPUT_FAULT) && (s->running || s->booting)) {
        an1017_press_stop(s, AN1017_STATE_FAULT, AN1017_FAULT_OVERCURRENT);
    }
}

static inline void decl_report(hrt_t *rt, hrt_report_t *out)
{
    const an1017_t *s = FW(rt);
    out->output_mode = s->output_mode;
    out->state = s->state;
    out->sector = an1017_sector_reported(s);
    out->direction_ccw = s->cur_ccw;
    out->required_ccw = s->req_ccw;
    out->fault = s->fault;
    out->telemetry[0] = s->ref_speed;
    out->telemetry[1] = s->measured_speed;
    out->telemetry[2] = s->control_output;
}

static inline void decl_start(hrt_t *rt)
{
    an1017_press_start(FW(rt)); /* S2 as a command */
}

static inline void decl_stop(hrt_t *rt, uint8_t why)
{
    an1017_t *s = FW(rt);
    if (why == HRT_STOP_WATCHDOG) {
        an1017_press_stop(s, AN1017_STATE_FAULT, AN1017_FAULT_WATCHDOG);
    } else if (s->running || s->booting) {
        an1017_press_stop(s, AN1017_STATE_STOPPED, AN1017_FAULT_NONE);
    }
}

/* Declared parameters (ids 0..7, the same table as hilbench/targets/an1017/target.py's PARAMS). */
static const hrt_param_decl_t params[AN1017_N_PARAMS] = {
    HRT_PARAM("kp", "", 0, 32767, HBP_PTYPE_Q15, HBP_ACCESS_RW),
    HRT_PARAM("ki", "", 0, 32767, HBP_PTYPE_Q15, HBP_ACCESS_RW),
    HRT_PARAM("kd", "", 0, 32767, HBP_PTYPE_Q15, HBP_ACCESS_RW),
    HRT_PARAM("ph_adv_on", "", 0, 1, HBP_PTYPE_BOOL, HBP_ACCESS_RW),
    HRT_PARAM("ph_adv_deg", "deg", 0, 60, HBP_PTYPE_INT, HBP_ACCESS_RW),
    HRT_PARAM("ref_ovr_on", "", 0, 1, HBP_PTYPE_BOOL, HBP_ACCESS_RW),
    HRT_PARAM("ref_override", "", -32767 - 1, 32767, HBP_PTYPE_Q15, HBP_ACCESS_RW),
    HRT_PARAM("stall_ms", "ms", 10, 30000, HBP_PTYPE_INT, HBP_ACCESS_RW),
};

/* RefSpeed, MeasuredSpeed in rpm: one Q15 step is 9 375 000 / (pole pairs * (MINPERIOD - 1) * 32768) rpm
 * (the note's Table 6 for its build: 1 875 000 / (312 * 32768)). */
#define AN1017_RPM_NUM ((int32_t)AN1017_PERIOD_X_RPM)
#define AN1017_RPM_DEN ((int32_t)(AN1017_POLE_PAIRS * (AN1017_MINPERIOD_RAW - 1UL) * 32768UL))
static const hrt_telemetry_decl_t telemetry[3] = {
    HRT_TELEMETRY("ref_speed", "rpm", AN1017_RPM_NUM, AN1017_RPM_DEN, HBP_TELEMETRY_REF_SPEED, HBP_PTYPE_Q15),
    HRT_TELEMETRY("measured_speed", "rpm", AN1017_RPM_NUM, AN1017_RPM_DEN, HBP_TELEMETRY_MEASURED_SPEED, HBP_PTYPE_Q15),
    HRT_TELEMETRY("control_output", "q15", 1, 1, HBP_TELEMETRY_CONTROL_OUTPUT, HBP_PTYPE_Q15),
};

/* AN2 pot, AN1 bus current, AN0 bus voltage: only the pot is used */
static const uint8_t adc_roles[3] = {HBP_ADC_POT, HBP_ADC_IBUS, HBP_ADC_VBUS};

/* Simultaneous interrupts in the dsPIC's natural order: Timer1, the end of ChargeBootstraps (the
 * main loop's), the hall ISRs, the PWM/ADC boundary. */
static const hrt_timer_decl_t timers[2] = {
    {body_timer1, AN1017_TIMER1_PERIOD_TCY, 0u},
    {body_boot, 0u, 1u},
};

static const hrt_edge_decl_t edges[3] = {
    {body_hall_a, HRT_IN_HALL_A, HRT_EDGE_BOTH},
    {body_hall_b, HRT_IN_HALL_B, HRT_EDGE_BOTH},
    {body_hall_c, HRT_IN_HALL_C, HRT_EDGE_BOTH},
};

const hrt_firmware_t hrt_firmware = {
    .name = AN1017_FIRMWARE_NAME,
    .version = AN1017_FIRMWARE_VERSION,
    .ticks_per_us = AN1017_TCY_PER_US,
    .period_step_us = AN1017_PERIOD_STEP_US,
    /* PWM: 20 kHz centre-aligned, 1000 counts = 100 %, PWMCON2.IUE = 0 */
    .pwm_period_ticks = AN1017_PWM_PERIOD_TCY,
    .pwm_counts = AN1017_DUTY_MAX,
    .duty_timing = HRT_DUTY_NEXT_PERIOD,
    .pwm_priority = 3u,
    .pwm_isr = body_pwm,
    /* inputs: the halls, S2, FLTA; AN2, AN1, AN0 */
    .inputs = (uint8_t)(HRT_IN_HALLS | HRT_IN_S2 | HRT_IN_FAULT),
    .adc_bits = AN1017_ADC_BITS,
    .n_adc = 3u,
    .adc_roles = adc_roles,
    /* interrupt bodies */
    .timers = timers,
    .n_timers = 2u,
    .edges = edges,
    .n_edges = 3u,
    .edge_priority = 2u,
    .main_body = body_main,
    /* parameters */
    .params = params,
    .n_params = AN1017_N_PARAMS,
    .param_get = decl_param_get,
    .param_set = decl_param_set,
    .param_check = decl_param_check,
    /* telemetry, the Drive, commands */
    .telemetry = telemetry,
    .n_telemetry = 3u,
    .report = decl_report,
    .start = decl_start,
    .stop = decl_stop,
#if HRT_PREDICT_BYTES > 0
    .state_size = (uint16_t)sizeof(an1017_t), /* mode PREDICT copies it */
#endif
};
#if HRT_PREDICT_BYTES > 0
/* the copy of the state that mode PREDICT keeps fits (C99: a negative array size stops the build) */
typedef char an1017_predict_room[(sizeof(an1017_t) <= HRT_PREDICT_BYTES) ? 1 : -1];
#endif
