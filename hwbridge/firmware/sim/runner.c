/*
 * hwbridge-simavr: run AVR firmware (an ELF or an Intel HEX) in simavr with UART0 on a
 * pseudo-terminal and devices on its pins, driven line by line from a controlling process
 * (hwbridge.firmware.sim).
 *
 *   hwbridge-simavr --mcu atmega328p --freq 16000000 [--speed 1.0] [--report-us 5000] [--hold]
 *                   [--bootloader BOOT.hex] [--trace-uart FILE] [--trace-pc FILE] [--hex] FIRMWARE
 *
 * FIRMWARE is an ELF, or with --hex an Intel HEX (whatever its name: the controlling process,
 * which knows the names of HEX files, says which).
 *
 * With --bootloader (an Intel HEX at the top of flash: Optiboot's 0x7E00 on the ATmega328P, the
 * stk500v2 bootloader's 0x3E000 on the ATmega2560) the CPU starts at the bootloader, as the
 * BOOTRST fuse makes it, and FIRMWARE (an ELF or an Intel HEX) is optional: the application
 * already in flash. An open of the pty resets the AVR with EXTRF set in MCUSR,
 * as an Uno's auto-reset does when the host opens the port (DTR falls): a pty has no modem lines
 * avrdude could toggle, so the open is what the runner sees (inotify). Flash written by the
 * bootloader (SPM) stays for the rest of the run: resets keep it.
 * stdout, one event per line (the first line is the UART's URL):
 *   serial:///dev/pts/N           UART0's pseudo-terminal
 *   t US PIN=DUTY ...             every report period: simulated time (us since power-on) and the
 *                                 share of that period each watched output pin was high (0..1)
 *   i2cw ADDR REG HEX             the firmware wrote bytes HEX from register REG of slave ADDR
 *   uart N HEX                    the firmware sent a packet on bus UART N; the AVR waits for
 *                                 "tx N ..." (see bus)
 *   reset                         the AVR was reset (watchdog, or the "reset" command)
 *   exit STATE                    the AVR stopped (crashed, or slept with interrupts off)
 *   mem ADDR HEX                  the answer to "peek": N bytes of data space from ADDR (hex)
 * stdin, one command per line (pins are port and bit: D2, B5):
 *   out PIN                       watch an output pin (its duty appears in the "t" lines)
 *   in PIN 0|1                    drive an input pin
 *   enc ID PINA PINB              a quadrature encoder (ID 0..7) on two input pins
 *   pos ID STEPS                  move encoder ID's disc to STEPS quadrature steps (edges), the
 *                                 edges spread over the next report period
 *   sonar ID TRIG ECHO            an HC-SR04: a trigger pulse on TRIG starts an echo on ECHO
 *   echo ID US                    the width of sonar ID's next echo pulses (0: none)
 *   i2c ADDR                      a register-file slave at 7-bit ADDR (hex) on the TWI bus
 *   reg ADDR REG HEX              set registers from REG of slave ADDR (hex bytes)
 *   go                            start the AVR (with --hold, commands before it set up devices)
 *   bus N                         a half-duplex bus on UART N (1..3): packets out, replies in
 *   tx N HEX|-                    the reply to the last packet on bus N (- for none)
 *   reset                         reset the AVR (as its reset pin does)
 *   peek ADDR N                   read N (1..64) bytes of data space (SRAM, registers) from ADDR
 *                                 (hex; an ELF symbol's address less 0x800000), between two
 *                                 instructions: answered by a "mem" line
 *   quit                          exit
 * --trace-uart FILE: every byte through UART0, stamped with the AVR's cycle count, one line each
 * way: "i CYCLE HEX" for what the runner read from the pty and handed to the UART at that cycle
 * (the UART delivers the bytes to the firmware one per byte time from then on), "o CYCLE XX" for
 * each byte the firmware wrote to the UART's data register (simavr puts it out then; the next
 * write waits a byte time). For benchmarks: where the
 * board's time goes in a round trip, in simulated time, whatever the host's load.
 * --trace-pc FILE: from each read of the pty that brought bytes to the next byte the firmware
 * writes to UART0 (a request and the start of its answer), every instruction as a 12-byte
 * record, little-endian: the cycle count before it (u64) and its byte address in flash (u32);
 * an instruction's cycles are the next record's count less its own. For profiling the board's
 * answer (tools/bench/sim_profile.py), not for long runs (some 2 MB per hundred requests).
 * Time: the simulation is held to the wall clock times --speed (0: as fast as it goes).
 * UART0's pty is the runner's own (not simavr's uart_pty part, whose thread polls every 500 us
 * of wall time and feeds the UART from outside the simulation's thread): the main loop moves
 * the bytes both ways every PTY_US of simulated time (see the pty section).
 */
#define _GNU_SOURCE
#include <errno.h>
#include <stdarg.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <poll.h>
#include <dirent.h>
#include <pthread.h>
#include <sys/inotify.h>
#include <unistd.h>

#include <avr_extint.h>
#include <avr_ioport.h>
#include <avr_twi.h>
#include <avr_uart.h>
#include <pty.h>
#include <termios.h>
#include <sim_avr.h>
#include <sim_elf.h>
#include <sim_hex.h>
#include <sim_irq.h>
#include <sim_time.h>

#define MAX_PINS 32
#define MAX_ENC 8
#define MAX_SONAR 4
#define MAX_I2C 4
/* The pacing quantum: every TICK_US of simulated time the runner sleeps off whatever the
   simulation gained on the wall clock past AHEAD_US. Between two sleeps the simulation runs
   several times faster than real time, so a request that reaches the pty while the runner
   sleeps waits for the next burst: up to a quantum more than a real board would take. With a
   1 ms quantum, as long as a service call at 1 Mbaud, a call's round trip depended on where it
   fell in the quantum, and two runners of one firmware answered 11 % apart over 600 calls
   (tools/bench/sim.py's service sketches); with 100 us they are within 1-3 %, for some 5 % more
   of a core. */
#define TICK_US 100
#define AHEAD_US 100
#define PTY_US 50

typedef struct pin_ref {
  char port;
  uint8_t bit;
} pin_ref;

typedef struct pwm_out pwm_out;
typedef struct watched_pin {
  pin_ref pin;
  const pwm_out *pwm;
  double pwm_sum;           // high cycles (or duty x cycles on the timer) this period
  avr_cycle_count_t pwm_at; // cycle of the last sample
  avr_irq_t *irq;
  int level;
  avr_cycle_count_t since;  // cycle of the last level change or report
  avr_cycle_count_t high;   // high cycles in this report period
} watched_pin;

