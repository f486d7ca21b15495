/* hbp.h: hilbench protocol, C99 target library (framing, CRC, receive state machine, parameters).
 *
 * No heap, no floating point, only <stdint.h> types; every narrowing is an explicit cast so the code
 * is correct with a 16-bit int (dsPIC30F) and clean under -Wconversion. Message structs and their
 * pack/unpack functions are generated from schema.toml into hbp_messages.h/.c.
 *
 * Static RAM (AN1017 profile: -DHBP_MAX_ADC=3u -DHBP_MAX_TELEMETRY=3u, so HBP_RX_MAX = 24, the
 * largest host -> target frame: ParamSet with 4 (id u8, value i32) pairs):
 *   hbp_rx_t        24 (buffer) + 5 (state) + 10 (five u16 counters) + 1 (last_error) = 40 bytes,
 *                   42 with 2-byte alignment padding
 *   hbp_params_t    can be const (flash); the firmware owns the int32_t values (3 params: 12 bytes)
 *   total           54 bytes of the 128-byte budget (tests/test_c_library.py checks sizeof and nm).
 * Stack: sending a frame uses a HBP_MAX_FRAME (64) byte pack buffer and HBP_MAX_WIRE (66) bytes out,
 * transiently, in the caller's (non-ISR) context; a firmware may use one static buffer instead.
 */
#ifndef HBP_H
#define HBP_H

#include <stdint.h>

#include "hbp_messages.h"

/* Encoded frame on the wire: COBS adds one byte to a <= 64-byte frame, plus the 0x00 delimiter. */
#define HBP_MAX_WIRE (HBP_MAX_FRAME + 2u)

/* Largest host -> target frames (type..crc) for the configured capacities. */
#define HBP_SENSORS_MAX_LEN (HBP_SENSORS_FIXED_LEN + 2u * HBP_MAX_ADC + 2u)
#define HBP_PARAM_SET_MAX_LEN (HBP_PARAM_SET_FIXED_LEN + 5u * HBP_MAX_PARAM_PAIRS + 2u)
#ifndef HBP_RX_MAX
#if HBP_SENSORS_MAX_LEN > HBP_PARAM_SET_MAX_LEN
#define HBP_RX_MAX HBP_SENSORS_MAX_LEN
#else
#define HBP_RX_MAX HBP_PARAM_SET_MAX_LEN
#endif
#endif
#if HBP_RX_MAX > HBP_MAX_FRAME
#error "HBP_RX_MAX must not exceed HBP_MAX_FRAME"
#endif

/* ---- CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no xorout) ----
 * Sent after the frame HIGH byte first, so the bits on the wire run in the order of the polynomial
 * division and every burst of up to 16 bits is detected (PROTOCOL.md, Framing). */
#define HBP_CRC_INIT 0xFFFFu
uint16_t hbp_crc16_update(uint16_t crc, uint8_t byte);
uint16_t hbp_crc16(const uint8_t *data, uint8_t len);

/* ---- Frame encoder ----
 * frame: type, seq, payload (len bytes, 2 <= len <= HBP_MAX_FRAME - 2). Writes COBS(frame . crc16 BE)
 * and the 0x00 delimiter to out (room for HBP_MAX_WIRE bytes); returns the wire length, 0 if len is
 * out of range. */
uint8_t hbp_encode_frame(const uint8_t *frame, uint8_t len, uint8_t *out);

/* ---- Receive state machine, one byte at a time (call from the UART RX ISR) ----
 * The ISR calls hbp_rx_byte for each received byte. When it returns 1 a good frame (CRC checked,
 * known type) waits in rx->buf[0 .. rx->frame_len) as type, seq, payload; the main loop handles it
 * and calls hbp_rx_release. Until then further bytes are dropped and counted as an overrun. The ISR
 * owns every field except `ready`, which the main loop only clears (one byte store: atomic). */
