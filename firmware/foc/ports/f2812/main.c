/* ports/f2812/main.c: the FOC firmware on the TMS320F2812 it was written for, on the hilbench runtime,
 * under the bench (hardware in the loop: the servo, its encoder and its currents are the bench's plant).
 *
 * The same firmware source (firmware/foc) as every other build; this file is the runtime's port
 * (byte I/O on SCI-A, the clock, interrupt glue) and the chip's set-up. Register values are the
 * facts of docs/foc.md (TI's F281x drivers and reference guides; no TI code):
 * - Clock: 30 MHz crystal, PLLCR = 10: SYSCLKOUT = 150 MHz; HSPCLK = 150 MHz (HISPCP = 0): the
 *   Event Manager's clock and the firmware's ticks; LSPCLK = 37.5 MHz (LOSPCP = 2) for SCI-A.
 * - SCI-A (GPIOF4/F5) at 8N1, BRR = 18: 37.5 MHz / (8 * 19) = 246 711 baud (-1.3 % from the bench's
 *   250 000), 16-level FIFOs; its receive interrupt (PIE 9.1) feeds the link's receiver, the main
 *   loop handles frames.
 * - CPU timer 0 counts down from 2^32 - 1 at 150 MHz: 2^32 - 1 - TIM is the clock in the firmware's
 *   ticks, wrapping at 2^32 as the runtime wants.
 * - EV-A timer 1: continuous up/down, T1PR = 7500 (10 kHz), COMCONA = 0xA200 (CMPRx reload at
 *   underflow and period), DBTCONA = 0x0FF4 (3.2 us dead band), ACTRA = 0x0666 (PWM1/3/5 active
 *   high, 2/4/6 active low) only with HIL_DRIVE_BRIDGE, else 0x0000 (all six forced low: under the
 *   bench the plant is simulated and the power stage must stay off). T2 in directional QEP mode,
 *   T2PR = 10000, CAPCONA = 0x9004 (CAP1/2 QEP, CAP3 the index on rising edges).
 * Lockstep: the EV interrupts stay off; each Sensors runs one span of virtual time (hrt_link).
 * Real time (HRT_PORT_HW): T1UFINT runs hrt_rt_pwm (the underflow ISR body), whose compare values
 * go to CMPR1..3 (the hardware loads them at the period match); T1PINT runs hrt_rt_reload (the
 * runtime's model of that reload); CAPINT3 the index edge. The ADC codes and the encoder count come from Sensors
 * (the plant's), unless HIL_LOCAL_SENSORS reads ADCRESULT0..2 and T2CNT.
 *
 * Build: TI's C2000 compiler with TI's DSP281x headers (not available here); CI compiles this file
 * with host gcc and clang against hostcheck/ (tests/test_foc_builds.py).
 */
#include "DSP281x_Device.h"
#include "foc_hrt.h"
#include "hrt_link.h"

#if defined(HIL_DRIVE_BRIDGE) && !defined(HIL_LOCAL_SENSORS)
/* Under the bench the currents and the encoder are the plant's: a build that switches a real
 * bridge must not do so from simulated sensors. */
#error "HIL_DRIVE_BRIDGE needs HIL_LOCAL_SENSORS: the bridge is never switched from the bench's simulated sensors"
#endif

#define SCI_BRR 18u
#define T1CON_UPDOWN 0x0842u /* TMODE continuous up/down, TENABLE, TECMPR, prescale 1 */
#define T2CON_QEP 0x1870u    /* TMODE directional up/down, TENABLE, clock and direction from the QEP */
#define ACTRA_DRIVE 0x0666u
#define ACTRA_OFF 0x0000u

static hrt_t *rt;         /* the firmware's (hrt_firmware_init) */
static hrt_link_t host_link;

/* ---------------------------------------------------------------------------- the port */

void hrt_port_send(const hbp_u8 *wire, hbp_u8 len)
{
    unsigned i;
    for (i = 0u; i < len; i++) {
        while (SciaRegs.SCIFFTX.bit.TXFFST >= 15u) { /* room in the 16-level FIFO */
        }
        SciaRegs.SCITXBUF = (Uint16)(wire[i] & 0xFFu); /* one octet in bits 7:0 */
    }
}

