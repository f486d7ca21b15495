/* hbp_codec.c: hilbench protocol 3 in buffers: a frame's wire bytes at once (hbp_encode_frame), and
 * message structs packed and unpacked by the generated layouts of hbp_messages.c (hbp_pack_into,
 * hbp_unpack), with the HostHello check on a struct. For hosts, tests and targets built on the bare
 * library (the loopback example); the runtime's link reads its requests in place and writes its
 * replies field by field, so a firmware on the runtime does not compile this file. See hbp.h. */
#include <stddef.h>

#include "hbp.h"

#define BYTE(x) ((hbp_u8)((x) & 0xFFu))

uint16_t hbp_crc16(const hbp_u8 *data, hbp_u8 len)
{
    uint16_t crc = HBP_CRC_INIT;
    hbp_u8 i;
    for (i = 0u; i < len; i++) {
        crc = hbp_crc16_update(crc, data[i]);
    }
    return crc;
}

/* ------------------------------------------------------------------------------------ framing */

hbp_u8 hbp_encode_frame(const hbp_u8 *message, hbp_u8 len, hbp_u8 *out)
{
    hbp_u8 total;
    hbp_u8 i;
    hbp_u8 code_at = 0u; /* where the current block's code byte goes */
    hbp_u8 o = 1u;       /* next output position */
    uint16_t crc;
    if (len < 2u || len > HBP_MAX_FRAME) {
        return 0u;
    }
    total = (hbp_u8)(len + HBP_WIRE_OVERHEAD - 1u); /* the frame's length between delimiters */
    for (i = 0u; i < (hbp_u8)(len + 2u); i++) {    /* COBS of L . message . L, one forward pass */
        hbp_u8 b = (i == 0u || i == (hbp_u8)(len + 1u)) ? total : BYTE(message[i - 1u]);
        if (b == 0u) {
            out[code_at] = (hbp_u8)(o - code_at);
            code_at = o;
        } else {
            out[o] = b;
        }
        o++;
    }
    out[code_at] = (hbp_u8)(o - code_at);
    crc = hbp_crc16(out, o); /* over the COBS bytes */
    out[o] = BYTE(0x80u | (crc >> 9));
    out[o + 1u] = BYTE(0x80u | ((crc >> 2) & 0x7Fu));
    out[o + 2u] = BYTE(0x80u | ((unsigned)(crc & 3u) << 5));
    out[o + 3u] = 0u;
    return (hbp_u8)(o + 4u);
}

/* ------------------------------------------------------------------- the table-driven codec */

static void put16(hbp_u8 *p, uint16_t v)
{
    p[0] = BYTE(v);
    p[1] = BYTE(v >> 8);
}

static void put32(hbp_u8 *p, uint32_t v)
{
    put16(p, (uint16_t)(v & 0xFFFFu));
    put16(&p[2], (uint16_t)(v >> 16));
}

static uint16_t get16(const hbp_u8 *p)
{
    return (uint16_t)((uint16_t)(p[0] & 0xFFu) | (uint16_t)((uint16_t)(p[1] & 0xFFu) << 8));
}

static uint32_t get32(const hbp_u8 *p)
{
    return (uint32_t)get16(p) | ((uint32_t)get16(&p[2]) << 16);
}

static int16_t as_i16(uint16_t u) /* no implementation-defined conversion */
{
    return (u < 0x8000u) ? (int16_t)u : (int16_t)(-(int16_t)(0xFFFFu - u) - 1);
}

static int32_t as_i32(uint32_t u)
{
    return (u < 0x80000000UL) ? (int32_t)u : (int32_t)(-(int32_t)(0xFFFFFFFFUL - u) - 1);
}

/* Wire bytes of one scalar or array element of `kind`. */
static hbp_u8 elem_bytes(hbp_u8 kind)
{
    switch (kind) {
    case HBP_F_U16:
    case HBP_F_I16:
        return 2u;
    case HBP_F_U32:
    case HBP_F_I32:
        return 4u;
    case HBP_F_PAIR:
        return 5u;
    case HBP_F_EDGE:
        return 3u;
    default:
        return 1u;
    }
}

/* Pack one scalar or element of `kind` from member m; returns the bytes written. */
static hbp_u8 put_elem(hbp_u8 kind, const unsigned char *m, hbp_u8 *p)
{
    switch (kind) {
    case HBP_F_U16:
        put16(p, *(const uint16_t *)(const void *)m);
        return 2u;
    case HBP_F_I16:
        put16(p, (uint16_t)*(const int16_t *)(const void *)m);
        return 2u;
    case HBP_F_U32:
        put32(p, *(const uint32_t *)(const void *)m);
        return 4u;
    case HBP_F_I32:
        put32(p, (uint32_t)*(const int32_t *)(const void *)m);
        return 4u;
    case HBP_F_PAIR: {
        const hbp_pair_t *x = (const hbp_pair_t *)(const void *)m;
        p[0] = BYTE(x->id);
        put32(&p[1], (uint32_t)x->value);
        return 5u;
    }
    case HBP_F_EDGE: {
        const hbp_edge_t *x = (const hbp_edge_t *)(const void *)m;
        put16(p, x->time_100ns);
        p[2] = BYTE(x->lines);
        return 3u;
    }
    case HBP_F_BOOL:
        p[0] = (hbp_u8)(*(const hbp_u8 *)m != 0u);
        return 1u;
    default:
        p[0] = BYTE(*(const hbp_u8 *)m);
        return 1u;
    }
}

