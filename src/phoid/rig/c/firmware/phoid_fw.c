/*
 * phoid_fw.c -- the microcontroller side of phoid's rig link (see phoid_fw.h).
 *
 * C99, no heap, no stdio, no libm: text is compared with constants, numbers travel as IEEE
 * bytes (binary frames, docs/rig-protocol.md), so neither printf nor strtod is needed.
 */
#include "phoid_fw.h"
#include "board.h"

#if DBL_MANT_DIG != 53 && DBL_MANT_DIG != 24
#error "phoid_fw.c needs an IEEE double of 64 bits, or of 32 bits (AVR)"
#endif

/* the handshake's lines, whole (payload, " *", its CRC-32 in hex, LF) */
static const char HELLO[] = "PHOID-RIG 1 *b79b4dcf\n";
static const char FRAMING[] = "FRAMING cobs *df590735\n";
static const char TEXT_OK[] = "OK *d736d92d\n";
static const char NEED_HELLO[] = "ERROR send the hello PHOID-RIG 1 first *2b258d97\n";
static const char NEED_BINARY[] =
    "ERROR this rig speaks the binary framing: send FRAMING cobs *5555427c\n";

enum { MODE_HELLO = 0, MODE_FRAMING = 1, MODE_BINARY = 2 };
enum { HELLO_LEN = sizeof(HELLO) - 1, HELLO_MISS = sizeof(HELLO) };

/* ---- bytes ------------------------------------------------------------------------------ */

static void copy_bytes(unsigned char *dst, const unsigned char *src, unsigned int n)
{
    unsigned int i;
    for (i = 0; i < n; i++) {
        dst[i] = src[i];
    }
}

static int same_text(const unsigned char *a, const char *b, unsigned int n)
{
    unsigned int i;
    for (i = 0; i < n; i++) {
        if (a[i] != (unsigned char)b[i]) {
            return 0;
        }
    }
    return 1;
}

static void send_text(const char *s)
{
    while (*s) {
        board_link_putc((unsigned char)*s++);
    }
}

static unsigned long get_u4(const unsigned char *p)
{
    return (unsigned long)p[0] | ((unsigned long)p[1] << 8) | ((unsigned long)p[2] << 16)
           | ((unsigned long)p[3] << 24);
}

static void put_u4(unsigned char *p, unsigned long v)
{
    p[0] = (unsigned char)(v & 0xffu);
    p[1] = (unsigned char)((v >> 8) & 0xffu);
    p[2] = (unsigned char)((v >> 16) & 0xffu);
    p[3] = (unsigned char)((v >> 24) & 0xffu);
}

#if DBL_MANT_DIG == 53
double phoid_fw_get_f8(const unsigned char *p)
{
    /* little-endian bytes into the double's own representation (an unsigned char view of an
     * object is always allowed; ARM and x86 store doubles little-endian) */
    double v = 0.0;
    unsigned char *d = (unsigned char *)&v;
    unsigned int i;
    for (i = 0; i < 8; i++) {
        d[i] = p[i];
    }
    return v;
}

void phoid_fw_put_f8(unsigned char *p, double v)
{
    const unsigned char *s = (const unsigned char *)&v;
    unsigned int i;
    for (i = 0; i < 8; i++) {
        p[i] = s[i];
    }
}
#else
/* a 32-bit double (AVR): converted by the bits, phoid_fw_f8_to_f4 / phoid_fw_f4_to_f8 */
double phoid_fw_get_f8(const unsigned char *p)
{
    double v = 0.0;
    phoid_fw_f8_to_f4(p, (unsigned char *)&v);
    return v;
}

void phoid_fw_put_f8(unsigned char *p, double v)
{
    phoid_fw_f4_to_f8((const unsigned char *)&v, p);
}
#endif

