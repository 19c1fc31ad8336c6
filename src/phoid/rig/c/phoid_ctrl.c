/*
 * phoid_ctrl.c -- the portable PD controller of a phoid rig (see phoid_ctrl.h for the contract).
 *
 * C99, no heap, no stdio, no libm. The arithmetic of the RUN phase follows phoid's model
 * (phoid.simulation.tracking.simulate_tracking) operation by operation, so that a plant
 * simulated exactly and driven by this step gives phoid's records to rounding:
 *   vhat = b0*x_n + b1*x_{n-1} (+ b2*x_{n-2}) - a1*vhat_{n-1},   u = K*(P*(r - x) - D*vhat).
 *
 * For microcontrollers: every real is phoid_real and every constant PHOID_R(...), so a float
 * build does no double arithmetic; no division and no % on the step path (power-of-two rings,
 * unsigned masks); no 0/0 (the NaN is a bit pattern); finiteness is read from the bits (it
 * holds under -ffast-math); state transitions are O(1) (the delay ring is never wiped: the
 * slots not written since the last clear read as 0).
 */
#include "phoid_ctrl.h"

#include <stdint.h>

#define ZERO PHOID_R(0.0)
#define ONE PHOID_R(1.0)
#define RING_MASK ((unsigned)PHOID_RING_SIZE - 1u)
#define LOG_MASK ((unsigned)PHOID_EVENT_LOG - 1u)

/* unsigned indices: the masks need the sizes to fit an unsigned int (16 bits at least) */
#if PHOID_RING_SIZE > 32768 || PHOID_EVENT_LOG > 32768
#error "PHOID_RING_SIZE and PHOID_EVENT_LOG must be at most 32768"
#endif

/* the IEEE layout of phoid_real: binary32 (float; AVR's double) or binary64 */
#if PHOID_REAL_MAX_EXP == 128
typedef uint32_t real_bits_t;
#define EXP_BITS ((real_bits_t)0x7f800000UL)
#define ABS_BITS ((real_bits_t)0x7fffffffUL)
#define QNAN_BITS ((real_bits_t)0x7fc00000UL)
#elif PHOID_REAL_MAX_EXP == 1024
typedef uint64_t real_bits_t;
#define EXP_BITS ((real_bits_t)0x7ff0000000000000ULL)
#define ABS_BITS ((real_bits_t)0x7fffffffffffffffULL)
#define QNAN_BITS ((real_bits_t)0x7ff8000000000000ULL)
#else
#error "phoid_real must be an IEEE binary32 or binary64 type"
#endif

/* the bits and the real share their storage (C99 TC3 6.5.2.3: reading the other member
 * reinterprets the bytes) */
typedef union real_bits {
    real_bits_t b;
    phoid_real r;
} real_bits;

typedef char phoid_check_real_bits_[sizeof(real_bits_t) == sizeof(phoid_real) ? 1 : -1];

/* a quiet NaN from its bits (no 0/0, nothing computed) */
static const real_bits nan_bits = {QNAN_BITS};

/* finite: false for NaN and +/-inf (the exponent bits all ones). An integer test on the bits,
 * so -ffast-math (-ffinite-math-only) cannot fold it away. */
static int finite_(phoid_real x)
{
    real_bits v;
    v.r = x;
    return (v.b & EXP_BITS) != EXP_BITS;
}

/* NaN: the exponent bits all ones and a fraction (a test on the bits, as finite_). The
 * configuration's checks call it wherever a comparison alone would let a NaN through: under
 * -ffast-math the compiler may rewrite !(a > b) as a <= b, which a NaN passes. */
static int nan_(phoid_real x)
{
    real_bits v;
    v.r = x;
    return (v.b & ABS_BITS) > EXP_BITS;
}

static phoid_real absr(phoid_real x) { return x < ZERO ? -x : x; }

static void push_event(phoid_ctrl *c, unsigned long long index, int code, phoid_real value)
{
    phoid_event *e;
    if (c->log_count == (unsigned)PHOID_EVENT_LOG) { /* full: drop the oldest */
        c->log_head = (c->log_head + 1u) & LOG_MASK;
        c->log_count--;
        c->events_lost++;
    }
    e = &c->log[(c->log_head + c->log_count) & LOG_MASK];
    e->index = index;
    e->code = code;
    e->value = value;
    c->log_count++;
}

/* the delay ring holds no command from now on (O(1): see phoid_ctrl.filled) */
static void clear_ring(phoid_ctrl *c) { c->filled = 0u; }

static void fault(phoid_ctrl *c, int code, phoid_real value)
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
    cfg->sample_time = PHOID_R(1e-3);
    cfg->P = ZERO;
    cfg->D = ZERO;
    cfg->gain = ONE;
    cfg->command_gain = ONE;
    cfg->velocity = PHOID_VEL_BACKWARD;
    cfg->filter_pole = ZERO;
    cfg->delay_samples = 0;
    cfg->hold_P = ZERO;
    cfg->hold_D = ZERO;
    cfg->x_start = ZERO;
    cfg->hold_samples = 0;
    cfg->run_samples = 1;
    cfg->x_min = -PHOID_NO_LIMIT;
    cfg->x_max = PHOID_NO_LIMIT;
    cfg->u_max = PHOID_NO_LIMIT;
    cfg->growth_limit = ZERO;
    cfg->stall_samples = 0;
    cfg->stall_epsilon = ZERO;
    cfg->has_force = 0;
}