static void get_elem(hbp_u8 kind, const hbp_u8 *p, unsigned char *m)
{
    switch (kind) {
    case HBP_F_U16:
        *(uint16_t *)(void *)m = get16(p);
        break;
    case HBP_F_I16:
        *(int16_t *)(void *)m = as_i16(get16(p));
        break;
    case HBP_F_U32:
        *(uint32_t *)(void *)m = get32(p);
        break;
    case HBP_F_I32:
        *(int32_t *)(void *)m = as_i32(get32(p));
        break;
    case HBP_F_PAIR: {
        hbp_pair_t *x = (hbp_pair_t *)(void *)m;
        x->id = BYTE(p[0]);
        x->value = as_i32(get32(&p[1]));
        break;
    }
    case HBP_F_EDGE: {
        hbp_edge_t *x = (hbp_edge_t *)(void *)m;
        x->time_100ns = get16(p);
        x->lines = BYTE(p[2]);
        break;
    }
    case HBP_F_BOOL:
        *(hbp_u8 *)m = (hbp_u8)((p[0] & 0xFFu) != 0u);
        break;
    default:
        *(hbp_u8 *)m = BYTE(p[0]);
        break;
    }
}

/* The member size of one array element of `kind` in a message struct. */
static size_t elem_size(hbp_u8 kind)
{
    switch (kind) {
    case HBP_F_U16:
    case HBP_F_I16:
        return sizeof(uint16_t);
    case HBP_F_PAIR:
        return sizeof(hbp_pair_t);
    case HBP_F_EDGE:
        return sizeof(hbp_edge_t);
    default:
        return sizeof(hbp_u8);
    }
}

hbp_u8 hbp_pack_into(const hbp_layout_t *layout, const void *msg, hbp_u8 *frame, hbp_u8 cap)
{
    const unsigned char *m = (const unsigned char *)msg;
    const hbp_field_t *f = layout->fields;
    const hbp_field_t *end = f + layout->n_fields;
    unsigned pos = 2u;
    frame[0] = layout->type;
    frame[1] = BYTE(m[0]); /* seq, every message struct's first member */
    while (f < end) {
        hbp_u8 kind = (hbp_u8)(f->kind & 0x7Fu);
        hbp_u8 last = (hbp_u8)(f->kind & HBP_F_LAST);
        const unsigned char *at = m + f->offset;
        if (kind == HBP_F_BITS) {
            uint32_t word = 0u;
            hbp_u8 shift = 0u;
            hbp_u8 j;
            for (j = 1u; j <= f->max; j++) {
                hbp_u8 width = f[j].aux;
                const unsigned char *b = m + f[j].offset;
                uint32_t v = (width <= 8u) ? (uint32_t)*(const hbp_u8 *)b : (uint32_t)*(const uint16_t *)(const void *)b;
                word |= (v & (((uint32_t)1u << width) - 1u)) << shift;
                shift = (hbp_u8)(shift + width);
            }
            if (pos + f->aux > cap) {
                return 0u;
            }
            for (j = 0u; j < f->aux; j++) {
                frame[pos++] = BYTE(word >> (8u * j));
            }
            f += 1u + f->max;
            continue;
        }
        if (kind == HBP_F_STR) {
            hbp_u8 n = 0u;
            const char *s = (const char *)at;
            while (n < f->aux && s[n] != '\0') {
                n++;
            }
            if (pos + 1u + n > cap) {
                return 0u;
            }
            if (!last) {
                frame[pos++] = n;
            }
            while (n-- > 0u) {
                frame[pos++] = BYTE((unsigned char)*s++);
            }
        } else if (kind == HBP_F_ARRAY) {
            hbp_u8 n = BYTE(m[f->count]);
            hbp_u8 i;
            if (n > f->max || pos + 1u + (unsigned)n * elem_bytes(f->aux) > cap) {
                return 0u;
            }
            if (!last) {
                frame[pos++] = n;
            }
            for (i = 0u; i < n; i++) {
                pos += put_elem(f->aux, at + (size_t)i * elem_size(f->aux), &frame[pos]);
            }
        } else {
            if (pos + elem_bytes(kind) > cap) {
                return 0u;
            }
            pos += put_elem(kind, at, &frame[pos]);
        }
        f++;
    }
    return (hbp_u8)pos;
}

