/* ports/avr/main.c: the AN1017 firmware on an ATmega328P (16-bit int, 2 KB RAM, no FPU), the same
 * firmware and runtime as the dsPIC30F2010 port, for running the firmware cycle by cycle in an MCU
 * simulator (simavr) with the bench driving it in lockstep over the UART.
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
#define UART_UBRR 7u /* 250 000 baud with U2X0 at 16 MHz */

static an1017_t fw;
static hrt_link_t host_link;
static volatile uint16_t timer1_overflows;

ISR(USART_RX_vect)
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
    /* 2 MHz ticks -> 20 MHz Tcy: x10 */
    return (((uint32_t)high << 16) | low) * 10UL;
}

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
