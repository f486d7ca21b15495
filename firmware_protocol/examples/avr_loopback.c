/* avr_loopback.c: the loopback target on an 8-bit AVR (ATmega328P / ATmega2560, USART0, 16-bit int).
 *
 * Proof that the library and the loopback example build for a 16-bit-int MCU with the strict flags
 * (tests/test_protocol_avr.py compiles it with avr-gcc and reads the static RAM with avr-size). The
 * USART0 RX interrupt feeds the receive state machine; the main loop handles a ready frame and
 * answers by polling the transmitter. Clock and baud: F_CPU 16 MHz, 250 000 baud (UBRR0 = 3, U2X0 = 0:
 * 16e6 / (16 * 4) = 250 000 exactly).
 */
#include <avr/interrupt.h>
#include <avr/io.h>

/* The platform-free part, compiled in this translation unit (so one source file builds the target). */
#include "loopback_core.c"

#if defined(USART_RX_vect)
#define LOOPBACK_RX_VECT USART_RX_vect /* ATmega328P */
#else
#define LOOPBACK_RX_VECT USART0_RX_vect /* ATmega2560 */
#endif

ISR(LOOPBACK_RX_VECT)
{
    (void)hbp_rx_byte(&loopback_rx, UDR0);
}

int loopback_send(const uint8_t *wire, uint8_t n)
{
    uint8_t i;
    for (i = 0u; i < n; i++) {
        while ((UCSR0A & (1u << UDRE0)) == 0u) {
        }
        UDR0 = wire[i];
    }
    return 0;
}

int main(void)
{
    hbp_rx_init(&loopback_rx);
    UBRR0H = 0u;
    UBRR0L = 3u;
    UCSR0B = (uint8_t)((1u << RXEN0) | (1u << TXEN0) | (1u << RXCIE0));
    UCSR0C = (uint8_t)((1u << UCSZ01) | (1u << UCSZ00)); /* 8N1 */
    sei();
    for (;;) {
        if (loopback_rx.ready != 0u) {
            (void)loopback_handle(loopback_rx.buf, loopback_rx.frame_len);
            hbp_rx_release(&loopback_rx);
        }
    }
}
