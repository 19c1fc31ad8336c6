/*
 * phoid_ctrl.c -- the portable PD controller of a phoid rig (see phoid_ctrl.h for the contract).
 *
 * C99, no heap, no stdio, no libm. The arithmetic of the RUN phase follows phoid's model
 * (phoid.simulation.tracking.simulate_tracking) operation by operation, so that a plant
 * simulated exactly and driven by this step gives phoid's records to rounding:
 *   vhat = b0*x_n + b1*x_{n-1} (+ b2*x_{n-2}) - a1*vhat_{n-1},   u = K*(P*(r - x) - D*vhat).
 */
#include "phoid_ctrl.h"

#define PHOID_NO_LIMIT 1e300

/* finite: false for NaN and +/-inf (x - x is NaN for both); needs IEEE arithmetic, so do not
 * compile with -ffast-math. */
static int finite_(double x) { return (x - x) == 0.0; }

/* a quiet NaN without libm (volatile: not folded at compile time) */
static double nan_(void)
{
    volatile double z = 0.0;
    return z / z;
}

static double absd(double x) { return x < 0.0 ? -x : x; }

static void push_event(phoid_ctrl *c, unsigned long index, int code, double value)
{
    int slot;
    if (c->log_count == PHOID_EVENT_LOG) { /* full: drop the oldest */
        c->log_head = (c->log_head + 1) % PHOID_EVENT_LOG;
        c->log_count--;
        c->events_lost++;
    }
    slot = (c->log_head + c->log_count) % PHOID_EVENT_LOG;
    c->log[slot].index = index;
    c->log[slot].code = code;
    c->log[slot].value = value;
    c->log_count++;
}

static void clear_ring(phoid_ctrl *c)
{
    int i;
    for (i = 0; i <= PHOID_MAX_DELAY; i++) {
        c->ring[i] = 0.0;
    }
}

static void fault(phoid_ctrl *c, int code, double value)
{
    c->state = PHOID_FAULT;
    c->release_pending = 0;
    c->clipping = 0;
    clear_ring(c);
    push_event(c, c->n, code, value);
}

void phoid_config_default(phoid_config *cfg)
{
    if (!cfg) {
        return;
    }
    cfg->sample_time = 1e-3;
    cfg->P = 0.0;
    cfg->D = 0.0;
    cfg->gain = 1.0;
    cfg->command_gain = 1.0;
    cfg->velocity = PHOID_VEL_BACKWARD;
    cfg->filter_pole = 0.0;
    cfg->delay_samples = 0;
    cfg->hold_P = 0.0;
    cfg->hold_D = 0.0;
    cfg->x_start = 0.0;
    cfg->hold_samples = 0;
    cfg->run_samples = 1;
    cfg->x_min = -PHOID_NO_LIMIT;
    cfg->x_max = PHOID_NO_LIMIT;
    cfg->u_max = PHOID_NO_LIMIT;
    cfg->growth_limit = 0.0;
    cfg->stall_samples = 0;
    cfg->stall_epsilon = 0.0;
    cfg->has_force = 0;
}

/* 0 <= n <= PHOID_MAX_COUNT (compared as unsigned long: never a comparison that is always
 * false, and so no warning, where a long has 32 bits) */
static int count_ok(long n)
{
    return n >= 0 && (unsigned long)n <= (unsigned long)PHOID_MAX_COUNT;
}

static int check_config(const phoid_config *g)
{
    if (!finite_(g->sample_time) || !(g->sample_time >= PHOID_MIN_SAMPLE_TIME)) {
        return PHOID_E_SAMPLE_TIME;
    }
    if (g->velocity != PHOID_VEL_BACKWARD && g->velocity != PHOID_VEL_CENTRAL
        && g->velocity != PHOID_VEL_FILTERED) {
        return PHOID_E_VELOCITY;
    }
    if (g->velocity == PHOID_VEL_FILTERED && !(g->filter_pole >= 0.0 && g->filter_pole < 1.0)) {
        return PHOID_E_FILTER_POLE;
    }
    if (g->delay_samples < 0 || g->delay_samples > PHOID_MAX_DELAY) {
        return PHOID_E_DELAY;
    }
    if (!finite_(g->P) || !finite_(g->D) || !finite_(g->gain) || !finite_(g->hold_P)
        || !finite_(g->hold_D)) {
        return PHOID_E_GAIN;
    }
    if (!finite_(g->command_gain) || !(g->command_gain > 0.0)) {
        return PHOID_E_COMMAND_GAIN;
    }
    if (!(g->x_min < g->x_max)) {
        return PHOID_E_LIMITS;
    }
    if (!finite_(g->x_start) || !(g->x_start >= g->x_min && g->x_start <= g->x_max)) {
        return PHOID_E_START;
    }
    if (!(g->u_max > 0.0)) {
        return PHOID_E_COMMAND_LIMIT;
    }
    if (!(g->growth_limit == 0.0 || (finite_(g->growth_limit) && g->growth_limit >= 1.0))) {
        return PHOID_E_GROWTH;
    }
    if (!count_ok(g->stall_samples) || !finite_(g->stall_epsilon)
        || !(g->stall_epsilon >= 0.0)) {
        return PHOID_E_STALL;
    }
    if (!count_ok(g->hold_samples) || !count_ok(g->run_samples) || g->run_samples < 1) {
        return PHOID_E_SAMPLES;
    }
    if (g->has_force != 0 && g->has_force != 1) {
        return PHOID_E_HAS_FORCE;
    }
    return PHOID_OK;
}

