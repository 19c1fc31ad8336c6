/*
 * phoid_ctrl.h -- the portable PD controller of a phoid rig (C99, no heap, no OS, no libm).
 *
 * One fixed-rate step function closes the PD position loop that phoid models
 * (phoid.dynamics.controller.SampledController with a whole-sample delay) and runs one
 * parametric-harmonic-oscillation run: hold the start position with a stiff loop, release,
 * run the run's gains for a fixed number of samples, stop. Safety checks run inside the step.
 *
 * The loop, per sample n (period T, called once per sample at the fixed rate):
 *   1. x_n = the measured position (m); r_n = the reference (m);
 *   2. the velocity estimate vhat_n (m/s), one of
 *        PHOID_VEL_BACKWARD  vhat_n = (x_n - x_{n-1})/T,
 *        PHOID_VEL_CENTRAL   vhat_n = (x_n - x_{n-2})/(2T),
 *        PHOID_VEL_FILTERED  vhat_n = a*vhat_{n-1} + (1 - a)(x_n - x_{n-1})/T, a = exp(-w_c T);
 *   3. the command u_n = K*(P*(r_n - x_n) - D*vhat_n) (command units; in HOLD
 *      u_n = K*(P_hold*(x_start - x_n) - D_hold*vhat_n)), clipped to +/-u_max;
 *   (x_n may come with a measured force f_n, N: phoid_step_force stores and checks it, the
 *    loop does not use it.)
 *   4. the step returns u_{n-d} (d = delay_samples), to be applied at once and held until the
 *      next sample (zero-order hold); the plant sees the force G*u_{n-d}.
 *
 * Sign convention: positive P pulls x towards r (it stiffens the loop), positive D damps.
 * With K = G = 1, P is in N/m and D in N*s/m.
 *
 * State machine: IDLE --phoid_start--> HOLD --hold_samples or phoid_release--> RUN
 *   --run_samples--> DONE;  any safety trip --> FAULT (command 0, latched until
 *   phoid_clear_fault, which returns to IDLE). phoid_start is accepted in IDLE and DONE.
 * Every state change and fault is pushed into a fixed-size event log with its sample index.
 * A command that is not finite (gains so large that the product overflows) faults the
 * controller (PHOID_EV_FAULT_COMMAND) instead of reaching the amplifier.
 *
 * The real type: phoid_real is PHOID_REAL, `double` by default; build with -DPHOID_REAL=float
 * for a single-precision FPU (Cortex-M4F). Every real of the API and of the structs has this
 * type; every constant of the step is of this type too, so a float build does no double
 * arithmetic. Bit-identity with phoid's model (and between targets) needs -std=c99
 * -ffp-contract=off (no fused multiply-adds); the finiteness checks read the bits, so they also
 * hold under -ffast-math (bit-identity then does not).
 */
#ifndef PHOID_CTRL_H
#define PHOID_CTRL_H

#include <float.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ---- the real type ---------------------------------------------------------------------- */

/** The controller's real type: `double` (default) or `float` (-DPHOID_REAL=float). */
#ifndef PHOID_REAL
#define PHOID_REAL double
#endif

/* PHOID_REAL_IS_FLOAT: 1 for float, 0 for double, found by pasting the type's name onto a
 * prefix (PHOID_REAL_KIND_float / PHOID_REAL_KIND_double); any other type is an error. */
