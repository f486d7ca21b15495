/* hbp.c: hilbench protocol 3, what every target needs: the CRC, the streaming frame sender, the
 * receive state machine. See hbp.h and PROTOCOL.md. C99, no heap, no floats. (hbp_codec.c: frames and
 * message structs in buffers, for hosts, tests and targets that want them.) */
#include <stddef.h>

#include "hbp.h"

/* `static inline`: a small helper, or one called once, that XC16's -O1 inlines as GCC's does (the
 * dsPIC30F2010's 4K words, docs/board.md section 3a, measured one by one); the others stay calls. */
#define BYTE(x) ((hbp_u8)((x) & 0xFFu))

uint16_t hbp_crc16_update(uint16_t crc, hbp_u8 byte)
{
    hbp_u8 bit;
    crc = (uint16_t)(crc ^ (uint16_t)((uint16_t)(byte & 0xFFu) << 8));
    for (bit = 0u; bit < 8u; bit++) {
        if ((crc & 0x8000u) != 0u) {
            crc = (uint16_t)((uint16_t)(crc << 1) ^ 0x1021u);
        } else {
            crc = (uint16_t)(crc << 1);
        }
    }
    return crc;
}

/* Byte k of L . message . L. */
static hbp_u8 body_byte(const hbp_u8 *message, hbp_u8 len, hbp_u8 k)
{
    return (k == 0u || k == (hbp_u8)(len + 1u)) ? (hbp_u8)(len + HBP_WIRE_OVERHEAD - 1u) : BYTE(message[k - 1u]);
}

static inline uint16_t put_crc(hbp_put_fn put, uint16_t crc, hbp_u8 b)
{
    put(&b, 1u);
    return hbp_crc16_update(crc, b);
}

void hbp_send_frame(const hbp_u8 *message, hbp_u8 len, hbp_put_fn put)
{
    uint16_t crc = HBP_CRC_INIT;
    hbp_u8 k = 0u;
    hbp_u8 n = (hbp_u8)(len + 2u); /* bytes of L . message . L */
    hbp_u8 t[4];
    if (len < 2u || len > HBP_MAX_FRAME) {
        return;
    }
    for (;;) { /* one COBS block per pass: its code byte (the distance to the next zero), its data */
        hbp_u8 j = k;
        while (j < n && body_byte(message, len, j) != 0u) {
            j++;
        }
        crc = put_crc(put, crc, (hbp_u8)((unsigned)j - (unsigned)k + 1u));
        for (; k < j; k++) {
            crc = put_crc(put, crc, body_byte(message, len, k));
        }
        if (j == n) {
            break;
        }
        k = (hbp_u8)(j + 1u); /* past the zero the code byte stands for */
    }
    t[0] = BYTE(0x80u | (crc >> 9));
    t[1] = BYTE(0x80u | ((crc >> 2) & 0x7Fu));
    t[2] = BYTE(0x80u | ((unsigned)(crc & 3u) << 5));
    t[3] = 0u;
    put(t, 4u);
}

static void rx_restart(hbp_rx_t *rx)
{
    rx->first = 0u;
    rx->len = 0u;
    rx->remaining = 0u;
    rx->count = 0u;
    rx->crc = HBP_CRC_INIT;
    rx->flags = (hbp_u8)(rx->flags & HBP_RX_F_BAD);
}

static void rx_fail(hbp_rx_t *rx, hbp_u8 error)
{
    rx->errors++;
    rx->last_error = error;
    rx->flags = (hbp_u8)(rx->flags | HBP_RX_F_BAD | HBP_RX_F_DISCARD);
}

#if HBP_ERROR_NONE != 0u
#error "hbp_rx_init's zero bytes are HBP_ERROR_NONE"
#endif
void hbp_rx_init(hbp_rx_t *rx)
{
    hbp_u8 *p = (hbp_u8 *)rx;
    uint16_t k;
    for (k = 0u; k < (uint16_t)sizeof *rx; k++) { /* every field 0 (HBP_ERROR_NONE), byte by byte: no memset */
        p[k] = 0u;
    }
    rx->ready = 0u; /* again through its volatile lvalue: the loop's store through a plain pointer is not one */
    rx_restart(rx);
}

/* One decoded byte of L . message . L. */
static void rx_decoded(hbp_rx_t *rx, hbp_u8 b)
{
    if ((rx->flags & HBP_RX_F_BODY) == 0u) {
        rx->first = b; /* the leading length */
        rx->flags = (hbp_u8)(rx->flags | HBP_RX_F_BODY);
    } else if (rx->len < HBP_RX_MAX) {
        rx->buf[rx->len] = b;
        rx->len++;
    } else {
        rx_fail(rx, HBP_ERROR_OVERSIZED); /* longer than any message this build takes */
    }
}