/* 0 <= n <= PHOID_MAX_COUNT (compared as unsigned long: never a comparison that is always
 * false, and so no warning, where a long has 32 bits) */
static int count_ok(long n)
{
    return n >= 0 && (unsigned long)n <= (unsigned long)PHOID_MAX_COUNT;
}

/* x is +0 or -0 (false for NaN), without == on reals (-Wfloat-equal) */
static int is_zero(phoid_real x) { return x >= ZERO && x <= ZERO; }

static int check_config(const phoid_config *g)
{
    if (!finite_(g->sample_time) || !(g->sample_time >= PHOID_MIN_SAMPLE_TIME)) {
        return PHOID_E_SAMPLE_TIME;
    }
    if (g->velocity != PHOID_VEL_BACKWARD && g->velocity != PHOID_VEL_CENTRAL
        && g->velocity != PHOID_VEL_FILTERED) {
        return PHOID_E_VELOCITY;
    }
    if (g->velocity == PHOID_VEL_FILTERED
        && (nan_(g->filter_pole) || !(g->filter_pole >= ZERO && g->filter_pole < ONE))) {
        return PHOID_E_FILTER_POLE;
    }
    if (g->delay_samples < 0 || g->delay_samples > PHOID_MAX_DELAY) {
        return PHOID_E_DELAY;
    }
    if (!finite_(g->P) || !finite_(g->D) || !finite_(g->gain) || !finite_(g->hold_P)
        || !finite_(g->hold_D)) {
        return PHOID_E_GAIN;
    }
    if (!finite_(g->command_gain) || !(g->command_gain > ZERO)) {
        return PHOID_E_COMMAND_GAIN;
    }
    if (nan_(g->x_min) || nan_(g->x_max) || !(g->x_min < g->x_max)) {
        return PHOID_E_LIMITS;
    }
    if (!finite_(g->x_start) || !(g->x_start >= g->x_min && g->x_start <= g->x_max)) {
        return PHOID_E_START;
    }
    if (nan_(g->u_max) || !(g->u_max > ZERO)) {
        return PHOID_E_COMMAND_LIMIT;
    }
    if (!finite_(g->growth_limit) || !(is_zero(g->growth_limit) || g->growth_limit >= ONE)) {
        return PHOID_E_GROWTH;
    }
    if (!count_ok(g->stall_samples) || !finite_(g->stall_epsilon)
        || !(g->stall_epsilon >= ZERO)) {
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
    phoid_real T;
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
        c->c0 = ONE / T;
        c->c1 = ZERO;
    } else if (cfg->velocity == PHOID_VEL_CENTRAL) {
        c->c0 = ONE / (PHOID_R(2.0) * T);
        c->c1 = ZERO;
    } else {
        c->c0 = (ONE - cfg->filter_pole) / T;
        c->c1 = cfg->filter_pole;
    }
    c->state = PHOID_IDLE;
    c->n = 0u;
    c->x1 = c->x2 = ZERO;
    c->vhat = ZERO;
    c->history = 0;
    c->head = 0u;
    clear_ring(c);
    c->held = c->ran = c->still = 0;
    c->release_pending = 0;
    c->amplitude = ZERO;
    c->growth_bound = ZERO;
    c->clipping = 0;
    c->clips = 0u;
    c->force = nan_bits.r;
    c->log_head = c->log_count = 0u;
    c->events_lost = 0u;
    return PHOID_OK;
}

/* vhat_n from x_n and the history, in simulate_tracking's order of operations (do not
 * simplify: the host double build is bit-identical to phoid's model) */
