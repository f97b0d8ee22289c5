/* An unaligned 32-bit load, for tests/arm/test_traps.py: prints "before" through semihosting,
 * loads a word from an odd address, prints "after" (reached only when the core allows it). A
 * fault is reported on the UART by the start-up's HardFault handler ("HARDFAULT pc=... cfsr=..."). */
#include <stdint.h>
#include <string.h>
#include <unistd.h>

static uint8_t bytes[8] __attribute__((aligned(4))) = {1, 2, 3, 4, 5, 6, 7, 8};

static void say(const char* text) { write(1, text, strlen(text)); }

int main(void) {
  say("before\n");
  /* the address is computed at run time, through a volatile, so the compiler cannot split it */
  volatile uintptr_t address = (uintptr_t)bytes + 1u;
  const uint32_t word = *(const volatile uint32_t*)address;
  say(word == 0x05040302u ? "after: 05040302\n" : "after: another value\n");
  return 0;
}
