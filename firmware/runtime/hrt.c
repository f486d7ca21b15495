/* hrt.c: the runtime's scheduler, real-time glue, parameters and reports (see hrt.h).
 * C99, no heap, no floating point; every narrowing is an explicit cast (16-bit int safe). */
#include "hrt.h"

/* Time comparisons are made relative to the current instant: every pending event is at or after
 * rt->now and less than 2^31 ticks ahead, so `due - now` (unsigned) orders them. */
#define HRT_HALF_RANGE 0x80000000UL

/* The timers the port runs in hardware (none unless it may: HRT_HW_TIMERS, hrt.h). */
#if HRT_HW_TIMERS
#define TIMERS_HW(rt) ((rt)->timers_hw)
#else
#define TIMERS_HW(rt) 0u
#endif

/* `static inline`: a small helper, or one called once, that XC16's -O1 inlines as GCC's does (the
 * dsPIC30F2010's 4K words, docs/board.md section 3a, measured one by one); the others stay calls. */

static inline void advance_to(hrt_t *rt, uint32_t t)
{
#if HRT_MICROS
    if (t < rt->now) {
        rt->now_hi = (uint16_t)(rt->now_hi + 1u); /* the 32-bit tick count wrapped */
    }
#endif
    rt->now = t;
}

void hrt_init(hrt_t *rt)
{
    const hrt_firmware_t *decl = &hrt_firmware;
    hbp_u8 i;
    hbp_u8 *p = (hbp_u8 *)rt;
    uint16_t k;
    uint16_t mid;
    for (k = 0u; k < (uint16_t)sizeof *rt; k++) { /* no memset: no C library needed */
        p[k] = 0u;
    }
    mid = (uint16_t)(decl->pwm_counts / 2u);
    for (i = 0u; i < 3u; i++) {
        rt->duty[i] = mid;
        rt->duty_active[i] = mid;
    }
    mid = 0u;
    if (decl->adc_bits > 0u && decl->adc_bits <= 16u) {
        mid = (uint16_t)(1u << (decl->adc_bits - 1u));
    }
    for (i = 0u; i < HRT_MAX_ADC; i++) {
        rt->adc[i] = mid;
    }
#if HRT_REPORT_MEAN
    if (decl->duty_report == HRT_REPORT_ACTIVE) {
        rt->flags = HRT_F_MEAN; /* the Drive reports the span's mean */
    }
#endif
}

/* ------------------------------------------------------------------------------- services */

#if HRT_MICROS
uint32_t hrt_micros(hrt_t *rt)
{
    /* (now_hi:now) / ticks_per_us modulo 2^32, in 32-bit steps (ticks_per_us <= 255) */
    uint32_t d = hrt_firmware.ticks_per_us;
    uint32_t x;
    uint32_t q1;
    uint32_t q0;
    if (d == 0u) {
        return 0u;
    }
    x = (((uint32_t)rt->now_hi % d) << 16) | (rt->now >> 16);
    q1 = x / d;
    x = ((x % d) << 16) | (rt->now & 0xFFFFu);
    q0 = x / d;
    return (q1 << 16) + q0;
}
#endif

uint16_t hrt_duty_active(const hrt_t *rt, hbp_u8 phase)
{
    return (hrt_firmware.duty_timing == HRT_DUTY_IMMEDIATE) ? rt->duty[phase] : rt->duty_active[phase];
}

static void active_changes(hrt_t *rt);

void hrt_pwm_write(hrt_t *rt, uint16_t a, uint16_t b, uint16_t c)
{
    if (hrt_firmware.duty_timing == HRT_DUTY_IMMEDIATE) {
        active_changes(rt); /* the registers are the outputs */
    }
    rt->duty[0] = a;
    rt->duty[1] = b;
    rt->duty[2] = c;
}

/* The active duties are about to change: count the present ones up to now (HRT_REPORT_MEAN). */
static void active_changes(hrt_t *rt)
{
#if HRT_REPORT_MEAN
    uint32_t dt = rt->now - rt->acc_mark;
    hbp_u8 i;
    if ((rt->flags & HRT_F_MEAN) == 0u) {
        return; /* no mean asked for: no 64-bit arithmetic at every latch */
    }
    for (i = 0u; i < 3u; i++) {
        rt->duty_acc[i] += (uint64_t)hrt_duty_active(rt, i) * dt;
    }
    rt->acc_mark = rt->now;
#else
    (void)rt;
#endif
}

