/* ports/avr/main.c: the AN1017 firmware on an AVR (16-bit int, no FPU), the same firmware and runtime
 * as the dsPIC30F2010 port, in two builds:
 *
 * - the HIL build (the default, ATmega328P): the firmware runs cycle by cycle in an MCU simulator
 *   (simavr) with the bench driving it in lockstep (or real time) over the UART; its halls and pot
 *   come from Sensors frames, its duties go out in Drives and no pin is driven.
 * - the real-motor build (make MODE=motor, -DHIL_MOTOR, an ATmega2560: it has a 16-bit timer with
 *   three compare outputs for a centre-aligned three-phase PWM at 20 kHz): the firmware runs free on
 *   the chip's own timers from power-on. The halls are read from pins (INT0..INT2 on PD0..PD2, any
 *   edge: each edge's capture time is the Timer1 clock in its interrupt), the pot from ADC0 (PF0),
 *   the duties drive Timer3's compare units (OC3A/OC3B/OC3C on PE3/PE4/PE5, fast PWM with
 *   ICR3 = F_CPU / 20 kHz - 1 as TOP: 20 kHz, edge-aligned where the dsPIC's is centre-aligned: the
 *   same mean voltage per period; simavr models no phase-correct mode with ICR as TOP), PA0 enables the bridge driver (low: all six switches
 *   off; the firmware's OFF), and the host talks in HostHello mode MONITOR: a Drive with the
 *   declared telemetry streams every agreed period, gains and the reference are written with the
 *   checked parameter protocol, and the runtime's watchdog stops the motor when the host goes silent.
 *   A HIL build never drives a pin; this build never takes its halls from frames (Sensors are refused
 *   in MONITOR, and it accepts no other mode but the handshake's LOCKSTEP/REALTIME refusal below).
 *   run_motor.c is its pin-level harness: simavr with hilbench's plant on these pins.
 *
 * The UART, Timer1 (the free-running clock of real time and the watchdog), the main loop and, in the
 * real-motor build, the interrupt masking are the runtime's AVR port (firmware/runtime/ports/avr/
 * hrt_avr.c, linked with this file); here: the firmware's state, and the real-motor build's pins.
 */
#include <avr/interrupt.h>
#include <avr/io.h>

#include "an1017.h"
#include "hrt_link.h"
#include "ports/avr/hrt_avr.h"

#ifndef F_CPU
#define F_CPU 16000000UL
#endif
#if 20000000UL % (F_CPU / 8UL) != 0UL
#error "F_CPU / 8 must divide 20 MHz (16, 32, 40 or 80 MHz): Timer1 is the firmware's Tcy clock"
#endif
#if defined(HIL_MOTOR) && !HRT_MONITOR
#error "the real-motor build needs HRT_MONITOR=1 (make MODE=motor sets it)"
#endif

static an1017_t fw;

hrt_t *hrt_firmware_init(void)
{
    an1017_init(&fw, AN1017_VARIANT);
    return &fw.rt;
}

#if defined(HIL_MOTOR)
/* ---- the real-motor build: the chip's own timers, pins and ADC ---- */
#define PWM_CYCLES ((uint16_t)(F_CPU / 20000UL)) /* fast PWM: TOP + 1 = F_CPU / 20 kHz */
#define HALL_PINS 0x07u                       /* PD0 = A, PD1 = B, PD2 = C (INT0..INT2) */
#define BRIDGE_ENABLE 0x01u                   /* PA0: the gate driver's enable */

/* duty x PWM_CYCLES / AN1017_DUTY_MAX as a multiply and a shift (a 32-bit division costs ~600 cycles
 * on an AVR, three of them per PWM period of 800 cycles left the main loop no time) */
#define PWM_SCALE_Q16 ((((uint32_t)PWM_CYCLES << 16) + AN1017_DUTY_MAX / 2u) / AN1017_DUTY_MAX)

static uint16_t compare(uint16_t duty)
{
    return (uint16_t)(((uint32_t)duty * PWM_SCALE_Q16) >> 16);
}

/* The duty registers as the firmware wrote them (double-buffered: they take effect at the next BOTTOM, as the dsPIC's
 * PDCx at its period boundary) and the bridge enable for its output mode. */
static void write_outputs(void)
{
    uint8_t pwm = (uint8_t)(fw.output_mode != AN1017_MODE_OFF);
    uint8_t low_side = (uint8_t)(fw.output_mode == AN1017_MODE_LOW_SIDE);
    OCR3A = low_side ? 0u : compare(hrt_duty(&fw.rt, 0u));
    OCR3B = low_side ? 0u : compare(hrt_duty(&fw.rt, 1u));
    OCR3C = low_side ? 0u : compare(hrt_duty(&fw.rt, 2u));
    PORTA = (uint8_t)(pwm ? (PORTA | BRIDGE_ENABLE) : (PORTA & (uint8_t)~BRIDGE_ENABLE));
}

/* Timer3 overflow (TOP to BOTTOM): one PWM period boundary. The ADC conversion started at the last one is read
 * (the pot, 10 bits) and the next one started. */
ISR(TIMER3_OVF_vect)
{
    uint16_t code = ADC;
    uint16_t adc[1];
    adc[0] = code;
    ADCSRA = (uint8_t)(ADCSRA | (1u << ADSC));
    hrt_rt_levels(&fw.rt, hrt_inputs(&fw.rt), adc, 1u, 0u);
    hrt_rt_pwm(&fw.rt, hrt_port_now());
    write_outputs();
}

static void hall_edge(void)
{
    hrt_rt_edge(&fw.rt, (uint8_t)(PIND & HALL_PINS), hrt_port_now()); /* bit i = hall line i, as HRT_IN_HALL_* */
    write_outputs();
}

ISR(INT0_vect)
{
    hall_edge();
}

ISR(INT1_vect, ISR_ALIASOF(INT0_vect));
ISR(INT2_vect, ISR_ALIASOF(INT0_vect));

void hrt_avr_monitor_start(void)
{
    DDRA = BRIDGE_ENABLE;
    PORTA = 0u;                                 /* bridge off */
    DDRD = (uint8_t)(DDRD & (uint8_t)~HALL_PINS);
    DDRE = (uint8_t)(DDRE | 0x38u);             /* OC3A..C */
    EICRA = 0x15u;                              /* INT0..INT2 on any edge */
    EIFR = 0x07u;
    EIMSK = 0x07u;
    ADMUX = (uint8_t)(1u << REFS0);             /* AVcc reference, ADC0 */
    ADCSRA = (uint8_t)((1u << ADEN) | (1u << ADSC) | 7u); /* clk/128 */
    ICR3 = PWM_CYCLES - 1u;
    OCR3A = PWM_CYCLES / 2u;
    OCR3B = PWM_CYCLES / 2u;
    OCR3C = PWM_CYCLES / 2u;
    TCCR3A = (uint8_t)((1u << COM3A1) | (1u << COM3B1) | (1u << COM3C1) | (1u << WGM31));
    TCCR3B = (uint8_t)((1u << WGM33) | (1u << WGM32) | (1u << CS30)); /* fast PWM, TOP = ICR3, clk/1 */
    TIMSK3 = (uint8_t)(1u << TOIE3);
    fw.rt.in = (uint8_t)(PIND & HALL_PINS);     /* the rotor's position at power-on */
    hrt_rt_enter(&fw.rt, 1u);
}
#endif
