/* hostcheck/sfr.c: storage for the SFRs that hostcheck/xc.h declares, so that a host (or avr-gcc)
 * build of the dsPIC30F2010 port links; used only by tests/test_firmware_dspic.py. */
#include "xc.h"

#define SFR(name) volatile uint16_t name
#define BITS(name) volatile name##BITS name##bits

SFR(IFS0); SFR(IFS2); SFR(IEC0); SFR(IEC2); SFR(IPC2);
BITS(IFS0); BITS(IEC0); BITS(IFS2); BITS(IEC2); BITS(IPC2);
SFR(U1MODE); SFR(U1STA); SFR(U1BRG); SFR(U1TXREG); SFR(U1RXREG);
BITS(U1STA);
SFR(PTCON); SFR(PTPER); SFR(SEVTCMP); SFR(PWMCON1); SFR(PWMCON2); SFR(DTCON1); SFR(FLTACON); SFR(OVDCON);
SFR(PDC1); SFR(PDC2); SFR(PDC3);
SFR(T1CON); SFR(TMR1); SFR(PR1); SFR(T2CON); SFR(T3CON); SFR(TMR3); SFR(TMR3HLD); SFR(PR2); SFR(PR3);
#if HOSTCHECK_TMR2_LATCHES
static volatile uint16_t tmr2;
volatile uint16_t *hostcheck_tmr2(void)
{
    TMR3HLD = TMR3;
    return &tmr2;
}
#else
SFR(TMR2);
#endif
SFR(ADCON1); SFR(ADCON2); SFR(ADCON3); SFR(ADCHS); SFR(ADPCFG); SFR(ADCBUF0);
SFR(TRISB); SFR(TRISC); SFR(PORTC); SFR(TRISE); SFR(TRISF); SFR(LATF);
BITS(PORTC);
SFR(IFS1); SFR(IEC1); BITS(IFS1); BITS(IEC1);
SFR(IC7CON); SFR(IC8CON); SFR(IC7BUF); SFR(IC8BUF); SFR(CNEN1); SFR(PORTB);
BITS(IC7CON); BITS(IC8CON);
SFR(SR);
