/*
 * tests/mcu/cost_main.c -- the cost-measurement firmware of tests/test_mcu_cost.py.
 *
 * It runs the controller through every state transition once, each measured call bracketed
 * by mcu_mark_begin() / mcu_mark_end(); the test counts the instructions executed between the
 * two markers (QEMU trace, or Timer1 cycles on AVR) and subtracts an empty pair's count. The
 * order of the measured calls is the list COST_SEQUENCE of tests/test_mcu_cost.py: keep both
 * in step. After every call the firmware checks the state it must have reached and exits with
 * a failure (and a message) if not, so a count always belongs to the transition it is named
 * after. Every input comes through a volatile, so nothing is folded at compile time.
 *
 * The configuration takes the dearest path of a RUN step: the filtered estimator, a delay of
 * two samples, the growth and stall checks on.
 */
#include "mcu_board.h"
#include "phoid_ctrl.h"

#ifndef PHOID_REAL /* a controller from before the compile-time real type */
typedef double phoid_real;
#endif

static phoid_ctrl ctl;
static phoid_config cfg;
static volatile phoid_real in_x[] = {
    0.0040,  /* idle */
    0.0041, 0.0040, 0.0040, /* hold x3 */
    0.0040,  /* release (hold_samples reached) */
    0.0039, 0.0030, 0.0031, 0.0032, /* run, clip (a 1 mm jump), run, run */
    0.0033,  /* done */
    0.0040,  /* hold */
    0.0040,  /* release (phoid_release) */
    0.0039,  /* run */
    0.0500,  /* fault-position */
};
static volatile phoid_real in_r = 0.0;
static volatile phoid_real sink;
static unsigned k;

static void expect(int state, const char *what)
{
    if (phoid_state(&ctl) != state) {
        mcu_puts("cost: wrong state after ");
        mcu_puts(what);
        mcu_puts("\n");
        mcu_exit(1);
    }
}

static void step(int state, const char *what)
{
    phoid_real x = in_x[k++], r = in_r;
    mcu_mark_begin();
    sink = phoid_step(&ctl, x, r);
    mcu_mark_end();
    expect(state, what);
}

int main(void)
{
    phoid_config_default(&cfg);
    cfg.sample_time = 1e-3;
    cfg.P = 300.0;
    cfg.D = -35.0;
    cfg.velocity = PHOID_VEL_FILTERED;
    cfg.filter_pole = 0.5;
    cfg.delay_samples = 2;
    cfg.hold_P = 2000.0;
    cfg.hold_D = 20.0;
    cfg.x_start = 0.004;
    cfg.hold_samples = 3;
    cfg.run_samples = 6;
    cfg.x_min = -0.02;
    cfg.x_max = 0.02;
    cfg.u_max = 10.0;
    cfg.growth_limit = 2.0;
    cfg.stall_samples = 100;
    cfg.stall_epsilon = 1e-9;
    if (phoid_init(&ctl, &cfg) != PHOID_OK) {
        mcu_puts("cost: phoid_init refused the configuration\n");
        return 1;
    }

    mcu_mark_begin(); /* empty: the markers' own cost */
    mcu_mark_end();

    step(PHOID_IDLE, "idle step");
    mcu_mark_begin();
    phoid_start(&ctl);
    mcu_mark_end();
    expect(PHOID_HOLD, "phoid_start");
    step(PHOID_HOLD, "hold step 1");
    step(PHOID_HOLD, "hold step 2");
    step(PHOID_HOLD, "hold step 3");
    /* hold_samples = 3: the step after three held samples is the release */
    step(PHOID_RUN, "release step");
    step(PHOID_RUN, "run step 1");
    step(PHOID_RUN, "clip step");
    if (phoid_clips(&ctl) != 1) {
        mcu_puts("cost: the clip step did not clip\n");
        return 1;
    }
    step(PHOID_RUN, "run step 2");
    step(PHOID_RUN, "run step 3");
    /* run_samples = 6: the sixth RUN step (the release's is the first) is the last: DONE */
    step(PHOID_DONE, "done step");

    mcu_mark_begin();
    phoid_start(&ctl);
    mcu_mark_end();
    expect(PHOID_HOLD, "phoid_start from done");
    step(PHOID_HOLD, "hold step 4");
    mcu_mark_begin();
    phoid_release(&ctl);
    mcu_mark_end();
    step(PHOID_RUN, "release step (phoid_release)");
    step(PHOID_RUN, "run step 4");
    step(PHOID_FAULT, "fault-position step");
    mcu_mark_begin();
    phoid_clear_fault(&ctl);
    mcu_mark_end();
    expect(PHOID_IDLE, "phoid_clear_fault");
    phoid_start(&ctl);
    mcu_mark_begin();
    phoid_abort(&ctl, 1.0);
    mcu_mark_end();
    expect(PHOID_FAULT, "phoid_abort");
    return 0;
}
