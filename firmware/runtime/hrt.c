/* hrt.c: the runtime's scheduler, real-time glue, parameters and reports (see hrt.h).
 * C99, no heap, no floating point; every narrowing is an explicit cast (16-bit int safe). */
#include "hrt.h"

/* Time comparisons are made relative to the current instant: every pending event is at or after
 * rt->now and less than 2^31 ticks ahead, so `due - now` (unsigned) orders them. */
#define HRT_HALF_RANGE 0x80000000UL

/* Keep a function out of its callers (GCC, XC16): a leaf's locals then never sit under a body's. */
#if defined(__GNUC__)
#define HRT_NOINLINE __attribute__((noinline))
#else
#define HRT_NOINLINE
#endif

static void advance_to(hrt_t *rt, uint32_t t)
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
    uint8_t i;
    uint8_t *p = (uint8_t *)rt;
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

uint16_t hrt_duty_active(const hrt_t *rt, uint8_t phase)
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
    uint8_t i;
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

void hrt_timer_start(hrt_t *rt, uint8_t id, uint32_t first_ticks)
{
    uint8_t bit = (uint8_t)(1u << id);
    if (first_ticks == 0u) {
        first_ticks = 1u;
    }
    rt->timer_due[id] = rt->now + first_ticks;
    rt->timers_on = (uint8_t)(rt->timers_on | bit);
    rt->timers_hw = (uint8_t)(rt->timers_hw & (uint8_t)~bit);
#if defined(HRT_PORT_HW) && HRT_PORT_HW
    if ((rt->flags & HRT_F_HW) != 0u && hrt_port_timer(id, 1u, first_ticks)) {
        rt->timers_hw = (uint8_t)(rt->timers_hw | bit);
    }
#endif
}

void hrt_timer_stop(hrt_t *rt, uint8_t id)
{
    uint8_t bit = (uint8_t)(1u << id);
#if defined(HRT_PORT_HW) && HRT_PORT_HW
    if ((rt->timers_hw & bit) != 0u) {
        (void)hrt_port_timer(id, 0u, 0u);
    }
#endif
    rt->timers_on = (uint8_t)(rt->timers_on & (uint8_t)~bit);
    rt->timers_hw = (uint8_t)(rt->timers_hw & (uint8_t)~bit);
}

