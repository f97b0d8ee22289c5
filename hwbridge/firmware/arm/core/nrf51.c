/* nRF51822 board support (QEMU microbit): TIMER0 as a free-running 32-bit counter at 1 MHz for
 * hwbridge_board_micros() (the nRF51's Cortex-M0 has no SysTick), and the fault text on UART0.
 * Unaligned accesses always fault on a Cortex-M0 (ARMv6-M): nothing to switch on. */
#include <stdint.h>

#define REG(address) (*(volatile uint32_t*)(address))
#define TIMER0 0x40008000u
#define TIMER_START 0x000u
#define TIMER_CLEAR 0x00Cu
#define TIMER_CAPTURE3 0x04Cu
#define TIMER_MODE 0x504u
#define TIMER_BITMODE 0x508u
#define TIMER_PRESCALER 0x510u
#define TIMER_CC3 0x54Cu
#define UART0 0x40002000u

void hwbridge_board_setup(void) {
  REG(TIMER0 + TIMER_MODE) = 0;      /* timer */
  REG(TIMER0 + TIMER_BITMODE) = 3;   /* 32 bits */
  REG(TIMER0 + TIMER_PRESCALER) = 4; /* 16 MHz / 2^4 = 1 MHz */
  REG(TIMER0 + TIMER_CLEAR) = 1;
  REG(TIMER0 + TIMER_START) = 1;
}

uint32_t hwbridge_board_micros(void) {
  REG(TIMER0 + TIMER_CAPTURE3) = 1;
  return REG(TIMER0 + TIMER_CC3);
}

void hwbridge_board_fault_puts(const char* text) {
  if (REG(UART0 + 0x500u) != 4u) {
    REG(UART0 + 0x50Cu) = 24u;
    REG(UART0 + 0x524u) = 0x01D7E000u;
    REG(UART0 + 0x500u) = 4u;
    REG(UART0 + 0x008u) = 1u;
  }
  for (; *text != 0; ++text) {
    REG(UART0 + 0x11Cu) = 0;
    REG(UART0 + 0x51Cu) = (uint8_t)*text;
    while (REG(UART0 + 0x11Cu) == 0) {
    }
  }
}
