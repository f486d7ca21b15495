/* hrt_link.h: the runtime's side of the wire (firmware_protocol/): a firmware on hrt.h speaks the
 * hilbench protocol through one hrt_link_t.
 *
 * The link owns the handshake (the HELLO and the firmware's self-description from its
 * hrt_firmware_t: TargetHello, then TelemetryInfo and ParamInfo on request, with names, units and
 * scales), the parameter protocol (describe, get, all-or-nothing set), Start/Stop, Status,
 * the answer to a repeated seq (the last Drive again, no second step), telemetry packing, and the
 * watchdog in every mode: when no valid Sensors arrived for the agreed watchdog_ms (in lockstep at
 * least HRT_LOCKSTEP_WATCHDOG_MIN_MS) the outputs go off and one unsolicited Drive says so (OFF,
 * fault WATCHDOG), counted in Status. Real time: the firmware is stopped (HRT_STOP_WATCHDOG).
 * Lockstep: the firmware's state is left as it is (virtual time stands still while the host is
 * away), the port forces the outputs off (HRT_PORT_OUTPUTS_OFF) and the next Sensors gives them
 * back, so a host pausing on a loaded machine changes no recording. Lockstep: one Sensors = one agreed period of virtual time (hrt_span_*), every input edge it
 * carries at its time. Mode PREDICT (HRT_PREDICT_BYTES > 0) is lockstep whose Drive carries, instead of
 * the duties the declaration reports, the mean duties of the NEXT span as the firmware would run it
 * with no new input (its state copied, the span run, the state put back): the host holds those over
 * that span, so a period of many PWM periods does not hold duties that were right at its start. Real time: each Sensors
 * advances the firmware by the time that passed on the port's clock, or, on a port whose own
 * interrupts run the bodies (HRT_PORT_HW), updates the inputs they read.
 *
 * A PORT provides the four functions below, feeds every received byte to hrt_link_rx_byte (from its
 * UART receive interrupt or its read loop) and calls hrt_link_poll from its main loop.
 */
#ifndef HRT_LINK_H
#define HRT_LINK_H

#include <stdint.h>

#include "hbp.h"
#include "hrt.h"

/* The largest message the link sends (type..payload): a build may lower it to what its declaration
 * needs (hrt_config.h); a reply that would not fit is not sent (the host times out and says so). */
#ifndef HRT_TX_FRAME_MAX
#define HRT_TX_FRAME_MAX HBP_MAX_FRAME
#endif


/* The self-description beyond the HELLO (TargetDescribe, TelemetryDescribe, ParamDescribe). 1 by
 * default; a chip whose flash cannot spare it (the dsPIC30F2010's AN1017 build) sets 0 on its command
 * line (every file: the declaration's tables keep fewer fields, hrt.h): it then answers those requests
 * with ErrorReport(BAD_REQUEST), and a host that knows the firmware by its HELLO's name serves them
 * from its registered profile (hilbench's RemoteTarget.describe: the model's declaration). */
/* (HRT_DESCRIBE's default is in hrt.h: a declaration's describe-only texts follow it, HRT_DESCRIBED) */
/* Real time on a port without its own timers: each Sensors advances the firmware by the time that
 * passed, at most this many agreed periods (a firmware too slow for real time on its chip falls
 * behind instead of spending ever longer spans catching up). */
#ifndef HRT_RT_MAX_PERIODS
#define HRT_RT_MAX_PERIODS 4u
#endif
#if HRT_PREDICT_BYTES > 0 && !HRT_REPORT_MEAN
#error "HRT_PREDICT_BYTES needs HRT_REPORT_MEAN 1 (a predicted span's mean duties)"
#endif
/* Monitor mode (HostHello mode MONITOR; a real-motor build sets 1, every other build leaves it 0 and
 * carries none of its code): the port runs the firmware on its own timers and sensors from power-on
 * (hrt_rt_*), the host sends no Sensors, and hrt_link_stream, from the port's main loop, sends an
 * unsolicited Drive every agreed period_us, its seq counting periods of the port's clock (a skipped
 * slot is a seq skipped, never a burst). Any valid frame from the host feeds the watchdog; silence
 * for watchdog_ms stops the firmware (HRT_STOP_WATCHDOG), as in real time. Such a build agrees to no
 * other mode and refuses every Sensors: its motor is never driven from a simulated rotor. */
/* (HRT_MONITOR's default is in hrt.h, beside HRT_REALTIME's) */
/* Twin-speculative lockstep (SensorsBatch -> BatchDigest): 1 by default; a chip that will never run
 * behind a host twin and cannot spare the flash (the dsPIC30F2010's AN1017 build) sets 0, and its
 * link is then exactly as without it (a SensorsBatch is answered ErrorReport(BAD_REQUEST)). */
