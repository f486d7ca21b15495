/* hrt_link.c: the runtime's protocol side (see hrt_link.h).
 *
 * Requests are read in place from the receive buffer and replies written field by field into l->tx,
 * then streamed out (hbp_send_frame): no message structs, no codec tables. The byte layouts are the
 * schema's (firmware_protocol/schema.toml); tests/test_runtime_link.py decodes every reply with the
 * codec generated from it. */
#include "hrt_link.h"

/* `static inline`: a small helper, or one called once, that XC16's -O1 inlines as GCC's does (the
 * dsPIC30F2010's 4K words, docs/board.md section 3a, measured one by one); the others stay calls. */
/* The rarest requests (target and telemetry descriptions, Status, batches, prediction) keep their
 * locals in their own frames, off the lockstep path's stack (GCC and XC16; other compilers may inline
 * them). The handshake's and the parameters' are inline: the dsPIC30F2010's flash needed the ~85 words
 * more than its RAM the ~20 bytes (tests/test_firmware_dspic.py: 456 of 512 bytes). */
#if defined(__GNUC__)
#define HRT_NOINLINE __attribute__((noinline))
#else
#define HRT_NOINLINE
#endif

/* The clock and the PWM period as constants when hrt_config.h names them (the compiler then folds the
 * arithmetic a 16-bit chip would call a library routine for), else the declaration's. */
#ifdef HRT_TICKS_PER_US
#define TICKS_PER_US ((uint32_t)(HRT_TICKS_PER_US))
#else
#define TICKS_PER_US ((uint32_t)hrt_firmware.ticks_per_us)
#endif
#ifdef HRT_PWM_PERIOD_TICKS
#define PWM_PERIOD_TICKS ((uint32_t)(HRT_PWM_PERIOD_TICKS))
#else
#define PWM_PERIOD_TICKS (hrt_firmware.pwm_period_ticks)
#endif

static inline uint16_t get_u16(const hbp_u8 *p)
{
    return (uint16_t)((uint16_t)(p[0] & 0xFFu) | (uint16_t)((uint16_t)(p[1] & 0xFFu) << 8));
}

static uint32_t get_u32(const hbp_u8 *p)
{
    return (uint32_t)get_u16(p) | ((uint32_t)get_u16(&p[2]) << 16);
}

/* A little-endian two's-complement i32 (no implementation-defined conversion). */
static inline int32_t get_i32(const hbp_u8 *p)
{
    uint32_t u = get_u32(p);
    if (u < 0x80000000UL) {
        return (int32_t)u;
    }
    return (int32_t)(-(int32_t)(0xFFFFFFFFUL - u) - 1);
}

#if HBP_MODE_LOCKSTEP != 0u
#error "hrt_link_init's zero bytes are mode LOCKSTEP"
#endif
void hrt_link_init(hrt_link_t *l, hrt_t *rt)
{
    hbp_u8 *p = (hbp_u8 *)l;
    uint16_t k;
    for (k = 0u; k < (uint16_t)sizeof *l; k++) { /* every field 0 (mode HBP_MODE_LOCKSTEP), byte by byte */
        p[k] = 0u;
    }
    l->rt = rt;
    hbp_rx_init(&l->rx); /* (which stores rx.ready, the one volatile field, through its volatile lvalue) */
}

/* Mode PREDICT: this build has room for the firmware's state, and the firmware says how big it is. */
#if HRT_PREDICT_BYTES > 0
#define CAN_PREDICT (hrt_firmware.state_size != 0u && hrt_firmware.state_size <= HRT_PREDICT_BYTES)
#else
#define CAN_PREDICT 0
#endif
/* Real time on a port whose interrupts run the bodies (a Sensors updates the inputs they read), or
 * on one without (a Sensors runs the time that passed). */
#if defined(HRT_PORT_HW) && HRT_PORT_HW && HRT_REALTIME
#define RT_HW 1
#else
#define RT_HW 0
#endif
#define RT_SPAN (HRT_REALTIME && !RT_HW)
/* Lockstep, predicted or not (a build without prediction never agrees to PREDICT: its code as before;
 * a lockstep-only build agrees to nothing else). */
#if !HRT_REALTIME && !HRT_MONITOR
#define LOCKSTEP(mode) 1
#elif HRT_PREDICT_BYTES > 0
#define LOCKSTEP(mode) ((mode) == HBP_MODE_LOCKSTEP || (mode) == HBP_MODE_PREDICT)
#else
#define LOCKSTEP(mode) ((mode) == HBP_MODE_LOCKSTEP)
#endif

/* ---- replies, field by field ---- */

static void w8(hrt_link_t *l, hbp_u8 v)
{
    if (l->tx_len < HRT_TX_FRAME_MAX) {
        l->tx[l->tx_len] = (hbp_u8)(v & 0xFFu);
    }
    l->tx_len = (hbp_u8)(l->tx_len < 0xFFu ? l->tx_len + 1u : 0xFFu); /* past the end: not sent */
}

static void w16(hrt_link_t *l, uint16_t v)
{
    w8(l, (hbp_u8)(v & 0xFFu));
    w8(l, (hbp_u8)(v >> 8));
}

static inline void w32(hrt_link_t *l, uint32_t v)
{
    w16(l, (uint16_t)(v & 0xFFFFu));
    w16(l, (uint16_t)(v >> 16));
}

/* A declared name (at most max printable characters), with its count unless it is the last field. */
static inline void wname(hrt_link_t *l, const char *s, hbp_u8 max, hbp_u8 counted)
{
    hbp_u8 n = 0u;
    while (n < max && s[n] != '\0') {
        n++;
    }
    if (counted) {
        w8(l, n);
    }
    while (n-- > 0u) {
        w8(l, (hbp_u8)*s++);
    }
}

static void begin(hrt_link_t *l, hbp_u8 type, hbp_u8 seq)
{
    l->tx_len = 0u;
    w8(l, type);
    w8(l, seq);
}

/* Send the reply written since begin (nothing when it did not fit HRT_TX_FRAME_MAX: the host times
 * out and says so). */
static void finish(hrt_link_t *l)
{
    if (l->tx_len <= HRT_TX_FRAME_MAX) {
        hbp_send_frame(l->tx, l->tx_len, hrt_port_send);
    }
}

