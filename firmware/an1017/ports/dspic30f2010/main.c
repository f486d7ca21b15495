/* ports/dspic30f2010/main.c: the AN1017 firmware on a dsPIC30F2010 on the PICDEM MC LV board, under
 * the hilbench bench (hardware in the loop: the motor, its halls and the pot are the bench's plant).
 *
 * Peripherals (register values from the AN1017 v1.1 firmware and the data sheet; see docs/board.md):
 * - Clock: 5 MHz crystal, XT with PLLx16 -> FCY = 20 MHz (Tcy 50 ns).
 * - UART1 on RF2 (U1RX) / RF3 (U1TX), the board's RS-232 (ALTIO = 0): U1BRG = 4 -> 20 MHz / (16 * 5)
 *   = 250 000 baud, exact. The RX interrupt (priority 4, like the motor ISRs: they never nest)
 *   feeds hbp_rx_byte; the main loop handles frames.
 *   RF2/RF3 are also PGC/PGD: debug with the ICD on EMUC2/EMUD2, or unplug the ICD to talk.
 * - MCPWM: PTPER = 499, PTCON = 0x8002 (centre-aligned, 20 kHz), PWMCON1 = 0x0077 (three
 *   complementary pairs), PWMCON2 = 0x0F02 (OSYNC, IUE = 0: duties latch at the period boundary,
 *   SEVOPS 1:16), DTCON1 = 0x0010 (0.8 us dead time). The duties the firmware computes are written
 *   to PDC1..3, but OVDCON keeps all six outputs overridden inactive: under the bench the plant is
 *   simulated and the power stage must stay off (no motor is connected, or one is, and must not be
 *   driven twice). HIL_DRIVE_BRIDGE stops the compiler unless the halls come from the motor (below).
 * - FLTA (RE8, the board's over-current comparator): FLTACON = 0x0007 drives all pairs inactive on
 *   a fault, and its interrupt stops the firmware with state FAULT, fault OVERCURRENT.
 * - Timer1: Tcy/64, PR1 = 313 (1.0048 ms), the speed-loop tick in real-time mode.
 * - Timer2 at Tcy, with an overflow count, is the port's clock (hrt_port_now): the runtime's time in
 *   real time, the capture time of hall edges (the firmware derives TMR3 from it; IC7 itself is not
 *   used: the hall pins are frames) and the watchdog's. A lockstep-only build (HRT_REALTIME=0, the
 *   30F2010's board profile) runs Timer3:Timer2 as one 32-bit timer instead, without an interrupt.
 * - ADC: configured as AN1017 does (AN2 = pot R14, signed fractional, started by the PWM special
 *   event); the pot value comes from Sensors unless HIL_LOCAL_POT is defined, then from ADCBUF0.
 * - S2 (RC14, active low): pressing the board's S2 acts like the Sensors S2 bit.
 * Lockstep: Timer1 stays off (the firmware's timers are gated; in the lockstep profile Timer3 runs as
 * the clock's high word, above); each Sensors runs one period
 * of ISR bodies at their virtual times (the runtime's hrt_span_*). Real time (make PROFILE=full, the
 * 30F4012's default; the 30F2010's lockstep profile, HRT_REALTIME=0, keeps none of it; this port is
 * built with HRT_PORT_HW = 1): the PWM and Timer1 interrupts run the ISR bodies on the chip's own clock
 * through the runtime's real-time glue (hrt_rt_pwm, hrt_rt_timer; the end of ChargeBootstraps is a
 * runtime timer served at PWM-period resolution), and each Sensors updates the inputs they read
 * (a hall edge with its capture time back-dated by the frame's edge time).
 *
 * The real-motor build (make MODE=motor: HIL_LOCAL_HALLS, HIL_DRIVE_BRIDGE, HRT_MONITOR=1) reads the
 * motor's halls as AN1017 does (CN5 on RB3, IC7 on RB4 and IC8 on RB5 capturing TMR2, the Tcy clock),
 * the pot on AN2 and S2 on RC14, runs on the chip's timers from power-on (ChargeBootstraps, then the
 * bridge through OVDCON), FLTA armed, and talks to the host in HostHello mode MONITOR only: a Drive
 * with the declared telemetry every agreed period, gains and the reference override written with the
 * checked parameter protocol, no Sensors taken, the motor stopped when the host goes silent.
 *
 * Build: make (XC16, see Makefile). CI compiles this file with host gcc against hostcheck/xc.h.
 */