void hrt_pwm_preset(hrt_t *rt, uint16_t a, uint16_t b, uint16_t c)
{
    active_changes(rt);
    hrt_pwm_write(rt, a, b, c);
    rt->duty_active[0] = a;
    rt->duty_active[1] = b;
    rt->duty_active[2] = c;
}

hbp_u8 hrt_attach_interrupt(hrt_t *rt, hbp_u8 lines, hbp_u8 polarity, hrt_body_fn body)
{
#if HRT_MAX_ATTACH > 0
    hbp_u8 i;
    for (i = 0u; i < HRT_MAX_ATTACH; i++) { /* replace an attachment of the same lines, or take a free slot */
        if (rt->attached[i].body != 0 && rt->attached[i].lines == lines) {
            break;
        }
    }
    if (i == HRT_MAX_ATTACH) {
        if (body == 0) {
            return 1u;
        }
        for (i = 0u; i < HRT_MAX_ATTACH && rt->attached[i].body != 0; i++) {
        }
        if (i == HRT_MAX_ATTACH) {
            return 0u;
        }
    }
    rt->attached[i].lines = lines;
    rt->attached[i].polarity = polarity;
    rt->attached[i].body = body;
    return 1u;
#else
    (void)rt;
    (void)lines;
    (void)polarity;
    (void)body;
    return 0u;
#endif
}

/* ---------------------------------------------------------------------------- dispatching */

static inline hbp_u8 polarity_matches(hbp_u8 polarity, hbp_u8 lines, hbp_u8 changed, hbp_u8 levels)
{
    hbp_u8 mine = (hbp_u8)(changed & lines);
    if (mine == 0u) {
        return 0u;
    }
    if (polarity == HRT_EDGE_RISING) {
        return (hbp_u8)((mine & levels) != 0u);
    }
    if (polarity == HRT_EDGE_FALLING) {
        return (hbp_u8)((mine & (hbp_u8)~levels) != 0u);
    }
    return 1u;
}

/* The edge lines take `lines` now: the bodies of the changed ones, in declared order. */
static void apply_edge(hrt_t *rt, hbp_u8 lines)
{
    const hrt_firmware_t *d = &hrt_firmware;
    hbp_u8 levels = (hbp_u8)((rt->in & (hbp_u8)~HRT_IN_EDGE_LINES) | (lines & HRT_IN_HALLS));
    hbp_u8 changed = (hbp_u8)(((rt->in ^ levels) & HRT_IN_HALLS) | (lines & HRT_INDEX_READ));
    hbp_u8 i;
    if (changed == 0u) {
        return;
    }
    rt->in = (hbp_u8)(levels | (lines & HRT_INDEX_READ)); /* INDEX reads 1 during its own edge only */
    rt->changed = changed;
    for (i = 0u; i < d->n_edges; i++) {
        if (polarity_matches(d->edges[i].polarity, d->edges[i].lines, changed, rt->in)) {
            d->edges[i].body(rt);
        }
    }
#if HRT_MAX_ATTACH > 0
    for (i = 0u; i < HRT_MAX_ATTACH; i++) {
        if (rt->attached[i].body != 0 &&
            polarity_matches(rt->attached[i].polarity, rt->attached[i].lines, changed, rt->in)) {
            rt->attached[i].body(rt);
        }
    }
#endif
    rt->in = (hbp_u8)(rt->in & (hbp_u8)~HRT_IN_INDEX);
    rt->changed = 0u;
}

/* One PWM period boundary: the latch, the PWM ISR, the boundary count. */
static inline void pwm_boundary(hrt_t *rt)
{
    const hrt_firmware_t *d = &hrt_firmware;
    if (d->duty_timing == HRT_DUTY_NEXT_PERIOD) {
        active_changes(rt);
        rt->duty_active[0] = rt->duty[0];
        rt->duty_active[1] = rt->duty[1];
        rt->duty_active[2] = rt->duty[2];
    }
#if HRT_HALF_PERIOD
    else if (d->duty_timing == HRT_DUTY_HALF_PERIOD) {
        rt->flags = (hbp_u8)(rt->flags | HRT_F_RELOAD);
    }
#endif
    if (d->pwm_isr != 0) {
        d->pwm_isr(rt);
    }
    rt->pwm_count = (uint16_t)(rt->pwm_count + 1u);
}

#if HRT_HALF_PERIOD
static void reload(hrt_t *rt)
{
    active_changes(rt);
    rt->flags = (hbp_u8)(rt->flags & (hbp_u8)~HRT_F_RELOAD);
    rt->duty_active[0] = rt->duty[0];
    rt->duty_active[1] = rt->duty[1];
    rt->duty_active[2] = rt->duty[2];
}