void phoid_fw_f8_to_f4(const unsigned char *f8, unsigned char *f4)
{
    unsigned long long m = 0;
    unsigned long sign, bits;
    long e;
    unsigned int i;
    for (i = 0; i < 8u; i++) {
        m |= (unsigned long long)f8[i] << (8u * i);
    }
    sign = (unsigned long)(m >> 63) << 31;
    e = (long)((m >> 52) & 0x7ffu);
    m &= 0xfffffffffffffULL; /* the 52 fraction bits */
    if (e == 0x7ff) {
        bits = sign | 0x7f800000UL | (m ? 0x400000UL : 0UL);
    } else if (e == 0) {
        bits = sign; /* a binary64 subnormal is far below binary32's range */
    } else {
        m |= 1ULL << 52; /* the 53-bit significand */
        e = e - 1023 + 127; /* binary32's biased exponent */
        if (e >= 255) {
            bits = sign | 0x7f800000UL;
        } else if (e < -24) {
            bits = sign; /* below half the smallest subnormal */
        } else {
            unsigned int shift = e >= 1 ? 29u : (unsigned int)(29 + 1 - e);
            unsigned long long kept = m >> shift;
            unsigned long long rest = m & ((1ULL << shift) - 1u);
            unsigned long long half = 1ULL << (shift - 1u);
            if (rest > half || (rest == half && (kept & 1u))) {
                kept++; /* a carry runs into the exponent field: the sum below stays right */
            }
            bits = sign + (e >= 1 ? ((unsigned long)(e - 1) << 23) : 0UL) + (unsigned long)kept;
        }
    }
    put_u4(f4, bits);
}

void phoid_fw_f4_to_f8(const unsigned char *f4, unsigned char *f8)
{
    unsigned long bits = get_u4(f4);
    unsigned long long sign = (unsigned long long)(bits >> 31) << 63, out;
    long e = (long)((bits >> 23) & 0xffu);
    unsigned long long m = bits & 0x7fffffUL;
    unsigned int i;
    if (e == 0xff) {
        out = sign | (0x7ffULL << 52) | (m << 29);
    } else if (e == 0 && m == 0) {
        out = sign;
    } else {
        if (e == 0) { /* a binary32 subnormal: normal in binary64 */
            e = 1;
            while (!(m & 0x800000UL)) {
                m <<= 1;
                e--;
            }
            m &= 0x7fffffUL;
        }
        out = sign | ((unsigned long long)(e - 127 + 1023) << 52) | (m << 29);
    }
    for (i = 0; i < 8u; i++) {
        f8[i] = (unsigned char)((out >> (8u * i)) & 0xffu);
    }
}

#if PHOID_REAL_IS_FLOAT
static void put_f4(unsigned char *p, float v)
{
    const unsigned char *s = (const unsigned char *)&v;
    unsigned int i;
    for (i = 0; i < 4; i++) {
        p[i] = s[i];
    }
}
#endif

/* a double from the host as the controller's real: a float build maps what a float cannot
 * hold to +/-infinity (a plain conversion would be undefined), so phoid_init refuses it as
 * not finite where it must be finite (a limit of 1e300 becomes "no limit") */
phoid_real phoid_fw_real(double v)
{
#if PHOID_REAL_IS_FLOAT
    if (v > (double)FLT_MAX || v < -(double)FLT_MAX) {
        float inf;
        unsigned char *b = (unsigned char *)&inf;
        b[0] = 0x00;
        b[1] = 0x00;
        b[2] = 0x80;
        b[3] = (unsigned char)(v > 0.0 ? 0x7f : 0xff);
        return inf;
    }
#endif
    return (phoid_real)v;
}

/* the real's bytes on the wire: f4 in a float build, else f8; its size */
static unsigned int put_real(unsigned char *p, phoid_real v)
{
#if PHOID_REAL_IS_FLOAT
    put_f4(p, v);
    return 4u;
#else
    phoid_fw_put_f8(p, v);
    return 8u;
#endif
}

/* ---- CRC-32 (IEEE, reflected 0xEDB88320; zlib's), a nibble at a time --------------------- */

static const unsigned long CRC_NIBBLE[16] = {
    0x00000000UL, 0x1DB71064UL, 0x3B6E20C8UL, 0x26D930ACUL, 0x76DC4190UL, 0x6B6B51F4UL,
    0x4DB26158UL, 0x5005713CUL, 0xEDB88320UL, 0xF00F9344UL, 0xD6D6A3E8UL, 0xCB61B38CUL,
    0x9B64C2B0UL, 0x86D3D2D4UL, 0xA00AE278UL, 0xBDBDF21CUL
};

