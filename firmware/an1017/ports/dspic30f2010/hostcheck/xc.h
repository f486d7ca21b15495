/* hostcheck/xc.h: a register-definition header standing in for XC16's <xc.h> / <p30F2010.h>, so
 * that the dsPIC30F2010 port compiles with host gcc in CI (XC16 is not installable there).
 *
 * Written for the test from the dsPIC30F2010 data sheet (DS70118) register maps; only the
 * registers and bits the port uses. Each SFR is a plain volatile object (host RAM, not the chip's
 * SFR space) and each *bits struct names its fields at their data-sheet positions. A build with
 * XC16 never sees this file: it takes Microchip's header, which is the authority on the chip.
 */
#ifndef HOSTCHECK_XC_H
#define HOSTCHECK_XC_H

#include <stdint.h>

#define HOSTCHECK_SFR(name) extern volatile uint16_t name
#define HOSTCHECK_BITS(name, fields) \
    typedef struct { fields } name##BITS; \
    extern volatile name##BITS name##bits

/* ---- configuration words (legacy C30 macros): no code on the host ---- */
#define _FOSC(x) extern int hostcheck_fosc_unused
#define _FWDT(x) extern int hostcheck_fwdt_unused
#define _FBORPOR(x) extern int hostcheck_fborpor_unused
#define _FGS(x) extern int hostcheck_fgs_unused
#define CSW_FSCM_OFF 0xFFFFu
#define XT_PLL16 0xFFFFu
#define WDT_OFF 0xFFFFu
#define PBOR_OFF 0xFFFFu
#define MCLR_EN 0xFFFFu
#define CODE_PROT_OFF 0xFFFFu

/* ---- interrupts ---- */
HOSTCHECK_SFR(IFS0);
HOSTCHECK_SFR(IFS1);
HOSTCHECK_SFR(IFS2);
HOSTCHECK_SFR(IEC0);
HOSTCHECK_SFR(IEC1);
HOSTCHECK_SFR(IEC2);
HOSTCHECK_SFR(IPC2);
HOSTCHECK_BITS(IFS0, unsigned INT0IF : 1; unsigned IC1IF : 1; unsigned OC1IF : 1; unsigned T1IF : 1;
               unsigned IC2IF : 1; unsigned OC2IF : 1; unsigned T2IF : 1; unsigned T3IF : 1; unsigned SPI1IF : 1;
               unsigned U1RXIF : 1; unsigned U1TXIF : 1; unsigned ADIF : 1; unsigned NVMIF : 1;
               unsigned SI2CIF : 1; unsigned MI2CIF : 1; unsigned CNIF : 1;);
HOSTCHECK_BITS(IEC0, unsigned INT0IE : 1; unsigned IC1IE : 1; unsigned OC1IE : 1; unsigned T1IE : 1;
               unsigned IC2IE : 1; unsigned OC2IE : 1; unsigned T2IE : 1; unsigned T3IE : 1; unsigned SPI1IE : 1;
               unsigned U1RXIE : 1; unsigned U1TXIE : 1; unsigned ADIE : 1; unsigned NVMIE : 1;
               unsigned SI2CIE : 1; unsigned MI2CIE : 1; unsigned CNIE : 1;);
HOSTCHECK_BITS(IFS1, unsigned INT1IF : 1; unsigned IC7IF : 1; unsigned IC8IF : 1; unsigned : 13;);
HOSTCHECK_BITS(IEC1, unsigned INT1IE : 1; unsigned IC7IE : 1; unsigned IC8IE : 1; unsigned : 13;);
HOSTCHECK_BITS(IFS2, unsigned : 7; unsigned PWMIF : 1; unsigned QEIIF : 1; unsigned : 2; unsigned FLTAIF : 1;
               unsigned : 4;);
HOSTCHECK_BITS(IEC2, unsigned : 7; unsigned PWMIE : 1; unsigned QEIIE : 1; unsigned : 2; unsigned FLTAIE : 1;
               unsigned : 4;);
HOSTCHECK_BITS(IPC2, unsigned SPI1IP : 3; unsigned : 1; unsigned U1RXIP : 3; unsigned : 1; unsigned U1TXIP : 3;
               unsigned : 1; unsigned ADIP : 3; unsigned : 1;);

