/* hrt_link.c: the runtime's protocol side (see hrt_link.h). */
#include "hrt_link.h"

/* The rare requests (handshake, parameters) keep their message structs in their own frames, off
 * the lockstep path's stack (GCC and XC16; other compilers may inline them). */
#if defined(__GNUC__)
#define HRT_NOINLINE __attribute__((noinline))
#else
#define HRT_NOINLINE
#endif

#define TX (&l->wire[1]) /* where a reply is packed */

static uint8_t name_len(const char *s, uint8_t max)
{
    uint8_t n = 0u;
    while (n < max && s[n] != '\0') {
        n++;
    }
    return n;
}

/* A little-endian two's-complement i32 (no implementation-defined conversion). */
static int32_t get_i32(const uint8_t *p)
{
    uint32_t u = (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
    if (u < 0x80000000UL) {
        return (int32_t)u;
    }
    return (int32_t)(-(int32_t)(0xFFFFFFFFUL - u) - 1);
}

void hrt_link_init(hrt_link_t *l, hrt_t *rt)
{
    l->rt = rt;
    hbp_rx_init(&l->rx);
    l->period_us = 0u;
    l->last_rx = 0u;
    l->watchdog_ms = 0u;
    l->watchdog_trips = 0u;
    l->mode = HBP_MODE_LOCKSTEP;
    l->flags = 0u;
    l->last_error = HBP_ERROR_NONE;
    l->last_seq = 0u;
}

/* Encode in place and send the frame packed at l->wire[1] (len 0: nothing). In place is safe with
 * hbp_encode_frame's single forward pass: it computes the CRC first, output byte i + 1 is input
 * byte i (a data byte lands on itself) and a code byte goes to the position of a byte already read
 * (or wire[0]); the CRC and the delimiter land after the frame. */
static void send_frame(hrt_link_t *l, uint8_t len)
{
    uint8_t n;
    if (len == 0u || len > HRT_TX_FRAME_MAX) {
        return;
    }
    n = hbp_encode_frame(TX, len, l->wire);
    if (n > 0u) {
        hrt_port_send(l->wire, n);
    }
}

static void send_error(hrt_link_t *l, uint8_t seq, uint8_t code, uint8_t detail)
{
    hbp_error_report_t e;
    hbp_error_report(seq, code, detail, &e); /* carries this build's schema fingerprint */
    l->last_error = code;
    send_frame(l, hbp_pack_error_report(&e, TX));
}

void hrt_link_send_drive(hrt_link_t *l, uint8_t seq)
{
    hbp_drive_t d;
    hrt_report(l->rt, seq, &d);
    send_frame(l, hbp_pack_drive(&d, TX));
}

/* TargetHello: the firmware's declaration (its own frame, off the handshake's). */
static HRT_NOINLINE void send_target_hello(hrt_link_t *l, uint8_t seq)
{
    const hrt_firmware_t *d = &hrt_firmware;
    hbp_target_hello_t t;
    uint8_t i;
    uint8_t n = name_len(d->name, HBP_MAX_NAME);
    t.seq = seq;
    t.protocol_version = HBP_PROTOCOL_VERSION;
    t.schema_fingerprint = HBP_SCHEMA_FINGERPRINT;
    t.adc_bits = d->adc_bits;
    t.firmware_version = d->version;
    t.pwm_period_counts = d->pwm_counts;
    t.pwm_freq_hz = (uint32_t)((uint32_t)d->ticks_per_us * 1000000UL / d->pwm_period_ticks);
    t.n_params = d->n_params;
    for (i = 0u; i < n; i++) {
        t.firmware_name[i] = d->name[i];
    }
    t.firmware_name[n] = '\0';
    t.n_adc_roles = (d->n_adc > HBP_MAX_ADC) ? (uint8_t)HBP_MAX_ADC : d->n_adc;
    for (i = 0u; i < t.n_adc_roles; i++) {
        t.adc_roles[i] = d->adc_roles[i];
    }
    t.n_telemetry_ids = d->n_telemetry;
    for (i = 0u; i < d->n_telemetry; i++) {
        t.telemetry_ids[i] = d->telemetry[i].id;
    }
    if ((uint8_t)(HBP_TARGET_HELLO_FIXED_LEN + 2u + n + t.n_adc_roles + d->n_telemetry) <= HRT_TX_FRAME_MAX) {
        send_frame(l, hbp_pack_target_hello(&t, TX)); /* (else the build's HRT_TX_FRAME_MAX is too small) */
    }
}

static HRT_NOINLINE void on_hello(hrt_link_t *l, const uint8_t *buf, uint8_t len, uint8_t seq)
{
    hbp_host_hello_t h;
    uint8_t err = hbp_check_host_hello(buf, len, &h); /* version and schema fingerprint */
    uint16_t step = hrt_firmware.period_step_us;
    if (err == HBP_ERROR_VERSION) {
        send_error(l, seq, HBP_ERROR_VERSION, HBP_PROTOCOL_VERSION);
        return;
    }
    if (err != HBP_ERROR_NONE) {
        send_error(l, seq, HBP_ERROR_LENGTH, buf[0]);
        return;
    }
    if (h.period_us == 0u || (step != 0u && h.period_us % step != 0u) ||
        (h.mode != HBP_MODE_LOCKSTEP && h.mode != HBP_MODE_REALTIME)) {
        send_error(l, seq, HBP_ERROR_BAD_REQUEST, 0u);
        return;
    }
#if defined(HRT_PORT_HW) && HRT_PORT_HW
    if ((l->flags & HRT_LINK_F_RT) != 0u) {
        hrt_port_realtime(0u);
        hrt_rt_enter(l->rt, 0u);
    }
#endif
    l->period_us = h.period_us;
    l->mode = h.mode;
    l->watchdog_ms = h.watchdog_ms;
    l->flags = HRT_LINK_F_HELLO; /* a new session numbers its Sensors from 0 again */
    send_target_hello(l, seq);
}

#if defined(HRT_PORT_HW) && HRT_PORT_HW
static void rt_hw_sensors(hrt_link_t *l, const uint8_t *buf, uint8_t n_adc);
#endif

static uint16_t get_u16(const uint8_t *p)
{
    return (uint16_t)((uint16_t)p[0] | (uint16_t)((uint16_t)p[1] << 8));
}

/* Sensors, read in place: inputs u8, edge time u16 (100 ns), encoder u16, ADC codes u16 to the end. */
#define SENSORS_INPUTS 2u
#define SENSORS_EDGE 3u
#define SENSORS_ENCODER 5u
#define SENSORS_ADC 7u

/* One span of the agreed period (lockstep) or of the time that passed (real time). */
static void run_span(hrt_link_t *l, const uint8_t *buf, uint8_t n_adc, uint32_t span)
{
    hrt_t *rt = l->rt;
    uint32_t start = rt->now;
    uint8_t inputs = buf[SENSORS_INPUTS];
    uint16_t edge = get_u16(&buf[SENSORS_EDGE]);
    uint8_t have_edge = (uint8_t)(edge != HBP_EDGE_NONE);
    uint16_t adc[HRT_MAX_ADC];
    uint8_t i;
    for (i = 0u; i < n_adc && i < HRT_MAX_ADC; i++) {
        adc[i] = get_u16(&buf[SENSORS_ADC + 2u * i]);
    }
    hrt_span_begin(rt, inputs, have_edge, 0u, adc, i, get_u16(&buf[SENSORS_ENCODER]));
    if (have_edge) {
        uint32_t off = (uint32_t)edge * hrt_firmware.ticks_per_us / 10u;
        if (off >= span) {
            off = span - 1u;
        }
        hrt_span_edge(rt, start + off, (uint8_t)(inputs & HRT_IN_HALLS));
    }
    hrt_span_end(rt, start + span);
}

#if defined(HRT_PORT_HW) && HRT_PORT_HW
/* Real time on a port whose interrupts run the bodies: a Sensors updates the inputs they read. A
 * hall change is captured at the frame's edge time, back-dated from now by the rest of the period
 * (an estimate: the frame's own transit is not known). */
static void rt_hw_sensors(hrt_link_t *l, const uint8_t *buf, uint8_t n_adc)
{
    hrt_t *rt = l->rt;
    uint32_t now = hrt_port_now();
    uint8_t inputs = buf[SENSORS_INPUTS];
    uint16_t edge = get_u16(&buf[SENSORS_EDGE]);
    uint16_t adc[HRT_MAX_ADC];
    uint8_t i;
    if ((l->flags & HRT_LINK_F_RT) == 0u) {
        l->flags = (uint8_t)(l->flags | HRT_LINK_F_RT);
        hrt_rt_enter(rt, 1u);
        hrt_port_realtime(1u);
    }
    for (i = 0u; i < n_adc && i < HRT_MAX_ADC; i++) {
        adc[i] = get_u16(&buf[SENSORS_ADC + 2u * i]);
    }
    hrt_port_lock();
    hrt_rt_levels(rt, inputs, adc, i, get_u16(&buf[SENSORS_ENCODER]));
    hrt_rt_main(rt, now);
    if (((inputs ^ rt->in) & HRT_IN_HALLS) != 0u) {
        uint32_t back = 0u;
        if (edge != HBP_EDGE_NONE) {
            uint32_t period_100ns = (uint32_t)l->period_us * 10u;
            if ((uint32_t)edge < period_100ns) {
                back = (period_100ns - edge) * hrt_firmware.ticks_per_us / 10u;
            }
        }
        hrt_rt_edge(rt, (uint8_t)(inputs & HRT_IN_HALLS), now - back);
    }
    hrt_port_unlock();
}
#endif

static HRT_NOINLINE void on_sensors(hrt_link_t *l, const uint8_t *buf, uint8_t len, uint8_t seq)
{
    uint32_t span = (uint32_t)l->period_us * hrt_firmware.ticks_per_us;
    uint8_t n_adc = (uint8_t)((uint8_t)(len - SENSORS_ADC) / 2u);
    if (len < SENSORS_ADC || (uint8_t)(SENSORS_ADC + 2u * n_adc) != len || n_adc > HBP_MAX_ADC) {
        send_error(l, seq, HBP_ERROR_LENGTH, buf[0]);
        return;
    }
    if ((l->flags & HRT_LINK_F_ANSWERED) != 0u && seq == l->last_seq) {
        /* the host sent it again (our Drive was lost or late): the same answer, no second step */
        hrt_link_send_drive(l, seq);
        return;
    }
    if (l->mode == HBP_MODE_REALTIME) {
        uint32_t now = hrt_port_now();
        if ((l->flags & HRT_LINK_F_SENSORS) != 0u) {
            span = now - l->last_rx; /* the time that really passed */
        }
    }
    l->last_rx = hrt_port_now();
    l->flags = (uint8_t)((l->flags | HRT_LINK_F_SENSORS | HRT_LINK_F_ANSWERED) & (uint8_t)~HRT_LINK_F_TRIPPED);
#if defined(HRT_PORT_HW) && HRT_PORT_HW
    if (l->mode == HBP_MODE_REALTIME) {
        rt_hw_sensors(l, buf, n_adc);
        span = 0u;
    }
#endif
    if (span > 0u) {
        run_span(l, buf, n_adc, span);
    }
    l->last_seq = seq;
    hrt_link_send_drive(l, seq);
}

static HRT_NOINLINE void on_describe(hrt_link_t *l, const uint8_t *buf, uint8_t len, uint8_t seq)
{
    const hrt_firmware_t *d = &hrt_firmware;
    hbp_param_describe_t q;
    hbp_param_info_t info;
    const hrt_param_decl_t *p;
    uint8_t i;
    uint8_t n;
    if (hbp_unpack_param_describe(buf, len, &q) != HBP_ERROR_NONE) {
        send_error(l, seq, HBP_ERROR_LENGTH, buf[0]);
        return;
    }
    if (q.param_id >= d->n_params) {
        send_error(l, seq, HBP_ERROR_UNKNOWN_PARAM, q.param_id);
        return;
    }
    p = &d->params[q.param_id];
    info.seq = seq;
    info.param_id = q.param_id;
    info.ptype = p->ptype;
    info.access = p->access;
    info.min_value = p->min_value;
    info.max_value = p->max_value;
    info.value = d->param_get(l->rt, q.param_id);
    n = name_len(p->name, HBP_MAX_NAME);
    for (i = 0u; i < n; i++) {
        info.name[i] = p->name[i];
    }
    info.name[n] = '\0';
    if ((uint8_t)(HBP_PARAM_INFO_FIXED_LEN + n) <= HRT_TX_FRAME_MAX) {
        send_frame(l, hbp_pack_param_info(&info, TX));
    }
}

static HRT_NOINLINE void on_get(hrt_link_t *l, const uint8_t *buf, uint8_t len, uint8_t seq)
{
    hbp_param_get_t q;
    hbp_param_value_t v;
    if (hbp_unpack_param_get(buf, len, &q) != HBP_ERROR_NONE) {
        send_error(l, seq, HBP_ERROR_LENGTH, buf[0]);
        return;
    }
    v.seq = seq;
    v.param_id = q.param_id;
    if (q.param_id < hrt_firmware.n_params) {
        v.result = HBP_RESULT_OK;
        v.value = hrt_firmware.param_get(l->rt, q.param_id);
    } else {
        v.result = HBP_RESULT_UNKNOWN_ID;
        v.value = 0;
    }
    send_frame(l, hbp_pack_param_value(&v, TX));
}

/* ParamSet: the pairs read in place into a request, checked whole, applied all or nothing. */
static HRT_NOINLINE void on_set(hrt_link_t *l, const uint8_t *buf, uint8_t len, uint8_t seq)
{
    hrt_param_request_t req;
    hbp_param_set_result_t r;
    uint8_t i;
    uint8_t n = (uint8_t)((uint8_t)(len - HBP_PARAM_SET_FIXED_LEN) / 5u);
    if (len < HBP_PARAM_SET_FIXED_LEN || (uint8_t)(HBP_PARAM_SET_FIXED_LEN + 5u * n) != len ||
        n > HBP_MAX_PARAM_PAIRS) {
        send_error(l, seq, HBP_ERROR_LENGTH, buf[0]);
        return;
    }
    req.n = n;
    for (i = 0u; i < n; i++) {
        const uint8_t *pair = &buf[HBP_PARAM_SET_FIXED_LEN + 5u * i];
        req.id[i] = pair[0];
        req.value[i] = get_i32(&pair[1]);
    }
    r.seq = seq;
    hrt_port_lock();
    r.result = hrt_param_write(l->rt, &req, &r.param_id, &r.detail);
    hrt_port_unlock();
    send_frame(l, hbp_pack_param_set_result(&r, TX));
}

static HRT_NOINLINE void on_status(hrt_link_t *l, uint8_t seq)
{
    hbp_status_t st;
    hbp_rx_status(&l->rx, seq, l->watchdog_trips, &st);
    if (l->last_error != HBP_ERROR_NONE) {
        st.last_error = l->last_error;
    }
    send_frame(l, hbp_pack_status(&st, TX));
}

void hrt_link_handle(hrt_link_t *l, const uint8_t *frame, uint8_t len)
{
    hrt_t *rt = l->rt;
    uint8_t type = frame[0];
    uint8_t seq = frame[1];
    switch (type) {
    case HBP_MSG_SENSORS:
        on_sensors(l, frame, len, seq);
        break;
    case HBP_MSG_HOST_HELLO:
        on_hello(l, frame, len, seq);
        break;
    case HBP_MSG_PARAM_DESCRIBE:
        on_describe(l, frame, len, seq);
        break;
    case HBP_MSG_PARAM_GET:
        on_get(l, frame, len, seq);
        break;
    case HBP_MSG_PARAM_SET:
        on_set(l, frame, len, seq);
        break;
    case HBP_MSG_START:
        hrt_port_lock();
        hrt_firmware.start(rt); /* no reply */
        hrt_port_unlock();
        break;
    case HBP_MSG_STOP:
        hrt_port_lock();
        hrt_firmware.stop(rt, HRT_STOP_COMMAND);
        hrt_port_unlock();
        break;
    case HBP_MSG_STATUS_REQUEST:
        on_status(l, seq);
        break;
    default:
        send_error(l, seq, HBP_ERROR_BAD_REQUEST, 0u); /* a target -> host message */
        break;
    }
}

void hrt_link_watchdog(hrt_link_t *l)
{
    uint16_t limit_ms = l->watchdog_ms;
    uint32_t ticks_per_ms;
    if (limit_ms == 0u || (l->flags & (HRT_LINK_F_SENSORS | HRT_LINK_F_TRIPPED)) != HRT_LINK_F_SENSORS) {
        return;
    }
    if (l->mode == HBP_MODE_LOCKSTEP && limit_ms < HRT_LOCKSTEP_WATCHDOG_MIN_MS) {
        limit_ms = HRT_LOCKSTEP_WATCHDOG_MIN_MS;
    }
    ticks_per_ms = (uint32_t)hrt_firmware.ticks_per_us * 1000u;
    if ((hrt_port_now() - l->last_rx) / ticks_per_ms >= limit_ms) {
        /* frames stopped: outputs off, one unsolicited Drive that says so */
        l->flags = (uint8_t)(l->flags | HRT_LINK_F_TRIPPED);
        l->watchdog_trips = (uint16_t)(l->watchdog_trips + 1u);
        l->last_error = HBP_ERROR_WATCHDOG;
        hrt_port_lock();
        (&hrt_firmware)->stop(l->rt, HRT_STOP_WATCHDOG);
        hrt_port_unlock();
        hrt_link_send_drive(l, l->last_seq);
    }
}

void hrt_link_poll(hrt_link_t *l)
{
    if (l->rx.ready) {
        hrt_link_handle(l, l->rx.buf, l->rx.frame_len);
        hbp_rx_release(&l->rx);
    }
    hrt_link_watchdog(l);
}
