/* loopback_core.c: the documented loopback mapping of PROTOCOL.md on the C library, platform-free.
 *
 * The Sensors -> Drive mapping is identical to the Python loopback target, so end-to-end tests can
 * assert exact values. The platform supplies loopback_send (a tty on a PC: loopback_target.c; a UART
 * on an AVR: avr_loopback.c) and feeds received bytes to hbp_rx_byte(&loopback_rx, byte). Each
 * platform file #includes this file, so building a target stays one source file plus the library.
 */
#include <string.h>

#include "loopback_core.h"

static int send_frame(const uint8_t *frame, uint8_t len)
{
    uint8_t out[HBP_MAX_WIRE];
    uint8_t n = hbp_encode_frame(frame, len, out);
    return loopback_send(out, n);
}

hbp_rx_t loopback_rx;
static uint8_t running = 0u;
static uint8_t last_s2 = 0u;
/* A Sensors repeating the last seq (a duplicated frame) gets the last Drive again, no second step. */
static hbp_drive_t last_drive;
static uint8_t have_last_drive = 0u;

static const hbp_param_def_t param_defs[3] = {
    {"kp", 0, 32767, HBP_PTYPE_Q15, HBP_ACCESS_RW},
    {"ki", 0, 32767, HBP_PTYPE_Q15, HBP_ACCESS_RW},
    {"version", 1, 1, HBP_PTYPE_INT, HBP_ACCESS_RO},
};
static int32_t param_values[3] = {3277, 328, 1};

/* Constraint 1: kp + ki <= 32767. */
static uint8_t check_params(const hbp_params_t *p, const hbp_param_set_t *req, uint8_t *param_id, uint8_t *detail)
{
    int32_t sum = hbp_param_candidate(p, req, 0u) + hbp_param_candidate(p, req, 1u); /* both <= 32767 */
    if (sum > 32767L) {
        *param_id = 0u;
        *detail = 1u;
        return HBP_RESULT_CONSTRAINT;
    }
    return HBP_RESULT_OK;
}

static hbp_params_t params = {param_defs, param_values, 3u, check_params};

static int send_error(uint8_t seq, uint8_t code, uint8_t detail)
{
    hbp_error_report_t e;
    uint8_t frame[HBP_MAX_FRAME];
    hbp_error_report(seq, code, detail, &e);
    return send_frame(frame, hbp_pack_error_report(&e, frame));
}

static uint8_t sector_from_halls(uint8_t inputs)
{
    /* AN1017 Table 8, C B A -> sector */
    static const uint8_t table[8] = {7u, 4u, 2u, 3u, 0u, 5u, 1u, 7u};
    return table[inputs & 0x07u];
}

static int16_t as_int16(uint16_t u)
{
    return (u < 0x8000u) ? (int16_t)u : (int16_t)(-(int16_t)(0xFFFFu - u) - 1);
}

static uint16_t duty_from_adc(const hbp_sensors_t *s, uint8_t i)
{
    if (i >= s->n_adc) {
        return 0u;
    }
    return s->adc[i]; /* the full u16: a duty is a compare count of pwm_period_counts */
}

