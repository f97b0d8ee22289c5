// The Arduino Hardware: the node's byte link over a Stream (HardwareSerial `Serial` by default).
#ifndef HWBRIDGE_HARDWARE_ARDUINO_H
#define HWBRIDGE_HARDWARE_ARDUINO_H

#include <Arduino.h>

#include "arduino_seed.h"

namespace hwbridge {

#if !defined(HWBRIDGE_SERIAL_RING) && defined(ARDUINO_ARCH_AVR) && defined(UDRIE0) && \
    defined(SERIAL_TX_BUFFER_SIZE) && SERIAL_TX_BUFFER_SIZE <= 256 && \
    (SERIAL_TX_BUFFER_SIZE & (SERIAL_TX_BUFFER_SIZE - 1)) == 0 && \
    defined(SERIAL_RX_BUFFER_SIZE) && SERIAL_RX_BUFFER_SIZE <= 256 && \
    (SERIAL_RX_BUFFER_SIZE & (SERIAL_RX_BUFFER_SIZE - 1)) == 0
#define HWBRIDGE_SERIAL_RING 1
#endif

#if HWBRIDGE_SERIAL_RING
namespace detail {
/**
 * The rings of the AVR core's HardwareSerial, reached through pointers to its protected
 * members (formed in a derived class, as C++ allows): put() stores a run of bytes the way
 * HardwareSerial::write() stores one when the ring has room, and starts the transmission once
 * for all of them: no virtual call and no interrupt lock per byte (a few cycles a byte instead
 * of some 70). A run the ring has no room for goes through write() a byte at a time (it waits,
 * or polls the UART with interrupts off), as for any other Stream. -DHWBRIDGE_SERIAL_RING=0
 * turns this off (every byte through write()).
 */
struct SerialRing : HardwareSerial {
  /** Stores n (at least 1) bytes in the ring; false (nothing stored) when they do not fit. */
  static bool put(HardwareSerial& s, const uint8_t* p, size_t n) {
    typedef tx_buffer_index_t Index;
    const Index mask = SERIAL_TX_BUFFER_SIZE - 1;
    Index head = s.*(&SerialRing::_tx_buffer_head);
    const Index tail = s.*(&SerialRing::_tx_buffer_tail);  // the interrupt only frees more
    if (n > static_cast<Index>((tail - head - 1) & mask)) return false;  // no room for all
    s.*(&SerialRing::_written) = true;
#if defined(UDR0) && defined(MPCM0)
    if (EagerWrites<>::on && head == tail && (UCSR0A & _BV(UDRE0)) && &s == &Serial) {
      // Serial's line idle (ring and data register empty): the first byte goes to the UART at
      // once, as write() does with a single byte, and leaves while the rest is copied (see
      // EagerWrites). TXC cleared with it, for flush().
      const uint8_t sreg = SREG;
      cli();
      UDR0 = *p++;
      UCSR0A = static_cast<uint8_t>((UCSR0A & (_BV(U2X0) | _BV(MPCM0))) | _BV(TXC0));
      SREG = sreg;
      if (--n == 0) return true;
    }
#endif
    unsigned char* const ring = s.*(&SerialRing::_tx_buffer);
    // A pointer that wraps at the ring's end and a one-byte count (n is below the ring's size):
    // 11 cycles a byte, where avr-gcc 5.4 made 16 of the same loop in C (it recomputed the
    // address from the index at each byte).
    unsigned char* w = ring + head;
    unsigned char* const stop = ring + mask + 1;
    uint8_t k = static_cast<uint8_t>(n);
    __asm__ volatile(
        "1:\tld __tmp_reg__, %a[p]+\n\t"
        "st %a[w]+, __tmp_reg__\n\t"
        "cp %A[w], %A[stop]\n\t"
        "cpc %B[w], %B[stop]\n\t"
        "brne 2f\n\t"
        "movw %A[w], %A[ring]\n"
        "2:\tdec %[k]\n\t"
        "brne 1b"
        : [p] "+e"(p), [w] "+e"(w), [k] "+r"(k)
        : [stop] "r"(stop), [ring] "r"(ring)
        : "memory");
    head = static_cast<Index>(w - ring);
    volatile uint8_t* const ucsrb = s.*(&SerialRing::_ucsrb);
    const uint8_t sreg = SREG;
    cli();  // as write(): the interrupt may clear UDRIE0 between our read and write of UCSRnB
    s.*(&SerialRing::_tx_buffer_head) = head;
    *ucsrb = static_cast<uint8_t>(*ucsrb | _BV(UDRIE0));
    SREG = sreg;
    return true;
  }
  /** The next received byte, or -1: HardwareSerial::read() without its virtual call. */
  static int get(HardwareSerial& s) {
    const rx_buffer_index_t tail = s.*(&SerialRing::_rx_buffer_tail);
    if (s.*(&SerialRing::_rx_buffer_head) == tail) return -1;
    const uint8_t c = (s.*(&SerialRing::_rx_buffer))[tail];
    s.*(&SerialRing::_rx_buffer_tail) =
        static_cast<rx_buffer_index_t>((tail + 1) & (SERIAL_RX_BUFFER_SIZE - 1));
    return c;
  }
};
}  // namespace detail
#endif

/**
 * The Hardware concept over Arduino: init(baud) opens Serial (or the HardwareSerial given to
 * setPort), or uses any already-open Stream given to setStream (SoftwareSerial, USB CDC...).
 * read() never blocks; put() writes one byte (HardwareSerial buffers 64 bytes and blocks only
 * when its ring is full); micros() is Arduino's.
 */
class ArduinoHardware {
 public:
  /** Use this serial port instead of Serial (before initNode). */
  void setPort(HardwareSerial* port) { serial_ = port; stream_ = port; }
  /** Use an already-initialised Stream (init() then leaves it alone). */
  void setStream(Stream* stream) { stream_ = stream; serial_ = nullptr; external_ = true; }

  bool init(uint32_t baud) {
    if (!external_) {
      if (serial_ == nullptr) serial_ = &Serial;
      serial_->begin(baud);
      stream_ = serial_;
    }
    return true;
  }
  /** The next received byte, or -1 (never blocks). */
  int read() {
#if HWBRIDGE_SERIAL_RING
    if (serial_ != nullptr) return detail::SerialRing::get(*serial_);
#endif
    return stream_->read();
  }
  /** One byte out. */
  void put(uint8_t b) { put_block(&b, 1); }
  /** n (at least 1) bytes out: into HardwareSerial's ring directly when the port is one (see
   * SerialRing), else one by one to the Stream. */
  __attribute__((noinline)) void put_block(const uint8_t* p, size_t n) {
#if HWBRIDGE_SERIAL_RING
    if (serial_ != nullptr && detail::SerialRing::put(*serial_, p, n)) return;
#endif
    do stream_->write(*p++); while (--n != 0);  // a full ring: write() waits (or polls)
  }
  void flush() {}
  uint32_t micros() { return ::micros(); }
  /** Entropy for the session id: the clock, A0 and on AVR the count of boots
   * (detail::arduino_seed()). */
  uint32_t seed() { return detail::arduino_seed(); }

 private:
  HardwareSerial* serial_ = nullptr;
  Stream* stream_ = nullptr;
  bool external_ = false;
};

}  // namespace hwbridge

#endif  // HWBRIDGE_HARDWARE_ARDUINO_H