#ifndef HRT_SPECULATE
#define HRT_SPECULATE (!HRT_MONITOR) /* a real-motor build takes no Sensors, batched or not */
#endif
#if HRT_MONITOR && HRT_SPECULATE
#error "a real-motor build (HRT_MONITOR) takes no SensorsBatch: leave HRT_SPECULATE at 0"
#endif
#ifndef HRT_LOCKSTEP_WATCHDOG_MIN_MS
#define HRT_LOCKSTEP_WATCHDOG_MIN_MS 1000u
#endif
/* A lockstep watchdog trip leaves the firmware's state alone (its virtual time stands still): a
 * port whose pins can switch something (a bridge in lockstep) defines this to force them off until
 * the next Sensors; on the others the Drives saying OFF are the outputs. */
#ifndef HRT_PORT_OUTPUTS_OFF
#define HRT_PORT_OUTPUTS_OFF() ((void)0)
#endif

/* ---- what a port provides ---- */
void hrt_port_send(const hbp_u8 *bytes, hbp_u8 len); /* wire bytes, in order (a frame in pieces) */
uint32_t hrt_port_now(void);  /* a free-running clock in the firmware's ticks, wrapping at 2^32 */
void hrt_port_lock(void);     /* hold off the interrupts that run bodies (real time on a hardware port) */
void hrt_port_unlock(void);
#if HRT_HW_TIMERS
void hrt_port_realtime(hbp_u8 on); /* enter (1) or leave (0) real time: start or stop the chip's timers */
#endif

#define HRT_LINK_F_SENSORS 0x01u  /* a Sensors arrived since the handshake */
#define HRT_LINK_F_TRIPPED 0x02u  /* the watchdog tripped and no Sensors came since */
#define HRT_LINK_F_ANSWERED 0x04u /* a Drive went out since the handshake: last_seq is valid */
#define HRT_LINK_F_HELLO 0x08u    /* a handshake happened */
#define HRT_LINK_F_RT 0x10u       /* real time on a hardware port is running */

#if HRT_SPECULATE
typedef struct {
    uint16_t encoder;
    uint16_t enc_step;          /* the encoder's last change: a period without an encoder record repeats it */
    uint16_t adc[HBP_MAX_ADC];
    hbp_u8 inputs;
    hbp_u8 n_adc;
} hrt_batch_in_t;
#endif

typedef struct {
    hrt_t *rt;
    hbp_rx_t rx;
    uint16_t period_us;        /* the agreed period */
    uint32_t last_rx;          /* the port's clock at the last Sensors */
    uint16_t watchdog_ms;
    uint16_t watchdog_trips;
    hbp_u8 mode;              /* HBP_MODE_* */
    hbp_u8 flags;             /* HRT_LINK_F_* */
    hbp_u8 last_seq;
    hbp_u8 tx_len;             /* bytes written to tx (more than HRT_TX_FRAME_MAX: it did not fit) */
    hbp_u8 tx[HRT_TX_FRAME_MAX]; /* the message being sent (hbp_send_frame makes its wire bytes) */
#if HRT_MONITOR
    uint32_t stream_at;        /* monitor mode: the port's clock at the slot of the last streamed Drive */
#endif
#if HRT_SPECULATE
    /* SensorsBatch: the periods' inputs as the records left them (they carry over from batch to batch),
     * the period the next batch starts at, and the last batch's answer (kept for a repeat) */
    hrt_batch_in_t b_in;
    hbp_u8 b_synced;           /* 1: a batch was run since the handshake or the last Sensors */
    hbp_u8 b_count;            /* the last batch's period count */
    uint16_t b_first;          /* the last batch's first period */
    uint32_t b_digest;         /* the CRC-32 of the last batch's Drives */
#endif
#if HRT_PREDICT_BYTES > 0
    uint16_t predicted[3];     /* mode PREDICT: the mean duties predicted for the next span */
    hbp_u8 snapshot[HRT_PREDICT_BYTES]; /* the firmware's state, kept while a span is predicted */
#endif
} hrt_link_t;

void hrt_link_init(hrt_link_t *l, hrt_t *rt);
static inline hbp_u8 hrt_link_rx_byte(hrt_link_t *l, hbp_u8 byte)
{
    return hbp_rx_byte(&l->rx, byte);
}
/* Handle the frame waiting in l->rx, if any, and release it; then the watchdog. */
void hrt_link_poll(hrt_link_t *l);
/* Handle one frame (type, seq, payload; CRC stripped) and send its reply, if it has one. */
void hrt_link_handle(hrt_link_t *l, const hbp_u8 *frame, hbp_u8 len);
/* The watchdog alone (a port that handles frames itself calls it from its main loop). */
void hrt_link_watchdog(hrt_link_t *l);
/* Send the Drive of the present state with this seq. */
void hrt_link_send_drive(hrt_link_t *l, hbp_u8 seq);
#if HRT_MONITOR
/* Monitor mode: send the Drive of the present state when a period_us slot has passed (from the
 * port's main loop; the state is read with the port locked, the bytes sent unlocked). */
void hrt_link_stream(hrt_link_t *l);
#endif

#endif /* HRT_LINK_H */