static void send_error(hrt_link_t *l, hbp_u8 seq, hbp_u8 code, hbp_u8 detail)
{
    l->rx.last_error = code; /* Status reports it as the last error */
    begin(l, HBP_MSG_ERROR_REPORT, seq);
    w8(l, code);
    w8(l, detail);
    w32(l, HBP_SCHEMA_FINGERPRINT); /* this build's: the host names both when they differ */
    finish(l);
}

/* The Drive of the present state, written into l->tx: a monitor build fills it with the port locked
 * and sends it unlocked (hrt_link_stream), a batch folds its bytes into the digest; every other build
 * keeps it one function, sending too (no call more on a 12 KB chip: tests/test_dspic_size.py). */
#if HRT_MONITOR || HRT_SPECULATE
static void fill_drive(hrt_link_t *l, hbp_u8 seq)
#else
void hrt_link_send_drive(hrt_link_t *l, hbp_u8 seq)
#endif
{
    hrt_report_t d;
    hbp_u8 i;
    hrt_report(l->rt, seq, &d);
    if ((l->flags & HRT_LINK_F_TRIPPED) != 0u) { /* the watchdog turned the outputs off: say so */
        d.output_mode = HBP_OUTPUT_OFF;
        if (d.fault == HBP_FAULT_NONE) {
            d.fault = HBP_FAULT_WATCHDOG;
        }
    }
#if HRT_PREDICT_BYTES > 0
    if (l->mode == HBP_MODE_PREDICT) { /* the duties predicted for the next span */
        d.duty_a = l->predicted[0];
        d.duty_b = l->predicted[1];
        d.duty_c = l->predicted[2];
    }
#endif
    begin(l, HBP_MSG_DRIVE, seq);
    w16(l, d.duty_a);
    w16(l, d.duty_b);
    w16(l, d.duty_c);
    w16(l, (uint16_t)((unsigned)(d.output_mode & 3u) | ((unsigned)(d.state & 7u) << 2) |
                      ((unsigned)(d.sector & 7u) << 5) | ((unsigned)(d.direction_ccw != 0u) << 8) |
                      ((unsigned)(d.required_ccw != 0u) << 9) | ((unsigned)(d.fault & 0x3Fu) << 10)));
    for (i = 0u; i < d.n_telemetry; i++) {
        w16(l, (uint16_t)d.telemetry[i]);
    }
#if !(HRT_MONITOR || HRT_SPECULATE)
    finish(l);
#endif
}

#if HRT_MONITOR || HRT_SPECULATE
void hrt_link_send_drive(hrt_link_t *l, hbp_u8 seq)
{
#if HRT_MONITOR /* the timers' and the halls' interrupts change what the Drive reports */
    hrt_port_lock();
    fill_drive(l, seq);
    hrt_port_unlock();
#else
    fill_drive(l, seq);
#endif
    finish(l);
}
#endif

#if HRT_MONITOR
void hrt_link_stream(hrt_link_t *l)
{
    uint32_t period = (uint32_t)l->period_us * TICKS_PER_US;
    uint32_t now = hrt_port_now();
    hbp_u8 seq = l->last_seq;
    if (l->mode != HBP_MODE_MONITOR || (l->flags & HRT_LINK_F_HELLO) == 0u || now - l->stream_at < period) {
        return;
    }
    while (now - l->stream_at >= period) { /* a slot missed (the UART was busy) is a seq skipped */
        l->stream_at += period;
        seq = (hbp_u8)(seq + 1u);
    }
    l->last_seq = seq;
    hrt_port_lock();
    fill_drive(l, seq);
    hrt_port_unlock();
    finish(l);
}
#endif

/* TargetHello: the firmware's declaration. */
static inline void send_target_hello(hrt_link_t *l, hbp_u8 seq)
{
    const hrt_firmware_t *d = &hrt_firmware;
    hbp_u8 i;
    hbp_u8 n_adc = (d->n_adc > HBP_MAX_ADC) ? (hbp_u8)HBP_MAX_ADC : d->n_adc;
    begin(l, HBP_MSG_TARGET_HELLO, seq);
    w8(l, HBP_PROTOCOL_VERSION);
    w32(l, HBP_SCHEMA_FINGERPRINT);
    w16(l, d->version);
    w16(l, d->pwm_counts);
    w32(l, (uint32_t)(TICKS_PER_US * 1000000UL / PWM_PERIOD_TICKS));
    w8(l, d->n_params);
    w8(l, d->adc_bits);
    wname(l, d->name, HBP_MAX_NAME, 1u);
    w8(l, n_adc);
    for (i = 0u; i < n_adc; i++) {
        w8(l, d->adc_roles[i]);
    }
    for (i = 0u; i < d->n_telemetry; i++) {
        w8(l, d->telemetry[i].id);
    }
    finish(l);
}

#if HRT_DESCRIBE
/* TargetInfo: what a host needs beyond the HELLO to serve the firmware (TargetDescribe). */
static HRT_NOINLINE void on_target_describe(hrt_link_t *l, hbp_u8 seq)
{
    const hrt_firmware_t *d = &hrt_firmware;
    /* the edges one Sensors may carry: what the receive buffer holds beside the declared ADC codes */
    hbp_u8 room = (hbp_u8)((HBP_RX_MAX - 1u - HBP_SENSORS_FIXED_LEN - 1u - 2u * d->n_adc) / 3u);
    begin(l, HBP_MSG_TARGET_INFO, seq);
    w8(l, d->duty_timing);
    w8(l, d->duty_report);
    w8(l, d->inputs);
    w16(l, d->encoder_counts);
    w8(l, (room < HBP_MAX_EDGES) ? room : (hbp_u8)HBP_MAX_EDGES);
    finish(l);
}
#endif

/* HostHello, read in place: the version byte first (a HostHello of another version may have another
 * length), then the length, the schema fingerprint, the period and the mode. */
