/*
 * fw_libc.c -- the two C library functions the firmware needs (GCC emits calls to them for
 * struct copies and clears): linked with -nostdlib and libgcc, nothing else. Compile it with
 * -fno-tree-loop-distribute-patterns, or GCC turns these loops into calls to themselves.
 */
#include <stddef.h>

void *memcpy(void *dst, const void *src, size_t n);
void *memset(void *dst, int c, size_t n);

void *memcpy(void *dst, const void *src, size_t n)
{
    unsigned char *d = (unsigned char *)dst;
    const unsigned char *s = (const unsigned char *)src;
    while (n--) {
        *d++ = *s++;
    }
    return dst;
}

void *memset(void *dst, int c, size_t n)
{
    unsigned char *d = (unsigned char *)dst;
    while (n--) {
        *d++ = (unsigned char)c;
    }
    return dst;
}
