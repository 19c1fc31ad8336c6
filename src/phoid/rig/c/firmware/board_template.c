/*
 * board_template.c -- phoid's firmware on your Cortex-M board: fill in the five marked
 * functions (FILL IN), build with `make BOARD=template TARGET=... LDSCRIPT=your.ld`.
 *
 * The sample clock is SysTick, reprogrammed to the period of each accepted CONFIG
 * (sample_time): its interrupt reads the position, steps the controller (phoid_fw_tick) and
 * writes the command at once — outside a run the command is 0. The main loop moves bytes
 * between the link UART and phoid_fw. Keep anything slow out of the interrupt.
 *
 * Sign convention: read_position() returns metres, positive one way along the axis;
 * write_command() must push the mass towards positive x for a positive u. Check it before
 * the first run (README.md, "Sign convention, and checking it before the first run").
 */
#include "board.h"
#include "phoid_fw.h"

/* ---- FILL IN: your core clock and your hardware ----------------------------------------- */

#define CORE_HZ 16000000.0 /* SysTick's clock, Hz (the core clock on most parts) */

static void hardware_init(void)
{
    /* FILL IN: clocks, the link UART (8N1; 230400 baud for 1 kHz with a float build, 460800
     * with a double one: README.md), the encoder's timer, the DAC or PWM */
}

int board_link_getc(void)
{
    /* FILL IN: the UART's received byte (0..255) when one is waiting, else -1; never wait */
    return -1;
}

void board_link_putc(unsigned char byte)
{
    /* FILL IN: wait until the UART can take a byte, then write it */
    (void)byte;
}

static phoid_real read_position(void)
{
    /* FILL IN: the encoder's count times its metres per count (m), read now */
    return PHOID_R(0);
}

static void write_command(phoid_real u)
{
    /* FILL IN: u in the amplifier's units (the force is command_gain * u N) to the DAC or
     * PWM, now; held until the next sample */
    (void)u;
}

/* ---- the sample clock (no need to change below) ----------------------------------------- */

#define SYST_CSR (*(volatile unsigned long *)0xE000E010UL)
#define SYST_RVR (*(volatile unsigned long *)0xE000E014UL)
#define SYST_CVR (*(volatile unsigned long *)0xE000E018UL)

static phoid_fw fw;

void SysTick_Handler(void);
void SysTick_Handler(void)
{
    write_command(phoid_fw_tick(&fw, read_position()));
}

static void systick(unsigned long ticks)
{
    SYST_CSR = 0UL;
    SYST_RVR = ticks - 1UL;
    SYST_CVR = 0UL;
    SYST_CSR = 7UL; /* the core clock, the interrupt, on */
}

const char *board_configure(const phoid_config *cfg, const unsigned char sample_time_f8[8],
                            const unsigned char command_gain_f8[8])
{
    /* the period in whole SysTick counts, exactly: phoid models the loop at sample_time, so
     * a timer that cannot make it refuses the run rather than running another period */
    double T = phoid_fw_get_f8(sample_time_f8);
    double ticks = T * CORE_HZ;
    unsigned long n;
    (void)cfg;
    (void)command_gain_f8;
    if (!(ticks >= 100.0 && ticks <= 16777216.0)) {
        return "sample_time: SysTick cannot make this period (100 to 2^24 core clocks)";
    }
    n = (unsigned long)(ticks + 0.5);
    if ((double)n - ticks > 1e-6 * ticks || ticks - (double)n > 1e-6 * ticks) {
        return "sample_time: not a whole number of core clocks (within 1 ppm)";
    }
    systick(n);
    return 0;
}

void board_run_start(void)
{
    /* the next SysTick is the run's first sample */
}

int main(void)
{
    hardware_init();
    phoid_fw_init(&fw);
    systick((unsigned long)(CORE_HZ / 1000.0)); /* 1 kHz (command 0) until a CONFIG */
    for (;;) {
        int c = board_link_getc();
        if (c >= 0) {
            phoid_fw_rx(&fw, (unsigned char)c);
        }
        phoid_fw_flush(&fw);
    }
}