unsigned long phoid_fw_crc32(const unsigned char *p, unsigned int n)
{
    unsigned long crc = 0xFFFFFFFFUL;
    unsigned int i;
    for (i = 0; i < n; i++) {
        crc ^= p[i];
        crc = (crc >> 4) ^ CRC_NIBBLE[crc & 15u];
        crc = (crc >> 4) ^ CRC_NIBBLE[crc & 15u];
    }
    return (crc ^ 0xFFFFFFFFUL) & 0xFFFFFFFFUL;
}

/* ---- COBS ------------------------------------------------------------------------------- */

unsigned int phoid_fw_frame(const unsigned char *payload, unsigned int n, unsigned char *out)
{
    unsigned char crc[4];
    unsigned int code_at = 0, len = 1, i;
    unsigned char code = 1;
    put_u4(crc, phoid_fw_crc32(payload, n));
    for (i = 0; i < n + 4u; i++) {
        unsigned char b = i < n ? payload[i] : crc[i - n];
        if (b == 0) {
            out[code_at] = code;
            code_at = len++;
            code = 1;
        } else {
            out[len++] = b;
            code++;
            if (code == 0xFF && i + 1u < n + 4u) { /* a full block with more to come */
                out[code_at] = code;
                code_at = len++;
                code = 1;
            }
        }
    }
    out[code_at] = code;
    out[len++] = 0;
    return len;
}

int phoid_fw_unframe(unsigned char *buf, unsigned int n)
{
    unsigned int r = 0, w = 0;
    while (r < n) {
        unsigned int code = buf[r++], j;
        if (code == 0) {
            return -1;
        }
        for (j = 1; j < code; j++) {
            if (r >= n || buf[r] == 0) {
                return -1;
            }
            buf[w++] = buf[r++];
        }
        if (code < 0xFF && r < n) {
            buf[w++] = 0;
        }
    }
    if (w < 5u || phoid_fw_crc32(buf, w - 4u) != get_u4(buf + w - 4u)) {
        return -1;
    }
    return (int)(w - 4u);
}

/* ---- sending frames --------------------------------------------------------------------- */

static void send_frame(const unsigned char *payload, unsigned int n)
{
    unsigned char out[PHOID_FW_MAX_FRAME + 1];
    unsigned int len = phoid_fw_frame(payload, n, out), i;
    for (i = 0; i < len; i++) {
        board_link_putc(out[i]);
    }
}

static void send_ok(void)
{
    unsigned char k = 'K';
    send_frame(&k, 1u);
}

static void send_error(phoid_fw *fw, const char *message)
{
    unsigned char p[PHOID_FW_MAX_PAYLOAD];
    unsigned int n = 1;
    p[0] = 'E';
    while (message[n - 1] && n < PHOID_FW_MAX_PAYLOAD) {
        p[n] = (unsigned char)message[n - 1];
        n++;
    }
    send_frame(p, n);
    fw->configured = 0; /* a refused frame may have been a CONFIG: none survives it */
}

/* ---- init ------------------------------------------------------------------------------- */

void phoid_fw_init(phoid_fw *fw)
{
    fw->running = 0;
    fw->finished = 0;
    fw->abort_pending = 0;
    fw->abort_reason = PHOID_R(0);
    fw->configured = 0;
    fw->q_head = fw->q_tail = 0;
    fw->lost = 0;
    fw->mode = MODE_HELLO;
    fw->refused_in_run = 0;
    fw->rx_len = 0;
    fw->rx_overflow = 0;
    fw->hello_match = 0;
    fw->start_index = 0;
    fw->last_index = 0;
    phoid_config_default(&fw->cfg);
    (void)phoid_init(&fw->ctl, &fw->cfg);
}

/* ---- CONFIG ----------------------------------------------------------------------------- */

