/* an1017_bridge.c: see an1017_bridge.h. */
#include "an1017_bridge.h"

/* The rare requests (handshake, parameters) keep their message structs in their own frames, off
 * the lockstep path's stack (GCC and XC16; other compilers may inline them). */
#if defined(__GNUC__)
#define AN1017_NOINLINE __attribute__((noinline))
#else
#define AN1017_NOINLINE
#endif

/* Declared parameters (ids 0..7, the same table as hilbench/targets/an1017.py's PARAMS). */
static const hbp_param_def_t param_defs[AN1017_N_PARAMS] = {
    {"kp", 0, 32767, HBP_PTYPE_Q15, HBP_ACCESS_RW},
    {"ki", 0, 32767, HBP_PTYPE_Q15, HBP_ACCESS_RW},
    {"kd", 0, 32767, HBP_PTYPE_Q15, HBP_ACCESS_RW},
    {"ph_adv_on", 0, 1, HBP_PTYPE_BOOL, HBP_ACCESS_RW},
    {"ph_adv_deg", 0, 60, HBP_PTYPE_INT, HBP_ACCESS_RW},
    {"ref_ovr_on", 0, 1, HBP_PTYPE_BOOL, HBP_ACCESS_RW},
    {"ref_override", -32767 - 1, 32767, HBP_PTYPE_Q15, HBP_ACCESS_RW},
    {"stall_ms", 10, 30000, HBP_PTYPE_INT, HBP_ACCESS_RW},
};

static uint8_t is_gain(uint8_t id)
{
    return (uint8_t)(id <= AN1017_PARAM_KD);
}

/* The note's PID constraints on the candidate gains, checked only when a gain is written. The
 * offending id is the first written gain that takes part in the broken constraint. */
static uint8_t check_gains(const struct hbp_params *params, const hbp_param_set_t *request, uint8_t *param_id,
                           uint8_t *detail)
{
    uint8_t i;
    uint8_t broken;
    uint8_t first_gain = 0xFFu;
    for (i = 0u; i < request->n_pairs; i++) {
        if (is_gain(request->pairs[i].id) && first_gain == 0xFFu) {
            first_gain = request->pairs[i].id;
        }
    }
    if (first_gain == 0xFFu) {
        return HBP_RESULT_OK;
    }
    broken = an1017_check_gains(hbp_param_candidate(params, request, AN1017_PARAM_KP),
                                hbp_param_candidate(params, request, AN1017_PARAM_KI),
                                hbp_param_candidate(params, request, AN1017_PARAM_KD));
    if (broken == 0u) {
        return HBP_RESULT_OK;
    }
    *param_id = first_gain;
    for (i = 0u; i < request->n_pairs; i++) {
        uint8_t id = request->pairs[i].id;
        uint8_t involved = (uint8_t)((broken == 1u && is_gain(id)) ||
                                     (broken == 2u && (id == AN1017_PARAM_KP || id == AN1017_PARAM_KD)) ||
                                     (broken == 3u && id == AN1017_PARAM_KD));
        if (involved) {
            *param_id = id;
            break;
        }
    }
    *detail = broken;
    return HBP_RESULT_CONSTRAINT;
}

static void params_of(an1017_bridge_t *b, hbp_params_t *p)
{
    uint8_t i;
    for (i = 0u; i < AN1017_N_PARAMS; i++) {
        b->values[i] = an1017_param_value(&b->fw, i);
    }
    p->defs = param_defs;
    p->values = b->values;
    p->count = AN1017_N_PARAMS;
    p->check = check_gains;
}

void an1017_bridge_init(an1017_bridge_t *b, uint8_t variant)
{
    an1017_init(&b->fw, variant);
    hbp_rx_init(&b->rx);
    b->period_tcy = (uint32_t)AN1017_PERIOD_STEP_US * AN1017_TCY_PER_US;
    b->last_sensors_tcy = 0u;
    b->watchdog_ms = 0u;
    b->watchdog_trips = 0u;
    b->mode = HBP_MODE_LOCKSTEP;
    b->have_sensors = 0u;
    b->tripped = 0u;
    b->last_error = HBP_ERROR_NONE;
    b->last_seq = 0u;
    b->answered = 0u;
}