static inline void on_hello(hrt_link_t *l, const hbp_u8 *buf, hbp_u8 len, hbp_u8 seq)
{
    uint16_t period_us;
    hbp_u8 mode;
    uint16_t step = hrt_firmware.period_step_us;
    if (len >= 3u && buf[2] != HBP_PROTOCOL_VERSION) {
        send_error(l, seq, HBP_ERROR_VERSION, HBP_PROTOCOL_VERSION);
        return;
    }
    if (len != HBP_HOST_HELLO_FIXED_LEN) {
        send_error(l, seq, HBP_ERROR_LENGTH, buf[0]);
        return;
    }
    if (get_u32(&buf[8]) != HBP_SCHEMA_FINGERPRINT) {
        send_error(l, seq, HBP_ERROR_VERSION, HBP_PROTOCOL_VERSION);
        return;
    }
    period_us = get_u16(&buf[3]);
    mode = buf[5];
#if HRT_MONITOR
    if (period_us == 0u || (step != 0u && period_us % step != 0u) || mode != HBP_MODE_MONITOR ||
        get_u16(&buf[6]) == 0u) {
        /* a real-motor build runs on its motor's own sensors: it never takes them from frames; and
         * its motor stops when the host falls silent, so a hello without a watchdog is refused */
#else
    if (period_us == 0u || (step != 0u && period_us % step != 0u) ||
        (mode != HBP_MODE_LOCKSTEP && !(mode == HBP_MODE_REALTIME && HRT_REALTIME) &&
         !(mode == HBP_MODE_PREDICT && CAN_PREDICT))) {
#endif
        send_error(l, seq, HBP_ERROR_BAD_REQUEST, 0u);
        return;
    }
#if RT_HW
    if ((l->flags & HRT_LINK_F_RT) != 0u) {
        hrt_port_realtime(0u);
        hrt_rt_enter(l->rt, 0u);
    }
#endif
    l->period_us = period_us;
    l->mode = mode;
    l->watchdog_ms = get_u16(&buf[6]);
    l->flags = HRT_LINK_F_HELLO; /* a new session numbers its Sensors from 0 again */
#if HRT_MONITOR
    if (mode == HBP_MODE_MONITOR) { /* the stream starts: the watchdog counts from now */
        l->flags = (hbp_u8)(HRT_LINK_F_HELLO | HRT_LINK_F_SENSORS);
        l->last_rx = hrt_port_now();
        l->stream_at = l->last_rx;
        l->last_seq = 0u;
    }
#endif
#if HRT_SPECULATE
    l->b_synced = 0u; /* the next SensorsBatch starts the records afresh */
#endif
    send_target_hello(l, seq);
}

/* Sensors, read in place: inputs u8, encoder u16, ADC codes (a count, u16 each), edges to the end
 * (time u16 in 100 ns units, lines u8 each). */
#define SENSORS_INPUTS 2u
#define SENSORS_ENCODER 3u
#define SENSORS_N_ADC 5u
#define SENSORS_ADC 6u

/* The encoder count of a Sensors (0 in a build without an encoder, HRT_ENCODER 0: not read). */
#define SENSORS_ENCODER_VALUE(buf) ((uint16_t)(HRT_ENCODER ? get_u16(&(buf)[SENSORS_ENCODER]) : 0u))

/* 100 ns units (the wire's edge times) in the firmware's ticks. */
static inline uint32_t ticks_of(uint32_t t_100ns)
{
    /* exact: t_100ns < 2^16, ticks_per_us < 2^8 */
    return (TICKS_PER_US % 10u == 0u) ? t_100ns * (TICKS_PER_US / 10u) : t_100ns * TICKS_PER_US / 10u;
}

/* A Sensors' inputs, ADC codes and edges into the runtime. Lockstep (span > 0): one span of the
 * agreed period, or of the time that passed (real time on a port that runs the bodies itself), every
 * edge at its time (one at or beyond the span's end at its last tick). Real time on a port whose
 * interrupts run the bodies (span 0): the inputs the bodies read, each edge captured at its time
 * back-dated from now by the rest of the period (an estimate: the frame's own transit is not known). */
static inline void serve_sensors(hrt_link_t *l, const hbp_u8 *buf, hbp_u8 len, hbp_u8 n_edges, uint32_t span)
{
    hrt_t *rt = l->rt;
    uint32_t start = rt->now;
    hbp_u8 inputs = buf[SENSORS_INPUTS];
    hbp_u8 at = (hbp_u8)(SENSORS_ADC + 2u * buf[SENSORS_N_ADC]); /* the first edge */
    hbp_u8 has_index = 0u;
    uint16_t adc[HRT_MAX_ADC];
    hbp_u8 n_adc;
    hbp_u8 i;
    for (n_adc = 0u; n_adc < buf[SENSORS_N_ADC] && n_adc < HRT_MAX_ADC; n_adc++) {
        adc[n_adc] = get_u16(&buf[SENSORS_ADC + 2u * n_adc]);
    }
#if RT_HW
    if (span == 0u) {
        uint32_t period_100ns = (uint32_t)l->period_us * 10u;
        start = hrt_port_now();
        if ((l->flags & HRT_LINK_F_RT) == 0u) {
            l->flags = (hbp_u8)(l->flags | HRT_LINK_F_RT);
            hrt_rt_enter(rt, 1u);
            hrt_port_realtime(1u);
        }
        hrt_port_lock();
        hrt_rt_levels(rt, inputs, adc, n_adc, SENSORS_ENCODER_VALUE(buf));
        hrt_rt_main(rt, start);
        if (n_edges == 0u) {
            hrt_rt_edge(rt, (hbp_u8)(inputs & HRT_IN_EDGE_LINES), start); /* a change without its time */
        }
        for (; at < len; at = (hbp_u8)(at + 3u)) {
            uint32_t t = get_u16(&buf[at]);
            hrt_rt_edge(rt, buf[at + 2u], start - ((t < period_100ns) ? ticks_of(period_100ns - t) : 0u));
        }
        hrt_port_unlock();
        return;
    }
#endif
    for (i = at; i < len; i = (hbp_u8)(i + 3u)) {
        has_index = (hbp_u8)(has_index | (buf[i + 2u] & HRT_INDEX_READ));
    }
    hrt_span_begin(rt, inputs, n_edges, has_index, adc, n_adc, SENSORS_ENCODER_VALUE(buf));
    for (; at < len; at = (hbp_u8)(at + 3u)) {
        uint32_t off = ticks_of(get_u16(&buf[at]));
        hrt_span_edge(rt, start + ((off < span) ? off : span - 1u), buf[at + 2u]);
    }
    hrt_span_end(rt, start + span);
}

#if HRT_PREDICT_BYTES > 0
/* Mode PREDICT, after a span: the next span as the firmware would run it on the present inputs and
 * no edge (it extrapolates as it would on the chip until the next edge), on its own state; keep the
 * mean of the duties active over it, and put the state back. The next Sensors runs that span for
 * real, with its edges. Deterministic: the same state and span give the same prediction. */
static HRT_NOINLINE void predict(hrt_link_t *l, uint32_t span)
{
    hrt_t *rt = l->rt;
    hbp_u8 *state = (hbp_u8 *)(void *)rt;
    uint16_t n = hrt_firmware.state_size;
    uint16_t i;
    for (i = 0u; i < n; i++) {
        l->snapshot[i] = state[i];
    }
    rt->flags = (hbp_u8)(rt->flags | HRT_F_MEAN);
    hrt_span_begin(rt, (hbp_u8)(rt->in & (hbp_u8)~HRT_IN_INDEX), 0u, 0u, 0, 0u, hrt_encoder(rt));
    hrt_span_end(rt, rt->now + span);
    for (i = 0u; i < 3u; i++) {
        uint16_t v = hrt_span_mean(rt, (hbp_u8)i);
        l->predicted[i] = (v > hrt_firmware.pwm_counts) ? hrt_firmware.pwm_counts : v;
    }
    for (i = 0u; i < n; i++) {
        state[i] = l->snapshot[i];
    }
}
#endif

static inline void on_sensors(hrt_link_t *l, const hbp_u8 *buf, hbp_u8 len, hbp_u8 seq)
{
    uint32_t span = (uint32_t)l->period_us * TICKS_PER_US;
    uint32_t now = hrt_port_now();
    hbp_u8 at = (hbp_u8)(SENSORS_ADC + 2u * buf[SENSORS_N_ADC]); /* the first edge */
    hbp_u8 n_edges = 0u;
    while (at + 3u <= len) { /* the edges, 3 bytes each, counted (a division costs a library call on a 16-bit chip) */
        at = (hbp_u8)(at + 3u);
        n_edges++;
    }
    if (len < SENSORS_ADC || buf[SENSORS_N_ADC] > HBP_MAX_ADC || at != len || n_edges > HBP_MAX_EDGES) {
        send_error(l, seq, HBP_ERROR_LENGTH, buf[0]);
        return;
    }
    if (LOCKSTEP(l->mode)) { /* the host is there: a tripped watchdog gives the outputs back */
        l->last_rx = now;
        l->flags = (hbp_u8)(l->flags & (hbp_u8)~HRT_LINK_F_TRIPPED);
    }
    if ((l->flags & HRT_LINK_F_ANSWERED) != 0u && seq == l->last_seq) {
        /* the host sent it again (our Drive was lost or late): the same answer, no second step */
        hrt_link_send_drive(l, seq);
        return;
    }
#if RT_SPAN /* (a hardware port's real time runs no span: below) */
    if (l->mode == HBP_MODE_REALTIME) {
        if ((l->flags & HRT_LINK_F_SENSORS) != 0u) {
            uint32_t passed = now - l->last_rx; /* the time that really passed, at most HRT_RT_MAX_PERIODS
                                                 * periods: a firmware too slow for real time on its chip
                                                 * falls behind instead of running ever longer spans */
            span = (passed < HRT_RT_MAX_PERIODS * span) ? passed : HRT_RT_MAX_PERIODS * span;
        }
    }
#endif
    l->last_rx = now;
    l->flags = (hbp_u8)((l->flags | HRT_LINK_F_SENSORS | HRT_LINK_F_ANSWERED) & (hbp_u8)~HRT_LINK_F_TRIPPED);
#if HRT_SPECULATE
    l->b_synced = 0u; /* a period run one by one: the next SensorsBatch starts the records afresh */
#endif
#if RT_HW
    if (l->mode == HBP_MODE_REALTIME) {
        span = 0u; /* the port's interrupts run the bodies: the inputs only */
        serve_sensors(l, buf, len, n_edges, 0u);
    }
#endif
    if (span > 0u) {
        serve_sensors(l, buf, len, n_edges, span);
#if HRT_PREDICT_BYTES > 0
        if (l->mode == HBP_MODE_PREDICT) {
            predict(l, span);
        }
#endif
    }
    l->last_seq = seq;
    hrt_link_send_drive(l, seq);
}

#if HRT_SPECULATE
/* ---- twin-speculative lockstep: SensorsBatch -> BatchDigest (PROTOCOL.md, "Batches") ----
 * Each period of a batch runs exactly as a Sensors of per-period lockstep does (its Sensors message
 * rebuilt from the records, the same span, the same Drive), and the Drive's message bytes are folded
 * into a CRC-32 instead of being sent; the answer is the digest and the last Drive. */
#define BATCH_FIRST 2u
#define BATCH_COUNT 4u
#define BATCH_RECORDS 5u
#define REC_RUN 0x80u    /* (REC_RUN | n), n < 64: n + 1 periods as the one before, without edges */
#define REC_TINY 0xC0u   /* (REC_TINY | c2 c1 c0): one period whose only change is ADC channels 0..2 by
                          * 2-bit codes (0: none, 1: +1, 2: +2, 3: -1), channel 0 in the low bits */
#define REC_INPUTS 0x01u /* the inputs byte follows */
#define REC_ENCODER 0x02u /* the encoder: a value (below) from the prediction (the last step again) */
#define REC_ADC0 0x04u   /* ADC channels 0, 1, 2 (0x04, 0x08, 0x10): a nibble each (below) */
#define REC_ADC_ALL 0x20u /* a channel count, then every channel's code as u16 */
#define REC_EDGES 0x40u  /* an edge count (1..), then the edges as in Sensors (time u16, lines u8) */
#define SENSORS_MSG_MAX (SENSORS_ADC + 2u * HBP_MAX_ADC + 3u * HBP_MAX_EDGES)
/* The records a batch may carry here: what the receive buffer holds beside the fixed fields. */
#define BATCH_ROOM ((HBP_RX_MAX - 1u - HBP_SENSORS_BATCH_FIXED_LEN < HBP_MAX_BATCH) ? \
                    (hbp_u8)(HBP_RX_MAX - 1u - HBP_SENSORS_BATCH_FIXED_LEN) : (hbp_u8)HBP_MAX_BATCH)