#endif

/* The timer slot of a periodic main body. */
static hbp_u8 main_slot(const hrt_firmware_t *d)
{
#if HRT_MAIN_RATE
    return (d->main_body != 0 && d->main_period_ticks != 0u) ? d->n_timers : HRT_NONE;
#else
    (void)d;
    return HRT_NONE;
#endif
}

static inline void expire(hrt_t *rt, hbp_u8 id)
{
    const hrt_firmware_t *d = &hrt_firmware;
    uint32_t period;
    hrt_body_fn body;
#if HRT_MAIN_RATE
    if (id == main_slot(d)) {
        period = d->main_period_ticks;
        body = d->main_body;
    } else
#endif
    {
        period = d->timers[id].period_ticks;
        body = d->timers[id].body;
    }
    if (period == 0u) {
        rt->timers_on = (hbp_u8)(rt->timers_on & (hbp_u8)~(hbp_u8)(1u << id));
    } else {
        rt->timer_due[id] += period; /* before the body, which may stop or restart it */
    }
    body(rt);
}

#define EV_NONE 0u
#define EV_PWM 1u
#define EV_RELOAD 2u
#define EV_TIMER 3u

/* The first event before (bound_rel ticks from now, bound_prio): due earlier, or due at the bound
 * with a priority below bound_prio. Ties: the lower priority first; equal priorities: the PWM
 * boundary (or reload), then the timers in declared order. Returns its kind (EV_NONE: none), *id the
 * timer, *rel its time from now. Inline in run_until, its one caller. */
static inline hbp_u8 next_event(const hrt_t *rt, uint32_t bound_rel, hbp_u8 bound_prio, hbp_u8 *id,
                                       uint32_t *rel_out)
{
    const hrt_firmware_t *d = &hrt_firmware;
    hbp_u8 n_slots = (hbp_u8)(d->n_timers + (main_slot(d) != HRT_NONE ? 1u : 0u));
    hbp_u8 usable = (hbp_u8)(rt->timers_on & (hbp_u8)~TIMERS_HW(rt));
    hbp_u8 kind = EV_NONE;
    hbp_u8 k = EV_PWM; /* the PWM boundary first (it wins ties of equal priority), then the timers */
    hbp_u8 prio = d->pwm_priority;
    hbp_u8 i = 0u;
    uint32_t rel = rt->pwm_due - rt->now;
#if HRT_HALF_PERIOD
    if ((rt->flags & HRT_F_RELOAD) != 0u && rel - (d->pwm_period_ticks >> 1) < rel) {
        rel -= d->pwm_period_ticks >> 1; /* the half-period reload comes first */
        k = EV_RELOAD;
    }
#endif
    for (;;) {
        if (rel < bound_rel || (rel == bound_rel && prio < bound_prio)) {
            bound_rel = rel;
            bound_prio = prio;
            kind = k;
            *id = (hbp_u8)(i - 1u);
        }
        while (i < n_slots && ((unsigned)usable & (1u << i)) == 0u) {
            i++;
        }
        if (i >= n_slots) {
            break;
        }
        rel = rt->timer_due[i] - rt->now;
#if HRT_MAIN_RATE
        prio = (i < d->n_timers) ? d->timers[i].priority : d->main_priority;
#else
        prio = d->timers[i].priority;
#endif
        k = EV_TIMER;
        i++;
    }
    *rel_out = bound_rel;
    return kind;
}

/* Serve every event before (bound, bound_prio) (see next_event). */
static void run_until(hrt_t *rt, uint32_t bound, hbp_u8 bound_prio)
{
    uint32_t bound_rel = bound - rt->now;
    if (bound_rel >= HRT_HALF_RANGE) {
        return; /* the bound is already past */
    }
    for (;;) {
        hbp_u8 id = 0u;
        uint32_t rel;
        hbp_u8 kind = next_event(rt, bound_rel, bound_prio, &id, &rel);
        if (kind == EV_NONE) {
            return;
        }
        advance_to(rt, rt->now + rel);
        bound_rel -= rel;
        if (kind == EV_PWM) {
            rt->pwm_due += hrt_firmware.pwm_period_ticks;
            pwm_boundary(rt);
        }
#if HRT_HALF_PERIOD
        else if (kind == EV_RELOAD) {
            reload(rt);
        }
#endif
        else {
            expire(rt, id);
        }
    }
}

/* ------------------------------------------------------------------------------- lockstep */

