/* The switching inverter of the C plant backend: hilbench/plant/switching.py, operation by operation.
 *
 * Included by _plantcore.c after the Core struct and the functions it shares (edge_time, finish,
 * friction, rk4_dq, sense):
 * one compilation unit, the bridge kept in its own file. Every function here has the name of the
 * Python function it mirrors; the arithmetic is in the same order (built with -ffp-contract=off),
 * so the two backends agree to the last bit on the same libm (tests/test_switching_backends.py).
 * The state lives in Core's members (_sw_u, _sw_s0.., _sw_e0.., _ia_s, _ib_s, _adc_live) so that the
 * Python reference can take over any period (energy tracking, a quadratic load).
 */

#define SW_HIGH 1
#define SW_LOW 0
#define SW_DEAD 2
#define SW_PHASE_EPS 1e-9
#define SW_DUTY_EPS 1e-6

/* switching.advance_phase */
static double sw_advance_phase(double u, double dt_s, double freq_hz)
{
    u = u + dt_s * freq_hz;
    double n = floor(u + 0.5);
    if (-SW_PHASE_EPS < u - n && u - n < SW_PHASE_EPS) u = n;
    return u - floor(u);
}

/* switching.idle: returns the carrier's phase at the period's start */
static double sw_idle(Core *s, double dt_s)
{
    double u0 = s->sw_u;
    s->sw_u = sw_advance_phase(u0, dt_s, s->sw_f);
    s->sw_s[0] = s->sw_s[1] = s->sw_s[2] = 0;
    s->sw_e[0] = s->sw_e[1] = s->sw_e[2] = -INFINITY;
    s->adc_live = 1;
    return u0;
}

/* switching.ideal_high */
static int sw_ideal_high(double u, double centre, double duty)
{
    if (duty <= SW_DUTY_EPS) return 0;
    if (duty >= 1.0 - SW_DUTY_EPS) return 1;
    double x = u + SW_PHASE_EPS - centre + 0.5 * duty;
    return x - floor(x) < duty ? 1 : 0;
}

/* switching.next_edge: the phase of the leg's next ideal edge, and the command it sets */
static double sw_next_edge(double u, double centre, double duty, int *kind)
{
    *kind = 0;
    if (duty <= SW_DUTY_EPS || duty >= 1.0 - SW_DUTY_EPS) return INFINITY;
    double w = 0.5 * duty;
    double x = u - centre + w;
    double r = floor(x) + 1.0 - x;
    double y = u - centre - w;
    double f = floor(y) + 1.0 - y;
    if (r <= SW_PHASE_EPS) r += 1.0;
    if (f <= SW_PHASE_EPS) f += 1.0;
    if (r < f) { *kind = 1; return u + r; }
    return u + f;
}

/* switching.next_sample */
static double sw_next_sample(double u, double sample)
{
    double x = u - sample;
    double r = floor(x) + 1.0 - x;
    if (r <= SW_PHASE_EPS) r += 1.0;
    return u + r;
}

static void sw_back_emf_abc(Core *s, double e[3]);

/* switching.dead_band_volt_seconds */
static double sw_dead_band_volt_seconds(int rising, double i_e, double lo_v, double hi_v, double v_f, double vbus,
                                        double td, double rs, double l_h)
{
    double v, slope;
    if (i_e > 0.0) {
        v = 0.0;
        slope = (lo_v - rs * i_e) / l_h;
    } else if (i_e < 0.0) {
        v = vbus;
        slope = (hi_v - rs * i_e) / l_h;
    } else {
        v = v_f;
        slope = 0.0;
    }
    double t_z = td;
    if (i_e != 0.0 && slope != 0.0 && ((slope > 0.0) != (i_e > 0.0))) {
        t_z = -i_e / slope;
        if (t_z > td) t_z = td;
    }
    double held = v * t_z + v_f * (td - t_z);
    return held - (rising ? vbus * td : 0.0);
}