int phoid_init(phoid_ctrl *c, const phoid_config *cfg)
{
    int err;
    double T;
    if (!c || !cfg) {
        return PHOID_E_NULL;
    }
    err = check_config(cfg);
    if (err != PHOID_OK) {
        return err;
    }
    c->cfg = *cfg;
    T = cfg->sample_time;
    /* the coefficients as phoid.dynamics.velocity.VelocityFilter defines them */
    if (cfg->velocity == PHOID_VEL_BACKWARD) {
        c->c0 = 1.0 / T;
        c->c1 = 0.0;
    } else if (cfg->velocity == PHOID_VEL_CENTRAL) {
        c->c0 = 1.0 / (2.0 * T);
        c->c1 = 0.0;
    } else {
        c->c0 = (1.0 - cfg->filter_pole) / T;
        c->c1 = cfg->filter_pole;
    }
    c->state = PHOID_IDLE;
    c->n = 0;
    c->x1 = c->x2 = 0.0;
    c->vhat = 0.0;
    c->history = 0;
    clear_ring(c);
    c->head = 0;
    c->held = c->ran = c->still = 0;
    c->release_pending = 0;
    c->amplitude = 0.0;
    c->clipping = 0;
    c->clips = 0;
    c->force = nan_();
    c->log_head = c->log_count = 0;
    c->events_lost = 0;
    return PHOID_OK;
}

/* vhat_n from x_n and the history, in simulate_tracking's order of operations */
static double estimate(phoid_ctrl *c, double x)
{
    double acc;
    if (c->history == 0) { /* the first sample: at rest before it, x_{-1} = x_{-2} = x_0 */
        c->x1 = c->x2 = x;
    }
    if (c->cfg.velocity == PHOID_VEL_CENTRAL) {
        acc = c->c0 * x;
        acc += 0.0 * c->x1;
        acc += (-c->c0) * c->x2;
    } else {
        acc = c->c0 * x;
        acc += (-c->c0) * c->x1;
        if (c->cfg.velocity == PHOID_VEL_FILTERED) {
            acc -= (-c->c1) * c->vhat;
        }
    }
    c->x2 = c->x1;
    c->x1 = x;
    c->history = 1;
    c->vhat = acc;
    return acc;
}

static void enter_run(phoid_ctrl *c, double x, double r)
{
    double a = absd(c->cfg.x_start - r);
    double b = absd(x - r);
    c->state = PHOID_RUN;
    c->release_pending = 0;
    c->ran = 0;
    c->still = 0;
    c->amplitude = a > b ? a : b;
    push_event(c, c->n, PHOID_EV_RELEASE, x);
}

double phoid_step(phoid_ctrl *c, double x, double r)
{
    return phoid_step_force(c, x, r, nan_());
}