static const char *init_error(int err)
{
    switch (err) {
    case PHOID_E_SAMPLE_TIME:
        return "controller config: `sample_time` must be finite and >= 1e-9 s";
    case PHOID_E_VELOCITY:
        return "controller config: `velocity` must be 0, 1 or 2";
    case PHOID_E_FILTER_POLE:
        return "controller config: `filter_pole` must be in [0, 1)";
    case PHOID_E_DELAY:
        return "controller config: `delay_samples` must be a whole number from 0 to "
               "PHOID_MAX_DELAY";
    case PHOID_E_GAIN:
        return "controller config: `P, D, gain, hold_P, hold_D` must be finite (in the "
               "controller's real type)";
    case PHOID_E_COMMAND_GAIN:
        return "controller config: `command_gain` must be finite and > 0";
    case PHOID_E_LIMITS:
        return "controller config: `x_min, x_max` must satisfy x_min < x_max";
    case PHOID_E_START:
        return "controller config: `x_start` must be finite and within [x_min, x_max]";
    case PHOID_E_COMMAND_LIMIT:
        return "controller config: `u_max` must be > 0";
    case PHOID_E_GROWTH:
        return "controller config: `growth_limit` must be 0 (off) or finite and >= 1";
    case PHOID_E_STALL:
        return "controller config: `stall_samples, stall_epsilon` must be stall_samples from "
               "0 to 2147483647 and stall_epsilon finite and >= 0";
    case PHOID_E_SAMPLES:
        return "controller config: `hold_samples, run_samples` must be hold_samples from 0 "
               "and run_samples from 1, to 2147483647";
    case PHOID_E_HAS_FORCE:
        return "controller config: `has_force` must be 0 or 1";
    default:
        return "controller config: refused";
    }
}

#if PHOID_REAL_IS_FLOAT || DBL_MANT_DIG != 53
/* The reals of a CONFIG (offset in the payload, name); limit: beyond the real's range it is
 * "no limit" (the host's default 1e300), as the C controller's defaults say. */
static const struct {
    unsigned char at;
    unsigned char limit;
    const char *name;
} CONFIG_REALS[] = {
    {1, 0, "sample_time"}, {9, 0, "P"}, {17, 0, "D"}, {25, 0, "gain"},
    {33, 0, "command_gain"}, {42, 0, "filter_pole"}, {52, 0, "hold_P"}, {60, 0, "hold_D"},
    {68, 0, "x_start"}, {84, 1, "x_min"}, {92, 1, "x_max"}, {100, 1, "u_max"},
    {108, 0, "growth_limit"}, {120, 0, "stall_epsilon"},
};

static unsigned int append(char *out, unsigned int n, const char *s)
{
    while (*s && n < 95u) {
        out[n++] = *s++;
    }
    out[n] = 0;
    return n;
}

/* A real the wire gives as binary64 that the build's real (binary32: a float build, or AVR's
 * double) cannot carry: a value that is not 0 but rounds to 0, or a finite value beyond the
 * real's range (but for a limit: "no limit"). Its message, naming the field, in out; 0 if
 * none. Decided on the f8's bits and the converted value, so it holds on AVR too. */
static const char *unrepresentable(const unsigned char *p, char *out)
{
    unsigned int i, n;
    for (i = 0; i < sizeof(CONFIG_REALS) / sizeof(CONFIG_REALS[0]); i++) {
        const unsigned char *b = p + CONFIG_REALS[i].at;
        unsigned int exponent = ((unsigned int)(b[7] & 0x7fu) << 4) | (unsigned int)(b[6] >> 4);
        int nonzero = (b[0] | b[1] | b[2] | b[3] | b[4] | b[5] | b[6] | (b[7] & 0x7fu)) != 0;
        phoid_real r = phoid_fw_real(phoid_fw_get_f8(b));
        const char *why = 0;
        if (exponent == 0x7ffu) {
            continue; /* NaN, infinity: phoid_init says what it takes */
        }
        if (nonzero && r >= PHOID_R(0) && r <= PHOID_R(0)) {
            why = "` is not 0 but rounds to 0 in this build's 32-bit real";
        } else if (!CONFIG_REALS[i].limit && !(r >= -PHOID_REAL_MAX && r <= PHOID_REAL_MAX)) {
            why = "` is beyond this build's 32-bit real (3.4e38)";
        }
        if (why) {
            n = append(out, 0u, "controller config: `");
            n = append(out, n, CONFIG_REALS[i].name);
            (void)append(out, n, why);
            return out;
        }
    }
    return 0;
}
#endif

#if PHOID_REAL_IS_FLOAT && DBL_MANT_DIG == 53
/* A float build on a target whose double is binary64: the CONFIG's reals checked as the
 * double build's phoid_init checks them, in double, before they are rounded to float (so a
 * value the double build refuses, e.g. growth_limit 0.99999999 or x_start one ulp beyond
 * x_max, is refused here too). Config time only: the step path stays float. */