typedef struct encoder {
  int used;
  pin_ref a, b;
  int64_t position, target;
  avr_cycle_count_t period;  // cycles between edges while catching up
  int running;
} encoder;

typedef struct sonar {
  int used;
  pin_ref trig, echo;
  avr_irq_t *trig_irq;
  uint32_t echo_us;
  avr_cycle_count_t trig_rise;
  int busy;
} sonar;

typedef struct i2c_slave {
  int used;
  uint8_t addr;
  uint8_t regs[256];
  int selected;
  int index;  // bytes written since START
  uint8_t reg;
  uint8_t written[64];
  int nwritten;
  uint8_t first_reg;
} i2c_slave;

static avr_t *avr;
static watched_pin watched[MAX_PINS];
static int nwatched;
static encoder encoders[MAX_ENC];
static sonar sonars[MAX_SONAR];
static i2c_slave slaves[MAX_I2C];
static avr_irq_t *twi_irq;
static uint8_t ext_mask[26], ext_value[26];
static double speed = 1.0;
static uint32_t report_us = 5000;
static avr_cycle_count_t last_report;
static struct timespec wall_start;
static avr_cycle_count_t cycle_start;
static char inbuf[8192];
static size_t inlen;
static int want_reset, want_quit, want_go;
static int boot_mode;        // --bootloader: resets set EXTRF, opens of the pty reset
static int open_watch = -1;  // inotify on the pty's slave: opens and closes
static int open_wake[2] = {-1, -1};  // the watcher's self-pipe: wait_for_reset polls it
static volatile int open_seen;       // set by the watcher thread, taken by the main loop

static void out_line(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
static void out_line(const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  vprintf(fmt, ap);
  va_end(ap);
  fflush(stdout);
}

static void quiet_logger(avr_t *a, const int level, const char *format, va_list ap) {
  (void)a;
  if (level <= LOG_WARNING) vfprintf(stderr, format, ap);
}

static int parse_pin(const char *s, pin_ref *p) {
  if (!s || strlen(s) != 2 || s[0] < 'A' || s[0] > 'L' || s[1] < '0' || s[1] > '7') return -1;
  p->port = s[0];
  p->bit = (uint8_t)(s[1] - '0');
  return 0;
}

static avr_irq_t *pin_irq(pin_ref p) {
  return avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(p.port), p.bit);
}

/* Drive an input pin from outside: the port's "external" value keeps PORT writes (pull-ups)
   from overriding it, and raising the pin's IRQ updates PIN and fires INTn/PCINT. */
static void drive(pin_ref p, int level) {
  int i = p.port - 'A';
  ext_mask[i] |= (uint8_t)(1u << p.bit);
  if (level)
    ext_value[i] |= (uint8_t)(1u << p.bit);
  else
    ext_value[i] &= (uint8_t)~(1u << p.bit);
  avr_ioport_external_t e;
  e.name = (unsigned long)p.port;
  e.mask = ext_mask[i];
  e.value = ext_value[i];
  avr_ioctl(avr, AVR_IOCTL_IOPORT_SET_EXTERNAL(p.port), &e);
  avr_raise_irq(pin_irq(p), level ? 1 : 0);
}

static void reapply_inputs(void) {
  for (int i = 0; i < 26; i++)
    for (int b = 0; b < 8; b++)
      if (ext_mask[i] & (1u << b)) {
        pin_ref p = {(char)('A' + i), (uint8_t)b};
        drive(p, (ext_value[i] >> b) & 1);
      }
}

/* ------------------------------------------------------------------ watched outputs */
/* Timer outputs: simavr 1.6 drives an OCnx pin in some waveform modes only (not, for one, the
   phase-correct PWM Arduino sets up on timer 1), so while a pin's COM bits connect it to its
   timer, its duty is taken from the timer's registers: OCR / TOP. */
typedef struct pwm_out {
  char port;
  uint8_t bit;
  uint16_t tccra;  // TCCRnA; TCCRnB follows it, ICRn is at +6 on 16-bit timers
  uint8_t channel; // 0 A, 1 B, 2 C
  uint16_t ocr;    // OCRnx (low byte)
  uint8_t wide;    // a 16-bit timer
} pwm_out;

static const pwm_out pwm_328p[] = {
    {'D', 6, 0x44, 0, 0x47, 0}, {'D', 5, 0x44, 1, 0x48, 0}, {'B', 1, 0x80, 0, 0x88, 1},
    {'B', 2, 0x80, 1, 0x8A, 1}, {'B', 3, 0xB0, 0, 0xB3, 0}, {'D', 3, 0xB0, 1, 0xB4, 0},
    {0, 0, 0, 0, 0, 0}};
static const pwm_out pwm_2560[] = {
    {'B', 7, 0x44, 0, 0x47, 0},  {'G', 5, 0x44, 1, 0x48, 0},  {'B', 5, 0x80, 0, 0x88, 1},
    {'B', 6, 0x80, 1, 0x8A, 1},  {'B', 4, 0xB0, 0, 0xB3, 0},  {'H', 6, 0xB0, 1, 0xB4, 0},
    {'E', 3, 0x90, 0, 0x98, 1},  {'E', 4, 0x90, 1, 0x9A, 1},  {'E', 5, 0x90, 2, 0x9C, 1},
    {'H', 3, 0xA0, 0, 0xA8, 1},  {'H', 4, 0xA0, 1, 0xAA, 1},  {'H', 5, 0xA0, 2, 0xAC, 1},
    {'L', 3, 0x120, 0, 0x128, 1}, {'L', 4, 0x120, 1, 0x12A, 1}, {'L', 5, 0x120, 2, 0x12C, 1},
    {0, 0, 0, 0, 0, 0}};
static const pwm_out *pwm_table = pwm_328p;

static const pwm_out *pwm_of(pin_ref p) {
  for (const pwm_out *o = pwm_table; o->port; o++)
    if (o->port == p.port && o->bit == p.bit) return o;
  return NULL;
}

static uint16_t reg16(uint16_t addr) {
  return (uint16_t)(avr->data[addr] | (avr->data[addr + 1] << 8));
}

