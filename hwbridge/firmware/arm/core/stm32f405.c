/* STM32F405 board support (QEMU netduinoplus2): the FPU, unaligned-access and divide-by-zero
 * traps, SysTick at 1 kHz from the 168 MHz core clock for hwbridge_board_micros(), and the fault
 * text on USART1. */
#include <stdint.h>

#define REG(address) (*(volatile uint32_t*)(address))
#define SCB_CCR 0xE000ED14u
#define SCB_CPACR 0xE000ED88u
#define SCB_AIRCR 0xE000ED0Cu
#define SYST_CSR 0xE000E010u
#define SYST_RVR 0xE000E014u
#define SYST_CVR 0xE000E018u
#define USART1_SR 0x40011000u
#define USART1_DR 0x40011004u
#define USART1_BRR 0x40011008u
#define USART1_CR1 0x4001100Cu

#ifndef HWBRIDGE_CORE_HZ
#define HWBRIDGE_CORE_HZ 168000000u
#endif
#define TICKS_PER_MS (HWBRIDGE_CORE_HZ / 1000u)
#define TICKS_PER_US (HWBRIDGE_CORE_HZ / 1000000u)

static volatile uint32_t ms_count;

void hwbridge_board_setup(void) {
  REG(SCB_CPACR) |= 0xFu << 20; /* CP10 and CP11: the FPU, before any float instruction */
  __asm volatile("dsb\n isb");
  REG(SCB_CCR) |= (1u << 3) | (1u << 4); /* UNALIGN_TRP, DIV_0_TRP */
  REG(SYST_RVR) = TICKS_PER_MS - 1u;
  REG(SYST_CVR) = 0;
  REG(SYST_CSR) = 7u; /* processor clock, interrupt, enabled */
}

void SysTick_Handler(void) { ms_count = ms_count + 1u; }

uint32_t hwbridge_board_micros(void) {
  uint32_t ms, left;
  do {
    ms = ms_count;
    left = REG(SYST_CVR);
  } while (ms != ms_count); /* a tick between the two reads: read again */
  /* COUNTFLAG pending (the counter wrapped, the interrupt not yet taken) */
  if ((REG(SYST_CSR) & (1u << 16)) != 0 && left > TICKS_PER_MS / 2u) {
    ms_count = ms_count + 1u;
    ms = ms_count;
  }
  return ms * 1000u + (TICKS_PER_MS - 1u - left) / TICKS_PER_US;
}

uint32_t hwbridge_board_millis(void) { return ms_count; }

void hwbridge_board_reset(void) {
  REG(SCB_AIRCR) = (0x05FAu << 16) | (1u << 2); /* SYSRESETREQ */
  for (;;) {
  }
}

void hwbridge_board_fault_puts(const char* text) {
  if ((REG(USART1_CR1) & (1u << 13)) == 0) {
    REG(USART1_BRR) = 84000000u / 115200u;
    REG(USART1_CR1) = (1u << 13) | (1u << 3) | (1u << 2);
  }
  for (; *text != 0; ++text) {
    while ((REG(USART1_SR) & (1u << 7)) == 0) {
    }
    REG(USART1_DR) = (uint8_t)*text;
  }
}

/* newlib's memcpy for ARMv7-M loads words from unaligned sources (the core allows it unless
 * CCR.UNALIGN_TRP is set); with the trap on, that faults. This one copies words only when both
 * addresses are word-aligned, else bytes; being defined here, it replaces the library's. */
#include <stddef.h>
__attribute__((optimize("no-tree-loop-distribute-patterns"))) void* memcpy(
    void* restrict to, const void* restrict from, size_t n) {
  uint8_t* d = (uint8_t*)to;
  const uint8_t* s = (const uint8_t*)from;
  if ((((uintptr_t)d | (uintptr_t)s) & 3u) == 0) {
    for (; n >= 4; n -= 4, d += 4, s += 4) *(uint32_t*)(void*)d = *(const uint32_t*)(const void*)s;
  }
  while (n-- > 0) *d++ = *s++;
  return to;
}