static int check_as_double(const unsigned char *p)
{
    double T = phoid_fw_get_f8(p + 1), command_gain = phoid_fw_get_f8(p + 33);
    double pole = phoid_fw_get_f8(p + 42), x_start = phoid_fw_get_f8(p + 68);
    double x_min = phoid_fw_get_f8(p + 84), x_max = phoid_fw_get_f8(p + 92);
    double u_max = phoid_fw_get_f8(p + 100), growth = phoid_fw_get_f8(p + 108);
    double epsilon = phoid_fw_get_f8(p + 120);
    if (!(T >= 1e-9 && T <= DBL_MAX)) {
        return PHOID_E_SAMPLE_TIME;
    }
    if (p[41] == (unsigned char)PHOID_VEL_FILTERED && !(pole >= 0.0 && pole < 1.0)) {
        return PHOID_E_FILTER_POLE;
    }
    if (!(command_gain > 0.0 && command_gain <= DBL_MAX)) {
        return PHOID_E_COMMAND_GAIN;
    }
    if (!(x_min < x_max)) {
        return PHOID_E_LIMITS;
    }
    if (!(x_start >= x_min && x_start <= x_max && x_start >= -DBL_MAX && x_start <= DBL_MAX)) {
        return PHOID_E_START;
    }
    if (!(u_max > 0.0)) {
        return PHOID_E_COMMAND_LIMIT;
    }
    if (!((growth >= 0.0 && growth <= 0.0) || (growth >= 1.0 && growth <= DBL_MAX))) {
        return PHOID_E_GROWTH;
    }
    if (!(epsilon >= 0.0 && epsilon <= DBL_MAX)) {
        return PHOID_E_STALL;
    }
    return PHOID_OK;
}
#endif

static void take_config(phoid_fw *fw, const unsigned char *p, unsigned int n)
{
    phoid_config cfg;
    unsigned long hold, run, stall;
    unsigned int delay;
    const char *why;
    int err;
#if PHOID_REAL_IS_FLOAT || DBL_MANT_DIG != 53
    char message[96];
#endif
    if (n != PHOID_FW_CONFIG_BYTES) {
        send_error(fw, "a CONFIG frame must have 129 bytes of payload");
        return;
    }
    phoid_config_default(&cfg);
    cfg.sample_time = phoid_fw_real(phoid_fw_get_f8(p + 1));
    cfg.P = phoid_fw_real(phoid_fw_get_f8(p + 9));
    cfg.D = phoid_fw_real(phoid_fw_get_f8(p + 17));
    cfg.gain = phoid_fw_real(phoid_fw_get_f8(p + 25));
    cfg.command_gain = phoid_fw_real(phoid_fw_get_f8(p + 33));
    cfg.velocity = p[41];
    cfg.filter_pole = phoid_fw_real(phoid_fw_get_f8(p + 42));
    delay = (unsigned int)p[50] | ((unsigned int)p[51] << 8);
    cfg.hold_P = phoid_fw_real(phoid_fw_get_f8(p + 52));
    cfg.hold_D = phoid_fw_real(phoid_fw_get_f8(p + 60));
    cfg.x_start = phoid_fw_real(phoid_fw_get_f8(p + 68));
    hold = get_u4(p + 76);
    run = get_u4(p + 80);
    cfg.x_min = phoid_fw_real(phoid_fw_get_f8(p + 84));
    cfg.x_max = phoid_fw_real(phoid_fw_get_f8(p + 92));
    cfg.u_max = phoid_fw_real(phoid_fw_get_f8(p + 100));
    cfg.growth_limit = phoid_fw_real(phoid_fw_get_f8(p + 108));
    stall = get_u4(p + 116);
    cfg.stall_epsilon = phoid_fw_real(phoid_fw_get_f8(p + 120));
    cfg.has_force = p[128];
    /* the whole numbers within what the C types hold, before they are assigned */
    if (delay > (unsigned int)PHOID_MAX_DELAY) {
        send_error(fw, init_error(PHOID_E_DELAY));
        return;
    }
    if (hold > (unsigned long)PHOID_MAX_COUNT || run > (unsigned long)PHOID_MAX_COUNT) {
        send_error(fw, init_error(PHOID_E_SAMPLES));
        return;
    }
    if (stall > (unsigned long)PHOID_MAX_COUNT) {
        send_error(fw, init_error(PHOID_E_STALL));
        return;
    }
#if PHOID_REAL_IS_FLOAT && DBL_MANT_DIG == 53
    err = check_as_double(p);
    if (err != PHOID_OK) {
        send_error(fw, init_error(err));
        return;
    }
#endif
#if PHOID_REAL_IS_FLOAT || DBL_MANT_DIG != 53
    why = unrepresentable(p, message);
    if (why) {
        send_error(fw, why);
        return;
    }
#endif
    cfg.delay_samples = (int)delay;
    cfg.hold_samples = (long)hold;
    cfg.run_samples = (long)run;
    cfg.stall_samples = (long)stall;
    err = phoid_init(&fw->ctl, &cfg); /* checks it (IDLE: no run in progress) */
    if (err != PHOID_OK) {
        send_error(fw, init_error(err));
        return;
    }
    if (cfg.hold_samples == 0) {
        send_error(fw, "hold_samples 0 (hold until a release) would hold for ever: the "
                       "protocol has no release command; give hold_samples >= 1");
        return;
    }
    if (cfg.has_force) {
        send_error(fw, "has_force 1: this firmware reads no force sensor");
        return;
    }
    copy_bytes(fw->sample_time_f8, p + 1, 8u);
    copy_bytes(fw->command_gain_f8, p + 33, 8u);
    why = board_configure(&cfg, fw->sample_time_f8, fw->command_gain_f8);
    if (why) {
        send_error(fw, why);
        return;
    }
    fw->cfg = cfg;
    fw->configured = 1;
    send_ok();
}

