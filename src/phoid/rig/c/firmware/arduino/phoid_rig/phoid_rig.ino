// phoid_rig.ino -- phoid's rig firmware as an Arduino sketch, for the Arduino Mega 2560
// (ATmega2560 at 16 MHz; the Uno's 2 kB of RAM are too few).
//
// Copy next to this file: ../../phoid_fw.h, ../../phoid_fw.c, ../../board.h,
// ../../../phoid_ctrl.h, ../../../phoid_ctrl.c (the IDE builds every .c of the sketch folder).
// Then fill in read_position() and write_command() (FILL IN) and upload.
//
// The link is the board's USB serial port (USART0) at 500000 baud, 8N1:
//   phoid run PLAN --port "serial:///dev/ttyACM0?baud=500000" --framing binary
// (a double has 32 bits on AVR: samples travel as f8, 29 bytes each, so 500000 baud carries
// up to 1700 samples/s). The sample clock is Timer1 at the configured sample_time; one step
// of the controller costs about 0.3 ms here (software floating point), so run at 500 Hz or
// less with your encoder read and command write added (a tick that comes while the last step
// still runs stops the run: fault-host with value -1). Do not use the Arduino API's Serial
// (nor Timer1: the Servo library, PWM on pins 11 and 12): the sketch drives USART0 itself,
// from its interrupt, so that no byte is lost while a step runs.
//
// Sign convention: read_position() in metres; a positive command must push the mass towards
// positive x. Check it before the first run (../../README.md, "Sign convention, and checking
// it before the first run").

#include <avr/interrupt.h>
#include <avr/io.h>

#include "board.h"
#include "phoid_fw.h"

#define CPU_HZ 16000000.0
#define LINK_UBRR 3 // 500000 baud with U2X0 at 16 MHz, exactly

// ---- FILL IN: the encoder and the amplifier ----------------------------------------------

static void hardware_init(void) {
  // FILL IN: the encoder (e.g. a quadrature decoder IC on a port, or pin-change interrupts
  // counting into a variable) and the command output (a DAC on SPI, or a PWM and its filter)
}

static phoid_real read_position(void) {
  return 0;  // FILL IN: the encoder's count times its metres per count, read now
}

static void write_command(phoid_real u) {
  (void)u;  // FILL IN: u in the amplifier's units (the force is command_gain * u N), now
}

// ---- the link (USART0) and the sample clock (Timer1) -------------------------------------

static phoid_fw fw;
static volatile unsigned char rx_ring[64];
static volatile unsigned char rx_head, rx_tail;
static volatile unsigned char in_tick;
static volatile unsigned long overruns;  // ticks that came while the last one still ran

ISR(USART0_RX_vect) {
  unsigned char c = UDR0;
  unsigned char next = (unsigned char)((rx_tail + 1u) & 63u);
  if (next != rx_head) {  // a full ring drops the byte: the frame's CRC then refuses it
    rx_ring[rx_tail] = c;
    rx_tail = next;
  }
}

// interrupts stay on during the step, so the link's bytes keep arriving
ISR(TIMER1_COMPA_vect, ISR_NOBLOCK) {
  if (in_tick) {  // the last step still runs: a sample would be lost, so the run stops
    overruns++;
    fw.abort_reason = -1;  // fault-host, value -1: the sample clock overran the step
    fw.abort_pending = 1;
    return;
  }
  in_tick = 1;
  write_command(phoid_fw_tick(&fw, read_position()));
  in_tick = 0;
}

int board_link_getc(void) {
  int c = -1;
  cli();
  if (rx_head != rx_tail) {
    c = rx_ring[rx_head];
    rx_head = (unsigned char)((rx_head + 1u) & 63u);
  }
  sei();
  return c;
}

void board_link_putc(unsigned char byte) {
  while (!(UCSR0A & (1 << UDRE0))) {
  }
  UDR0 = byte;
}

const char *board_configure(const phoid_config *cfg, const unsigned char sample_time_f8[8],
                            const unsigned char command_gain_f8[8]) {
  static const unsigned int prescale[5] = {1, 8, 64, 256, 1024};
  double T = cfg->sample_time;  // a 32-bit double: 24 bits, enough for the count below
  unsigned char i;
  (void)sample_time_f8;
  (void)command_gain_f8;
  for (i = 0; i < 5; i++) {
    double ticks = T * (CPU_HZ / prescale[i]);
    if (ticks <= 65536.0) {
      unsigned long n = (unsigned long)(ticks + 0.5);
      if (n < 100 || (double)n - ticks > 1e-6 * ticks || ticks - (double)n > 1e-6 * ticks) {
        return "sample_time: Timer1 cannot make this period in whole counts (within 1 ppm)";
      }
      cli();
      TCCR1A = 0;
      TCCR1B = (1 << WGM12) | (unsigned char)(i + 1);  // CTC; CS12..10 = the prescaler
      OCR1A = (unsigned int)(n - 1);
      TCNT1 = 0;
      TIMSK1 = 1 << OCIE1A;
      sei();
      return 0;
    }
  }
  return "sample_time: longer than Timer1 can count (4.19 s)";
}

void board_run_start(void) {}

void setup(void) {
  cli();
  UCSR0A = 1 << U2X0;
  UBRR0 = LINK_UBRR;
  UCSR0B = (1 << RXEN0) | (1 << TXEN0) | (1 << RXCIE0);
  UCSR0C = (1 << UCSZ01) | (1 << UCSZ00);  // 8N1
  TCCR1A = 0;
  TCCR1B = (1 << WGM12) | (1 << CS10);  // 1 kHz, command 0, until a CONFIG
  OCR1A = 15999;
  TIMSK1 = 1 << OCIE1A;
  hardware_init();
  phoid_fw_init(&fw);
  sei();
}

void loop(void) {
  int c;
  while ((c = board_link_getc()) >= 0) {
    phoid_fw_rx(&fw, (unsigned char)c);
  }
  phoid_fw_flush(&fw);
}