hbp_u8 hbp_unpack(const hbp_layout_t *layout, const hbp_u8 *frame, hbp_u8 len, void *msg)
{
    unsigned char *m = (unsigned char *)msg;
    const hbp_field_t *f = layout->fields;
    const hbp_field_t *end = f + layout->n_fields;
    unsigned pos = 2u;
    if (len < 2u || frame[0] != layout->type) {
        return HBP_ERROR_LENGTH;
    }
    m[0] = BYTE(frame[1]);
    while (f < end) {
        hbp_u8 kind = (hbp_u8)(f->kind & 0x7Fu);
        hbp_u8 last = (hbp_u8)(f->kind & HBP_F_LAST);
        unsigned char *at = m + f->offset;
        if (kind == HBP_F_BITS) {
            uint32_t word = 0u;
            hbp_u8 shift = 0u;
            hbp_u8 j;
            if (pos + f->aux > len) {
                return HBP_ERROR_LENGTH;
            }
            for (j = 0u; j < f->aux; j++) {
                word |= (uint32_t)(frame[pos++] & 0xFFu) << (8u * j);
            }
            for (j = 1u; j <= f->max; j++) {
                hbp_u8 width = f[j].aux;
                unsigned char *b = m + f[j].offset;
                uint32_t v = (word >> shift) & (((uint32_t)1u << width) - 1u);
                if (width <= 8u) {
                    *(hbp_u8 *)b = (hbp_u8)v;
                } else {
                    *(uint16_t *)(void *)b = (uint16_t)v;
                }
                shift = (hbp_u8)(shift + width);
            }
            f += 1u + f->max;
            continue;
        }
        if (kind == HBP_F_STR || kind == HBP_F_ARRAY) {
            hbp_u8 size = (kind == HBP_F_STR) ? 1u : elem_bytes(f->aux);
            hbp_u8 max = (kind == HBP_F_STR) ? f->aux : f->max;
            unsigned n;
            unsigned i;
            if (last) {
                n = (len - pos) / size;
                if (pos + n * size != len) {
                    return HBP_ERROR_LENGTH;
                }
            } else {
                if (pos >= len) {
                    return HBP_ERROR_LENGTH;
                }
                n = frame[pos++] & 0xFFu;
                if (pos + n * size > len) {
                    return HBP_ERROR_LENGTH;
                }
            }
            if (n > max) {
                return HBP_ERROR_LENGTH;
            }
            for (i = 0u; i < n; i++) {
                if (kind == HBP_F_STR) {
                    hbp_u8 c = BYTE(frame[pos++]);
                    if (c < 0x20u || c > 0x7Eu) {
                        return HBP_ERROR_LENGTH;
                    }
                    ((char *)at)[i] = (char)c;
                } else {
                    get_elem(f->aux, &frame[pos], at + (size_t)i * elem_size(f->aux));
                    pos += size;
                }
            }
            if (kind == HBP_F_STR) {
                ((char *)at)[n] = '\0';
            } else {
                m[f->count] = (hbp_u8)n;
            }
        } else {
            hbp_u8 size = elem_bytes(kind);
            if (pos + size > len) {
                return HBP_ERROR_LENGTH;
            }
            get_elem(kind, &frame[pos], at);
            pos += size;
        }
        f++;
    }
    return (pos == len) ? HBP_ERROR_NONE : HBP_ERROR_LENGTH;
}

/* ---------------------------------------------------------------------------------- handshake */

hbp_u8 hbp_check_hello(const hbp_host_hello_t *hello)
{
    if (hello->protocol_version != HBP_PROTOCOL_VERSION || hello->schema_fingerprint != HBP_SCHEMA_FINGERPRINT) {
        return HBP_ERROR_VERSION;
    }
    return HBP_ERROR_NONE;
}

hbp_u8 hbp_check_host_hello(const hbp_u8 *frame, hbp_u8 len, hbp_host_hello_t *out)
{
    /* the version byte first: a HostHello of another protocol version may have another length */
    if (len >= 3u && frame[0] == HBP_MSG_HOST_HELLO && frame[2] != HBP_PROTOCOL_VERSION) {
        return HBP_ERROR_VERSION;
    }
    if (hbp_unpack_host_hello(frame, len, out) != HBP_ERROR_NONE) {
        return HBP_ERROR_LENGTH;
    }
    return hbp_check_hello(out);
}

void hbp_error_report(hbp_u8 seq, hbp_u8 code, hbp_u8 detail, hbp_error_report_t *out)
{
    out->seq = seq;
    out->code = code;
    out->detail = detail;
    out->schema_fingerprint = HBP_SCHEMA_FINGERPRINT;
}

void hbp_rx_status(const hbp_rx_t *rx, hbp_u8 seq, uint16_t watchdog_trips, hbp_status_t *out)
{
    out->seq = seq;
    out->rx_frames = rx->frames;
    out->rx_errors = rx->errors;
    out->resyncs = rx->resyncs;
    out->unknown = rx->unknown;
    out->overruns = rx->overruns;
    out->watchdog_trips = watchdog_trips;
    out->last_error = rx->last_error;
}