uint32_t hrt_port_now(void)
{
    return 0xFFFFFFFFUL - CpuTimer0Regs.TIM;
}

static Uint16 saved_ier;

void hrt_port_lock(void)
{
    saved_ier = IER;
    IER = (Uint16)(IER & (Uint16)~(M_INT2 | M_INT3)); /* the motor ISRs; SCI-A keeps receiving */
}

void hrt_port_unlock(void)
{
    IER = saved_ier;
}

hbp_u8 hrt_port_timer(hbp_u8 id, hbp_u8 on, uint32_t first_ticks)
{
    (void)id;
    (void)on;
    (void)first_ticks;
    return 0u; /* the firmware declares no timers */
}

void hrt_port_realtime(hbp_u8 on)
{
    EvaRegs.EVAIFRA.all = EVA_T1UFINT | EVA_T1PINT;
    EvaRegs.EVAIFRC.all = EVA_CAP3INT;
    if (on) {
        IER = (Uint16)(IER | M_INT2 | M_INT3);
    } else {
        IER = (Uint16)(IER & (Uint16)~(M_INT2 | M_INT3));
    }
}

/* ---------------------------------------------------------------------------- interrupts */

/* The compare shadows the ISR wrote, clamped to a 16-bit CMPR (above T1PR never matches). */
static void write_compares(void)
{
#if defined(HIL_DRIVE_BRIDGE)
    const int32_t *c = ((const foc_app_t *)(const void *)rt)->foc.compare_shadow;
    EvaRegs.CMPR1 = (Uint16)(c[0] > FOC_T1PR ? FOC_T1PR + 1 : c[0]);
    EvaRegs.CMPR2 = (Uint16)(c[1] > FOC_T1PR ? FOC_T1PR + 1 : c[1]);
    EvaRegs.CMPR3 = (Uint16)(c[2] > FOC_T1PR ? FOC_T1PR + 1 : c[2]);
#endif
}

interrupt void isr_t1_underflow(void)
{
#if defined(HIL_LOCAL_SENSORS)
    Uint16 adc[3];
    adc[0] = (Uint16)(AdcRegs.ADCRESULT0 >> 4);
    adc[1] = (Uint16)(AdcRegs.ADCRESULT1 >> 4);
    adc[2] = (Uint16)(AdcRegs.ADCRESULT2 >> 4);
    hrt_rt_levels(rt, hrt_inputs(rt), adc, 3u, EvaRegs.T2CNT);
#endif
    hrt_rt_pwm(rt, hrt_port_now());
    write_compares();
    EvaRegs.EVAIFRA.all = EVA_T1UFINT;
    PieCtrlRegs.PIEACK.all = PIEACK_GROUP2;
}

interrupt void isr_t1_period(void)
{
    hrt_rt_reload(rt, hrt_port_now());
    EvaRegs.EVAIFRA.all = EVA_T1PINT;
    PieCtrlRegs.PIEACK.all = PIEACK_GROUP2;
}

interrupt void isr_index(void)
{
    hrt_rt_edge(rt, HRT_IN_INDEX, hrt_port_now());
    EvaRegs.EVAIFRC.all = EVA_CAP3INT;
    PieCtrlRegs.PIEACK.all = PIEACK_GROUP3;
}

interrupt void isr_sci_rx(void)
{
    while (SciaRegs.SCIFFRX.bit.RXFFST != 0u) {
        (void)hrt_link_rx_byte(&host_link, (hbp_u8)(SciaRegs.SCIRXBUF.all & 0xFFu));
    }
    SciaRegs.SCIFFRX.bit.RXFFOVRCLR = 1u;
    SciaRegs.SCIFFRX.bit.RXFFINTCLR = 1u;
    PieCtrlRegs.PIEACK.all = PIEACK_GROUP9;
}

/* ---------------------------------------------------------------------------- set-up */