/* The duty a connected timer output gives, or -1 when the pin is not connected to its timer. */
static double pwm_duty(const pwm_out *o) {
  uint8_t a = avr->data[o->tccra], b = avr->data[o->tccra + 1];
  uint8_t com = (uint8_t)((a >> (6 - 2 * o->channel)) & 3);
  if (com == 0) return -1;
  if (com == 1) return 0.5;  // toggling on compare match
  double top, ocr;
  if (o->wide) {
    uint8_t wgm = (uint8_t)((a & 3) | (((b >> 3) & 3) << 2));
    switch (wgm) {
      case 1: case 5: top = 0xFF; break;
      case 2: case 6: top = 0x1FF; break;
      case 3: case 7: top = 0x3FF; break;
      case 8: case 10: case 12: case 14: top = reg16((uint16_t)(o->tccra + 6)); break;
      case 9: case 11: case 15: top = reg16((uint16_t)(o->ocr - 2 * o->channel)); break;
      default: top = 0xFFFF; break;
    }
    ocr = reg16(o->ocr);
  } else {
    uint8_t wgm = (uint8_t)((a & 3) | (((b >> 3) & 1) << 2));
    top = (wgm == 5 || wgm == 7) ? avr->data[o->ocr - o->channel] : 0xFF;
    ocr = avr->data[o->ocr];
  }
  double duty = top > 0 ? ocr / top : 0;
  if (duty > 1) duty = 1;
  return com == 3 ? 1 - duty : duty;
}

static void watched_hook(avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq;
  watched_pin *w = (watched_pin *)param;
  int level = (value & 0xff) != 0;
  if (level == w->level) return;
  if (w->level) w->high += avr->cycle - w->since;
  w->since = avr->cycle;
  w->level = level;
}

static void watch(pin_ref p) {
  if (nwatched >= MAX_PINS) return;
  watched_pin *w = &watched[nwatched++];
  w->pin = p;
  w->pwm = pwm_of(p);
  w->pwm_sum = 0;
  w->pwm_at = avr->cycle;
  w->irq = pin_irq(p);
  w->level = (int)(w->irq->value & 0xff) != 0;
  w->since = avr->cycle;
  w->high = 0;
  avr_irq_register_notify(w->irq, watched_hook, w);
}

/* ------------------------------------------------------------------ encoders */
static const uint8_t quad_a[4] = {0, 1, 1, 0};
static const uint8_t quad_b[4] = {0, 0, 1, 1};

static void encoder_levels(encoder *e) {
  int phase = (int)(((e->position % 4) + 4) % 4);
  drive(e->a, quad_a[phase]);
  drive(e->b, quad_b[phase]);
}

static avr_cycle_count_t encoder_step(avr_t *a, avr_cycle_count_t when, void *param) {
  (void)a;
  encoder *e = (encoder *)param;
  if (e->position == e->target) {
    e->running = 0;
    return 0;
  }
  e->position += e->target > e->position ? 1 : -1;
  encoder_levels(e);
  if (e->position == e->target) {
    e->running = 0;
    return 0;
  }
  return when + e->period;
}

static void encoder_move(encoder *e, int64_t target) {
  e->target = target;
  int64_t steps = target > e->position ? target - e->position : e->position - target;
  if (steps == 0) return;
  avr_cycle_count_t span = avr_usec_to_cycles(avr, report_us);
  avr_cycle_count_t period = span / (avr_cycle_count_t)steps;
  avr_cycle_count_t shortest = avr_usec_to_cycles(avr, 4);
  e->period = period < shortest ? shortest : period;
  if (!e->running) {
    e->running = 1;
    avr_cycle_timer_register(avr, e->period, encoder_step, e);
  }
}

/* ------------------------------------------------------------------ sonar */
static avr_cycle_count_t sonar_echo_end(avr_t *a, avr_cycle_count_t when, void *param) {
  (void)a;
  (void)when;
  sonar *s = (sonar *)param;
  drive(s->echo, 0);
  s->busy = 0;
  return 0;
}

static avr_cycle_count_t sonar_echo_start(avr_t *a, avr_cycle_count_t when, void *param) {
  (void)a;
  (void)when;
  sonar *s = (sonar *)param;
  if (s->echo_us == 0) {
    s->busy = 0;
    return 0;
  }
  drive(s->echo, 1);
  avr_cycle_timer_register_usec(avr, s->echo_us, sonar_echo_end, s);
  return 0;
}

static void sonar_trig_hook(avr_irq_t *irq, uint32_t value, void *param) {
  sonar *s = (sonar *)param;
  int level = (value & 0xff) != 0;
  int was = (irq->value & 0xff) != 0;
  if (level && !was) {
    s->trig_rise = avr->cycle;
  } else if (!level && was && !s->busy) {
    // The module wants a pulse of 10 us; it then sends its burst (8 cycles at 40 kHz) and
    // raises the echo line about 0.5 ms after the trigger's fall.
    if (avr->cycle - s->trig_rise >= avr_usec_to_cycles(avr, 8)) {
      s->busy = 1;
      avr_cycle_timer_register_usec(avr, 460, sonar_echo_start, s);
    }
  }
}

/* ------------------------------------------------------------------ I2C register files */
static void flush_i2c_write(i2c_slave *s) {
  if (s->nwritten == 0) return;
  char hex[2 * 64 + 1];
  for (int i = 0; i < s->nwritten; i++) snprintf(hex + 2 * i, 3, "%02x", s->written[i]);
  out_line("i2cw %02x %02x %s\n", s->addr, s->first_reg, hex);
  s->nwritten = 0;
}

static void twi_hook(avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq;
  (void)param;
  avr_twi_msg_irq_t v;
  v.u.v = value;
  for (int k = 0; k < MAX_I2C; k++) {
    i2c_slave *s = &slaves[k];
    if (!s->used) continue;
    if (v.u.twi.msg & TWI_COND_STOP) {
      if (s->selected) flush_i2c_write(s);
      s->selected = 0;
    }
    if (v.u.twi.msg & TWI_COND_START) {
      if (s->selected) flush_i2c_write(s);
      s->selected = 0;
      s->index = 0;
      if ((v.u.twi.addr >> 1) == s->addr) {
        s->selected = v.u.twi.addr;
        avr_raise_irq(twi_irq, avr_twi_irq_msg(TWI_COND_ACK, (uint8_t)s->selected, 1));
      }
    }
    if (!s->selected) continue;
    if (v.u.twi.msg & TWI_COND_WRITE) {
      avr_raise_irq(twi_irq, avr_twi_irq_msg(TWI_COND_ACK, (uint8_t)s->selected, 1));
      if (s->index == 0) {
        s->reg = v.u.twi.data;
        s->first_reg = s->reg;
      } else {
        if (s->nwritten == (int)sizeof s->written) {
          flush_i2c_write(s);
          s->first_reg = s->reg;
        }
        s->written[s->nwritten++] = v.u.twi.data;
        s->regs[s->reg] = v.u.twi.data;
        s->reg++;
      }
      s->index++;
    }
    if (v.u.twi.msg & TWI_COND_READ) {
      uint8_t data = s->regs[s->reg];
      avr_raise_irq(twi_irq, avr_twi_irq_msg(TWI_COND_READ, (uint8_t)s->selected, data));
      s->reg++;
    }
  }
}