#define PHOID_PASTE2_(a, b) a##b
#define PHOID_PASTE_(a, b) PHOID_PASTE2_(a, b)
#define PHOID_REAL_KIND_float 1
#define PHOID_REAL_KIND_double 2
#if PHOID_PASTE_(PHOID_REAL_KIND_, PHOID_REAL) == 1
#define PHOID_REAL_IS_FLOAT 1
#define PHOID_REAL_MAX FLT_MAX            /**< the largest finite phoid_real */
#define PHOID_REAL_MAX_EXP FLT_MAX_EXP    /**< 128: binary32; 1024: binary64 */
#define PHOID_REAL_MAX_10_EXP FLT_MAX_10_EXP
#elif PHOID_PASTE_(PHOID_REAL_KIND_, PHOID_REAL) == 2
#define PHOID_REAL_IS_FLOAT 0
#define PHOID_REAL_MAX DBL_MAX
#define PHOID_REAL_MAX_EXP DBL_MAX_EXP    /* 128 where a double has 32 bits (AVR) */
#define PHOID_REAL_MAX_10_EXP DBL_MAX_10_EXP
#else
#error "PHOID_REAL must be float or double"
#endif

typedef PHOID_REAL phoid_real;

/** A constant of the real type (a cast of a literal: folded at compile time). */
#define PHOID_R(v) ((phoid_real)(v))

/** The "no limit" of the defaults (x_min = -PHOID_NO_LIMIT, x_max = u_max = PHOID_NO_LIMIT):
 * 1e300 where phoid_real holds it (a 64-bit double: as before), else the largest finite
 * phoid_real (float; AVR's 32-bit double). Every finite position and command is inside. */
#if PHOID_REAL_MAX_10_EXP >= 300
#define PHOID_NO_LIMIT PHOID_R(1e300)
#else
#define PHOID_NO_LIMIT PHOID_R(PHOID_REAL_MAX)
#endif

/* ---- sizes ------------------------------------------------------------------------------ */

/** Largest command delay, in samples (at most PHOID_RING_SIZE - 1). */
#ifndef PHOID_MAX_DELAY
#define PHOID_MAX_DELAY 64
#endif

/** Entries of the delay ring: a power of two > PHOID_MAX_DELAY (indices are masked). */
#ifndef PHOID_RING_SIZE
#define PHOID_RING_SIZE 128
#endif

/** Entries of the event log ring, a power of two (the oldest is overwritten when full). */
#ifndef PHOID_EVENT_LOG
#define PHOID_EVENT_LOG 32
#endif

#if PHOID_MAX_DELAY < 0
#error "PHOID_MAX_DELAY must be >= 0"
#endif
#if PHOID_RING_SIZE < 1 || (PHOID_RING_SIZE & (PHOID_RING_SIZE - 1)) != 0
#error "PHOID_RING_SIZE must be a power of two"
#endif
#if PHOID_RING_SIZE <= PHOID_MAX_DELAY
#error "PHOID_RING_SIZE must be > PHOID_MAX_DELAY"
#endif
#if PHOID_EVENT_LOG < 1 || (PHOID_EVENT_LOG & (PHOID_EVENT_LOG - 1)) != 0
#error "PHOID_EVENT_LOG must be a power of two"
#endif

/** Largest sample count (hold_samples, run_samples, stall_samples): 2^31 - 1, what a 32-bit
 * long holds, so that a configuration means the same on every target. */
#define PHOID_MAX_COUNT 2147483647L

/** Shortest sample time, s (1 ns): 1/sample_time must be a finite, sensible rate. */
#define PHOID_MIN_SAMPLE_TIME PHOID_R(1e-9)

/** Velocity estimators (phoid's presets "backward-difference", "central-difference",
 * "filtered"). */
enum phoid_velocity {
    PHOID_VEL_BACKWARD = 0,
    PHOID_VEL_CENTRAL = 1,
    PHOID_VEL_FILTERED = 2
};

/** States of the run state machine. */
enum phoid_state {
    PHOID_IDLE = 0,  /**< command 0; the estimator follows x */
    PHOID_HOLD = 1,  /**< the hold loop pulls x to x_start */
    PHOID_RUN = 2,   /**< the run's gains, from the release on */
    PHOID_DONE = 3,  /**< run_samples recorded; command 0 */
    PHOID_FAULT = 4  /**< a safety trip; command 0 until phoid_clear_fault */
};

