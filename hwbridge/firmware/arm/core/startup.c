/* Bare-metal start-up for the Cortex-M boards of `hwbridge firmware build --board stm32f405|microbit`:
 * the vector table (the 16 core exceptions; every peripheral is polled, so no IRQ vector is
 * used), the reset handler (copies .data from flash, zeroes .bss, runs the board's set-up and the
 * C++ constructors, then main(); a test program built with HWBRIDGE_SEMIHOSTED exits with
 * main's result through QEMU's semihosting), and a HardFault handler that reports the fault on the board's
 * UART ("HARDFAULT pc=... cfsr=...") and stops. Symbols come from the target's linker script. */
#include <stdint.h>

extern uint32_t __data_load, __data_start, __data_end, __bss_start, __bss_end, __stack_top;
extern void (*__init_array_start[])(void);
extern void (*__init_array_end[])(void);

int main(void);
#ifdef HWBRIDGE_SEMIHOSTED
#include <stdlib.h>
void initialise_monitor_handles(void);
#endif
void hwbridge_board_setup(void);
void hwbridge_board_fault_puts(const char* text);
uint32_t hwbridge_board_micros(void);
uint32_t hwbridge_board_millis(void);
void hwbridge_board_reset(void);

#define SCB_AIRCR (*(volatile uint32_t*)0xE000ED0Cu) /* the same on every Cortex-M */

void Reset_Handler(void);
void Default_Handler(void);
void HardFault_Handler(void);
void SysTick_Handler(void) __attribute__((weak, alias("Default_Handler")));
void NMI_Handler(void) __attribute__((weak, alias("Default_Handler")));
void SVC_Handler(void) __attribute__((weak, alias("Default_Handler")));
void PendSV_Handler(void) __attribute__((weak, alias("Default_Handler")));

/* The C++ runtime's handle for destructors registered with __cxa_atexit (crtbegin.o defines it
 * where the default start files are linked; here they are not). */
__attribute__((weak)) void* __dso_handle = 0;

typedef void (*Vector)(void);

__attribute__((section(".isr_vector"), used)) const Vector hwbridge_vectors[16] = {
    (Vector)(uintptr_t)&__stack_top,
    Reset_Handler,
    NMI_Handler,
    HardFault_Handler,
    HardFault_Handler, /* MemManage (M3/M4; reserved on M0) */
    HardFault_Handler, /* BusFault */
    HardFault_Handler, /* UsageFault: unaligned access with CCR.UNALIGN_TRP on the M4 */
    0, 0, 0, 0,
    SVC_Handler,
    0, 0,
    PendSV_Handler,
    SysTick_Handler,
};

void Reset_Handler(void) {
  uint32_t* from = &__data_load;
  for (uint32_t* to = &__data_start; to < &__data_end;) *to++ = *from++;
  for (uint32_t* to = &__bss_start; to < &__bss_end;) *to++ = 0;
  hwbridge_board_setup();
  for (void (**f)(void) = __init_array_start; f < __init_array_end; ++f) (*f)();
#ifdef HWBRIDGE_SEMIHOSTED
  /* test programs (tests/arm): stdio and the exit code through QEMU's semihosting */
  initialise_monitor_handles();
  exit(main());
#else
  main();
  for (;;) {
  }
#endif
}

void Default_Handler(void) {
  hwbridge_board_fault_puts("\r\nUNEXPECTED EXCEPTION\r\n");
  for (;;) {
  }
}

static void put_hex(char* out, uint32_t value) {
  for (int i = 7; i >= 0; --i) {
    const uint32_t nibble = value & 0xFu;
    out[i] = (char)(nibble < 10 ? '0' + nibble : 'a' + nibble - 10);
    value >>= 4;
  }
}

/* Called with the exception frame (r0-r3, r12, lr, pc, xpsr) of the faulting code. */
__attribute__((used)) void hwbridge_fault_report(const uint32_t* frame) {
  char line[] = "\r\nHARDFAULT pc=00000000 cfsr=00000000\r\n";
  put_hex(line + 15, frame[6]);
#if defined(__ARM_ARCH_7EM__) || defined(__ARM_ARCH_7M__)
  put_hex(line + 29, *(volatile uint32_t*)0xE000ED28u); /* SCB->CFSR */
#endif
  hwbridge_board_fault_puts(line);
  for (;;) {
  }
}

/* Finds the stack the fault was taken on (MSP or PSP, bit 2 of EXC_RETURN), passes its frame. */
__attribute__((naked)) void HardFault_Handler(void) {
  __asm volatile(
      "movs r0, #4\n"
      "mov r1, lr\n"
      "tst r0, r1\n"
      "beq 1f\n"
      "mrs r0, psp\n"
      "b hwbridge_fault_report\n"
      "1:\n"
      "mrs r0, msp\n"
      "b hwbridge_fault_report\n");
}

/* Milliseconds since reset from the board's microsecond counter (its own timer), wrapping at 2^32
 * like Arduino's millis(): the counter wraps every 71 minutes, so the elapsed microseconds are
 * summed in 64 bits at each call. */
uint32_t hwbridge_board_millis(void) {
  static uint32_t last_us;
  static uint64_t total_us;
  const uint32_t now = hwbridge_board_micros();
  total_us += (uint32_t)(now - last_us);
  last_us = now;
  return (uint32_t)(total_us / 1000u);
}

/* A system reset request (SYSRESETREQ), as a board's reset pin would. */
void hwbridge_board_reset(void) {
  SCB_AIRCR = (0x05FAu << 16) | (1u << 2);
  for (;;) {
  }
}