#include <xc.h>

#include "an1017.h"
#include "hrt_link.h"

#if !defined(HRT_PORT_HW) || !HRT_PORT_HW
#error "the dsPIC30F2010 port runs real time on the chip's interrupts: build it with -DHRT_PORT_HW=1"
#endif

/* Safety (docs/board.md, "Safety rules of each build"): the six MOSFETs may only be switched by a
 * build that commutates from the motor's own hall sensors (RB3-RB5 through CN5/IC7/IC8). This port
 * takes the halls from the bench's Sensors frames, i.e. from a simulated rotor: a real motor would be
 * commutated from a model. No such build may exist, so the combination stops the compiler. */
#if defined(HIL_DRIVE_BRIDGE) && !defined(HIL_LOCAL_HALLS)
#error "HIL_DRIVE_BRIDGE needs HIL_LOCAL_HALLS: the bridge is never switched from the bench's simulated halls"
#endif
#if defined(HIL_LOCAL_HALLS) && !HRT_MONITOR
#error "HIL_LOCAL_HALLS (the real-motor build) needs HRT_MONITOR=1: the host monitors, it never sends the sensors (make MODE=motor)"
#endif
#if defined(HIL_LOCAL_POT) && !HRT_HW_TIMERS
#error "HIL_LOCAL_POT reads the pot in the real-time PWM interrupt, which a lockstep-only build (HRT_REALTIME=0) has not: make PROFILE=full"
#endif
#if defined(HIL_LOCAL_HALLS) && !defined(HIL_LOCAL_POT)
#define HIL_LOCAL_POT /* the real motor's reference: the board's pot, or the host's override parameter */
#endif

/* `static inline`: a small helper, or one called once, that XC16's -O1 inlines as GCC's does (the
 * dsPIC30F2010's 4K words, docs/board.md section 3a, measured one by one); the others stay calls. */
#if defined(__XC16__)
#define AN1017_ISR __attribute__((__interrupt__, no_auto_psv))
#else
#define AN1017_ISR
#endif

#ifndef AN1017_VARIANT
#define AN1017_VARIANT AN1017_VARIANT_SEED
#endif

_FOSC(CSW_FSCM_OFF & XT_PLL16);
_FWDT(WDT_OFF);
_FBORPOR(PBOR_OFF & MCLR_EN);
_FGS(CODE_PROT_OFF);

#ifndef UART_BRG
#define UART_BRG 4u           /* 250 000 baud at FCY = 20 MHz (docs/board.md: the baud table) */
#endif
#define OVDCON_ALL_OFF 0x0000u
#define OVDCON_PWM 0x3F00u    /* all six outputs from the PWM generator */
#define OVDCON_LOW_SIDE 0x0015u

static an1017_t fw;
static hrt_link_t host_link;
#if HRT_HW_TIMERS
static volatile uint16_t tcy_high; /* Timer2 overflows: bits 31:16 of the Tcy clock */
static uint8_t realtime_on;
#endif

void hrt_port_send(const uint8_t *wire, uint8_t len)
{
    uint8_t i;
    for (i = 0u; i < len; i++) {
        while (U1STAbits.UTXBF) {
        }
        U1TXREG = wire[i];
    }
}

void hrt_port_lock(void)
{
#if HRT_HW_TIMERS
    IEC2bits.PWMIE = 0;
    IEC0bits.T1IE = 0;
#endif
    IEC2bits.FLTAIE = 0;
#if defined(HIL_LOCAL_HALLS)
    IEC0bits.CNIE = 0;
    IEC1bits.IC7IE = 0;
    IEC1bits.IC8IE = 0;
#endif
}

void hrt_port_unlock(void)
{
    IEC2bits.FLTAIE = 1;
#if defined(HIL_LOCAL_HALLS)
    IEC0bits.CNIE = 1;
    IEC1bits.IC7IE = 1;
    IEC1bits.IC8IE = 1;
#endif
#if HRT_HW_TIMERS
    if (realtime_on) {
        IEC0bits.T1IE = 1;
        IEC2bits.PWMIE = 1;
    }
#endif
}

