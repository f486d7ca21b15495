/* ports/avr/main.c: the F2812 FOC firmware on an ATmega1284P (8-bit core, 16-bit int, 16 KB RAM,
 * no FPU, no hardware 32-bit multiply), on the hilbench runtime, for running it cycle by cycle in
 * an MCU simulator (simavr) with the bench driving it in lockstep over the UART.
 *
 * The same firmware source (firmware/foc) as every other build. Why this part: the IQ24 sine table
 * (two arrays, 32 KB, in program memory below 64 KB) does not fit an ATmega328P's 32 KB of flash
 * with the code around it; the ATmega1284P has 128 KB. IQ24 products use the 16-bit limb form
 * (firmware/foc/iq24.h, IQ24_MPY_LIMBS).
 *
 * USART0 at F_CPU / (8 * (UBRR0 + 1)) with U2X0 (16 MHz, UBRR0 = 1: 1 000 000 baud, exact). Its
 * RX-complete interrupt feeds the link's receiver; the main loop handles a complete frame and
 * writes the reply by polling UDRE0. Timer1 (clk/8, 2 MHz) with an overflow count is the
 * free-running clock (in the firmware's 150 MHz ticks: x75) of real-time mode and the watchdog; its
 * overflow interrupt (every 32.8 ms) also wakes the sleeping main loop for the watchdog.
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>

#include "foc_hrt.h"
#include "hrt_link.h"

#ifndef F_CPU
#define F_CPU 16000000UL
#endif
#ifndef UART_UBRR
#define UART_UBRR 1u /* 1 000 000 baud with U2X0 at 16 MHz */
#endif

static hrt_link_t host_link;
static volatile uint16_t timer1_overflows;

ISR(USART0_RX_vect)
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

void hrt_port_lock(void)
{
    /* only the UART RX interrupt runs, and it touches no firmware state */
}

void hrt_port_unlock(void)
{
}

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
    return ((((uint32_t)high << 16) | low) * 75UL); /* 2 MHz -> 150 MHz ticks (wraps) */
}

int main(void)
{
    hrt_link_init(&host_link, hrt_firmware_init()); /* the build's settings (foc_config.h) */
    UBRR0H = (uint8_t)(UART_UBRR >> 8);
    UBRR0L = (uint8_t)(UART_UBRR & 0xFFu);
    UCSR0A = (uint8_t)(1u << U2X0);
    UCSR0C = (uint8_t)((1u << UCSZ01) | (1u << UCSZ00)); /* 8N1 */
    UCSR0B = (uint8_t)((1u << RXEN0) | (1u << TXEN0) | (1u << RXCIE0));
    TCCR1A = 0u;
    TCCR1B = (uint8_t)(1u << CS11); /* clk/8 */
    TIMSK1 = (uint8_t)(1u << TOIE1);
    sei();
    for (;;) {
        hrt_link_poll(&host_link);
        cli();
        if (!host_link.rx.ready) {
            /* nothing to do until a byte or the clock's overflow: sleep (sei then sleep is atomic) */
            sleep_enable();
            sei();
            sleep_cpu();
            sleep_disable();
        }
        sei();
    }
}