/* switching.average_dead_time: the averaged bridge's duties with the dead band edge by edge */
static void sw_average_dead_time(Core *s, double u0, double *duty_a, double *duty_b, double *duty_c, double dt_s)
{
    const double f = s->sw_f, td = s->sw_td, c = s->sw_c, vbus = s->vbus_v;
    double da = *duty_a, db = *duty_b, dc = *duty_c;
    double duties[3] = {da, db, dc}, out[3], e[3];
    double mean_d = (da + db + dc) / 3.0;
    double i0[3] = {s->i_a, s->i_b, s->i_c};
    sw_back_emf_abc(s, e);
    double half_t = 0.5 / f;
    for (int x = 0; x < 3; x++) {
        double d = duties[x];
        if (d <= SW_DUTY_EPS || d >= 1.0 - SW_DUTY_EPS) {
            out[x] = d;
            continue;
        }
        double g = d - ((d < da ? d : da) + (d < db ? d : db) + (d < dc ? d : dc)) / 3.0 - d * (d - mean_d);
        double ripple = vbus * half_t * g / s->sw_l;
        double slope = (vbus * (d - mean_d) - s->rs * i0[x] - e[x]) / s->sw_l;
        int n_hi = (da > d) + (db > d) + (dc > d);
        double lo_v = -vbus * n_hi / 3.0 - e[x];
        double hi_v = vbus * (2 - n_hi) / 3.0 - e[x];
        double v_f = 1.5 * e[x] + 0.5 * vbus * n_hi;
        v_f = v_f < 0.0 ? 0.0 : v_f > vbus ? vbus : v_f;
        double err = 0.0, u = u0;
        for (;;) {
            int kind;
            double ph = sw_next_edge(u, c, d, &kind);
            double t = (ph - u0) / f;
            if (t >= dt_s - SW_PHASE_EPS / f) break;
            double i_e = i0[x] + slope * t + (kind ? -ripple : ripple);
            err += sw_dead_band_volt_seconds(kind, i_e, lo_v, hi_v, v_f, vbus, td, s->rs, s->sw_l) / vbus;
            u = ph;
        }
        double xd = d + err / dt_s;
        out[x] = xd < 0.0 ? 0.0 : xd > 1.0 ? 1.0 : xd;
    }
    *duty_a = out[0]; *duty_b = out[1]; *duty_c = out[2];
}

/* cos and sin of the rotor angle, remembered for the angle last asked (the start of an interval
 * is the end of the one before): the same values, computed once */
static void sw_trig(Core *s, double th, double *c, double *sn)
{
    if (!(s->trig_ok && th == s->trig_th)) {
        s->trig_th = th;
        s->trig_c = cos(th);
        s->trig_s = sin(th);
        s->trig_ok = 1;
    }
    *c = s->trig_c;
    *sn = s->trig_s;
}

/* model.Plant._abc_now and _phase_currents (round-off of an open phase snapped to zero) */
static void sw_abc_now(Core *s, double out[3])
{
    double c, sn;
    sw_trig(s, s->th, &c, &sn);
    double ia = s->i_d * c - s->i_q * sn;
    double ibe = s->i_d * sn + s->i_q * c;
    out[0] = ia;
    out[1] = -0.5 * ia + HALF_SQRT3 * ibe;
    out[2] = -0.5 * ia - HALF_SQRT3 * ibe;
}

static void sw_phase_currents(Core *s, double out[3])
{
    sw_abc_now(s, out);
    for (int k = 0; k < 3; k++)
        if (-1e-12 < out[k] && out[k] < 1e-12) out[k] = 0.0;
}

/* model.Plant._project: the open phases' currents to exactly zero, the sum kept zero */
static void sw_project(Core *s, const double i[3], const int open_[3], int n_open)
{
    if (n_open == 0) return;
    int live[3], n_live = 0;
    for (int k = 0; k < 3; k++) {
        int is_open = 0;
        for (int m = 0; m < n_open; m++) is_open |= open_[m] == k;
        if (!is_open) live[n_live++] = k;
    }
    if (n_live < 2) { s->i_d = 0.0; s->i_q = 0.0; return; }
    int a = live[0], b = live[1];
    double x = 0.5 * (i[a] - i[b]);
    double out[3] = {0.0, 0.0, 0.0};
    out[a] = x;
    out[b] = -x;
    if (x == 0.0) { s->i_d = 0.0; s->i_q = 0.0; return; }
    /* model.Plant._set_phase_currents */
    double c, sn;
    sw_trig(s, s->th, &c, &sn);
    double ial = out[0];
    double ibe = (out[0] + 2.0 * out[1]) * INV_SQRT3;
    s->i_d = ial * c + ibe * sn;
    s->i_q = -ial * sn + ibe * c;
}

/* model.Plant._compare_now: the overcurrent comparator at an interval's end (the ripple's peaks) */
static void sw_compare_now(Core *s)
{
    double oc = s->oc;
    if (s->i_d * s->i_d + s->i_q * s->i_q > oc * oc) {
        double i[3];
        sw_abc_now(s, i);
        if (i[0] > oc || i[0] < -oc || i[1] > oc || i[1] < -oc || i[2] > oc || i[2] < -oc)
            s->fault_input = 1;
    }
}