#if HRT_HW_TIMERS
/* Called from the main loop and from the priority-4 ISRs, where the Timer2 interrupt (the same
 * priority) cannot run: an overflow may be pending, not yet counted in tcy_high. A low TMR2 read
 * with T2IF set is after that overflow, so it counts here (else the time would step back 65 536 Tcy
 * and could trip the watchdog). */
uint32_t hrt_port_now(void)
{
    uint16_t high;
    uint16_t low;
    uint8_t pending;
    do {
        high = tcy_high;
        low = TMR2;
        pending = (uint8_t)IFS0bits.T2IF;
    } while (high != tcy_high); /* the Timer2 interrupt ran meanwhile: read again */
    if (pending && low < 0x8000u) {
        high = (uint16_t)(high + 1u); /* an overflow not yet served (a high TMR2 was read before it) */
    }
    return ((uint32_t)high << 16) | low;
}

#else
/* A lockstep-only build (HRT_REALTIME=0) captures nothing with Timer2: Timer2 and Timer3 run as one
 * 32-bit timer (T32) at Tcy, no interrupt. Reading TMR2 latches TMR3 into TMR3HLD, so the two halves
 * are of one instant (dsPIC30F family reference manual DS70046, "32-bit timer"). Safe only because no
 * ISR of this build (UART1 RX, FLTA) calls hrt_port_now: one that read TMR2 between the two reads below
 * would latch TMR3HLD anew, of a later instant. */
uint32_t hrt_port_now(void)
{
    uint16_t low = TMR2; /* first: it latches TMR3HLD */
    return ((uint32_t)TMR3HLD << 16) | low;
}
#endif

static void write_outputs(void)
{
    PDC1 = hrt_duty(&fw.rt, 0u); /* the MCPWM latches them at its period boundary (IUE = 0) */
    PDC2 = hrt_duty(&fw.rt, 1u);
    PDC3 = hrt_duty(&fw.rt, 2u);
#if defined(HIL_DRIVE_BRIDGE)
    OVDCON = (fw.output_mode == AN1017_MODE_PWM) ? OVDCON_PWM
             : (fw.output_mode == AN1017_MODE_LOW_SIDE) ? OVDCON_LOW_SIDE : OVDCON_ALL_OFF;
#else
    OVDCON = OVDCON_ALL_OFF;
#endif
}

/* ---- real time: the chip's timers (a lockstep-only build, HRT_REALTIME=0, has none of it) ---- */
#if HRT_HW_TIMERS

/* Timer1 runs in hardware (PR1 fixed: its period is the declared one); the end of ChargeBootstraps
 * is left to the runtime. */
uint8_t hrt_port_timer(uint8_t id, uint8_t on, uint32_t first_ticks)
{
    (void)first_ticks;
    if (id != AN1017_TIMER_T1) {
        return 0u;
    }
    if (on) {
        TMR1 = 0u;
        IFS0bits.T1IF = 0;
    }
    return 1u;
}

void hrt_port_realtime(uint8_t on)
{
    if (on) {
        TMR1 = 0u;
        T1CON = 0x8020u;
        IFS0bits.T1IF = 0;
        IFS2bits.PWMIF = 0;
        realtime_on = 1u;
    } else {
        IEC2bits.PWMIE = 0;
        IEC0bits.T1IE = 0;
        T1CON = 0x0020u;
        realtime_on = 0u;
    }
}
#endif

/* ---- the real-motor build: the motor's own halls (AN1017's CN5 = A on RB3, IC7 = B on RB4, IC8 = C
 * on RB5; facts: docs/board.md "Real-motor mode") ---- */
#if defined(HIL_LOCAL_HALLS)
static uint8_t halls_now(void)
{
    return (uint8_t)((PORTB >> 3) & 7u); /* bit 0 = RB3 = A, 1 = RB4 = B, 2 = RB5 = C (HRT_IN_HALL_*) */
}

/* A capture of TMR2 (the Tcy clock's low word) as the full clock: the newest time whose low word it
 * is (the ISR runs less than 65 536 Tcy, 3.3 ms, after the edge). */
static uint32_t captured_at(uint16_t capture)
{
    uint32_t now = hrt_port_now();
    return now - (uint16_t)((uint16_t)now - capture);
}