void hrt_span_begin(hrt_t *rt, hbp_u8 inputs, hbp_u8 n_edges, hbp_u8 edges_have_index, const uint16_t *adc,
                    hbp_u8 n_adc, uint16_t encoder)
{
    const hrt_firmware_t *d = &hrt_firmware;
    hbp_u8 start = 0u;
    hbp_u8 hall = (hbp_u8)(rt->in & HRT_IN_HALLS);
#if HRT_REPORT_MEAN
    if ((rt->flags & HRT_F_MEAN) != 0u) { /* the span's mean is kept: its accumulators from now */
        rt->duty_acc[0] = 0u;
        rt->duty_acc[1] = 0u;
        rt->duty_acc[2] = 0u;
        rt->acc_mark = rt->now;
        rt->span_start = rt->now;
    }
#endif
    hrt_rt_levels(rt, inputs, adc, n_adc, encoder);
    if (d->main_body != 0 && d->main_period_ticks == 0u) {
        d->main_body(rt);
    }
    if (n_edges == 0u && ((inputs ^ hall) & HRT_IN_HALLS) != 0u) {
        hall = (hbp_u8)(inputs & HRT_IN_HALLS);
        start = 1u;
    }
    if ((inputs & HRT_INDEX_READ) != 0u && !edges_have_index) {
        hall = (hbp_u8)(hall | HRT_IN_INDEX);
        start = 1u;
    }
    if (start) { /* at the span's first tick, after the events of that tick with a lower priority */
        run_until(rt, rt->now, d->edge_priority);
        apply_edge(rt, hall);
    }
}

void hrt_span_edge(hrt_t *rt, uint32_t at_ticks, hbp_u8 lines)
{
    if (at_ticks - rt->now >= HRT_HALF_RANGE) {
        at_ticks = rt->now; /* an edge listed out of order is served now */
    }
    run_until(rt, at_ticks, hrt_firmware.edge_priority);
    advance_to(rt, at_ticks);
    apply_edge(rt, lines);
}

void hrt_span_end(hrt_t *rt, uint32_t end_ticks)
{
    run_until(rt, end_ticks, 0u);
    if (end_ticks - rt->now < HRT_HALF_RANGE) {
        advance_to(rt, end_ticks);
    }
#if HRT_REPORT_MEAN
    if ((rt->flags & HRT_F_MEAN) != 0u) {
        uint32_t span = rt->now - rt->span_start;
        hbp_u8 i;
        active_changes(rt);
        for (i = 0u; i < 3u; i++) {
            uint64_t q = span ? rt->duty_acc[i] / span : hrt_duty_active(rt, i);
            uint64_t r2 = span ? 2u * (rt->duty_acc[i] % span) : 0u;
            if (r2 > span || (r2 == span && span != 0u && (q & 1u) != 0u)) {
                q++; /* half to even */
            }
            rt->duty_mean[i] = (uint16_t)q;
        }
    }
#endif
}

/* ------------------------------------------------------------------------------ real time */

void hrt_rt_enter(hrt_t *rt, hbp_u8 hw)
{
    rt->flags = (hbp_u8)(hw ? (rt->flags | HRT_F_HW) : (rt->flags & (hbp_u8)~HRT_F_HW));
}

/* Soft timers due by now (real time on a hardware port). */
static void rt_soft_timers(hrt_t *rt, uint32_t now)
{
    hbp_u8 i;
    hbp_u8 n_slots = hrt_firmware.n_timers;
    if (main_slot(&hrt_firmware) != HRT_NONE) {
        n_slots = (hbp_u8)(n_slots + 1u);
    }
    for (i = 0u; i < n_slots; i++) {
        hbp_u8 bit = (hbp_u8)(1u << i);
        if ((rt->timers_on & bit) != 0u && (TIMERS_HW(rt) & bit) == 0u &&
            now - rt->timer_due[i] < HRT_HALF_RANGE) {
            advance_to(rt, rt->timer_due[i]);
            expire(rt, i);
        }
    }
    advance_to(rt, now);
}

void hrt_rt_pwm(hrt_t *rt, uint32_t now)
{
    advance_to(rt, now);
    rt->pwm_due = now + hrt_firmware.pwm_period_ticks;
    pwm_boundary(rt);
    rt_soft_timers(rt, now);
}

#if HRT_HALF_PERIOD
void hrt_rt_reload(hrt_t *rt, uint32_t now)
{
    advance_to(rt, now);
    reload(rt);
}
#endif