/* ---- the run ---------------------------------------------------------------------------- */

static void start_run(phoid_fw *fw)
{
    if (!fw->configured) {
        send_error(fw, "START without an accepted CONFIG");
        return;
    }
    /* a fresh controller per run, as phoid virtual-rig: sample 0 is the hold's first */
    (void)phoid_init(&fw->ctl, &fw->cfg);
    (void)phoid_start(&fw->ctl);
    fw->start_index = phoid_sample_index(&fw->ctl);
    fw->q_head = fw->q_tail = 0;
    fw->lost = 0;
    fw->abort_pending = 0;
    fw->finished = 0;
    fw->refused_in_run = 0;
    PHOID_FW_BARRIER(); /* the controller and the queue are whole before the tick sees them */
    fw->running = 1;
    board_run_start();
}

phoid_real phoid_fw_tick(phoid_fw *fw, phoid_real x)
{
    int before, after, shown;
    unsigned long long idx;
    unsigned int tail;
    phoid_real u;
    if (!fw->running) {
        return PHOID_R(0);
    }
    if (fw->abort_pending) {
        fw->abort_pending = 0;
        phoid_abort(&fw->ctl, fw->abort_reason);
    }
    before = phoid_state(&fw->ctl);
    idx = phoid_sample_index(&fw->ctl) - fw->start_index;
    u = phoid_step(&fw->ctl, x, PHOID_R(0));
    after = phoid_state(&fw->ctl);
    if (!(x >= -PHOID_REAL_MAX && x <= PHOID_REAL_MAX)) {
        /* a position that is not finite (a sensor failure: the controller faulted,
         * fault-input): a SAMPLE carries finite numbers only, so the run ends without it */
        fw->last_index = (unsigned long)(idx & 0xFFFFFFFFULL);
        fw->running = 0;
        fw->finished = 1;
        return u;
    }
    /* the protocol's state of the sample: the last run sample is `run` (the controller is
     * done after it), the sample after the run `done`, the one that tripped `fault` */
    shown = (before == PHOID_RUN && after == PHOID_DONE) ? PHOID_RUN : after;
    fw->last_index = (unsigned long)(idx & 0xFFFFFFFFULL);
    tail = fw->q_tail;
    if (tail - fw->q_head < PHOID_FW_QUEUE) {
        phoid_fw_sample *s = &fw->queue[tail & (PHOID_FW_QUEUE - 1u)];
        s->index = fw->last_index;
        s->state = (unsigned char)shown;
        s->x = x;
        s->u = u;
        fw->q_tail = tail + 1u;
    } else {
        fw->lost++;
    }
    if ((after == PHOID_DONE || after == PHOID_FAULT) && shown != PHOID_RUN) {
        fw->running = 0;
        fw->finished = 1;
    }
    return u;
}