void AN1017_ISR _CNInterrupt(void) /* hall A: CN5 has no capture, the edge is timed here */
{
    IFS0bits.CNIF = 0;
    hrt_rt_edge(&fw.rt, halls_now(), hrt_port_now());
    write_outputs();
}

void AN1017_ISR _IC7Interrupt(void) /* hall B: IC7 captures TMR2 at the edge */
{
    uint16_t capture = IC7BUF;
    IFS1bits.IC7IF = 0;
    while (IC7CONbits.ICBNE) { /* the FIFO's newer captures, as AN1017 flushes it */
        capture = IC7BUF;
    }
    hrt_rt_edge(&fw.rt, halls_now(), captured_at(capture));
    write_outputs();
}

void AN1017_ISR _IC8Interrupt(void) /* hall C */
{
    uint16_t capture = IC8BUF;
    IFS1bits.IC8IF = 0;
    while (IC8CONbits.ICBNE) {
        capture = IC8BUF;
    }
    hrt_rt_edge(&fw.rt, halls_now(), captured_at(capture));
    write_outputs();
}

static void init_halls(void)
{
    IC7CON = 0x0081u;  /* ICTMR = 1 (TMR2, the Tcy clock), ICM = 001: capture every edge */
    IC8CON = 0x0081u;
    CNEN1 = 0x0020u;   /* CN5 (RB3) only, as AN1017 */
    IFS0bits.CNIF = 0;
    IFS1bits.IC7IF = 0;
    IFS1bits.IC8IF = 0;
    fw.rt.in = halls_now(); /* the rotor's position at power-on */
    IEC0bits.CNIE = 1;
    IEC1bits.IC7IE = 1;
    IEC1bits.IC8IE = 1;
}
#endif

/* ---- interrupts ---- */

void AN1017_ISR _U1RXInterrupt(void)
{
    IFS0bits.U1RXIF = 0;
    while (U1STAbits.URXDA) {
        (void)hrt_link_rx_byte(&host_link, (uint8_t)U1RXREG);
    }
    if (U1STAbits.OERR) {
        U1STAbits.OERR = 0; /* the hardware FIFO overflowed: bytes were lost, the CRC will tell */
    }
}

#if HRT_HW_TIMERS
void AN1017_ISR _T2Interrupt(void)
{
    IFS0bits.T2IF = 0;
    tcy_high = (uint16_t)(tcy_high + 1u);
}
#endif

#if HRT_HW_TIMERS
/* Real time only: one PWM period boundary, the same work as the lockstep scheduler's. */
void AN1017_ISR _PWMInterrupt(void)
{
    IFS2bits.PWMIF = 0;
#if defined(HIL_LOCAL_POT)
    fw.rt.adc[0] = (uint16_t)((uint16_t)(ADCBUF0 >> 6) ^ 0x200u); /* signed fractional -> code */
#endif
    hrt_rt_pwm(&fw.rt, hrt_port_now());
    write_outputs();
}

void AN1017_ISR _T1Interrupt(void)
{
    IFS0bits.T1IF = 0;
    hrt_rt_timer(&fw.rt, AN1017_TIMER_T1, hrt_port_now());
}
#endif

void AN1017_ISR _FLTAInterrupt(void)
{
    IFS2bits.FLTAIF = 0;
    an1017_press_stop(&fw, AN1017_STATE_FAULT, AN1017_FAULT_OVERCURRENT);
    write_outputs();
}

/* ---- the board's S2 (RC14, active low): a mechanical contact bounces for a few ms. A lockstep-only
 * build (HRT_REALTIME=0) has none of it: its S2 is the bench's (the Sensors bit, at its time in the
 * span); the board's would act between spans, at no time of the session ---- */
#if HRT_HW_TIMERS

#define S2_STABLE_TCY 400000UL /* 20 ms at FCY = 20 MHz: a level must hold this long to count */

static uint32_t s2_changed_at;
static uint8_t s2_raw_was;

/* Feed the raw pressed level and the time; returns 1 when the debounced level (*level) changed. */
static uint8_t s2_debounced(uint8_t raw, uint32_t now, uint8_t *level)
{
    if (raw != s2_raw_was) {
        s2_raw_was = raw;
        s2_changed_at = now;
        return 0u;
    }
    if (raw != *level && (uint32_t)(now - s2_changed_at) >= S2_STABLE_TCY) {
        *level = raw;
        return 1u;
    }
    return 0u;
}
#endif

