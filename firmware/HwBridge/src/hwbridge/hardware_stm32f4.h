// The STM32F4 Hardware: the node's byte link over USART1 (PA9 TX, PA10 RX), polled, on a bare
// Cortex-M4 (no Arduino core). QEMU's netduinoplus2 connects its first -serial to USART1.
//
// Hardware concept (what the node uses; see firmware/HwBridge/README.md, "Porting"): bool
// init(baud), int read() (a byte or -1, never blocks), put(uint8_t) (one byte out; blocks only
// while the transmitter is busy), flush(), uint32_t micros() (wrapping), uint32_t seed().
// The microsecond clock comes from the board's start-up code (hwbridge_board_micros(), TIM2 in
// hwbridge/firmware/arm/), as ArduinoHardware takes it from the Arduino core.
#ifndef HWBRIDGE_HARDWARE_STM32F4_H
#define HWBRIDGE_HARDWARE_STM32F4_H

#if defined(__AVR__)
#error "this Hardware is for 32-bit ARM boards (hwbridge firmware build --board stm32f405|microbit)"
#endif

#include <stdint.h>

#include "boot_count.h"
#include "config.h"

extern "C" uint32_t hwbridge_board_micros(void);

namespace hwbridge {

/** Register addresses and bits of the STM32F405/407 (reference manual RM0090). */
namespace stm32f4 {
const uint32_t kRcc = 0x40023800u;
const uint32_t kRccAhb1Enr = kRcc + 0x30u;  ///< bit 0: GPIOA clock
const uint32_t kRccApb2Enr = kRcc + 0x44u;  ///< bit 4: USART1 clock
const uint32_t kGpioA = 0x40020000u;
const uint32_t kGpioModer = 0x00u;
const uint32_t kGpioAfrh = 0x24u;
const uint32_t kUsart1 = 0x40011000u;
const uint32_t kSr = 0x00u;
const uint32_t kDr = 0x04u;
const uint32_t kBrr = 0x08u;
const uint32_t kCr1 = 0x0Cu;
const uint32_t kSrRxne = 1u << 5;
const uint32_t kSrTxe = 1u << 7;
const uint32_t kCr1Re = 1u << 2;
const uint32_t kCr1Te = 1u << 3;
const uint32_t kCr1Ue = 1u << 13;
/** APB2 clock feeding USART1: 84 MHz with the core at 168 MHz (QEMU's model; on a real board
 * the PLL must be set to that first, or define HWBRIDGE_STM32F4_PCLK2 to the real value). */
#ifdef HWBRIDGE_STM32F4_PCLK2
const uint32_t kPclk2 = HWBRIDGE_STM32F4_PCLK2;
#else
const uint32_t kPclk2 = 84000000u;
#endif

inline volatile uint32_t& reg(uint32_t address) {
  return *reinterpret_cast<volatile uint32_t*>(address);
}
}  // namespace stm32f4

/** USART1 at init(baud), 8N1, polled. */
class Stm32f4Hardware {
 public:
  /** In QEMU the board shares the host's CPU: the stall rule applies (config.h). */
  static const bool kSharesCpu = HWBRIDGE_QEMU_CLOCK != 0;
  bool init(uint32_t baud) {
    using namespace stm32f4;
    reg(kRccAhb1Enr) |= 1u;
    reg(kRccApb2Enr) |= 1u << 4;
    // PA9 and PA10 in alternate function 7 (USART1)
    reg(kGpioA + kGpioModer) = (reg(kGpioA + kGpioModer) & ~(0xFu << 18)) | (0xAu << 18);
    reg(kGpioA + kGpioAfrh) = (reg(kGpioA + kGpioAfrh) & ~0xFF0u) | 0x770u;
    reg(kUsart1 + kBrr) = (kPclk2 + baud / 2u) / (baud == 0 ? 1u : baud);
    reg(kUsart1 + kCr1) = kCr1Ue | kCr1Te | kCr1Re;
    return true;
  }
  int read() {
    using namespace stm32f4;
    if ((reg(kUsart1 + kSr) & kSrRxne) == 0) return -1;
    return static_cast<int>(reg(kUsart1 + kDr) & 0xFFu);
  }
  void put(uint8_t b) {
    using namespace stm32f4;
    while ((reg(kUsart1 + kSr) & kSrTxe) == 0) {
    }
    reg(kUsart1 + kDr) = b;
  }
  void flush() {}
  uint32_t micros() { return hwbridge_board_micros(); }
  /** Entropy for the session id: the clock at the first spin, mixed (no noise source is read),
   * and the count of boots (boot_count.h: the clock alone reads the same at every boot). */
  uint32_t seed() {
    uint32_t s = hwbridge_board_micros() * 2654435761u;
    return (s ^ (s >> 15)) ^ detail::count_boot();
  }
};

}  // namespace hwbridge

#endif  // HWBRIDGE_HARDWARE_STM32F4_H