/* One wire byte older than the check-byte window: the CRC, then COBS. */
static inline void rx_cobs(hbp_rx_t *rx, hbp_u8 b)
{
    rx->crc = hbp_crc16_update(rx->crc, b);
    if (rx->remaining == 0u) {
        /* a code byte: the previous block (if any) ends with an implied zero */
        if ((rx->flags & HBP_RX_F_ZERO) != 0u) {
            rx_decoded(rx, 0u);
        }
        rx->remaining = (hbp_u8)(b - 1u);
        rx->flags = (hbp_u8)((b == 0xFFu) ? (rx->flags & (hbp_u8)~HBP_RX_F_ZERO) : (rx->flags | HBP_RX_F_ZERO));
    } else {
        rx_decoded(rx, b);
        rx->remaining--;
    }
}

static inline hbp_u8 rx_end_of_frame(hbp_rx_t *rx)
{
    hbp_u8 n = rx->count;
    const hbp_u8 *t = rx->window;
    uint16_t crc = (uint16_t)((uint16_t)((t[0] & 0x7Fu) << 9) | (uint16_t)((t[1] & 0x7Fu) << 2) |
                              (uint16_t)((t[2] >> 5) & 3u));
    if (n < HBP_MIN_FRAME_WIRE) {
        rx_fail(rx, HBP_ERROR_LENGTH);
        return 0u;
    }
    if ((t[0] & t[1] & t[2] & 0x80u) == 0u || (t[2] & 0x1Fu) != 0u || crc != rx->crc) {
        rx_fail(rx, HBP_ERROR_CRC);
        return 0u;
    }
    if (rx->remaining != 0u) {
        rx_fail(rx, HBP_ERROR_COBS); /* the last block is shorter than its code byte says */
        return 0u;
    }
    if (rx->first != n || rx->len < 3u || rx->buf[rx->len - 1u] != n) {
        rx_fail(rx, HBP_ERROR_LENGTH); /* bytes lost or gained at either end */
        return 0u;
    }
    if (!hbp_type_known(rx->buf[0])) {
        rx->unknown++;
        rx->last_error = HBP_ERROR_UNKNOWN_TYPE;
        rx->flags = (hbp_u8)(rx->flags | HBP_RX_F_BAD);
        return 0u;
    }
    rx->frames++;
    if ((rx->flags & HBP_RX_F_BAD) != 0u) {
        rx->resyncs++;
        rx->flags = (hbp_u8)(rx->flags & (hbp_u8)~HBP_RX_F_BAD);
    }
    rx->frame_len = (hbp_u8)(rx->len - 1u);
    rx->ready = 1u;
    return 1u;
}

hbp_u8 hbp_rx_byte(hbp_rx_t *rx, hbp_u8 byte)
{
    hbp_u8 got = 0u;
    byte = BYTE(byte);
    if (byte == 0u) {
        if ((rx->flags & (HBP_RX_F_STARTED | HBP_RX_F_DISCARD)) == HBP_RX_F_STARTED) {
            got = rx_end_of_frame(rx);
        }
        rx->flags = (hbp_u8)(rx->flags & (hbp_u8)~(HBP_RX_F_STARTED | HBP_RX_F_DISCARD | HBP_RX_F_BODY | HBP_RX_F_ZERO));
        rx_restart(rx);
        return got;
    }
    if ((rx->flags & HBP_RX_F_DISCARD) != 0u) {
        return 0u;
    }
    rx->flags = (hbp_u8)(rx->flags | HBP_RX_F_STARTED);
    if (rx->ready != 0u) {
        /* the main loop still holds the previous frame: drop this one whole */
        rx->overruns++;
        rx->last_error = HBP_ERROR_OVERRUN;
        rx->flags = (hbp_u8)(rx->flags | HBP_RX_F_DISCARD | HBP_RX_F_BAD);
        return 0u;
    }
    if (rx->count >= (hbp_u8)(HBP_MAX_WIRE - 1u)) {
        rx_fail(rx, HBP_ERROR_OVERSIZED);
        return 0u;
    }
    if (rx->count >= 3u) {
        rx_cobs(rx, rx->window[0]); /* the oldest of the window is not a check byte */
    }
    rx->window[0] = rx->window[1];
    rx->window[1] = rx->window[2];
    rx->window[2] = byte;
    rx->count++;
    return 0u;
}

void hbp_rx_release(hbp_rx_t *rx)
{
    rx->ready = 0u;
}
