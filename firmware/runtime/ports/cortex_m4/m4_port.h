/* m4_port.h: what a firmware's Cortex-M4 port needs of the MPS2 AN386 board (QEMU's mps2-an386):
 * UART0 byte I/O with a receive interrupt, a free-running clock, interrupt masking and sleep.
 * The startup code (startup.c) and the memory map (mps2_an386.ld) are this folder's too. */
#ifndef HIL_M4_PORT_H
#define HIL_M4_PORT_H

#include <stdint.h>

#define M4_CLOCK_HZ 25000000UL          /* the clock's tick rate (PCLK) */
#define M4_UART_BAUD 1562500UL          /* PCLK / 16, the fastest BAUDDIV allows */

/* UART0 on (8N1), its RX interrupt calling on_rx(byte) for every received byte; timer 0 as the
 * clock; SysTick at 1 kHz (it only wakes a sleeping main loop, for a watchdog); then interrupts on. */
void m4_init(void (*on_rx)(uint8_t byte));
/* Send bytes (waits while the transmit buffer is full). */
void m4_uart_write(const uint8_t *bytes, uint16_t len);
/* Ticks of M4_CLOCK_HZ since m4_init, 64 bits (timer 0 counts 32, its wrap interrupt the rest). */
uint64_t m4_clock_ticks(void);
/* Mask / unmask every interrupt (PRIMASK); nestable by the caller's own discipline. */
void m4_irq_off(void);
void m4_irq_on(void);
/* Sleep until an interrupt (WFI); returns after its handler ran. */
void m4_wait_for_interrupt(void);

#endif /* HIL_M4_PORT_H */