/* CRC-32 (IEEE 802.3, reflected, zlib's crc32), a nibble at a time: 64 bytes of table. */
static const uint32_t crc32_nibble[16] = {
    0x00000000UL, 0x1DB71064UL, 0x3B6E20C8UL, 0x26D930ACUL, 0x76DC4190UL, 0x6B6B51F4UL, 0x4DB26158UL, 0x5005713CUL,
    0xEDB88320UL, 0xF00F9344UL, 0xD6D6A3E8UL, 0xCB61B38CUL, 0x9B64C2B0UL, 0x86D3D2D4UL, 0xA00AE278UL, 0xBDBDF21CUL};

static uint32_t crc32_update(uint32_t crc, const hbp_u8 *p, hbp_u8 n)
{
    while (n-- > 0u) {
        crc ^= (uint32_t)(*p++ & 0xFFu);
        crc = (crc >> 4) ^ crc32_nibble[crc & 15u];
        crc = (crc >> 4) ^ crc32_nibble[crc & 15u];
    }
    return crc;
}

/* One value of a record into *v: a byte other than 0x80 is a signed change (-127..127), 0x80 is followed
 * by the value as u16. The bytes used, 0 when the record ends first. */
static hbp_u8 rec_value(const hbp_u8 *p, hbp_u8 left, uint16_t *v)
{
    hbp_u8 b;
    if (left < 1u) {
        return 0u;
    }
    b = (hbp_u8)(p[0] & 0xFFu);
    if (b != 0x80u) {
        *v = (uint16_t)(*v + ((b < 0x80u) ? (uint16_t)b : (uint16_t)(0xFF00u | b)));
        return 1u;
    }
    if (left < 3u) {
        return 0u;
    }
    *v = get_u16(&p[1]);
    return 3u;
}

