/*
 * tests/mcu/cortexm_start.c -- the smallest Cortex-M start-up the MCU tests link with: a vector
 * table, .data/.bss set-up, memcpy/memset (the only C library functions the controller may
 * need), the measurement markers and an exit through ARM semihosting (QEMU's
 * -semihosting-config enable=on). No C library, no libm: the link is -nostdlib + libgcc.
 */
#include <stddef.h>

#include "mcu_board.h"

extern unsigned long _sidata, _sdata, _edata, _sbss, _ebss, _estack;
int main(void);
void reset_handler(void);
void fault_handler(void);

/* ARM semihosting call (bkpt 0xab on M-profile): r0 = operation, r1 = argument */
static int semihost(int op, const void *arg)
{
    register int r0 __asm__("r0") = op;
    register const void *r1 __asm__("r1") = arg;
    __asm__ volatile("bkpt 0xab" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}

void mcu_exit(int code)
{
    /* SYS_EXIT (0x18) with ADP_Stopped_ApplicationExit (0x20026): QEMU exits with status 0;
     * ADP_Stopped_RunTimeErrorUnknown (0x20023): status 1 */
    semihost(0x18, (const void *)(code == 0 ? 0x20026UL : 0x20023UL));
    for (;;) {
    }
}

void mcu_puts(const char *s)
{
    semihost(0x04, s); /* SYS_WRITE0: a NUL-terminated string on QEMU's console */
}

volatile unsigned long mcu_mark_sink;

/* the markers bracketing a measured call: the tests count the instructions traced between the
 * entry of mcu_mark_begin and the entry of mcu_mark_end; different bodies, so that no
 * identical-code folding merges them */
__attribute__((noinline)) void mcu_mark_begin(void) { mcu_mark_sink = 1; }
__attribute__((noinline)) void mcu_mark_end(void) { mcu_mark_sink = 2; }

/* (the loops must not be turned back into calls to memcpy/memset by GCC's pattern matcher) */
#define NO_LIBCALL __attribute__((optimize("no-tree-loop-distribute-patterns")))

NO_LIBCALL void *memcpy(void *dst, const void *src, size_t n)
{
    unsigned char *d = dst;
    const unsigned char *s = src;
    while (n--) {
        *d++ = *s++;
    }
    return dst;
}

NO_LIBCALL void *memset(void *dst, int c, size_t n)
{
    unsigned char *d = dst;
    while (n--) {
        *d++ = (unsigned char)c;
    }
    return dst;
}

NO_LIBCALL void reset_handler(void)
{
    unsigned long *s = &_sidata, *d = &_sdata;
    while (d < &_edata) {
        *d++ = *s++;
    }
    for (d = &_sbss; d < &_ebss; d++) {
        *d = 0;
    }
#if defined(__ARM_FP)
    /* the FPU: full access for CP10 and CP11 (CPACR) */
    *(volatile unsigned long *)0xE000ED88UL |= 0xFUL << 20;
    __asm__ volatile("dsb\n\tisb" ::: "memory");
#endif
    mcu_exit(main());
}

void fault_handler(void)
{
    mcu_puts("mcu: hard fault\n");
    mcu_exit(1);
}

__attribute__((section(".vectors"), used)) static void (*const vectors[16])(void) = {
    (void (*)(void))&_estack, reset_handler, fault_handler, fault_handler, fault_handler,
    fault_handler, fault_handler, 0, 0, 0, 0, fault_handler, fault_handler, 0, fault_handler,
    fault_handler,
};
