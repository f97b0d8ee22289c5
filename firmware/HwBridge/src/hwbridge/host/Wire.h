// Host builds: an I2C bus with no device on it (every address NACKs). See Arduino.h here.
#ifndef HWBRIDGE_HOST_WIRE_H
#define HWBRIDGE_HOST_WIRE_H

#include "Arduino.h"

class TwoWire : public Stream {
 public:
  void begin() {}
  void end() {}
  void setClock(uint32_t) {}
  void beginTransmission(uint8_t) {}
  uint8_t endTransmission(bool = true) { return 2; }  // address NACK
  uint8_t requestFrom(uint8_t, uint8_t, uint8_t = 1) { return 0; }
  uint8_t requestFrom(int a, int n, int stop = 1) {
    return requestFrom(static_cast<uint8_t>(a), static_cast<uint8_t>(n), static_cast<uint8_t>(stop));
  }
  using Print::write;
  size_t write(uint8_t) override { return 1; }
  int available() override { return 0; }
  int read() override { return -1; }
  int peek() override { return -1; }
};

extern TwoWire Wire;

#endif  // HWBRIDGE_HOST_WIRE_H