#define TX (&b->wire[1]) /* where a reply is packed */

/* Encode in place and send the frame packed at b->wire[1] (len 0: the pack function refused it).
 * In place is safe with hbp_encode_frame's single forward pass: it computes the CRC first, output
 * byte i + 1 is input byte i (a data byte lands on itself) and a code byte goes to the position of
 * a byte already read (or wire[0]); the CRC and the delimiter land after the frame. The SIL and AVR
 * tests exercise every reply type through this path. */
static void send_frame(an1017_bridge_t *b, uint8_t len)
{
    uint8_t n;
    if (len == 0u || len > AN1017_TX_FRAME_MAX) {
        return;
    }
    n = hbp_encode_frame(TX, len, b->wire);
    if (n > 0u) {
        an1017_port_send(b->wire, n);
    }
}

static void send_error(an1017_bridge_t *b, uint8_t seq, uint8_t code, uint8_t detail)
{
    hbp_error_report_t e;
    hbp_error_report(seq, code, detail, &e); /* carries this build's schema fingerprint */
    b->last_error = code;
    send_frame(b, hbp_pack_error_report(&e, TX));
}

void an1017_bridge_send_drive(an1017_bridge_t *b, uint8_t seq)
{
    hbp_drive_t d;
    d.seq = seq;
    d.duty_a = an1017_duty(&b->fw, 0u);
    d.duty_b = an1017_duty(&b->fw, 1u);
    d.duty_c = an1017_duty(&b->fw, 2u);
    d.output_mode = b->fw.output_mode;
    d.state = b->fw.state;
    d.sector = an1017_sector_reported(&b->fw);
    d.direction_ccw = b->fw.cur_ccw;
    d.required_ccw = b->fw.req_ccw;
    d.fault = b->fw.fault;
    d.n_telemetry = 3u;
    d.telemetry[0] = b->fw.ref_speed;
    d.telemetry[1] = b->fw.measured_speed;
    d.telemetry[2] = b->fw.control_output;
    send_frame(b, hbp_pack_drive(&d, TX));
}

static AN1017_NOINLINE void on_hello(an1017_bridge_t *b, const uint8_t *buf, uint8_t len, uint8_t seq)
{
    hbp_host_hello_t h;
    hbp_target_hello_t t;
    uint8_t i;
    uint8_t err = hbp_check_host_hello(buf, len, &h); /* version and schema fingerprint */
    if (err == HBP_ERROR_VERSION) {
        send_error(b, seq, HBP_ERROR_VERSION, HBP_PROTOCOL_VERSION);
        return;
    }
    if (err != HBP_ERROR_NONE) {
        send_error(b, seq, HBP_ERROR_LENGTH, buf[0]);
        return;
    }
    if (h.period_us == 0u || h.period_us % AN1017_PERIOD_STEP_US != 0u ||
        (h.mode != HBP_MODE_LOCKSTEP && h.mode != HBP_MODE_REALTIME)) {
        send_error(b, seq, HBP_ERROR_BAD_REQUEST, 0u);
        return;
    }
    b->period_tcy = (uint32_t)h.period_us * AN1017_TCY_PER_US;
    b->mode = h.mode;
    b->watchdog_ms = h.watchdog_ms;
    b->have_sensors = 0u;
    b->tripped = 0u;
    b->answered = 0u; /* a new session numbers its Sensors from 0 again */
    t.seq = seq;
    t.protocol_version = HBP_PROTOCOL_VERSION;
    t.schema_fingerprint = HBP_SCHEMA_FINGERPRINT;
    t.adc_bits = AN1017_ADC_BITS;
    t.firmware_version = AN1017_FIRMWARE_VERSION;
    t.pwm_period_counts = AN1017_DUTY_MAX;
    t.pwm_freq_hz = AN1017_PWM_FREQ_HZ;
    t.n_params = AN1017_N_PARAMS;
    for (i = 0u; AN1017_FIRMWARE_NAME[i] != '\0'; i++) {
        t.firmware_name[i] = AN1017_FIRMWARE_NAME[i];
    }
    t.firmware_name[i] = '\0';
    t.n_adc_roles = 3u; /* AN2 pot, AN1 bus current, AN0 bus voltage: only the pot is used */
    t.adc_roles[0] = HBP_ADC_POT;
    t.adc_roles[1] = HBP_ADC_IBUS;
    t.adc_roles[2] = HBP_ADC_VBUS;
    t.n_telemetry_ids = 3u;
    t.telemetry_ids[0] = HBP_TELEMETRY_REF_SPEED;
    t.telemetry_ids[1] = HBP_TELEMETRY_MEASURED_SPEED;
    t.telemetry_ids[2] = HBP_TELEMETRY_CONTROL_OUTPUT;
    send_frame(b, hbp_pack_target_hello(&t, TX));
}