static phoid_real estimate(phoid_ctrl *c, phoid_real x)
{
    phoid_real acc;
    if (c->history == 0) { /* the first sample: at rest before it, x_{-1} = x_{-2} = x_0 */
        c->x1 = c->x2 = x;
    }
    if (c->cfg.velocity == PHOID_VEL_CENTRAL) {
        acc = c->c0 * x;
        acc += ZERO * c->x1;
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

static void enter_run(phoid_ctrl *c, phoid_real x, phoid_real r)
{
    phoid_real a = absr(c->cfg.x_start - r);
    phoid_real b = absr(x - r);
    c->state = PHOID_RUN;
    c->release_pending = 0;
    c->ran = 0;
    c->still = 0;
    c->amplitude = a > b ? a : b;
    c->growth_bound = c->cfg.growth_limit * c->amplitude;
    push_event(c, c->n, PHOID_EV_RELEASE, x);
}

/* RUN's growth and stall checks (x within the limits): 1 when one faulted */
static int run_checks(phoid_ctrl *c, const phoid_config *g, phoid_real x, phoid_real r)
{
    if (g->growth_limit > ZERO) {
        phoid_real dev = absr(x - r);
        if (dev > c->growth_bound) {
            fault(c, PHOID_EV_FAULT_GROWTH, dev);
            return 1;
        }
    }
    if (g->stall_samples > 0) {
        phoid_real step = absr(x - c->x2); /* x2 is x_{n-1} after estimate() */
        c->still = step < g->stall_epsilon ? c->still + 1 : 0;
        if (c->still >= g->stall_samples) {
            fault(c, PHOID_EV_FAULT_STALL, step);
            return 1;
        }
    }
    return 0;
}

phoid_real phoid_step(phoid_ctrl *c, phoid_real x, phoid_real r)
{
    return phoid_step_force(c, x, r, nan_bits.r);
}

phoid_real phoid_step_force(phoid_ctrl *c, phoid_real x, phoid_real r, phoid_real force)
{
    const phoid_config *g;
    phoid_real vhat, u, out;
    unsigned d;
    int state, clipped;
    if (!c) {
        return ZERO;
    }
    g = &c->cfg;
    c->force = force;
    if (!finite_(x) || !finite_(r) || (g->has_force && !finite_(force))) {
        if (c->state != PHOID_FAULT) {
            fault(c, PHOID_EV_FAULT_INPUT, (finite_(x) && finite_(r)) ? ONE : ZERO);
        }
        c->n++;
        return ZERO;
    }
    vhat = estimate(c, x);

    state = c->state;
    if (state == PHOID_HOLD
        && (c->release_pending || (g->hold_samples > 0 && c->held >= g->hold_samples))) {
        enter_run(c, x, r);
        state = PHOID_RUN;
    }

    /* safety, then the command (0 outside HOLD and RUN, and from a fault on) */
    u = ZERO;
    clipped = 0;
    if (state == PHOID_HOLD || state == PHOID_RUN) {
        if (x < g->x_min || x > g->x_max) {
            fault(c, PHOID_EV_FAULT_POSITION, x);
        } else if (state == PHOID_HOLD || !run_checks(c, g, x, r)) {
            phoid_real kp, kd, e;
            if (state == PHOID_RUN) {
                kp = g->P;
                kd = g->D;
                e = r - x;
            } else {
                kp = g->hold_P;
                kd = g->hold_D;
                e = g->x_start - x;
            }
            u = g->gain * (kp * e - kd * vhat);
            if (!finite_(u)) { /* overflow (inf) or inf - inf (NaN): never send it on */
                fault(c, PHOID_EV_FAULT_COMMAND, x);
                u = ZERO;
            } else if (u > g->u_max) {
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
        }
    }
    c->clipping = clipped;

    /* the delay ring: store u_n, return u_{n-d} (0 while that slot is not written since the
     * last clear) */
    d = (unsigned)g->delay_samples;
    c->ring[c->head] = u;
    if (c->filled < d) {
        c->filled++;
        out = ZERO;
    } else {
        out = c->ring[(c->head - d) & RING_MASK];
    }
    c->head = (c->head + 1u) & RING_MASK;

    state = c->state;
    if (state == PHOID_HOLD) {
        c->held++;
    } else if (state == PHOID_RUN) {
        c->ran++;
        if (c->ran >= g->run_samples) {
            c->state = PHOID_DONE;
            clear_ring(c);
            push_event(c, c->n + 1u, PHOID_EV_DONE, (phoid_real)c->ran);
        } /* (the last RUN sample's delayed command still goes out) */
    } else if (state != PHOID_IDLE) { /* DONE, FAULT (this sample's included): 0 */
        out = ZERO;
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

void phoid_abort(phoid_ctrl *c, phoid_real reason)
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
            c->vhat = ZERO;
        }
        c->state = PHOID_IDLE;
        c->held = c->ran = c->still = 0;
        push_event(c, c->n, PHOID_EV_CLEAR, ZERO);
    }
}

int phoid_state(const phoid_ctrl *c) { return c ? c->state : PHOID_FAULT; }

unsigned long long phoid_sample_index(const phoid_ctrl *c) { return c ? c->n : 0u; }

int phoid_set_sample_index(phoid_ctrl *c, unsigned long long n)
{
    if (!c) {
        return PHOID_E_NULL;
    }
    if (c->state != PHOID_IDLE) {
        return PHOID_E_STATE;
    }
    c->n = n;
    return PHOID_OK;
}

phoid_real phoid_velocity(const phoid_ctrl *c) { return c ? c->vhat : ZERO; }

phoid_real phoid_force(const phoid_ctrl *c) { return c ? c->force : nan_bits.r; }

unsigned long phoid_clips(const phoid_ctrl *c) { return c ? c->clips : 0UL; }

unsigned long phoid_events_lost(const phoid_ctrl *c) { return c ? c->events_lost : 0UL; }

int phoid_pop_event(phoid_ctrl *c, phoid_event *e)
{
    if (!c || !e || c->log_count == 0u) {
        return 0;
    }
    *e = c->log[c->log_head];
    c->log_head = (c->log_head + 1u) & LOG_MASK;
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

int phoid_real_size(void) { return (int)sizeof(phoid_real); }
