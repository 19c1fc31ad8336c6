/*
 * tests/mcu/avr_start.c -- the smallest atmega2560 start-up the MCU tests link with
 * (-nostdlib -nostartfiles): a reset vector, r1 = 0, libgcc's .data/.bss set-up (pulled in by
 * the compiler's references), main, then a halt; memcpy/memset; the measurement markers, which
 * time a call with Timer1 running at the CPU clock (1 count per cycle) and print the count on
 * USART0 (simavr shows USART0 on its console); an exit that simavr reports ("sleeping with
 * interrupts off").
 */
#include <stddef.h>

#include "mcu_board.h"

int main(void);

#define REG8(a) (*(volatile unsigned char *)(a))
#define UCSR0A REG8(0xC0)
#define UCSR0B REG8(0xC1)
#define UDR0 REG8(0xC6)
#define TCCR1A REG8(0x80)
#define TCCR1B REG8(0x81)
#define TCNT1L REG8(0x84)
#define TCNT1H REG8(0x85)
#define TIFR1 REG8(0x36)

__attribute__((naked, used, section(".vectors"))) void avr_vectors(void)
{
    __asm__ volatile("jmp avr_reset");
}

__attribute__((naked, used, section(".init0"))) void avr_reset(void)
{
    /* the stack pointer is RAMEND after a reset; __zero_reg__ and SREG cleared */
    __asm__ volatile("clr r1\n\tout 0x3f, r1");
}

__attribute__((naked, used, section(".init9"))) void avr_main(void)
{
    __asm__ volatile("call main\n\tjmp mcu_exit");
}

static void put(char ch)
{
    while (!(UCSR0A & 0x20)) { /* UDRE0 */
    }
    UDR0 = (unsigned char)ch;
}

void mcu_puts(const char *s)
{
    UCSR0B = 0x08; /* TXEN0 */
    while (*s) {
        put(*s++);
    }
}

void mcu_exit(int code)
{
    mcu_puts(code == 0 ? "exit 0\n" : "exit 1\n");
    __asm__ volatile("cli\n\tldi r24, 0x01\n\tout 0x33, r24\n\tsleep"); /* SMCR: SE, idle */
    for (;;) {
    }
}

__attribute__((noinline)) void mcu_mark_begin(void)
{
    TCCR1A = 0;
    TCCR1B = 0;    /* stop */
    TCNT1H = 0;    /* high byte first (the temporary register) */
    TCNT1L = 0;
    TIFR1 = 0x01;  /* clear TOV1 */
    TCCR1B = 0x01; /* run at clk/1 */
}

__attribute__((noinline)) void mcu_mark_end(void)
{
    unsigned char lo, hi, ov;
    unsigned int t;
    char buf[8];
    int i = 0;
    lo = TCNT1L; /* low byte first (it latches the high byte) */
    hi = TCNT1H;
    ov = TIFR1 & 0x01;
    TCCR1B = 0; /* stop */
    t = (unsigned int)hi << 8 | lo;
    if (ov) {
        mcu_puts("cycles overflow\n");
        return;
    }
    mcu_puts("cycles ");
    do {
        buf[i++] = (char)('0' + t % 10);
        t /= 10;
    } while (t);
    while (i) {
        put(buf[--i]);
    }
    put('\n');
}

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