/* One record (not a run) at p: the decoder state advances and the period's edges are at *edges_at (*n_edges
 * of them). The bytes used, 0 when malformed. */
static hbp_u8 rec_period(hrt_batch_in_t *in, const hbp_u8 *p, hbp_u8 left, hbp_u8 *edges_at, hbp_u8 *n_edges)
{
    hbp_u8 h = (hbp_u8)(p[0] & 0xFFu);
    hbp_u8 at = 1u;
    hbp_u8 used;
    hbp_u8 i;
    *n_edges = 0u;
    if ((h & REC_INPUTS) != 0u) {
        if (at >= left) {
            return 0u;
        }
        in->inputs = (hbp_u8)(p[at++] & 0xFFu);
    }
    { /* the encoder: predicted to move by its last step; a record says how far it was off */
        uint16_t value = (uint16_t)(in->encoder + in->enc_step);
        if ((h & REC_ENCODER) != 0u) {
            used = rec_value(&p[at], (hbp_u8)(left - at), &value);
            if (used == 0u) {
                return 0u;
            }
            at = (hbp_u8)(at + used);
            in->enc_step = (uint16_t)(value - in->encoder);
        }
        in->encoder = value;
    }
    if ((h & REC_ADC_ALL) != 0u) {
        hbp_u8 k;
        if (at >= left) {
            return 0u;
        }
        k = (hbp_u8)(p[at++] & 0xFFu);
        if (k > HBP_MAX_ADC || (hbp_u8)(left - at) < (hbp_u8)(2u * k)) {
            return 0u;
        }
        in->n_adc = k;
        for (i = 0u; i < k; i++) {
            in->adc[i] = get_u16(&p[at]);
            at = (hbp_u8)(at + 2u);
        }
    }
    { /* the ADC channels 0..2 that changed: a signed 4-bit change each (-7..7), two a byte, the lower
       * nibble first; -8 says the code follows as u16 after the nibbles (in channel order) */
        hbp_u8 j = 0u;
        hbp_u8 nibbles = (hbp_u8)(((h >> 2) & 1u) + ((h >> 3) & 1u) + ((h >> 4) & 1u));
        hbp_u8 tail = (hbp_u8)(at + (nibbles + 1u) / 2u);
        if (tail > left) {
            return 0u;
        }
        for (i = 0u; i < 3u; i++) {
            if ((h & (hbp_u8)(REC_ADC0 << i)) != 0u) {
                hbp_u8 nib = (hbp_u8)(((unsigned)(p[at + j / 2u] & 0xFFu) >> (4u * (unsigned)(j & 1u))) & 0x0Fu);
                if (i >= in->n_adc) {
                    return 0u;
                }
                if (nib == 8u) {
                    if ((hbp_u8)(left - tail) < 2u) {
                        return 0u;
                    }
                    in->adc[i] = get_u16(&p[tail]);
                    tail = (hbp_u8)(tail + 2u);
                } else {
                    in->adc[i] = (uint16_t)(in->adc[i] + ((nib < 8u) ? (uint16_t)nib : (uint16_t)(0xFFF0u | nib)));
                }
                j++;
            }
        }
        at = tail;
    }
    if ((h & REC_EDGES) != 0u) {
        if (at >= left) {
            return 0u;
        }
        *n_edges = (hbp_u8)(p[at++] & 0xFFu);
        if (*n_edges == 0u || *n_edges > HBP_MAX_EDGES || (hbp_u8)(left - at) / 3u < *n_edges) {
            return 0u;
        }
        *edges_at = at;
        at = (hbp_u8)(at + 3u * *n_edges);
    }
    return at;
}

/* The answer: the digest and the Drive of the present state (the batch's last), moved behind the
 * digest's fields in l->tx. count 0: refused, next says the period expected. */
static void send_digest(hrt_link_t *l, hbp_u8 seq, uint16_t first, hbp_u8 count, uint16_t next, uint32_t digest)
{
    hbp_u8 n;
    hbp_u8 i;
    fill_drive(l, (hbp_u8)((count != 0u) ? ((first + count - 1u) & 0xFFu) : l->last_seq));
    n = (hbp_u8)(l->tx_len - 2u);
    if (l->tx_len > HRT_TX_FRAME_MAX || (hbp_u8)(12u + n) > HRT_TX_FRAME_MAX) {
        return; /* does not fit this build's reply buffer: the host times out and says so */
    }
    for (i = n; i > 0u; i--) {
        l->tx[11u + i] = l->tx[1u + i];
    }
    begin(l, HBP_MSG_BATCH_DIGEST, seq);
    w16(l, first);
    w8(l, count);
    w16(l, next);
    w8(l, BATCH_ROOM);
    w32(l, digest);
    l->tx_len = (hbp_u8)(12u + n);
    finish(l);
}

/* A 1-byte record (REC_TINY | c2 c1 c0): the encoder moves by its step, ADC channels 0..2 by the codes.
 * 0 when a code changes a channel the state does not have. */
static hbp_u8 rec_tiny(hrt_batch_in_t *in, hbp_u8 h)
{
    hbp_u8 i;
    in->encoder = (uint16_t)(in->encoder + in->enc_step);
    for (i = 0u; i < 3u; i++) {
        hbp_u8 code = (hbp_u8)(((unsigned)h >> (2u * (unsigned)i)) & 3u);
        if (code != 0u) {
            if (i >= in->n_adc) {
                return 0u;
            }
            in->adc[i] = (uint16_t)(in->adc[i] + ((code == 3u) ? 0xFFFFu : (uint16_t)code));
        }
    }
    return 1u;
}