double phoid_step_force(phoid_ctrl *c, double x, double r, double force)
{
    const phoid_config *g;
    double vhat, u, out;
    int d, clipped, bad_x, bad_f;
    if (!c) {
        return 0.0;
    }
    g = &c->cfg;
    c->force = force;
    bad_x = !finite_(x) || !finite_(r);
    bad_f = g->has_force && !finite_(force);
    if (bad_x || bad_f) {
        if (c->state != PHOID_FAULT) {
            fault(c, PHOID_EV_FAULT_INPUT, bad_x ? 0.0 : 1.0);
        }
        c->n++;
        return 0.0;
    }
    vhat = estimate(c, x);

    if (c->state == PHOID_HOLD
        && (c->release_pending || (g->hold_samples > 0 && c->held >= g->hold_samples))) {
        enter_run(c, x, r);
    }

    /* safety */
    if (c->state == PHOID_HOLD || c->state == PHOID_RUN) {
        if (x < g->x_min || x > g->x_max) {
            fault(c, PHOID_EV_FAULT_POSITION, x);
        }
    }
    if (c->state == PHOID_RUN) {
        double dev = absd(x - r);
        double step = absd(x - c->x2); /* x2 is x_{n-1} after estimate() */
        if (g->growth_limit > 0.0 && dev > g->growth_limit * c->amplitude) {
            fault(c, PHOID_EV_FAULT_GROWTH, dev);
        } else if (g->stall_samples > 0) {
            c->still = step < g->stall_epsilon ? c->still + 1 : 0;
            if (c->still >= g->stall_samples) {
                fault(c, PHOID_EV_FAULT_STALL, step);
            }
        }
    }

    /* the command */
    if (c->state == PHOID_HOLD) {
        u = g->gain * (g->hold_P * (g->x_start - x) - g->hold_D * vhat);
    } else if (c->state == PHOID_RUN) {
        u = g->gain * (g->P * (r - x) - g->D * vhat);
    } else {
        u = 0.0;
    }
    if (!finite_(u)) { /* overflow (inf) or inf - inf (NaN): never send it on */
        fault(c, PHOID_EV_FAULT_COMMAND, x);
        u = 0.0;
    }
    clipped = 0;
    if (u > g->u_max) {
        clipped = 1;
    } else if (u < -g->u_max) {
        clipped = -1;
    }
    if (clipped) {
        c->clips++;
        if (!c->clipping) {
            push_event(c, c->n, PHOID_EV_CLIP, u);
        }
        u = clipped > 0 ? g->u_max : -g->u_max;
    }
    c->clipping = clipped != 0;

    /* the delay ring: store u_n, return u_{n-d} */
    d = g->delay_samples;
    c->ring[c->head] = u;
    out = c->ring[(c->head + PHOID_MAX_DELAY + 1 - d) % (PHOID_MAX_DELAY + 1)];
    c->head = (c->head + 1) % (PHOID_MAX_DELAY + 1);
    if (c->state == PHOID_FAULT || c->state == PHOID_DONE) {
        out = 0.0;
    }

    if (c->state == PHOID_HOLD) {
        c->held++;
    } else if (c->state == PHOID_RUN) {
        c->ran++;
        if (c->ran >= g->run_samples) {
            c->state = PHOID_DONE;
            clear_ring(c);
            push_event(c, c->n + 1, PHOID_EV_DONE, (double)c->ran);
        }
    }
    c->n++;
    return out;
}

int phoid_start(phoid_ctrl *c)
{
    if (!c) {
        return PHOID_E_NULL;
    }
    if (c->state != PHOID_IDLE && c->state != PHOID_DONE) {
        return PHOID_E_STATE;
    }
    c->state = PHOID_HOLD;
    c->held = 0;
    c->ran = 0;
    c->release_pending = 0;
    push_event(c, c->n, PHOID_EV_START, c->cfg.x_start);
    return PHOID_OK;
}

int phoid_release(phoid_ctrl *c)
{
    if (!c) {
        return PHOID_E_NULL;
    }
    if (c->state != PHOID_HOLD) {
        return PHOID_E_STATE;
    }
    c->release_pending = 1;
    return PHOID_OK;
}

void phoid_abort(phoid_ctrl *c, double reason)
{
    if (c && c->state != PHOID_FAULT) {
        fault(c, PHOID_EV_FAULT_HOST, reason);
    }
}

void phoid_clear_fault(phoid_ctrl *c)
{
    if (c && c->state == PHOID_FAULT) {
        if (!finite_(c->vhat)) { /* an overflowed estimate: start again at rest */
            c->history = 0;
            c->vhat = 0.0;
        }
        c->state = PHOID_IDLE;
        c->held = c->ran = c->still = 0;
        push_event(c, c->n, PHOID_EV_CLEAR, 0.0);
    }
}

int phoid_state(const phoid_ctrl *c) { return c ? c->state : PHOID_FAULT; }

unsigned long phoid_sample_index(const phoid_ctrl *c) { return c ? c->n : 0UL; }

double phoid_velocity(const phoid_ctrl *c) { return c ? c->vhat : 0.0; }

double phoid_force(const phoid_ctrl *c) { return c ? c->force : nan_(); }

unsigned long phoid_clips(const phoid_ctrl *c) { return c ? c->clips : 0UL; }

unsigned long phoid_events_lost(const phoid_ctrl *c) { return c ? c->events_lost : 0UL; }

int phoid_pop_event(phoid_ctrl *c, phoid_event *e)
{
    if (!c || !e || c->log_count == 0) {
        return 0;
    }
    *e = c->log[c->log_head];
    c->log_head = (c->log_head + 1) % PHOID_EVENT_LOG;
    c->log_count--;
    return 1;
}

const char *phoid_event_name(int code)
{
    static const char *const names[] = {
        "unknown", "start", "release", "done", "clip", "fault-position", "fault-growth",
        "fault-stall", "fault-input", "fault-host", "clear", "fault-command"
    };
    if (code < 1 || code > PHOID_EV_FAULT_COMMAND) {
        return names[0];
    }
    return names[code];
}

const char *phoid_state_name(int state)
{
    static const char *const names[] = {"idle", "hold", "run", "done", "fault"};
    if (state < PHOID_IDLE || state > PHOID_FAULT) {
        return "unknown";
    }
    return names[state];
}

unsigned long phoid_config_size(void) { return (unsigned long)sizeof(phoid_config); }

unsigned long phoid_ctrl_size(void) { return (unsigned long)sizeof(phoid_ctrl); }
