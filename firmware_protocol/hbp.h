/* hbp.h: hilbench protocol 3, the C99 library: hbp.c, what every target needs (the CRC, a streaming
 * frame sender, the receive state machine); hbp_codec.c, frames and message structs in buffers (the
 * table-driven codec over hbp_messages.c's generated layouts, handshake helpers) for hosts, tests
 * and targets on the bare library; hbp_params.c, a parameter table for those. A firmware on the
 * runtime (firmware/runtime/) needs hbp.c only: its link reads requests in place and writes replies
 * field by field.
 *
 * No heap, no floating point, only <stdint.h> types; a wire byte is an hbp_u8 (uint_least8_t: 16 bits
 * on the C28x, whose char is 16 bits) of which only the low 8 bits are used, and every narrowing is
 * an explicit cast, so the code is correct with a 16-bit int (dsPIC30F, AVR) and clean under
 * -Wconversion. Message structs and their layouts are generated from schema.toml into
 * hbp_messages.h/.c.
 *
 * Framing (PROTOCOL.md): wire = COBS(L . message . L) . T0 T1 T2 . 0x00, L = the frame's length
 * between delimiters, T = the CRC-16/CCITT-FALSE of the COBS bytes, 7 bits per check byte with the
 * top bit set.
 *
 * Static RAM (AN1017 profile, the dsPIC build: -DHBP_MAX_ADC=3u -DHBP_MAX_TELEMETRY=3u -DHBP_MAX_EDGES=3u
 * -DHBP_MAX_BATCH=17u, so
 * HBP_RX_MAX = 23: the largest host -> target message, ParamSet with 4 (id, value) pairs, 22 bytes,
 * and its trailing length byte):
 *   hbp_rx_t   23 (buffer) + 4 (COBS state, lengths) + 3 (check-byte window) + 3 (flags, ready, frame
 *              length) + 1 (last_error) + 2 (CRC) + 10 (five u16 counters) = 46 bytes, with 16-bit alignment
 *              too (the bytes first, 34 of them here, then the u16s: no padding).
 * Sending packs a message into a caller's buffer of HBP_MAX_WIRE bytes (the runtime's link keeps one
 * sized to its own replies) and encodes it in place.
 */
#ifndef HBP_H
#define HBP_H

#include <stdint.h>

#include "hbp_messages.h"

/* Wire bytes per message: two lengths, the COBS code byte, three check bytes, the delimiter. */
#define HBP_WIRE_OVERHEAD 7u
/* A frame on the wire, delimiter included. */
#define HBP_MAX_WIRE (HBP_MAX_FRAME + HBP_WIRE_OVERHEAD)
/* The bytes between two delimiters that can form a frame: at least 8, at most HBP_MAX_WIRE - 1. */
#define HBP_MIN_FRAME_WIRE 8u

/* Largest host -> target messages (type..payload) for the configured capacities. */
#define HBP_SENSORS_MAX_LEN (HBP_SENSORS_FIXED_LEN + 1u + 2u * HBP_MAX_ADC + 3u * HBP_MAX_EDGES)
#define HBP_PARAM_SET_MAX_LEN (HBP_PARAM_SET_FIXED_LEN + 5u * HBP_MAX_PARAM_PAIRS)
/* A SensorsBatch with HBP_MAX_BATCH bytes of records (a build short of RAM lowers HBP_MAX_BATCH, down to
 * 17: a ParamSet's size, which every host's first batch keeps to). */