static int hexbytes(const char *hex, uint8_t *out, int cap) {
  int n = 0;
  size_t len = strlen(hex);
  if (len % 2) return -1;
  for (size_t i = 0; i < len && n < cap; i += 2) {
    unsigned int b;
    if (sscanf(hex + i, "%2x", &b) != 1) return -1;
    out[n++] = (uint8_t)b;
  }
  return n;
}

/* ------------------------------------------------------------------ a bus on a second UART */
/* What the firmware sends on UARTn (n = 1..3) is collected; once the line has been quiet for
   two byte times the packet goes out as "uart N HEX" and the simulation waits, taking commands,
   until the controlling process answers "tx N HEX" (the devices' reply, put into the UART's
   receive FIFO at the byte rate by simavr) or "tx N -" (no reply). A Dynamixel bus is
   half-duplex: the firmware sends, then listens; holding the AVR while the host's model
   answers keeps the firmware's reply timeouts honest whatever the host's scheduling. */
#define MAX_BUS 4
typedef struct uart_bus {
  int used;
  char name;
  uint8_t packet[512];
  int len;
  avr_cycle_count_t last;
  avr_irq_t *input;
} uart_bus;
static uart_bus buses[MAX_BUS];
static int bus_waiting;  // the simulation holds until the controlling process answers

static void bus_out_hook(avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq;
  uart_bus *b = (uart_bus *)param;
  if (b->len < (int)sizeof b->packet) b->packet[b->len++] = (uint8_t)value;
  b->last = avr->cycle;
}

static void command(char *line);

/* Take commands (blocking) until *flag is cleared by one of them. */
static void read_blocking_until(int *flag) {
  fcntl(0, F_SETFL, fcntl(0, F_GETFL) & ~O_NONBLOCK);
  while (*flag && !want_quit) {
    char *nl = memchr(inbuf, '\n', inlen);
    if (nl) {
      static char line[sizeof inbuf];
      size_t used = (size_t)(nl - inbuf) + 1;
      memcpy(line, inbuf, used - 1);
      line[used - 1] = 0;
      inlen -= used;
      memmove(inbuf, inbuf + used, inlen);
      command(line);
      continue;
    }
    ssize_t n = read(0, inbuf + inlen, sizeof inbuf - 1 - inlen);
    if (n <= 0) {
      want_quit = 1;
      break;
    }
    inlen += (size_t)n;
  }
  fcntl(0, F_SETFL, fcntl(0, F_GETFL) | O_NONBLOCK);
}

static void flush_buses(void) {
  for (int i = 0; i < MAX_BUS; i++) {
    uart_bus *b = &buses[i];
    if (!b->used || b->len == 0) continue;
    if (avr->cycle - b->last < avr_usec_to_cycles(avr, 400)) continue;  // still sending
    static char hex[2 * 512 + 1];
    for (int k = 0; k < b->len; k++) snprintf(hex + 2 * k, 3, "%02x", b->packet[k]);
    b->len = 0;
    out_line("uart %c %s\n", b->name, hex);
    bus_waiting = 1;
    read_blocking_until(&bus_waiting);
  }
}

static void bus_setup(char name) {
  for (int i = 0; i < MAX_BUS; i++) {
    uart_bus *b = &buses[i];
    if (b->used) continue;
    b->used = 1;
    b->name = name;
    b->input = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ(name), UART_IRQ_INPUT);
    avr_irq_t *output = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ(name), UART_IRQ_OUTPUT);
    if (!b->input || !output) {
      fprintf(stderr, "hwbridge-simavr: this MCU has no UART%c\n", name);
      b->used = 0;
      return;
    }
    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS(name), &flags);
    flags &= ~(uint32_t)AVR_UART_FLAG_STDIO;
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS(name), &flags);
    avr_irq_register_notify(output, bus_out_hook, b);
    return;
  }
}

static void bus_reply(char name, const char *hex) {
  for (int i = 0; i < MAX_BUS; i++) {
    uart_bus *b = &buses[i];
    if (!b->used || b->name != name) continue;
    if (strcmp(hex, "-") != 0) {
      uint8_t bytes[512];
      int n = hexbytes(hex, bytes, (int)sizeof bytes);
      for (int k = 0; k < n; k++) avr_raise_irq(b->input, bytes[k]);
    }
  }
  bus_waiting = 0;
}

/* ------------------------------------------------------------------ commands */
static void command(char *line) {
  char *argv[8];
  int argc = 0;
  for (char *tok = strtok(line, " \t\r"); tok && argc < 8; tok = strtok(NULL, " \t\r"))
    argv[argc++] = tok;
  if (argc == 0) return;
  pin_ref p, q;
  const char *c = argv[0];
  if (!strcmp(c, "out") && argc == 2 && !parse_pin(argv[1], &p)) {
    watch(p);
  } else if (!strcmp(c, "in") && argc == 3 && !parse_pin(argv[1], &p)) {
    drive(p, atoi(argv[2]));
  } else if (!strcmp(c, "enc") && argc == 4 && !parse_pin(argv[2], &p) && !parse_pin(argv[3], &q)) {
    int id = atoi(argv[1]);
    if (id < 0 || id >= MAX_ENC) return;
    encoder *e = &encoders[id];
    e->used = 1;
    e->a = p;
    e->b = q;
    encoder_levels(e);
  } else if (!strcmp(c, "pos") && argc == 3) {
    int id = atoi(argv[1]);
    if (id < 0 || id >= MAX_ENC || !encoders[id].used) return;
    encoder_move(&encoders[id], strtoll(argv[2], NULL, 10));
  } else if (!strcmp(c, "sonar") && argc == 4 && !parse_pin(argv[2], &p) &&
             !parse_pin(argv[3], &q)) {
    int id = atoi(argv[1]);
    if (id < 0 || id >= MAX_SONAR) return;
    sonar *s = &sonars[id];
    s->used = 1;
    s->trig = p;
    s->echo = q;
    s->trig_irq = pin_irq(p);
    drive(q, 0);
    avr_irq_register_notify(s->trig_irq, sonar_trig_hook, s);
  } else if (!strcmp(c, "echo") && argc == 3) {
    int id = atoi(argv[1]);
    if (id < 0 || id >= MAX_SONAR) return;
    sonars[id].echo_us = (uint32_t)strtoul(argv[2], NULL, 10);
  } else if (!strcmp(c, "i2c") && argc == 2) {
    for (int k = 0; k < MAX_I2C; k++)
      if (!slaves[k].used) {
        slaves[k].used = 1;
        slaves[k].addr = (uint8_t)strtoul(argv[1], NULL, 16);
        break;
      }
  } else if (!strcmp(c, "reg") && argc == 4) {
    uint8_t addr = (uint8_t)strtoul(argv[1], NULL, 16);
    unsigned reg = (unsigned)strtoul(argv[2], NULL, 16);
    for (int k = 0; k < MAX_I2C; k++)
      if (slaves[k].used && slaves[k].addr == addr) {
        uint8_t bytes[256];
        int n = hexbytes(argv[3], bytes, 256);
        for (int i = 0; i < n; i++) slaves[k].regs[(reg + (unsigned)i) & 0xff] = bytes[i];
      }
  } else if (!strcmp(c, "bus") && argc == 2 && argv[1][0] >= '1' && argv[1][0] <= '3') {
    bus_setup(argv[1][0]);
  } else if (!strcmp(c, "tx") && argc == 3) {
    bus_reply(argv[1][0], argv[2]);
  } else if (!strcmp(c, "go")) {
    want_go = 1;
  } else if (!strcmp(c, "reset")) {
    want_reset = 1;
  } else if (!strcmp(c, "peek") && argc == 3) {
    unsigned long addr = strtoul(argv[1], NULL, 16);
    long n = strtol(argv[2], NULL, 10);
    if (!avr || n < 1 || n > 64 || addr + (unsigned long)n > (unsigned long)avr->ramend + 1) {
      fprintf(stderr, "hwbridge-simavr: peek %s %s: outside the data space\n", argv[1], argv[2]);
      out_line("mem %lx -\n", addr);
      return;
    }
    char hex[2 * 64 + 1];
    for (long i = 0; i < n; i++) snprintf(hex + 2 * i, 3, "%02x", avr->data[addr + (unsigned long)i]);
    out_line("mem %lx %s\n", addr, hex);
  } else if (!strcmp(c, "quit")) {
    want_quit = 1;
  } else {
    fprintf(stderr, "hwbridge-simavr: bad command: %s\n", argv[0]);
  }
}