/* The decoder state of a first batch (after a handshake or a per-period Sensors): all zero. */
static void batch_reset(hrt_link_t *l)
{
    hbp_u8 i;
    l->b_digest = 0UL;
    l->b_in.inputs = 0u;
    l->b_in.encoder = 0u;
    l->b_in.enc_step = 0u;
    l->b_in.n_adc = 0u;
    for (i = 0u; i < HBP_MAX_ADC; i++) {
        l->b_in.adc[i] = 0u;
    }
}

/* `runs` periods from period seq0: each the Sensors message per-period lockstep would send (the decoder
 * state and the record's edges; a run moves the encoder by its step each period), served as on_sensors
 * serves it, its Drive folded into crc instead of sent. */
static uint32_t run_periods(hrt_link_t *l, hrt_batch_in_t *in, const hbp_u8 *edges, hbp_u8 n_edges,
                            hbp_u8 is_run, uint16_t seq0, hbp_u8 runs, uint32_t crc)
{
    uint32_t span = (uint32_t)l->period_us * TICKS_PER_US;
    hbp_u8 msg[SENSORS_MSG_MAX];
    hbp_u8 m = SENSORS_ADC;
    hbp_u8 k;
    msg[0] = HBP_MSG_SENSORS;
    msg[SENSORS_INPUTS] = in->inputs;
    msg[SENSORS_N_ADC] = in->n_adc;
    for (k = 0u; k < in->n_adc; k++) {
        msg[m++] = (hbp_u8)(in->adc[k] & 0xFFu);
        msg[m++] = (hbp_u8)(in->adc[k] >> 8);
    }
    for (k = 0u; k < (hbp_u8)(3u * n_edges); k++) {
        msg[m++] = edges[k];
    }
    for (k = 0u; k < runs; k++) {
        hbp_u8 s = (hbp_u8)((unsigned)(seq0 + (uint16_t)k) & 0xFFu);
        if (is_run) {
            in->encoder = (uint16_t)(in->encoder + in->enc_step);
        }
        msg[1] = s;
        msg[SENSORS_ENCODER] = (hbp_u8)(in->encoder & 0xFFu);
        msg[SENSORS_ENCODER + 1u] = (hbp_u8)(in->encoder >> 8);
        l->last_rx = hrt_port_now();
        l->flags = (hbp_u8)((l->flags | HRT_LINK_F_SENSORS | HRT_LINK_F_ANSWERED) & (hbp_u8)~HRT_LINK_F_TRIPPED);
        serve_sensors(l, msg, m, n_edges, span);
#if HRT_PREDICT_BYTES > 0
        if (l->mode == HBP_MODE_PREDICT) {
            predict(l, span);
        }
#endif
        l->last_seq = s;
        fill_drive(l, s);
        /* a Drive that did not fit tx (a build whose HRT_TX_FRAME_MAX is too small) is folded as
         * nothing: never read past tx, and the digest then differs from the twin's, as it should */
        crc = crc32_update(crc, l->tx, l->tx_len <= HRT_TX_FRAME_MAX ? l->tx_len : 0u);
    }
    return crc;
}

/* The records of a batch: checked (pass 0, on a copy of the decoder state), then run (pass 1, the
 * state carried on). 0 when a record is malformed or they do not make `count` periods (pass 0). */
static hbp_u8 batch_records(hrt_link_t *l, const hbp_u8 *buf, hbp_u8 len, uint16_t first, hbp_u8 count,
                            hbp_u8 pass, uint32_t *crc)
{
    hrt_batch_in_t check = l->b_in;
    hrt_batch_in_t *in = (pass == 0u) ? &check : &l->b_in;
    hbp_u8 at = BATCH_RECORDS;
    hbp_u8 done = 0u;
    while (at < len && done < count) {
        hbp_u8 h = (hbp_u8)(buf[at] & 0xFFu);
        hbp_u8 runs = 1u;
        hbp_u8 edges_at = 0u;
        hbp_u8 n_edges = 0u;
        hbp_u8 used = 1u;
        hbp_u8 is_run = (hbp_u8)((h & REC_TINY) == REC_RUN);
        if ((h & REC_TINY) == REC_TINY) {
            used = rec_tiny(in, h);
        } else if (is_run) {
            runs = (hbp_u8)((h & 0x3Fu) + 1u);
            if (pass == 0u) { /* (pass 1 moves the encoder period by period) */
                in->encoder = (uint16_t)(in->encoder + (uint16_t)((unsigned)runs * (unsigned)in->enc_step));
            }
        } else {
            used = rec_period(in, &buf[at], (hbp_u8)(len - at), &edges_at, &n_edges);
        }
        if (used == 0u || runs > (hbp_u8)(count - done)) {
            return 0u;
        }
        if (pass == 1u) {
            *crc = run_periods(l, in, &buf[at + edges_at], n_edges, is_run, (uint16_t)(first + done), runs, *crc);
        }
        done = (hbp_u8)(done + runs);
        at = (hbp_u8)(at + used);
    }
    return (hbp_u8)(at == len && done == count);
}

/* A SensorsBatch: a repeat gets the kept answer, a batch out of order a refusal; else every record is
 * checked before any period runs, then they run and the digest goes out. */
static HRT_NOINLINE void on_batch(hrt_link_t *l, const hbp_u8 *buf, hbp_u8 len, hbp_u8 seq)
{
    uint16_t first;
    hbp_u8 count;
    uint32_t crc;
    if (len < BATCH_RECORDS || !LOCKSTEP(l->mode) || l->period_us == 0u) {
        send_error(l, seq, (len < BATCH_RECORDS) ? HBP_ERROR_LENGTH : HBP_ERROR_BAD_REQUEST, buf[0]);
        return;
    }
    first = get_u16(&buf[BATCH_FIRST]);
    count = (hbp_u8)(buf[BATCH_COUNT] & 0xFFu);
    if (count == 0u) {
        send_error(l, seq, HBP_ERROR_BAD_REQUEST, buf[0]);
        return;
    }
    if (l->b_synced != 0u) {
        uint16_t next = (uint16_t)(l->b_first + l->b_count);
        if (first == l->b_first && count == l->b_count) { /* a repeat: the kept answer, not run again */
            send_digest(l, seq, first, count, next, l->b_digest);
            return;
        }
        if (first != next) {
            send_digest(l, seq, first, 0u, next, l->b_digest); /* what it has run, and the digest through it */
            return;
        }
    } else {
        batch_reset(l);
    }
    crc = l->b_digest ^ 0xFFFFFFFFUL; /* the digest goes on from the last batch's: it vouches for every period */
    if (!batch_records(l, buf, len, first, count, 0u, &crc)) {
        send_error(l, seq, HBP_ERROR_LENGTH, buf[0]);
        return;
    }
    (void)batch_records(l, buf, len, first, count, 1u, &crc);
    l->b_synced = 1u;
    l->b_first = first;
    l->b_count = count;
    l->b_digest = crc ^ 0xFFFFFFFFUL;
    send_digest(l, seq, first, count, (uint16_t)(first + count), l->b_digest);
}
#endif