#define HBP_SENSORS_BATCH_MAX_LEN (HBP_SENSORS_BATCH_FIXED_LEN + HBP_MAX_BATCH)
/* The receive buffer: the largest of them (no message exceeds HBP_MAX_FRAME) and its trailing length. */
#ifndef HBP_RX_MAX
#if HBP_SENSORS_MAX_LEN > HBP_MAX_FRAME || HBP_SENSORS_BATCH_MAX_LEN > HBP_MAX_FRAME
#define HBP_RX_MAX (HBP_MAX_FRAME + 1u)
#elif HBP_SENSORS_MAX_LEN > HBP_PARAM_SET_MAX_LEN && HBP_SENSORS_MAX_LEN >= HBP_SENSORS_BATCH_MAX_LEN
#define HBP_RX_MAX (HBP_SENSORS_MAX_LEN + 1u)
#elif HBP_SENSORS_BATCH_MAX_LEN > HBP_PARAM_SET_MAX_LEN
#define HBP_RX_MAX (HBP_SENSORS_BATCH_MAX_LEN + 1u)
#else
#define HBP_RX_MAX (HBP_PARAM_SET_MAX_LEN + 1u)
#endif
#endif
#if HBP_RX_MAX > HBP_MAX_FRAME + 1u
#error "HBP_RX_MAX must not exceed HBP_MAX_FRAME + 1"
#endif

/* ---- CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no xorout) over the COBS bytes ---- */
#define HBP_CRC_INIT 0xFFFFu
uint16_t hbp_crc16_update(uint16_t crc, hbp_u8 byte);
uint16_t hbp_crc16(const hbp_u8 *data, hbp_u8 len);

/* ---- Frame encoder (hbp_codec.c) ----
 * message: type, seq, payload (len bytes, 2 <= len <= HBP_MAX_FRAME). Writes the frame's wire bytes,
 * delimiter included, to out (room for len + HBP_WIRE_OVERHEAD bytes) and returns their count, 0 if
 * len is out of range. In place: with the message packed at out + 2 the result is the same (every
 * byte lands at or before a position already read). */
hbp_u8 hbp_encode_frame(const hbp_u8 *message, hbp_u8 len, hbp_u8 *out);

/* ---- Frame sender without a wire buffer ----
 * The same wire bytes as hbp_encode_frame, handed to put one at a time as they are made (COBS looks
 * ahead in the message for the next zero): a target needs only the message's buffer. */
typedef void (*hbp_put_fn)(const hbp_u8 *bytes, hbp_u8 n);
void hbp_send_frame(const hbp_u8 *message, hbp_u8 len, hbp_put_fn put);

/* ---- Receive state machine, one byte at a time (call from the UART RX ISR) ----
 * When hbp_rx_byte returns 1 a good frame (check bytes, COBS, both lengths, a known type) waits in
 * rx->buf[0 .. rx->frame_len) as type, seq, payload; the main loop handles it and calls
 * hbp_rx_release. Until then further frames are dropped and counted as overruns. The ISR owns every
 * field except `ready`, which the main loop only clears (one byte store: atomic). */
typedef struct {
    hbp_u8 buf[HBP_RX_MAX];
    hbp_u8 len;        /* decoded bytes kept (the message and the trailing length) */
    hbp_u8 remaining;  /* data bytes left in the current COBS block; 0 = a code byte is next */
    hbp_u8 count;      /* wire bytes of the frame so far */
    hbp_u8 first;      /* the first decoded byte: the leading length */
    hbp_u8 window[3];  /* the last three wire bytes: the check bytes once the delimiter comes */
    hbp_u8 flags;      /* HBP_RX_F_* */
    volatile hbp_u8 ready;
    hbp_u8 frame_len;  /* length of the ready message */
    hbp_u8 last_error; /* HBP_ERROR_* of the most recent fault (beside the bytes: no padding) */
    uint16_t crc;      /* over the wire bytes older than the window */
    uint16_t frames;   /* good frames */
    uint16_t errors;   /* bad frames: check bytes, COBS, length, oversized */
    uint16_t resyncs;  /* good frames that followed bad input */
    uint16_t unknown;  /* good frame, unknown type */
    uint16_t overruns; /* frames dropped because the previous one was not released */
} hbp_rx_t;