/** Event codes of the log (phoid_event_name gives their names). */
enum phoid_event_code {
    PHOID_EV_START = 1,           /**< IDLE/DONE -> HOLD; value: x_start (m) */
    PHOID_EV_RELEASE = 2,         /**< HOLD -> RUN; value: x at the release (m) */
    PHOID_EV_DONE = 3,            /**< RUN -> DONE; value: samples run (= run_samples),
                                       as a phoid_real: exact up to 2^24 = 16777216 in a
                                       32-bit real (float, AVR's double), rounded beyond;
                                       the exact count is run_samples */
    PHOID_EV_CLIP = 4,            /**< a clipping episode begins; value: the unclipped command */
    PHOID_EV_FAULT_POSITION = 5,  /**< x outside [x_min, x_max]; value: x (m) */
    PHOID_EV_FAULT_GROWTH = 6,    /**< |x - r| > growth_limit*A; value: |x - r| (m) */
    PHOID_EV_FAULT_STALL = 7,     /**< no motion for stall_samples; value: |x_n - x_{n-1}| (m) */
    PHOID_EV_FAULT_INPUT = 8,     /**< x or r not finite (value 0), or the measured force
                                       not finite with has_force = 1 (value 1) */
    PHOID_EV_FAULT_HOST = 9,      /**< phoid_abort; value: the host's reason */
    PHOID_EV_CLEAR = 10,          /**< FAULT -> IDLE (phoid_clear_fault); value: 0 */
    PHOID_EV_FAULT_COMMAND = 11   /**< the command computed is not finite (the gains times the
                                       state overflow phoid_real); value: x (m) */
};

/** Error codes of phoid_init (0 is success); each names the field that is wrong. */
enum phoid_error {
    PHOID_OK = 0,
    PHOID_E_NULL = -1,           /**< a NULL pointer */
    PHOID_E_SAMPLE_TIME = -2,    /**< sample_time not finite and >= PHOID_MIN_SAMPLE_TIME */
    PHOID_E_VELOCITY = -3,       /**< unknown velocity estimator */
    PHOID_E_FILTER_POLE = -4,    /**< filter_pole not in [0, 1) (filtered estimator) */
    PHOID_E_DELAY = -5,          /**< delay_samples < 0 or > PHOID_MAX_DELAY */
    PHOID_E_GAIN = -6,           /**< P, D, gain, hold_P or hold_D not finite */
    PHOID_E_COMMAND_GAIN = -7,   /**< command_gain not finite and > 0 */
    PHOID_E_LIMITS = -8,         /**< x_min < x_max does not hold (or a NaN) */
    PHOID_E_START = -9,          /**< x_start not finite or outside [x_min, x_max] */
    PHOID_E_COMMAND_LIMIT = -10, /**< u_max not > 0 (or a NaN) */
    PHOID_E_GROWTH = -11,        /**< growth_limit neither 0 (off) nor finite and >= 1 */
    PHOID_E_STALL = -12,         /**< stall_samples not in [0, PHOID_MAX_COUNT], or
                                      stall_epsilon not finite and >= 0 */
    PHOID_E_SAMPLES = -13,       /**< hold_samples not in [0, PHOID_MAX_COUNT] or run_samples
                                      not in [1, PHOID_MAX_COUNT] */
    PHOID_E_STATE = -14,         /**< (phoid_start, phoid_release) not allowed in this state */
    PHOID_E_HAS_FORCE = -15      /**< has_force neither 0 nor 1 */
};

