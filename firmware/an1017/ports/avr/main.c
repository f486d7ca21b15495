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
 * USART0 at F_CPU / (8 * (UBRR0 + 1)) with U2X0 (16 MHz, UBRR0 = 7: 250 000 baud, exact, the same
 * rate as the dsPIC30F2010 port). Its RX-complete interrupt feeds the receive state machine; the
 * main loop handles a complete frame and writes the reply by polling UDRE0. Timer1 (clk/8, 2 MHz)
 * with an overflow count is the free-running clock of real-time mode and the watchdog; its overflow
 * interrupt (every 32.8 ms) also wakes the sleeping main loop, so the watchdog is checked while no
 * bytes arrive.
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>

#include "an1017.h"
#include "hrt_link.h"

#ifndef F_CPU
#define F_CPU 16000000UL
#endif
#define UART_UBRR ((uint16_t)(F_CPU / 2000000UL - 1UL)) /* 250 000 baud with U2X0: 7 at 16 MHz, exact at any whole 2 MHz */
#define TCY_PER_T1 (20000000UL / (F_CPU / 8UL)) /* Timer1 at clk/8 in the firmware's 20 MHz Tcy */
#if 20000000UL % (F_CPU / 8UL) != 0UL
#error "F_CPU / 8 must divide 20 MHz (16, 32, 40 or 80 MHz): Timer1 is the firmware's Tcy clock"
#endif
#if defined(USART0_RX_vect)
#define UART_RX_VECT USART0_RX_vect /* ATmega2560 */
#else
#define UART_RX_VECT USART_RX_vect /* ATmega328P */
#endif
#if defined(HIL_MOTOR) && !HRT_MONITOR
#error "the real-motor build needs HRT_MONITOR=1 (make MODE=motor sets it)"
#endif

static an1017_t fw;
static hrt_link_t host_link;
static volatile uint16_t timer1_overflows;

ISR(UART_RX_VECT)
{
    (void)hrt_link_rx_byte(&host_link, UDR0);
}

ISR(TIMER1_OVF_vect)
{
    timer1_overflows = (uint16_t)(timer1_overflows + 1u);
}

void hrt_port_send(const uint8_t *wire, uint8_t len)
{
    uint8_t i;
    for (i = 0u; i < len; i++) {
        while (!(UCSR0A & (1u << UDRE0))) {
        }
        UDR0 = wire[i];
    }
}

#if defined(HIL_MOTOR)
/* The timer and hall interrupts run the firmware's bodies: the main loop holds them off. */
void hrt_port_lock(void)
{
    cli();
}

void hrt_port_unlock(void)
{
    sei();
}
#else
void hrt_port_lock(void)
{
    /* only the UART RX interrupt runs, and it touches no firmware state */
}

void hrt_port_unlock(void)
{
}
#endif

uint32_t hrt_port_now(void)
{
    uint16_t high;
    uint16_t low;
    uint8_t sreg = SREG;
    cli();
    low = TCNT1;
    high = timer1_overflows;
    if ((TIFR1 & (1u << TOV1)) && low < 0x8000u) {
        high = (uint16_t)(high + 1u); /* an overflow not yet served */
    }
    SREG = sreg;
    /* F_CPU / 8 ticks -> 20 MHz Tcy (16 MHz: x10) */
    return (((uint32_t)high << 16) | low) * TCY_PER_T1;
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

static void init_motor(void)
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

int main(void)
{
    an1017_init(&fw, AN1017_VARIANT);
    hrt_link_init(&host_link, &fw.rt);
    UBRR0H = (uint8_t)(UART_UBRR >> 8);
    UBRR0L = (uint8_t)(UART_UBRR & 0xFFu);
    UCSR0A = (uint8_t)(1u << U2X0);
    UCSR0C = (uint8_t)((1u << UCSZ01) | (1u << UCSZ00)); /* 8N1 */
    UCSR0B = (uint8_t)((1u << RXEN0) | (1u << TXEN0) | (1u << RXCIE0));
    TCCR1A = 0u;
    TCCR1B = (uint8_t)(1u << CS11); /* clk/8 */
    TIMSK1 = (uint8_t)(1u << TOIE1);
#if defined(HIL_MOTOR)
    init_motor();
    sei();
    for (;;) { /* the timers run the firmware (the PWM ISR writes the outputs every period, after a
                * Start, a Stop or the watchdog too); the loop serves the host and streams. The
                * firmware's main body (the board's S2 and the FLTA level) has no pin in this build:
                * the host's Start and Stop are S2, the watchdog and Stop are the way to stop. */
        hrt_link_poll(&host_link);
        hrt_link_stream(&host_link);
    }
#endif
    sei();
    for (;;) {
        hrt_link_poll(&host_link);
        cli();
        if (!host_link.rx.ready && host_link.mode != HBP_MODE_REALTIME) {
            /* nothing to do until a byte arrives or Timer1 overflows: sleep (sei then sleep is atomic on AVR) */
            sleep_enable();
            sei();
            sleep_cpu();
            sleep_disable();
        }
        sei();
    }
}