#define HBP_RX_F_STARTED 0x01u /* a non-zero byte arrived since the last delimiter */
#define HBP_RX_F_DISCARD 0x02u /* drop everything up to the next delimiter */
#define HBP_RX_F_ZERO 0x04u    /* the current block ends with an implied zero */
#define HBP_RX_F_BAD 0x08u     /* bad input seen since the last good frame */
#define HBP_RX_F_BODY 0x10u    /* the leading length is read: decoded bytes go to buf */

void hbp_rx_init(hbp_rx_t *rx);
hbp_u8 hbp_rx_byte(hbp_rx_t *rx, hbp_u8 byte);
void hbp_rx_release(hbp_rx_t *rx);
/* Fill a Status message from the counters (watchdog_trips comes from the firmware; hbp_codec.c). */
void hbp_rx_status(const hbp_rx_t *rx, hbp_u8 seq, uint16_t watchdog_trips, hbp_status_t *out);

/* ---- Handshake (hbp_codec.c) ----
 * hbp_check_hello: HBP_ERROR_NONE if the host speaks our protocol version AND was built from the same
 * schema (HBP_SCHEMA_FINGERPRINT), else HBP_ERROR_VERSION.
 * hbp_check_host_hello: the same on a received HostHello message (type, seq, payload; len bytes),
 * checking the version byte before the length (a HostHello of another version may be longer):
 * HBP_ERROR_VERSION, HBP_ERROR_LENGTH, or HBP_ERROR_NONE with *out filled.
 * Answer HBP_ERROR_VERSION with hbp_error_report(seq, HBP_ERROR_VERSION, HBP_PROTOCOL_VERSION, &e):
 * every ErrorReport carries this build's fingerprint, so the host can name both. */
hbp_u8 hbp_check_hello(const hbp_host_hello_t *hello);
hbp_u8 hbp_check_host_hello(const hbp_u8 *frame, hbp_u8 len, hbp_host_hello_t *out);
void hbp_error_report(hbp_u8 seq, hbp_u8 code, hbp_u8 detail, hbp_error_report_t *out);

/* ---- Parameter table (hbp_params.c; the runtime has its own, firmware/runtime/hrt.h) ----
 * The firmware declares its parameters in a const table (flash) and owns their values. A set request
 * is checked completely (ids, access, ranges, then the optional cross-parameter constraint) before
 * any value changes: all of it is applied or none. */
typedef struct {
    const char *name; /* <= HBP_MAX_NAME printable ASCII characters */
    int32_t min_value;
    int32_t max_value;
    hbp_u8 ptype;     /* HBP_PTYPE_* */
    hbp_u8 access;    /* HBP_ACCESS_* */
} hbp_param_def_t;

struct hbp_params;
/* Constraint check of a candidate set: return HBP_RESULT_OK or HBP_RESULT_CONSTRAINT and set
 * *param_id (the first parameter of the broken constraint) and *detail (the constraint number).
 * hbp_param_candidate gives the value a parameter would have after the set. */
typedef hbp_u8 (*hbp_param_check_fn)(const struct hbp_params *params, const hbp_param_set_t *request,
                                     hbp_u8 *param_id, hbp_u8 *detail);

typedef struct hbp_params {
    const hbp_param_def_t *defs;
    int32_t *values;
    hbp_u8 count;
    hbp_param_check_fn check; /* may be 0 */
} hbp_params_t;

int32_t hbp_param_candidate(const hbp_params_t *params, const hbp_param_set_t *request, hbp_u8 id);
/* Fills a ParamInfo; returns HBP_RESULT_OK or HBP_RESULT_UNKNOWN_ID (out untouched but seq). */
hbp_u8 hbp_param_describe(const hbp_params_t *params, hbp_u8 id, hbp_u8 seq, hbp_param_info_t *out);
void hbp_param_get(const hbp_params_t *params, hbp_u8 id, hbp_u8 seq, hbp_param_value_t *out);
void hbp_param_set(hbp_params_t *params, const hbp_param_set_t *request, hbp_u8 seq,
                   hbp_param_set_result_t *out);

#endif /* HBP_H */