static void read_commands(void) {
  for (;;) {
    ssize_t n = read(0, inbuf + inlen, sizeof inbuf - 1 - inlen);
    if (n == 0) {
      want_quit = 1;  // the controlling process went away
      return;
    }
    if (n < 0) return;  // EAGAIN: nothing more now
    inlen += (size_t)n;
    char *start = inbuf;
    char *nl;
    while ((nl = memchr(start, '\n', inlen - (size_t)(start - inbuf))) != NULL) {
      *nl = 0;
      command(start);
      start = nl + 1;
    }
    inlen -= (size_t)(start - inbuf);
    memmove(inbuf, start, inlen);
    if (inlen == sizeof inbuf - 1) inlen = 0;  // a line too long: dropped
  }
}

/* ------------------------------------------------------------------ UART0's pty */
/* The runner's end of UART0: the pty's master, non-blocking, in the simulation's own thread.
   What the firmware transmits is collected as the UART sends it and written to the master
   every PTY_US of simulated time (a byte at 1 Mbaud takes 10 us); the host's bytes are read
   at the same moments and handed to the UART while its receive FIFO has room (simavr raises
   XOFF when it is full and XON when there is room again), the rest kept for the next time.
   The slave stays open here too, so the master never reads a hang-up between two openers
   (and what the firmware sends meanwhile waits in the pty, as it did with simavr's uart_pty,
   until the pty and then this buffer are full: then it is dropped, as on a line with nobody
   listening). */
typedef struct pty_port {
  int master, slave;
  char slavename[64];
  avr_irq_t *to_uart;   // our output irq, connected to the UART's input
  int xon;              // the UART's receive FIFO has room
  uint8_t in[256];      // read from the host, not yet taken by the UART
  size_t in_len, in_done;
  uint8_t out[4096];    // sent by the firmware, not yet written to the host
  size_t out_len;
} pty_port;
static pty_port uart;

static FILE *uart_trace;  // --trace-uart
static FILE *pc_trace;    // --trace-pc
static int pc_window;     // --trace-pc: between a read of the pty and the next byte out

static void uart_byte_out(avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq;
  (void)param;
  if (uart_trace) fprintf(uart_trace, "o %llu %02x\n", (unsigned long long)avr->cycle, value & 0xFFu);
  if (pc_window) fflush(pc_trace);  // each window whole on disk, whenever the runner is stopped
  pc_window = 0;
  if (uart.out_len < sizeof uart.out) uart.out[uart.out_len++] = (uint8_t)value;
}

static void uart_xon(avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq;
  (void)value;
  (void)param;
  uart.xon = 1;
}

static void uart_xoff(avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq;
  (void)value;
  (void)param;
  uart.xon = 0;
}

static void pty_write_out(void) {
  size_t done = 0;
  while (done < uart.out_len) {
    ssize_t n = write(uart.master, uart.out + done, uart.out_len - done);
    if (n > 0) {
      done += (size_t)n;
    } else if (n < 0 && errno == EINTR) {
      continue;
    } else {
      break;  // the pty is full (nobody reads): keep the rest while there is room
    }
  }
  memmove(uart.out, uart.out + done, uart.out_len - done);
  uart.out_len -= done;
}

static void pty_feed_in(void) {
  if (uart.in_done == uart.in_len) {
    ssize_t n = read(uart.master, uart.in, sizeof uart.in);
    uart.in_len = n > 0 ? (size_t)n : 0;
    uart.in_done = 0;
    if (n > 0) pc_window = pc_trace != NULL;
    if (uart_trace && n > 0) {
      fprintf(uart_trace, "i %llu ", (unsigned long long)avr->cycle);
      for (ssize_t k = 0; k < n; k++) fprintf(uart_trace, "%02x", uart.in[k]);
      fputc('\n', uart_trace);
    }
  }
  // simavr's UART raises XOFF from inside this irq once its FIFO is full.
  while (uart.xon && uart.in_done < uart.in_len) avr_raise_irq(uart.to_uart, uart.in[uart.in_done++]);
}

static avr_cycle_count_t pty_timer(avr_t *a, avr_cycle_count_t when, void *param) {
  (void)a;
  (void)param;
  if (uart.out_len) pty_write_out();
  pty_feed_in();
  return when + avr_usec_to_cycles(avr, PTY_US);
}

/* A reset loses what the host sent before it, as a board held in reset does. */
static void pty_drop_input(void) {
  uint8_t drain[256];
  uart.in_len = uart.in_done = 0;
  while (read(uart.master, drain, sizeof drain) > 0) {
  }
}

