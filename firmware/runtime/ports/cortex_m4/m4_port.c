/* m4_port.c: UART0, the clock, interrupt masking on the MPS2 AN386 (see m4_port.h). */
#include "m4_port.h"

#include "cmsdk.h"

static void (*rx_handler)(uint8_t byte);
static volatile uint32_t clock_wraps; /* timer 0 reached zero this many times */

void m4_irq_off(void)
{
    __asm__ volatile("cpsid i" ::: "memory");
}

void m4_irq_on(void)
{
    __asm__ volatile("cpsie i" ::: "memory");
}

void m4_wait_for_interrupt(void)
{
    __asm__ volatile("wfi" ::: "memory");
}

void UART0RX_Handler(void);
void TIMER0_Handler(void);
void SysTick_Handler(void);

void SysTick_Handler(void)
{
    /* nothing: it only ends the main loop's WFI once a millisecond (watchdog checks) */
}

void UART0RX_Handler(void)
{
    /* clear first, then drain: a byte that lands after the last look raises the interrupt again */
    UART0_INTCLEAR = UART_INT_RX;
    while (UART0_STATE & UART_STATE_RX_FULL) {
        uint8_t byte = (uint8_t)(UART0_DATA & 0xFFu);
        if (rx_handler != 0) {
            rx_handler(byte);
        }
    }
}

void TIMER0_Handler(void)
{
    TIMER0_INTCLEAR = 1u;
    clock_wraps = clock_wraps + 1u;
}

void m4_init(void (*on_rx)(uint8_t byte))
{
    rx_handler = on_rx;
    UART0_BAUDDIV = MPS2_SYSCLK_HZ / M4_UART_BAUD;
    UART0_CTRL = UART_CTRL_TX_EN | UART_CTRL_RX_EN | UART_CTRL_RX_IRQ_EN;
    /* Empty the receiver once. In QEMU this read is also what tells the character backend that
     * the UART takes bytes now: its host side is not polled while RX is disabled, and enabling RX
     * alone does not wake it, so bytes sent before this point would wait forever. */
    (void)UART0_DATA;
    TIMER0_CTRL = 0u;
    TIMER0_RELOAD = 0xFFFFFFFFUL;
    TIMER0_VALUE = 0xFFFFFFFFUL;
    TIMER0_INTCLEAR = 1u;
    TIMER0_CTRL = TIMER_CTRL_EN | TIMER_CTRL_IRQ_EN;
    SYST_RVR = M4_CLOCK_HZ / 1000u - 1u; /* 1 kHz on the core clock */
    SYST_CVR = 0u;
    SYST_CSR = 0x7u;                     /* enable, interrupt, core clock */
    NVIC_IPR_BYTE(UART0_RX_IRQ) = 0x40u; /* the UART above the clock's wrap: bytes are never lost */
    NVIC_IPR_BYTE(TIMER0_IRQ) = 0x80u;
    NVIC_ISER0 = (1UL << UART0_RX_IRQ) | (1UL << TIMER0_IRQ);
    m4_irq_on();
}

void m4_uart_write(const uint8_t *bytes, uint16_t len)
{
    uint16_t i;
    for (i = 0u; i < len; i++) {
        while (UART0_STATE & UART_STATE_TX_FULL) {
        }
        UART0_DATA = bytes[i];
    }
}

uint64_t m4_clock_ticks(void)
{
    uint32_t wraps, value, pending, again;
    do { /* a wrap interrupt served between the reads is seen as a change of the count */
        wraps = clock_wraps;
        value = TIMER0_VALUE;
        pending = TIMER0_INTCLEAR & 1u;
        again = clock_wraps;
    } while (wraps != again);
    if (pending != 0u && value >= 0x80000000UL) {
        /* the counter wrapped before the read but its interrupt has not run yet (interrupts masked,
         * or taken a few instructions late): count that wrap here, or the clock would step back
         * 2^32 ticks (171.8 s) */
        wraps += 1u;
    }
    return ((uint64_t)wraps << 32) | (uint64_t)(0xFFFFFFFFUL - value);
}