uint8_t hrt_attach_interrupt(hrt_t *rt, uint8_t lines, uint8_t polarity, hrt_body_fn body)
{
#if HRT_MAX_ATTACH > 0
    uint8_t i;
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

static uint8_t polarity_matches(uint8_t polarity, uint8_t lines, uint8_t changed, uint8_t levels)
{
    uint8_t mine = (uint8_t)(changed & lines);
    if (mine == 0u) {
        return 0u;
    }
    if (polarity == HRT_EDGE_RISING) {
        return (uint8_t)((mine & levels) != 0u);
    }
    if (polarity == HRT_EDGE_FALLING) {
        return (uint8_t)((mine & (uint8_t)~levels) != 0u);
    }
    return 1u;
}

/* The edge lines take `lines` now: the bodies of the changed ones, in declared order. */
static void apply_edge(hrt_t *rt, uint8_t lines)
{
    const hrt_firmware_t *d = &hrt_firmware;
    uint8_t levels = (uint8_t)((rt->in & (uint8_t)~HRT_IN_EDGE_LINES) | (lines & HRT_IN_HALLS));
    uint8_t changed = (uint8_t)(((rt->in ^ levels) & HRT_IN_HALLS) | (lines & HRT_IN_INDEX));
    uint8_t i;
    if (changed == 0u) {
        return;
    }
    rt->in = (uint8_t)(levels | (lines & HRT_IN_INDEX)); /* INDEX reads 1 during its own edge only */
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
    rt->in = (uint8_t)(rt->in & (uint8_t)~HRT_IN_INDEX);
    rt->changed = 0u;
}

/* One PWM period boundary: the latch, the PWM ISR, the boundary count. */
static void pwm_boundary(hrt_t *rt)
{
    const hrt_firmware_t *d = &hrt_firmware;
    if (d->duty_timing == HRT_DUTY_NEXT_PERIOD) {
        active_changes(rt);
        rt->duty_active[0] = rt->duty[0];
        rt->duty_active[1] = rt->duty[1];
        rt->duty_active[2] = rt->duty[2];
    } else if (d->duty_timing == HRT_DUTY_HALF_PERIOD) {
        rt->flags = (uint8_t)(rt->flags | HRT_F_RELOAD);
    }
    if (d->pwm_isr != 0) {
        d->pwm_isr(rt);
    }
    rt->pwm_count = (uint16_t)(rt->pwm_count + 1u);
}

static void reload(hrt_t *rt)
{
    active_changes(rt);
    rt->flags = (uint8_t)(rt->flags & (uint8_t)~HRT_F_RELOAD);
    rt->duty_active[0] = rt->duty[0];
    rt->duty_active[1] = rt->duty[1];
    rt->duty_active[2] = rt->duty[2];
}

/* The timer slot of a periodic main body. */
static uint8_t main_slot(const hrt_firmware_t *d)
{
    return (d->main_body != 0 && d->main_period_ticks != 0u) ? d->n_timers : HRT_NONE;
}

static void expire(hrt_t *rt, uint8_t id)
{
    const hrt_firmware_t *d = &hrt_firmware;
    uint32_t period;
    hrt_body_fn body;
    if (id == main_slot(d)) {
        period = d->main_period_ticks;
        body = d->main_body;
    } else {
        period = d->timers[id].period_ticks;
        body = d->timers[id].body;
    }
    if (period == 0u) {
        rt->timers_on = (uint8_t)(rt->timers_on & (uint8_t)~(uint8_t)(1u << id));
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
 * with a priority below bound_prio. Ties: the lower priority first; equal priorities: PWM, reload,
 * timers in declared order. Returns its kind (EV_NONE: none), *rel its time from now. A leaf, so
 * that the bodies run on a small stack. */
static HRT_NOINLINE uint8_t next_event(const hrt_t *rt, uint32_t bound_rel, uint8_t bound_prio, uint8_t *id,
                                       uint32_t *rel_out)
{
    const hrt_firmware_t *d = &hrt_firmware;
    uint32_t best = bound_rel;
    uint8_t best_prio = bound_prio;
    uint8_t kind = EV_NONE;
    uint8_t n_slots = d->n_timers;
    uint8_t i;
    uint32_t rel;
    if (main_slot(d) != HRT_NONE) {
        n_slots = (uint8_t)(n_slots + 1u);
    }
    for (i = 0u; i <= n_slots; i++) {
        uint8_t prio = d->pwm_priority;
        uint8_t k = EV_TIMER;
        if (i == n_slots) { /* the PWM boundary, then the half-period reload */
            rel = rt->pwm_due - rt->now;
            k = EV_PWM;
            if ((rt->flags & HRT_F_RELOAD) != 0u) {
                uint32_t r = rel - (d->pwm_period_ticks >> 1);
                if (r < rel) {
                    rel = r;
                    k = EV_RELOAD;
                }
            }
        } else if ((rt->timers_on & (uint8_t)(1u << i)) != 0u && (rt->timers_hw & (uint8_t)(1u << i)) == 0u) {
            prio = (i < d->n_timers) ? d->timers[i].priority : d->main_priority;
            rel = rt->timer_due[i] - rt->now;
        } else {
            continue;
        }
        if (rel < best || (rel == best && prio < best_prio) ||
            (rel == best && prio == best_prio && k != EV_TIMER && kind == EV_TIMER)) {
            best = rel;
            best_prio = prio;
            kind = k;
            *id = i;
        }
    }
    *rel_out = best;
    return kind;
}

/* Serve every event before (bound, bound_prio) (see next_event). */
static void run_until(hrt_t *rt, uint32_t bound, uint8_t bound_prio)
{
    uint32_t bound_rel = bound - rt->now;
    if (bound_rel >= HRT_HALF_RANGE) {
        return; /* the bound is already past */
    }
    for (;;) {
        uint8_t id = 0u;
        uint32_t rel;
        uint8_t kind = next_event(rt, bound_rel, bound_prio, &id, &rel);
        if (kind == EV_NONE) {
            return;
        }
        advance_to(rt, rt->now + rel);
        bound_rel -= rel;
        if (kind == EV_PWM) {
            rt->pwm_due += hrt_firmware.pwm_period_ticks;
            pwm_boundary(rt);
        } else if (kind == EV_RELOAD) {
            reload(rt);
        } else {
            expire(rt, id);
        }
    }
}

/* ------------------------------------------------------------------------------- lockstep */

void hrt_span_begin(hrt_t *rt, uint8_t inputs, uint8_t n_edges, uint8_t edges_have_index, const uint16_t *adc,
                    uint8_t n_adc, uint16_t encoder)
{
    const hrt_firmware_t *d = &hrt_firmware;
    uint8_t start = 0u;
    uint8_t hall = (uint8_t)(rt->in & HRT_IN_HALLS);
#if HRT_REPORT_MEAN
    rt->duty_acc[0] = 0u;
    rt->duty_acc[1] = 0u;
    rt->duty_acc[2] = 0u;
    rt->acc_mark = rt->now;
    rt->span_start = rt->now;
#endif
    hrt_rt_levels(rt, inputs, adc, n_adc, encoder);
    if (d->main_body != 0 && d->main_period_ticks == 0u) {
        d->main_body(rt);
    }
    if (n_edges == 0u && ((inputs ^ hall) & HRT_IN_HALLS) != 0u) {
        hall = (uint8_t)(inputs & HRT_IN_HALLS);
        start = 1u;
    }
    if ((inputs & HRT_IN_INDEX) != 0u && !edges_have_index) {
        hall = (uint8_t)(hall | HRT_IN_INDEX);
        start = 1u;
    }
    if (start) { /* at the span's first tick, after the events of that tick with a lower priority */
        run_until(rt, rt->now, d->edge_priority);
        apply_edge(rt, hall);
    }
}

void hrt_span_edge(hrt_t *rt, uint32_t at_ticks, uint8_t lines)
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
    {
        uint32_t span = rt->now - rt->span_start;
        uint8_t i;
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

void hrt_rt_enter(hrt_t *rt, uint8_t hw)
{
    rt->flags = (uint8_t)(hw ? (rt->flags | HRT_F_HW) : (rt->flags & (uint8_t)~HRT_F_HW));
}

/* Soft timers due by now (real time on a hardware port). */
static void rt_soft_timers(hrt_t *rt, uint32_t now)
{
    uint8_t i;
    uint8_t n_slots = hrt_firmware.n_timers;
    if (main_slot(&hrt_firmware) != HRT_NONE) {
        n_slots = (uint8_t)(n_slots + 1u);
    }
    for (i = 0u; i < n_slots; i++) {
        uint8_t bit = (uint8_t)(1u << i);
        if ((rt->timers_on & bit) != 0u && (rt->timers_hw & bit) == 0u &&
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

void hrt_rt_reload(hrt_t *rt, uint32_t now)
{
    advance_to(rt, now);
    reload(rt);
}

void hrt_rt_timer(hrt_t *rt, uint8_t id, uint32_t now)
{
    if ((rt->timers_on & (uint8_t)(1u << id)) == 0u) {
        return;
    }
    advance_to(rt, now);
    expire(rt, id);
}

void hrt_rt_edge(hrt_t *rt, uint8_t lines, uint32_t at)
{
    uint32_t keep = rt->now;
    rt->now = at; /* the capture time the edge bodies read (it may lie before the present) */
    apply_edge(rt, lines);
    rt->now = keep;
}

void hrt_rt_levels(hrt_t *rt, uint8_t levels, const uint16_t *adc, uint8_t n_adc, uint16_t encoder)
{
    uint8_t i;
    rt->in = (uint8_t)((rt->in & HRT_IN_HALLS) | (levels & (uint8_t)~HRT_IN_EDGE_LINES));
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

int32_t hrt_param_candidate(hrt_t *rt, const hrt_param_request_t *req, uint8_t id)
{
    uint8_t i;
    int32_t value = hrt_firmware.param_get(rt, id);
    for (i = 0u; i < req->n; i++) {
        if (req->id[i] == id) {
            value = req->value[i];
        }
    }
    return value;
}

uint8_t hrt_param_write(hrt_t *rt, const hrt_param_request_t *req, uint8_t *param_id, uint8_t *detail)
{
    const hrt_firmware_t *d = &hrt_firmware;
    uint8_t i;
    uint8_t j;
    *param_id = 0u;
    *detail = 0u;
    if (req->n == 0u || req->n > HBP_MAX_PARAM_PAIRS) {
        return HBP_RESULT_BAD_REQUEST;
    }
    for (i = 0u; i < req->n; i++) {
        uint8_t id = req->id[i];
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
        uint8_t result = d->param_check(rt, req, param_id, detail);
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

static uint16_t clamp_duty(uint16_t v)
{
    return (v > hrt_firmware.pwm_counts) ? hrt_firmware.pwm_counts : v;
}

/* The duty the declaration's duty_report names, of one phase. */
static uint16_t reported_duty(const hrt_t *rt, uint8_t phase)
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

void hrt_report(hrt_t *rt, uint8_t seq, hrt_report_t *out)
{
    out->seq = seq;
    out->duty_a = clamp_duty(reported_duty(rt, 0u));
    out->duty_b = clamp_duty(reported_duty(rt, 1u));
    out->duty_c = clamp_duty(reported_duty(rt, 2u));
    out->n_telemetry = hrt_firmware.n_telemetry;
    hrt_firmware.report(rt, out);
}
