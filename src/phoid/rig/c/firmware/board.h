/*
 * board.h -- what a board gives phoid's firmware (phoid_fw.c). Fill these in for your board
 * (board_template.c is a bare-metal Cortex-M start; board_mps2_hil.c is the emulated rig that
 * phoid's tests run in QEMU).
 *
 * Sign convention (as ../README.md): the position is in m, positive one way along the
 * axis; the command is in the amplifier's units, and a positive command must push the mass
 * towards positive x. Check it on the rig before the first run (firmware/README.md).
 */
#ifndef PHOID_BOARD_H
#define PHOID_BOARD_H

#include "phoid_ctrl.h"

#ifdef __cplusplus
extern "C" {
#endif

/** The next byte from the host's link (UART), or -1 when none is waiting. Never blocks. */
int board_link_getc(void);

/** Send one byte to the host's link; may wait until the UART takes it. */
void board_link_putc(unsigned char byte);

/** A CONFIG was received and the controller accepts it: can the board run it? Return 0 when
 * it can (the sample timer can make sample_time), else a constant message (ASCII, no NUL
 * inside) that goes back to the host as the ERROR. sample_time is also given as the host
 * sent it (IEEE binary64, little-endian), for boards that need it exactly. */
const char *board_configure(const phoid_config *cfg, const unsigned char sample_time_f8[8],
                            const unsigned char command_gain_f8[8]);

/** A run starts (the controller holds from its next tick on). */
void board_run_start(void);

#ifdef __cplusplus
}
#endif

#endif /* PHOID_BOARD_H */
