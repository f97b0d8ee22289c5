/* STM32F405 board support (QEMU netduinoplus2): the FPU, the divide-by-zero trap, the
 * unaligned-access trap when HWBRIDGE_UNALIGN_TRAP is 1 (not by default: Debian's newlib-nano
 * for this core stores halfwords at odd stack addresses in printf/snprintf, which then fault), TIM2 as a free-running 32-bit counter at 1 MHz for
 * hwbridge_board_micros(), and the fault text on USART1.
 *
 * Why TIM2, read directly, and not SysTick: a millisecond count kept by the SysTick interrupt,
 * or a 24-bit SysTick polled and extended in software, loses time whenever QEMU's CPU thread is
 * held off the host's cores for longer than a period (on a busy 2-core host that happens: the
 * board's clock ran at some 60% of the host's, and the host's link timeout fired). A 32-bit
 * counter at 1 MHz read from the timer needs no help (it wraps every 71 minutes, as micros()).
 * TIM2's input clock, HWBRIDGE_TIM2_HZ: 1 GHz in the model of Debian's QEMU (7.2; later QEMU
 * models 48 MHz); 84 MHz on a real F405 with the core at 168 MHz and APB1 at 42 MHz. */
#include <stdint.h>

#define REG(address) (*(volatile uint32_t*)(address))
#define SCB_CCR 0xE000ED14u
#define SCB_CPACR 0xE000ED88u
#define RCC_APB1ENR 0x40023840u
#define TIM2 0x40000000u
#define TIM_CR1 0x00u
#define TIM_EGR 0x14u
#define TIM_CNT 0x24u
#define TIM_PSC 0x28u
#define TIM_ARR 0x2Cu
#define USART1_SR 0x40011000u
#define USART1_DR 0x40011004u
#define USART1_BRR 0x40011008u
#define USART1_CR1 0x4001100Cu

#ifndef HWBRIDGE_TIM2_HZ
#define HWBRIDGE_TIM2_HZ 1000000000u
#endif

void hwbridge_board_setup(void) {
  REG(SCB_CPACR) |= 0xFu << 20; /* CP10 and CP11: the FPU, before any float instruction */
  __asm volatile("dsb\n isb");
#if HWBRIDGE_UNALIGN_TRAP
  REG(SCB_CCR) |= 1u << 3; /* UNALIGN_TRP: an unaligned load or store faults, as on a Cortex-M0 */
#endif
  REG(SCB_CCR) |= 1u << 4; /* DIV_0_TRP */
  REG(RCC_APB1ENR) |= 1u;                /* TIM2's clock */
  REG(TIM2 + TIM_PSC) = HWBRIDGE_TIM2_HZ / 1000000u - 1u;
  REG(TIM2 + TIM_ARR) = 0xFFFFFFFFu;
  REG(TIM2 + TIM_EGR) = 1u; /* UG: load the prescaler */
  REG(TIM2 + TIM_CNT) = 0;
  REG(TIM2 + TIM_CR1) = 1u; /* CEN */
}

uint32_t hwbridge_board_micros(void) { return REG(TIM2 + TIM_CNT); }

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
 * CCR.UNALIGN_TRP is set); with the trap on, that faults (GCC's own inlined copies are kept
 * aligned by -mno-unaligned-access). This one copies words only when both
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