typedef struct {
    uint8_t buf[HBP_RX_MAX];
    uint8_t len;        /* decoded bytes of the frame being received */
    uint8_t remaining;  /* data bytes left in the current COBS block; 0 = a code byte is next */
    uint8_t flags;      /* HBP_RX_F_* */
    volatile uint8_t ready;
    uint8_t frame_len;  /* length of the ready frame without its CRC */
    uint16_t frames;    /* good frames */
    uint16_t errors;    /* bad frames: CRC, COBS, length, oversized */
    uint16_t resyncs;   /* good frames that followed bad input */
    uint16_t unknown;   /* good CRC, unknown type */
    uint16_t overruns;  /* frames dropped because the previous one was not released */
    uint8_t last_error; /* HBP_ERROR_* of the most recent fault */
} hbp_rx_t;

#define HBP_RX_F_STARTED 0x01u /* a non-zero byte arrived since the last delimiter */
#define HBP_RX_F_DISCARD 0x02u /* drop everything up to the next delimiter */
#define HBP_RX_F_ZERO 0x04u    /* the current block ends with an implied zero */
#define HBP_RX_F_BAD 0x08u     /* bad input seen since the last good frame */

void hbp_rx_init(hbp_rx_t *rx);
uint8_t hbp_rx_byte(hbp_rx_t *rx, uint8_t byte);
void hbp_rx_release(hbp_rx_t *rx);
/* Fill a Status message from the counters (watchdog_trips comes from the firmware). */
void hbp_rx_status(const hbp_rx_t *rx, uint8_t seq, uint16_t watchdog_trips, hbp_status_t *out);

/* ---- Handshake ----
 * hbp_check_hello: HBP_ERROR_NONE if the host speaks our protocol version AND was built from the same
 * schema (HBP_SCHEMA_FINGERPRINT), else HBP_ERROR_VERSION.
 * hbp_check_host_hello: the same on a received HostHello frame (type, seq, payload; len bytes),
 * checking the version byte before the length (a HostHello of another version may be longer):
 * HBP_ERROR_VERSION, HBP_ERROR_LENGTH, or HBP_ERROR_NONE with *out filled.
 * Answer HBP_ERROR_VERSION with hbp_error_report(seq, HBP_ERROR_VERSION, HBP_PROTOCOL_VERSION, &e):
 * every ErrorReport carries this build's fingerprint, so the host can name both. */
uint8_t hbp_check_hello(const hbp_host_hello_t *hello);
uint8_t hbp_check_host_hello(const uint8_t *frame, uint8_t len, hbp_host_hello_t *out);
void hbp_error_report(uint8_t seq, uint8_t code, uint8_t detail, hbp_error_report_t *out);

/* ---- Parameter table ----
 * The firmware declares its parameters in a const table (flash) and owns their values. A set request
 * is checked completely (ids, access, ranges, then the optional cross-parameter constraint) before
 * any value changes: all of it is applied or none. */
typedef struct {
    const char *name; /* <= HBP_MAX_NAME printable ASCII characters */
    int32_t min_value;
    int32_t max_value;
    uint8_t ptype;    /* HBP_PTYPE_* */
    uint8_t access;   /* HBP_ACCESS_* */
} hbp_param_def_t;

struct hbp_params;
/* Constraint check of a candidate set: return HBP_RESULT_OK or HBP_RESULT_CONSTRAINT and set
 * *param_id (the first parameter of the broken constraint) and *detail (the constraint number).
 * hbp_param_candidate gives the value a parameter would have after the set. */
typedef uint8_t (*hbp_param_check_fn)(const struct hbp_params *params, const hbp_param_set_t *request,
                                      uint8_t *param_id, uint8_t *detail);

typedef struct hbp_params {
    const hbp_param_def_t *defs;
    int32_t *values;
    uint8_t count;
    hbp_param_check_fn check; /* may be 0 */
} hbp_params_t;

int32_t hbp_param_candidate(const hbp_params_t *params, const hbp_param_set_t *request, uint8_t id);
/* Fills a ParamInfo; returns HBP_RESULT_OK or HBP_RESULT_UNKNOWN_ID (out untouched but seq). */
uint8_t hbp_param_describe(const hbp_params_t *params, uint8_t id, uint8_t seq, hbp_param_info_t *out);
void hbp_param_get(const hbp_params_t *params, uint8_t id, uint8_t seq, hbp_param_value_t *out);
void hbp_param_set(hbp_params_t *params, const hbp_param_set_t *request, uint8_t seq,
                   hbp_param_set_result_t *out);

#endif /* HBP_H */