/* ---- UART1 ---- */
HOSTCHECK_SFR(U1MODE);
HOSTCHECK_SFR(U1STA);
HOSTCHECK_SFR(U1BRG);
HOSTCHECK_SFR(U1TXREG);
HOSTCHECK_SFR(U1RXREG);
HOSTCHECK_BITS(U1STA, unsigned URXDA : 1; unsigned OERR : 1; unsigned FERR : 1; unsigned PERR : 1;
               unsigned RIDLE : 1; unsigned ADDEN : 1; unsigned URXISEL : 2; unsigned TRMT : 1; unsigned UTXBF : 1;
               unsigned UTXEN : 1; unsigned UTXBRK : 1; unsigned : 3; unsigned UTXISEL : 1;);

/* ---- motor-control PWM ---- */
HOSTCHECK_SFR(PTCON);
HOSTCHECK_SFR(PTPER);
HOSTCHECK_SFR(SEVTCMP);
HOSTCHECK_SFR(PWMCON1);
HOSTCHECK_SFR(PWMCON2);
HOSTCHECK_SFR(DTCON1);
HOSTCHECK_SFR(FLTACON);
HOSTCHECK_SFR(OVDCON);
HOSTCHECK_SFR(PDC1);
HOSTCHECK_SFR(PDC2);
HOSTCHECK_SFR(PDC3);

/* ---- timers ---- */
HOSTCHECK_SFR(T1CON);
HOSTCHECK_SFR(TMR1);
HOSTCHECK_SFR(PR1);
HOSTCHECK_SFR(T2CON);
HOSTCHECK_SFR(T3CON);
HOSTCHECK_SFR(TMR3);
HOSTCHECK_SFR(TMR3HLD);
#if defined(__MSP430__)
HOSTCHECK_SFR(TMR2); /* make size: a plain load, as the chip's one instruction */
#else
/* The host tests: reading TMR2 latches TMR3 into TMR3HLD as the chip does for a 32-bit timer (DS70046),
 * so a clock that read TMR3HLD before TMR2 would read a stale high word there too. (Writes go through
 * the same accessor; the latch is then harmless.) */
#define HOSTCHECK_TMR2_LATCHES 1
volatile uint16_t *hostcheck_tmr2(void);
#define TMR2 (*hostcheck_tmr2())
#endif
HOSTCHECK_SFR(PR2);
HOSTCHECK_SFR(PR3);

/* ---- ADC ---- */
HOSTCHECK_SFR(ADCON1);
HOSTCHECK_SFR(ADCON2);
HOSTCHECK_SFR(ADCON3);
HOSTCHECK_SFR(ADCHS);
HOSTCHECK_SFR(ADPCFG);
HOSTCHECK_SFR(ADCBUF0);

/* ---- input capture and change notification (the real-motor build's halls) ----
 * ICxCON: ICM 2:0 (001 = every edge), ICBNE 3, ICOV 4, ICI 6:5, ICTMR 7 (1 = TMR2, 0 = TMR3), ICSIDL 13
 * (Family Reference Manual DS70062, Input Capture). IFS1/IEC1's INT1, IC7, IC8 bit positions are as
 * recalled from the data sheet's interrupt table and not checked against p30F2010.h here: this
 * compile check needs only the names, which XC16's header defines. */
HOSTCHECK_SFR(IC7CON);
HOSTCHECK_SFR(IC8CON);
HOSTCHECK_SFR(IC7BUF);
HOSTCHECK_SFR(IC8BUF);
HOSTCHECK_SFR(CNEN1);
HOSTCHECK_BITS(IC7CON, unsigned ICM : 3; unsigned ICBNE : 1; unsigned ICOV : 1; unsigned ICI : 2; unsigned ICTMR : 1;
               unsigned : 5; unsigned ICSIDL : 1; unsigned : 2;);
HOSTCHECK_BITS(IC8CON, unsigned ICM : 3; unsigned ICBNE : 1; unsigned ICOV : 1; unsigned ICI : 2; unsigned ICTMR : 1;
               unsigned : 5; unsigned ICSIDL : 1; unsigned : 2;);

/* ---- ports ---- */
HOSTCHECK_SFR(TRISB);
HOSTCHECK_SFR(PORTB);
HOSTCHECK_SFR(TRISC);
HOSTCHECK_SFR(PORTC);
HOSTCHECK_SFR(TRISE);
HOSTCHECK_SFR(TRISF);
HOSTCHECK_SFR(LATF);
HOSTCHECK_BITS(PORTC, unsigned : 13; unsigned RC13 : 1; unsigned RC14 : 1; unsigned : 1;);

/* ---- CPU ---- */
HOSTCHECK_SFR(SR);
#define Nop() ((void)0)
#define ClrWdt() ((void)0)
#define Idle() ((void)0)

#endif /* HOSTCHECK_XC_H */
