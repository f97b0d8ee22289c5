/* A test program for the simavr runner (ATmega328P, 16 MHz), plain avr-libc.
 * UART0 at 115200 baud: prints "boot" at reset, echoes every byte except the commands
 *   c  -> "C<count>"   the quadrature count of A = PD2 (INT0, both edges), B = PD4 (x2 decoding)
 *   p<byte> -> "P"     PWM on OC0B (PD5, Arduino D5) with that duty, PD7 (D7) high
 *   s  -> "S<us>"      an HC-SR04 reading: trigger PB1 (D9), echo PB2 (D10) timed with timer 1
 *   i  -> "I<hex>"     I2C: wake the MPU at 0x68, then WHO_AM_I and 6 bytes from 0x3B
 *   r  -> "R<hex>"     I2C, no writes: PWR_MGMT_1 (0x6B) and 6 bytes from 0x3B
 *   a<byte> -> "A"     I2C: ACCEL_CONFIG (0x1C) = byte
 *   w  -> (nothing)    the watchdog resets the chip after 15 ms
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/wdt.h>
#include <stdio.h>
#include <util/delay.h>

static volatile int16_t count;

ISR(INT0_vect) {
  uint8_t a = (PIND >> 2) & 1, b = (PIND >> 4) & 1;
  if (a != b) count++; else count--;
}

static void put(char c) { while (!(UCSR0A & _BV(UDRE0))) {} UDR0 = (uint8_t)c; }
static void puts_(const char *s) { while (*s) put(*s++); }
static char get(void) { while (!(UCSR0A & _BV(RXC0))) {} return (char)UDR0; }

static uint8_t twi_wait(void) { while (!(TWCR & _BV(TWINT))) {} return TWSR & 0xF8; }
static void twi_start(void) { TWCR = _BV(TWINT) | _BV(TWSTA) | _BV(TWEN); twi_wait(); }
static void twi_stop(void) { TWCR = _BV(TWINT) | _BV(TWSTO) | _BV(TWEN); }
static void twi_write(uint8_t b) { TWDR = b; TWCR = _BV(TWINT) | _BV(TWEN); twi_wait(); }
static uint8_t twi_read(uint8_t ack) {
  TWCR = _BV(TWINT) | _BV(TWEN) | (ack ? _BV(TWEA) : 0);
  twi_wait();
  return TWDR;
}
static void twi_read_regs(uint8_t reg, uint8_t *out, uint8_t n) {
  twi_start(); twi_write(0x68 << 1); twi_write(reg);
  twi_start(); twi_write((0x68 << 1) | 1);
  for (uint8_t i = 0; i < n; i++) out[i] = twi_read(i + 1 < n);
  twi_stop();
}

int main(void) {
  MCUSR = 0;
  wdt_disable();
  UCSR0A = _BV(U2X0);
  UBRR0 = 16;  /* 115200 with U2X at 16 MHz */
  UCSR0B = _BV(RXEN0) | _BV(TXEN0);
  DDRD |= _BV(5) | _BV(7);
  PORTD |= _BV(2) | _BV(4);  /* pull-ups on the encoder pins, as a sketch would */
  DDRB |= _BV(1);
  EICRA = _BV(ISC00);
  EIMSK = _BV(INT0);
  TWBR = 72;  /* 100 kHz */
  TCCR1B = _BV(CS11);  /* 2 MHz: 0.5 us ticks */
  sei();
  puts_("boot\n");
  char buf[48];
  for (;;) {
    char c = get();
    if (c == 'c') {
      cli(); int16_t n = count; sei();
      snprintf(buf, sizeof buf, "C%d\n", n); puts_(buf);
    } else if (c == 'p') {
      uint8_t duty = (uint8_t)get();
      TCCR0A = _BV(COM0B1) | _BV(WGM01) | _BV(WGM00);
      TCCR0B = _BV(CS01) | _BV(CS00);
      OCR0B = duty;
      PORTD |= _BV(7);
      puts_("P\n");
    } else if (c == 's') {
      PORTB |= _BV(1); _delay_us(12); PORTB &= ~_BV(1);
      uint16_t t0 = TCNT1;
      while (!(PINB & _BV(2))) { if ((uint16_t)(TCNT1 - t0) > 60000) break; }
      uint16_t rise = TCNT1;
      while (PINB & _BV(2)) { if ((uint16_t)(TCNT1 - rise) > 60000) break; }
      uint16_t fall = TCNT1;
      snprintf(buf, sizeof buf, "S%u\n", (unsigned)((uint16_t)(fall - rise) / 2)); puts_(buf);
    } else if (c == 'i') {
      twi_start(); twi_write(0x68 << 1); twi_write(0x6B); twi_write(0x00); twi_stop();
      uint8_t who, data[6];
      twi_read_regs(0x75, &who, 1);
      twi_read_regs(0x3B, data, 6);
      snprintf(buf, sizeof buf, "I%02x %02x%02x%02x%02x%02x%02x\n", who, data[0], data[1],
               data[2], data[3], data[4], data[5]);
      puts_(buf);
    } else if (c == 'r') {
      uint8_t power, data[6];
      twi_read_regs(0x6B, &power, 1);
      twi_read_regs(0x3B, data, 6);
      snprintf(buf, sizeof buf, "R%02x %02x%02x%02x%02x%02x%02x\n", power, data[0], data[1],
               data[2], data[3], data[4], data[5]);
      puts_(buf);
    } else if (c == 'a') {
      uint8_t value = (uint8_t)get();
      twi_start(); twi_write(0x68 << 1); twi_write(0x1C); twi_write(value); twi_stop();
      puts_("A\n");
    } else if (c == 'w') {
      wdt_enable(WDTO_15MS);
      for (;;) {}
    } else {
      put(c);
    }
  }
}
