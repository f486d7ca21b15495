/* firmware/runtime/ports/cortex_m4/hrt_m4.c: any firmware on the runtime on a Cortex-M4 (the Arm
 * MPS2 AN386 image, run in QEMU's mps2-an386 machine), with this folder's board support (startup
 * code, memory map, UART0, clock). The firmware defines hrt_firmware and hrt_firmware_init(); link
 * this file, startup.c, m4_port.c, the firmware, hrt.c, hrt_link.c and firmware_protocol/hbp*.c
 * (the Makefile's goals `foc` and `an1017` do so for those firmwares; `app` for another).
 *
 * The runtime's port: UART0's receive interrupt feeds the link's receiver; the main loop handles a
 * complete frame, writes the reply by polling the transmit buffer, and sleeps (WFI) until a byte or
 * the 1 kHz SysTick (the watchdog's look) wakes it; the clock is timer 0 (25 MHz, 64 bits) in the
 * firmware's ticks.
 */
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
    /* 25 MHz ticks -> the firmware's ticks_per_us MHz, on the 64-bit count; the low 32 bits wrap */
    return (uint32_t)((m4_clock_ticks() * hrt_firmware.ticks_per_us) / (M4_CLOCK_HZ / 1000000u));
}

int main(void)
{
    hrt_link_init(&link_state, hrt_firmware_init());
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
