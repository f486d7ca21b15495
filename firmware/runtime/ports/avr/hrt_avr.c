/* firmware/runtime/ports/avr/hrt_avr.c: any firmware on the runtime on an ATmega328P or another
 * ATmega with USART0 (16-bit int, no FPU), to run cycle by cycle in simavr with the bench driving it
 * over the UART (simavr:PATH). The firmware defines hrt_firmware and hrt_firmware_init(); its
 * ticks_per_us x 8 must be a multiple of F_CPU in MHz (Timer1 at clk/8 is the clock: at 16 MHz an
 * even ticks_per_us).
 *
 * A monitor build (HRT_MONITOR=1: the firmware runs free on the chip's own timers and pins, the host
 * watches and tunes) also defines hrt_avr_monitor_start() (hrt_avr.h): its pins and timers, set up
 * once before interrupts are enabled. Its timer and pin interrupts run the firmware's bodies, so the
 * main loop holds them off while it serves the host, and streams the declared telemetry.
 *
 * USART0 at F_CPU / (8 * (UBRR0 + 1)) with U2X0 (UBRR0 = F_CPU / 2 MHz - 1: 250 000 baud, exact at any
 * whole 2 MHz, the same rate as the dsPIC30F2010 port; at 16 MHz -DHRT_AVR_UBRR=1u: 1 000 000 baud). Its RX-complete interrupt feeds the receive state machine; the
 * main loop handles a complete frame and writes the reply by polling UDRE0. Timer1 (clk/8, 2 MHz)
 * with an overflow count is the free-running clock of real-time mode and the watchdog; its overflow
 * interrupt (every 32.8 ms) also wakes the sleeping main loop, so the watchdog is checked while no
 * bytes arrive.
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>

#include "hrt_avr.h"
#include "hrt_link.h"

#ifndef F_CPU
#define F_CPU 16000000UL
#endif
#ifndef HRT_AVR_UBRR
#define HRT_AVR_UBRR ((uint16_t)(F_CPU / 2000000UL - 1UL)) /* 250 000 baud with U2X0 (7 at 16 MHz) */
#endif
#define UART_UBRR HRT_AVR_UBRR
/* USART0's receive interrupt: USART_RX_vect on the ATmega328P, USART0_RX_vect on the ATmega1284P and
 * ATmega2560 */
#if defined(USART0_RX_vect)
#define HRT_AVR_RX_VECT USART0_RX_vect
#else
#define HRT_AVR_RX_VECT USART_RX_vect
#endif

static hrt_link_t host_link;
static volatile uint16_t timer1_overflows;
static uint8_t ticks_per_timer1; /* the firmware's ticks per Timer1 tick (set once in main) */

ISR(HRT_AVR_RX_VECT)
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

#if HRT_MONITOR
/* The timer and pin interrupts run the firmware's bodies: the main loop holds them off. */
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
    /* Timer1 ticks (F_CPU / 8) -> the firmware's ticks, wrapping at 2^32 as the runtime needs */
    return (((uint32_t)high << 16) | low) * ticks_per_timer1;
}

int main(void)
{
    /* ticks_per_us x 8 / (F_CPU in MHz), here once: hrt_port_now runs in interrupts, and a 32-bit
     * division costs an AVR hundreds of cycles (16 MHz: ticks_per_us / 2) */
    ticks_per_timer1 = (uint8_t)((uint32_t)hrt_firmware.ticks_per_us * 8UL / (F_CPU / 1000000UL));
    hrt_link_init(&host_link, hrt_firmware_init());
    UBRR0H = (uint8_t)(UART_UBRR >> 8);
    UBRR0L = (uint8_t)(UART_UBRR & 0xFFu);
    UCSR0A = (uint8_t)(1u << U2X0);
    UCSR0C = (uint8_t)((1u << UCSZ01) | (1u << UCSZ00)); /* 8N1 */
    UCSR0B = (uint8_t)((1u << RXEN0) | (1u << TXEN0) | (1u << RXCIE0));
    TCCR1A = 0u;
    TCCR1B = (uint8_t)(1u << CS11); /* clk/8 */
    TIMSK1 = (uint8_t)(1u << TOIE1);
#if HRT_MONITOR
    hrt_avr_monitor_start();
    sei();
    for (;;) { /* the timers run the firmware; the loop serves the host and streams */
        hrt_link_poll(&host_link);
        hrt_link_stream(&host_link);
    }
#else
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
#endif
}
