// The nRF51 Hardware: the node's byte link over UART0, polled, on a bare Cortex-M0 (no Arduino
// core). QEMU's microbit connects its first -serial to UART0. The micro:bit's pins: TX P0.24,
// RX P0.25 (its USB bridge).
//
// Hardware concept: as hardware_stm32f4.h (see firmware/HwBridge/README.md, "Porting"). The
// microsecond clock comes from the board's start-up code (hwbridge_board_micros(): TIMER0 at
// 1 MHz, since the nRF51's Cortex-M0 has no SysTick).
#ifndef HWBRIDGE_HARDWARE_NRF51_H
#define HWBRIDGE_HARDWARE_NRF51_H

#if defined(__AVR__)
#error "this Hardware is for 32-bit ARM boards (hwbridge firmware build --board stm32f405|microbit)"
#endif

#include <stdint.h>

#include "boot_count.h"
#include "config.h"

extern "C" uint32_t hwbridge_board_micros(void);

namespace hwbridge {

/** Register addresses of the nRF51 UART (nRF51 Series Reference Manual, chapter 29). */
namespace nrf51 {
const uint32_t kUart0 = 0x40002000u;
const uint32_t kStartRx = 0x000u;
const uint32_t kStartTx = 0x008u;
const uint32_t kRxdRdy = 0x108u;
const uint32_t kTxdRdy = 0x11Cu;
const uint32_t kEnable = 0x500u;
const uint32_t kPselTxd = 0x50Cu;
const uint32_t kPselRxd = 0x514u;
const uint32_t kRxd = 0x518u;
const uint32_t kTxd = 0x51Cu;
const uint32_t kBaudrate = 0x524u;
#ifndef HWBRIDGE_NRF51_TX_PIN
#define HWBRIDGE_NRF51_TX_PIN 24
#endif
#ifndef HWBRIDGE_NRF51_RX_PIN
#define HWBRIDGE_NRF51_RX_PIN 25
#endif

inline volatile uint32_t& reg(uint32_t address) {
  return *reinterpret_cast<volatile uint32_t*>(address);
}

/** The BAUDRATE register's value for a rate (the manual's table; 115200 when not listed). */
inline uint32_t baud_value(uint32_t baud) {
  switch (baud) {
    case 9600: return 0x00275000u;
    case 19200: return 0x004EA000u;
    case 38400: return 0x009D5000u;
    case 57600: return 0x00EBF000u;
    case 230400: return 0x03AFB000u;
    case 1000000: return 0x10000000u;
    default: return 0x01D7E000u;
  }
}
}  // namespace nrf51

/** UART0 at init(baud), 8N1, polled. */
class Nrf51Hardware {
 public:
  /** In QEMU the board shares the host's CPU: the stall rule applies (config.h). */
  static const bool kSharesCpu = HWBRIDGE_QEMU_CLOCK != 0;
  bool init(uint32_t baud) {
    using namespace nrf51;
    reg(kUart0 + kPselTxd) = HWBRIDGE_NRF51_TX_PIN;
    reg(kUart0 + kPselRxd) = HWBRIDGE_NRF51_RX_PIN;
    reg(kUart0 + kBaudrate) = baud_value(baud);
    reg(kUart0 + kEnable) = 4;
    reg(kUart0 + kTxdRdy) = 0;
    reg(kUart0 + kRxdRdy) = 0;
    reg(kUart0 + kStartTx) = 1;
    reg(kUart0 + kStartRx) = 1;
    return true;
  }
  int read() {
    using namespace nrf51;
    if (reg(kUart0 + kRxdRdy) == 0) return -1;
    reg(kUart0 + kRxdRdy) = 0;  // cleared before RXD is read: a next byte sets it again
    return static_cast<int>(reg(kUart0 + kRxd) & 0xFFu);
  }
  void put(uint8_t b) {
    using namespace nrf51;
    reg(kUart0 + kTxdRdy) = 0;
    reg(kUart0 + kTxd) = b;
    while (reg(kUart0 + kTxdRdy) == 0) {
    }
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

#endif  // HWBRIDGE_HARDWARE_NRF51_H