void hrt_rt_timer(hrt_t *rt, hbp_u8 id, uint32_t now)
{
    if ((rt->timers_on & (hbp_u8)(1u << id)) == 0u) {
        return;
    }
    advance_to(rt, now);
    expire(rt, id);
}

void hrt_rt_edge(hrt_t *rt, hbp_u8 lines, uint32_t at)
{
    uint32_t keep = rt->now;
    rt->now = at; /* the capture time the edge bodies read (it may lie before the present) */
    apply_edge(rt, lines);
    rt->now = keep;
}

void hrt_rt_levels(hrt_t *rt, hbp_u8 levels, const uint16_t *adc, hbp_u8 n_adc, uint16_t encoder)
{
    hbp_u8 i;
    rt->in = (hbp_u8)((rt->in & HRT_IN_HALLS) | (levels & (hbp_u8)~HRT_IN_EDGE_LINES));
    for (i = 0u; i < n_adc && i < HRT_MAX_ADC; i++) {
        rt->adc[i] = adc[i];
    }
#if HRT_ENCODER
    rt->encoder = encoder;
#else
    (void)encoder;
#endif
}

void hrt_rt_main(hrt_t *rt, uint32_t now)
{
    advance_to(rt, now);
    if (hrt_firmware.main_body != 0) {
        hrt_firmware.main_body(rt);
    }
}

/* ----------------------------------------------------------------------------- parameters */

int32_t hrt_param_candidate(hrt_t *rt, const hrt_param_request_t *req, hbp_u8 id)
{
    hbp_u8 i;
    int32_t value = hrt_firmware.param_get(rt, id);
    for (i = 0u; i < req->n; i++) {
        if (req->id[i] == id) {
            value = req->value[i];
        }
    }
    return value;
}

hbp_u8 hrt_param_write(hrt_t *rt, const hrt_param_request_t *req, hbp_u8 *param_id, hbp_u8 *detail)
{
    const hrt_firmware_t *d = &hrt_firmware;
    hbp_u8 i;
    hbp_u8 j;
    *param_id = 0u;
    *detail = 0u;
    if (req->n == 0u || req->n > HBP_MAX_PARAM_PAIRS) {
        return HBP_RESULT_BAD_REQUEST;
    }
    for (i = 0u; i < req->n; i++) {
        hbp_u8 id = req->id[i];
        int32_t value = req->value[i];
        *param_id = id;
        if (id >= d->n_params) {
            return HBP_RESULT_UNKNOWN_ID;
        }
        if (d->params[id].access != HBP_ACCESS_RW) {
            return HBP_RESULT_READ_ONLY;
        }
        if (value < d->params[id].min_value || value > d->params[id].max_value) {
            return HBP_RESULT_OUT_OF_RANGE;
        }
        for (j = 0u; j < i; j++) {
            if (req->id[j] == id) {
                return HBP_RESULT_BAD_REQUEST; /* the same id twice */
            }
        }
    }
    if (d->param_check != 0) {
        hbp_u8 result = d->param_check(rt, req, param_id, detail);
        if (result != HBP_RESULT_OK) {
            return result;
        }
    }
    for (i = 0u; i < req->n; i++) {
        d->param_set(rt, req->id[i], req->value[i]);
    }
    *param_id = req->id[req->n - 1u];
    *detail = 0u;
    return HBP_RESULT_OK;
}

/* -------------------------------------------------------------------------------- reports */

static inline uint16_t clamp_duty(uint16_t v)
{
    return (v > hrt_firmware.pwm_counts) ? hrt_firmware.pwm_counts : v;
}

/* The duty the declaration's duty_report names, of one phase. */
static inline uint16_t reported_duty(const hrt_t *rt, hbp_u8 phase)
{
    if (hrt_firmware.duty_report != HRT_REPORT_ACTIVE) {
        return rt->duty[phase]; /* the registers as written: in effect from the next latch */
    }
#if HRT_REPORT_MEAN
    if ((rt->flags & HRT_F_HW) == 0u) {
        return rt->duty_mean[phase];
    }
#endif
    return hrt_duty_active(rt, phase);
}

void hrt_report(hrt_t *rt, hbp_u8 seq, hrt_report_t *out)
{
    out->seq = seq;
    out->duty_a = clamp_duty(reported_duty(rt, 0u));
    out->duty_b = clamp_duty(reported_duty(rt, 1u));
    out->duty_c = clamp_duty(reported_duty(rt, 2u));
    out->n_telemetry = hrt_firmware.n_telemetry;
    hrt_firmware.report(rt, out);
}
