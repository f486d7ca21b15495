/* hbp.c: hilbench protocol target library. See hbp.h and PROTOCOL.md. C99, no heap, no floats. */
#include "hbp.h"

uint16_t hbp_crc16_update(uint16_t crc, uint8_t byte)
{
    uint8_t bit;
    crc = (uint16_t)(crc ^ (uint16_t)((uint16_t)byte << 8));
    for (bit = 0u; bit < 8u; bit++) {
        if ((crc & 0x8000u) != 0u) {
            crc = (uint16_t)((uint16_t)(crc << 1) ^ 0x1021u);
        } else {
            crc = (uint16_t)(crc << 1);
        }
    }
    return crc;
}

uint16_t hbp_crc16(const uint8_t *data, uint8_t len)
{
    uint16_t crc = HBP_CRC_INIT;
    uint8_t i;
    for (i = 0u; i < len; i++) {
        crc = hbp_crc16_update(crc, data[i]);
    }
    return crc;
}

uint8_t hbp_encode_frame(const uint8_t *frame, uint8_t len, uint8_t *out)
{
    uint16_t crc;
    uint8_t total;
    uint8_t i;
    uint8_t code_at = 0u; /* where the current block's code byte goes */
    uint8_t o = 1u;       /* next output position */
    if (len < 2u || len > (uint8_t)(HBP_MAX_FRAME - 2u)) {
        return 0u;
    }
    crc = hbp_crc16(frame, len);
    total = (uint8_t)(len + 2u);
    for (i = 0u; i < total; i++) {
        uint8_t b;
        if (i < len) {
            b = frame[i];
        } else if (i == len) {
            b = (uint8_t)(crc >> 8); /* high byte first: the wire bit order is the division's */
        } else {
            b = (uint8_t)(crc & 0xFFu);
        }
        if (b == 0u) {
            out[code_at] = (uint8_t)(o - code_at);
            code_at = o;
            o++;
        } else {
            out[o] = b;
            o++;
        }
    }
    out[code_at] = (uint8_t)(o - code_at);
    out[o] = 0u;
    o++;
    return o;
}

static void rx_restart(hbp_rx_t *rx)
{
    rx->len = 0u;
    rx->remaining = 0u;
    rx->flags = (uint8_t)(rx->flags & HBP_RX_F_BAD);
}

static void rx_fail(hbp_rx_t *rx, uint8_t error)
{
    rx->errors++;
    rx->last_error = error;
    rx->flags = (uint8_t)(rx->flags | HBP_RX_F_BAD);
}

void hbp_rx_init(hbp_rx_t *rx)
{
    uint8_t i;
    for (i = 0u; i < HBP_RX_MAX; i++) {
        rx->buf[i] = 0u;
    }
    rx->len = 0u;
    rx->remaining = 0u;
    rx->flags = 0u;
    rx->ready = 0u;
    rx->frame_len = 0u;
    rx->frames = 0u;
    rx->errors = 0u;
    rx->resyncs = 0u;
    rx->unknown = 0u;
    rx->overruns = 0u;
    rx->last_error = HBP_ERROR_NONE;
}

static uint8_t rx_end_of_frame(hbp_rx_t *rx)
{
    uint16_t crc;
    uint8_t n = rx->len;
    if (rx->remaining != 0u) {
        rx_fail(rx, HBP_ERROR_COBS); /* the last block is shorter than its code byte says */
        return 0u;
    }
    if (n < 4u) {
        rx_fail(rx, HBP_ERROR_LENGTH);
        return 0u;
    }
    crc = hbp_crc16(rx->buf, (uint8_t)(n - 2u));
    if (crc != (uint16_t)((uint16_t)((uint16_t)rx->buf[n - 2u] << 8) | (uint16_t)rx->buf[n - 1u])) {
        rx_fail(rx, HBP_ERROR_CRC);
        return 0u;
    }
    if (!hbp_type_known(rx->buf[0])) {
        rx->unknown++;
        rx->last_error = HBP_ERROR_UNKNOWN_TYPE;
        rx->flags = (uint8_t)(rx->flags | HBP_RX_F_BAD);
        return 0u;
    }
    rx->frames++;
    if ((rx->flags & HBP_RX_F_BAD) != 0u) {
        rx->resyncs++;
        rx->flags = (uint8_t)(rx->flags & (uint8_t)~HBP_RX_F_BAD);
    }
    rx->frame_len = (uint8_t)(n - 2u);
    rx->ready = 1u;
    return 1u;
}

