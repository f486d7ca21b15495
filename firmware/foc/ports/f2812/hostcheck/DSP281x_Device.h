/* hostcheck/DSP281x_Device.h: a register header standing in for TI's DSP281x_Device.h, so that the
 * TMS320F2812 port compiles with a host gcc/clang in CI (TI's C2000 compiler is not available here).
 *
 * Written for the test from the register names and bit positions of TI's F281x reference guides
 * (SPRU078 system control and interrupts, SPRU065 Event Manager, SPRU060 ADC, SPRU051 SCI), only
 * the registers the port uses. A register with fields is a union of `all` and named bits, as TI's
 * header has it; the port writes whole registers (`.all`) with values it spells out, and reads the
 * few status bits by name. Each register block is a plain object in host RAM (on the chip they sit
 * at fixed addresses through the linker command file). A build with TI's compiler never sees this
 * file: it takes TI's header, which is the authority on the chip.
 */
#ifndef HOSTCHECK_DSP281X_DEVICE_H
#define HOSTCHECK_DSP281X_DEVICE_H

#include "c28x_types.h"

/* ---- the C28x compiler's keywords and intrinsics, as no-ops on the host ---- */
#define interrupt
#define EALLOW
#define EDIS
#define EINT
#define DINT
#define ERTM
extern volatile Uint16 IER; /* cregister on the chip */
extern volatile Uint16 IFR;

typedef void (*PINT)(void);

/* ---- system control (SPRU078) ---- */
struct SYS_CTRL_REGS {
    Uint16 PLLCR;   /* DIV: SYSCLKOUT = OSCCLK * DIV / 2 */
    Uint16 HISPCP;  /* HSPCLK = SYSCLKOUT / (2 * HSPCLK), 0: / 1 */
    Uint16 LOSPCP;  /* LSPCLK = SYSCLKOUT / (2 * LSPCLK) */
    Uint16 PCLKCR;  /* peripheral clocks: bit0 EVAENCLK, bit3 ADCENCLK, bit10 SCIAENCLK */
    Uint16 WDCR;    /* 0x0068: watchdog disabled */
};
extern volatile struct SYS_CTRL_REGS SysCtrlRegs;

struct GPIO_MUX_REGS {
    Uint16 GPAMUX;  /* bits 0..5 PWM1..6, 8 CAP1_QEP1, 9 CAP2_QEP2, 10 CAP3_QEPI1 */
    Uint16 GPFMUX;  /* bit 4 SCITXDA, bit 5 SCIRXDA */
};
extern volatile struct GPIO_MUX_REGS GpioMuxRegs;

/* ---- PIE (SPRU078): groups 2 (EV-A timer 1), 3 (EV-A timer 2, captures), 9 (SCI-A) ---- */
struct PIEACK_BITS {
    Uint16 ACK1 : 1; Uint16 ACK2 : 1; Uint16 ACK3 : 1; Uint16 ACK4 : 1; Uint16 ACK5 : 1; Uint16 ACK6 : 1;
    Uint16 ACK7 : 1; Uint16 ACK8 : 1; Uint16 ACK9 : 1; Uint16 ACK10 : 1; Uint16 ACK11 : 1; Uint16 ACK12 : 1;
    Uint16 rsvd : 4;
};
union PIEACK_REG {
    Uint16 all;
    struct PIEACK_BITS bit;
};
struct PIE_CTRL_REGS {
    Uint16 PIECRTL;        /* bit0 ENPIE */
    union PIEACK_REG PIEACK;
    Uint16 PIEIER1, PIEIFR1, PIEIER2, PIEIFR2, PIEIER3, PIEIFR3, PIEIER9, PIEIFR9;
};
extern volatile struct PIE_CTRL_REGS PieCtrlRegs;

struct PIE_VECT_TABLE {
    PINT TINT0;    /* INT1.7 */
    PINT T1PINT;   /* INT2.4: timer 1 period match */
    PINT T1UFINT;  /* INT2.6: timer 1 underflow */
    PINT CAPINT3;  /* INT3.7: CAP3 / QEPI1 */
    PINT RXAINT;   /* INT9.1: SCI-A receive */
};
extern volatile struct PIE_VECT_TABLE PieVectTable;
#define PIE_GROUP2_T1PINT 0x0008u
#define PIE_GROUP2_T1UFINT 0x0020u
#define PIE_GROUP3_CAPINT3 0x0040u
#define PIE_GROUP9_RXAINT 0x0001u
#define M_INT2 0x0002u
#define M_INT3 0x0004u
#define M_INT9 0x0100u
#define PIEACK_GROUP2 0x0002u
#define PIEACK_GROUP3 0x0004u
#define PIEACK_GROUP9 0x0100u

/* ---- CPU timer 0: a 32-bit down counter at SYSCLKOUT (the port's free-running clock) ---- */
struct CPUTIMER_REGS {
    Uint32 TIM;
    Uint32 PRD;
    Uint16 TCR;    /* bit4 TSS (stop), bit5 TRB (reload) */
    Uint16 TPR;
    Uint16 TPRH;
};
extern volatile struct CPUTIMER_REGS CpuTimer0Regs;

