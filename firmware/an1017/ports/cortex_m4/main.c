/* ports/cortex_m4/main.c: the AN1017 firmware on a Cortex-M4 (the Arm MPS2 AN386 image, run in QEMU's
 * mps2-an386 machine): the same firmware and runtime as the dsPIC30F2010 and AVR ports, with the
 * board support of firmware/runtime/ports/cortex_m4 (startup code, memory map, UART0, clock).
 *
 * UART0's receive interrupt feeds the link's receiver; the main loop handles a complete frame and
 * writes the reply by polling the transmit buffer, and sleeps (WFI) until a byte or the 1 kHz
 * SysTick (the watchdog's look) wakes it. Timer 0 (25 MHz, extended to 64 bits) is the clock of
 * real-time mode and the watchdog, scaled to the firmware's 20 MHz Tcy.
 */
#include "an1017.h"
#include "hrt_link.h"
#include "m4_port.h"

static an1017_t fw;
static hrt_link_t host_link;

static void on_rx(uint8_t byte)
{
    (void)hrt_link_rx_byte(&host_link, byte);
}

void hrt_port_send(const uint8_t *wire, uint8_t len)
{
    m4_uart_write(wire, len);
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
    /* 25 MHz ticks -> 20 MHz Tcy: x4/5 on the 64-bit count, then the low 32 bits (a wrapping counter) */
    return (uint32_t)((m4_clock_ticks() * 4u) / 5u);
}

int main(void)
{
    an1017_init(&fw, AN1017_VARIANT);
    hrt_link_init(&host_link, &fw.rt);
    m4_init(on_rx);
    for (;;) {
        hrt_link_poll(&host_link);
        m4_irq_off();
        if (!host_link.rx.ready) {
            m4_wait_for_interrupt(); /* a byte, or SysTick's millisecond for the watchdog */
        }
        m4_irq_on();
    }
}