static void init_system(void)
{
    EALLOW;
    SysCtrlRegs.WDCR = 0x0068u;   /* watchdog off */
    SysCtrlRegs.PLLCR = 0x000Au;  /* 30 MHz x 10 / 2 = 150 MHz */
    SysCtrlRegs.HISPCP = 0x0000u; /* HSPCLK = SYSCLKOUT */
    SysCtrlRegs.LOSPCP = 0x0002u; /* LSPCLK = SYSCLKOUT / 4 */
    SysCtrlRegs.PCLKCR = 0x0409u; /* EVA, ADC, SCI-A clocks on */
    GpioMuxRegs.GPAMUX = 0x073Fu; /* PWM1..6, CAP1_QEP1, CAP2_QEP2, CAP3_QEPI1 */
    GpioMuxRegs.GPFMUX = 0x0030u; /* SCITXDA, SCIRXDA */
    PieVectTable.T1UFINT = &isr_t1_underflow;
    PieVectTable.T1PINT = &isr_t1_period;
    PieVectTable.CAPINT3 = &isr_index;
    PieVectTable.RXAINT = &isr_sci_rx;
    EDIS;
    CpuTimer0Regs.TCR = 0x0010u;  /* stopped */
    CpuTimer0Regs.PRD = 0xFFFFFFFFUL;
    CpuTimer0Regs.TPR = 0u;
    CpuTimer0Regs.TPRH = 0u;
    CpuTimer0Regs.TCR = 0x0020u;  /* reload, then run */
}

static void init_sci(void)
{
    SciaRegs.SCICCR.all = 0x0007u; /* 1 stop bit, no parity, 8 bits */
    SciaRegs.SCICTL1.all = 0x0003u;
    SciaRegs.SCIHBAUD = 0u;
    SciaRegs.SCILBAUD = SCI_BRR;
    SciaRegs.SCIFFTX.all = 0xE040u; /* FIFOs on, TX FIFO out of reset */
    SciaRegs.SCIFFRX.all = 0x2061u; /* RX FIFO out of reset, interrupt at 1 byte */
    SciaRegs.SCIFFCT.all = 0x0000u;
    SciaRegs.SCICTL1.all = 0x0023u; /* out of reset */
}

static void init_event_manager(void)
{
    EvaRegs.T1PR = FOC_T1PR;
    EvaRegs.T1CNT = 0u;
    EvaRegs.DBTCONA.all = 0x0FF4u;
    EvaRegs.COMCONA.all = 0xA200u;
    EvaRegs.CMPR1 = FOC_T1PR; /* no on-time */
    EvaRegs.CMPR2 = FOC_T1PR;
    EvaRegs.CMPR3 = FOC_T1PR;
#if defined(HIL_DRIVE_BRIDGE)
    EvaRegs.ACTRA.all = ACTRA_DRIVE;
#else
    EvaRegs.ACTRA.all = ACTRA_OFF;
#endif
    EvaRegs.T2PR = 10000u;
    EvaRegs.T2CNT = 0u;
    EvaRegs.CAPCONA.all = 0x9004u;
    EvaRegs.T2CON.all = T2CON_QEP;
    EvaRegs.EVAIMRA.all = EVA_T1UFINT | EVA_T1PINT;
    EvaRegs.EVAIMRC.all = EVA_CAP3INT;
    EvaRegs.T1CON.all = T1CON_UPDOWN;
    PieCtrlRegs.PIEIER2 = PIE_GROUP2_T1UFINT | PIE_GROUP2_T1PINT;
    PieCtrlRegs.PIEIER3 = PIE_GROUP3_CAPINT3;
    PieCtrlRegs.PIEIER9 = PIE_GROUP9_RXAINT;
    PieCtrlRegs.PIECRTL = 1u;
}

int main(void)
{
    DINT;
    init_system();
    rt = hrt_firmware_init(); /* the build's settings (foc_config.h) */
    hrt_link_init(&host_link, rt);
    init_sci();
    init_event_manager();
    IER = M_INT9; /* SCI-A now; the motor ISRs only in real time (hrt_port_realtime) */
    EINT;
    ERTM;
    for (;;) {
        hrt_link_poll(&host_link);
    }
}
