/* an1017_bridge.h: the AN1017 firmware core behind the hilbench protocol (firmware_protocol/).
 *
 * Under the bench the firmware's pins are frames: hall states, S2 and the ADC channels come from
 * Sensors (a hall change runs the matching hall ISR, the IC7 capture computed from the frame's
 * edge time); PWM duties, state and telemetry go back in Drive. Parameters are declared in a const
 * table and written through the protocol with the note's PID constraints checked here, by the
 * firmware. Lockstep: one Sensors = one agreed period of virtual time, every ISR at its true time
 * inside it. Real time: each Sensors advances the firmware by the time that really passed since
 * the previous one (the port's clock), and the watchdog turns PWM off when frames stop.
 *
 * A port provides two functions and feeds received bytes to hbp_rx_byte(&bridge.rx, byte)
 * (from its UART RX interrupt or its read loop), then calls an1017_bridge_poll from its main loop.
 */
#ifndef AN1017_BRIDGE_H
#define AN1017_BRIDGE_H

#include <stdint.h>

#include "an1017.h"
#include "hbp.h"

#define AN1017_FIRMWARE_NAME "AN1017"
#define AN1017_FIRMWARE_VERSION 0x0101u /* v1.1 */
#define AN1017_PWM_FREQ_HZ 20000UL
#define AN1017_PERIOD_STEP_US 50u       /* the agreed period is a whole number of PWM periods */
#define AN1017_ADC_BITS 10u             /* the dsPIC30F2010's 10-bit ADC */
/* The largest frame this firmware sends (type..payload, before the CRC): TargetHello, 17 fixed +
 * name (1 + 6) + ADC roles (1 + 3) + telemetry ids (3) = 31 bytes; ParamInfo of "ref_override",
 * 17 + 12 = 29; Drive 11 + 6 = 17. One static transmit buffer of 32 + 4 bytes (COBS code byte, CRC 2,
 * delimiter) instead of a frame and a wire buffer of HBP_MAX_FRAME keeps RAM inside the
 * dsPIC30F2010's 512 bytes: messages are packed at wire[1] and COBS-encoded in place (see
 * send_frame). */
#define AN1017_TX_FRAME_MAX 32u
#define AN1017_TX_WIRE_MAX (AN1017_TX_FRAME_MAX + 4u)

/* ---- what a port provides ---- */
/* Send wire bytes (a whole encoded frame, at most HBP_MAX_WIRE). */
void an1017_port_send(const uint8_t *wire, uint8_t len);
/* A free-running count of Tcy (50 ns), wrapping at 2^32 (real-time mode and the watchdog only). */
uint32_t an1017_port_now_tcy(void);
/* Hold off / let in again the interrupts that run ISR bodies (a port whose hardware interrupts run
 * them in real time); the bridge brackets every change it makes to the firmware's state. */
void an1017_port_lock(void);
void an1017_port_unlock(void);

typedef struct {
    an1017_t fw;
    hbp_rx_t rx;
    int32_t values[AN1017_N_PARAMS]; /* the declared parameter values */
    uint32_t period_tcy;             /* the agreed period */
    uint32_t last_sensors_tcy;       /* port clock at the last Sensors (real time) */
    uint16_t watchdog_ms;
    uint16_t watchdog_trips;
    uint8_t mode;                    /* HBP_MODE_* */
    uint8_t have_sensors;            /* a Sensors arrived since the handshake (real time) */
    uint8_t tripped;
    uint8_t last_error;              /* HBP_ERROR_* of the last ErrorReport or the watchdog */
    uint8_t last_seq;
    uint8_t answered;                /* a Drive went out since the handshake: last_seq is valid */
    uint8_t wire[AN1017_TX_WIRE_MAX]; /* the frame being sent, packed at wire[1], encoded in place */
} an1017_bridge_t;

void an1017_bridge_init(an1017_bridge_t *b, uint8_t variant);
/* Handle the frame waiting in b->rx, if any, and release it; check the watchdog (real time). */
void an1017_bridge_poll(an1017_bridge_t *b);
/* Only the watchdog: in real time, StopMotor and an unsolicited Drive when Sensors stop. */
void an1017_bridge_watchdog(an1017_bridge_t *b);
/* Send the Drive of the firmware's present state (a port whose own interrupts run the ISR bodies). */
void an1017_bridge_send_drive(an1017_bridge_t *b, uint8_t seq);
/* Handle one frame (type, seq, payload; CRC stripped) and send its reply, if it has one. */
void an1017_bridge_handle(an1017_bridge_t *b, const uint8_t *frame, uint8_t len);

#endif /* AN1017_BRIDGE_H */
