/* echo.c: the Cortex-M4 port's bring-up program: every byte received on UART0 is sent back, and a
 * byte 0xFF is answered with the clock's 8 low bytes (little endian) instead, and 0xFE with the
 * clock before and after a wrap whose interrupt is held off (16 bytes). Checks the startup code, the
 * UART's receive interrupt and the clock (tests/test_qemu_m4.py). */
#include "cmsdk.h"
#include "m4_port.h"

#define QUEUE 64u

static volatile uint8_t queue[QUEUE];
static volatile uint16_t head, tail;

static void on_rx(uint8_t byte)
{
    uint16_t next = (uint16_t)((head + 1u) % QUEUE);
    if (next != tail) {
        queue[head] = byte;
        head = next;
    }
}

/* the clock's 8 low bytes, little endian */
static void send_ticks(uint64_t t)
{
    uint8_t out[8];
    uint16_t k;
    for (k = 0u; k < 8u; k++) {
        out[k] = (uint8_t)(t >> (8u * k));
    }
    m4_uart_write(out, 8u);
}

int main(void)
{
    m4_init(on_rx);
    for (;;) {
        while (tail != head) {
            uint8_t byte = queue[tail];
            tail = (uint16_t)((tail + 1u) % QUEUE);
            if (byte == 0xFFu) {
                send_ticks(m4_clock_ticks());
            } else if (byte == 0xFEu) {
                /* the clock across a wrap whose interrupt cannot run yet: interrupts masked, the
                 * counter moved to just above zero, read once it has wrapped */
                uint64_t before, after;
                m4_irq_off();
                before = m4_clock_ticks();
                TIMER0_VALUE = 1000u;
                while ((TIMER0_INTCLEAR & 1u) == 0u) {
                }
                after = m4_clock_ticks();
                m4_irq_on();
                send_ticks(before);
                send_ticks(after);
            } else {
                m4_uart_write(&byte, 1u);
            }
        }
        m4_irq_off();
        if (tail == head) {
            m4_irq_on();
            m4_wait_for_interrupt();
        } else {
            m4_irq_on();
        }
    }
}