static AN1017_NOINLINE void on_sensors(an1017_bridge_t *b, const uint8_t *buf, uint8_t len, uint8_t seq)
{
    hbp_sensors_t s;
    uint32_t span = b->period_tcy;
    if (hbp_unpack_sensors(buf, len, &s) != HBP_ERROR_NONE) {
        send_error(b, seq, HBP_ERROR_LENGTH, buf[0]);
        return;
    }
    if (b->answered && s.seq == b->last_seq) {
        /* the host sent it again (our Drive was lost or late): the same answer, no second step */
        an1017_bridge_send_drive(b, s.seq);
        return;
    }
    if (b->mode == HBP_MODE_REALTIME) {
        uint32_t now = an1017_port_now_tcy();
        if (b->have_sensors) {
            span = now - b->last_sensors_tcy; /* the time that really passed */
        }
        b->last_sensors_tcy = now;
        b->have_sensors = 1u;
        b->tripped = 0u;
    }
    if (span > 0u) { /* (real time: no Tcy has passed, nothing to run, as the Python model) */
        an1017_run(&b->fw, span, s.inputs, (uint8_t)(s.edge_time_100ns != HBP_EDGE_NONE),
                   (uint32_t)s.edge_time_100ns * 2u, (uint8_t)(s.n_adc > 0u), (s.n_adc > 0u) ? s.adc[0] : 0u);
    }
    b->last_seq = s.seq;
    b->answered = 1u;
    an1017_bridge_send_drive(b, s.seq);
}

static AN1017_NOINLINE void on_params(an1017_bridge_t *b, const uint8_t *buf, uint8_t len, uint8_t seq)
{
    hbp_params_t p;
    params_of(b, &p);
    switch (buf[0]) {
    case HBP_MSG_PARAM_DESCRIBE: {
        hbp_param_describe_t q;
        hbp_param_info_t info;
        if (hbp_unpack_param_describe(buf, len, &q) != HBP_ERROR_NONE) {
            send_error(b, seq, HBP_ERROR_LENGTH, buf[0]);
        } else if (hbp_param_describe(&p, q.param_id, seq, &info) != HBP_RESULT_OK) {
            send_error(b, seq, HBP_ERROR_UNKNOWN_PARAM, q.param_id);
        } else {
            send_frame(b, hbp_pack_param_info(&info, TX));
        }
        break;
    }
    case HBP_MSG_PARAM_GET: {
        hbp_param_get_t q;
        hbp_param_value_t v;
        if (hbp_unpack_param_get(buf, len, &q) != HBP_ERROR_NONE) {
            send_error(b, seq, HBP_ERROR_LENGTH, buf[0]);
        } else {
            hbp_param_get(&p, q.param_id, seq, &v);
            send_frame(b, hbp_pack_param_value(&v, TX));
        }
        break;
    }
    default: { /* HBP_MSG_PARAM_SET: checked whole, applied all or nothing */
        hbp_param_set_t q;
        hbp_param_set_result_t r;
        uint8_t i;
        uint8_t gains = 0u;
        if (hbp_unpack_param_set(buf, len, &q) != HBP_ERROR_NONE) {
            send_error(b, seq, HBP_ERROR_LENGTH, buf[0]);
            break;
        }
        hbp_param_set(&p, &q, seq, &r);
        if (r.result == HBP_RESULT_OK) {
            for (i = 0u; i < q.n_pairs; i++) {
                gains = (uint8_t)(gains | is_gain(q.pairs[i].id));
            }
            an1017_port_lock();
            an1017_apply_params(&b->fw, b->values, gains);
            an1017_port_unlock();
            r.param_id = q.pairs[q.n_pairs - 1u].id; /* as the Python model answers */
        }
        send_frame(b, hbp_pack_param_set_result(&r, TX));
        break;
    }
    }
}

