/* hostcheck/regs.c: the register blocks of hostcheck/DSP281x_Device.h as host objects, so the
 * F2812 port links on the host (compiled, never run: on the chip these sit at fixed addresses). */
#include "DSP281x_Device.h"

volatile Uint16 IER;
volatile Uint16 IFR;
volatile struct SYS_CTRL_REGS SysCtrlRegs;
volatile struct GPIO_MUX_REGS GpioMuxRegs;
volatile struct PIE_CTRL_REGS PieCtrlRegs;
volatile struct PIE_VECT_TABLE PieVectTable;
volatile struct CPUTIMER_REGS CpuTimer0Regs;
volatile struct EVA_REGS EvaRegs;
volatile struct ADC_REGS AdcRegs;
volatile struct SCI_REGS SciaRegs;