unsigned long phoid_fw_last_index(const phoid_fw *fw) { return fw->last_index; }

static void send_sample(const phoid_fw_sample *s)
{
    unsigned char p[1 + 4 + 1 + 1 + 16];
    unsigned int n;
    p[0] = 'X';
    put_u4(p + 1, s->index);
    p[5] = s->state;
    p[6] = (unsigned char)(PHOID_REAL_IS_FLOAT ? 1u : 0u);
    n = 7u;
    n += put_real(p + n, s->x);
    n += put_real(p + n, s->u);
    send_frame(p, n);
}

static void send_end(phoid_fw *fw)
{
    phoid_event ev;
    unsigned char p[1 + 4 + 1 + 1 + 8];
    unsigned char reason = 0; /* END's "a fault whose event was lost" */
    int faulted = phoid_state(&fw->ctl) == PHOID_FAULT;
    while (phoid_pop_event(&fw->ctl, &ev)) {
        unsigned int n;
        p[0] = 'V';
        put_u4(p + 1, (unsigned long)((ev.index - fw->start_index) & 0xFFFFFFFFULL));
        p[5] = (unsigned char)ev.code;
        p[6] = (unsigned char)(PHOID_REAL_IS_FLOAT ? 1u : 0u);
        n = 7u + put_real(p + 7, ev.value);
        send_frame(p, n);
        if (ev.code >= PHOID_EV_FAULT_POSITION && ev.code != PHOID_EV_CLEAR) {
            reason = (unsigned char)ev.code;
        }
    }
    p[0] = 'D';
    p[1] = faulted ? reason : (unsigned char)PHOID_EV_DONE;
    send_frame(p, 2u);
    if (fw->refused_in_run) {
        fw->configured = 0;
    }
}

void phoid_fw_flush(phoid_fw *fw)
{
    int finished = fw->finished; /* read before the queue: its last sample is in by then */
    while (fw->q_head != fw->q_tail) {
        unsigned int head = fw->q_head;
        send_sample(&fw->queue[head & (PHOID_FW_QUEUE - 1u)]);
        fw->q_head = head + 1u;
    }
    if (finished) {
        fw->finished = 0;
        send_end(fw);
    }
}

/* ---- receiving -------------------------------------------------------------------------- */

static void end_session(phoid_fw *fw)
{
    fw->running = 0;
    fw->finished = 0;
    fw->configured = 0;
    fw->q_head = fw->q_tail;
}

static void take_frame(phoid_fw *fw, unsigned char *p, unsigned int n)
{
    if (fw->running || fw->finished) {
        if (p[0] == 'A' && n == 9u) {
            /* abort whatever the reason says (safety first); one that is not a finite real
             * is reported as 0 (the EVENT carries finite numbers only) */
            phoid_real reason = phoid_fw_real(phoid_fw_get_f8(p + 1));
            fw->abort_reason = reason >= -PHOID_REAL_MAX && reason <= PHOID_REAL_MAX
                                   ? reason : PHOID_R(0);
            /* the reason is written before the flag the tick reads it by. The abort acts at
             * the next tick: a rig whose ticks stopped (a stalled plant in the lockstep
             * emulation) ends the run when they resume; the host gives up after --timeout */
            PHOID_FW_BARRIER();
            fw->abort_pending = 1;
        } else {
            send_error(fw, "only ABORT is taken during a run: abort it first");
            fw->refused_in_run = 1;
        }
        return;
    }
    switch (p[0]) {
    case 'C':
        take_config(fw, p, n);
        break;
    case 'S':
        if (n != 1u) {
            send_error(fw, "a START frame has no fields");
        } else {
            start_run(fw);
        }
        break;
    case 'A': /* no run in progress: nothing to abort */
        if (n != 9u) {
            send_error(fw, "an ABORT frame has one f8 field");
        } else {
            send_ok();
        }
        break;
    case 'L': /* the controller is made afresh at every START: nothing to clear */
        if (n != 1u) {
            send_error(fw, "a CLEAR frame has no fields");
        } else {
            send_ok();
        }
        break;
    case 'B':
        end_session(fw);
        fw->mode = MODE_HELLO;
        break;
    default:
        send_error(fw, "unknown frame type");
        break;
    }
}

