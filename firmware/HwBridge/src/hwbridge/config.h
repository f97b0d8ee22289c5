// Library-wide settings that a sketch may override before including HwBridge.h.
#ifndef HWBRIDGE_CONFIG_H
#define HWBRIDGE_CONFIG_H

#include <stdint.h>

namespace hwbridge {

#ifdef HWBRIDGE_COUNTER_TYPE
typedef HWBRIDGE_COUNTER_TYPE Counter;
#elif defined(__AVR__)
/** Type of every statistics counter: 8 bits (wrapping) on an 8-bit board, where ~40 counters
 * over the layers would otherwise cost 80 B of a 2 KB RAM. */
typedef uint8_t Counter;
#else
/** Type of every statistics counter: 16 bits (wrapping). */
typedef uint16_t Counter;
#endif

#if !defined(HWBRIDGE_TRAFFIC_COUNTERS) && !defined(__AVR__)
#define HWBRIDGE_TRAFFIC_COUNTERS 1
#endif
#if HWBRIDGE_TRAFFIC_COUNTERS
/** A counter of traffic (frames and messages sent and received, ACKs, sessions, HELLOs,
 * heartbeats): a Counter on hosts, and on AVR with -DHWBRIDGE_TRAFFIC_COUNTERS=1. */
typedef Counter TrafficCounter;
#else
/** On AVR the traffic counters count nothing (they read 0), unless HWBRIDGE_TRAFFIC_COUNTERS is
 * 1: their increments would take some 150 B of a 32 KB flash. Every counter of something lost,
 * refused or rejected is a real Counter always. */
struct NullCounter {
  NullCounter& operator++() { return *this; }
  NullCounter& operator--() { return *this; }
  NullCounter operator++(int) { return *this; }
  NullCounter& operator=(int) { return *this; }
  operator uint8_t() const { return 0; }
};
typedef NullCounter TrafficCounter;
#endif

#ifndef HWBRIDGE_ACK_IN_DATA
#ifdef __AVR__
/** On AVR the library profiles announce ACK_IN_DATA (PROTOCOL.md 2.4: a service exchange with
 * no ACK frames, some 2000 cycles less a call) only when a sketch defines HWBRIDGE_ACK_IN_DATA
 * as 1 before including HwBridge.h: it costs some 300 B of flash, more than a hello world at
 * its budget has. */
#define HWBRIDGE_ACK_IN_DATA 0
#else
#define HWBRIDGE_ACK_IN_DATA 1
#endif
#endif

#ifndef HWBRIDGE_QEMU_CLOCK
/** The ARM boards' builds are for QEMU's models (their clocks are QEMU's: see the firmware
 * README), whose guest clock runs on the host's time: when the host's scheduler leaves QEMU
 * out, the board's clock jumps on as the host's does, and the board would take that time for
 * its peer's silence. With 1 (the default) Stm32f4Hardware and Nrf51Hardware declare
 * kSharesCpu, and the node applies PROTOCOL.md 2.9's stall rule as on a host build. Define it
 * as 0 for real silicon, which never stops. */
#define HWBRIDGE_QEMU_CLOCK 1
#endif

namespace detail {
/** Whether a write of several bytes puts its first byte straight into an idle UART, where the
 * hardware can (ArduinoHardware on Serial): it leaves while the rest is stored, some 300 cycles
 * sooner on an AVR. advertiseService turns it on (a service's answer starts sooner); in a sketch
 * that serves nothing nothing writes the flag, and the optimizer drops the code that reads it
 * (a template's static member: defined in this header). */
template <class Unused = void>
struct EagerWrites {
  static bool on;
};
template <class Unused>
bool EagerWrites<Unused>::on = false;
}  // namespace detail
}  // namespace hwbridge

#endif  // HWBRIDGE_CONFIG_H