void an1017_bridge_handle(an1017_bridge_t *b, const uint8_t *frame, uint8_t len)
{
    uint8_t type = frame[0];
    uint8_t seq = frame[1];
    switch (type) {
    case HBP_MSG_SENSORS:
        on_sensors(b, frame, len, seq);
        break;
    case HBP_MSG_HOST_HELLO:
        on_hello(b, frame, len, seq);
        break;
    case HBP_MSG_PARAM_DESCRIBE:
    case HBP_MSG_PARAM_GET:
    case HBP_MSG_PARAM_SET:
        on_params(b, frame, len, seq);
        break;
    case HBP_MSG_START:
        an1017_port_lock();
        an1017_press_start(&b->fw); /* S2 as a command; no reply */
        an1017_port_unlock();
        break;
    case HBP_MSG_STOP:
        an1017_port_lock();
        if (b->fw.running || b->fw.booting) {
            an1017_press_stop(&b->fw, AN1017_STATE_STOPPED, AN1017_FAULT_NONE);
        }
        an1017_port_unlock();
        break;
    case HBP_MSG_STATUS_REQUEST: {
        hbp_status_t st;
        hbp_rx_status(&b->rx, seq, b->watchdog_trips, &st);
        if (b->last_error != HBP_ERROR_NONE) {
            st.last_error = b->last_error;
        }
        send_frame(b, hbp_pack_status(&st, TX));
        break;
    }
    default:
        send_error(b, seq, HBP_ERROR_BAD_REQUEST, 0u); /* a target -> host message */
        break;
    }
}

void an1017_bridge_watchdog(an1017_bridge_t *b)
{
    if (b->mode == HBP_MODE_REALTIME && b->watchdog_ms != 0u && b->have_sensors && !b->tripped) {
        uint32_t quiet = an1017_port_now_tcy() - b->last_sensors_tcy;
        if (quiet >= (uint32_t)b->watchdog_ms * 1000UL * AN1017_TCY_PER_US) {
            /* frames stopped: StopMotor, state FAULT, fault WATCHDOG, one unsolicited Drive */
            b->tripped = 1u;
            b->watchdog_trips = (uint16_t)(b->watchdog_trips + 1u);
            b->last_error = HBP_ERROR_WATCHDOG;
            an1017_port_lock();
            an1017_press_stop(&b->fw, AN1017_STATE_FAULT, AN1017_FAULT_WATCHDOG);
            an1017_port_unlock();
            an1017_bridge_send_drive(b, b->last_seq);
        }
    }
}

void an1017_bridge_poll(an1017_bridge_t *b)
{
    if (b->rx.ready) {
        an1017_bridge_handle(b, b->rx.buf, b->rx.frame_len);
        hbp_rx_release(&b->rx);
    }
    an1017_bridge_watchdog(b);
}