/** The configuration of one run. Units: SI (m, s) and the command's own units. */
typedef struct phoid_config {
    phoid_real sample_time;   /**< T, s (>= PHOID_MIN_SAMPLE_TIME, finite): the period at which
                                   phoid_step is called */
    phoid_real P;             /**< run proportional gain, command units per m (any sign) */
    phoid_real D;             /**< run derivative gain, command units per m/s (any sign) */
    phoid_real gain;          /**< K, dimensionless (finite; 1 for phoid's release loop) */
    phoid_real command_gain;  /**< G, N per command unit (> 0): the force is G*u. Not used by
                                   the step; kept so that one configuration describes the
                                   loop. */
    int velocity;             /**< enum phoid_velocity */
    phoid_real filter_pole;   /**< a = exp(-w_c*T) of PHOID_VEL_FILTERED, in [0, 1) */
    int delay_samples;        /**< d: the command computed at n is returned at n + d
                                   (0..PHOID_MAX_DELAY) */
    phoid_real hold_P;        /**< hold loop proportional gain, command units per m */
    phoid_real hold_D;        /**< hold loop derivative gain, command units per m/s */
    phoid_real x_start;       /**< hold position, m */
    long hold_samples;        /**< samples held before the release (0: until phoid_release;
                                   at most PHOID_MAX_COUNT) */
    long run_samples;         /**< samples run from the release on (1..PHOID_MAX_COUNT), then
                                   DONE */
    phoid_real x_min;         /**< lowest allowed position in HOLD and RUN, m */
    phoid_real x_max;         /**< highest allowed position in HOLD and RUN, m */
    phoid_real u_max;         /**< command limit, command units (> 0): commands are clipped */
    phoid_real growth_limit;  /**< RUN aborts when |x - r| > growth_limit*A (0: off;
                                   else >= 1) */
    long stall_samples;       /**< RUN aborts after this many samples in a row with
                                   |x_n - x_{n-1}| < stall_epsilon (0: off; at most
                                   PHOID_MAX_COUNT) */
    phoid_real stall_epsilon; /**< m (>= 0) */
    int has_force;            /**< 1: a force sensor is declared, so every sample must bring a
                                   finite measured force (phoid_step_force), else FAULT_INPUT;
                                   0 (default): no sensor, a force given is stored
                                   unchecked */
} phoid_config;

/** One entry of the event log. */
typedef struct phoid_event {
    unsigned long long index; /**< sample index at which it took effect (64-bit: no wrap) */
    int code;                 /**< enum phoid_event_code */
    phoid_real value;         /**< the code's value (see enum phoid_event_code) */
} phoid_event;

/** The controller's whole state. Treat as opaque; read it through the functions below. */
typedef struct phoid_ctrl {
    phoid_config cfg;
    int state;
    unsigned long long n;      /* index of the next sample (64-bit: 5.8e8 years at 1 kHz) */
    /* estimator */
    phoid_real x1, x2;         /* x_{n-1}, x_{n-2} */
    phoid_real vhat;           /* vhat of the last sample */
    int history;               /* 0 before the first sample, then 1 */
    phoid_real c0, c1;         /* estimator coefficients */
    /* delay ring: u_n at ring[head]; u_{n-d} at ring[(head - d) & (PHOID_RING_SIZE - 1)] */
    phoid_real ring[PHOID_RING_SIZE];
    unsigned head;
    unsigned filled;           /* entries written since the last clear, counted up to d: the
                                  delayed slots not yet written read as 0 (O(1) clear) */
    /* run bookkeeping */
    long held, ran, still;
    int release_pending;
    phoid_real amplitude;      /* A of the growth bound, m */
    phoid_real growth_bound;   /* growth_limit*A, set at the release */
    int clipping;              /* the last command was clipped */
    unsigned long clips;       /* commands clipped since phoid_init */
    phoid_real force;          /* the measured force of the last sample, N (NaN: none) */
    /* event log */
    phoid_event log[PHOID_EVENT_LOG];
    unsigned log_head, log_count;
    unsigned long events_lost;
} phoid_ctrl;

/** Fill *cfg with defaults: K = G = 1, backward difference, no delay, zero gains, no limits
 * in effect (x_min = -PHOID_NO_LIMIT, x_max = u_max = PHOID_NO_LIMIT), growth and stall
 * checks off, hold_samples = 0 (hold until phoid_release), run_samples = 1, no force sensor
 * (has_force = 0). */
void phoid_config_default(phoid_config *cfg);