static int pty_open(void) {
  if (openpty(&uart.master, &uart.slave, uart.slavename, NULL, NULL) < 0) {
    fprintf(stderr, "hwbridge-simavr: cannot make a pty: %s\n", strerror(errno));
    return -1;
  }
  struct termios tio;
  tcgetattr(uart.master, &tio);
  cfmakeraw(&tio);
  tcsetattr(uart.master, TCSANOW, &tio);
  fcntl(uart.master, F_SETFL, fcntl(uart.master, F_GETFL) | O_NONBLOCK);
  fcntl(uart.master, F_SETFD, FD_CLOEXEC);
  fcntl(uart.slave, F_SETFD, FD_CLOEXEC);
  uint32_t flags = 0;
  avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
  // No stdio dump of the bytes; and no sleep at each read of UCSR0A with RXC and TXC clear
  // (simavr's way of sparing the CPU of a polling firmware): that usleep(1) costs tens of
  // microseconds of wall time, more on a busy machine, for a fraction of one of simulated
  // time. The Arduino core reads UCSR0A on every Serial.write() into an empty ring, and the
  // Mega's stk500v2 bootloader in its receive loop (it fell minutes behind avrdude's
  // timeouts). The runner paces the simulation to real time by itself (tick).
  flags &= ~(uint32_t)(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);
  avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
  static const char *names[1] = {"8>pty.out"};
  uart.to_uart = avr_alloc_irq(&avr->irq_pool, 0, 1, names);
  avr_connect_irq(uart.to_uart, avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT));
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                          uart_byte_out, NULL);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON),
                          uart_xon, NULL);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF),
                          uart_xoff, NULL);
  uart.xon = 1;
  return 0;
}

/* ------------------------------------------------------------------ bootloader mode */
/* The auto-reset of an Uno: opening its port pulls DTR and resets the AVR at once, before the
   host can send a byte. A pty has no DTR, so a thread waits on inotify for opens of the slave
   and raises open_seen the moment one happens; the main loop looks at it after every
   instruction. Looking only in the pacing tick (1 ms then) was not enough on a busy machine:
   with the runner descheduled for longer than avrdude's 300 ms pause after the open, its first
   bytes reached the bootloader that was running before the reset, which then cut the exchange
   in the middle ("protocol expects OK byte 0x10 but got 0x04"). */
static char watched_slave[64];

#define MAX_HOLDERS 16

/* The other processes that have the pty's slave open now (from /proc/PID/fd): up to
   MAX_HOLDERS of their pids into held[]; returns how many. */
static int slave_holders(pid_t held[MAX_HOLDERS]) {
  DIR *procs = opendir("/proc");
  if (procs == NULL) return 0;
  int count = 0;
  pid_t self = getpid();
  struct dirent *p;
  while (count < MAX_HOLDERS && (p = readdir(procs)) != NULL) {
    char *end;
    long pid = strtol(p->d_name, &end, 10);
    if (*end != '\0' || pid <= 0 || pid == self) continue;
    char fds[64];
    snprintf(fds, sizeof fds, "/proc/%ld/fd", pid);
    DIR *dir = opendir(fds);
    if (dir == NULL) continue;
    struct dirent *f;
    while ((f = readdir(dir)) != NULL) {
      char link[384], target[64];
      snprintf(link, sizeof link, "%s/%s", fds, f->d_name);
      ssize_t n = readlink(link, target, sizeof target - 1);
      if (n <= 0) continue;
      target[n] = '\0';
      if (strcmp(target, watched_slave) == 0) {
        held[count++] = (pid_t)pid;
        break;
      }
    }
    closedir(dir);
  }
  closedir(procs);
  return count;
}

/* Whether a process of before[] still holds the slave in now[]: the port was open all along. */
static int held_throughout(const pid_t *before, int nb, const pid_t *now, int nn) {
  for (int i = 0; i < nb; i++)
    for (int j = 0; j < nn; j++)
      if (before[i] == now[j]) return 1;
  return 0;
}

/* DTR follows the port, not each open: a second process opening a port that another one holds
   leaves DTR asserted, so it does not reset a real board (a busy check of the port a bridge
   holds must not restart the board under it). So an open resets the AVR only when no process
   that held the slave at the previous look still holds it; every open and close updates the
   look (inotify may merge repeated events: the holders are read, not counted). */
static void *watch_opens(void *arg) {
  (void)arg;
  char events[4096] __attribute__((aligned(__alignof__(struct inotify_event))));
  pid_t before[MAX_HOLDERS], now[MAX_HOLDERS];
  int nbefore = slave_holders(before);
  for (;;) {
    ssize_t n = read(open_watch, events, sizeof events);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return NULL;
    for (char *at = events; at < events + n;) {
      const struct inotify_event *e = (const struct inotify_event *)at;
      int nnow = slave_holders(now);
      if ((e->mask & IN_OPEN) && !held_throughout(before, nbefore, now, nnow)) {
        __atomic_store_n(&open_seen, 1, __ATOMIC_RELEASE);
        ssize_t w = write(open_wake[1], "o", 1);  // a full pipe has a wake-up pending already
        (void)w;
      }
      memcpy(before, now, sizeof now[0] * (size_t)nnow);
      nbefore = nnow;
      at += sizeof *e + e->len;
    }
  }
}

static void start_open_watch(const char *slave) {
  pthread_t thread;
  snprintf(watched_slave, sizeof watched_slave, "%s", slave);
  open_watch = inotify_init1(IN_CLOEXEC);
  if (open_watch < 0 || inotify_add_watch(open_watch, slave, IN_OPEN | IN_CLOSE) < 0 ||
      pipe2(open_wake, O_NONBLOCK | O_CLOEXEC) < 0 ||
      pthread_create(&thread, NULL, watch_opens, NULL) != 0) {
    fprintf(stderr, "hwbridge-simavr: cannot watch %s for opens: %s\n", slave, strerror(errno));
    return;
  }
  pthread_detach(thread);
}

/* Whether the host opened the pty since the last look. */
static int pty_opened(void) {
  if (!__atomic_load_n(&open_seen, __ATOMIC_RELAXED)) return 0;
  __atomic_store_n(&open_seen, 0, __ATOMIC_RELAXED);
  char drain[64];
  while (read(open_wake[0], drain, sizeof drain) > 0) {
  }
  return 1;
}