/* ---- Event Manager A (SPRU065) ---- */
union EV_REG16 {
    Uint16 all;
};
struct GPTCON_BITS {
    Uint16 T1PIN : 2; Uint16 T2PIN : 2; Uint16 rsvd1 : 2; Uint16 TCMPOE : 1; Uint16 T1TOADC : 2;
    Uint16 T2TOADC : 2; Uint16 rsvd2 : 2; Uint16 T1STAT : 1; Uint16 T2STAT : 1; Uint16 rsvd3 : 1;
};
union GPTCON_REG {
    Uint16 all;
    struct GPTCON_BITS bit;
};
struct EVA_REGS {
    union GPTCON_REG GPTCONA;
    Uint16 T1CNT, T1CMPR, T1PR;
    union EV_REG16 T1CON;   /* TMODE bits 12:11, TPS 10:8, TENABLE 6, TCLKS 5:4, TCLD 3:2, TECMPR 1 */
    Uint16 T2CNT, T2CMPR, T2PR;
    union EV_REG16 T2CON;
    union EV_REG16 EXTCONA;
    union EV_REG16 COMCONA; /* 0xA200: compare enabled, CMPR reload on underflow or period */
    union EV_REG16 ACTRA;   /* output polarity of PWM1..6 */
    union EV_REG16 DBTCONA; /* DBT 11:8, EDBT3..1 7:5, DBTPS 4:2 */
    Uint16 CMPR1, CMPR2, CMPR3;
    union EV_REG16 CAPCONA; /* 0x9004 in the QEP driver: CAP1/CAP2 as QEP, CAP3 on rising edges */
    union EV_REG16 CAPFIFOA;
    Uint16 CAP1FIFO, CAP2FIFO, CAP3FIFO;
    union EV_REG16 EVAIMRA, EVAIMRB, EVAIMRC; /* A: bit7 T1PINT, bit9 T1UFINT; C: bit2 CAP3INT */
    union EV_REG16 EVAIFRA, EVAIFRB, EVAIFRC; /* the same bits: write 1 to clear */
};
extern volatile struct EVA_REGS EvaRegs;
#define EVA_T1PINT 0x0080u
#define EVA_T1UFINT 0x0200u
#define EVA_CAP3INT 0x0004u

/* ---- ADC (SPRU060): results left-justified, code << 4 ---- */
struct ADC_REGS {
    union EV_REG16 ADCTRL1, ADCTRL2, ADCTRL3;
    Uint16 ADCMAXCONV;
    Uint16 ADCCHSELSEQ1;
    union EV_REG16 ADCST;
    Uint16 ADCRESULT0, ADCRESULT1, ADCRESULT2;
};
extern volatile struct ADC_REGS AdcRegs;

/* ---- SCI-A (SPRU051) with its 16-level FIFOs ---- */
struct SCIFFRX_BITS {
    Uint16 RXFFIL : 5; Uint16 RXFFIENA : 1; Uint16 RXFFINTCLR : 1; Uint16 RXFFINT : 1; Uint16 RXFFST : 5;
    Uint16 RXFIFORESET : 1; Uint16 RXFFOVRCLR : 1; Uint16 RXFFOVF : 1;
};
union SCIFFRX_REG {
    Uint16 all;
    struct SCIFFRX_BITS bit;
};
struct SCIFFTX_BITS {
    Uint16 TXFFIL : 5; Uint16 TXFFIENA : 1; Uint16 TXFFINTCLR : 1; Uint16 TXFFINT : 1; Uint16 TXFFST : 5;
    Uint16 TXFIFOXRESET : 1; Uint16 SCIFFENA : 1; Uint16 SCIRST : 1;
};
union SCIFFTX_REG {
    Uint16 all;
    struct SCIFFTX_BITS bit;
};
struct SCIRXBUF_BITS {
    Uint16 RXDT : 8; Uint16 rsvd : 6; Uint16 SCIFFPE : 1; Uint16 SCIFFFE : 1;
};
union SCIRXBUF_REG {
    Uint16 all;
    struct SCIRXBUF_BITS bit;
};
struct SCI_REGS {
    union EV_REG16 SCICCR;  /* 0x0007: one stop bit, no parity, 8 data bits */
    union EV_REG16 SCICTL1; /* 0x0003 RXENA | TXENA; 0x0023 with SWRESET released */
    Uint16 SCIHBAUD, SCILBAUD;
    union EV_REG16 SCICTL2;
    union EV_REG16 SCIRXST;
    union SCIRXBUF_REG SCIRXBUF;
    Uint16 SCITXBUF;        /* an octet in bits 7:0 */
    union SCIFFTX_REG SCIFFTX;
    union SCIFFRX_REG SCIFFRX;
    union EV_REG16 SCIFFCT;
    union EV_REG16 SCIPRI;
};
extern volatile struct SCI_REGS SciaRegs;

#endif /* HOSTCHECK_DSP281X_DEVICE_H */
