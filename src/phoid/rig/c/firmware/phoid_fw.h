/*
 * phoid_fw.h -- the microcontroller side of phoid's rig link (C99, no heap, no stdio, no libm).
 *
 * On top of the controller (../phoid_ctrl.h) this speaks the rig protocol to `phoid run`
 * (docs/rig-protocol.md): the text handshake `PHOID-RIG 1` then `FRAMING cobs`, each line
 * compared whole with a constant (no CRC or number code for text), and from then on binary
 * frames only: COBS(payload | CRC-32(payload), little-endian) followed by one 0x00 byte.
 *
 *   host -> rig  C CONFIG (137 bytes), S START, A ABORT reason f8, L CLEAR, B BYE
 *   rig -> host  K OK, E ERROR text, X SAMPLE, V EVENT, D END
 *
 * A board (board.h) feeds it the host's bytes (phoid_fw_rx), steps it once per sample
 * (phoid_fw_tick, from the timer interrupt or, in the emulated rig, when the plant's position
 * arrives) and lets it send what is queued (phoid_fw_flush, from the main loop). The tick
 * touches only the controller and the sample queue; the main loop only the link, so a tick in
 * an interrupt never races the link code (the queue's two indices each have one writer).
 */
#ifndef PHOID_FW_H
#define PHOID_FW_H

#include "phoid_ctrl.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Samples queued between the tick and the link (a power of two). A link too slow for the
 * sample rate loses samples (the host sees a gap and records the run incomplete). */
#ifndef PHOID_FW_QUEUE
#define PHOID_FW_QUEUE 64u
#endif

/** Largest binary payload, bytes (the protocol's 250). */
#define PHOID_FW_MAX_PAYLOAD 250u
/** Largest encoded frame without its delimiter: payload + CRC 4 + COBS 1. */
#define PHOID_FW_MAX_FRAME (PHOID_FW_MAX_PAYLOAD + 5u)
/** Bytes of a CONFIG payload: type 1 + 14 f8 + u1 + u2 + 3 u4 + u1. */
#define PHOID_FW_CONFIG_BYTES 129u

/** A compiler memory barrier: the link (main loop) publishes a run or an abort to the tick
 * (an interrupt on the same core) by a volatile flag written after the data it guards; the
 * barrier keeps the compiler from moving those writes after the flag's (a single-core MCU
 * needs no more). Define PHOID_FW_BARRIER() yourself for a compiler other than GCC/Clang. */
#ifndef PHOID_FW_BARRIER
#if defined(__GNUC__)
#define PHOID_FW_BARRIER() __asm__ __volatile__("" ::: "memory")
#else
#error "define PHOID_FW_BARRIER() as your compiler's memory barrier"
#endif
#endif

/** One queued sample. */
typedef struct phoid_fw_sample {
    unsigned long index; /* from the run's start (the low 32 bits go on the wire) */
    unsigned char state; /* enum phoid_state as the protocol reports it */
    phoid_real x, u;
} phoid_fw_sample;

/** The link's whole state (one per link; no globals in phoid_fw.c). */
typedef struct phoid_fw {
    phoid_ctrl ctl;
    phoid_config cfg;
    int configured;           /* a CONFIG was accepted and nothing refused since */
    unsigned char sample_time_f8[8], command_gain_f8[8]; /* as the host sent them */
    /* the tick's side */
    volatile int running;     /* set by the link at START, cleared by the tick at the end */
    volatile int finished;    /* set by the tick after the run's last sample */
    volatile int abort_pending;
    phoid_real abort_reason;
    unsigned long long start_index; /* the controller's counter at START */
    unsigned long last_index;       /* the last tick's index from the start, low 32 bits */
    phoid_fw_sample queue[PHOID_FW_QUEUE];
    volatile unsigned int q_head, q_tail; /* tail: written by the tick; head: by the link */
    volatile unsigned long lost;         /* samples dropped on a full queue */
    /* the link's side */
    int mode;                 /* 0 wait for the hello, 1 wait for FRAMING, 2 binary */
    int refused_in_run;       /* a frame was refused during the run */
    unsigned char rx[PHOID_FW_MAX_FRAME + 1];
    unsigned int rx_len;
    int rx_overflow;
    unsigned int hello_match; /* bytes of the hello line matched so far */
} phoid_fw;

/** Reset the link (waiting for the hello) and the controller. */
void phoid_fw_init(phoid_fw *fw);

/** One byte from the host (main loop). */
void phoid_fw_rx(phoid_fw *fw, unsigned char byte);

/** One sample: the position x (m) read now; returns the command to apply now (0 outside a
 * run). Call once per sample period (timer interrupt), or per plant frame in lockstep. */
phoid_real phoid_fw_tick(phoid_fw *fw, phoid_real x);

/** Send the queued samples, and after the run's last one its events and END (main loop). */
void phoid_fw_flush(phoid_fw *fw);

/** The sample index of the tick that just ran, low 32 bits (for the emulated plant). */
unsigned long phoid_fw_last_index(const phoid_fw *fw);

/* helpers shared with the boards */
unsigned long phoid_fw_crc32(const unsigned char *p, unsigned int n);
/** Encode payload | CRC as one COBS frame with its 0x00, into out (>= n + 6 bytes); its
 * length. */
unsigned int phoid_fw_frame(const unsigned char *payload, unsigned int n, unsigned char *out);
/** Decode a COBS frame (without its 0x00) in place and check its CRC: the payload's length,
 * or -1 when the COBS or the CRC is wrong. */
int phoid_fw_unframe(unsigned char *buf, unsigned int n);
/** f8 little-endian bytes <-> double (memcpy, no type punning). */
double phoid_fw_get_f8(const unsigned char *p);
void phoid_fw_put_f8(unsigned char *p, double v);
/** IEEE binary64 bytes -> binary32 bytes (little-endian), rounded to nearest even as an FPU
 * converts (+/-infinity beyond the range, NaN stays NaN), and back (exact): by the bits, for
 * targets whose double has 32 bits (AVR). */
void phoid_fw_f8_to_f4(const unsigned char *f8, unsigned char *f4);
void phoid_fw_f4_to_f8(const unsigned char *f4, unsigned char *f8);
/** A double as the controller's real; a float build maps what a float cannot hold to
 * +/-infinity (a plain conversion of it is undefined behaviour in C99). */
phoid_real phoid_fw_real(double v);

#ifdef __cplusplus
}
#endif

#endif /* PHOID_FW_H */