/* ---- initialisation ---- */

static inline void init_io(void)
{
    ADPCFG = 0x0038u;  /* RB3..RB5 digital (halls on the board; unused under the bench) */
    TRISB = 0xFFFFu;
    TRISC = 0xFFFFu;   /* RC13 = S3, RC14 = S2 */
    TRISE = 0x0100u;   /* RE8 = FLTA input, PWM pins outputs */
    LATF = 0x0008u;    /* RS-232 idle high */
    TRISF = 0xFFF7u;   /* RF3 = U1TX output, RF2 = U1RX input */
}

static inline void init_uart(void)
{
    U1BRG = UART_BRG;
    U1MODE = 0x8000u;  /* UARTEN, 8N1, ALTIO = 0 (RF2/RF3) */
    U1STA = 0x0400u;   /* UTXEN; interrupt on every received character */
    /* the default priority 4, as the motor interrupts: no nesting, so the stack holds one ISR frame.
     * No byte is lost meanwhile: UART1's 4-character receive FIFO covers 160 us at 250 kbaud, much
     * longer than a PWM or Timer1 ISR body (a few hundred instructions, < 20 us at 20 MIPS) */
    IPC2bits.U1RXIP = 4;
    IFS0bits.U1RXIF = 0;
    IEC0bits.U1RXIE = 1;
}

static inline void init_pwm(void)
{
    PTPER = AN1017_PTPER;
    PWMCON1 = 0x0077u;
    PWMCON2 = 0x0F02u;
    DTCON1 = 0x0010u;
    FLTACON = 0x0007u;
    OVDCON = OVDCON_ALL_OFF;
    PDC1 = AN1017_PTPER;
    PDC2 = AN1017_PTPER;
    PDC3 = AN1017_PTPER;
    SEVTCMP = 1u;
    IFS2bits.FLTAIF = 0;
    IEC2bits.FLTAIE = 1;
    PTCON = 0x8002u;
}

static inline void init_timers(void)
{
    T1CON = 0x0020u;   /* Tcy/64, off until real time starts */
    PR1 = 313u;
    PR2 = 0xFFFFu;
#if HRT_HW_TIMERS
    T2CON = 0x8000u;   /* Tcy, free running: the Tcy clock's low word, overflows counted */
    IFS0bits.T2IF = 0;
    IEC0bits.T2IE = 1;
#else
    PR3 = 0xFFFFu;
    T2CON = 0x8008u;   /* Tcy, T32: Timer3:Timer2 free running, the 32-bit Tcy clock */
#endif
}

static inline void init_adc(void)
{
    ADCHS = 0x0002u;   /* CH0+ = AN2, the pot */
    ADCON3 = 0x0003u;
    ADCON2 = 0x0000u;
    ADCON1 = 0x836Eu;  /* ADON, signed fractional, PWM special-event trigger, auto-sample */
}

int main(void)
{
#if HRT_HW_TIMERS
    uint8_t s2_level = 0u;
#endif
    an1017_init(&fw, AN1017_VARIANT);
    hrt_link_init(&host_link, &fw.rt);
    init_io();
    init_timers();
    init_pwm();
    init_adc();
    init_uart();
#if defined(HIL_LOCAL_HALLS)
    init_halls();
    hrt_rt_enter(&fw.rt, 1u); /* the chip's interrupts run the firmware from power-on */
    hrt_port_realtime(1u);
    hrt_port_unlock();
#endif
    for (;;) {
        hrt_link_poll(&host_link); /* lockstep spans, real-time inputs, parameters, the handshake, the watchdog */
#if defined(HIL_LOCAL_HALLS)
        hrt_link_stream(&host_link); /* monitor mode: the telemetry stream */
#endif
#if HRT_HW_TIMERS
        if (s2_debounced((uint8_t)(PORTCbits.RC14 == 0), hrt_port_now(), &s2_level)) {
            /* the board's own S2: released -> toggle, as main() does */
            hrt_port_lock();
            an1017_main_loop_buttons(&fw, (uint8_t)(s2_level ? AN1017_INPUT_S2 : 0u));
            hrt_port_unlock();
        }
#endif
        hrt_port_lock(); /* a frame, the button or the watchdog may have changed the outputs */
        write_outputs();
        hrt_port_unlock();
    }
}