#if HRT_DESCRIBE
/* ParamDescribe, ParamGet, TelemetryDescribe: one id byte. */
static inline void on_describe(hrt_link_t *l, hbp_u8 id, hbp_u8 seq)
{
    const hrt_firmware_t *d = &hrt_firmware;
    const hrt_param_decl_t *p;
    if (id >= d->n_params) {
        send_error(l, seq, HBP_ERROR_UNKNOWN_PARAM, id);
        return;
    }
    p = &d->params[id];
    begin(l, HBP_MSG_PARAM_INFO, seq);
    w8(l, id);
    w8(l, p->ptype);
    w8(l, p->access);
    w32(l, (uint32_t)p->min_value);
    w32(l, (uint32_t)p->max_value);
    w32(l, (uint32_t)d->param_get(l->rt, id));
    wname(l, p->name, HBP_MAX_NAME, 1u);
    wname(l, p->unit, HBP_MAX_UNIT, 0u);
    finish(l);
}

static HRT_NOINLINE void on_telemetry(hrt_link_t *l, hbp_u8 index, hbp_u8 seq)
{
    const hrt_firmware_t *d = &hrt_firmware;
    const hrt_telemetry_decl_t *t;
    if (index >= d->n_telemetry) {
        send_error(l, seq, HBP_ERROR_UNKNOWN_TELEMETRY, index);
        return;
    }
    t = &d->telemetry[index];
    begin(l, HBP_MSG_TELEMETRY_INFO, seq);
    w8(l, index);
    w8(l, t->id);
    w8(l, t->ptype);
    w32(l, (uint32_t)t->scale_num);
    w32(l, (uint32_t)t->scale_den);
    wname(l, t->name, HBP_MAX_NAME, 1u);
    wname(l, t->unit, HBP_MAX_UNIT, 0u);
    finish(l);
}
#endif

static inline void on_get(hrt_link_t *l, hbp_u8 id, hbp_u8 seq)
{
    hbp_u8 known = (hbp_u8)(id < hrt_firmware.n_params);
    begin(l, HBP_MSG_PARAM_VALUE, seq);
    w8(l, id);
    w8(l, (hbp_u8)(known ? HBP_RESULT_OK : HBP_RESULT_UNKNOWN_ID));
    w32(l, known ? (uint32_t)hrt_firmware.param_get(l->rt, id) : 0u);
    finish(l);
}

/* ParamSet: the pairs read in place into a request, checked whole, applied all or nothing. */
static inline void on_set(hrt_link_t *l, const hbp_u8 *buf, hbp_u8 len, hbp_u8 seq)
{
    hrt_param_request_t req;
    hbp_u8 result;
    hbp_u8 param_id;
    hbp_u8 detail;
    hbp_u8 i;
    hbp_u8 n = (hbp_u8)((hbp_u8)(len - HBP_PARAM_SET_FIXED_LEN) / 5u);
    if (len < HBP_PARAM_SET_FIXED_LEN || (hbp_u8)(HBP_PARAM_SET_FIXED_LEN + 5u * n) != len ||
        n > HBP_MAX_PARAM_PAIRS) {
        send_error(l, seq, HBP_ERROR_LENGTH, buf[0]);
        return;
    }
    req.n = n;
    for (i = 0u; i < n; i++) {
        const hbp_u8 *pair = &buf[HBP_PARAM_SET_FIXED_LEN + 5u * i];
        req.id[i] = pair[0];
        req.value[i] = get_i32(&pair[1]);
    }
    hrt_port_lock();
    result = hrt_param_write(l->rt, &req, &param_id, &detail);
    hrt_port_unlock();
    begin(l, HBP_MSG_PARAM_SET_RESULT, seq);
    w8(l, result);
    w8(l, param_id);
    w8(l, detail);
    finish(l);
}

static HRT_NOINLINE void on_status(hrt_link_t *l, hbp_u8 seq)
{
    const hbp_rx_t *rx = &l->rx;
    begin(l, HBP_MSG_STATUS, seq);
    w16(l, rx->frames);
    w16(l, rx->errors);
    w16(l, rx->resyncs);
    w16(l, rx->unknown);
    w16(l, rx->overruns);
    w16(l, l->watchdog_trips);
    w8(l, rx->last_error);
    finish(l);
}

/* A request by its type, told apart by the type's group (its high nibble, as the schema numbers the
 * messages) first: a switch over the sparse types themselves (0x01..0x52) becomes a jump table of
 * one entry per value in between, more flash than the whole dispatch on a 12 KB chip (docs/board.md,
 * section 3a). */