/* model.Plant._back_emf_abc */
static void sw_back_emf_abc(Core *s, double e[3])
{
    double we = s->p * s->w_m, c, sn;
    sw_trig(s, s->th, &c, &sn);
    double e_al = -we * s->psi * sn;
    double e_be = we * s->psi * c;
    e[0] = e_al;
    e[1] = -0.5 * e_al + HALF_SQRT3 * e_be;
    e[2] = -0.5 * e_al - HALF_SQRT3 * e_be;
}

/* switching.phase_slopes */
static void sw_phase_slopes(Core *s, const double v[3], double out[3])
{
    double va = (2.0 * v[0] - v[1] - v[2]) / 3.0;
    double vb = (v[1] - v[2]) * INV_SQRT3;
    double c, sn;
    sw_trig(s, s->th, &c, &sn);
    double idv = s->i_d, iqv = s->i_q, we = s->p * s->w_m;
    double vd = va * c + vb * sn;
    double vq = vb * c - va * sn;
    double did = (vd - s->rs * idv + we * s->lq * iqv) / s->ld;
    double diq = (vq - s->rs * iqv - we * (s->ld * idv + s->psi)) / s->lq;
    double dal = did * c - diq * sn - we * (idv * sn + iqv * c);
    double dbe = did * sn + diq * c + we * (idv * c - iqv * sn);
    out[0] = dal;
    out[1] = -0.5 * dal + HALF_SQRT3 * dbe;
    out[2] = -0.5 * dal - HALF_SQRT3 * dbe;
}

/* switching.open_leg_voltage */
static double sw_open_leg_voltage(Core *s, const double v[3], int o, double vbus)
{
    double lo[3] = {v[0], v[1], v[2]}, hi[3] = {v[0], v[1], v[2]}, d[3];
    lo[o] = 0.0;
    hi[o] = vbus;
    sw_phase_slopes(s, lo, d);
    double f0 = d[o];
    sw_phase_slopes(s, hi, d);
    double f1 = d[o];
    return -f0 * vbus / (f1 - f0);
}

/* switching.float_open_legs: v of the open legs; returns how many stay open */
static int sw_float_open_legs(Core *s, double v[3], int open_[3], int n_open, double vbus)
{
    while (n_open >= 2) {
        double e[3], vn;
        sw_back_emf_abc(s, e);
        int fixed = -1;
        for (int x = 0; x < 3 && fixed < 0; x++) {
            int is_open = 0;
            for (int m = 0; m < n_open; m++) is_open |= open_[m] == x;
            if (!is_open) fixed = x;
        }
        if (fixed >= 0) {
            vn = v[fixed] - e[fixed];
        } else {
            double mx = e[0], mn = e[0];
            for (int x = 1; x < 3; x++) {
                if (e[x] > mx) mx = e[x];
                if (e[x] < mn) mn = e[x];
            }
            vn = 0.5 * (vbus - mx - mn);
        }
        int worst = -1, worst_at = -1;
        double excess = 0.0;
        for (int m = 0; m < n_open; m++) {
            int o = open_[m];
            v[o] = vn + e[o];
            double out = v[o] > vbus ? v[o] - vbus : v[o] < 0.0 ? -v[o] : 0.0;
            if (out > excess) { worst = o; worst_at = m; excess = out; }
        }
        if (worst < 0) return n_open;
        v[worst] = v[worst] > vbus ? vbus : 0.0;
        for (int m = worst_at; m + 1 < n_open; m++) open_[m] = open_[m + 1];
        n_open--;
    }
    return n_open;
}

/* switching.leg_voltages: the legs' voltages; open_ gets the open legs (n returned) */
static int sw_leg_voltages(Core *s, const int gates[3], const double i[3], double vbus, double v[3], int open_[3])
{
    int n_open = 0;
    for (int x = 0; x < 3; x++) {
        int g = gates[x];
        v[x] = 0.0;
        if (g == SW_HIGH) v[x] = vbus;
        else if (g == SW_LOW) v[x] = 0.0;
        else if (i[x] > 0.0) v[x] = 0.0;
        else if (i[x] < 0.0) v[x] = vbus;
        else open_[n_open++] = x;
    }
    if (n_open >= 2) n_open = sw_float_open_legs(s, v, open_, n_open, vbus);
    if (n_open == 1) {
        int o = open_[0];
        double vo = sw_open_leg_voltage(s, v, o, vbus);
        if (vo > vbus || vo < 0.0) {
            v[o] = vo > vbus ? vbus : 0.0;
            n_open = 0;
        } else {
            v[o] = vo;
        }
    }
    return n_open;
}