int loopback_handle(const uint8_t *buf, uint8_t len)
{
    uint8_t frame[HBP_MAX_FRAME];
    uint8_t type = buf[0];
    uint8_t seq = buf[1];
    switch (type) {
    case HBP_MSG_HOST_HELLO: {
        hbp_host_hello_t h;
        hbp_target_hello_t t;
        uint8_t check = hbp_check_host_hello(buf, len, &h);
        if (check == HBP_ERROR_VERSION) {
            return send_error(seq, HBP_ERROR_VERSION, HBP_PROTOCOL_VERSION);
        }
        if (check != HBP_ERROR_NONE) {
            return send_error(seq, HBP_ERROR_LENGTH, type);
        }
        memset(&t, 0, sizeof t);
        t.seq = seq;
        t.protocol_version = HBP_PROTOCOL_VERSION;
        t.schema_fingerprint = HBP_SCHEMA_FINGERPRINT;
        t.firmware_version = 1u;
        t.pwm_period_counts = 1000u;
        t.pwm_freq_hz = 20000u;
        t.n_params = params.count;
        t.adc_bits = 10u;
        strcpy(t.firmware_name, "loopback");
        t.n_adc_roles = 3u;
        t.adc_roles[0] = HBP_ADC_POT;
        t.adc_roles[1] = HBP_ADC_IBUS;
        t.adc_roles[2] = HBP_ADC_VBUS;
        t.n_telemetry_ids = 3u;
        t.telemetry_ids[0] = HBP_TELEMETRY_ECHO_ENCODER;
        t.telemetry_ids[1] = HBP_TELEMETRY_ECHO_EDGE;
        t.telemetry_ids[2] = HBP_TELEMETRY_ECHO_SEQ;
        running = 0u;
        have_last_drive = 0u;
        return send_frame(frame, hbp_pack_target_hello(&t, frame));
    }
    case HBP_MSG_SENSORS: {
        hbp_sensors_t s;
        hbp_drive_t d;
        uint8_t s2;
        if (hbp_unpack_sensors(buf, len, &s) != HBP_ERROR_NONE) {
            return send_error(seq, HBP_ERROR_LENGTH, type);
        }
        if (have_last_drive && s.seq == last_drive.seq) {
            return send_frame(frame, hbp_pack_drive(&last_drive, frame));
        }
        s2 = (uint8_t)((s.inputs & HBP_INPUT_S2) != 0u);
        if (s2 && !last_s2) {
            running = (uint8_t)!running;
        }
        last_s2 = s2;
        d.seq = s.seq;
        d.duty_a = duty_from_adc(&s, 0u);
        d.duty_b = duty_from_adc(&s, 1u);
        d.duty_c = duty_from_adc(&s, 2u);
        d.output_mode = running ? HBP_OUTPUT_PWM : HBP_OUTPUT_OFF;
        d.state = running ? HBP_STATE_RUNNING : HBP_STATE_STOPPED;
        d.sector = sector_from_halls(s.inputs);
        d.direction_ccw = (uint8_t)((s.inputs & HBP_INPUT_S3) != 0u);
        d.required_ccw = 0u;
        d.fault = HBP_FAULT_NONE;
        d.n_telemetry = 3u;
        d.telemetry[0] = as_int16(s.encoder);
        d.telemetry[1] = (s.n_edges > 0u) ? as_int16(s.edges[0].time_100ns) : -1; /* the first edge's time */
        d.telemetry[2] = (int16_t)s.seq;
        last_drive = d;
        have_last_drive = 1u;
        return send_frame(frame, hbp_pack_drive(&d, frame));
    }
    case HBP_MSG_PARAM_DESCRIBE: {
        hbp_param_describe_t q;
        hbp_param_info_t info;
        if (hbp_unpack_param_describe(buf, len, &q) != HBP_ERROR_NONE) {
            return send_error(seq, HBP_ERROR_LENGTH, type);
        }
        if (hbp_param_describe(&params, q.param_id, seq, &info) != HBP_RESULT_OK) {
            return send_error(seq, HBP_ERROR_UNKNOWN_PARAM, q.param_id);
        }
        return send_frame(frame, hbp_pack_param_info(&info, frame));
    }
    case HBP_MSG_PARAM_GET: {
        hbp_param_get_t q;
        hbp_param_value_t v;
        if (hbp_unpack_param_get(buf, len, &q) != HBP_ERROR_NONE) {
            return send_error(seq, HBP_ERROR_LENGTH, type);
        }
        hbp_param_get(&params, q.param_id, seq, &v);
        return send_frame(frame, hbp_pack_param_value(&v, frame));
    }
    case HBP_MSG_PARAM_SET: {
        hbp_param_set_t q;
        hbp_param_set_result_t r;
        if (hbp_unpack_param_set(buf, len, &q) != HBP_ERROR_NONE) {
            return send_error(seq, HBP_ERROR_LENGTH, type);
        }
        hbp_param_set(&params, &q, seq, &r);
        return send_frame(frame, hbp_pack_param_set_result(&r, frame));
    }
    case HBP_MSG_START:
    case HBP_MSG_STOP:
        if (len != 2u) {
            return send_error(seq, HBP_ERROR_LENGTH, type);
        }
        running = (uint8_t)(type == HBP_MSG_START);
        have_last_drive = 0u;
        return 0;
    case HBP_MSG_TARGET_DESCRIBE: {
        hbp_target_info_t info;
        if (len != 2u) {
            return send_error(seq, HBP_ERROR_LENGTH, type);
        }
        memset(&info, 0, sizeof info);
        info.seq = seq;
        info.duty_timing = HBP_DUTY_IMMEDIATE;
        info.duty_report = HBP_REPORT_WRITTEN;
        info.inputs = (uint8_t)(HBP_INPUT_HALL_A | HBP_INPUT_HALL_B | HBP_INPUT_HALL_C | HBP_INPUT_S2 | HBP_INPUT_S3);
        info.encoder_counts = 0u;
        info.max_edges = (uint8_t)HBP_MAX_EDGES;
        return send_frame(frame, hbp_pack_target_info(&info, frame));
    }
    case HBP_MSG_TELEMETRY_DESCRIBE: {
        static const char *const names[3] = {"echo_encoder", "echo_edge", "echo_seq"};
        static const char *const units[3] = {"counts", "100ns", ""};
        hbp_telemetry_info_t info;
        uint8_t index;
        if (len != 3u) {
            return send_error(seq, HBP_ERROR_LENGTH, type);
        }
        index = buf[2];
        if (index >= 3u) {
            return send_error(seq, HBP_ERROR_UNKNOWN_TELEMETRY, index);
        }
        memset(&info, 0, sizeof info);
        info.seq = seq;
        info.index = index;
        info.telemetry_id = (uint8_t)(HBP_TELEMETRY_ECHO_ENCODER + index);
        info.ptype = HBP_PTYPE_INT;
        info.scale_num = 1;
        info.scale_den = 1;
        strcpy(info.name, names[index]);
        strcpy(info.unit, units[index]);
        return send_frame(frame, hbp_pack_telemetry_info(&info, frame));
    }
    case HBP_MSG_STATUS_REQUEST: {
        hbp_status_t st;
        if (len != 2u) {
            return send_error(seq, HBP_ERROR_LENGTH, type);
        }
        hbp_rx_status(&loopback_rx, seq, 0u, &st);
        return send_frame(frame, hbp_pack_status(&st, frame));
    }
    default:
        return send_error(seq, HBP_ERROR_BAD_REQUEST, type); /* a target -> host message */
    }
}
