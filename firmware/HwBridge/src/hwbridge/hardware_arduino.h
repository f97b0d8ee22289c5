// The Arduino Hardware: the node's byte link over a Stream (HardwareSerial `Serial` by default).
#ifndef HWBRIDGE_HARDWARE_ARDUINO_H
#define HWBRIDGE_HARDWARE_ARDUINO_H

#include <Arduino.h>

namespace hwbridge {

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
  int read() { return stream_->read(); }
  void put(uint8_t b) { stream_->write(b); }
  void flush() {}
  uint32_t micros() { return ::micros(); }
  /** Entropy for the session id: the floating analog input 0 and the clock. */
  uint32_t seed() {
    uint32_t s = ::micros();
#ifdef A0
    for (uint8_t i = 0; i < 8; ++i) s = (s << 3) ^ static_cast<uint32_t>(analogRead(A0)) ^ (s >> 29);
#endif
    return s;
  }

 private:
  HardwareSerial* serial_ = nullptr;
  Stream* stream_ = nullptr;
  bool external_ = false;
};

}  // namespace hwbridge

#endif  // HWBRIDGE_HARDWARE_ARDUINO_H