/* Copy an Intel HEX file into flash; the lowest address loaded goes to *lowest. */
static int load_hex(const char *path, uint32_t *lowest) {
  ihex_chunk_p chunks = NULL;
  int n = read_ihex_chunks(path, &chunks);
  if (n <= 0) {
    fprintf(stderr, "hwbridge-simavr: cannot read the Intel HEX file %s\n", path);
    return -1;
  }
  uint32_t low = avr->flashend + 1;
  for (int i = 0; i < n; i++) {
    uint32_t base = chunks[i].baseaddr, size = chunks[i].size;
    if (base + size > avr->flashend + 1) {
      fprintf(stderr,
              "hwbridge-simavr: %s has bytes at 0x%04x..0x%04x, past the end of flash (0x%04x)\n",
              path, base, base + size - 1, avr->flashend);
      free_ihex_chunks(chunks);
      return -1;
    }
    memcpy(avr->flash + base, chunks[i].data, size);
    if (size && base < low) low = base;
  }
  free_ihex_chunks(chunks);
  *lowest = low;
  return 0;
}

static void external_reset(void) {
  pty_drop_input();
  avr_reset(avr);
  if (boot_mode) avr_regbit_set(avr, avr->reset_flags.extrf);
}

/* The AVR stopped (blank flash, a crashed application): like a hung board, it waits for its
   reset, an open of the pty (the next upload) or the "reset" command. */
static void wait_for_reset(void) {
  while (!want_reset && !want_quit) {
    struct pollfd fds[2] = {{.fd = 0, .events = POLLIN}, {.fd = open_wake[0], .events = POLLIN}};
    if (poll(fds, 2, -1) < 0 && errno != EINTR) {
      want_quit = 1;
      break;
    }
    if (fds[0].revents) read_commands();
    if (pty_opened()) want_reset = 1;
  }
}

/* ------------------------------------------------------------------ the tick */
static double wall_seconds(void) {
  struct timespec now;
  clock_gettime(CLOCK_MONOTONIC, &now);
  return (double)(now.tv_sec - wall_start.tv_sec) + 1e-9 * (double)(now.tv_nsec - wall_start.tv_nsec);
}

/* Every tick closes an interval of each watched pin: a pin connected to its timer counts the
   timer's duty over it, any other pin the time it was high. */
static void sample_pins(void) {
  for (int i = 0; i < nwatched; i++) {
    watched_pin *w = &watched[i];
    if (w->level) w->high += avr->cycle - w->since;
    w->since = avr->cycle;
    avr_cycle_count_t span = avr->cycle - w->pwm_at;
    w->pwm_at = avr->cycle;
    double duty = w->pwm ? pwm_duty(w->pwm) : -1;
    w->pwm_sum += duty >= 0 ? duty * (double)span : (double)w->high;
    w->high = 0;
  }
}

static void report(void) {
  static char line[64 * MAX_PINS];
  avr_cycle_count_t span = avr->cycle - last_report;
  int n = snprintf(line, sizeof line, "t %llu",
                   (unsigned long long)(avr->cycle * 1000000ULL / avr->frequency));
  sample_pins();
  for (int i = 0; i < nwatched; i++) {
    watched_pin *w = &watched[i];
    double duty = span ? w->pwm_sum / (double)span : (double)w->level;
    if (duty > 1) duty = 1;
    w->pwm_sum = 0;
    n += snprintf(line + n, sizeof line - (size_t)n, " %c%u=%.4f", w->pin.port, w->pin.bit, duty);
  }
  last_report = avr->cycle;
  out_line("%s\n", line);
}

static avr_cycle_count_t tick(avr_t *a, avr_cycle_count_t when, void *param) {
  (void)a;
  (void)param;
  read_commands();
  if (pty_opened()) want_reset = 1;
  flush_buses();
  if (avr->cycle - last_report >= avr_usec_to_cycles(avr, report_us))
    report();
  else
    sample_pins();
  if (speed > 0) {
    double sim = (double)(avr->cycle - cycle_start) / (double)avr->frequency / speed;
    double wall = wall_seconds();
    double ahead = sim - wall;
    if (ahead > AHEAD_US * 1e-6) {
      // What the firmware sent goes out now, not after the pause (the host waits for it).
      if (uart.out_len) pty_write_out();
      usleep((useconds_t)(ahead * 1e6));
    }
    // A board that answers late looks broken to peers with wall-clock timeouts (avrdude
    // drains for 250 ms between its sync attempts): say so when the machine holds us back.
    static double warned_at = -10.0;
    if (ahead < -0.25 && wall - warned_at > 5.0) {
      warned_at = wall;
      fprintf(stderr,
              "hwbridge-simavr: the simulation runs %.2f s behind real time (the machine is "
              "busy): peers with timeouts, such as avrdude, may see a slow board\n",
              -ahead);
    }
  }
  return when + avr_usec_to_cycles(avr, TICK_US);
}

static void start_timers(void) {
  // simavr 1.6 polls a low INTn pin every cycle while ISCn selects "low level", and keeps
  // polling (and raising INTn) after the firmware switched to edges: level triggering then
  // acts as a falling edge instead, which no Arduino sketch tells apart.
  for (uint8_t i = 0; i < 8; i++) avr_extint_set_strict_lvl_trig(avr, i, 0);
  avr_cycle_timer_register_usec(avr, TICK_US, tick, NULL);
  avr_cycle_timer_register_usec(avr, PTY_US, pty_timer, NULL);
  for (int i = 0; i < MAX_ENC; i++) encoders[i].running = 0;
  for (int i = 0; i < MAX_ENC; i++)
    if (encoders[i].used) encoder_move(&encoders[i], encoders[i].target);
  for (int i = 0; i < MAX_SONAR; i++) sonars[i].busy = 0;
}

static void usage(void) {
  fprintf(stderr,
          "usage: hwbridge-simavr [--mcu atmega328p] [--freq 16000000] [--speed 1.0] "
          "[--report-us 5000] [--hold] [--bootloader BOOT.hex] [--trace-uart FILE] "
          "[--trace-pc FILE] [--hex] FIRMWARE (an ELF; with --hex an Intel HEX)\n");
  exit(2);
}