/** Check *cfg and reset *c to IDLE at sample index 0 (estimator at rest at the first x,
 * delay ring and log empty). Returns PHOID_OK or a negative enum phoid_error naming the
 * first field that is wrong; *c is left untouched on error. */
int phoid_init(phoid_ctrl *c, const phoid_config *cfg);

/** One sample: take the position x (m) and reference r (m; used in RUN only), return the
 * command to apply now (command units; already delayed by delay_samples, already clipped).
 * Call exactly once per sample period. Returns 0 in IDLE, DONE and FAULT (and while the
 * delay still brings out the zeros issued in IDLE). */
phoid_real phoid_step(phoid_ctrl *c, phoid_real x, phoid_real r);

/** One sample with a measured force: as phoid_step, and `force` (N, the force applied to the
 * plant as the rig's force sensor reads it; NaN: no reading) is stored for phoid_force. The
 * loop does not use it (phoid's loop model is on x). With has_force = 1 a non-finite force
 * faults the controller (PHOID_EV_FAULT_INPUT, value 1), exactly as a non-finite x does;
 * phoid_step(c, x, r) is phoid_step_force(c, x, r, NaN), so a controller configured with
 * has_force = 1 must be stepped with phoid_step_force. */
phoid_real phoid_step_force(phoid_ctrl *c, phoid_real x, phoid_real r, phoid_real force);

/** The measured force given with the last sample, N; NaN when none was given (phoid_step,
 * or before the first sample). */
phoid_real phoid_force(const phoid_ctrl *c);

/** IDLE or DONE -> HOLD from the next sample on. PHOID_OK or PHOID_E_STATE. */
int phoid_start(phoid_ctrl *c);

/** Release at the next sample (HOLD only): the next sample is the first of RUN.
 * PHOID_OK or PHOID_E_STATE. */
int phoid_release(phoid_ctrl *c);

/** Abort from the host: FAULT (PHOID_EV_FAULT_HOST with value `reason`) unless already. */
void phoid_abort(phoid_ctrl *c, phoid_real reason);

/** FAULT -> IDLE (other states: no effect). */
void phoid_clear_fault(phoid_ctrl *c);

/** The current state (enum phoid_state). */
int phoid_state(const phoid_ctrl *c);

/** The index of the next sample (= samples stepped since phoid_init). */
unsigned long long phoid_sample_index(const phoid_ctrl *c);

/** Set the index of the next sample (IDLE only: PHOID_OK, else PHOID_E_STATE): for a firmware
 * that numbers samples from an outside clock, and for tests of the 64-bit counter (reaching
 * 2^32 by stepping takes 2^32 calls). Nothing else changes. */
int phoid_set_sample_index(phoid_ctrl *c, unsigned long long n);

/** The velocity estimate vhat of the last sample, m/s. */
phoid_real phoid_velocity(const phoid_ctrl *c);

/** Commands clipped to +/-u_max since phoid_init. */
unsigned long phoid_clips(const phoid_ctrl *c);

/** Events overwritten in the log before they were popped. */
unsigned long phoid_events_lost(const phoid_ctrl *c);

/** Pop the oldest event into *e: 1 if there was one, 0 if the log is empty. */
int phoid_pop_event(phoid_ctrl *c, phoid_event *e);

/** The name of an event code ("release", "fault-growth", ...), "unknown" for others. */
const char *phoid_event_name(int code);

/** The name of a state ("idle", "hold", "run", "done", "fault"), "unknown" for others. */
const char *phoid_state_name(int state);

/** sizeof(phoid_config) and sizeof(phoid_ctrl), for bindings that allocate them. */
unsigned long phoid_config_size(void);
unsigned long phoid_ctrl_size(void);

/** sizeof(phoid_real): 8 (double) or 4 (float, and AVR's double), for bindings. */
int phoid_real_size(void);

#ifdef __cplusplus
}
#endif

#endif /* PHOID_CTRL_H */
