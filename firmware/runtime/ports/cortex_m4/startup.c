/* startup.c: the Cortex-M4 vector table and reset code for the MPS2 AN386 (QEMU mps2-an386).
 *
 * Reset copies .data from its load address in the code memory, clears .bss and calls main; a
 * fault or an unexpected interrupt parks the core in a loop (the bench's watchdog sees silence).
 * Written for hilbench: the ARMv7-M vector layout (SP, then 15 system exceptions, then the
 * external interrupts; AN386: UART0 RX = IRQ 0, TX = IRQ 1, timer 0 = IRQ 8). */
#include <stdint.h>

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;
int main(void);

void Reset_Handler(void);
void Default_Handler(void);
void UART0RX_Handler(void) __attribute__((weak, alias("Default_Handler")));
void TIMER0_Handler(void) __attribute__((weak, alias("Default_Handler")));
void SysTick_Handler(void) __attribute__((weak, alias("Default_Handler")));

#define N_IRQ 32u

typedef struct {
    uint32_t *initial_sp;
    void (*exception[15])(void); /* Reset .. SysTick */
    void (*irq[N_IRQ])(void);
} vector_table_t;

__attribute__((section(".isr_vector"), used)) const vector_table_t vector_table = {
    &_estack,
    {
        Reset_Handler, Default_Handler, Default_Handler, Default_Handler, Default_Handler, Default_Handler,
        0, 0, 0, 0, Default_Handler, Default_Handler, 0, Default_Handler, SysTick_Handler,
    },
    {
        UART0RX_Handler, Default_Handler, Default_Handler, Default_Handler, Default_Handler, Default_Handler,
        Default_Handler, Default_Handler, TIMER0_Handler, Default_Handler, Default_Handler, Default_Handler,
        Default_Handler, Default_Handler, Default_Handler, Default_Handler, Default_Handler, Default_Handler,
        Default_Handler, Default_Handler, Default_Handler, Default_Handler, Default_Handler, Default_Handler,
        Default_Handler, Default_Handler, Default_Handler, Default_Handler, Default_Handler, Default_Handler,
        Default_Handler, Default_Handler,
    },
};

void Reset_Handler(void)
{
    uint32_t *src = &_sidata;
    uint32_t *dst = &_sdata;
    while (dst < &_edata) {
        *dst++ = *src++;
    }
    for (dst = &_sbss; dst < &_ebss; dst++) {
        *dst = 0u;
    }
    (void)main();
    for (;;) {
    }
}

void Default_Handler(void)
{
    for (;;) {
    }
}
