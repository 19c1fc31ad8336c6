/*
 * board_mps2_hil.c -- phoid's firmware on an emulated ARM MPS2 board (QEMU mps2-an385 M3,
 * mps2-an386 M4F, mps2-an500 M7), hardware in the loop against an emulated plant.
 *
 * CMSDK APB UART0 (0x40004000, QEMU's first -serial) is the link to `phoid run`; UART1
 * (0x40005000, the second -serial) is the plant (`phoid virtual-plant`, or a test's plant),
 * in lockstep: the tick is the plant's position, not a timer. Frames on UART1 are the link's
 * (COBS of payload | CRC-32, then 0x00):
 *   plant -> MCU  P  flags u1 (0), x f8        the position read at this sample, m
 *   MCU -> plant  U  index u4, u f8            the command applied from this sample on
 *   MCU -> plant  R  sample_time f8, command_gain f8   a run starts: the period and G
 * The plant sends its first P when it connects; the MCU steps once per P while a run is
 * in progress and answers U; the plant moves one period T under G*u exactly and sends the
 * next P. Outside a run the MCU keeps the last P unanswered, so the plant's time stands
 * still until the next run's first sample (an emulated plant has no clock of its own).
 */
#include "board.h"
#include "phoid_fw.h"

#define UART0_BASE 0x40004000UL
#define UART1_BASE 0x40005000UL
#define UART_DATA 0x00UL
#define UART_STATE 0x04UL /* bit 0: TX full, bit 1: RX full */
#define UART_CTRL 0x08UL  /* bit 0: TX enable, bit 1: RX enable */
#define UART_INTCLEAR 0x0CUL /* write 1 to bit 1: clear the RX interrupt */
#define UART_BAUDDIV 0x10UL
#define REG(base, off) (*(volatile unsigned long *)((base) + (off)))
#define NVIC_ISER0 (*(volatile unsigned long *)0xE000E100UL)
#define NVIC_ICPR0 (*(volatile unsigned long *)0xE000E280UL)
#define UART_RX_IRQS ((1UL << 0) | (1UL << 2)) /* QEMU's MPS2: UART0 RX IRQ 0, UART1 RX 2 */

static phoid_fw fw;
static unsigned char plant_rx[PHOID_FW_MAX_FRAME + 1];
static unsigned int plant_len;
static int plant_overflow;
static int pending; /* a P frame waits for a run */
static double pending_x;
static unsigned char run_frame[17];

static void uart_init(unsigned long base)
{
    REG(base, UART_BAUDDIV) = 16UL; /* the smallest divider; QEMU ignores the rate */
    REG(base, UART_CTRL) = 3UL | 8UL; /* TX, RX, the RX interrupt (it only wakes WFI) */
}

static int uart_getc(unsigned long base)
{
    if (REG(base, UART_STATE) & 2UL) {
        return (int)(REG(base, UART_DATA) & 0xFFUL);
    }
    return -1;
}

static void uart_putc(unsigned long base, unsigned char c)
{
    while (REG(base, UART_STATE) & 1UL) {
    }
    REG(base, UART_DATA) = c;
}

int board_link_getc(void) { return uart_getc(UART0_BASE); }

void board_link_putc(unsigned char byte) { uart_putc(UART0_BASE, byte); }

static void plant_send(const unsigned char *payload, unsigned int n)
{
    unsigned char out[PHOID_FW_MAX_FRAME + 1];
    unsigned int len = phoid_fw_frame(payload, n, out), i;
    for (i = 0; i < len; i++) {
        uart_putc(UART1_BASE, out[i]);
    }
}

const char *board_configure(const phoid_config *cfg, const unsigned char sample_time_f8[8],
                            const unsigned char command_gain_f8[8])
{
    unsigned int i;
    (void)cfg; /* the emulated plant runs any period phoid_init accepts */
    run_frame[0] = 'R';
    for (i = 0; i < 8u; i++) {
        run_frame[1 + i] = sample_time_f8[i];
        run_frame[9 + i] = command_gain_f8[i];
    }
    return 0;
}

/* one sample: step on the plant's x, answer U */
static void tick(double x)
{
    unsigned char p[13];
    phoid_real u = phoid_fw_tick(&fw, phoid_fw_real(x));
    unsigned long idx = phoid_fw_last_index(&fw);
    p[0] = 'U';
    p[1] = (unsigned char)(idx & 0xFFUL);
    p[2] = (unsigned char)((idx >> 8) & 0xFFUL);
    p[3] = (unsigned char)((idx >> 16) & 0xFFUL);
    p[4] = (unsigned char)((idx >> 24) & 0xFFUL);
    phoid_fw_put_f8(p + 5, (double)u);
    plant_send(p, 13u);
}

void board_run_start(void)
{
    plant_send(run_frame, 17u);
    if (pending) {
        pending = 0;
        tick(pending_x);
    }
}

static void plant_frame(void)
{
    int n = phoid_fw_unframe(plant_rx, plant_len);
    double x;
    if (n != 10 || plant_rx[0] != 'P' || plant_rx[1] != 0) {
        return; /* not a position frame: the plant gets no answer and says so */
    }
    x = phoid_fw_get_f8(plant_rx + 2);
    if (fw.running) {
        tick(x);
    } else {
        pending = 1;
        pending_x = x;
    }
}

static int poll_plant(void)
{
    int c = uart_getc(UART1_BASE);
    if (c < 0) {
        return 0;
    }
    if (c == 0) {
        if (!plant_overflow && plant_len > 0u) {
            plant_frame();
        }
        plant_len = 0;
        plant_overflow = 0;
    } else if (plant_len < sizeof(plant_rx)) {
        plant_rx[plant_len++] = (unsigned char)c;
    } else {
        plant_overflow = 1;
    }
    return 1;
}

/* sleep until a byte arrives on either UART. Interrupts stay masked (PRIMASK): a pending
 * one only ends the WFI, no handler runs. Sleeping instead of polling the status registers
 * leaves QEMU's I/O thread the time to move the bytes (a polling vCPU starves it). */
static void wait_for_bytes(void)
{
    REG(UART0_BASE, UART_INTCLEAR) = 2UL;
    REG(UART1_BASE, UART_INTCLEAR) = 2UL;
    NVIC_ICPR0 = UART_RX_IRQS;
    if (!(REG(UART0_BASE, UART_STATE) & 2UL) && !(REG(UART1_BASE, UART_STATE) & 2UL)) {
        __asm__ volatile("wfi");
    }
}

int main(void)
{
    __asm__ volatile("cpsid i");
    uart_init(UART0_BASE);
    uart_init(UART1_BASE);
    NVIC_ISER0 = UART_RX_IRQS;
    phoid_fw_init(&fw);
    for (;;) {
        int c = board_link_getc(), busy = 0;
        if (c >= 0) {
            phoid_fw_rx(&fw, (unsigned char)c);
            busy = 1;
        }
        busy |= poll_plant();
        phoid_fw_flush(&fw);
        if (!busy) {
            wait_for_bytes();
        }
    }
}
