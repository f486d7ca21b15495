/* ports/cortex_m4/main.c: the F2812 FOC firmware on a Cortex-M4 (the Arm MPS2 AN386 image, run in
 * QEMU's mps2-an386 machine), on the hilbench runtime, with the board support of
 * firmware/ports/cortex_m4 (startup code, memory map, UART0, clock).
 *
 * The same firmware source (firmware/foc) as the in-process core, the SIL build, the AVR and the
 * F2812: this file supplies only the runtime's port (byte I/O on UART0, the clock in the firmware's
 * 150 MHz ticks, interrupt masking). UART0's receive interrupt feeds the link's receiver; the main
 * loop handles a complete frame, writes the reply by polling the transmit buffer, and sleeps (WFI)
 * while it waits for a byte. The build's settings are compiled in (foc_config.h, -DFOC_CFG_*).
 */
#include "foc_hrt.h"
#include "hrt_link.h"
#include "m4_port.h"

static hrt_link_t link_state;

static void on_rx(uint8_t byte)
{
    (void)hrt_link_rx_byte(&link_state, byte);
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
    return (uint32_t)(m4_clock_ticks() * 6u); /* 25 MHz -> the firmware's 150 MHz ticks (wraps) */
}

int main(void)
{
    hrt_link_init(&link_state, hrt_firmware_init()); /* the build's settings (foc_config.h) */
    m4_init(on_rx);
    for (;;) {
        hrt_link_poll(&link_state);
        m4_irq_off();
        if (!link_state.rx.ready) {
            m4_wait_for_interrupt(); /* a byte, or SysTick's millisecond for the watchdog */
        }
        m4_irq_on();
    }
}