int main(int argc, char **argv) {
  const char *mcu = "atmega328p";
  const char *elf = NULL;
  uint32_t freq = 16000000;
  int hold = 0;
  const char *boot = NULL;
  int firmware_hex = 0;  // --hex
  for (int i = 1; i < argc; i++) {
    if (!strcmp(argv[i], "--mcu") && i + 1 < argc)
      mcu = argv[++i];
    else if (!strcmp(argv[i], "--freq") && i + 1 < argc)
      freq = (uint32_t)strtoul(argv[++i], NULL, 10);
    else if (!strcmp(argv[i], "--speed") && i + 1 < argc)
      speed = atof(argv[++i]);
    else if (!strcmp(argv[i], "--report-us") && i + 1 < argc)
      report_us = (uint32_t)strtoul(argv[++i], NULL, 10);
    else if (!strcmp(argv[i], "--hold"))
      hold = 1;
    else if (!strcmp(argv[i], "--hex"))
      firmware_hex = 1;
    else if (!strcmp(argv[i], "--bootloader") && i + 1 < argc)
      boot = argv[++i];
    else if (!strcmp(argv[i], "--trace-uart") && i + 1 < argc) {
      uart_trace = fopen(argv[++i], "w");
      if (!uart_trace) {
        fprintf(stderr, "hwbridge-simavr: cannot write %s: %s\n", argv[i], strerror(errno));
        exit(2);
      }
      setvbuf(uart_trace, NULL, _IOLBF, 0);  // whole lines, readable while the run goes on
    }
    else if (!strcmp(argv[i], "--trace-pc") && i + 1 < argc) {
      pc_trace = fopen(argv[++i], "wb");
      if (!pc_trace) {
        fprintf(stderr, "hwbridge-simavr: cannot write %s: %s\n", argv[i], strerror(errno));
        exit(2);
      }
    }
    else if (argv[i][0] == '-')
      usage();
    else
      elf = argv[i];
  }
  if (!elf && !boot) usage();
  int app_hex = elf && firmware_hex;  // else an ELF (libsimavr reads no HEX: load_hex() does)
  avr_global_logger_set(quiet_logger);

  elf_firmware_t fw;
  memset(&fw, 0, sizeof fw);
  if (elf && !app_hex && elf_read_firmware(elf, &fw) != 0) {
    fprintf(stderr, "hwbridge-simavr: cannot read %s\n", elf);
    return 1;
  }
  if (!strcmp(mcu, "atmega2560")) pwm_table = pwm_2560;
  avr = avr_make_mcu_by_name(mcu);
  if (!avr) {
    fprintf(stderr, "hwbridge-simavr: simavr does not know the MCU %s\n", mcu);
    return 1;
  }
  avr_init(avr);
  avr->log = LOG_WARNING;
  fw.frequency = freq;
  if (elf && !app_hex) avr_load_firmware(avr, &fw);
  avr->frequency = freq;
  if (app_hex && !boot) {
    uint32_t start = 0;
    if (load_hex(elf, &start) != 0) return 1;
    avr->codeend = avr->flashend;
  }
  if (boot) {
    uint32_t start = 0, boot_start = 0;
    if (app_hex && load_hex(elf, &start) != 0) return 1;
    if (load_hex(boot, &boot_start) != 0) return 1;
    boot_mode = 1;
    avr->codeend = avr->flashend;  // the application may grow to the bootloader
    avr->reset_pc = boot_start;    // BOOTRST: resets start the bootloader
    avr->pc = boot_start;
    // Power-on: PORF, and Optiboot starts the application; with none yet, EXTRF as if the
    // reset button were pressed, and the bootloader waits for an upload first.
    if (!elf) avr_regbit_set(avr, avr->reset_flags.extrf);
  }

  if (pty_open() != 0) return 1;
  if (boot_mode) start_open_watch(uart.slavename);
  out_line("serial://%s\n", uart.slavename);

  static const char *twi_names[2] = {"<twi.in", ">twi.out"};
  twi_irq = avr_alloc_irq(&avr->irq_pool, 0, 2, twi_names);
  avr_irq_register_notify(twi_irq + TWI_IRQ_OUTPUT, twi_hook, NULL);
  avr_connect_irq(twi_irq + TWI_IRQ_INPUT, avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_INPUT));
  avr_connect_irq(avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_OUTPUT), twi_irq + TWI_IRQ_OUTPUT);
  twi_irq = twi_irq + TWI_IRQ_INPUT;

  for (uint8_t i = 0; i < 8; i++) avr_extint_set_strict_lvl_trig(avr, i, 0);
  if (hold) {
    // Devices first: commands are taken (blocking) until "go".
    while (!want_go && !want_quit) {
      ssize_t n = read(0, inbuf + inlen, sizeof inbuf - 1 - inlen);
      if (n <= 0) return 0;
      inlen += (size_t)n;
      char *start = inbuf;
      char *nl;
      while (!want_go && (nl = memchr(start, '\n', inlen - (size_t)(start - inbuf))) != NULL) {
        *nl = 0;
        command(start);
        start = nl + 1;
      }
      inlen -= (size_t)(start - inbuf);
      memmove(inbuf, start, inlen);
    }
  }
  fcntl(0, F_SETFL, fcntl(0, F_GETFL) | O_NONBLOCK);
  clock_gettime(CLOCK_MONOTONIC, &wall_start);
  cycle_start = avr->cycle;
  start_timers();

  int state = cpu_Running;
  while (!want_quit) {
    if (pc_window) {
      uint8_t rec[12];
      uint64_t cycle = avr->cycle;
      uint32_t pc = avr->pc;
      for (int k = 0; k < 8; k++) rec[k] = (uint8_t)(cycle >> (8 * k));
      for (int k = 0; k < 4; k++) rec[8 + k] = (uint8_t)(pc >> (8 * k));
      fwrite(rec, sizeof rec, 1, pc_trace);
    }
    state = avr_run(avr);
    if (boot_mode && pty_opened()) want_reset = 1;
    if ((state == cpu_Done || state == cpu_Crashed) && boot_mode) {
      fprintf(stderr, "hwbridge-simavr: the AVR stopped (%s) at 0x%04x; it waits for a reset\n",
              state == cpu_Crashed ? "crashed" : "done", avr->pc);
      wait_for_reset();
      if (want_quit) break;
      state = cpu_Running;
    }
    if (state == cpu_Done || state == cpu_Crashed) break;
    if (want_reset) {
      want_reset = 0;
      external_reset();
      avr->state = cpu_Running;
    }
    if (avr->pc == avr->reset_pc && avr_cycle_timer_status(avr, tick, NULL) == 0) {
      // avr_reset (ours, or the watchdog's) cleared the cycle timers and the registers.
      start_timers();
      reapply_inputs();
      for (int i = 0; i < MAX_I2C; i++) slaves[i].selected = 0;
      out_line("reset\n");
    }
  }
  if (!want_quit) {
    out_line("exit %s\n", state == cpu_Crashed ? "crashed" : "done");
    // Stay until told to go, so the controlling process sees the pty as long as it wants.
    fcntl(0, F_SETFL, fcntl(0, F_GETFL) & ~O_NONBLOCK);
    char buf[256];
    while (read(0, buf, sizeof buf) > 0) {
    }
  }
  fflush(stdout);
  _exit(0);
}
