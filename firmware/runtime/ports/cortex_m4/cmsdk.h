/* cmsdk.h: the registers of the Arm MPS2 AN386 image (Cortex-M4, CMSDK peripherals) this port uses,
 * as QEMU's mps2-an386 machine models them (hw/arm/mps2.c, hw/char/cmsdk-apb-uart.c,
 * hw/timer/cmsdk-apb-timer.c) and Arm's AN386 and CMSDK documentation describe them.
 * Written for hilbench; addresses and bit numbers are facts, the layout is ours. */
#ifndef HIL_CMSDK_H
#define HIL_CMSDK_H

#include <stdint.h>

#define HIL_REG(addr) (*(volatile uint32_t *)(addr))

#define MPS2_SYSCLK_HZ 25000000UL      /* SYSCLK = PCLK of the APB peripherals */

/* CMSDK APB UART0 (APB, 0x40004000): RX interrupt IRQ 0, TX interrupt IRQ 1 */
#define UART0_BASE 0x40004000UL
#define UART0_DATA HIL_REG(UART0_BASE + 0x00u)
#define UART0_STATE HIL_REG(UART0_BASE + 0x04u)     /* bit0 TX buffer full, bit1 RX buffer full */
#define UART0_CTRL HIL_REG(UART0_BASE + 0x08u)      /* bit0 TX en, bit1 RX en, bit2 TX irq en, bit3 RX irq en */
#define UART0_INTCLEAR HIL_REG(UART0_BASE + 0x0Cu) /* INTSTATUS: read pending, write 1 to clear */
#define UART0_BAUDDIV HIL_REG(UART0_BASE + 0x10u)   /* PCLK / baud, at least 16 */
#define UART_STATE_TX_FULL 0x1u
#define UART_STATE_RX_FULL 0x2u
#define UART_CTRL_TX_EN 0x1u
#define UART_CTRL_RX_EN 0x2u
#define UART_CTRL_RX_IRQ_EN 0x8u
#define UART_INT_RX 0x2u
#define UART0_RX_IRQ 0u

/* CMSDK APB timer 0 (0x40000000): a 32-bit down counter at PCLK, IRQ 8 when it reaches zero */
#define TIMER0_BASE 0x40000000UL
#define TIMER0_CTRL HIL_REG(TIMER0_BASE + 0x00u)    /* bit0 enable, bit3 interrupt enable */
#define TIMER0_VALUE HIL_REG(TIMER0_BASE + 0x04u)
#define TIMER0_RELOAD HIL_REG(TIMER0_BASE + 0x08u)
#define TIMER0_INTCLEAR HIL_REG(TIMER0_BASE + 0x0Cu) /* INTSTATUS: read bit0 pending, write 1 to clear */
#define TIMER_CTRL_EN 0x1u
#define TIMER_CTRL_IRQ_EN 0x8u
#define TIMER0_IRQ 8u

/* Cortex-M4 system control space */
#define NVIC_ISER0 HIL_REG(0xE000E100UL)               /* write 1: enable IRQ n (n < 32) */
#define NVIC_IPR_BYTE(n) (*(volatile uint8_t *)(0xE000E400UL + (n)))
#define SYST_CSR HIL_REG(0xE000E010UL)                 /* SysTick: bit0 enable, bit1 tick irq, bit2 core clock */
#define SYST_RVR HIL_REG(0xE000E014UL)
#define SYST_CVR HIL_REG(0xE000E018UL)

#endif /* HIL_CMSDK_H */