uint8_t hbp_rx_byte(hbp_rx_t *rx, uint8_t byte)
{
    uint8_t got = 0u;
    if (byte == 0u) {
        if ((rx->flags & (HBP_RX_F_STARTED | HBP_RX_F_DISCARD)) == HBP_RX_F_STARTED) {
            got = rx_end_of_frame(rx);
        }
        rx->flags = (uint8_t)(rx->flags & (uint8_t)~(HBP_RX_F_STARTED | HBP_RX_F_DISCARD));
        rx_restart(rx);
        return got;
    }
    if ((rx->flags & HBP_RX_F_DISCARD) != 0u) {
        return 0u;
    }
    rx->flags = (uint8_t)(rx->flags | HBP_RX_F_STARTED);
    if (rx->ready != 0u) {
        /* the main loop still holds the previous frame: drop this one whole */
        rx->overruns++;
        rx->last_error = HBP_ERROR_OVERRUN;
        rx->flags = (uint8_t)(rx->flags | HBP_RX_F_DISCARD | HBP_RX_F_BAD);
        return 0u;
    }
    if (rx->remaining == 0u) {
        /* a code byte: the previous block (if any) ends with an implied zero */
        if ((rx->flags & HBP_RX_F_ZERO) != 0u) {
            if (rx->len >= HBP_RX_MAX) {
                rx_fail(rx, HBP_ERROR_OVERSIZED);
                rx->flags = (uint8_t)(rx->flags | HBP_RX_F_DISCARD);
                return 0u;
            }
            rx->buf[rx->len] = 0u;
            rx->len++;
        }
        rx->remaining = (uint8_t)(byte - 1u);
        if (byte == 0xFFu) {
            rx->flags = (uint8_t)(rx->flags & (uint8_t)~HBP_RX_F_ZERO);
        } else {
            rx->flags = (uint8_t)(rx->flags | HBP_RX_F_ZERO);
        }
        return 0u;
    }
    if (rx->len >= HBP_RX_MAX) {
        rx_fail(rx, HBP_ERROR_OVERSIZED);
        rx->flags = (uint8_t)(rx->flags | HBP_RX_F_DISCARD);
        return 0u;
    }
    rx->buf[rx->len] = byte;
    rx->len++;
    rx->remaining--;
    return 0u;
}

void hbp_rx_release(hbp_rx_t *rx)
{
    rx->ready = 0u;
}

void hbp_rx_status(const hbp_rx_t *rx, uint8_t seq, uint16_t watchdog_trips, hbp_status_t *out)
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

uint8_t hbp_check_hello(const hbp_host_hello_t *hello)
{
    if (hello->protocol_version != HBP_PROTOCOL_VERSION || hello->schema_fingerprint != HBP_SCHEMA_FINGERPRINT) {
        return HBP_ERROR_VERSION;
    }
    return HBP_ERROR_NONE;
}

uint8_t hbp_check_host_hello(const uint8_t *frame, uint8_t len, hbp_host_hello_t *out)
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

void hbp_error_report(uint8_t seq, uint8_t code, uint8_t detail, hbp_error_report_t *out)
{
    out->seq = seq;
    out->code = code;
    out->detail = detail;
    out->schema_fingerprint = HBP_SCHEMA_FINGERPRINT;
}

int32_t hbp_param_candidate(const hbp_params_t *params, const hbp_param_set_t *request, uint8_t id)
{
    uint8_t i;
    int32_t value = params->values[id];
    for (i = 0u; i < request->n_pairs; i++) {
        if (request->pairs[i].id == id) {
            value = request->pairs[i].value;
        }
    }
    return value;
}

uint8_t hbp_param_describe(const hbp_params_t *params, uint8_t id, uint8_t seq, hbp_param_info_t *out)
{
    const hbp_param_def_t *def;
    uint8_t i;
    out->seq = seq;
    if (id >= params->count) {
        return HBP_RESULT_UNKNOWN_ID;
    }
    def = &params->defs[id];
    out->param_id = id;
    out->ptype = def->ptype;
    out->access = def->access;
    out->min_value = def->min_value;
    out->max_value = def->max_value;
    out->value = params->values[id];
    for (i = 0u; i < HBP_MAX_NAME && def->name[i] != '\0'; i++) {
        out->name[i] = def->name[i];
    }
    out->name[i] = '\0';
    return HBP_RESULT_OK;
}

void hbp_param_get(const hbp_params_t *params, uint8_t id, uint8_t seq, hbp_param_value_t *out)
{
    out->seq = seq;
    out->param_id = id;
    if (id >= params->count) {
        out->result = HBP_RESULT_UNKNOWN_ID;
        out->value = 0;
        return;
    }
    out->result = HBP_RESULT_OK;
    out->value = params->values[id];
}

void hbp_param_set(hbp_params_t *params, const hbp_param_set_t *request, uint8_t seq,
                   hbp_param_set_result_t *out)
{
    uint8_t i;
    uint8_t j;
    out->seq = seq;
    out->param_id = 0u;
    out->detail = 0u;
    if (request->n_pairs == 0u || request->n_pairs > HBP_MAX_PARAM_PAIRS) {
        out->result = HBP_RESULT_BAD_REQUEST;
        return;
    }
    for (i = 0u; i < request->n_pairs; i++) {
        uint8_t id = request->pairs[i].id;
        int32_t value = request->pairs[i].value;
        out->param_id = id;
        if (id >= params->count) {
            out->result = HBP_RESULT_UNKNOWN_ID;
            return;
        }
        if (params->defs[id].access != HBP_ACCESS_RW) {
            out->result = HBP_RESULT_READ_ONLY;
            return;
        }
        if (value < params->defs[id].min_value || value > params->defs[id].max_value) {
            out->result = HBP_RESULT_OUT_OF_RANGE;
            return;
        }
        for (j = 0u; j < i; j++) {
            if (request->pairs[j].id == id) {
                out->result = HBP_RESULT_BAD_REQUEST; /* the same id twice */
                return;
            }
        }
    }
    if (params->check != 0) {
        uint8_t bad_id = 0u;
        uint8_t detail = 0u;
        uint8_t result = params->check(params, request, &bad_id, &detail);
        if (result != HBP_RESULT_OK) {
            out->result = result;
            out->param_id = bad_id;
            out->detail = detail;
            return;
        }
    }
    for (i = 0u; i < request->n_pairs; i++) {
        params->values[request->pairs[i].id] = request->pairs[i].value;
    }
    out->result = HBP_RESULT_OK;
    out->param_id = 0u;
}