static void say_hello(phoid_fw *fw)
{
    end_session(fw);
    send_text(HELLO);
    fw->mode = MODE_FRAMING;
    fw->rx_len = 0;
    fw->rx_overflow = 0;
    fw->hello_match = 0;
}

/* a text line that is not the hello (found by phoid_fw_rx): FRAMING, or an ERROR */
static void take_line(phoid_fw *fw)
{
    unsigned int n = fw->rx_len;
    /* a CR before the LF is ignored */
    if (n >= 2u && fw->rx[n - 2u] == '\r') {
        fw->rx[n - 2u] = '\n';
        n--;
    }
    if (!fw->rx_overflow && fw->mode == MODE_FRAMING && n == sizeof(FRAMING) - 1u
        && same_text(fw->rx, FRAMING, n)) {
        send_text(TEXT_OK);
        fw->mode = MODE_BINARY;
        fw->hello_match = 0;
    } else {
        send_text(fw->mode == MODE_HELLO ? NEED_HELLO : NEED_BINARY);
    }
}

void phoid_fw_rx(phoid_fw *fw, unsigned char byte)
{
    if (fw->mode != MODE_BINARY) {
        /* text: a line that ends with the hello is the hello, whatever came before it on
         * the line (line noise, the rest of a line cut off, an over-long line). The hello has
         * one 'P', at its start, so a plain matcher finds its end; a CR before its LF is
         * ignored, as in every line. */
        if (byte == (unsigned char)HELLO[fw->hello_match]) {
            fw->hello_match++;
        } else if (!(byte == '\r' && HELLO[fw->hello_match] == '\n')) {
            fw->hello_match = byte == (unsigned char)HELLO[0] ? 1u : 0u;
        }
        if (fw->hello_match == HELLO_LEN) {
            say_hello(fw);
            return;
        }
        if (byte == '\n') {
            if (fw->rx_len < sizeof(fw->rx)) {
                fw->rx[fw->rx_len++] = byte;
            } else {
                fw->rx_overflow = 1;
            }
            take_line(fw);
            fw->rx_len = 0;
            fw->rx_overflow = 0;
            fw->hello_match = 0;
        } else if (fw->rx_len < sizeof(fw->rx) - 1u) {
            fw->rx[fw->rx_len++] = byte;
        } else {
            fw->rx_overflow = 1;
        }
        return;
    }
    if (byte == 0) {
        fw->hello_match = 0;
        if (fw->rx_overflow) {
            send_error(fw, "a frame longer than the protocol's 255 bytes");
        } else if (fw->rx_len > 0u) {
            int n = phoid_fw_unframe(fw->rx, fw->rx_len);
            if (n < 1) {
                send_error(fw, "a frame whose COBS or CRC-32 is wrong");
                if (fw->running || fw->finished) {
                    fw->refused_in_run = 1;
                }
            } else {
                take_frame(fw, fw->rx, (unsigned int)n);
            }
        }
        fw->rx_len = 0;
        fw->rx_overflow = 0;
        return;
    }
    if (fw->rx_len < sizeof(fw->rx)) {
        fw->rx[fw->rx_len++] = byte;
    } else {
        fw->rx_overflow = 1;
    }
    /* a host that connects again says hello in text. In binary mode it is the hello only
     * when it is exactly the bytes since the last 0x00 or LF (a frame's delimiter, the end of
     * a text line): the bytes of a frame may spell the hello (a CONFIG's reals can), and
     * those do not end the session. HELLO_MISS: this segment is not the hello. */
    if (fw->hello_match < HELLO_LEN && byte == (unsigned char)HELLO[fw->hello_match]) {
        fw->hello_match++;
    } else {
        fw->hello_match = HELLO_MISS;
    }
    if (fw->hello_match == HELLO_LEN) {
        say_hello(fw);
    } else if (byte == '\n') {
        fw->hello_match = 0;
    }
}