static void sw_trig(Core *s, double th, double *c, double *sn);

/* switching.rk4_dq: one RK4 step with the alpha-beta voltage held, the averaged model's (friction,
 * rk4_dq), the angle wrapped; returns the input energy */
static double sw_rk4_dq(Core *s, double va, double vb, double h)
{
    double vmag = sqrt(va * va + vb * vb);
    double th0 = s->th, w0 = s->w_m, ij, fr;
    s->w_start = w0;
    friction(s, s->i_d, s->i_q, &w0, &ij, &fr);
    double y[5] = {s->i_d, s->i_q, w0, 0.0, 0.0};
    rk4_dq(s, y, atan2(vb, va) - th0, vmag, ij, fr, h);
    double w1 = y[2];
    if (fr != 0.0 && w0 != 0.0 && ((w1 > 0.0) != (w0 > 0.0))) {
        w1 = 0.0;
        s->stuck = 1;
    }
    s->i_d = y[0]; s->i_q = y[1]; s->w_m = w1;
    double th1 = th0 + y[3];
    double k = floor(th1 / TWO_PI);
    s->dturns = (long long)k;
    s->turns += (long long)k;
    s->th = th1 - k * TWO_PI;
    return 1.5 * vmag * y[4];
}

/* switching.interval: up to h seconds with these gates; returns the time used, adds the energy */
static double sw_interval(Core *s, const int gates[3], const double dead_until[3], double h, double t_off,
                          double *energy, int *have_edge, double *edge)
{
    double vbus = s->vbus_v, i[3] = {0.0, 0.0, 0.0}, v[3], i1[3] = {0.0, 0.0, 0.0};
    int open_[3];
    /* with every leg driven nothing here depends on the currents (switching.interval computes them
     * all the same; skipping them changes no result) */
    int any_dead = gates[0] == SW_DEAD || gates[1] == SW_DEAD || gates[2] == SW_DEAD;
    if (any_dead) sw_phase_currents(s, i);
    int n_open = sw_leg_voltages(s, gates, i, vbus, v, open_);
    double va = (2.0 * v[0] - v[1] - v[2]) / 3.0;
    double vb = (v[1] - v[2]) * INV_SQRT3;
    double sid = s->i_d, siq = s->i_q, sw = s->w_m, sth = s->th;
    long long sturns = s->turns;
    char sstuck = s->stuck;
    double th0 = s->th;
    double e = sw_rk4_dq(s, va, vb, h);
    if (any_dead) sw_phase_currents(s, i1);
    double fx[3] = {2.0, 2.0, 2.0};
    for (int x = 0; x < 3; x++) {
        if (gates[x] == SW_DEAD && i[x] != 0.0 && ((i1[x] > 0.0) != (i[x] > 0.0))) {
            double f = i[x] / (i[x] - i1[x]);
            if (t_off + f * h < dead_until[x]) fx[x] = f;
        }
    }
    double frac = fx[0];
    if (fx[1] < frac) frac = fx[1];
    if (fx[2] < frac) frac = fx[2];
    if (frac < 1.0) {
        s->i_d = sid; s->i_q = siq; s->w_m = sw; s->th = sth; s->turns = sturns; s->stuck = sstuck;
        h = h * frac;
        e = sw_rk4_dq(s, va, vb, h);
        sw_phase_currents(s, i1);
        for (int x = 0; x < 3; x++)
            if (fx[x] <= frac * (1.0 + 1e-9) + 1e-12) open_[n_open++] = x;
    }
    finish(s, th0, s->th - th0 + (double)s->dturns * TWO_PI, h, t_off, s->w_start, have_edge, edge);
    sw_project(s, i1, open_, n_open);
    if (s->oc > 0.0) sw_compare_now(s);
    *energy += e;
    return h;
}

/* switching.start_legs: at the period's start, a leg whose command the new duty changes switches
 * there (sx, te); each leg's next ideal edge into nt, nk */
static void sw_start_legs(double u0, double c, double f, const double duties[3], int sx[3], double te[3],
                          double nt[3], int nk[3])
{
    for (int x = 0; x < 3; x++) {
        int now = sw_ideal_high(u0, c, duties[x]);
        if (now != sx[x]) {
            sx[x] = now;
            te[x] = 0.0;
        }
        double ph = sw_next_edge(u0, c, duties[x], &nk[x]);
        nt[x] = (ph - u0) / f;
    }
}