void hrt_link_handle(hrt_link_t *l, const hbp_u8 *frame, hbp_u8 len)
{
    hrt_t *rt = l->rt;
    hbp_u8 type = frame[0];
    hbp_u8 seq = frame[1];
    hbp_u8 group = (hbp_u8)(type >> 4);
    hbp_u8 want = 0u; /* the payload-less (2) and one-byte (3) requests' length; 0: not a request */
#if HRT_MONITOR
    if ((l->flags & HRT_LINK_F_HELLO) != 0u && type != HBP_MSG_HOST_HELLO) {
        /* the host is there: any frame feeds the watchdog (a tripped one stays stopped until Start) */
        l->last_rx = hrt_port_now();
        l->flags = (hbp_u8)((l->flags | HRT_LINK_F_SENSORS) & (hbp_u8)~HRT_LINK_F_TRIPPED);
    }
    if (type == HBP_MSG_SENSORS) { /* a real-motor build runs on its own sensors, never on frames */
        send_error(l, seq, HBP_ERROR_BAD_REQUEST, type);
        return;
    }
    if ((l->flags & HRT_LINK_F_HELLO) == 0u && (type == HBP_MSG_START || type == HBP_MSG_PARAM_SET)) {
        /* nothing runs or changes the motor before a MONITOR hello has agreed a watchdog: a Start
         * from a host that never said hello ran the motor with none */
        send_error(l, seq, HBP_ERROR_BAD_REQUEST, type);
        return;
    }
#endif
    if (type == HBP_MSG_SENSORS) {
        on_sensors(l, frame, len, seq);
        return;
    }
    if (type == HBP_MSG_HOST_HELLO) {
        on_hello(l, frame, len, seq);
        return;
    }
#if HRT_SPECULATE
    if (type == HBP_MSG_SENSORS_BATCH) {
        on_batch(l, frame, len, seq);
        return;
    }
#endif
    if (type == HBP_MSG_PARAM_SET) {
        on_set(l, frame, len, seq);
        return;
    }
    /* (a build without the self-description, HRT_DESCRIBE 0, serves no ParamDescribe, TelemetryDescribe or
     * TargetDescribe: they are refused as the target -> host messages are) */
    if (group == (HBP_MSG_PARAM_GET >> 4)) {
        want = (hbp_u8)((type == HBP_MSG_PARAM_GET || (HRT_DESCRIBE && type == HBP_MSG_PARAM_DESCRIBE)) ? 3u : 0u);
    } else if (group == (HBP_MSG_START >> 4)) {
        want = (hbp_u8)((type == HBP_MSG_START || type == HBP_MSG_STOP) ? 2u : 0u);
    } else if (group == (HBP_MSG_STATUS_REQUEST >> 4)) {
        want = (hbp_u8)((type == HBP_MSG_STATUS_REQUEST) ? 2u : 0u);
    }
#if HRT_DESCRIBE
    else if (group == (HBP_MSG_TELEMETRY_DESCRIBE >> 4)) {
        want = (hbp_u8)((type == HBP_MSG_TELEMETRY_DESCRIBE) ? 3u : (type == HBP_MSG_TARGET_DESCRIBE) ? 2u : 0u);
    }
#endif
    if (want == 0u) {
        send_error(l, seq, HBP_ERROR_BAD_REQUEST, type); /* a target -> host message, or one not served */
        return;
    }
    if (len != want) {
        send_error(l, seq, HBP_ERROR_LENGTH, type);
        return;
    }
    if (group == (HBP_MSG_PARAM_GET >> 4)) {
#if HRT_DESCRIBE
        if (type == HBP_MSG_PARAM_DESCRIBE) {
            on_describe(l, frame[2], seq);
            return;
        }
#endif
        on_get(l, frame[2], seq);
    } else if (group == (HBP_MSG_START >> 4)) {
        hrt_port_lock();
        if (type == HBP_MSG_START) {
            hrt_firmware.start(rt); /* no reply */
        } else {
            hrt_firmware.stop(rt, HRT_STOP_COMMAND);
            /* the host stopped the outputs and may now leave: the watchdog waits for its next Sensors
             * (a trip after a clean end would leave a FAULT the next session starts in) */
            l->flags = (hbp_u8)(l->flags & (hbp_u8)~HRT_LINK_F_SENSORS);
        }
        hrt_port_unlock();
    } else if (group == (HBP_MSG_STATUS_REQUEST >> 4)) {
        on_status(l, seq);
    }
#if HRT_DESCRIBE
    else if (type == HBP_MSG_TELEMETRY_DESCRIBE) {
        on_telemetry(l, frame[2], seq);
    } else {
        on_target_describe(l, seq);
    }
#endif
}

void hrt_link_watchdog(hrt_link_t *l)
{
    uint16_t limit_ms = l->watchdog_ms;
    uint32_t ticks_per_ms;
    if (limit_ms == 0u || (l->flags & (HRT_LINK_F_SENSORS | HRT_LINK_F_TRIPPED)) != HRT_LINK_F_SENSORS) {
        return;
    }
    if (LOCKSTEP(l->mode) && limit_ms < HRT_LOCKSTEP_WATCHDOG_MIN_MS) {
        limit_ms = HRT_LOCKSTEP_WATCHDOG_MIN_MS;
    }
    ticks_per_ms = TICKS_PER_US * 1000u;
    if ((hrt_port_now() - l->last_rx) / ticks_per_ms >= limit_ms) {
        /* frames stopped: outputs off, one unsolicited Drive that says so. In lockstep the firmware's
         * virtual time stands still while the host is away, so its state is left as it is (a host
         * pausing on a loaded machine changes no recording): the port turns the outputs off and the
         * Drives say OFF until the next Sensors. In real time the firmware stops (HRT_STOP_WATCHDOG). */
        l->flags = (hbp_u8)(l->flags | HRT_LINK_F_TRIPPED);
        l->watchdog_trips = (uint16_t)(l->watchdog_trips + 1u);
        l->rx.last_error = HBP_ERROR_WATCHDOG;
        if (LOCKSTEP(l->mode)) {
            HRT_PORT_OUTPUTS_OFF();
        } else {
            hrt_port_lock();
            (&hrt_firmware)->stop(l->rt, HRT_STOP_WATCHDOG);
            hrt_port_unlock();
        }
        hrt_link_send_drive(l, l->last_seq);
    }
}

#if HRT_SPECULATE
/* A batch runs many periods: its frame is copied out and the receive buffer released first, so the
 * host's next batch (pipelined) arrives while this one runs. The copy lives in this function's own
 * frame, so the per-period path's stack does not carry it (it did when the copy sat in
 * hrt_link_poll: 74 bytes on every period's stack with avr-gcc). */
static HRT_NOINLINE void poll_batch(hrt_link_t *l)
{
    hbp_u8 frame[HBP_RX_MAX];
    hbp_u8 len = l->rx.frame_len;
    hbp_u8 i;
    for (i = 0u; i < len; i++) {
        frame[i] = l->rx.buf[i];
    }
    hbp_rx_release(&l->rx);
    hrt_link_handle(l, frame, len);
}
#endif

void hrt_link_poll(hrt_link_t *l)
{
    if (l->rx.ready) {
#if HRT_SPECULATE
        if (l->rx.buf[0] == HBP_MSG_SENSORS_BATCH) {
            poll_batch(l);
            hrt_link_watchdog(l);
            return;
        }
#endif
        hrt_link_handle(l, l->rx.buf, l->rx.frame_len);
        hbp_rx_release(&l->rx);
    }
    hrt_link_watchdog(l);
}
