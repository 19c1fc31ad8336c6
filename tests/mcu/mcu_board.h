/* tests/mcu/mcu_board.h -- what a test firmware gets from its start-up file
 * (cortexm_start.c, avr_start.c). */
#ifndef MCU_BOARD_H
#define MCU_BOARD_H

/** Leave the emulator: 0 success, else failure (QEMU's exit status 0 / 1). */
void mcu_exit(int code);
/** Print a NUL-terminated string on the emulator's console. */
void mcu_puts(const char *s);
/** The markers around one measured call (see tests/test_mcu_cost.py). */
void mcu_mark_begin(void);
void mcu_mark_end(void);

#endif