/* switching.next_event */
static double sw_next_event(Core *s, double tau, const int gates[3], const int sx[3], const double dead_until[3],
                            const double nt[3], double ts, double t_end, double dt_s)
{
    double i[3] = {0.0, 0.0, 0.0};
    if (gates[0] == SW_DEAD || gates[1] == SW_DEAD || gates[2] == SW_DEAD) sw_phase_currents(s, i);
    double t_next = dt_s;
    for (int x = 0; x < 3; x++) {
        if (nt[x] < t_next) t_next = nt[x];
        if (tau < dead_until[x] && dead_until[x] < t_next && !(sx[x] ? i[x] < 0.0 : i[x] > 0.0))
            t_next = dead_until[x];
    }
    if (ts < t_next) t_next = ts;
    return t_next > t_end ? dt_s : t_next;
}

/* switching.step_pwm: one step of complementary PWM, edge by edge; the step's last hall edge in
 * *have_edge and *edge. 0, or -1 with an exception. */
static int sw_step_pwm(Core *s, double duty_a, double duty_b, double duty_c, double dt_s, int *have_edge,
                       double *edge)
{
    if (s->t_load_change <= s->t_s + 1e-12) {
        PyObject *r = PyObject_CallMethodNoArgs((PyObject *)s, str_update_load);
        if (r == NULL) return -1;
        Py_DECREF(r);
    }
    const double f = s->sw_f, td = s->sw_td, c = s->sw_c, u0 = s->sw_u;
    if (s->adc_live) {
        s->ia_s = s->i_a;
        s->ib_s = s->i_b;
    }
    double duties[3] = {duty_a, duty_b, duty_c};
    for (int x = 0; x < 3; x++) {
        double d = duties[x] > 0.0 ? duties[x] : 0.0;
        duties[x] = 1.0 < d ? 1.0 : d;
    }
    int sx[3] = {s->sw_s[0], s->sw_s[1], s->sw_s[2]}, nk[3], gates[3];
    double te[3] = {s->sw_e[0], s->sw_e[1], s->sw_e[2]}, nt[3];
    sw_start_legs(u0, c, f, duties, sx, te, nt, nk);
    double t_end = dt_s - SW_PHASE_EPS / f;
    double ts = (sw_next_sample(u0, s->sw_smp) - u0) / f;
    double h_max = dt_s / (double)s->substeps;
    *have_edge = 0;
    *edge = 0.0;
    s->last_mode = OUTPUT_PWM;
    s->da = duties[0]; s->db = duties[1]; s->dc = duties[2];
    double energy = 0.0, tau = 0.0, dead_until[3];
    for (;;) {
        for (int x = 0; x < 3; x++) {
            dead_until[x] = te[x] + td;
            gates[x] = tau >= dead_until[x] ? (sx[x] ? SW_HIGH : SW_LOW) : SW_DEAD;
        }
        double t_next = sw_next_event(s, tau, gates, sx, dead_until, nt, ts, t_end, dt_s);
        double h = t_next - tau;
        if (h > h_max) h = h_max;
        double used = sw_interval(s, gates, dead_until, h, tau, &energy, have_edge, edge);
        tau = used == t_next - tau ? t_next : tau + used;
        if (tau < t_next) continue;
        if (t_next >= dt_s) break;
        for (int x = 0; x < 3; x++) {
            if (nt[x] <= t_next) {
                sx[x] = nk[x];
                te[x] = t_next;
                double ph = sw_next_edge(u0 + t_next * f, c, duties[x], &nk[x]);
                nt[x] = (ph - u0) / f;
            }
        }
        if (ts <= t_next) {
            double now[3];
            sw_abc_now(s, now);
            s->ia_s = now[0];
            s->ib_s = now[1];
            ts = (sw_next_sample(u0 + t_next * f, s->sw_smp) - u0) / f;
        }
    }
    for (int x = 0; x < 3; x++) {
        s->sw_s[x] = sx[x];
        s->sw_e[x] = te[x] - dt_s;
    }
    s->sw_u = sw_advance_phase(u0, dt_s, f);
    s->adc_live = ts <= dt_s + SW_PHASE_EPS / f;
    s->t_s += dt_s;
    sense(s);
    s->i_bus = bus_average(s, energy, dt_s);
    return 0;
}
